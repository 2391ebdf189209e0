//! The LD-60 backend: ratioDrive over ArNetworking (percentages from the configured top
//! speeds), odometry from updateNumbers, `stop` for a safe stop, and the e-stop lines of ARCL
//! (watched in a thread; ARCL is optional: the drive path does not need it).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use motm_omron::{ArClient, ArclClient, ArclLine, DriveLimits, Event, RatioDrive};

use crate::base::{BaseHardware, BaseState};

/// An LD-60 over ArNetworking.
#[derive(Debug)]
pub struct ArnlBase {
    client: ArClient,
    limits: DriveLimits,
    estop: Arc<AtomicBool>,
    /// Commands beyond the base's reach (sent saturated).
    pub saturated_commands: u64,
}

impl ArnlBase {
    /// A base on a connected client, with the ratio-drive scaling `limits`.
    pub fn new(client: ArClient, limits: DriveLimits) -> Self {
        Self {
            client,
            limits,
            estop: Arc::new(AtomicBool::new(false)),
            saturated_commands: 0,
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
                    Ok(Some(ArclLine::Error(e))) => eprintln!("ld60-driver: ARCL Error: {e}"),
                    Ok(_) => {}
                    Err(e) => {
                        eprintln!("ld60-driver: ARCL: {e}");
                        return;
                    }
                }
            }
        });
        Ok(())
    }

    /// The ArNetworking client (its counters).
    pub fn client(&self) -> &ArClient {
        &self.client
    }
}

impl BaseHardware for ArnlBase {
    fn poll(&mut self, _now_ns: u64) -> Result<Option<BaseState>, String> {
        let mut newest = None;
        loop {
            match self.client.poll(Duration::ZERO) {
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
                Ok(Some(Event::Shutdown)) => return Err("the robot's server shuts down".into()),
                Ok(Some(Event::Other(_))) => {}
                Ok(None) => return Ok(newest),
                Err(e) => return Err(e.to_string()),
            }
        }
    }

    fn drive(&mut self, v: f64, omega: f64) -> Result<(), String> {
        let c = self.limits.ratio(v, omega);
        self.saturated_commands += u64::from(c.saturated);
        self.client.ratio_drive(&c.drive).map_err(|e| e.to_string())
    }

    fn safe_stop(&mut self) -> Result<(), String> {
        let zero = self.client.ratio_drive(&RatioDrive::ZERO);
        let stop = self.client.stop();
        zero.and(stop).map_err(|e| e.to_string())
    }

    fn fault(&self, _now_ns: u64) -> Option<String> {
        self.estop
            .load(Ordering::Relaxed)
            .then(|| "EStop pressed (ARCL)".to_owned())
    }
}
