//! Generated mission layouts: missions no scenario file holds, to judge the controllers on
//! layouts they were not tuned on (`motm experiment generated`, `motm trial --scenario
//! generated:<robot> --seed N`).
//!
//! The layout is a function of the robot and the trial's seed alone, so a failure is
//! reproduced by its seed. Each has 2–4 picks, each followed by its place, in a chain: the
//! object 1.5–4 m from where the robot was (the start, or the previous place) in any direction,
//! its place 1.5–4 m from the object. Every target (object, place, button) stands at least
//! [`MIN_SEPARATION`] from every other and from the start. Objects are static (70 %) or move
//! at 0.03 m/s, in a line (15 %) or on a random path (15 %); three layouts in ten add a button,
//! pressed after one of the picks' places. The base starts at the origin facing any way and
//! drives at 0.3 m/s.

use std::f64::consts::PI;
use std::fmt::Write;

use crate::random::{SimRng, Stream};

/// Scenario names that ask for a generated layout: `generated:<robot>`.
pub const PREFIX: &str = "generated:";

/// Least distance between two targets of a generated layout, and from the start, m: room for
/// the largest base (the Husky's, 0.99 m long) to pass one target at r_C clear of the others.
pub const MIN_SEPARATION: f64 = 2.0;

/// Speed of the moving objects, m/s.
const MOVING_SPEED: f64 = 0.03;

/// Tries at placing one target before the layout is built anew from a fresh draw.
const PLACEMENT_TRIES: usize = 1000;

/// The robot a generated scenario name asks for (`generated:<robot>`), if it is one.
pub fn robot_of(name: &str) -> Option<&str> {
    name.strip_prefix(PREFIX).filter(|robot| !robot.is_empty())
}

/// The scenario file text of the layout for `robot` and `seed` (see the module doc).
pub fn layout_toml(robot: &str, seed: u64) -> String {
    let mut rng = SimRng::new(seed, Stream::Layout);
    loop {
        if let Some(text) = draw(robot, seed, &mut rng) {
            return text;
        }
    }
}

/// One draw of a layout, or `None` when a target found no free place. (Writing to a `String`
/// cannot fail.)
fn draw(robot: &str, seed: u64, rng: &mut SimRng) -> Option<String> {
    let mut taken = vec![[0.0, 0.0]];
    let mut place_near = |rng: &mut SimRng, from: [f64; 2]| {
        (0..PLACEMENT_TRIES).find_map(|_| {
            let distance = rng.uniform_in(1.5, 4.0);
            let bearing = rng.uniform_in(-PI, PI);
            let p = [
                from[0] + distance * bearing.cos(),
                from[1] + distance * bearing.sin(),
            ];
            let free = taken
                .iter()
                .all(|q| (p[0] - q[0]).hypot(p[1] - q[1]) >= MIN_SEPARATION);
            free.then(|| {
                taken.push(p);
                p
            })
        })
    };
    let mut text = String::new();
    let yaw = rng.uniform_in(-PI, PI);
    let _ = writeln!(text, "name = \"{PREFIX}{robot}:{seed}\"");
    let _ = writeln!(text, "robot = \"{robot}\"");
    let _ = writeln!(text, "start_pose = [0.0, 0.0, {yaw:.4}]");
    let _ = writeln!(text, "base_speed = 0.3");
    let objects = 2 + (rng.uniform() * 3.0) as usize;
    let mut from = [0.0, 0.0];
    for _ in 0..objects {
        let object = place_near(rng, from)?;
        let place = place_near(rng, object)?;
        from = place;
        let _ = writeln!(text, "\n[[objects]]");
        let _ = writeln!(
            text,
            "position = [{:.3}, {:.3}, 0.45]",
            object[0], object[1]
        );
        let motion = rng.uniform();
        if motion < 0.7 {
            let _ = writeln!(text, "motion = \"static\"");
        } else if motion < 0.85 {
            let heading = rng.uniform_in(-PI, PI);
            let _ = writeln!(text, "motion = \"line\"\nspeed = {MOVING_SPEED}");
            let _ = writeln!(text, "heading = {heading:.4}");
        } else {
            let _ = writeln!(text, "motion = \"random\"\nspeed = {MOVING_SPEED}");
        }
        let _ = writeln!(text, "place = [{:.3}, {:.3}, 0.35]", place[0], place[1]);
    }
    if rng.uniform() < 0.3 {
        let after = (rng.uniform() * objects as f64) as usize;
        let button = place_near(rng, from)?;
        let _ = writeln!(text, "\n[[buttons]]");
        let _ = writeln!(text, "position = [{:.3}, {:.3}, 0.5]", button[0], button[1]);
        let _ = writeln!(text, "depth = 0.01\nafter_object = {after}");
    }
    Some(text)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::Scenario;
    use std::path::Path;

    #[test]
    fn generated_layouts_are_valid_scenarios_with_their_targets_apart() {
        let mut buttons = 0;
        let mut moving = 0;
        for seed in 0..200 {
            let text = layout_toml("fetch", seed);
            assert_eq!(
                text,
                layout_toml("fetch", seed),
                "the same seed gives the same layout"
            );
            let scenario = Scenario::from_toml_str(Path::new("generated:fetch"), &text)
                .unwrap_or_else(|e| panic!("seed {seed}: {e}\n{text}"));
            assert!((2..=4).contains(&scenario.objects.len()));
            assert_eq!(scenario.robot, "fetch");
            let mut targets: Vec<[f64; 2]> = vec![[0.0, 0.0]];
            for o in &scenario.objects {
                targets.push([o.position[0], o.position[1]]);
                targets.push([o.place[0], o.place[1]]);
                moving += usize::from(o.motion_speed() > 0.0);
            }
            for b in &scenario.buttons {
                targets.push([b.position[0], b.position[1]]);
                buttons += 1;
            }
            for (i, a) in targets.iter().enumerate() {
                for b in &targets[i + 1..] {
                    // Rounded to the millimetre in the text.
                    assert!((a[0] - b[0]).hypot(a[1] - b[1]) >= MIN_SEPARATION - 2e-3);
                }
            }
        }
        assert!(
            buttons > 20 && moving > 60,
            "{buttons} buttons, {moving} moving objects"
        );
    }

    #[test]
    fn only_generated_names_name_a_robot() {
        assert_eq!(robot_of("generated:husky_ur5"), Some("husky_ur5"));
        assert_eq!(robot_of("generated:"), None);
        assert_eq!(robot_of("exp2"), None);
    }
}
