//! libfranka 0.9.2's last stage before a joint velocity goes out: the first-order low-pass
//! filter (cutoff 100 Hz) and the velocity rate limiter, with libfranka's constants, computed
//! per joint from the state's `dq_d` and `ddq_d` (what the robot last executed).
//!
//! Per joint: (1) `y = g·dq_cmd + (1−g)·dq_d`, `g = dt/(dt + 1/(2π·fc))`; (2) `jerk = ((y −
//! dq_d)/dt − ddq_d)/dt`; (3) `a = ddq_d + clamp(jerk, ±J_max)·dt`; (4) `a_max = min(J/A·(V_max
//! − dq_d), A)`, `a_min = max(J/A·(−V_max − dq_d), −A)`; (5) `dq_c = dq_d + clamp(a, a_min,
//! a_max)·dt`. A NaN or infinite input or output is an error and nothing is sent.

use crate::wire::ProtocolError;

/// libfranka's control period, s.
pub const DT: f64 = 1e-3;
/// libfranka's safety margin on the limits.
pub const EPS: f64 = 1e-3;
/// The Panda's joint velocity limits, rad/s (before the margins).
pub const VELOCITY_LIMIT: [f64; 7] = [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61];
/// The Panda's joint acceleration limits, rad/s² (before the margin).
pub const ACCELERATION_LIMIT: [f64; 7] = [15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0];
/// The Panda's joint jerk limits, rad/s³ (before the margin).
pub const JERK_LIMIT: [f64; 7] = [7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0];
/// Default low-pass cutoff, Hz.
pub const DEFAULT_CUTOFF_HZ: f64 = 100.0;

/// libfranka's `kMaxJointJerk`: the jerk limits minus [`EPS`].
pub fn max_joint_jerk() -> [f64; 7] {
    JERK_LIMIT.map(|j| j - EPS)
}

/// libfranka's `kMaxJointAcceleration`: the acceleration limits minus [`EPS`].
pub fn max_joint_acceleration() -> [f64; 7] {
    ACCELERATION_LIMIT.map(|a| a - EPS)
}

/// libfranka's `kMaxJointVelocity`: `v_lim − EPS − 3e-3·A_max`.
pub fn max_joint_velocity() -> [f64; 7] {
    let a = max_joint_acceleration();
    std::array::from_fn(|i| VELOCITY_LIMIT[i] - EPS - 3e-3 * a[i])
}

/// The low-pass gain at sample time `dt` and cutoff `cutoff_hz`.
pub fn lowpass_gain(dt: f64, cutoff_hz: f64) -> f64 {
    dt / (dt + 1.0 / (2.0 * std::f64::consts::PI * cutoff_hz))
}

/// The filter and limiter settings (libfranka's defaults: both on, 100 Hz).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateLimitConfig {
    /// Whether the rate limiter runs (libfranka: `limit_rate = true`).
    pub limit_rate: bool,
    /// Low-pass cutoff, Hz; at or above 1000 Hz (libfranka's `kMaxCutoffFrequency`) the filter
    /// is off.
    pub cutoff_hz: f64,
}

impl Default for RateLimitConfig {
    fn default() -> Self {
        Self {
            limit_rate: true,
            cutoff_hz: DEFAULT_CUTOFF_HZ,
        }
    }
}

/// The last stage of the client: low-pass filter then rate limiter. Stateless between calls
/// (the state comes from the robot's `dq_d`, `ddq_d`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateLimiter {
    config: RateLimitConfig,
    gain: f64,
    max_velocity: [f64; 7],
    max_acceleration: [f64; 7],
    max_jerk: [f64; 7],
}

impl RateLimiter {
    /// A limiter with libfranka's constants. Errors when the cutoff is not positive.
    pub fn new(config: RateLimitConfig) -> Result<Self, String> {
        if !(config.cutoff_hz.is_finite() && config.cutoff_hz > 0.0) {
            return Err(format!(
                "cutoff_hz must be positive, got {}",
                config.cutoff_hz
            ));
        }
        Ok(Self {
            config,
            gain: lowpass_gain(DT, config.cutoff_hz),
            max_velocity: max_joint_velocity(),
            max_acceleration: max_joint_acceleration(),
            max_jerk: max_joint_jerk(),
        })
    }

    /// The low-pass gain in use (0.38587 at 100 Hz), 1 when the filter is off.
    pub fn gain(&self) -> f64 {
        if self.config.cutoff_hz >= 1000.0 {
            1.0
        } else {
            self.gain
        }
    }

    /// The velocity to send for commanded `dq_cmd`, given the robot's last desired velocity
    /// `dq_d` and acceleration `ddq_d`. Any non-finite value is an error.
    pub fn limit(
        &self,
        dq_cmd: &[f64; 7],
        dq_d: &[f64; 7],
        ddq_d: &[f64; 7],
    ) -> Result<[f64; 7], ProtocolError> {
        let finite = |field: &'static str, v: &[f64; 7]| {
            if v.iter().all(|x| x.is_finite()) {
                Ok(())
            } else {
                Err(ProtocolError::NotFinite {
                    message: "RobotCommand",
                    field,
                })
            }
        };
        finite("dq_c", dq_cmd)?;
        finite("dq_d", dq_d)?;
        finite("ddq_d", ddq_d)?;
        let g = self.gain();
        let mut out = [0.0; 7];
        for i in 0..7 {
            let y = g * dq_cmd[i] + (1.0 - g) * dq_d[i];
            out[i] = if self.config.limit_rate {
                let (j, a_lim, v) = (
                    self.max_jerk[i],
                    self.max_acceleration[i],
                    self.max_velocity[i],
                );
                let jerk = ((y - dq_d[i]) / DT - ddq_d[i]) / DT;
                let a = ddq_d[i] + jerk.clamp(-j, j) * DT;
                let a_max = (j / a_lim * (v - dq_d[i])).min(a_lim);
                let a_min = (j / a_lim * (-v - dq_d[i])).max(-a_lim);
                // max then min (not `clamp`, which panics when a_min > a_max): beyond +V_max,
                // a_max < a_min and a_max wins (the harder brake); beyond −V_max a_min wins
                // through the symmetric case below.
                let a = if dq_d[i] < -v {
                    a.min(a_max).max(a_min)
                } else {
                    a.max(a_min).min(a_max)
                };
                dq_d[i] + a * DT
            } else {
                y
            };
        }
        finite("dq_c", &out)?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_constants_are_libfrankas() {
        assert!((lowpass_gain(DT, 100.0) - 0.38587).abs() < 1e-5);
        let v = max_joint_velocity();
        let expected = [
            2.129003, 2.151503, 2.144003, 2.136503, 2.564003, 2.549003, 2.549003,
        ];
        for i in 0..7 {
            assert!((v[i] - expected[i]).abs() < 1e-9, "{i}: {}", v[i]);
        }
        assert_eq!(max_joint_acceleration()[1], 7.499);
        assert_eq!(max_joint_jerk()[6], 9999.999);
    }

    #[test]
    fn one_step_from_rest_is_filtered_then_jerk_limited() {
        let l = RateLimiter::new(RateLimitConfig::default()).unwrap();
        let out = l.limit(&[1.0; 7], &[0.0; 7], &[0.0; 7]).unwrap();
        // Joint 0: y = 0.38587, jerk = 385870 → clamp 7499.999 → a = 7.499999, dq = 7.5e-3.
        assert!((out[0] - 7.499999e-3).abs() < 1e-12, "{}", out[0]);
        // Joint 1: J = 3749.999 → a = 3.749999e0 (below A = 7.499), dq = 3.749999e-3.
        assert!((out[1] - 3.749999e-3).abs() < 1e-12, "{}", out[1]);
        // Tiny commands pass through the filter only.
        let out = l.limit(&[1e-6; 7], &[0.0; 7], &[0.0; 7]).unwrap();
        assert!((out[0] - 0.38587e-6).abs() < 1e-10);
    }

    #[test]
    fn a_long_run_stays_within_the_limits_and_reaches_the_target() {
        let l = RateLimiter::new(RateLimitConfig::default()).unwrap();
        let (mut v, mut a) = ([0.0; 7], [0.0; 7]);
        for k in 0..3000 {
            let target = if k < 1500 { [5.0; 7] } else { [-5.0; 7] };
            let out = l.limit(&target, &v, &a).unwrap();
            for i in 0..7 {
                let na = (out[i] - v[i]) / DT;
                let jerk = (na - a[i]) / DT;
                assert!(
                    out[i].abs() <= VELOCITY_LIMIT[i],
                    "k {k} joint {i} v {}",
                    out[i]
                );
                assert!(
                    na.abs() <= ACCELERATION_LIMIT[i] + 1e-6,
                    "k {k} joint {i} a {na}"
                );
                assert!(
                    jerk.abs() <= JERK_LIMIT[i] + 1e-3,
                    "k {k} joint {i} j {jerk}"
                );
                a[i] = na;
                v[i] = out[i];
            }
            if k == 1499 {
                let vm = max_joint_velocity();
                assert!((0..7).all(|i| (v[i] - vm[i]).abs() < 1e-3), "{v:?}");
            }
        }
    }

    #[test]
    fn non_finite_values_are_errors() {
        let l = RateLimiter::new(RateLimitConfig::default()).unwrap();
        let mut bad = [0.0; 7];
        bad[3] = f64::NAN;
        assert!(matches!(
            l.limit(&bad, &[0.0; 7], &[0.0; 7]),
            Err(ProtocolError::NotFinite { field: "dq_c", .. })
        ));
        bad[3] = f64::INFINITY;
        assert!(l.limit(&[0.0; 7], &bad, &[0.0; 7]).is_err());
        assert!(l.limit(&[0.0; 7], &[0.0; 7], &bad).is_err());
        assert!(
            RateLimiter::new(RateLimitConfig {
                limit_rate: true,
                cutoff_hz: 0.0
            })
            .is_err()
        );
    }
}
