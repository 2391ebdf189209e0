//! Base hardware settings: `config/bases/<name>.toml` (`[arnl]` for an Omron LD-60, `[can]`
//! for an AgileX base). The protocol facts that are uncertain for a given robot live here as
//! values, not in the code.

use std::path::{Path, PathBuf};
use std::time::Duration;

use motm_omron::{ClientConfig, DriveLimits};
use serde::Deserialize;

/// Contents of a base config file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaseConfig {
    /// ArNetworking settings (LD-60).
    pub arnl: Option<ArnlConfig>,
    /// CAN settings (AgileX).
    pub can: Option<CanConfig>,
}

/// `[arnl]`: an Omron LD-60 over ArNetworking and ARCL.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArnlConfig {
    /// ArNetworking port.
    pub port: u16,
    /// ARCL port (0: ARCL is not watched).
    pub arcl_port: u16,
    /// ArNetworking user.
    pub user: String,
    /// ArNetworking password.
    pub password: String,
    /// Server key.
    pub server_key: String,
    /// Protocol version sent.
    pub protocol_version: String,
    /// ARCL password.
    pub arcl_password: String,
    /// updateNumbers request interval, ms.
    pub update_interval_ms: i32,
    /// Odometry older than this is stale: safe stop, ms.
    pub odometry_stale_ms: f64,
    /// Connection and handshake timeout, ms.
    pub connect_timeout_ms: f64,
    /// transVelMax, m/s.
    pub trans_vel_max: f64,
    /// rotVelMax, rad/s.
    pub rot_vel_max: f64,
    /// Reverse cap, fraction of transVelMax.
    pub reverse_fraction: f64,
    /// Rotation at full speed, fraction of rotVelMax.
    pub rot_at_full_speed_fraction: f64,
}

/// `[can]`: an AgileX base.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanConfig {
    /// CAN interface.
    pub interface: String,
    /// Effective track width of the wheel odometry, m.
    pub track_width: f64,
    /// No motion state for this long: safe stop, ms.
    pub feedback_timeout_ms: f64,
}

impl BaseConfig {
    /// `<config_dir>/bases/<name>.toml`, or `name` itself when it is a file.
    pub fn path(config_dir: &Path, name: &str) -> PathBuf {
        let direct = PathBuf::from(name);
        if direct.is_file() {
            direct
        } else {
            config_dir.join("bases").join(format!("{name}.toml"))
        }
    }

    /// Reads and checks a base config file.
    pub fn from_file(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Parses and checks the text of a base config.
    pub fn parse(text: &str) -> Result<Self, String> {
        let config: Self = toml::from_str(text).map_err(|e| e.to_string())?;
        if let Some(a) = &config.arnl {
            a.drive_limits()
                .validate()
                .map_err(|e| format!("[arnl] {e}"))?;
            for (key, v) in [
                ("odometry_stale_ms", a.odometry_stale_ms),
                ("connect_timeout_ms", a.connect_timeout_ms),
            ] {
                if !(v.is_finite() && v > 0.0) {
                    return Err(format!("[arnl] {key}: must be positive, got {v}"));
                }
            }
        }
        if let Some(c) = &config.can {
            for (key, v) in [
                ("track_width", c.track_width),
                ("feedback_timeout_ms", c.feedback_timeout_ms),
            ] {
                if !(v.is_finite() && v > 0.0) {
                    return Err(format!("[can] {key}: must be positive, got {v}"));
                }
            }
        }
        Ok(config)
    }
}

impl ArnlConfig {
    /// The ratio-drive scaling.
    pub fn drive_limits(&self) -> DriveLimits {
        DriveLimits {
            trans_vel_max: self.trans_vel_max,
            rot_vel_max: self.rot_vel_max,
            reverse_fraction: self.reverse_fraction,
            rot_at_full_speed_fraction: self.rot_at_full_speed_fraction,
        }
    }

    /// The ArNetworking client settings.
    pub fn client(&self) -> ClientConfig {
        ClientConfig {
            user: self.user.clone(),
            password: self.password.clone(),
            server_key: self.server_key.clone(),
            protocol_version: self.protocol_version.clone(),
            timeout: Duration::from_secs_f64(self.connect_timeout_ms * 1e-3),
            update_interval_ms: self.update_interval_ms,
        }
    }
}
