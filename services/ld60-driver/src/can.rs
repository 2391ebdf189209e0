//! The AgileX backend: 0x421 once, 0x111 every cycle (the driver's 50 Hz matches the
//! protocol's 20 ms), odometry from 0x311 and 0x221, faults from 0x211, over any
//! [`CanBus`] (a `socketcan` socket on a robot, the in-memory bus in tests, a replayed
//! `candump -L` log).

use motm_agilex::{AgilexHost, CanBus, HostConfig, HostFault, SocketCanBus};

use crate::base::{BaseHardware, BaseState};
use crate::config::CanConfig;
use motm_driver::{EXIT_BAD_INPUT, EXIT_FAILED};

/// Opens the AgileX base of `config` on CAN interface `interface` (the config's unless
/// given) and enables command mode. An interface that cannot be opened is an error naming
/// `--can-interface`, and nothing is sent: with the exit code for bad input when no such
/// interface exists (ENODEV), for a failure otherwise (no CAN support in the kernel, no
/// permission, a failed enable).
pub fn open(
    config: &CanConfig,
    interface: Option<&str>,
) -> Result<CanBase<SocketCanBus>, (u8, String)> {
    let interface = interface.unwrap_or(&config.interface);
    let socket = SocketCanBus::open(interface).map_err(|e| {
        let code = if e.raw_os_error() == Some(libc::ENODEV) {
            EXIT_BAD_INPUT
        } else {
            EXIT_FAILED
        };
        let hint = if motm_agilex::bus::is_unsupported(&e) {
            "this kernel has no CAN sockets (AF_CAN)".to_owned()
        } else {
            format!("is the interface up? `ip link set {interface} up type can bitrate 500000`")
        };
        (
            code,
            format!("--can-interface {interface}: cannot open the CAN socket: {e} ({hint})"),
        )
    })?;
    let host = HostConfig {
        track_width: config.track_width,
        feedback_timeout: config.feedback_timeout_ms * 1e-3,
    };
    CanBase::new(socket, host).map_err(|e| {
        (
            EXIT_FAILED,
            format!("--can-interface {interface}: enable: {e}"),
        )
    })
}

/// An AgileX base on bus `B`.
#[derive(Debug)]
pub struct CanBase<B> {
    host: AgilexHost<B>,
}

impl<B: CanBus> CanBase<B> {
    /// Enables CAN command mode on `bus` and returns the base.
    pub fn new(bus: B, config: HostConfig) -> Result<Self, String> {
        let mut host = AgilexHost::new(bus, config);
        host.enable().map_err(|e| e.to_string())?;
        Ok(Self { host })
    }

    /// The host side (its counters, the bus).
    pub fn host(&self) -> &AgilexHost<B> {
        &self.host
    }

    /// The host side, mutably.
    pub fn host_mut(&mut self) -> &mut AgilexHost<B> {
        &mut self.host
    }
}

impl<B: CanBus> BaseHardware for CanBase<B> {
    fn poll(&mut self, now_ns: u64) -> Result<Option<BaseState>, String> {
        let motions = self.host.poll(now_ns).map_err(|e| e.to_string())?;
        let o = self.host.odometry();
        Ok((motions > 0).then_some(BaseState {
            x: o.x,
            y: o.y,
            yaw: o.yaw,
            v: o.v,
            omega: o.omega,
        }))
    }

    fn drive(&mut self, v: f64, omega: f64) -> Result<(), String> {
        self.host.command(v, omega).map_err(|e| e.to_string())
    }

    fn safe_stop(&mut self) -> Result<(), String> {
        self.host.command(0.0, 0.0).map_err(|e| e.to_string())
    }

    fn fault(&self, now_ns: u64) -> Option<String> {
        match self.host.fault(now_ns)? {
            // Staleness is the loop's own check, with its own limit.
            HostFault::NoFeedback => None,
            other => Some(format!("{other:?}")),
        }
    }
}
