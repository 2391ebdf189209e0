//! Planning baseline: one Exp-1 plan (route, QP passes with clarabel) for Frankie at 0.3 m/s.

use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use motm_core::planning::{PlanRequest, PlanningConfig, plan};
use motm_core::{BasePose, Robot};
use nalgebra::Vector3;

fn exp1_plan(c: &mut Criterion) {
    let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let robot = Robot::load(&config_dir, "frankie").expect("frankie model");
    let request = PlanRequest {
        start_base: BasePose::new(0.0, 0.0, 0.0),
        start_base_speed: 0.0,
        cube: Vector3::new(2.0, 0.6, 0.45),
        container: Vector3::new(3.6, 1.6, 0.35),
        base_speed: 0.3,
    };
    let config = PlanningConfig::default();
    let mut group = c.benchmark_group("planning");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(15));
    group.bench_function("exp1 plan (all passes)", |b| {
        b.iter(|| plan(black_box(&robot), black_box(&request), &config).expect("plan"))
    });
    let single = PlanningConfig {
        max_passes: 1,
        ..PlanningConfig::default()
    };
    group.bench_function("exp1 plan (one QP)", |b| {
        b.iter(|| plan(black_box(&robot), black_box(&request), &single).expect("plan"))
    });
    group.finish();
}

criterion_group!(benches, exp1_plan);
criterion_main!(benches);
