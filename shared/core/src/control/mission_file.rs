//! The mission a control process is given: a scenario file read for what the robot is to do
//! (the robot, the base speed, and the cubes to pick and place and the buttons to press, in
//! order, with their known positions), without the simulated world's parts.
//!
//! Choices:
//! - **One file.** The same scenario file drives the simulated world (`motm-sim` reads all of
//!   it) and tells the control processes their mission (this module reads the mission's keys).
//!   A control process so never links the simulator.
//! - **The world's keys are known but not read.** The start pose, the noise table, and each
//!   cube's motion, speed and heading are accepted and left to the simulator; any other key is
//!   an error naming the file and the key, so that a misspelt mission key is never ignored.
//! - **The checks are the scenario's own**: [`check_base_speed`], [`check_above_floor`] and the
//!   task order of [`mission_tasks`] are shared with `motm-sim`'s scenario.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::Deserialize;

use crate::error::ModelError;
use crate::mission::{MissionTask, TaskKind};

/// Greatest base speed a mission may ask for, m/s (none of the robots is faster).
pub const MAX_BASE_SPEED: f64 = 2.0;

/// A cube of the mission: where it is known to stand, and where it goes.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct MissionObject {
    position: [f64; 3],
    place: [f64; 3],
    /// The simulator's (how the cube moves); not read here.
    #[serde(default, rename = "motion")]
    _motion: Option<toml::Value>,
    /// The simulator's.
    #[serde(default, rename = "speed")]
    _speed: Option<toml::Value>,
    /// The simulator's.
    #[serde(default, rename = "heading")]
    _heading: Option<toml::Value>,
}

/// A button of the mission.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct MissionButton {
    position: [f64; 3],
    #[serde(default)]
    after_object: Option<usize>,
    /// The simulator's (the travel that counts as a press); not read here.
    #[serde(default, rename = "depth")]
    _depth: Option<toml::Value>,
}

/// The keys of a scenario file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct ScenarioKeys {
    robot: String,
    base_speed: f64,
    #[serde(default)]
    objects: Vec<MissionObject>,
    #[serde(default)]
    buttons: Vec<MissionButton>,
    /// The simulator's.
    #[serde(default, rename = "name")]
    _name: Option<toml::Value>,
    /// The simulator's.
    #[serde(default, rename = "start_pose")]
    _start_pose: Option<toml::Value>,
    /// The simulator's.
    #[serde(default, rename = "noise")]
    _noise: Option<toml::Value>,
}

/// A mission read from a scenario file.
#[derive(Debug, Clone, PartialEq)]
pub struct MissionFile {
    /// Robot name.
    pub robot: String,
    /// Base forward speed v_F, m/s.
    pub base_speed: f64,
    /// The tasks, in order.
    pub tasks: Vec<MissionTask>,
    /// The file it was read from.
    pub path: PathBuf,
}

impl MissionFile {
    /// Reads the mission of a scenario file; the error names the file and the key.
    pub fn from_file(path: &Path) -> Result<Self, ModelError> {
        let text = ModelError::read_to_string(path)?;
        Self::from_toml_str(path, &text)
    }

    /// Parses the mission of scenario text that came from `path`.
    pub fn from_toml_str(path: &Path, text: &str) -> Result<Self, ModelError> {
        let keys: ScenarioKeys = ModelError::parse_toml_str(path, text)?;
        if keys.robot.trim().is_empty() {
            return Err(ModelError::invalid(path, "robot", "must not be empty"));
        }
        check_base_speed(path, keys.base_speed)?;
        if keys.objects.is_empty() && keys.buttons.is_empty() {
            return Err(ModelError::invalid(
                path,
                "objects",
                "a mission needs at least one object or button",
            ));
        }
        for (i, object) in keys.objects.iter().enumerate() {
            check_above_floor(path, &format!("objects[{i}].position"), &object.position)?;
            check_above_floor(path, &format!("objects[{i}].place"), &object.place)?;
        }
        for (i, button) in keys.buttons.iter().enumerate() {
            check_above_floor(path, &format!("buttons[{i}].position"), &button.position)?;
            check_after_object(path, i, button.after_object, keys.objects.len())?;
        }
        let tasks = mission_tasks(
            keys.objects.iter().map(|o| (o.position, o.place)),
            keys.buttons.iter().map(|b| (b.position, b.after_object)),
        );
        Ok(Self {
            robot: keys.robot,
            base_speed: keys.base_speed,
            tasks,
            path: path.to_path_buf(),
        })
    }

    /// Replaces the base speed (e.g. from `--base-speed`); the error names the flag.
    pub fn set_base_speed(&mut self, base_speed: f64) -> Result<(), String> {
        check_base_speed_flag(&self.path, base_speed)?;
        self.base_speed = base_speed;
        Ok(())
    }
}

/// The tasks of a mission: pick and place each cube (`(position, place)`) in order, each button
/// (`(position, after_object)`) pressed right after the object its `after_object` names is
/// placed, or after every object without it.
pub fn mission_tasks(
    objects: impl ExactSizeIterator<Item = ([f64; 3], [f64; 3])>,
    buttons: impl Iterator<Item = ([f64; 3], Option<usize>)> + Clone,
) -> Vec<MissionTask> {
    let count = objects.len();
    let mut tasks = Vec::with_capacity(2 * count);
    let press = |item: usize, position: [f64; 3]| MissionTask {
        kind: TaskKind::PressButton,
        item,
        position: Vector3::from(position),
    };
    for (item, (position, place)) in objects.enumerate() {
        tasks.push(MissionTask {
            kind: TaskKind::Pick,
            item,
            position: Vector3::from(position),
        });
        tasks.push(MissionTask {
            kind: TaskKind::Place,
            item,
            position: Vector3::from(place),
        });
        for (b, (position, after)) in buttons.clone().enumerate() {
            if after == Some(item) {
                tasks.push(press(b, position));
            }
        }
    }
    for (b, (position, after)) in buttons.enumerate() {
        if after.is_none_or(|k| k >= count) {
            tasks.push(press(b, position));
        }
    }
    tasks
}

/// Checks the `base_speed` key of `file`.
pub fn check_base_speed(file: &Path, base_speed: f64) -> Result<(), ModelError> {
    if base_speed.is_finite() && base_speed > 0.0 && base_speed <= MAX_BASE_SPEED {
        Ok(())
    } else {
        Err(ModelError::invalid(
            file,
            "base_speed",
            format!("must be in (0, {MAX_BASE_SPEED}] m/s, got {base_speed}"),
        ))
    }
}

/// Checks a `--base-speed` flag that overrides the `base_speed` of `file`; the error names the
/// flag.
pub fn check_base_speed_flag(file: &Path, base_speed: f64) -> Result<(), String> {
    check_base_speed(file, base_speed).map_err(|_| {
        format!(
            "--base-speed {base_speed}: must be in (0, {MAX_BASE_SPEED}] m/s (it overrides base_speed of {})",
            file.display()
        )
    })
}

/// Checks that every value of key `key` is finite.
pub fn check_finite(file: &Path, key: &str, values: &[f64]) -> Result<(), ModelError> {
    match values.iter().find(|v| !v.is_finite()) {
        Some(v) => Err(ModelError::invalid(
            file,
            key,
            format!("must be finite numbers, got {v}"),
        )),
        None => Ok(()),
    }
}

/// Checks that position key `key` is finite and above the floor.
pub fn check_above_floor(file: &Path, key: &str, position: &[f64; 3]) -> Result<(), ModelError> {
    check_finite(file, key, position)?;
    if position[2] <= 0.0 {
        return Err(ModelError::invalid(
            file,
            key,
            format!(
                "height must be above the floor (> 0 m), got {}",
                position[2]
            ),
        ));
    }
    Ok(())
}

/// Checks button `index`'s `after_object` against the `objects` of the mission.
pub fn check_after_object(
    file: &Path,
    index: usize,
    after_object: Option<usize>,
    objects: usize,
) -> Result<(), ModelError> {
    match after_object {
        Some(k) if k >= objects => Err(ModelError::invalid(
            file,
            format!("buttons[{index}].after_object"),
            format!("no object {k}: the scenario has {objects}"),
        )),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MISSION: &str = r#"
name = "m"
robot = "frankie"
start_pose = [0.0, 0.0, 0.0]
base_speed = 0.3
[noise]
latency = 0.01
[[objects]]
position = [1.0, 0.5, 0.45]
motion = "random"
speed = 0.03
place = [3.0, 0.0, 0.35]
[[objects]]
position = [1.0, 0.3, 0.45]
motion = "static"
place = [3.0, 0.0, 0.35]
[[buttons]]
position = [2.0, 1.0, 0.5]
depth = 0.01
after_object = 0
"#;

    #[test]
    fn a_scenarios_mission_is_its_tasks_in_order_without_the_world() {
        let mission = MissionFile::from_toml_str(Path::new("m.toml"), MISSION).unwrap();
        assert_eq!(
            (mission.robot.as_str(), mission.base_speed),
            ("frankie", 0.3)
        );
        let kinds: Vec<(TaskKind, usize)> =
            mission.tasks.iter().map(|t| (t.kind, t.item)).collect();
        assert_eq!(
            kinds,
            [
                (TaskKind::Pick, 0),
                (TaskKind::Place, 0),
                (TaskKind::PressButton, 0),
                (TaskKind::Pick, 1),
                (TaskKind::Place, 1),
            ]
        );
        assert_eq!(mission.tasks[3].position, Vector3::new(1.0, 0.3, 0.45));
    }

    #[test]
    fn a_bad_mission_names_the_file_and_the_key() {
        let cases = [
            (
                "place = [3.0, 0.0, 0.35]",
                "plce = [3.0, 0.0, 0.35]",
                "plce",
            ),
            ("base_speed = 0.3", "base_speed = 9.0", "base_speed"),
            (
                "position = [1.0, 0.3, 0.45]",
                "position = [1.0, 0.3, -1.0]",
                "objects[1].position",
            ),
            (
                "after_object = 0",
                "after_object = 5",
                "buttons[0].after_object",
            ),
            ("robot = \"frankie\"", "robot = \"\"", "robot"),
        ];
        for (find, replace, key) in cases {
            let text = MISSION.replacen(find, replace, 1);
            let err = MissionFile::from_toml_str(Path::new("m.toml"), &text)
                .unwrap_err()
                .to_string();
            assert!(err.contains("m.toml") && err.contains(key), "{key}: {err}");
        }
        let mut mission = MissionFile::from_toml_str(Path::new("m.toml"), MISSION).unwrap();
        let err = mission.set_base_speed(-1.0).unwrap_err();
        assert!(
            err.contains("--base-speed") && err.contains("m.toml"),
            "{err}"
        );
        mission.set_base_speed(0.4).unwrap();
        assert_eq!(mission.base_speed, 0.4);
    }
}
