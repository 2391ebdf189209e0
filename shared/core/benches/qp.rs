//! One redundancy-resolution QP solve on Frankie (9 joints + 6 slacks), random reachable twists
//! with base tracking; and the whole control step (kinematics, Hessian, build, solve).

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use motm_core::qp_scenario::{QpScenario, ScenarioConfig};
use motm_core::{RedundancyResolver, ResolverConfig, Robot};

const SCENARIOS: usize = 2048;

fn frankie_qp(c: &mut Criterion) {
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let robot = Robot::load(&config, "frankie").expect("frankie model");
    let scenarios = QpScenario::random_set(&robot, &ScenarioConfig::default(), SCENARIOS, 1);
    let mut resolver = RedundancyResolver::for_robot(&robot, ResolverConfig::default());
    let mut i = 0;
    c.bench_function("frankie resolver solve", |b| {
        b.iter(|| {
            i = (i + 1) % SCENARIOS;
            black_box(resolver.resolve(black_box(&scenarios[i].input())))
        })
    });
    c.bench_function("frankie resolver control step", |b| {
        b.iter(|| {
            i = (i + 1) % SCENARIOS;
            black_box(scenarios[i].control_step(&robot, &mut resolver))
        })
    });
    assert_eq!(
        resolver.error_count(),
        0,
        "benchmark problems must all solve"
    );
}

criterion_group!(benches, frankie_qp);
criterion_main!(benches);
