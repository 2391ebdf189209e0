//! Acceleration limit on the base velocity target handed to the redundancy-resolution QP.
//!
//! The base controller's (v*, ω*) can jump: its polar law turns hard (up to ω_max) as the base
//! closes on the closest-approach pose, and when a task ends the goal switches to the next
//! target, so ω* may swing from −1.5 to +0.5 rad/s in one cycle. The base cannot follow (the
//! LD-60 turns at most 2 rad/s²), but the QP plans the arm's motion on the assumption that it
//! does: the arm swings to cancel a base rotation that has not happened, and the tool jerks
//! (filtered EE accelerations of 10 m/s² at these hand-overs). Limiting the target's rate of
//! change to the base's own acceleration limits keeps the QP's plan one the base can execute,
//! so the arm and the base stay coordinated.
//!
//! Choices:
//! - The limits are the base joints' URDF acceleration limits times
//!   [`BaseCommandRateConfig::limit_fraction`] (1.0: the base's full capability).
//! - **The forward acceleration scales with the run's base speed v_F**
//!   ([`BaseCommandRate::for_speed`]): at most
//!   [`BaseCommandRateConfig::forward_acceleration_per_speed`] × v_F, so the base takes the same
//!   time to reach v_F (or to come back to it from the linger speed after a task) at any v_F.
//!   The arm cancels the base's acceleration at the tool only as well as it knows it (the base
//!   lags its command, and the measured velocity is fed forward a cycle late); at the URDF's
//!   0.8 m/s², a slow run's start and its speed-up after each task were the largest tool
//!   accelerations left once the tool twist's own limit scaled with v_F. The yaw acceleration is
//!   the base controller's ([`BaseCommandRate::with_yaw_acceleration`]), which scales with v_F
//!   too: the controller plans its turns with it.
//! - **On by default.** The base controller itself limits its turn command to the same yaw
//!   acceleration (see [`crate::base_controller`]), so it plans with the turn the base will
//!   actually make and this limit changes little on the way; it still ramps the forward speed
//!   from rest and guards the QP against any other source of the target. In `motm experiment
//!   exp1` it brought MotM's max |a| from 3–10 m/s² to about 2.3 m/s². (While the base
//!   controller planned with instant turns, this limit alone cost 3 of 120 trials on seeds
//!   21–40: a base turning more slowly than the controller expected clipped the container.)

use serde::Deserialize;

use crate::robot::Robot;
use crate::types::BaseVelocity;

/// Tunables of the base-target rate limit (the `[base_rate]` table).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaseCommandRateConfig {
    /// Whether the target's rate of change is limited at all (true; see the module docs).
    pub enabled: bool,
    /// Fraction of the base joints' acceleration limits allowed for the target's change (1.0).
    pub limit_fraction: f64,
    /// Forward acceleration allowed per unit of the base speed v_F, 1/s (2.5: v_F is reached in
    /// 0.4 s from rest; 0.5 m/s² at 0.2 m/s, the URDF's 0.8 m/s² from 0.32 m/s).
    /// Applied by
    /// [`BaseCommandRate::for_speed`].
    pub forward_acceleration_per_speed: f64,
}

impl Default for BaseCommandRateConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            limit_fraction: 1.0,
            forward_acceleration_per_speed: 2.5,
        }
    }
}

/// The rate limiter: remembers the last target it let through.
#[derive(Debug, Clone)]
pub struct BaseCommandRate {
    config: BaseCommandRateConfig,
    /// Largest change per second of ω (rad/s²) and of v (m/s²).
    omega_acceleration: f64,
    v_acceleration: f64,
    last: BaseVelocity,
}

impl BaseCommandRate {
    /// A limiter for `robot`'s base (its first two joints: ω, then v), starting at rest.
    pub fn new(robot: &Robot, config: BaseCommandRateConfig) -> Self {
        let limits = robot.limits();
        let acceleration = |i: usize| {
            limits
                .get(i)
                .map_or(f64::INFINITY, |l| l.acceleration * config.limit_fraction)
        };
        Self {
            config,
            omega_acceleration: acceleration(0),
            v_acceleration: acceleration(1),
            last: BaseVelocity::default(),
        }
    }

    /// This limiter with its forward acceleration limit at most
    /// [`BaseCommandRateConfig::forward_acceleration_per_speed`] × |`forward_speed`| (the run's
    /// base speed v_F). A product that is not finite and positive leaves the limit as it is.
    pub fn for_speed(mut self, forward_speed: f64) -> Self {
        let scaled = self.config.forward_acceleration_per_speed * forward_speed.abs();
        if scaled.is_finite() && scaled > 0.0 {
            self.v_acceleration = self.v_acceleration.min(scaled);
        }
        self
    }

    /// This limiter with its yaw acceleration limit at most `limit` rad/s² (the base
    /// controller's, [`crate::base_controller::BaseControllerConfig::yaw_acceleration`], so that
    /// the QP's base target turns as the controller planned). A limit that is not finite and
    /// positive leaves it as it is.
    pub fn with_yaw_acceleration(mut self, limit: f64) -> Self {
        if limit.is_finite() && limit > 0.0 {
            self.omega_acceleration = self.omega_acceleration.min(limit);
        }
        self
    }

    /// The yaw acceleration limit in use, rad/s².
    pub fn yaw_acceleration(&self) -> f64 {
        self.omega_acceleration
    }

    /// The last target let through (at rest before the first).
    pub fn last(&self) -> BaseVelocity {
        self.last
    }

    /// The forward acceleration limit in use, m/s².
    pub fn forward_acceleration(&self) -> f64 {
        self.v_acceleration
    }

    /// `wanted`, moved from the last target by at most the allowed change in `dt`. A non-finite
    /// or disabled limit passes `wanted` through; a non-finite `wanted` holds the last target.
    pub fn apply(&mut self, wanted: BaseVelocity, dt: f64) -> BaseVelocity {
        if !(wanted.v.is_finite() && wanted.omega.is_finite()) {
            return self.last;
        }
        let step = |last: f64, wanted: f64, rate: f64| {
            let max = rate * dt;
            if max.is_finite() && max >= 0.0 {
                last + (wanted - last).clamp(-max, max)
            } else {
                wanted
            }
        };
        let limited = if self.config.enabled {
            BaseVelocity {
                v: step(self.last.v, wanted.v, self.v_acceleration),
                omega: step(self.last.omega, wanted.omega, self.omega_acceleration),
            }
        } else {
            wanted
        };
        self.last = limited;
        limited
    }

    /// Forgets the last target (the base is at rest).
    pub fn reset(&mut self) {
        self.last = BaseVelocity::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frankie() -> Robot {
        let config_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        Robot::load(&config_dir, "frankie").expect("frankie loads")
    }

    fn enabled() -> BaseCommandRateConfig {
        BaseCommandRateConfig {
            enabled: true,
            ..BaseCommandRateConfig::default()
        }
    }

    #[test]
    fn the_forward_and_yaw_limits_scale_with_the_base_speed_and_never_exceed_the_base() {
        let urdf = BaseCommandRate::new(&frankie(), BaseCommandRateConfig::default());
        let k = BaseCommandRateConfig::default().forward_acceleration_per_speed;
        let slow = urdf.clone().for_speed(0.2).with_yaw_acceleration(1.2);
        assert!((slow.forward_acceleration() - k * 0.2).abs() < 1e-12);
        assert_eq!(slow.yaw_acceleration(), 1.2);
        let fast = urdf.clone().for_speed(10.0).with_yaw_acceleration(100.0);
        assert_eq!(fast.forward_acceleration(), urdf.forward_acceleration());
        assert_eq!(fast.yaw_acceleration(), urdf.yaw_acceleration());
        let mut limited = slow;
        let out = limited.apply(BaseVelocity { v: 1.0, omega: 1.0 }, 0.1);
        assert!((out.v - k * 0.2 * 0.1).abs() < 1e-12);
        assert!((out.omega - 0.12).abs() < 1e-12);
    }

    #[test]
    fn a_jump_in_the_target_is_spread_over_the_base_acceleration_limits() {
        let robot = frankie();
        let limits = robot.limits();
        let (omega_acc, v_acc) = (limits[0].acceleration, limits[1].acceleration);
        let mut rate = BaseCommandRate::new(&robot, enabled());
        let dt = 0.005;
        // From rest to 0.4 m/s, turning −1.5 rad/s.
        let wanted = BaseVelocity {
            v: 0.4,
            omega: -1.5,
        };
        let first = rate.apply(wanted, dt);
        assert!((first.v - v_acc * dt).abs() < 1e-12, "{first:?}");
        assert!((first.omega + omega_acc * dt).abs() < 1e-12, "{first:?}");
        // It gets there in (change / limit) seconds, and then holds it.
        let cycles = ((1.5 / omega_acc).max(0.4 / v_acc) / dt).ceil() as usize;
        let mut last = first;
        for _ in 0..cycles {
            let next = rate.apply(wanted, dt);
            assert!((next.omega - last.omega).abs() <= omega_acc * dt + 1e-12);
            assert!((next.v - last.v).abs() <= v_acc * dt + 1e-12);
            last = next;
        }
        assert_eq!(last, wanted);
        // The hand-over swing to +0.5 rad/s is also spread out, never a step.
        let swung = rate.apply(BaseVelocity { v: 0.4, omega: 0.5 }, dt);
        assert!((swung.omega - (-1.5 + omega_acc * dt)).abs() < 1e-12);
    }

    #[test]
    fn disabled_passes_through_and_bad_input_holds() {
        let robot = frankie();
        let disabled = BaseCommandRateConfig {
            enabled: false,
            ..BaseCommandRateConfig::default()
        };
        let mut off = BaseCommandRate::new(&robot, disabled);
        let wanted = BaseVelocity { v: 0.4, omega: 1.0 };
        assert_eq!(off.apply(wanted, 0.005), wanted);

        let mut on = BaseCommandRate::new(&robot, enabled());
        let first = on.apply(wanted, 0.005);
        let nan = BaseVelocity {
            v: f64::NAN,
            omega: 0.0,
        };
        assert_eq!(on.apply(nan, 0.005), first);
        on.reset();
        let again = on.apply(wanted, 0.005);
        assert_eq!(again, first, "after a reset it starts from rest again");
    }
}
