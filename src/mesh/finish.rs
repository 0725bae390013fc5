//! The finishing stage, in the network's unit cube against the points it saw: components the
//! points do not support go, then the last fit to the points, a scene's sheets to one layer, the
//! trim of what was never scanned and the simplification, each when the settings ask for it
//! (the plan's "finish").

use super::fit::{fit_cloud, FitReport, Fitted};
use super::sheets::single_layer;
use super::simplify::{simplify, SimplifyReport, Target};
use super::trim::{open_kept, reach, surface_distance, trim, trim_between_sheets, Reach, TrimReport, BETWEEN_SHEETS_DEPTH, DEFAULT_TRIM, SPARSE_BETWEEN_SHEETS_SHARE};
use super::types::Mesh;
use crate::gpu::now;
use crate::settings::Settings;

/// What each finishing step did (None: not asked for).
pub struct Finished {
    pub fit: Option<FitReport>,
    pub trim: Option<TrimReport>,
    pub simplify: Option<SimplifyReport>,
}

/// What the finish may take of a closed surface that no trim was asked for.
#[derive(Clone, Copy)]
pub enum Closure<'a> {
    /// It stays whole: a Poisson surface kept, a scene, the field's surface asked for.
    Keep,
    /// The scan saw one side of the object or is an open shell (the Poisson surface ballooned):
    /// pieces that no point is near are the prior's guess of the rest and stay
    /// ([`super::remove_unsupported_components`]); what lies far from the points deep inside
    /// their hull goes ([`trim_between_sheets`]).
    OneSided,
    /// A Poisson surface that the balloon guard kept over the field's farther mesh (walls
    /// thinner than the field resolves, an opening the points ring, a slab beyond the points)
    /// with no trim asked for: it is opened where it is far from the points or far outside their
    /// hull ([`open_kept`]), as neither closure is the scan's; measured against the points as
    /// the guard measured them (the same points the finish gets).
    Open(&'a Reach<'a>),
    /// The field's level set of a cloud too small for the Poisson surface, which cannot tell an
    /// open shell: the fill between sheets goes only where it is a large part of the mesh
    /// ([`SPARSE_BETWEEN_SHEETS_SHARE`]).
    Sparse,
}

impl Closure<'_> {
    /// How far a finished mesh lies from the points, for the guard that keeps the network's
    /// mesh where the tuned field's is farther (`pipeline`, docs/poisson.md "Open shells"); None
    /// where the surface is kept whole (no guard).
    ///
    /// - `OneSided`: the points' mean distance to the mesh ([`reach`]): the sides the scan
    ///   missed lie far from every point by nature, so the mesh's own distance to the points
    ///   weighs the prior's guess of them, not a fault.
    /// - `Sparse`: both ways, half the sum of [`reach`] and the mesh's distance to the points
    ///   ([`surface_distance`]): a small cloud's mesh is meant to lie on its points everywhere,
    ///   and where the tuned field filled a cup with foam its mesh came nearer the points than
    ///   the network's opened cup while farther from the truth (nkrr behind the network alone by
    ///   up to 0.43 CD1 x100 at 500 points with the points' side alone). Chosen on the shells and
    ///   cups of `scripts/thin_clouds.py` and the eval clouds of cow, fandisk and suzanne at
    ///   500-1,500 points (docs/poisson.md, "Both ways below 2,000 points").
    pub fn distance(self, mesh: &Mesh, points: &[[f32; 3]]) -> Option<f64> {
        match self {
            Closure::Keep | Closure::Open(_) => None,
            Closure::OneSided => Some(reach(mesh, points)),
            Closure::Sparse => Some(0.5 * (reach(mesh, points) + surface_distance(mesh, points))),
        }
    }
}

/// Finishes `mesh` against `points` as `settings` ask, adding what it says to `notices` and
/// each step's seconds to `timings`. `fitted`: what the mesh is, which decides the fit ([`Fitted`]).
/// `sheet_gap`: a scene's (with [`Settings::one_layer`]), the most two coincident layers lie
/// apart after the fit ([`single_layer`]); objects pass None. `closure`: what of the closed
/// surface may be opened where no trim was asked for ([`Closure`]).
#[allow(clippy::too_many_arguments)]
pub fn finish(
    mesh: &mut Mesh,
    points: &[[f32; 3]],
    settings: &Settings,
    fitted: Fitted,
    closure: Closure,
    sheet_gap: Option<f32>,
    notices: &mut Vec<String>,
    timings: &mut Vec<(&'static str, f64)>,
) -> Finished {
    if let Some(share) = settings.min_support {
        let r = super::remove_unsupported_components(mesh, points, share as f32, matches!(closure, Closure::OneSided));
        notices.extend(r.unsupported_notice(share));
    }
    let fit = settings.fit.then(|| {
        let t = now();
        let r = fit_cloud(mesh, points, fitted, settings.fit_noise);
        timings.push(("fit", now() - t));
        notices.extend(r.notice());
        r
    });
    // After the fit, which lays both layers of a sheet on its points.
    if let Some(gap) = sheet_gap.filter(|_| settings.one_layer) {
        let t = now();
        let r = single_layer(mesh, points, gap);
        timings.push(("one layer", now() - t));
        notices.extend(r.notice());
    }
    let t = now();
    let trim = match settings.trim {
        Some(factor) => {
            let r = trim(mesh, points, factor);
            notices.push(r.notice(factor));
            Some(r)
        }
        None => match closure {
            Closure::Keep => None,
            Closure::Open(reach) => {
                let r = open_kept(mesh, reach);
                notices.push(r.opened_notice());
                Some(r)
            }
            // A one-sided scan's closure stays, an open shell's fill goes.
            Closure::OneSided | Closure::Sparse => {
                let (factor, depth) = (DEFAULT_TRIM, BETWEEN_SHEETS_DEPTH);
                let min_share = if matches!(closure, Closure::Sparse) { SPARSE_BETWEEN_SHEETS_SHARE } else { 0.0 };
                let r = trim_between_sheets(mesh, points, factor, depth, min_share);
                notices.extend(r.between_sheets_notice(factor, depth));
                Some(r)
            }
        },
    };
    if trim.is_some() {
        timings.push(("trim", now() - t));
    }
    // After the trim, so that the simplifier keeps the trimmed border where it is; before the
    // colours, which then go to the vertices that are left.
    let target = Target { triangles: settings.triangles, max_error: settings.max_error };
    let simplify = (target != Default::default()).then(|| {
        let t = now();
        let r = simplify(mesh, &target);
        timings.push(("simplify", now() - t));
        notices.push(r.notice());
        r
    });
    Finished { fit, trim, simplify }
}
