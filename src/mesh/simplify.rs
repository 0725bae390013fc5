//! Fewer triangles for web viewers: quadric edge-collapse simplification (meshoptimizer's
//! `meshopt_simplify`) to a target triangle count, a geometric error, or whichever comes first.
//!
//! Edge collapses only remove vertices, so the vertices left keep their positions, normals and
//! colours. The simplifier keeps a closed manifold mesh closed (it collapses no edge that would
//! tear or fold the topology), and the topological border of an open one (a trimmed mesh) is
//! locked in place, so trimming's edges stay where the points end.

use super::trim::retain_triangles;
use super::types::{is_closed, unpaired_edges, Mesh};

/// What [`simplify`] aims for; unset fields do not limit it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Target {
    /// At most this many triangles (the simplifier may stop above it when `max_error` or the
    /// topology does not let it go further).
    pub triangles: Option<usize>,
    /// The largest geometric deviation allowed, as a fraction of the mesh's extent (its largest
    /// bounding-box side).
    pub max_error: Option<f32>,
}

/// What [`simplify`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SimplifyReport {
    pub triangles_before: usize,
    pub triangles_after: usize,
    pub vertices_removed: usize,
    /// The deviation the simplifier reports for the result, as a fraction of the extent.
    pub error: f32,
    /// The target would have opened the closed mesh: some vertices were kept in place (and,
    /// if that was not enough, more triangles were kept).
    pub kept_closed: bool,
}

impl SimplifyReport {
    /// What the reconstruction tells the user.
    pub fn notice(&self) -> String {
        format!(
            "simplified from {} to {} triangles (largest deviation {:.2} % of the object's size){}",
            self.triangles_before,
            self.triangles_after,
            100.0 * self.error,
            if self.kept_closed { "; some vertices were held in place to keep the surface closed" } else { "" }
        )
    }
}

/// Simplifies `mesh` in place towards `target` (see the module documentation). A target with
/// neither field set, or one the mesh already meets, leaves it as it is.
pub fn simplify(mesh: &mut Mesh, target: &Target) -> SimplifyReport {
    let before = mesh.indices.len() / 3;
    let mut report = SimplifyReport { triangles_before: before, triangles_after: before, ..Default::default() };
    let want = target.triangles.unwrap_or(0).min(before);
    if (target.triangles.is_none() && target.max_error.is_none()) || (target.max_error.is_none() && want >= before) || before == 0 {
        return report;
    }
    let vertices = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&mesh.positions), 12, 0)
        .expect("positions are 12-byte vertices");
    // Without an error bound the count decides: any deviation is allowed on the way to it.
    let max_error = target.max_error.unwrap_or(f32::MAX);
    let run = |triangles: usize, lock: &[bool]| -> (Vec<u32>, f32) {
        let mut error = 0.0f32;
        let kept = meshopt::simplify_with_attributes_and_locks(
            &mesh.indices,
            &vertices,
            &[],
            &[],
            0,
            lock,
            triangles * 3,
            max_error,
            meshopt::SimplifyOptions::LockBorder,
            Some(&mut error),
        );
        // The simplifier can fold a thin part flat: two triangles on the same three vertices,
        // facing away from each other (a pillow of no volume). Dropping such pairs leaves the
        // surface around them closed.
        let keep = unfolded(&kept);
        (kept.chunks_exact(3).zip(keep).filter(|(_, k)| *k).flat_map(|(t, _)| t).copied().collect(), error)
    };
    let n = mesh.positions.len();
    let mut lock = vec![false; n];
    let (mut kept, mut error) = run(want, &lock);
    // It can also pinch a thin part until two sheets share an edge, which then no longer bounds
    // a solid. A closed mesh must stay closed: the vertices around such edges are locked and the
    // simplification run again, a few times; if that does not do it, the fewest triangles that
    // stay closed are searched for between the target and the full mesh (each run takes
    // milliseconds).
    if is_closed(&mesh.indices, n) {
        let mut tries = 0;
        // Locking the pinched vertices alone is not enough (their neighbours then collapse
        // onto them): every vertex of the full mesh within reach of the pinch is locked, the
        // reach doubling from the longest edge there while the pinch persists.
        let mut reach = 0.0f32;
        while !is_closed(&kept, n) && tries < 6 {
            let at = pinched(&kept);
            let p = |i: u32| glam::Vec3::from(mesh.positions[i as usize]);
            for t in kept.chunks_exact(3).filter(|t| t.iter().any(|v| at.binary_search(v).is_ok())) {
                reach = reach.max(p(t[0]).distance(p(t[1]))).max(p(t[1]).distance(p(t[2]))).max(p(t[2]).distance(p(t[0])));
            }
            reach *= if tries == 0 { 1.0 } else { 2.0 };
            for (v, l) in lock.iter_mut().enumerate() {
                *l |= at.iter().any(|&a| p(a).distance(p(v as u32)) <= reach);
            }
            (kept, error) = run(want, &lock);
            tries += 1;
        }
        if !is_closed(&kept, n) {
            let (mut lo, mut hi) = (want, before);
            let mut best = (mesh.indices.clone(), 0.0);
            while hi - lo > (before / 100).max(1) {
                let mid = lo + (hi - lo) / 2;
                let r = run(mid, &lock);
                if is_closed(&r.0, n) {
                    hi = mid;
                    best = r;
                } else {
                    lo = mid;
                }
            }
            (kept, error) = best;
        }
        report.kept_closed = tries > 0;
    }
    mesh.indices = kept;
    let keep = vec![true; mesh.indices.len() / 3];
    report.vertices_removed = retain_triangles(mesh, &keep);
    report.triangles_after = mesh.indices.len() / 3;
    report.error = error;
    report
}

/// The vertices of the edges that keep `indices` from being closed ([`unpaired_edges`]).
fn pinched(indices: &[u32]) -> Vec<u32> {
    let mut out: Vec<u32> = unpaired_edges(indices).into_iter().flat_map(|(a, b)| [a, b]).collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Per triangle: false for both triangles of every pair on the same three vertices (each
/// such pair once; a third copy stays).
fn unfolded(indices: &[u32]) -> Vec<bool> {
    let mut by_corners: Vec<([u32; 3], usize)> = indices
        .chunks_exact(3)
        .enumerate()
        .map(|(t, c)| {
            let mut k = [c[0], c[1], c[2]];
            k.sort_unstable();
            (k, t)
        })
        .collect();
    by_corners.sort_unstable();
    let mut keep = vec![true; indices.len() / 3];
    let mut i = 0;
    while i + 1 < by_corners.len() {
        if by_corners[i].0 == by_corners[i + 1].0 {
            keep[by_corners[i].1] = false;
            keep[by_corners[i + 1].1] = false;
            i += 2;
        } else {
            i += 1;
        }
    }
    keep
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed UV sphere of radius 1 with welded vertices (poles shared).
    fn sphere(rings: u32, segments: u32) -> Mesh {
        let mut positions = vec![[0.0, 0.0, 1.0]];
        for r in 1..rings {
            let th = std::f32::consts::PI * r as f32 / rings as f32;
            for s in 0..segments {
                let ph = std::f32::consts::TAU * s as f32 / segments as f32;
                positions.push([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]);
            }
        }
        positions.push([0.0, 0.0, -1.0]);
        let south = positions.len() as u32 - 1;
        let at = |r: u32, s: u32| 1 + (r - 1) * segments + s % segments;
        let mut indices = Vec::new();
        for s in 0..segments {
            indices.extend([0, at(1, s), at(1, s + 1)]);
            indices.extend([south, at(rings - 1, s + 1), at(rings - 1, s)]);
        }
        for r in 1..rings - 1 {
            for s in 0..segments {
                let (a, b, c, d) = (at(r, s), at(r, s + 1), at(r + 1, s), at(r + 1, s + 1));
                indices.extend([a, c, b, b, c, d]);
            }
        }
        let mut m = Mesh { positions, normals: Vec::new(), colors: None, indices };
        m.compute_vertex_normals();
        m
    }

    #[test]
    fn a_closed_mesh_stays_closed_and_near_its_surface() {
        let mut m = sphere(40, 80);
        assert!(m.is_watertight());
        let n = m.triangle_count();
        m.colors = Some((0..m.positions.len()).map(|i| [(i % 251) as u8, 7, 9, 255]).collect());
        let (before_pos, before_col) = (m.positions.clone(), m.colors.clone().unwrap());
        let r = simplify(&mut m, &Target { triangles: Some(n / 10), max_error: None });
        assert_eq!(r.triangles_before, n);
        assert!(r.triangles_after <= n / 10 && r.triangles_after > n / 20, "{r:?}");
        assert_eq!(m.triangle_count(), r.triangles_after);
        assert!(m.is_watertight(), "simplification opened the sphere");
        for p in &m.positions {
            let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-6, "vertices are kept, not moved: {len}");
        }
        // Each kept vertex brings its own colour along.
        let colors = m.colors.as_ref().unwrap();
        for (p, c) in m.positions.iter().zip(colors) {
            let i = before_pos.iter().position(|q| q == p).unwrap();
            assert_eq!(*c, before_col[i]);
        }
        assert_eq!(m.normals.len(), m.positions.len());
    }

    #[test]
    fn an_error_bound_limits_how_far_it_goes() {
        let n = sphere(40, 80).triangle_count();
        let mut tight = sphere(40, 80);
        let rt = simplify(&mut tight, &Target { triangles: None, max_error: Some(1e-4) });
        let mut loose = sphere(40, 80);
        let rl = simplify(&mut loose, &Target { triangles: None, max_error: Some(2e-2) });
        assert!(rt.error <= 1e-4 && rl.error <= 2e-2, "{rt:?} {rl:?}");
        assert!(rl.triangles_after < rt.triangles_after && rt.triangles_after <= n, "{rt:?} {rl:?}");
        assert!(rl.triangles_after < n / 4, "{rl:?}");
        // No target: untouched.
        let mut same = sphere(40, 80);
        assert_eq!(simplify(&mut same, &Target::default()).triangles_after, n);
        assert_eq!(same, sphere(40, 80));
    }

    #[test]
    fn the_border_of_an_open_mesh_stays_in_place() {
        // The upper half of the sphere: its equator is a border.
        let mut m = sphere(40, 80);
        let keep: Vec<bool> = m.indices.chunks_exact(3).map(|t| t.iter().all(|&i| m.positions[i as usize][2] >= -1e-6)).collect();
        retain_triangles(&mut m, &keep);
        let border = |m: &Mesh| -> Vec<[u32; 3]> {
            let mut edges = std::collections::HashMap::new();
            for t in m.indices.chunks_exact(3) {
                for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                    *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
                }
            }
            let mut pts: Vec<[u32; 3]> = edges
                .iter()
                .filter(|(_, &c)| c == 1)
                .flat_map(|((a, b), _)| [*a, *b])
                .map(|i| m.positions[i as usize].map(f32::to_bits))
                .collect();
            pts.sort_unstable();
            pts.dedup();
            pts
        };
        let before = border(&m);
        assert_eq!(before.len(), 80);
        let want = m.triangle_count() / 8;
        simplify(&mut m, &Target { triangles: Some(want), max_error: None });
        assert_eq!(border(&m), before, "border vertices moved or went");
    }
}
