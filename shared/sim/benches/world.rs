//! `World::step` at 1 kHz on the experiment 1 dynamic scenario (Frankie, default noise, a moving
//! cube): criterion's estimate, plus the median and p99 of single steps over a long run.

use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use motm_core::{BaseVelocity, GripperCommand, Robot};
use motm_sim::{HardwareCommand, Scenario, World};

const DT: f64 = 0.001;

fn setup() -> (World, Vec<HardwareCommand>) {
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let robot = Robot::load(&config, "frankie").expect("frankie model");
    let scenario =
        Scenario::from_file(&config.join("scenarios/exp1-dynamic.toml")).expect("scenario");
    let world = World::new(&robot, &scenario, 7);
    // A second of varied commands, replayed in a loop.
    let commands = (0..1000)
        .map(|k| {
            let t = k as f64 * DT;
            HardwareCommand {
                arm_qd: (0..robot.arm_dof())
                    .map(|i| 0.1 * (t + i as f64).sin())
                    .collect(),
                base: BaseVelocity {
                    v: 0.2,
                    omega: 0.1 * t.sin(),
                },
                gripper: GripperCommand::Open,
            }
        })
        .collect();
    (world, commands)
}

fn world_step(c: &mut Criterion) {
    let (world, commands) = setup();
    let mut running = world.clone();
    let mut k = 0;
    c.bench_function("world step 1 ms (exp1-dynamic, frankie)", |b| {
        b.iter(|| {
            running.step(black_box(DT), &commands[k % commands.len()]);
            k += 1;
            // Start over every 5 s of simulated time so the robot stays in its workspace.
            if k % 5000 == 0 {
                running = world.clone();
            }
        })
    });

    // Distribution of single steps over 20 s of simulated time, repeated.
    let mut samples: Vec<Duration> = Vec::with_capacity(100_000);
    for _ in 0..5 {
        let mut running = world.clone();
        for k in 0..20_000 {
            let command = &commands[k % commands.len()];
            let start = Instant::now();
            running.step(black_box(DT), command);
            samples.push(start.elapsed());
        }
        black_box(running.truth());
    }
    samples.sort();
    let at = |p: f64| samples[((samples.len() - 1) as f64 * p) as usize];
    println!(
        "world step 1 ms: median {:?}, p99 {:?}, max {:?} over {} steps ({:.0}x real time at the median)",
        at(0.5),
        at(0.99),
        samples[samples.len() - 1],
        samples.len(),
        DT / at(0.5).as_secs_f64()
    );
}

criterion_group!(benches, world_step);
criterion_main!(benches);
