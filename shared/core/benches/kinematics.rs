//! Frankie tool pose + world Jacobian + manipulability gradient, in one iteration.
//!
//! Criterion prints the mean. The median and p99 come from the per-sample means
//! (`times[i] / iters[i]`) in `target/criterion/<bench>/new/sample.json`; the median is also in
//! `estimates.json`.

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use motm_core::{BasePose, Robot, manipulability_gradient};

fn frankie_kinematics(c: &mut Criterion) {
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let robot = Robot::load(&config, "frankie").expect("frankie model");
    let q = robot.config.ready_pose.clone();
    let base = BasePose::new(1.0, -0.5, 0.3);
    c.bench_function("frankie pose+jacobian+manipulability_gradient", |b| {
        b.iter(|| {
            let fk = robot.forward(black_box(&base), black_box(&q));
            let arm = Robot::arm_jacobian(&fk.jacobian);
            black_box((fk.tool_pose, manipulability_gradient(&arm)))
        })
    });
}

criterion_group!(benches, frankie_kinematics);
criterion_main!(benches);
