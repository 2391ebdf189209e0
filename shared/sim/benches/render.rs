//! Palm camera: render one frame of the pick scene, and run perception on it.
//!
//! Besides criterion's estimates, prints the median and 99th percentile of 500 timed frames.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use motm_core::camera::CameraConfig;
use motm_core::perception::{Perception, PerceptionConfig, PerceptionInput};
use motm_sim::render::{CONTAINER_BLUE, PLATFORM_WOOD, Renderer, Scene, SceneBox};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A platform with the cube on it and a container, and a camera 0.5 m above looking down.
fn setup() -> (CameraConfig, Scene, Isometry3<f64>) {
    let config = CameraConfig::default();
    let mut scene = Scene::default();
    scene.boxes.push(SceneBox::platform(
        Vector3::new(0.0, 0.0, 0.42),
        1.2,
        0.8,
        PLATFORM_WOOD,
    ));
    scene.add_container(
        Vector3::new(0.0, 1.0, 0.35),
        0.3,
        0.4,
        0.3,
        0.01,
        CONTAINER_BLUE,
    );
    scene
        .boxes
        .push(SceneBox::cube(Vector3::new(0.1, 0.05, 0.435), 0.3, 0.03));
    let world_from_camera = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.935),
        UnitQuaternion::from_euler_angles(std::f64::consts::PI + 0.2, 0.0, 0.0),
    );
    let tool_pose = world_from_camera * config.tool_from_camera.isometry().inverse();
    (config, scene, tool_pose)
}

fn percentiles(name: &str, mut samples: Vec<Duration>) {
    samples.sort();
    let at = |q: f64| samples[((samples.len() - 1) as f64 * q).round() as usize];
    println!(
        "{name}: min {:.3} ms, median {:.3} ms, p99 {:.3} ms, max {:.3} ms ({} frames)",
        at(0.0).as_secs_f64() * 1e3,
        at(0.5).as_secs_f64() * 1e3,
        at(0.99).as_secs_f64() * 1e3,
        at(1.0).as_secs_f64() * 1e3,
        samples.len()
    );
}

/// Perception's input for `image` taken at `tool_pose`, stamped 0.
fn frame_input<'a>(
    config: &CameraConfig,
    tool_pose: &Isometry3<f64>,
    image: &'a [u8],
) -> PerceptionInput<'a> {
    PerceptionInput {
        image,
        width: config.width,
        height: config.height,
        stamp: 0.0,
        tool_pose: *tool_pose,
        object_height: 0.435,
        target_hint: None,
        neighbours: &[],
        layout_trusted: false,
        colour: motm_core::perception::BlobColour::Red,
    }
}

fn palm_camera(c: &mut Criterion) {
    let (config, scene, tool_pose) = setup();
    let world_from_camera = tool_pose * config.tool_from_camera.isometry();
    let renderer = Renderer::new(config.model(), config.pixel_noise_std);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut perception = Perception::new(PerceptionConfig::default(), config.calibration());
    let mut image = renderer.render(&scene, &world_from_camera, &mut rng);
    assert!(
        perception
            .step(&frame_input(&config, &tool_pose, &image))
            .visible,
        "the bench scene shows the cube"
    );

    let (mut render_times, mut perceive_times) = (Vec::new(), Vec::new());
    for k in 0..500 {
        let start = Instant::now();
        renderer.render_into(&scene, &world_from_camera, &mut rng, &mut image);
        render_times.push(start.elapsed());
        let mut frame = frame_input(&config, &tool_pose, &image);
        frame.stamp = k as f64 / 30.0;
        let start = Instant::now();
        black_box(perception.step(&frame));
        perceive_times.push(start.elapsed());
    }
    percentiles("render 320x240", render_times);
    percentiles("perception 320x240", perceive_times);

    c.bench_function("render 320x240", |b| {
        b.iter(|| {
            renderer.render_into(&scene, black_box(&world_from_camera), &mut rng, &mut image);
        })
    });
    let mut stamp = 0.0;
    c.bench_function("perception 320x240", |b| {
        b.iter(|| {
            stamp += 1.0 / 30.0;
            let mut frame = frame_input(&config, &tool_pose, &image);
            frame.stamp = stamp;
            black_box(perception.step(black_box(&frame)))
        })
    });
}

criterion_group!(benches, palm_camera);
criterion_main!(benches);
