//! Issue 23: GPU resources are made once per reconstruction, not per chunk of work, and each
//! stage's peak of device memory stays within what the plan (`nkrr info`, the page's preflight)
//! says it will take. The test build counts the device's buffer memory (wgpu's `counters`
//! feature, a dev-dependency); see `nkrr::gpu::ledger`.

mod common;

use nkrr::gpu::Gpu;
use nkrr::pipeline::{Engine, Reconstruction};
use nkrr::settings::{KrrBackend, Method, Settings, Surface};
use nkrr::PointCloud;

fn cloud() -> PointCloud {
    let path = common::repo_root().join("tests/data/eval/spot-3k.ply");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    nkrr::io::ply::read_ply(&bytes).unwrap().cloud
}

fn run(engine: &Engine, cloud: &PointCloud, s: &Settings) -> (Reconstruction, nkrr::gpu::Allocations) {
    let before = engine.gpu.allocations();
    let rec = pollster::block_on(engine.reconstruct(cloud, s, &mut |_| true)).unwrap();
    (rec, engine.gpu.allocations().since(&before))
}

#[test]
fn resources_are_made_once_and_each_stage_stays_within_its_plan() {
    let gpu = Gpu::new_blocking().expect("a wgpu adapter (lavapipe will do)");
    assert!(gpu.ledger.counted(), "the test build counts the device's buffer memory (wgpu's counters feature)");
    let engine = pollster::block_on(Engine::new(gpu)).unwrap();
    let cloud = cloud();
    // The field's own mesh, whose evaluations grow with the resolution (a Poisson surface meshes
    // the field at one coarse resolution: checked below).
    let base = Settings { steps: 3, krr_backend: KrrBackend::Gpu, surface: Surface::Field, ..Settings::default() };
    for method in [Method::Network, Method::Nkrr] {
        let coarse = Settings { method, resolution: 64, ..base.clone() };
        let fine = Settings { resolution: 160, ..coarse.clone() };
        let (rc, made_coarse) = run(&engine, &cloud, &coarse);
        let (rf, made_fine) = run(&engine, &cloud, &fine);
        let (ec, ef) = (rc.extract.refine.evaluations, rf.extract.refine.evaluations);
        // The finer mesh evaluates the field in several times as many calls of 32768 points;
        // the buffers and bind groups made are the same, and the second run compiles no
        // pipeline: the device keeps those the first one built (a scene builds its regression
        // once per tile).
        assert!(ef > 3 * ec && ef > 4 * 32_768, "{method:?}: {ec} and {ef} evaluations");
        assert_eq!(made_coarse.buffers, made_fine.buffers, "{method:?}: buffers made at resolution 64 and 160");
        assert_eq!(made_coarse.bind_groups, made_fine.bind_groups, "{method:?}: bind groups made");
        assert_eq!(made_fine.pipelines, 0, "{method:?}: pipelines made again (the first run made {})", made_coarse.pipelines);

        for (rec, s) in [(&rc, &coarse), (&rf, &fine)] {
            let plan = engine.memory_plan(cloud.len(), false, s);
            let names: Vec<_> = rec.gpu_peaks.iter().map(|(n, _)| *n).collect();
            let expected: &[&str] = if method == Method::Nkrr { &["features", "pairs", "tuning", "meshing"] } else { &["features", "meshing"] };
            assert_eq!(names, expected, "{method:?}");
            for (stage, bytes) in &rec.gpu_peaks {
                let planned = plan.stages.iter().find(|p| p.name == *stage).unwrap().gpu_bytes;
                eprintln!("{method:?} resolution {}: {stage:<8} peak {bytes:>10} B, plan {planned:>10} B ({:.2})", s.resolution, *bytes as f64 / planned as f64);
                // Within the plan (give or take 1 %: the driver rounds each buffer up to its
                // alignment), and the plan no more than four times what was taken (a preflight
                // that cries wolf is as useless as one that misses).
                assert!(*bytes <= planned + planned / 100, "{method:?} {stage}: {bytes} bytes held, {planned} planned");
                assert!(4 * *bytes >= planned, "{method:?} {stage}: {bytes} bytes held, {planned} planned");
            }
        }
    }
    // The Poisson surface (auto on this 3k cloud): the field meshed coarsely, then the solve and
    // χ's marching cubes, each stage within its plan.
    for method in [Method::Network, Method::Nkrr] {
        let s = Settings { method, resolution: 96, surface: Surface::Auto, ..base.clone() };
        let (rec, _) = run(&engine, &cloud, &s);
        let plan = engine.memory_plan(cloud.len(), false, &s);
        assert!(plan.poisson);
        let names: Vec<_> = rec.gpu_peaks.iter().map(|(n, _)| *n).collect();
        assert_eq!(names.last(), Some(&"poisson"), "{method:?}");
        for (stage, bytes) in &rec.gpu_peaks {
            let planned = plan.stages.iter().find(|p| p.name == *stage).unwrap().gpu_bytes;
            eprintln!("{method:?} Poisson: {stage:<8} peak {bytes:>10} B, plan {planned:>10} B ({:.2})", *bytes as f64 / planned as f64);
            assert!(*bytes <= planned + planned / 100 && 4 * *bytes >= planned, "{method:?} {stage}: {bytes} bytes held, {planned} planned");
        }
    }
}
