//! The mesh's last fit to the points: each vertex moves onto the plane that best fits the input
//! points around it (a weighted least-squares plane, as in moving least squares).
//!
//! Why: a level set of any smooth field, meshed by marching cubes, passes near the points but
//! not through them; the classical peers (screened Poisson, iPSR) win on Chamfer distance
//! because their surfaces interpolate the data. Projecting each vertex onto the local plane of
//! its nearest points keeps the field's topology and closes that gap, and it averages the
//! points' noise over the neighbourhood instead of following it.
//!
//! Per vertex v: the `k` nearest input points p_i at distances d_i, Gaussian weights
//! w_i = exp(−(d_i / h)²) with h = `scale` × d_k (the k-th distance, so the neighbourhood
//! follows the local density), their weighted centroid c and covariance; the plane's normal n is
//! the covariance's eigenvector of the smallest eigenvalue, and v' = v − ((v − c)·n) n. A vertex
//! is left where it is when its nearest point is farther than `max_distance` × the spacing there
//! (there is no data there to fit: the field's surface over a hole stays as it is), or when the
//! plane's normal is more than about 75° from the mesh's own normal there (two sheets of a thin
//! part, or a corner, in one neighbourhood: the plane would cut across the surface). The spacing
//! is the cloud's mean, or the nearest point's own where the points are sparser than that
//! ([`SparseReach`]): a scan's far, sparse end is fitted too. Where the points are much sparser
//! or denser than the cloud's mean, k follows the local density as it follows the point count
//! ([`LocalDensity`]). On a Poisson surface the points of a thin wall's other side are left out
//! of each vertex's plane ([`OTHER_SIDE_COS`]).
//! The moves are then averaged over each vertex's mesh neighbours a few times (`smoothing`), so
//! the noise of each small plane fit does not reach the surface's normals. The field's own level
//! set is low-passed first and its planes are averaged instead of its moves ([`Fitted::Field`]):
//! averaged moves would carry the field's ripples through.

use super::types::Mesh;
use crate::sample::{mean_spacing_of, neighbour_distances, PointIndex};

/// What the fit did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FitReport {
    /// Vertices moved onto their local plane.
    pub moved: usize,
    /// Vertices left alone: no point within reach, or a plane across the surface.
    pub kept: usize,
    /// Of the moved vertices, those reached only through their nearest point's own spacing,
    /// where the points are sparser than the cloud's mean ([`SparseReach`]).
    pub sparse: usize,
    /// Mean distance a moved vertex travelled onto its plane (after the low pass, where there is
    /// one), in units of the cloud's mean spacing.
    pub mean_shift: f64,
    /// Triangles the moves turned over (normal against the field's mesh), before and after the
    /// repair (see [`fit_to_points`]).
    pub flipped: usize,
    pub flipped_after_repair: usize,
    /// Neighbours each vertex's plane was fitted to (where the density is about the cloud's).
    pub neighbours: usize,
    /// Vertices whose plane was fitted to fewer neighbours, where the points are sparser than
    /// the cloud's mean, and to more, where denser ([`LocalDensity`]).
    pub fewer: usize,
    pub more: usize,
    /// Vertices whose plane left out points of the other side of a thin part ([`OTHER_SIDE_COS`]).
    pub other_side: usize,
    /// When the cloud was noisier than the clean eval clouds: its noise ([`noise_level`]) and
    /// the neighbours [`FitOptions::for_points`] would have used for its point count.
    pub widened: Option<(f64, usize)>,
    /// [`Local::Tangents`]: the most each vertex's offset moved towards its neighbours' tangent
    /// planes (0.5 on a clean cloud, less on a noisier one, 0 on a noisy one); None with
    /// another local surface.
    pub tangents: Option<f64>,
    /// Taubin pairs taken off the mesh first ([`Fitted::Field`]; 0: none).
    pub low_pass: usize,
    /// What the rounds averaged, and how many rounds.
    pub average: Average,
    pub rounds: usize,
}

impl FitReport {
    /// A line for the user when the neighbourhood was widened for noise.
    pub fn notice(&self) -> Option<String> {
        self.widened.map(|(noise, usual)| {
            format!(
                "the cloud is noisy (its points lie about {noise:.4} x its longest side off their local planes): the last fit averages over \
                 {} points instead of {usual}",
                self.neighbours
            )
        })
    }
}

/// The last fit as the pipeline runs it on a mesh of kind `fitted`: [`FitOptions::for_cloud`],
/// then [`fit_to_points`].
pub fn fit_cloud(mesh: &mut Mesh, points: &[[f32; 3]], fitted: Fitted, follow_noise: bool) -> FitReport {
    let (opts, noise) = FitOptions::for_cloud(points, fitted, follow_noise);
    let usual = FitOptions::for_points(points.len()).k;
    let mut report = fit_to_points(mesh, points, &opts);
    report.widened = (opts.k > usual).then_some((noise, usual));
    report
}

/// How the fit chooses its neighbourhoods.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Neighbours per vertex.
    pub k: usize,
    /// Gaussian width as a fraction of the k-th neighbour's distance.
    pub scale: f32,
    /// Vertices whose nearest point is farther than this many mean spacings stay put.
    pub max_distance: f32,
    /// Rounds of averaging each vertex's displacement with its neighbours' (over the mesh's
    /// edges) before it is applied: each plane is fitted to a few noisy points, and moving every
    /// vertex on its own would carry that noise into the surface's normals.
    pub smoothing: usize,
    /// What those rounds average.
    pub average: Average,
    /// Pairs of Taubin steps taken on the mesh before the fit ([`Fitted::Field`]), 0 for none.
    pub low_pass: usize,
    /// What each vertex is laid on.
    pub local: Local,
    /// Whether k follows the density around each vertex ([`LocalDensity`]) rather than the
    /// cloud's mean alone.
    pub follow_density: bool,
    /// Whether points whose side of the mesh faces against the vertex's are left out of its
    /// plane ([`OTHER_SIDE_COS`]).
    pub one_side: bool,
}

/// What the mesh to be fitted is: it decides what the fit does (measured per kind in
/// docs/fit.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fitted {
    /// An object's Poisson surface, smooth between the points already: [`Local::Tangents`], the
    /// moves averaged ([`FitOptions::for_points`]).
    Poisson,
    /// An object's field level set (below 1,000 points, `--surface field`, one-sided scans). The
    /// field has ripples a few mesh edges long that follow its feature planes' grid (terraces
    /// on smooth parts where the points are sparse: issue 26's grooves). Averaging the moves
    /// would keep them (each vertex moves by its neighbours' mean move and keeps its own ripple),
    /// so the mesh is low-passed first ([`FIELD_LOW_PASS`] Taubin pairs, which take off the
    /// shortest ripples without shrinking the shape), and then the planes are averaged instead
    /// of the moves, over twice the rounds: each vertex is projected onto its averaged plane,
    /// which removes what ripple is left. Chosen on the tuning shapes at 500 points (docs/fit.md).
    Field,
    /// A scene's tiles: the least-squares planes alone, the moves averaged (as the scenes were
    /// measured: the tangent planes' noise gate is set in an object's unit cube).
    Scene,
}

impl Fitted {
    /// An object's mesh: its Poisson surface, or else the field's level set.
    pub fn object(poisson_surface: bool) -> Fitted {
        if poisson_surface {
            Fitted::Poisson
        } else {
            Fitted::Field
        }
    }
}

/// What the fit's rounds average over the mesh.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Average {
    /// Each vertex's move: the field's own shape between the points stays, ripples included.
    #[default]
    Moves,
    /// Each vertex's plane, then the vertex is projected onto the averaged one ([`Fitted::Field`]).
    Planes,
}

/// [`Fitted::Field`]'s Taubin pairs before the fit: 20, 40 and 80 measured on the tuning shapes
/// at 500 points with the planes averaged; 40 and 80 the same, 20 a little less smooth.
const FIELD_LOW_PASS: usize = 40;

/// The local surface each vertex is moved onto, fitted to its neighbours.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Local {
    /// The weighted least-squares plane.
    Plane,
    /// The plane, with its offset moved towards the mean offset of the vertex to its neighbours'
    /// own tangent planes (each point's PCA normal, [`TANGENT_NORMAL_NEIGHBOURS`]; implicit MLS,
    /// Kolluri 2005, as RIMLS evaluates it). The plane of a curved neighbourhood lies inside the
    /// curve and the neighbours' tangent planes lie outside it, by about the same sag: halfway
    /// between the two the sags cancel, with no more parameters fitted to the noise than the
    /// plane's (a quadric of 11-20 noisy points follows their noise). Each vertex goes halfway
    /// only where the two offsets differ by more than the noise of the plane's explains
    /// ([`TANGENT_SHRINK`]), and not at all on clouds noisier than the clean eval clouds
    /// ([`TANGENT_NOISE`]), where the tangent planes' tilt adds more error than the sag it
    /// removes. Every object's mesh, the Poisson surface and the field's level set at any size
    /// (scenes keep the plane: their coordinates are not the unit cube the noise gate is set in):
    /// measured in docs/fit.md ("The neighbours' tangent planes"), where it also replaced a
    /// weighted quadric over the plane for the field's level set below 5,000 points.
    Tangents,
}

impl FitOptions {
    /// The neighbourhood for a cloud of `n` points, chosen on three of the six eval shapes (cow,
    /// fandisk, suzanne) at 500, 3k and 10k points and reported on the other three (docs/fit.md):
    /// k grows as √n (8 at 500, 11 at 3k, 20 at 10k), the Gaussian widens a little with it, and
    /// the moves are smoothed more the sparser the cloud (10 rounds at 500, 4 at 3k, none from
    /// 10k on, where 20-point planes are already smooth and smoothing only blurs). An object's
    /// mesh also lets k follow the local density ([`FitOptions::for_mesh`], [`LocalDensity`]).
    pub fn for_points(n: usize) -> FitOptions {
        let n = n.max(1) as f64;
        let k = neighbours_for(n);
        let t = ((n.log10() - 500f64.log10()) / (10_000f64.log10() - 500f64.log10())).clamp(0.0, 1.0);
        let smoothing = (10.0 - 7.7 * (n.log10() - 500f64.log10())).round().clamp(0.0, 12.0) as usize;
        FitOptions { k, scale: (0.45 + 0.1 * t) as f32, max_distance: 3.0, smoothing, average: Average::Moves, low_pass: 0, local: Local::Plane, follow_density: false, one_side: false }
    }

    /// [`FitOptions::for_points`] for a mesh of kind `fitted` (see [`Fitted`]).
    pub fn for_mesh(n: usize, fitted: Fitted) -> FitOptions {
        let o = FitOptions::for_points(n);
        match fitted {
            Fitted::Poisson => FitOptions { local: Local::Tangents, follow_density: true, one_side: true, ..o },
            Fitted::Field => FitOptions { local: Local::Tangents, average: Average::Planes, smoothing: 2 * o.smoothing, low_pass: FIELD_LOW_PASS, follow_density: true, ..o },
            Fitted::Scene => o,
        }
    }

    /// [`FitOptions::for_points`] for `points`, with the neighbourhood widened where the cloud
    /// is noisier than the eval clouds those rules were chosen on (noise σ 0.005, see
    /// [`CLEAN_NOISE`]). A plane fitted to k points with noise σ is off by about σ/√k: with the
    /// noise `r` times the clean clouds' (as [`noise_level`] measures it), r²·k points keep that
    /// error where the rules left it. Chosen on noisy clouds of cow, fandisk and suzanne (σ 0.01,
    /// 0.015, 0.02 at 3k and 10k; the smoothing rounds were not changed); clean clouds fall below
    /// the threshold and keep the rules as they were. Not yet the default (setting `fitNoise`).
    /// Also returns the noise measured (0 when `follow_noise` is off).
    pub fn for_cloud(points: &[[f32; 3]], fitted: Fitted, follow_noise: bool) -> (FitOptions, f64) {
        let mut o = FitOptions::for_mesh(points.len(), fitted);
        if !follow_noise {
            return (o, 0.0);
        }
        let noise = noise_level(points);
        let ratio = (noise / clean_noise(points.len())).powi(2);
        if ratio > 1.0 {
            o.k = ((o.k as f64 * ratio).round() as usize).clamp(o.k, MAX_NEIGHBOURS.max(o.k));
        }
        (o, noise)
    }
}

/// Neighbours of each point's PCA normal for [`Local::Tangents`] (30 gave about the same on the
/// tuning shapes; the Poisson surface's normals use 30 too, but are not at hand in the fit).
const TANGENT_NORMAL_NEIGHBOURS: usize = 20;

/// [`Local::Tangents`]: a vertex goes `½·d²/(d² + TANGENT_SHRINK·v)` of the way from the
/// plane's offset to the tangent planes' (`d` their difference, `v` the variance of the
/// plane's offset: its neighbours' weighted squared residuals over their effective count), so
/// halfway where the sag stands out of the noise and hardly at all where it does not. Chosen on
/// the tuning shapes from 1, 4 and 16 (docs/fit.md).
const TANGENT_SHRINK: f64 = 4.0;

/// [`Local::Tangents`] at full weight on clouds up to the first [`noise_ratio`], fading
/// linearly to none at the second: the clean eval clouds measure 0.81-0.99, clouds with σ
/// 0.0075 (1.5 times theirs) 1.04-1.27 and were better with the plane alone (docs/fit.md).
const TANGENT_NOISE: (f64, f64) = (1.0, 1.15);

/// The weight of the tangent planes ([`Local::Tangents`]) on a cloud of this [`noise_ratio`].
fn tangent_weight(noise_ratio: f64) -> f64 {
    let (full, none) = TANGENT_NOISE;
    0.5 * ((none - noise_ratio) / (none - full)).clamp(0.0, 1.0)
}

/// The most neighbours a noisy cloud's fit averages over: beyond it the plane spans so much of
/// the surface that it cuts across its curvature.
const MAX_NEIGHBOURS: usize = 64;

/// Points whose neighbourhoods [`noise_level`] looks at: a uniform stride through the cloud,
/// enough for a stable median at a few milliseconds.
const NOISE_SAMPLES: usize = 2000;
/// Neighbours of each such point (itself included).
const NOISE_NEIGHBOURS: usize = 10;

/// The cloud's noise: the median over its points of the rms distance of each point's
/// [`NOISE_NEIGHBOURS`] nearest to their own least-squares plane (√ of the smallest eigenvalue
/// of their covariance), in the points' units. On a clean smooth surface that is the
/// curvature's sag over a neighbourhood, small against the spacing; Gaussian noise of σ adds
/// about σ·√((k − 3)/k). 0 for fewer than [`NOISE_NEIGHBOURS`] points.
pub fn noise_level(points: &[[f32; 3]]) -> f64 {
    if points.len() < NOISE_NEIGHBOURS {
        return 0.0;
    }
    let index = PointIndex::new(points);
    let stride = points.len().div_ceil(NOISE_SAMPLES).max(1);
    let mut near = Vec::with_capacity(NOISE_NEIGHBOURS);
    let mut rms: Vec<f64> = points
        .iter()
        .step_by(stride)
        .filter_map(|&p| {
            index.k_nearest(p, NOISE_NEIGHBOURS, &mut near);
            let n = near.len() as f64;
            let mut c = [0.0f64; 3];
            for &(_, j) in &near {
                (0..3).for_each(|a| c[a] += points[j as usize][a] as f64 / n);
            }
            let mut cov = [[0.0f64; 3]; 3];
            for &(_, j) in &near {
                let q = sub(points[j as usize].map(f64::from), c);
                for a in 0..3 {
                    for b in 0..3 {
                        cov[a][b] += q[a] * q[b] / n;
                    }
                }
            }
            let (values, _) = crate::eigen3::symmetric(cov)?;
            let least = values.iter().copied().fold(f64::INFINITY, f64::min);
            least.is_finite().then(|| least.max(0.0).sqrt())
        })
        .collect();
    if rms.is_empty() {
        return 0.0;
    }
    let mid = rms.len() / 2;
    *rms.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

/// [`noise_level`] of the clean eval clouds (noise σ 0.005) at the point counts the fit's
/// neighbourhoods were chosen at, a little above the largest of the six shapes': below it,
/// the cloud is no noisier than those.
const CLEAN_NOISE: [(f64, f64); 3] = [(500.0, 0.013), (3000.0, 0.005), (10_000.0, 0.004)];

/// How many times noisier `points` are than the eval clouds of as many points ([`noise_level`]
/// against [`CLEAN_NOISE`]): about 1 on a clean scan, 4 at σ 0.02.
pub fn noise_ratio(points: &[[f32; 3]]) -> f64 {
    noise_level(points) / clean_noise(points.len())
}

/// [`CLEAN_NOISE`] at `n` points, linear in log n between its entries and constant beyond.
fn clean_noise(n: usize) -> f64 {
    let x = (n.max(1) as f64).ln();
    let at = |i: usize| (CLEAN_NOISE[i].0.ln(), CLEAN_NOISE[i].1);
    let (first, last) = (at(0), at(CLEAN_NOISE.len() - 1));
    if x <= first.0 {
        return first.1;
    }
    if x >= last.0 {
        return last.1;
    }
    (1..CLEAN_NOISE.len())
        .map(|i| (at(i - 1), at(i)))
        .find(|(_, b)| x <= b.0)
        .map_or(last.1, |(a, b)| a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0))
}

/// Moves `mesh`'s vertices onto the weighted least-squares planes of `points` (same
/// coordinates), then recomputes its normals. Triangles and topology are unchanged.
pub fn fit_to_points(mesh: &mut Mesh, points: &[[f32; 3]], opts: &FitOptions) -> FitReport {
    let mut report = FitReport::default();
    if points.len() < 3 || mesh.positions.is_empty() || opts.k < 3 {
        report.kept = mesh.positions.len();
        return report;
    }
    // The mesh's edges, found once for whichever of the low pass, the rounds and the repair of
    // turned-over triangles need them (the fit does not change the triangles).
    let n_vertices = mesh.positions.len();
    let mut edges: Option<Neighbours> = None;
    if opts.low_pass > 0 {
        let neighbours = edges.get_or_insert_with(|| Neighbours::of(&mesh.indices, n_vertices));
        low_pass(mesh, neighbours, opts.low_pass);
        mesh.compute_vertex_normals();
        report.low_pass = opts.low_pass;
    }
    if mesh.normals.len() != mesh.positions.len() {
        mesh.compute_vertex_normals();
    }
    // The nearest neighbour's distance (the cloud's mean spacing) and SparseReach's rank from
    // one search.
    let mut ranks = neighbour_distances(points, &[1, SparseReach::RANK]);
    let (by_rank, first) = (ranks.pop().unwrap_or_default(), ranks.pop().unwrap_or_default());
    let spacing = mean_spacing_of(&first) as f64;
    let reach2 = (opts.max_distance as f64 * spacing).powi(2);
    let density = LocalDensity::new(&by_rank);
    let sparse_reach2 = SparseReach::of(&density, spacing, opts.max_distance as f64);
    let density = opts.follow_density.then_some(density);
    let index = PointIndex::new(points);
    let sides = opts.one_side.then(|| sides(mesh, points));
    let k = opts.k.min(points.len());
    report.neighbours = k;
    // Local::Tangents: each point's own normal, unless the cloud is too noisy to use them.
    let tangents = if opts.local == Local::Tangents { tangent_weight(noise_ratio(points)) } else { 0.0 };
    let point_normals = (tangents > 0.0)
        .then(|| crate::orient::pca_normals(points, &crate::orient::neighbourhoods(points, TANGENT_NORMAL_NEIGHBOURS, 1)));
    report.tangents = (opts.local == Local::Tangents).then_some(tangents);
    // Each vertex's plane (a point on it and its normal, turned to the mesh's side; None where it
    // stays), the vertices split over the cores.
    let mut planes: Vec<Option<([f64; 3], [f64; 3])>> = vec![None; mesh.positions.len()];
    let counts = crate::par::fill(&mut planes, |start, chunk| {
        let mut near = Vec::with_capacity(k);
        let mut done = Counts::default();
        for (i, m) in (start..).zip(chunk.iter_mut()) {
            let (v, n_mesh) = (mesh.positions[i], mesh.normals[i]);
            index.k_nearest(v, k, &mut near);
            if let Some(density) = &density {
                let k_here = density.neighbours(&near, opts.k).min(points.len());
                if k_here < near.len() {
                    near.truncate(k_here);
                    done.fewer += 1;
                } else if k_here > near.len() {
                    index.k_nearest(v, k_here, &mut near);
                    done.more += 1;
                }
            }
            if let Some(sides) = &sides {
                let other = |&(_, j): &(f32, u32)| dot(sides[j as usize].map(f64::from), n_mesh.map(f64::from)) < -OTHER_SIDE_COS;
                if near.iter().any(other) {
                    // As many of this side's points as there would have been.
                    let want = near.len();
                    index.k_nearest(v, 3 * want, &mut near);
                    near.retain(|p| !other(p));
                    near.truncate(want);
                    done.other_side += 1;
                }
            }
            let Some(&(d2, nearest)) = near.first() else { continue };
            let d2 = d2 as f64;
            // Within the cloud's reach, or only within the sparse nearest point's own (which
            // asks the plane to agree more closely with the mesh).
            let (min_cos, sparse_only) = if d2 <= reach2 {
                (MIN_COS, false)
            } else if d2 <= sparse_reach2[nearest as usize] {
                (SparseReach::MIN_COS, true)
            } else {
                continue;
            };
            let plane = plane(points, &near, opts.scale as f64);
            if let Some((c, n)) = plane.filter(|&(_, n)| dot(n, n_mesh.map(f64::from)).abs() >= min_cos) {
                let mut off = dot(sub(v.map(f64::from), c), n);
                let tangent = point_normals.as_ref().and_then(|normals| tangent_offset(points, normals, &near, opts.scale as f64, (c, n), v.map(f64::from)));
                if let Some((off_t, var)) = tangent {
                    let d = off_t - off;
                    if d != 0.0 {
                        off += tangents * d * d / (d * d + TANGENT_SHRINK * var) * d;
                    }
                }
                // The same projection whichever way n points; turned to the mesh's side so
                // that neighbours' normals can be averaged.
                let (n, off) = if dot(n, n_mesh.map(f64::from)) < 0.0 { (n.map(|x| -x), -off) } else { (n, off) };
                *m = Some((sub(v.map(f64::from), n.map(|x| off * x)), n));
                done.moved += 1;
                done.sparse += sparse_only as usize;
            }
        }
        done
    });
    report.moved = counts.iter().map(|c| c.moved).sum();
    report.sparse = counts.iter().map(|c| c.sparse).sum();
    report.fewer = counts.iter().map(|c| c.fewer).sum();
    report.more = counts.iter().map(|c| c.more).sum();
    report.other_side = counts.iter().map(|c| c.other_side).sum();
    report.kept = planes.len() - report.moved;
    if opts.smoothing > 0 {
        edges.get_or_insert_with(|| Neighbours::of(&mesh.indices, n_vertices));
    }
    let moves = match opts.average {
        Average::Planes => smooth_planes(&planes, &mesh.positions, edges.as_ref(), opts.smoothing),
        Average::Moves => {
            let moves: Vec<[f64; 3]> = planes
                .iter()
                .zip(&mesh.positions)
                .map(|(p, v)| p.map_or([0.0; 3], |(q, _)| sub(q, v.map(f64::from))))
                .collect();
            smooth(&moves, edges.as_ref(), opts.smoothing)
        }
    };
    report.average = opts.average;
    report.rounds = opts.smoothing;
    let before: Vec<[f64; 3]> = triangle_normals(&mesh.positions, &mesh.indices);
    let mut shift = 0.0f64;
    for (v, d) in mesh.positions.iter_mut().zip(&moves) {
        shift += dot(*d, *d).sqrt();
        *v = [0, 1, 2].map(|a| (v[a] as f64 + d[a]) as f32);
    }
    (report.flipped, report.flipped_after_repair) = unflip(mesh, &before, &mut edges);
    report.mean_shift = if report.moved > 0 && spacing > 0.0 { shift / report.moved as f64 / spacing } else { 0.0 };
    mesh.compute_vertex_normals();
    report
}

/// What one core's share of the vertices did in [`fit_to_points`].
#[derive(Default)]
struct Counts {
    moved: usize,
    sparse: usize,
    fewer: usize,
    more: usize,
    other_side: usize,
}

/// A point of the other side: its side of the mesh (the normal of the mesh's vertex nearest to
/// it) is more than this cosine against the fitted vertex's normal, i.e. within about 37° of
/// opposite. [`FitOptions::one_side`] leaves such points out of the vertex's plane.
///
/// Why: a wall thinner than a neighbourhood (a cup's, a sheet of metal, a leaf) has points of
/// both its faces among a vertex's nearest; their plane is the wall's middle, and both of the
/// mesh's faces were laid on it, a wall as thick as the points' noise: a cup whose wall is 2.5 %
/// of its height came out with F 0.71 at 10k points. Chosen on those cups (`scripts/thin_clouds.py`)
/// and the tuning shapes' clouds (docs/fit.md, "A thin wall's other side"): 0 (any point facing
/// away) gained the most on the cups but moved cow's clouds by up to +0.018, 0.5 by up to
/// +0.008; 0.8 keeps most of the cups' gain (cup020-10k 0.851 -> 0.571) and moves no eval cloud
/// by more than 0.004. The Poisson surface only: the field's level set around a one-sided scan
/// is a thin shell whose two layers are both meant to land on the same points (measured: the
/// one-sided clouds +0.08 to +0.13 with it).
const OTHER_SIDE_COS: f64 = 0.8;

/// Each point's side of `mesh`: the normal of the vertex nearest to it.
fn sides(mesh: &Mesh, points: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let vertices = PointIndex::new(&mesh.positions);
    let mut found = Vec::with_capacity(1);
    points
        .iter()
        .map(|&p| {
            vertices.k_nearest(p, 1, &mut found);
            found.first().map_or([0.0; 3], |&(_, v)| mesh.normals[v as usize])
        })
        .collect()
}

/// The neighbours [`FitOptions::for_points`] fits each plane to on a cloud of `n` points spread
/// evenly: 0.2·√n, at least 8 and at most 32.
fn neighbours_for(n: f64) -> usize {
    (0.2 * n.sqrt()).round().clamp(8.0, 32.0) as usize
}

/// The density around a vertex as a point count: the cloud's count, times the squared ratio of
/// the cloud's mean [`SparseReach::RANK`]-th neighbour distance to the mean of that distance over
/// the vertex's k nearest points (the count of an evenly spread cloud as dense as the points
/// there). Where that is more than [`LocalDensity::BAND`] times sparser or denser than the
/// cloud's own, k is scaled as [`neighbours_for`] scales it with the count, so that each plane
/// spans about the area it spans on an even cloud of that density.
///
/// Why: on a scan whose density falls along it (the density-falloff clouds, 55 times from end to
/// end) the cloud's k spread the sparse end's planes over an area several times wider than an
/// even cloud of that density would, and a plane over a curved patch that wide sags inside it.
/// Chosen on the density-falloff clouds (mean CD1 x100 of the tuning shapes cow, fandisk,
/// suzanne: 0.4939 -> 0.4865; docs/fit.md, "k follows the density"). The band keeps the even
/// clouds' k: without it the noise of each vertex's own density moved k on the eval clouds and
/// cost them up to 0.0017 (10k).
struct LocalDensity<'a> {
    by_rank: &'a [f32],
    mean: f64,
    count: f64,
}

impl<'a> LocalDensity<'a> {
    const BAND: f64 = 2.0;

    fn new(by_rank: &'a [f32]) -> LocalDensity<'a> {
        let mean = by_rank.iter().map(|&x| x as f64).sum::<f64>() / by_rank.len().max(1) as f64;
        LocalDensity { by_rank, mean, count: by_rank.len() as f64 }
    }

    /// The neighbours to fit a vertex's plane to, given its `near`est points (at least `k`
    /// where there are so many) and the cloud's `k`.
    fn neighbours(&self, near: &[(f32, u32)], k: usize) -> usize {
        let near = &near[..near.len().min(k)];
        if near.is_empty() || !(self.mean > 0.0) {
            return k;
        }
        let local = near.iter().map(|&(_, j)| self.by_rank[j as usize] as f64).sum::<f64>() / near.len() as f64;
        let like = self.count * (self.mean / local.max(self.mean * 1e-6)).powi(2);
        if like > self.count / Self::BAND && like < self.count * Self::BAND {
            return k;
        }
        // k in proportion to the even-cloud rule, so that a k already widened for noise
        // (FitOptions::for_cloud) keeps its widening.
        let scaled = k as f64 * neighbours_for(like) as f64 / neighbours_for(self.count) as f64;
        (scaled.round() as usize).clamp(k.min(8), k.max(32))
    }
}

/// How far from a point a vertex may be and still be fitted where the points are sparser than
/// the cloud's mean: `max_distance` × the point's own spacing (its distance to its
/// [`SparseReach::RANK`]-th neighbour, scaled so that their mean is the cloud's mean spacing),
/// when that is more than the cloud's reach.
///
/// Why: on a scan whose density falls along it (the density-falloff clouds: 55 times from one end
/// to the other), the mean spacing is the dense end's, and the sparse end's vertices were left
/// as the field or the Poisson solve put them (2,558 of cow's 20,490), though points are there.
/// A vertex reached only this way needs its plane within [`SparseReach::MIN_COS`] of the mesh's
/// normal: a sparse neighbourhood more easily spans both sides of a thin part (teapot's spout;
/// with the usual 0.25 it lost 0.019 CD1 x100 there). Chosen on the tuning shapes' falloff clouds
/// (cow, fandisk, suzanne; mean CD1 x100 0.5099 before, 0.4965 with 0.25, 0.4939 with 0.8,
/// 0.5035 with 0.95); docs/fit.md, "The sparse end", has the results.
struct SparseReach;

impl SparseReach {
    const RANK: usize = 4;
    const MIN_COS: f64 = 0.8;

    /// Each point's own reach, squared, from its distance to its [`SparseReach::RANK`]-th
    /// neighbour (`density`'s distances, over their mean; the loop takes the cloud's reach where
    /// that is larger).
    fn of(density: &LocalDensity, spacing: f64, max_distance: f64) -> Vec<f64> {
        let (d, mean) = (density.by_rank, density.mean);
        if !(mean > 0.0) {
            return vec![0.0; d.len()];
        }
        d.iter().map(|&x| (max_distance * x as f64 * spacing / mean).powi(2)).collect()
    }
}

/// Unnormalised normals (twice the area) of the triangles of `indices`.
fn triangle_normals(positions: &[[f32; 3]], indices: &[u32]) -> Vec<[f64; 3]> {
    indices
        .chunks_exact(3)
        .map(|t| {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions[i as usize].map(f64::from));
            cross(sub(b, a), sub(c, a))
        })
        .collect()
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Rounds of the repair of turned-over triangles.
const UNFLIP_ROUNDS: usize = 8;

/// Marching cubes' slivers can turn over when their vertices move onto slightly different
/// planes: a triangle whose normal now points against its normal `before` the fit shows as a
/// dark speck and breaks the surface's orientation. Each round moves the vertices of such
/// triangles to the mean of their mesh neighbours (one umbrella step, on those vertices only),
/// which unfolds a sliver without pulling the rest of the surface off its points. Returns the
/// turned-over triangles before and after the repair. `edges`: the mesh's [`Neighbours`], found
/// here if they are not yet.
fn unflip(mesh: &mut Mesh, before: &[[f64; 3]], edges: &mut Option<Neighbours>) -> (usize, usize) {
    let flipped = |mesh: &Mesh| -> Vec<usize> {
        triangle_normals(&mesh.positions, &mesh.indices)
            .iter()
            .zip(before)
            .enumerate()
            .filter(|(_, (now, was))| dot(**was, **was) > 0.0 && dot(**now, **was) <= 0.0)
            .map(|(t, _)| t)
            .collect()
    };
    let mut bad = flipped(mesh);
    let first = bad.len();
    if bad.is_empty() {
        return (0, 0);
    }
    let n = mesh.positions.len();
    let neighbours = edges.get_or_insert_with(|| Neighbours::of(&mesh.indices, n));
    for _ in 0..UNFLIP_ROUNDS {
        if bad.is_empty() {
            break;
        }
        let mut marked = vec![false; n];
        for &t in &bad {
            for &i in &mesh.indices[3 * t..3 * t + 3] {
                marked[i as usize] = true;
            }
        }
        // Jacobi-style: every marked vertex moves to the mean of its neighbours as they were.
        let moved: Vec<(usize, [f32; 3])> = (0..n)
            .filter(|&i| marked[i])
            .filter_map(|i| Some((i, neighbours.mean(i, &mesh.positions)?.map(|x| x as f32))))
            .collect();
        for (i, p) in moved {
            mesh.positions[i] = p;
        }
        bad = flipped(mesh);
    }
    (first, bad.len())
}

/// Planes more than about 75° from the mesh's own normal are not used (see the module docs).
const MIN_COS: f64 = 0.25;

/// Each vertex's distinct neighbours along the edges of a mesh's triangles, as compressed rows:
/// what the smoothing of the moves and the unfolding of turned-over triangles average over.
struct Neighbours {
    /// (vertex, neighbour), sorted: vertex `i`'s neighbours are `pairs[start[i]..start[i + 1]]`.
    pairs: Vec<(u32, u32)>,
    start: Vec<usize>,
}

impl Neighbours {
    /// The neighbours of the `n` vertices of the triangles `indices` (indices out of range and
    /// degenerate edges are ignored).
    fn of(indices: &[u32], n: usize) -> Neighbours {
        let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(indices.len() * 2);
        for t in indices.chunks_exact(3) {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                if (a as usize) < n && (b as usize) < n && a != b {
                    pairs.push((a, b));
                    pairs.push((b, a));
                }
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        let mut start = vec![0usize; n + 1];
        for &(a, _) in &pairs {
            start[a as usize + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        Neighbours { pairs, start }
    }

    /// Vertex `i`'s neighbours.
    fn of_vertex(&self, i: usize) -> impl ExactSizeIterator<Item = usize> + '_ {
        self.pairs[self.start[i]..self.start[i + 1]].iter().map(|&(_, j)| j as usize)
    }

    /// The mean of `values` over vertex `i`'s neighbours (the umbrella's centre), summed in f64;
    /// None for a vertex without neighbours.
    fn mean<T: Copy + Into<f64>>(&self, i: usize, values: &[[T; 3]]) -> Option<[f64; 3]> {
        let row = self.of_vertex(i);
        let len = row.len() as f64;
        if len == 0.0 {
            return None;
        }
        let mut sum = [0.0f64; 3];
        for j in row {
            for a in 0..3 {
                sum[a] += values[j][a].into();
            }
        }
        Some(sum.map(|x| x / len))
    }
}

/// `rounds` rounds of replacing each vertex's value by the mean over itself and its
/// `neighbours` (a uniform, Jacobi-style average); none without neighbours.
fn smooth(values: &[[f64; 3]], neighbours: Option<&Neighbours>, rounds: usize) -> Vec<[f64; 3]> {
    let n = values.len();
    let Some(neighbours) = neighbours.filter(|_| rounds > 0 && n > 0) else {
        return values.to_vec();
    };
    let mut cur = values.to_vec();
    let mut next = vec![[0.0f64; 3]; n];
    for _ in 0..rounds {
        for (i, out) in next.iter_mut().enumerate() {
            let row = neighbours.of_vertex(i);
            let w = 1.0 / (row.len() + 1) as f64;
            let mut acc = cur[i];
            for j in row {
                for a in 0..3 {
                    acc[a] += cur[j][a];
                }
            }
            *out = acc.map(|x| x * w);
        }
        std::mem::swap(&mut cur, &mut next);
    }
    cur
}

/// Taubin's λ|μ smoothing of the positions (`pairs` pairs of uniform umbrella steps, λ = 0.5,
/// μ = −0.53): ripples a few edges long fade, shapes many edges long keep their size, where
/// plain umbrella steps would shrink them. What [`Fitted::Field`] takes off the field's level
/// set before the fit (see there).
fn low_pass(mesh: &mut Mesh, neighbours: &Neighbours, pairs: usize) {
    let (lambda, mu) = (0.5f64, -0.53f64);
    let mut cur: Vec<[f64; 3]> = mesh.positions.iter().map(|p| p.map(f64::from)).collect();
    let mut next = cur.clone();
    for step in 0..2 * pairs {
        let f = if step % 2 == 0 { lambda } else { mu };
        for (i, out) in next.iter_mut().enumerate() {
            *out = match neighbours.mean(i, &cur) {
                Some(mean) => [0, 1, 2].map(|a| cur[i][a] + f * (mean[a] - cur[i][a])),
                None => cur[i],
            };
        }
        std::mem::swap(&mut cur, &mut next);
    }
    for (p, c) in mesh.positions.iter_mut().zip(&cur) {
        *p = c.map(|x| x as f32);
    }
}

/// Each vertex's move onto its plane after `rounds` rounds of averaging the planes (not the
/// moves) over the vertex and its mesh neighbours ([`Average::Planes`]): a neighbour's plane
/// counts as the projection of the vertex onto it and its normal, a vertex without a plane as
/// weight 0. The final move is the projection onto the averaged plane times the averaged weight
/// (1 inside the fitted part, fading to 0 across its edge, as the moves' average does). With no
/// rounds this is the plain projection, as [`Average::Moves`].
fn smooth_planes(planes: &[Option<([f64; 3], [f64; 3])>], positions: &[[f32; 3]], neighbours: Option<&Neighbours>, rounds: usize) -> Vec<[f64; 3]> {
    let mut cur: Vec<(f64, [f64; 3], [f64; 3])> = planes.iter().map(|p| p.map_or((0.0, [0.0; 3], [0.0; 3]), |(q, nn)| (1.0, q, nn))).collect();
    if let Some(neighbours) = neighbours.filter(|_| rounds > 0) {
        let mut next = cur.clone();
        for _ in 0..rounds {
            for (i, out) in next.iter_mut().enumerate() {
                let v = positions[i].map(f64::from);
                let (mut sw, mut sn, mut sp) = (0.0f64, [0.0f64; 3], [0.0f64; 3]);
                let mut count = 0usize;
                for j in std::iter::once(i).chain(neighbours.of_vertex(i)) {
                    count += 1;
                    let (w, q, nn) = cur[j];
                    if w > 0.0 {
                        let off = dot(sub(v, q), nn);
                        for a in 0..3 {
                            sn[a] += w * nn[a];
                            sp[a] += w * (v[a] - off * nn[a]);
                        }
                        sw += w;
                    }
                }
                let len = dot(sn, sn).sqrt();
                *out = if sw > 0.0 && len > 0.0 { (sw / count as f64, sp.map(|x| x / sw), sn.map(|x| x / len)) } else { (0.0, [0.0; 3], [0.0; 3]) };
            }
            std::mem::swap(&mut cur, &mut next);
        }
    }
    cur.iter()
        .zip(positions)
        .map(|(&(w, q, nn), v)| {
            let off = dot(sub(v.map(f64::from), q), nn);
            nn.map(|x| -w * off * x)
        })
        .collect()
}

/// The weighted centroid and unit normal of the plane through `near` (squared distances and
/// indices into `points`, nearest first), or None when the neighbourhood is degenerate.
fn plane(points: &[[f32; 3]], near: &[(f32, u32)], scale: f64) -> Option<([f64; 3], [f64; 3])> {
    let h2 = width2(near, scale)?;
    let mut wsum = 0.0;
    let mut c = [0.0f64; 3];
    for &(d2, i) in near {
        let w = (-(d2 as f64) / h2).exp();
        let p = points[i as usize];
        for a in 0..3 {
            c[a] += w * p[a] as f64;
        }
        wsum += w;
    }
    if !(wsum > 0.0) {
        return None;
    }
    c = c.map(|x| x / wsum);
    let mut cov = [[0.0f64; 3]; 3];
    for &(d2, i) in near {
        let w = (-(d2 as f64) / h2).exp() / wsum;
        let q = sub(points[i as usize].map(f64::from), c);
        for a in 0..3 {
            for b in 0..3 {
                cov[a][b] += w * q[a] * q[b];
            }
        }
    }
    let n = smallest_eigenvector(cov)?;
    Some((c, n))
}

/// [`Local::Tangents`]' two numbers at vertex `v` over the plane `(c, n)` of `near` (the
/// plane's Gaussian weights): the weighted mean of `v`'s offsets to the neighbours' tangent
/// planes (their `normals` turned to agree with `n`), and the variance of the plane's own offset
/// (the weighted mean squared residual of the neighbours over their effective count); None
/// where the weights vanish (as [`plane`], which is then None first).
fn tangent_offset(points: &[[f32; 3]], normals: &[[f32; 3]], near: &[(f32, u32)], scale: f64, (c, n): ([f64; 3], [f64; 3]), v: [f64; 3]) -> Option<(f64, f64)> {
    let h2 = width2(near, scale)?;
    let (mut sw, mut sw2, mut off, mut res2) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for &(d2, i) in near {
        let w = (-(d2 as f64) / h2).exp();
        let p = points[i as usize].map(f64::from);
        let ni = normals[i as usize].map(f64::from);
        let ni = if dot(ni, n) < 0.0 { ni.map(|a| -a) } else { ni };
        sw += w;
        sw2 += w * w;
        off += w * dot(sub(v, p), ni);
        res2 += w * dot(sub(p, c), n).powi(2);
    }
    // Effective count (Σw)²/Σw², so the variance of the mean is (Σw·r²/Σw)·Σw²/(Σw)².
    (sw > 0.0).then(|| (off / sw, res2 / sw * sw2 / (sw * sw)))
}

/// The squared width of the fit's Gaussian weights `exp(−d²/h²)` over the neighbourhood `near`
/// (nearest first): `h = scale` × the farthest neighbour's distance; None without neighbours.
fn width2(near: &[(f32, u32)], scale: f64) -> Option<f64> {
    let dk2 = near.last()?.0 as f64;
    Some((scale * scale * dk2).max(f64::MIN_POSITIVE))
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The unit eigenvector of the smallest eigenvalue of the symmetric 3×3 matrix `a` (the plane's
/// normal for a covariance matrix); None when `a` is not finite.
fn smallest_eigenvector(a: [[f64; 3]; 3]) -> Option<[f64; 3]> {
    let (values, vectors) = crate::eigen3::symmetric(a)?;
    let i = (0..3).min_by(|&i, &j| values[i].total_cmp(&values[j]))?;
    Some(vectors[i])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::mean_spacing;

    /// A 5 × 5 vertex grid in the plane z = 0, two triangles a cell, all facing +z.
    fn grid() -> Mesh {
        let positions: Vec<[f32; 3]> = (0..25).map(|i| [(i % 5) as f32, (i / 5) as f32, 0.0]).collect();
        let mut indices = Vec::new();
        for y in 0..4u32 {
            for x in 0..4u32 {
                let v = y * 5 + x;
                indices.extend_from_slice(&[v, v + 1, v + 6, v, v + 6, v + 5]);
            }
        }
        Mesh { normals: vec![[0.0, 0.0, 1.0]; 25], positions, colors: None, indices }
    }

    #[test]
    fn turned_over_triangles_are_unfolded() {
        let mut mesh = grid();
        let before = triangle_normals(&mesh.positions, &mesh.indices);
        // The centre vertex pushed across two of its neighbours turns triangles over.
        mesh.positions[12] = [3.6, 2.4, 0.0];
        let now = triangle_normals(&mesh.positions, &mesh.indices);
        let turned = now.iter().zip(&before).filter(|(a, b)| dot(**a, **b) <= 0.0).count();
        assert!(turned >= 2, "the set-up should turn triangles over: {turned}");
        let (first, after) = unflip(&mut mesh, &before, &mut None);
        assert_eq!((first, after), (turned, 0));
        // Only the vertices of turned-over triangles moved; the border stayed.
        assert_eq!(mesh.positions[0], [0.0, 0.0, 0.0]);
        assert_eq!(mesh.positions[24], [4.0, 4.0, 0.0]);
        // Nothing to repair: nothing moves.
        let mut flat = grid();
        assert_eq!(unflip(&mut flat, &before, &mut None), (0, 0));
        assert_eq!(flat.positions, grid().positions);
    }

    #[test]
    fn the_normal_is_the_eigenvector_of_the_smallest_eigenvalue() {
        // The solver itself is tested in eigen3; here, that the smallest one is picked.
        let n = smallest_eigenvector([[2.0, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 1.0]]).unwrap();
        assert!((n[1].abs() - 1.0).abs() < 1e-12, "{n:?}");
        assert_eq!(smallest_eigenvector([[f64::NAN; 3]; 3]), None);
    }

    #[test]
    fn vertices_land_on_the_plane_of_their_points() {
        // Points on z = 0.1 (a grid), a mesh vertex hovering at z = 0.13 with an upward normal.
        let points: Vec<[f32; 3]> =
            (0..21).flat_map(|i| (0..21).map(move |j| [i as f32 * 0.01, j as f32 * 0.01, 0.1])).collect();
        let mut mesh = Mesh {
            positions: vec![[0.1, 0.1, 0.13], [0.11, 0.1, 0.13], [0.1, 0.11, 0.13], [5.0, 5.0, 5.0]],
            normals: vec![[0.0, 0.0, 1.0]; 4],
            colors: None,
            indices: vec![0, 1, 2, 1, 3, 2],
        };
        let r = fit_to_points(&mut mesh, &points, &FitOptions { k: 12, scale: 0.7, max_distance: 5.0, smoothing: 0, average: Average::Moves, low_pass: 0, local: Local::Plane, follow_density: false, one_side: false });
        assert_eq!((r.moved, r.kept), (3, 1));
        for v in &mesh.positions[..3] {
            assert!((v[2] - 0.1).abs() < 1e-6, "{v:?}");
        }
        assert_eq!(mesh.positions[3], [5.0, 5.0, 5.0], "beyond reach: unchanged");
        assert!((r.mean_shift - 3.0).abs() < 1e-3, "{}", r.mean_shift);
    }

    #[test]
    fn the_neighbourhood_follows_the_point_count() {
        let at = |n| {
            let o = FitOptions::for_points(n);
            (o.k, o.smoothing)
        };
        assert_eq!([at(500), at(3000), at(10_000), at(1_000_000)], [(8, 10), (11, 4), (20, 0), (32, 0)]);
    }

    /// On a sphere (radius 0.4, 3000 exact points, the fit's 3k neighbourhood) vertices
    /// hovering 0.01 outside land on the plane of their neighbours inside the sphere by the
    /// curve's sag (measured −4.3e-4); with the neighbours' tangent planes (`Local::Tangents`,
    /// full weight on a clean cloud) the sag cancels (−4.6e-5; a weighted quadric, since
    /// removed, left −7.7e-5).
    #[test]
    fn the_neighbours_tangent_planes_cancel_the_planes_sag() {
        let points = noisy_sphere(3000, 0.0);
        let opts = FitOptions { smoothing: 0, ..FitOptions::for_points(points.len()) };
        let dirs = noisy_sphere(200, 0.0);
        let fit = |local: Local| {
            let mut mesh = hovering(&dirs);
            let r = fit_to_points(&mut mesh, &points, &FitOptions { local, ..opts });
            let bias = mesh.positions.iter().map(|v| v.iter().map(|&c| (c as f64).powi(2)).sum::<f64>().sqrt() - 0.4).sum::<f64>();
            (bias / dirs.len() as f64, r)
        };
        let ((plane, _), (tangents, report)) = (fit(Local::Plane), fit(Local::Tangents));
        println!("mean radius error: plane {plane:e}, with the tangent planes {tangents:e}");
        assert_eq!(report.tangents, Some(0.5), "a clean cloud: full weight");
        assert_eq!(report.moved, dirs.len());
        assert!(plane < -2e-4, "the plane lies inside the curve: {plane:e}");
        assert!(tangents.abs() < 0.3 * plane.abs(), "tangent planes {tangents:e} against plane {plane:e}");
    }

    /// On a cloud noisier than the clean eval clouds the tangent planes stay out: the same
    /// vertices as the plane's, to the bit. Between, the weight falls with the noise.
    #[test]
    fn a_noisy_cloud_keeps_the_plane() {
        let points = noisy_sphere(3000, 0.02);
        assert!(noise_ratio(&points) > TANGENT_NOISE.1, "{}", noise_ratio(&points));
        let dirs = noisy_sphere(200, 0.0);
        let fit = |local: Local| {
            let mut mesh = hovering(&dirs);
            let r = fit_to_points(&mut mesh, &points, &FitOptions { local, ..FitOptions::for_points(points.len()) });
            (mesh.positions, r.tangents)
        };
        let (plane, tangents) = (fit(Local::Plane), fit(Local::Tangents));
        assert_eq!(tangents.1, Some(0.0));
        assert_eq!(plane.0, tangents.0);
        assert_eq!(tangent_weight(TANGENT_NOISE.0), 0.5);
        assert_eq!(tangent_weight(0.5 * (TANGENT_NOISE.0 + TANGENT_NOISE.1)), 0.25);
        assert_eq!(tangent_weight(TANGENT_NOISE.1), 0.0);
    }

    /// Where the points are sparser than the cloud's mean (a scan's far end), vertices are fitted
    /// within the sparse points' own reach ([`SparseReach`]), not left where they were; a vertex
    /// beyond every point's reach still stays.
    #[test]
    fn the_sparse_end_is_fitted_too() {
        let mut rng = crate::rng::SplitMix64(11);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.unit();
        // z = 0: 4000 points on x in [-1, 0], 100 on x in [0, 1] (40 times sparser).
        let mut points: Vec<[f32; 3]> = Vec::new();
        for (n, lo, hi) in [(4000, -1.0, 0.0), (100, 0.0, 1.0)] {
            for _ in 0..n {
                points.push([uniform(lo, hi) as f32, uniform(-1.0, 1.0) as f32, 0.0]);
            }
        }
        // Vertices 0.01 above the sparse half, and one far off to the side.
        let mut positions: Vec<[f32; 3]> = (0..64).map(|i| [0.3 + 0.6 * (i % 8) as f32 / 7.0, -0.8 + 1.6 * (i / 8) as f32 / 7.0, 0.01]).collect();
        positions.push([4.0, 0.0, 0.01]);
        let mut mesh = Mesh { normals: vec![[0.0, 0.0, 1.0]; positions.len()], positions, colors: None, indices: Vec::new() };
        let spacing = mean_spacing(&points) as f64;
        let opts = FitOptions { smoothing: 0, local: Local::Plane, ..FitOptions::for_points(points.len()) };
        let index = PointIndex::new(&points);
        let mut near = Vec::new();
        let beyond_the_mean = mesh.positions[..64]
            .iter()
            .filter(|&&v| {
                index.k_nearest(v, 1, &mut near);
                (near[0].0 as f64).sqrt() > opts.max_distance as f64 * spacing
            })
            .count();
        assert!(beyond_the_mean > 32, "the set-up: most of the sparse half's vertices are beyond the mean's reach ({beyond_the_mean})");
        let report = fit_to_points(&mut mesh, &points, &opts);
        let landed = mesh.positions[..64].iter().filter(|v| v[2].abs() < 1e-4).count();
        assert_eq!(landed, 64, "{report:?}");
        assert!(report.sparse >= beyond_the_mean, "{report:?}");
        assert_eq!(mesh.positions[64], [4.0, 0.0, 0.01], "no point within reach: left alone");
    }

    #[test]
    fn k_follows_the_density_where_it_falls() {
        // The radius-0.4 sphere, clean, its density falling 40 times from z = -0.4 to z = 0.4
        // (as the density-falloff clouds'); vertices hovering over its sparse cap.
        let mut rng = crate::rng::SplitMix64(5);
        let points: Vec<[f32; 3]> = noisy_sphere(40_000, 0.0).into_iter().filter(|p| rng.unit() < 40f64.powf(-(p[2] as f64 + 0.4) / 0.8)).take(3000).collect();
        assert!(points.len() > 2500, "the set-up: {} points", points.len());
        let dirs: Vec<[f32; 3]> = noisy_sphere(400, 0.0).into_iter().filter(|d| d[2] > 0.25).collect();
        let opts = FitOptions { smoothing: 0, local: Local::Plane, ..FitOptions::for_points(points.len()) };
        let fit = |follow_density: bool| {
            let mut mesh = hovering(&dirs);
            let r = fit_to_points(&mut mesh, &points, &FitOptions { follow_density, ..opts });
            let err = mesh.positions.iter().map(|v| (v.iter().map(|&c| (c as f64).powi(2)).sum::<f64>().sqrt() - 0.4).abs()).sum::<f64>();
            (err / dirs.len() as f64, r)
        };
        let ((cloud_k, before), (local_k, after)) = (fit(false), fit(true));
        println!("sparse cap, mean radius error: the cloud's k {cloud_k:e}, k following the density {local_k:e} ({after:?})");
        assert_eq!((before.fewer, before.more), (0, 0));
        assert!(after.fewer > dirs.len() / 2, "{after:?}");
        assert!(local_k < 0.8 * cloud_k, "the plane over the cloud's k sags more: {local_k:e} against {cloud_k:e}");
    }

    #[test]
    fn a_thin_walls_faces_keep_their_own_points() {
        // A wall 0.02 thick: points on z = 0 and z = 0.02 (x, y in [-1, 1]); the mesh's two faces
        // 0.005 outside it, facing out. The cloud's k spans both faces' points.
        let mut rng = crate::rng::SplitMix64(3);
        let mut points: Vec<[f32; 3]> = Vec::new();
        for z in [0.0f32, 0.02] {
            for _ in 0..3000 {
                points.push([(2.0 * rng.unit() - 1.0) as f32, (2.0 * rng.unit() - 1.0) as f32, z]);
            }
        }
        let grid: Vec<[f32; 2]> = (0..49).map(|i| [-0.6 + 1.2 * (i % 7) as f32 / 6.0, -0.6 + 1.2 * (i / 7) as f32 / 6.0]).collect();
        let wall = || {
            let mut positions: Vec<[f32; 3]> = grid.iter().map(|&[x, y]| [x, y, -0.005]).collect();
            positions.extend(grid.iter().map(|&[x, y]| [x, y, 0.025]));
            let normals = (0..2 * grid.len()).map(|i| if i < grid.len() { [0.0, 0.0, -1.0] } else { [0.0, 0.0, 1.0] }).collect();
            Mesh { positions, normals, colors: None, indices: Vec::new() }
        };
        let opts = FitOptions { k: 24, smoothing: 0, local: Local::Plane, ..FitOptions::for_points(points.len()) };
        let z_error = |mesh: &Mesh| {
            let n = grid.len();
            mesh.positions.iter().enumerate().map(|(i, v)| (v[2] - if i < n { 0.0 } else { 0.02 }).abs() as f64).sum::<f64>() / (2 * n) as f64
        };
        let (mut both, mut own) = (wall(), wall());
        let before = fit_to_points(&mut both, &points, &FitOptions { one_side: false, ..opts });
        let after = fit_to_points(&mut own, &points, &FitOptions { one_side: true, ..opts });
        println!("mean distance to the own face: both faces' points {:e}, one side's {:e}", z_error(&both), z_error(&own));
        assert_eq!(before.other_side, 0);
        assert_eq!(after.other_side, 2 * grid.len(), "{after:?}");
        assert!(z_error(&both) > 0.005, "the set-up: the planes of both faces' points lie in the wall's middle");
        assert!(z_error(&own) < 1e-4, "each face on its own points: {:e}", z_error(&own));
    }

    #[test]
    fn an_even_cloud_keeps_its_k() {
        // Uniform random samples clump here and there (the eval clouds: about 1 % of the
        // vertices); without the band every vertex's k would follow its own clump.
        let points = noisy_sphere(3000, 0.005);
        let dirs = noisy_sphere(300, 0.0);
        let opts = FitOptions { smoothing: 0, ..FitOptions::for_points(points.len()) };
        let (mut a, mut b) = (hovering(&dirs), hovering(&dirs));
        fit_to_points(&mut a, &points, &FitOptions { follow_density: false, ..opts });
        let r = fit_to_points(&mut b, &points, &FitOptions { follow_density: true, ..opts });
        assert!(r.fewer + r.more <= dirs.len() / 10, "an even cloud: its k almost everywhere ({r:?})");
        let same = a.positions.iter().zip(&b.positions).filter(|(p, q)| p == q).count();
        assert!(same >= dirs.len() - r.fewer - r.more, "{same} of {} vertices where they were", dirs.len());
    }

    /// Vertices (no triangles) 0.01 outside the radius-0.4 sphere along the directions `dirs`
    /// (points of that sphere), with the sphere's normals.
    fn hovering(dirs: &[[f32; 3]]) -> Mesh {
        Mesh {
            positions: dirs.iter().map(|d| d.map(|c| c * 0.41 / 0.4)).collect(),
            normals: dirs.iter().map(|d| d.map(|c| c / 0.4)).collect(),
            colors: None,
            indices: Vec::new(),
        }
    }

    /// `n` points on the unit sphere's surface scaled to radius 0.4 (a cloud the size of the
    /// unit cube), pushed along the radius by Gaussian noise of `sigma`; seeded.
    fn noisy_sphere(n: usize, sigma: f64) -> Vec<[f32; 3]> {
        let mut rng = crate::rng::SplitMix64(7);
        let mut gauss = || rng.normal();
        (0..n)
            .map(|_| {
                let d = [gauss(), gauss(), gauss()];
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-12);
                let r = 0.4 + sigma * gauss();
                d.map(|x| (x / len * r) as f32)
            })
            .collect()
    }

    #[test]
    fn the_noise_level_grows_with_the_noise() {
        let clean = noise_level(&noisy_sphere(3000, 0.0));
        let some = noise_level(&noisy_sphere(3000, 0.005));
        let more = noise_level(&noisy_sphere(3000, 0.02));
        // Clean: only the sphere's sag over a 10-point patch (radius ~0.03): ~1e-3 at most.
        assert!(clean < 1.5e-3, "{clean}");
        // With noise it measures a fraction of sigma that falls as sigma nears the spacing (the
        // neighbourhood's own extent), but it is ordered and well apart.
        assert!(some > 2.0 * clean && some < 0.006, "{some}");
        assert!(more > 1.6 * some && more < 0.02, "{more}");
        assert_eq!(noise_level(&noisy_sphere(5, 0.01)), 0.0, "too few points to say");
    }

    #[test]
    fn a_noisy_cloud_gets_a_wider_neighbourhood() {
        let usual = FitOptions::for_points(3000);
        let (clean, _) = FitOptions::for_cloud(&noisy_sphere(3000, 0.004), Fitted::Scene, true);
        assert_eq!(clean, usual, "at the eval clouds' noise the rules are unchanged");
        let (noisy, noise) = FitOptions::for_cloud(&noisy_sphere(3000, 0.02), Fitted::Scene, true);
        let expected = ((usual.k as f64 * (noise / clean_noise(3000)).powi(2)).round() as usize).min(MAX_NEIGHBOURS);
        assert!(noisy.k > 2 * usual.k && noisy.k == expected, "{} vs {} ({noise})", noisy.k, usual.k);
        assert_eq!((noisy.smoothing, noisy.scale), (usual.smoothing, usual.scale));
        let (off, _) = FitOptions::for_cloud(&noisy_sphere(3000, 0.02), Fitted::Scene, false);
        assert_eq!(off, usual, "without --fit-noise the point count's rule stays");
        // The reference follows the point count between its entries, constant beyond.
        assert_eq!(clean_noise(100), 0.013);
        assert_eq!(clean_noise(1_000_000), 0.004);
        assert!((clean_noise(3000) - 0.005).abs() < 1e-12);
        let mid = clean_noise(1225); // √(500·3000): halfway in log n
        assert!((mid - 0.009).abs() < 1e-5, "{mid}");
    }

    /// A `side` × `side` vertex grid with spacing `edge` in x and y, at height `z(x, y)`, two
    /// triangles a cell, facing +z.
    fn wavy_grid(side: u32, edge: f32, z: impl Fn(f32, f32) -> f32) -> Mesh {
        let positions: Vec<[f32; 3]> = (0..side * side)
            .map(|i| {
                let (x, y) = ((i % side) as f32 * edge, (i / side) as f32 * edge);
                [x, y, z(x, y)]
            })
            .collect();
        let mut indices = Vec::new();
        for y in 0..side - 1 {
            for x in 0..side - 1 {
                let v = y * side + x;
                indices.extend_from_slice(&[v, v + 1, v + side + 1, v, v + side + 1, v + side]);
            }
        }
        let mut mesh = Mesh { normals: Vec::new(), positions, colors: None, indices };
        mesh.compute_vertex_normals();
        mesh
    }

    /// The rms of `z − 0.1` over the vertices at least `margin` from the grid's border.
    fn ripple_rms(mesh: &Mesh, side: u32, margin: u32) -> f64 {
        let inner: Vec<f64> = (0..side * side)
            .filter(|i| (margin..side - margin).contains(&(i % side)) && (margin..side - margin).contains(&(i / side)))
            .map(|i| mesh.positions[i as usize][2] as f64 - 0.1)
            .collect();
        (inner.iter().map(|d| d * d).sum::<f64>() / inner.len() as f64).sqrt()
    }

    /// Taubin's pairs take off a ripple 4 edges long (measured: to 1.6 %) and keep a wave 40 edges
    /// long (+0.9 %): the shape stays (plain umbrella steps shrink waves of every length).
    #[test]
    fn the_low_pass_takes_ripples_not_shapes() {
        let (side, edge) = (81, 0.01);
        let wave = |period: f32, amplitude: f32| move |x: f32, _y: f32| 0.1 + amplitude * (std::f32::consts::TAU * x / (period * edge)).sin();
        let mut short = wavy_grid(side, edge, wave(4.0, 0.003));
        let mut long = wavy_grid(side, edge, wave(40.0, 0.01));
        let (short0, long0) = (ripple_rms(&short, side, 10), ripple_rms(&long, side, 10));
        let neighbours = Neighbours::of(&short.indices, short.positions.len());
        low_pass(&mut short, &neighbours, FIELD_LOW_PASS);
        low_pass(&mut long, &neighbours, FIELD_LOW_PASS);
        let (short1, long1) = (ripple_rms(&short, side, 10), ripple_rms(&long, side, 10));
        println!("ripple rms {short0:e} -> {short1:e}, long wave {long0:e} -> {long1:e}");
        assert!(short1 < 0.05 * short0, "the ripple stays: {short0:e} -> {short1:e}");
        assert!((long1 / long0 - 1.0).abs() < 0.03, "the long wave changed: {long0:e} -> {long1:e}");
    }

    /// The field's ripples (here 4 edges long, 0.003 high, over points on the plane z = 0.1 at
    /// about 500 points' spacing in the unit cube): averaging the moves keeps them, the field's
    /// fit (the low pass, then the planes averaged) leaves next to nothing of them.
    #[test]
    fn the_fields_ripples_do_not_survive_the_fit() {
        let (side, edge) = (61, 0.01);
        let ripple = |x: f32, _y: f32| 0.1 + 0.003 * (std::f32::consts::TAU * x / (4.0 * edge)).sin();
        let mut rng = crate::rng::SplitMix64(3);
        let points: Vec<[f32; 3]> = (0..500).map(|_| [(rng.unit() * 0.6) as f32, (rng.unit() * 0.6) as f32, 0.1]).collect();
        let fit = |fitted: Fitted| {
            let mut mesh = wavy_grid(side, edge, ripple);
            let r = fit_to_points(&mut mesh, &points, &FitOptions::for_mesh(points.len(), fitted));
            (ripple_rms(&mesh, side, 8), r)
        };
        let ((moves, _), (field, report)) = (fit(Fitted::Poisson), fit(Fitted::Field));
        println!("ripple rms after the fit: moves averaged {moves:e}, the field's fit {field:e}");
        assert_eq!((report.low_pass, report.average, report.rounds), (FIELD_LOW_PASS, Average::Planes, 20));
        assert!(moves > 1e-3, "averaging the moves should keep the ripple: {moves:e}");
        assert!(field < 0.05 * moves, "the field's fit kept the ripple: {field:e} against {moves:e}");
    }

    /// With no rounds, averaging the planes is the plain projection, as averaging the moves.
    #[test]
    fn planes_without_rounds_are_the_projection() {
        let points: Vec<[f32; 3]> = (0..21).flat_map(|i| (0..21).map(move |j| [i as f32 * 0.03, j as f32 * 0.03, 0.1])).collect();
        let fit = |average: Average| {
            let mut mesh = wavy_grid(31, 0.02, |x, y| 0.1 + 0.004 * (x * 40.0).sin() * (y * 30.0).cos());
            let opts = FitOptions { smoothing: 0, average, ..FitOptions::for_points(points.len()) };
            fit_to_points(&mut mesh, &points, &opts);
            mesh.positions
        };
        let (moves, planes) = (fit(Average::Moves), fit(Average::Planes));
        let worst = moves.iter().zip(&planes).flat_map(|(a, b)| (0..3).map(move |i| (a[i] - b[i]).abs())).fold(0.0f32, f32::max);
        assert!(worst < 1e-6, "{worst:e}");
    }

    #[test]
    fn moves_are_averaged_over_mesh_neighbours() {
        // One triangle and a lone vertex: the triangle's moves mix, the lone one keeps its own.
        let moves = [[3.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 6.0, 0.0]];
        let once = smooth(&moves, Some(&Neighbours::of(&[0, 1, 2, 0, 2, 1], moves.len())), 1);
        assert_eq!(once, vec![[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 6.0, 0.0]]);
        assert_eq!(smooth(&moves, Some(&Neighbours::of(&[0, 1, 2], moves.len())), 0), moves.to_vec());
    }

    #[test]
    fn a_plane_across_the_surface_is_not_used() {
        // Points on x = 0; the vertex's own normal says the surface there faces z: the fitted
        // plane (normal x) is more than 60° from it, so the vertex stays.
        let points: Vec<[f32; 3]> =
            (0..11).flat_map(|i| (0..11).map(move |j| [0.0, i as f32 * 0.01, j as f32 * 0.01])).collect();
        let mut mesh = Mesh {
            positions: vec![[0.01, 0.05, 0.05]],
            normals: vec![[0.0, 0.0, 1.0]],
            colors: None,
            indices: vec![],
        };
        let r = fit_to_points(&mut mesh, &points, &FitOptions { k: 12, scale: 0.7, max_distance: 5.0, smoothing: 0, average: Average::Moves, low_pass: 0, local: Local::Plane, follow_density: false, one_side: false });
        assert_eq!((r.moved, r.kept), (0, 1));
        assert_eq!(mesh.positions[0], [0.01, 0.05, 0.05]);
    }
}
