//! What a `ratioDrive` means in m/s and rad/s, both ways: the server's semantics
//! ([`DriveLimits::velocity`], used by the fake robot) and its inverse
//! ([`DriveLimits::ratio`], used by the driver).
//!
//! Server semantics (ARIA 2.9.1's ratio-drive mode; ARAM is closed, so the two fractions are
//! config values):
//! - forward: `v = trans/100 · transVelMax · throttle/100`;
//! - reverse: the same, but never faster than `reverse_fraction · transVelMax` (¼);
//! - rotation: `ω = rot/100 · rotMax(v)`, where `rotMax` falls linearly from `rotVelMax` at
//!   rest to `rot_at_full_speed_fraction · rotVelMax` (½) at `transVelMax`. The linear fall
//!   is this project's reading (*uncertain*).
//!
//! The percentages are computed from the base's configured top speeds; passing m/s as
//! percentages (as one public driver does) would be wrong by the factor transVelMax/100.

use crate::protocol::RatioDrive;

/// The base's top speeds and the ratio-drive scaling (config values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveLimits {
    /// transVelMax, m/s: the speed of `trans = 100`, `throttle = 100`.
    pub trans_vel_max: f64,
    /// rotVelMax, rad/s: the rotation speed of `rot = 100` at rest.
    pub rot_vel_max: f64,
    /// Reverse speed cap as a fraction of `trans_vel_max` (0.25).
    pub reverse_fraction: f64,
    /// Rotation speed of `rot = 100` at full forward speed, as a fraction of `rot_vel_max`
    /// (0.5).
    pub rot_at_full_speed_fraction: f64,
}

/// A velocity turned into a ratio drive, and whether it had to be saturated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RatioCommand {
    /// The ratio drive to send.
    pub drive: RatioDrive,
    /// Whether the requested velocity was beyond what the base can do (the drive is the
    /// nearest it can).
    pub saturated: bool,
}

impl DriveLimits {
    /// Checks that every value is positive and finite and the fractions in (0, 1].
    pub fn validate(&self) -> Result<(), String> {
        for (key, v) in [
            ("trans_vel_max", self.trans_vel_max),
            ("rot_vel_max", self.rot_vel_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{key}: must be positive and finite, got {v}"));
            }
        }
        for (key, v) in [
            ("reverse_fraction", self.reverse_fraction),
            (
                "rot_at_full_speed_fraction",
                self.rot_at_full_speed_fraction,
            ),
        ] {
            if !(v > 0.0 && v <= 1.0) {
                return Err(format!("{key}: must be in (0, 1], got {v}"));
            }
        }
        Ok(())
    }

    /// Largest rotation speed at forward speed `v`, rad/s.
    pub fn rot_max_at(&self, v: f64) -> f64 {
        let s = (v.abs() / self.trans_vel_max).min(1.0);
        self.rot_vel_max * (1.0 - (1.0 - self.rot_at_full_speed_fraction) * s)
    }

    /// The velocity `(v, ω)` the server drives for `drive` (the server's semantics).
    pub fn velocity(&self, drive: &RatioDrive) -> (f64, f64) {
        let mut v = drive.trans / 100.0 * self.trans_vel_max * drive.throttle / 100.0;
        v = v.max(-self.reverse_fraction * self.trans_vel_max);
        let omega = drive.rot / 100.0 * self.rot_max_at(v);
        (v, omega)
    }

    /// The ratio drive for velocity `(v, ω)` (full throttle): the inverse of
    /// [`velocity`](Self::velocity), saturated at the base's reach. Non-finite input gives a
    /// zero drive, marked saturated.
    pub fn ratio(&self, v: f64, omega: f64) -> RatioCommand {
        if !(v.is_finite() && omega.is_finite()) {
            return RatioCommand {
                drive: RatioDrive::ZERO,
                saturated: true,
            };
        }
        let v_lo = -self.reverse_fraction * self.trans_vel_max;
        let v_sent = v.clamp(v_lo, self.trans_vel_max);
        let rot_max = self.rot_max_at(v_sent);
        let omega_sent = omega.clamp(-rot_max, rot_max);
        let tolerance = 1e-9;
        let saturated = (v - v_sent).abs() > tolerance * self.trans_vel_max
            || (omega - omega_sent).abs() > tolerance * self.rot_vel_max;
        RatioCommand {
            drive: RatioDrive {
                trans: (100.0 * v_sent / self.trans_vel_max).clamp(-100.0, 100.0),
                rot: (100.0 * omega_sent / rot_max).clamp(-100.0, 100.0),
                throttle: 100.0,
                lateral: 0.0,
            },
            saturated,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LD60: DriveLimits = DriveLimits {
        trans_vel_max: 1.8,
        rot_vel_max: 3.0,
        reverse_fraction: 0.25,
        rot_at_full_speed_fraction: 0.5,
    };

    #[test]
    fn percentages_come_from_the_top_speeds() {
        let c = LD60.ratio(0.9, 0.0);
        assert!(!c.saturated);
        assert!((c.drive.trans - 50.0).abs() < 1e-9);
        assert_eq!(
            (c.drive.rot, c.drive.throttle, c.drive.lateral),
            (0.0, 100.0, 0.0)
        );
        // At rest, rot 100 % is rotVelMax; at half speed, 75 % of it; at full speed, half.
        assert!((LD60.rot_max_at(0.0) - 3.0).abs() < 1e-12);
        assert!((LD60.rot_max_at(0.9) - 2.25).abs() < 1e-12);
        assert!((LD60.rot_max_at(-1.8) - 1.5).abs() < 1e-12);
        let c = LD60.ratio(0.9, 1.125);
        assert!((c.drive.rot - 50.0).abs() < 1e-9, "{c:?}");
    }

    #[test]
    fn ratio_inverts_velocity_within_reach() {
        for &(v, w) in &[
            (0.0, 0.0),
            (0.3, -0.4),
            (1.2, 1.5),
            (-0.2, 0.7),
            (1.8, -1.5),
        ] {
            let c = LD60.ratio(v, w);
            assert!(!c.saturated, "{v} {w}");
            let (v2, w2) = LD60.velocity(&c.drive);
            assert!(
                (v - v2).abs() < 1e-9 && (w - w2).abs() < 1e-9,
                "{v} {w}: {v2} {w2}"
            );
        }
    }

    #[test]
    fn reverse_is_capped_and_beyond_reach_is_saturated() {
        let c = LD60.ratio(-1.0, 0.0);
        assert!(c.saturated);
        assert!((LD60.velocity(&c.drive).0 + 0.45).abs() < 1e-9);
        // The server caps a full reverse ratio itself too.
        let full_reverse = RatioDrive {
            trans: -100.0,
            ..RatioDrive::ZERO
        };
        assert!((LD60.velocity(&full_reverse).0 + 0.45).abs() < 1e-9);
        let c = LD60.ratio(2.5, 4.0);
        assert!(c.saturated && c.drive.trans == 100.0 && c.drive.rot == 100.0);
        let c = LD60.ratio(f64::NAN, 0.0);
        assert!(c.saturated && c.drive == RatioDrive::ZERO);
        assert!(LD60.validate().is_ok());
        let bad = DriveLimits {
            reverse_fraction: 0.0,
            ..LD60
        };
        assert!(bad.validate().unwrap_err().contains("reverse_fraction"));
    }
}
