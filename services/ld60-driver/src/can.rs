//! The AgileX backend: 0x421 once, 0x111 every cycle (the driver's 50 Hz matches the
//! protocol's 20 ms), odometry from 0x311 and 0x221, faults from 0x211, over any
//! [`CanBus`] (a `socketcan` socket on a robot, the in-memory bus in tests, a replayed
//! `candump -L` log).

use motm_agilex::{AgilexHost, CanBus, HostConfig, HostFault};

use crate::base::{BaseHardware, BaseState};

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
