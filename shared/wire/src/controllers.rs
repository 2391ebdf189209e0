//! [`ControllerLatest`]: the newest command per controller id
//! ([`motm_tasks::controllers::PerController`]) read from an iceoryx2 subscriber.

use motm_bus::{Bus, BusError, Qos, Subscriber};
pub use motm_tasks::controllers::{FromController, PerController};

/// Newest command per controller id on one service.
pub struct ControllerLatest<M: FromController> {
    subscriber: Subscriber<M>,
    newest: PerController<M>,
}

impl<M: FromController> ControllerLatest<M> {
    /// Creates the reader on service `name` of `bus`.
    pub fn new(bus: &Bus, name: &str, qos: &Qos) -> Result<Self, BusError> {
        Ok(Self {
            subscriber: Subscriber::new(bus, name, qos)?,
            newest: PerController::default(),
        })
    }

    /// Takes in every sample that arrived.
    pub fn update(&mut self) -> Result<(), BusError> {
        while let Some(sample) = self.subscriber.receive()? {
            self.newest.insert(*sample);
        }
        Ok(())
    }

    /// The newest command of controller `active` (of any controller while none is named).
    pub fn get(&self, active: Option<u32>) -> Option<&M> {
        self.newest.get(active)
    }
}
