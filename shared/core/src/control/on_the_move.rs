//! The settings of the MotM controllers, by module, and the twist rate limit: what every
//! control task is built from ([`OnTheMoveConfig`], read from the controllers' config file that
//! the stack config names).
//!
//! The control loop itself is composed once, as tasks over typed topics (the `motm-tasks`
//! crate), and scheduled either as processes or in one process. Choices it relies on:
//! - **Reach target of a place task** is the container point raised so that the reacher's
//!   pre-grasp point is the drop controller's release point (`drop.release_height` above the
//!   rim): the cube then arrives over the container, not beside its rim
//!   ([`crate::stack::reach_aim`]).
//! - **Gripper outside the final phase** follows the task: open while reaching for a pick, closed
//!   while carrying to a place or pressing a button ([`crate::stack::resting_gripper`]).
//! - **Tool state fed back to the reacher** is the twist the QP resolver resolved on the previous
//!   cycle, with the reacher's planned acceleration (see [`crate::stack::reacher`]).
//! - **e_t** for the QP's 1/e_t weights is the tool's distance to the current target, capped at
//!   [`OnTheMoveConfig::max_position_error`]; it rises by at most
//!   [`OnTheMoveConfig::max_position_error_rate`] per second. When a task ends the distance jumps
//!   from a few centimetres to metres: e_t at once at its cap would halve the slack's weight in
//!   one cycle, and the tool, held to its twist half as tightly against the manipulability
//!   gradient and the base's lag, would jerk (about 0.5 m/s² of the peak after a grasp).
//! - **Twist rate limit.** The twist sent to the QP changes by at most [`TwistRateLimit`] per
//!   second, so hand-overs (reacher → final phase → next task) do not jerk the tool.
//! - **Base velocity error feed-forward.** The twist sent to the QP also carries the correction
//!   of [`crate::base_slip`]: minus the tool motion caused by the difference between the base's
//!   measured velocity and the one the QP commanded on the previous cycle.
//! - **Base target rate limit** ([`crate::base_command_rate`]): the base controller's velocity
//!   target reaches the QP with its change limited to the base's acceleration limits, the
//!   forward one also to a multiple of the run's base speed.

use std::path::Path;

use serde::Deserialize;

use crate::base_command_rate::BaseCommandRateConfig;
use crate::base_controller::BaseControllerConfig;
use crate::base_slip::BaseSlipConfig;
use crate::error::ModelError;
use crate::final_phase::FinalPhaseConfig;
use crate::mission::MissionConfig;
use crate::perception::PerceptionConfig;
use crate::reacher::ReacherConfig;
use crate::resolver::ResolverConfig;
use crate::types::Twist;

/// Limits on how fast the commanded tool twist may change.
///
/// The linear limit scales with the run's base speed v_F: every tool motion of MotM is paced by
/// the base (the reacher's transit speed is k_A·v_B, the final-phase servo's speed limit k_A·v_B,
/// the tool carried at v_F), so the accelerations that the tasks need scale with it too, and a
/// limit fixed at what the fastest run needs lets every hand-over of a slow run jerk the tool
/// as hard as a fast one's. The limit at v_F is
/// `clamp(linear_acceleration_per_speed · v_F, min_linear_acceleration, linear_acceleration)`
/// ([`TwistRateLimit::for_speed`]).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TwistRateLimit {
    /// Largest change of the linear velocity per second at any base speed, m/s².
    pub linear_acceleration: f64,
    /// Largest change of the angular velocity per second, rad/s².
    pub angular_acceleration: f64,
    /// Linear limit per unit of the base speed v_F, 1/s (3.5: 0.7 m/s² at 0.2 m/s, 1.4 m/s² at
    /// 0.4 m/s; 2.5 meets the paper's max |a| on Exp 1 but leaves a U-turn place's reach short).
    pub linear_acceleration_per_speed: f64,
    /// Floor of the speed-scaled linear limit, m/s² (0.3), so that a slow or stopped base
    /// still lets the servo move the tool.
    pub min_linear_acceleration: f64,
    /// Share of the base's forward acceleration that the linear limit gives up while the base
    /// speeds up (0.5; 0 turns it off): the arm cancels the base's acceleration at the tool
    /// only as well as it knows the base's motion, which lags its command, so a reach begun as
    /// the base speeds up (after a lift, at the start) had the two add up at the tool
    /// ([`TwistRateLimit::sharing`]).
    pub base_acceleration_share: f64,
}

impl Default for TwistRateLimit {
    fn default() -> Self {
        Self {
            linear_acceleration: 2.0,
            angular_acceleration: 4.0,
            linear_acceleration_per_speed: 3.5,
            min_linear_acceleration: 0.3,
            base_acceleration_share: 0.5,
        }
    }
}

impl TwistRateLimit {
    /// The linear acceleration limit at base speed `forward_speed` (m/s; its magnitude counts),
    /// m/s²: `linear_acceleration_per_speed · |v_F|` within `[min_linear_acceleration,
    /// linear_acceleration]`.
    pub fn linear_limit(&self, forward_speed: f64) -> f64 {
        let scaled = self.linear_acceleration_per_speed * forward_speed.abs();
        let floor = self.min_linear_acceleration.min(self.linear_acceleration);
        if scaled.is_finite() {
            scaled.clamp(floor, self.linear_acceleration)
        } else {
            self.linear_acceleration
        }
    }

    /// These limits with the linear one fixed at its value for base speed `forward_speed`
    /// ([`TwistRateLimit::linear_limit`]).
    pub fn for_speed(&self, forward_speed: f64) -> Self {
        Self {
            linear_acceleration: self.linear_limit(forward_speed),
            ..*self
        }
    }

    /// These limits with the linear one lowered, while the base speeds up (its forward speed
    /// `base_speed` and acceleration `base_acceleration`, m/s and m/s², of one sign), by
    /// `base_acceleration_share` × |`base_acceleration`|, down to the floor
    /// `min_linear_acceleration` (or the linear limit itself, if lower). Slowing down, the base
    /// lingers past a target whose grasp, lift or drop the final phase is still servoing, and
    /// taking from its budget then cost Exp 2 transports. Values that are not finite leave the
    /// limits as they are.
    pub fn sharing(&self, base_speed: f64, base_acceleration: f64) -> Self {
        let speeding_up = base_speed * base_acceleration > 0.0;
        if !(speeding_up && base_acceleration.is_finite()) {
            return *self;
        }
        let floor = self.min_linear_acceleration.min(self.linear_acceleration);
        let lowered =
            self.linear_acceleration - self.base_acceleration_share * base_acceleration.abs();
        Self {
            linear_acceleration: lowered.max(floor),
            ..*self
        }
    }

    /// `wanted`, moved from `last` by at most the allowed change in `dt` (direction kept).
    pub fn apply(&self, last: &Twist, wanted: &Twist, dt: f64) -> Twist {
        let change = wanted - last;
        let linear = change
            .fixed_rows::<3>(0)
            .into_owned()
            .cap_magnitude(self.linear_acceleration * dt);
        let angular = change
            .fixed_rows::<3>(3)
            .into_owned()
            .cap_magnitude(self.angular_acceleration * dt);
        last + Twist::new(
            linear.x, linear.y, linear.z, angular.x, angular.y, angular.z,
        )
    }
}

/// The controllers file of a config folder (`config/controllers.toml`).
pub const CONTROLLERS_FILE: &str = "controllers.toml";

/// Every tunable of the composed MotM controller, by module. Every key is optional.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OnTheMoveConfig {
    /// Mission sequencing.
    pub mission: MissionConfig,
    /// Base controller.
    pub base: BaseControllerConfig,
    /// Reacher.
    pub reacher: ReacherConfig,
    /// Final-phase controllers.
    pub final_phase: FinalPhaseConfig,
    /// Redundancy-resolution QP.
    pub resolver: ResolverConfig,
    /// Rate limit on the tool twist sent to the QP (smooths hand-overs between the reacher and
    /// the final phase, and between tasks).
    pub twist_rate: TwistRateLimit,
    /// Cap on e_t in the QP's 1/e_t weights, m. MotM's twists come from trajectories that must
    /// be followed, so the slack must stay expensive even when the target is metres away;
    /// the cap also keeps the weights from jumping when a new task starts.
    pub max_position_error: f64,
    /// Fastest rise of e_t, m/s (0.2: from a grasp's 0.1 m to the 0.2 m cap in half a
    /// second). It falls as fast as the distance does, so the slack tightens at once as the tool
    /// closes on a target.
    pub max_position_error_rate: f64,
    /// Feed-forward of the base's velocity error into the twist sent to the QP.
    pub base_slip: BaseSlipConfig,
    /// Acceleration limit on the base velocity target sent to the QP.
    pub base_rate: BaseCommandRateConfig,
    /// Perception: colour thresholds, gates and the velocity fit.
    pub perception: PerceptionConfig,
}

impl Default for OnTheMoveConfig {
    fn default() -> Self {
        Self {
            mission: MissionConfig::default(),
            base: BaseControllerConfig::default(),
            reacher: ReacherConfig::default(),
            final_phase: FinalPhaseConfig::default(),
            resolver: ResolverConfig::default(),
            twist_rate: TwistRateLimit::default(),
            max_position_error: 0.2,
            max_position_error_rate: 0.2,
            base_slip: BaseSlipConfig::default(),
            base_rate: BaseCommandRateConfig::default(),
            perception: PerceptionConfig::default(),
        }
    }
}

impl OnTheMoveConfig {
    /// Loads and checks a controllers file (`config/controllers.toml`: tables by module, every
    /// key optional); unknown keys and bad values are errors naming the file and the key.
    pub fn load(file: &Path) -> Result<Self, ModelError> {
        let text = ModelError::read_to_string(file)?;
        Self::from_toml_str(file, &text)
    }

    /// The controllers of a stack: `file` when given (relative paths as given), else
    /// [`CONTROLLERS_FILE`] in `config_dir` when it exists, else the defaults. The deployed
    /// services and the in-process trials take their gains from the same file this way.
    pub fn for_stack(config_dir: &Path, file: Option<&Path>) -> Result<Self, ModelError> {
        match file {
            Some(file) => Self::load(file),
            None => {
                let default = config_dir.join(CONTROLLERS_FILE);
                if default.is_file() {
                    Self::load(&default)
                } else {
                    Ok(Self::default())
                }
            }
        }
    }

    /// Parses and checks TOML text that came from `file`.
    pub fn from_toml_str(file: &Path, text: &str) -> Result<Self, ModelError> {
        let config: Self = ModelError::parse_toml_str(file, text)?;
        config.validate(file)?;
        Ok(config)
    }

    /// Checks the modules' values; `file` is named in the error.
    pub fn validate(&self, file: &Path) -> Result<(), ModelError> {
        self.mission.validate(file)?;
        self.base.validate(file)?;
        self.reacher.validate(file)?;
        self.final_phase.validate(file)?;
        self.perception.validate(file)?;
        let rates = [
            (
                "twist_rate.linear_acceleration",
                self.twist_rate.linear_acceleration,
            ),
            (
                "twist_rate.angular_acceleration",
                self.twist_rate.angular_acceleration,
            ),
            (
                "twist_rate.linear_acceleration_per_speed",
                self.twist_rate.linear_acceleration_per_speed,
            ),
            (
                "twist_rate.min_linear_acceleration",
                self.twist_rate.min_linear_acceleration,
            ),
            (
                "base_rate.forward_acceleration_per_speed",
                self.base_rate.forward_acceleration_per_speed,
            ),
            ("max_position_error", self.max_position_error),
            ("max_position_error_rate", self.max_position_error_rate),
        ];
        ModelError::check_positive(file, &rates)?;
        let share = self.twist_rate.base_acceleration_share;
        if !(share.is_finite() && share >= 0.0) {
            return Err(ModelError::invalid(
                file,
                "twist_rate.base_acceleration_share",
                format!("must be finite and not negative, got {share}"),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod config_file_tests {
    use super::*;

    #[test]
    fn the_linear_twist_limit_scales_with_the_base_speed_within_its_bounds() {
        let limits = TwistRateLimit::default();
        let k = limits.linear_acceleration_per_speed;
        assert!((limits.linear_limit(0.3) - k * 0.3).abs() < 1e-12);
        assert!((limits.linear_limit(-0.3) - k * 0.3).abs() < 1e-12);
        assert_eq!(limits.linear_limit(0.0), limits.min_linear_acceleration);
        assert_eq!(limits.linear_limit(10.0), limits.linear_acceleration);
        assert_eq!(limits.linear_limit(f64::NAN), limits.linear_acceleration);
        let at = limits.for_speed(0.2);
        assert!((at.linear_acceleration - k * 0.2).abs() < 1e-12);
        assert_eq!(at.angular_acceleration, limits.angular_acceleration);
    }

    #[test]
    fn the_base_s_speed_up_lowers_the_linear_twist_limit_down_to_its_floor() {
        let limits = TwistRateLimit::default().for_speed(0.3);
        let full = limits.linear_acceleration;
        let share = limits.base_acceleration_share;
        // Speeding up at 0.75 m/s², forward or in reverse, gives up the share.
        for (v, a) in [(0.2, 0.75), (-0.2, -0.75)] {
            let lowered = limits.sharing(v, a).linear_acceleration;
            assert!((lowered - (full - share * 0.75)).abs() < 1e-12, "{lowered}");
        }
        // Slowing down, at rest or at a constant speed, it does not.
        for (v, a) in [(0.2, -0.75), (-0.2, 0.75), (0.0, 0.75), (0.3, 0.0)] {
            assert_eq!(limits.sharing(v, a), limits, "{v} {a}");
        }
        assert_eq!(limits.sharing(0.2, f64::NAN), limits);
        assert_eq!(limits.sharing(0.2, f64::INFINITY), limits);
        let flat_out = limits.sharing(0.2, 1e6);
        assert_eq!(flat_out.linear_acceleration, limits.min_linear_acceleration);
        assert_eq!(flat_out.angular_acceleration, limits.angular_acceleration);
        let off = TwistRateLimit {
            base_acceleration_share: 0.0,
            ..limits
        };
        assert_eq!(off.sharing(0.2, 0.75), off);
    }

    #[test]
    fn the_shipped_controllers_file_is_the_defaults() {
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/controllers.toml");
        let loaded = OnTheMoveConfig::load(&file).unwrap();
        assert_eq!(
            format!("{loaded:?}"),
            format!("{:?}", OnTheMoveConfig::default())
        );
    }

    #[test]
    fn a_bad_controllers_file_names_the_file_and_the_key() {
        let file = Path::new("gains.toml");
        let cases = [
            ("[reacher]\narm_sped_ratio = 0.5\n", "arm_sped_ratio"),
            ("max_position_error = -1.0\n", "max_position_error"),
            ("max_position_error_rate = 0.0\n", "max_position_error_rate"),
            (
                "[twist_rate]\nlinear_acceleration = nan\n",
                "linear_acceleration",
            ),
            (
                "[twist_rate]\nlinear_acceleration_per_speed = -1.0\n",
                "twist_rate.linear_acceleration_per_speed",
            ),
            (
                "[twist_rate]\nmin_linear_acceleration = 0.0\n",
                "twist_rate.min_linear_acceleration",
            ),
            (
                "[base_rate]\nforward_acceleration_per_speed = inf\n",
                "base_rate.forward_acceleration_per_speed",
            ),
            (
                "[mission]\nlandmark_fix_weight = 2.0\n",
                "mission.landmark_fix_weight",
            ),
            (
                "[mission]\nlandmark_max_range = 0.0\n",
                "mission.landmark_max_range",
            ),
            ("[perception]\nmin_red = 300\n", "min_red"),
            ("[perception]\nmin_pixels = 0\n", "perception.min_pixels"),
            ("[perception]\nmax_range = -1.0\n", "perception.max_range"),
            (
                "[perception]\nmin_ray_angle = 1.6\n",
                "perception.min_ray_angle",
            ),
            (
                "[perception]\nmin_ray_angle = -0.1\n",
                "perception.min_ray_angle",
            ),
            (
                "[perception]\nmin_velocity_span = 2.0\n",
                "perception.min_velocity_span",
            ),
        ];
        for (text, key) in cases {
            let err = OnTheMoveConfig::from_toml_str(file, text)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("gains.toml") && err.contains(key),
                "{key}: {err}"
            );
        }
        let tuned = OnTheMoveConfig::from_toml_str(file, "[reacher]\narm_speed_ratio = 0.4\n");
        assert_eq!(tuned.unwrap().reacher.arm_speed_ratio, 0.4);
        let tuned = OnTheMoveConfig::from_toml_str(file, "[perception]\nmin_red = 90\n");
        assert_eq!(tuned.unwrap().perception.min_red, 90);
    }
}
