//! Scenario files: the robot, its start pose and speed, the objects to pick and where to drop
//! them, and the noise of the simulated world (docs/architecture.md, "Scenario file").
//!
//! ```toml
//! name = "exp1-dynamic"
//! robot = "frankie"                 # frankie | fetch | husky_ur5
//! start_pose = [0.0, 0.0, 0.0]      # base [x, y, yaw]
//! base_speed = 0.3                  # m/s, may be overridden by --base-speed
//!
//! [[objects]]                       # picked in order
//! position = [2.0, 0.0, 0.45]       # cube centre, m
//! motion = "random"                 # "static" | "random" | "line"
//! speed = 0.03                      # m/s for random and line
//! heading = 1.57                    # rad, for "line" (initial heading for "random")
//! place = [4.0, 0.0, 0.35]          # drop point (container centre at rim height)
//!
//! [[buttons]]                       # optional: pressed in order after every object is placed
//! position = [6.0, 0.5, 0.5]        # centre of the button's top face, m
//! depth = 0.01                      # m the button must be pushed (optional)
//! after_object = 0                  # optional: pressed right after object 0 is placed
//!
//! [noise]                           # every key optional; defaults are the realistic ones
//! camera_pixel_std = 1.0
//! camera_extrinsic_error = 0.005    # m
//! odometry_drift = 0.01             # fraction of distance
//! base_velocity_error = 0.05        # fraction
//! arm_velocity_error = 0.02         # fraction
//! latency = 0.01                    # s
//! ```
//!
//! `[[buttons]]` is the one addition to the format of docs/architecture.md: a scenario with a button to press,
//! for the swappable final-phase controller. Unknown keys, missing required keys and bad values
//! are errors that name the file and the key, e.g. `exp1.toml: objects[0].speed: must be > 0`.

use std::path::{Path, PathBuf};

use motm_core::mission::MissionTask;
use motm_core::mission_file::{
    check_above_floor, check_after_object, check_base_speed, check_base_speed_flag, check_finite,
    mission_tasks,
};
use motm_core::{BasePose, ModelError, ROBOT_NAMES};
use motm_msgs::MAX_SIM_OBJECTS;
use serde::Deserialize;

/// How a cube moves on its platform. The robot is never told.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Motion {
    /// The cube does not move.
    Static,
    /// The cube follows a random smooth path on its platform at constant speed (new for each seed).
    Random,
    /// The cube moves in a straight line at constant speed until the end of its platform's travel.
    Line,
}

/// One cube to pick, and where to drop it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioObject {
    /// World position of the cube centre at the start, m.
    pub position: [f64; 3],
    /// How the cube moves.
    pub motion: Motion,
    /// Speed of a `random` or `line` cube, m/s. Required for those; absent or 0 for `static`.
    #[serde(default)]
    pub speed: Option<f64>,
    /// Heading of a `line` cube, rad (required). For a `random` cube, its initial heading
    /// (optional; drawn from the seed when absent). Ignored for a `static` cube.
    #[serde(default)]
    pub heading: Option<f64>,
    /// Drop point: the centre of the container at rim height, m.
    pub place: [f64; 3],
}

/// A button to press with the gripper.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioButton {
    /// World position of the centre of the button's top face (unpressed), m.
    pub position: [f64; 3],
    /// How far the button must be pushed down to count as pressed, m.
    #[serde(default = "default_button_depth")]
    pub depth: f64,
    /// Index of the object after whose place the button is pressed; without it the button is
    /// pressed after every object is placed (buttons in their order either way).
    #[serde(default)]
    pub after_object: Option<usize>,
}

/// The default button travel that counts as a press, m.
fn default_button_depth() -> f64 {
    0.01
}

/// Imperfections of the simulated world. Every key is optional; the defaults are realistic.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Noise {
    /// Standard deviation of the camera's per-pixel intensity noise, in 8-bit levels.
    pub camera_pixel_std: f64,
    /// Standard deviation of the camera extrinsic (mounting) position error, m.
    pub camera_extrinsic_error: f64,
    /// Odometry error as a fraction of the distance travelled (standard deviation of the
    /// per-trial scale errors of the measured forward speed and yaw rate).
    pub odometry_drift: f64,
    /// Base velocity tracking error as a fraction of the command (standard deviation of the
    /// per-trial gain error; the per-step noise is scaled from it, see `WorldConfig`).
    pub base_velocity_error: f64,
    /// Arm joint velocity tracking error as a fraction of the command (as for the base).
    pub arm_velocity_error: f64,
    /// Command latency: time from a hardware command to its effect, s.
    pub latency: f64,
}

impl Default for Noise {
    fn default() -> Self {
        Self {
            camera_pixel_std: 1.0,
            camera_extrinsic_error: 0.005,
            odometry_drift: 0.01,
            base_velocity_error: 0.05,
            arm_velocity_error: 0.02,
            latency: 0.01,
        }
    }
}

impl Noise {
    /// A world without imperfections (for tests that isolate one effect).
    pub fn none() -> Self {
        Self {
            camera_pixel_std: 0.0,
            camera_extrinsic_error: 0.0,
            odometry_drift: 0.0,
            base_velocity_error: 0.0,
            arm_velocity_error: 0.0,
            latency: 0.0,
        }
    }
}

/// A scenario file: `name` itself when it is an existing file, else
/// `<config_dir>/scenarios/<name>.toml`.
pub fn scenario_path(config_dir: &Path, name: &str) -> PathBuf {
    let direct = PathBuf::from(name);
    if direct.is_file() {
        direct
    } else {
        config_dir.join("scenarios").join(format!("{name}.toml"))
    }
}

/// A scenario: robot, start, speed, objects, buttons and noise.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Scenario name (e.g. `exp1-dynamic`).
    pub name: String,
    /// Robot name: one of `frankie`, `fetch`, `husky_ur5`.
    pub robot: String,
    /// Base start pose `[x, y, yaw]` in the world frame, m and rad.
    pub start_pose: [f64; 3],
    /// Base forward speed v_F, m/s (may be overridden, e.g. by `--base-speed`).
    pub base_speed: f64,
    /// The cubes, picked in order.
    #[serde(default)]
    pub objects: Vec<ScenarioObject>,
    /// The buttons, pressed in order after every cube is placed.
    #[serde(default)]
    pub buttons: Vec<ScenarioButton>,
    /// Imperfections of the world.
    #[serde(default)]
    pub noise: Noise,
    /// The file the scenario was read from (empty for a scenario built in code).
    #[serde(skip)]
    pub path: PathBuf,
}

pub use motm_core::mission_file::MAX_BASE_SPEED;
/// Greatest cube speed a scenario may ask for, m/s.
pub const MAX_OBJECT_SPEED: f64 = 0.5;
/// Greatest command latency a scenario may ask for, s.
pub const MAX_LATENCY: f64 = 0.5;

impl Scenario {
    /// Reads and validates a scenario file.
    pub fn from_file(path: &Path) -> Result<Self, ModelError> {
        let text = ModelError::read_to_string(path)?;
        Self::from_toml_str(path, &text)
    }

    /// Parses and validates scenario text that came from `path` (used in error messages).
    pub fn from_toml_str(path: &Path, text: &str) -> Result<Self, ModelError> {
        let deserializer =
            toml::Deserializer::parse(text).map_err(|e| syntax_error(path, text, &e))?;
        let mut scenario: Scenario =
            serde_path_to_error::deserialize(deserializer).map_err(|e| {
                let key = error_key(&e.path().to_string(), e.inner().message());
                ModelError::invalid(path, key, e.inner().message().trim().to_string())
            })?;
        scenario.path = path.to_path_buf();
        scenario.validate()?;
        Ok(scenario)
    }

    /// Replaces the base speed (e.g. from `--base-speed`), with the same check as the file's key.
    pub fn set_base_speed(&mut self, base_speed: f64) -> Result<(), String> {
        // The value comes from the command line, so the error names the flag, not the file.
        check_base_speed_flag(&self.path, base_speed)?;
        self.base_speed = base_speed;
        Ok(())
    }

    /// The base start pose.
    pub fn start(&self) -> BasePose {
        BasePose::new(self.start_pose[0], self.start_pose[1], self.start_pose[2])
    }

    /// The mission: pick and place each cube in order, each button pressed right after the
    /// object its `after_object` names is placed, or after every object without it.
    pub fn mission_tasks(&self) -> Vec<MissionTask> {
        mission_tasks(
            self.objects.iter().map(|o| (o.position, o.place)),
            self.buttons.iter().map(|b| (b.position, b.after_object)),
        )
    }

    /// Checks every value; the error names the file and the key.
    pub fn validate(&self) -> Result<(), ModelError> {
        let file = self.path.as_path();
        let bad = |key: &str, message: &str| Err(ModelError::invalid(file, key, message));
        if self.name.trim().is_empty() {
            return bad("name", "must not be empty");
        }
        if !ROBOT_NAMES.contains(&self.robot.as_str()) {
            return bad(
                "robot",
                &format!(
                    "unknown robot '{}': expected one of {}",
                    self.robot,
                    ROBOT_NAMES.join(", ")
                ),
            );
        }
        check_finite(file, "start_pose", &self.start_pose)?;
        check_base_speed(file, self.base_speed)?;
        if self.objects.is_empty() && self.buttons.is_empty() {
            return bad("objects", "a scenario needs at least one object or button");
        }
        if self.objects.len() > MAX_SIM_OBJECTS {
            return bad(
                "objects",
                &format!(
                    "at most {MAX_SIM_OBJECTS} objects (what the simulator's ground truth reports), got {}",
                    self.objects.len()
                ),
            );
        }
        for (i, object) in self.objects.iter().enumerate() {
            object.validate(file, &format!("objects[{i}]"))?;
        }
        for (i, button) in self.buttons.iter().enumerate() {
            let key = format!("buttons[{i}]");
            check_above_floor(file, &format!("{key}.position"), &button.position)?;
            if !(button.depth.is_finite() && button.depth > 0.0 && button.depth <= 0.05) {
                return bad(&format!("{key}.depth"), "must be in (0, 0.05] m");
            }
            check_after_object(file, i, button.after_object, self.objects.len())?;
        }
        self.noise.validate(file)
    }
}

impl ScenarioObject {
    /// Speed of the cube, m/s (0 for a static cube).
    pub fn motion_speed(&self) -> f64 {
        match self.motion {
            Motion::Static => 0.0,
            Motion::Random | Motion::Line => self.speed.unwrap_or(0.0),
        }
    }

    fn validate(&self, file: &Path, key: &str) -> Result<(), ModelError> {
        check_above_floor(file, &format!("{key}.position"), &self.position)?;
        check_above_floor(file, &format!("{key}.place"), &self.place)?;
        let speed_key = format!("{key}.speed");
        match (self.motion, self.speed) {
            (Motion::Static, Some(speed)) if speed != 0.0 => {
                return Err(ModelError::invalid(
                    file,
                    speed_key,
                    format!(
                        "a static object has no speed (got {speed}); use motion = \"random\" or \"line\""
                    ),
                ));
            }
            (Motion::Random | Motion::Line, None) => {
                return Err(ModelError::invalid(
                    file,
                    speed_key,
                    "missing: required for motion \"random\" and \"line\"",
                ));
            }
            (Motion::Random | Motion::Line, Some(speed))
                if !(speed.is_finite() && speed > 0.0 && speed <= MAX_OBJECT_SPEED) =>
            {
                return Err(ModelError::invalid(
                    file,
                    speed_key,
                    format!("must be in (0, {MAX_OBJECT_SPEED}] m/s, got {speed}"),
                ));
            }
            _ => {}
        }
        let heading_key = format!("{key}.heading");
        match (self.motion, self.heading) {
            (Motion::Line, None) => Err(ModelError::invalid(
                file,
                heading_key,
                "missing: required for motion \"line\"",
            )),
            (_, Some(heading)) if !heading.is_finite() => Err(ModelError::invalid(
                file,
                heading_key,
                format!("must be a finite angle in rad, got {heading}"),
            )),
            _ => Ok(()),
        }
    }
}

impl Noise {
    fn validate(&self, file: &Path) -> Result<(), ModelError> {
        let fractions = [
            ("noise.odometry_drift", self.odometry_drift),
            ("noise.base_velocity_error", self.base_velocity_error),
            ("noise.arm_velocity_error", self.arm_velocity_error),
        ];
        for (key, value) in fractions {
            if !(value.is_finite() && (0.0..0.5).contains(&value)) {
                return Err(ModelError::invalid(
                    file,
                    key,
                    format!("must be a fraction in [0, 0.5), got {value}"),
                ));
            }
        }
        let bounded = [
            (
                "noise.camera_pixel_std",
                self.camera_pixel_std,
                255.0,
                "levels",
            ),
            (
                "noise.camera_extrinsic_error",
                self.camera_extrinsic_error,
                0.1,
                "m",
            ),
            ("noise.latency", self.latency, MAX_LATENCY, "s"),
        ];
        for (key, value, max, unit) in bounded {
            if !(value.is_finite() && (0.0..=max).contains(&value)) {
                return Err(ModelError::invalid(
                    file,
                    key,
                    format!("must be in [0, {max}] {unit}, got {value}"),
                ));
            }
        }
        Ok(())
    }
}

/// The key an error from `serde_path_to_error` refers to: its path, plus the field named in a
/// "missing field `x`" or "unknown field `x`" message when the path stops at the enclosing table.
fn error_key(path: &str, message: &str) -> String {
    let named_field = ["missing field `", "unknown field `"]
        .iter()
        .find_map(|prefix| message.strip_prefix(prefix))
        .and_then(|rest| rest.split('`').next());
    match named_field {
        Some(field) if !path.ends_with(field) => {
            if path == "." || path.is_empty() {
                field.to_string()
            } else {
                format!("{path}.{field}")
            }
        }
        _ if path == "." || path.is_empty() => "document".to_string(),
        _ => path.to_string(),
    }
}

/// A TOML syntax error, located by line.
fn syntax_error(path: &Path, text: &str, error: &toml::de::Error) -> ModelError {
    let element = error
        .span()
        .map(|span| {
            let start = span.start.min(text.len());
            let number = text[..start].matches('\n').count() + 1;
            let content = text.lines().nth(number - 1).unwrap_or("").trim();
            format!("line {number} `{content}`")
        })
        .unwrap_or_else(|| "document".to_string());
    ModelError::invalid(path, element, error.message().trim().to_string())
}

#[cfg(test)]
#[path = "scenario_tests.rs"]
mod tests;
