//! A fake AgileX base on a bus (normally one end of a [`MemoryBus`](crate::MemoryBus)): it
//! starts in standby and ignores 0x111 until 0x421 puts it in CAN mode, stops when no 0x111
//! came for 500 ms, and sends 0x221 and 0x311 every 20 ms and 0x211 every 100 ms. It tracks
//! the commanded velocity within its acceleration limits and integrates the wheel distances
//! of a differential drive. Time is passed in ([`FakeBase::step`]), so tests run on a
//! simulated clock; [`FakeBase::spawn`] runs it on the real clock in a thread.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::bus::{CanBus, CanBusError};
use crate::frame::{CLEAR_FAULTS, CONTROL_MODE, MOTION_COMMAND, MOTION_STATE};
use crate::protocol::{ControlMode, Motion, SystemState, VehicleState, WheelOdometry};

/// Settings of a [`FakeBase`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FakeBaseConfig {
    /// The base stops this long after the last motion command, s (0.5).
    pub command_timeout: f64,
    /// Track width of the wheel odometry, m.
    pub track_width: f64,
    /// Largest |linear| accepted, m/s (beyond: clamped and counted).
    pub max_linear: f64,
    /// Largest |angular| accepted, rad/s.
    pub max_angular: f64,
    /// Linear acceleration, m/s².
    pub linear_acceleration: f64,
    /// Angular acceleration, rad/s².
    pub angular_acceleration: f64,
    /// Motion state and odometry period, s (0.02).
    pub motion_period: f64,
    /// System state period, s (0.1; Tracer 0.02).
    pub system_period: f64,
    /// Battery voltage reported, V.
    pub battery_v: f64,
}

impl Default for FakeBaseConfig {
    fn default() -> Self {
        // Scout 2.0-like.
        Self {
            command_timeout: 0.5,
            track_width: 0.58,
            max_linear: 1.5,
            max_angular: 2.0,
            linear_acceleration: 1.5,
            angular_acceleration: 3.0,
            motion_period: 0.02,
            system_period: 0.1,
            battery_v: 26.4,
        }
    }
}

/// Counts of a [`FakeBase`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FakeBaseCounters {
    /// Motion commands followed.
    pub commands_accepted: u64,
    /// Motion commands ignored (standby or e-stop).
    pub commands_ignored: u64,
    /// Commands beyond the speed limits (clamped).
    pub limit_violations: u64,
    /// Times the base stopped because commands stopped coming.
    pub command_timeouts: u64,
    /// Frames with another ID or a bad length.
    pub other_frames: u64,
}

/// The fake base.
#[derive(Debug)]
pub struct FakeBase<B> {
    bus: B,
    config: FakeBaseConfig,
    mode: ControlMode,
    estop: bool,
    target: (f64, f64),
    velocity: (f64, f64),
    last_command_ns: Option<u64>,
    timed_out: bool,
    left_m: f64,
    right_m: f64,
    last_step_ns: Option<u64>,
    next_motion_ns: u64,
    next_system_ns: u64,
    count: u8,
    counters: FakeBaseCounters,
}

impl<B: CanBus> FakeBase<B> {
    /// A base in standby on `bus`.
    pub fn new(bus: B, config: FakeBaseConfig) -> Self {
        Self {
            bus,
            config,
            mode: ControlMode::Standby,
            estop: false,
            target: (0.0, 0.0),
            velocity: (0.0, 0.0),
            last_command_ns: None,
            timed_out: false,
            left_m: 0.0,
            right_m: 0.0,
            last_step_ns: None,
            next_motion_ns: 0,
            next_system_ns: 0,
            count: 0,
            counters: FakeBaseCounters::default(),
        }
    }

    /// Presses (`true`) or releases the e-stop: pressed, the base stops and ignores commands.
    pub fn set_estop(&mut self, pressed: bool) {
        self.estop = pressed;
    }

    /// The velocity `(v, ω)` the base moves at.
    pub fn velocity(&self) -> (f64, f64) {
        self.velocity
    }

    /// The control mode.
    pub fn mode(&self) -> ControlMode {
        self.mode
    }

    /// Wheel distances travelled, m (left, right).
    pub fn wheels(&self) -> (f64, f64) {
        (self.left_m, self.right_m)
    }

    /// Counters.
    pub fn counters(&self) -> FakeBaseCounters {
        self.counters
    }

    /// One step at `now_ns`: reads the frames that arrived, applies the timeout, moves, and
    /// sends the feedback that is due.
    pub fn step(&mut self, now_ns: u64) -> Result<(), CanBusError> {
        while let Some(f) = self.bus.receive(Duration::ZERO)? {
            match (f.id, f.len) {
                (CONTROL_MODE, 1..) => {
                    if f.data[0] == 0x01 {
                        self.mode = ControlMode::Can;
                    }
                }
                (MOTION_COMMAND, 8) if self.mode == ControlMode::Can && !self.estop => {
                    let m = Motion::from_frame(&f)?;
                    let (v, w) = (m.linear, m.angular);
                    let vc = v.clamp(-self.config.max_linear, self.config.max_linear);
                    let wc = w.clamp(-self.config.max_angular, self.config.max_angular);
                    self.counters.limit_violations += u64::from(vc != v || wc != w);
                    self.target = (vc, wc);
                    self.last_command_ns = Some(now_ns);
                    self.timed_out = false;
                    self.counters.commands_accepted += 1;
                }
                (MOTION_COMMAND, 8) => self.counters.commands_ignored += 1,
                (CLEAR_FAULTS, _) => {}
                _ => self.counters.other_frames += 1,
            }
        }
        let timeout_ns = (self.config.command_timeout * 1e9) as u64;
        let expired = self
            .last_command_ns
            .is_some_and(|t| now_ns.saturating_sub(t) > timeout_ns);
        if (expired || self.estop) && self.target != (0.0, 0.0) {
            self.target = (0.0, 0.0);
        }
        if expired && !self.timed_out {
            self.timed_out = true;
            self.counters.command_timeouts += 1;
        }
        let dt = self
            .last_step_ns
            .map_or(0.0, |t| now_ns.saturating_sub(t) as f64 * 1e-9);
        self.last_step_ns = Some(now_ns);
        let toward = |x: f64, target: f64, rate: f64| {
            if self.estop {
                return 0.0;
            }
            x + (target - x).clamp(-rate * dt, rate * dt)
        };
        let v = toward(
            self.velocity.0,
            self.target.0,
            self.config.linear_acceleration,
        );
        let w = toward(
            self.velocity.1,
            self.target.1,
            self.config.angular_acceleration,
        );
        self.velocity = (v, w);
        let half = 0.5 * self.config.track_width * w;
        self.left_m += (v - half) * dt;
        self.right_m += (v + half) * dt;
        if now_ns >= self.next_motion_ns {
            self.next_motion_ns = now_ns + (self.config.motion_period * 1e9) as u64;
            let motion = Motion {
                linear: v,
                angular: w,
                ..Motion::default()
            };
            self.bus.send(&motion.to_frame(MOTION_STATE).0)?;
            let mm = |m: f64| (m * 1e3).round() as i32;
            self.bus.send(
                &WheelOdometry {
                    left_mm: mm(self.left_m),
                    right_mm: mm(self.right_m),
                }
                .to_frame(),
            )?;
        }
        if now_ns >= self.next_system_ns {
            self.next_system_ns = now_ns + (self.config.system_period * 1e9) as u64;
            self.count = self.count.wrapping_add(1);
            let state = SystemState {
                vehicle: if self.estop {
                    VehicleState::EStop
                } else {
                    VehicleState::Normal
                },
                mode: self.mode,
                battery_v: self.config.battery_v,
                error_code: 0,
                count: self.count,
            };
            self.bus.send(&state.to_frame())?;
        }
        Ok(())
    }
}

/// A fake base running in its own thread on the real clock.
#[derive(Debug)]
pub struct FakeBaseHandle {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<FakeBaseCounters, CanBusError>>>,
}

impl FakeBaseHandle {
    /// Stops the thread and returns the base's counters.
    pub fn stop(mut self) -> Result<FakeBaseCounters, CanBusError> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread
            .take()
            .expect("joined once")
            .join()
            .unwrap_or(Err(CanBusError::Disconnected))
    }
}

impl Drop for FakeBaseHandle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl<B: CanBus + Send + 'static> FakeBase<B> {
    /// Runs the base in a thread, stepping every `period` on the monotonic clock, until the
    /// handle is stopped or the bus's other end is gone.
    pub fn spawn(mut self, period: Duration) -> FakeBaseHandle {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let origin = Instant::now();
            while !flag.load(Ordering::Relaxed) {
                self.step(origin.elapsed().as_nanos() as u64)?;
                std::thread::sleep(period);
            }
            Ok(self.counters)
        });
        FakeBaseHandle {
            stop,
            thread: Some(thread),
        }
    }
}
