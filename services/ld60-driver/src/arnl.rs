//! The LD-60 backend: ratioDrive over ArNetworking (percentages from the configured top
//! speeds), odometry from updateNumbers, `stop` for a safe stop, and the e-stop lines of ARCL
//! (watched in a thread; ARCL is optional: the drive path does not need it).
//!
//! A dropped ArNetworking connection is a hardware error (the base loop holds the base
//! stopped); the backend then connects again, at most once per [`RECONNECT_EVERY`], with the
//! whole handshake (introduction, TCP_ONLY, LIST). Once odometry flows again the loop resumes
//! from rest.

use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use motm_omron::{ArClient, ArclClient, ArclLine, ClientConfig, DriveLimits, Event, RatioDrive};

use crate::base::{BaseHardware, BaseState};
use crate::config::ArnlConfig;

/// Shortest time between two connection attempts after the connection dropped.
pub const RECONNECT_EVERY: Duration = Duration::from_millis(500);

/// An LD-60 over ArNetworking.
#[derive(Debug)]
pub struct ArnlBase {
    client: Option<ArClient>,
    /// Where and how to connect again (none: never reconnect).
    reconnect: Option<(SocketAddr, ClientConfig)>,
    last_attempt: Option<Instant>,
    limits: DriveLimits,
    estop: Arc<AtomicBool>,
    /// Commands beyond the base's reach (sent saturated).
    pub saturated_commands: u64,
    /// Connections made again after a drop.
    pub reconnects: u64,
}

impl ArnlBase {
    /// A base on a connected client, with the ratio-drive scaling `limits`; it does not
    /// reconnect.
    pub fn new(client: ArClient, limits: DriveLimits) -> Self {
        Self {
            client: Some(client),
            reconnect: None,
            last_attempt: None,
            limits,
            estop: Arc::new(AtomicBool::new(false)),
            saturated_commands: 0,
            reconnects: 0,
        }
    }

    /// Connects to the LD-60 at `addr` with `config`; the base reconnects there after a
    /// dropped connection.
    pub fn connect(
        addr: SocketAddr,
        config: ClientConfig,
        limits: DriveLimits,
    ) -> Result<Self, String> {
        let client = ArClient::connect(addr, &config).map_err(|e| e.to_string())?;
        let mut base = Self::new(client, limits);
        base.reconnect = Some((addr, config));
        Ok(base)
    }

    /// The LD-60 of `config` at `host` (`port`, `arcl_port`: the config's unless given), with
    /// ARCL watched unless its port is 0; the first connection is awaited for up to `wait`.
    /// Errors name the address or flag.
    pub fn open(
        config: &ArnlConfig,
        host: &str,
        port: Option<u16>,
        arcl_port: Option<u16>,
        wait: Duration,
    ) -> Result<Self, String> {
        let resolve = |flag: &str, port: u16| {
            (host, port)
                .to_socket_addrs()
                .ok()
                .and_then(|mut a| a.next())
                .ok_or_else(|| format!("--host {host}: no address ({flag} {port})"))
        };
        let addr = resolve("--port", port.unwrap_or(config.port))?;
        let mut base = motm_driver::connect_within(&format!("ArNetworking {addr}"), wait, || {
            Self::connect(addr, config.client(), config.drive_limits())
        })?;
        let arcl_port = arcl_port.unwrap_or(config.arcl_port);
        if arcl_port != 0 {
            let watched = resolve("--arcl-port", arcl_port).and_then(|addr| {
                base.watch_arcl(addr, &config.arcl_password, config.client().timeout)
            });
            if let Err(e) = watched {
                motm_bus::say!("ld60-driver: ARCL not watched (e-stop lines unseen): {e}");
            }
        }
        Ok(base)
    }

    /// Whether the ArNetworking connection is up.
    pub fn connected(&self) -> bool {
        self.client.is_some()
    }

    /// The connected client, or an error.
    fn client_mut(&mut self) -> Result<&mut ArClient, String> {
        self.client
            .as_mut()
            .ok_or_else(|| "ArNetworking: not connected".to_owned())
    }

    /// After a drop: one connection attempt, unless the last was under [`RECONNECT_EVERY`]
    /// ago.
    fn try_reconnect(&mut self) -> Result<(), String> {
        let Some((addr, config)) = &self.reconnect else {
            return Err("ArNetworking: connection lost".into());
        };
        if self
            .last_attempt
            .is_some_and(|at| at.elapsed() < RECONNECT_EVERY)
        {
            return Err("ArNetworking: connection lost; reconnecting".into());
        }
        self.last_attempt = Some(Instant::now());
        match ArClient::connect(*addr, config) {
            Ok(client) => {
                motm_bus::say!("ld60-driver: ArNetworking: connected again to {addr}");
                self.client = Some(client);
                self.reconnects += 1;
                Ok(())
            }
            Err(e) => Err(format!("ArNetworking {addr}: reconnect: {e}")),
        }
    }

    /// Watches ARCL at `addr` in a thread: `EStop pressed` holds the base stopped until
    /// `EStop relieved`. A failed login is returned; a connection lost later is printed.
    pub fn watch_arcl(
        &mut self,
        addr: SocketAddr,
        password: &str,
        timeout: Duration,
    ) -> Result<(), String> {
        let mut arcl = ArclClient::connect(addr, password, timeout).map_err(|e| e.to_string())?;
        let estop = self.estop.clone();
        std::thread::spawn(move || {
            loop {
                match arcl.next_line(Duration::from_millis(200)) {
                    Ok(Some(ArclLine::EStopPressed)) => estop.store(true, Ordering::Relaxed),
                    Ok(Some(ArclLine::EStopRelieved)) => estop.store(false, Ordering::Relaxed),
                    Ok(Some(ArclLine::Error(e))) => motm_bus::say!("ld60-driver: ARCL Error: {e}"),
                    Ok(_) => {}
                    Err(e) => {
                        motm_bus::say!("ld60-driver: ARCL: {e}");
                        return;
                    }
                }
            }
        });
        Ok(())
    }

    /// The ArNetworking client (its counters), while connected.
    pub fn client(&self) -> Option<&ArClient> {
        self.client.as_ref()
    }
}

impl BaseHardware for ArnlBase {
    fn poll(&mut self, _now_ns: u64) -> Result<Option<BaseState>, String> {
        if self.client.is_none() {
            self.try_reconnect()?;
        }
        let mut newest = None;
        loop {
            let polled = self.client_mut()?.poll(Duration::ZERO);
            let lost = |base: &mut Self, e: String| {
                base.client = None;
                Err(e)
            };
            match polled {
                Ok(Some(Event::Numbers(u))) => {
                    let o = u.odometry();
                    newest = Some(BaseState {
                        x: o.x,
                        y: o.y,
                        yaw: o.yaw,
                        v: o.v,
                        omega: o.omega,
                    });
                }
                Ok(Some(Event::Shutdown)) => {
                    return lost(self, "the robot's server shuts down".into());
                }
                Ok(Some(Event::Other(_))) => {}
                Ok(None) => return Ok(newest),
                Err(e) => return lost(self, e.to_string()),
            }
        }
    }

    fn drive(&mut self, v: f64, omega: f64) -> Result<(), String> {
        let c = self.limits.ratio(v, omega);
        self.saturated_commands += u64::from(c.saturated);
        self.client_mut()?
            .ratio_drive(&c.drive)
            .map_err(|e| e.to_string())
    }

    fn safe_stop(&mut self) -> Result<(), String> {
        let client = self.client_mut()?;
        let zero = client.ratio_drive(&RatioDrive::ZERO);
        let stop = client.stop();
        zero.and(stop).map_err(|e| e.to_string())
    }

    fn fault(&self, _now_ns: u64) -> Option<String> {
        self.estop
            .load(Ordering::Relaxed)
            .then(|| "EStop pressed (ARCL)".to_owned())
    }
}
