//! The finishing stage, in the network's unit cube against the points it saw: components the
//! points do not support go, then the last fit to the points, a scene's sheets to one layer, the
//! trim of what was never scanned and the simplification, each when the settings ask for it
//! (the plan's "finish").

use super::fit::{fit_cloud, FitReport, Fitted};
use super::sheets::single_layer;
use super::simplify::{simplify, SimplifyReport, Target};
use super::trim::{trim, trim_between_sheets, TrimReport, BETWEEN_SHEETS_DEPTH, DEFAULT_TRIM};
use super::types::Mesh;
use crate::gpu::now;
use crate::settings::Settings;

/// What each finishing step did (None: not asked for).
pub struct Finished {
    pub fit: Option<FitReport>,
    pub trim: Option<TrimReport>,
    pub simplify: Option<SimplifyReport>,
}

/// Finishes `mesh` against `points` as `settings` ask, adding what it says to `notices` and
/// each step's seconds to `timings`. `fitted`: what the mesh is, which decides the fit ([`Fitted`]).
/// `sheet_gap`: a scene's (with [`Settings::one_layer`]), the most two coincident layers lie
/// apart after the fit ([`single_layer`]); objects pass None. `one_sided`: the scan saw one side
/// of the object or is an open shell (the Poisson surface ballooned), so pieces that no point is
/// near are the prior's guess of the rest and stay ([`super::remove_unsupported_components`]),
/// and, unless a trim was asked for, what lies far from the points deep inside their hull goes
/// ([`trim_between_sheets`]).
#[allow(clippy::too_many_arguments)]
pub fn finish(
    mesh: &mut Mesh,
    points: &[[f32; 3]],
    settings: &Settings,
    fitted: Fitted,
    one_sided: bool,
    sheet_gap: Option<f32>,
    notices: &mut Vec<String>,
    timings: &mut Vec<(&'static str, f64)>,
) -> Finished {
    if let Some(share) = settings.min_support {
        let r = super::remove_unsupported_components(mesh, points, share as f32, one_sided);
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
        // The Poisson surface ballooned: a one-sided scan's closure stays, an open shell's fill goes.
        None if one_sided => {
            let (factor, depth) = (DEFAULT_TRIM, BETWEEN_SHEETS_DEPTH);
            let r = trim_between_sheets(mesh, points, factor, depth);
            notices.extend(r.between_sheets_notice(factor, depth));
            Some(r)
        }
        None => None,
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
