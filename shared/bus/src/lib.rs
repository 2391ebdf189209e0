//! iceoryx2 glue for the motm processes: a per-process [`Bus`] (one iceoryx2 node), typed
//! [`Publisher`]/[`Subscriber`] ports over `motm-msgs` payloads with receive-side validation,
//! a latest-value reader ([`Latest`]), per-process heartbeats, the standard [`ServiceLoop`]
//! (periodic timer or data events on a WaitSet, cycle statistics, deadline misses, connection
//! refresh) and dead-node cleanup for supervisors.
//!
//! All ports use `ipc::Service`: they are not `Send` and stay on the thread that made them.
//!
//! A control process in a few lines:
//!
//! ```no_run
//! use motm_bus::{Bus, Flow, Latest, LoopConfig, Publisher, Qos, ServiceLoop};
//! use motm_msgs::{ArmVelocityCommand, JointState, Message, services};
//!
//! # fn main() -> Result<(), motm_bus::BusError> {
//! let bus = Bus::open("qp-resolver")?; // prefix from $MOTM_IPC_PREFIX
//! let mut joints = Latest::<JointState>::new(&bus, services::ARM_JOINT_STATE, &Qos::default())?;
//! let mut command =
//!     Publisher::<ArmVelocityCommand>::new(&bus, services::ARM_VELOCITY_COMMAND, &Qos::default())?;
//! let mut service = ServiceLoop::new(&bus, LoopConfig::with_rate(200.0))?;
//! service.run_periodic(|_cycle| {
//!     joints.update().ok();
//!     if let Some(state) = joints.get() {
//!         let mut out = ArmVelocityCommand::zeroed();
//!         out.joint_count = state.joint_count;
//!         command.publish(out).ok(); // a pure step function computes `out`
//!     }
//!     Flow::Continue
//! })?; // returns on SIGTERM/SIGINT; dropping the ports and the bus cleans up
//! # Ok(())
//! # }
//! ```

mod cleanup;
mod clock;
mod heartbeat;
pub mod inject;
mod ports;
mod process;
mod say;
mod service_loop;
mod stats;
mod systemd;
pub mod termination;
mod tick;

pub use cleanup::{
    CleanupReport, cleanup_dead_nodes, live_nodes, remove_domain, shared_memory_entries,
};
pub use clock::monotonic_now_ns;
pub use heartbeat::HeartbeatPublisher;
pub use ports::{Latest, Publisher, Qos, Received, Stamp, Subscriber, Trigger};
pub use process::OwnedProcess;
pub use say::say_line;
pub use service_loop::{CycleContext, Flow, LoopConfig, LoopExit, ServiceLoop};
pub use stats::{CycleStats, percentile};
pub use systemd::SystemdNotifier;
pub use tick::{PeriodicTimer, TICK_SOURCE_ENV, TickSource};

use std::cell::{Cell, RefCell};
use std::rc::{Rc, Weak};

use iceoryx2::prelude::*;

/// Environment variable that sets the iceoryx2 resource prefix ([`IpcConfig::prefix`]).
pub const PREFIX_ENV: &str = "MOTM_IPC_PREFIX";

/// The iceoryx2 resource prefix of the stack that systemd runs on a robot (`deploy/`: the
/// units set [`PREFIX_ENV`] to it); `motm status` looks there when no `motm run` is going on.
pub const DEPLOYED_PREFIX: &str = "motm_";

/// The iceoryx2 resource prefix used when [`PREFIX_ENV`] is not set (iceoryx2's own default).
pub const DEFAULT_PREFIX: &str = "iox2_";

/// Errors of the bus layer; each names the service or port it concerns.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// The resource prefix is not a valid file name part.
    #[error("invalid iceoryx2 prefix '{prefix}': {detail}")]
    InvalidPrefix {
        /// The rejected prefix.
        prefix: String,
        /// Why it was rejected.
        detail: String,
    },
    /// A node, service or port name is not valid for iceoryx2.
    #[error("invalid name '{name}': {detail}")]
    InvalidName {
        /// The rejected name.
        name: String,
        /// Why it was rejected.
        detail: String,
    },
    /// The iceoryx2 node could not be created.
    #[error("cannot create iceoryx2 node '{process}': {detail}")]
    Node {
        /// Process (node) name.
        process: String,
        /// iceoryx2 failure.
        detail: String,
    },
    /// A service could not be opened or created. `IncompatibleTypes` here means that another
    /// process uses other payload types on this name (a schema mismatch).
    #[error("cannot open service '{service}': {detail}")]
    Service {
        /// Service name.
        service: String,
        /// iceoryx2 failure.
        detail: String,
    },
    /// A port (publisher, subscriber, notifier, listener) failed.
    #[error("port on service '{service}' failed: {detail}")]
    Port {
        /// Service name.
        service: String,
        /// iceoryx2 failure.
        detail: String,
    },
    /// The WaitSet failed.
    #[error("service loop failed: {0}")]
    Loop(String),
    /// The iceoryx2 config file could not be read.
    #[error("{file}: cannot read the iceoryx2 config: {detail}")]
    Config {
        /// The file.
        file: String,
        /// Why.
        detail: String,
    },
}

/// Which set of iceoryx2 resources a process uses. Processes with different prefixes never see
/// each other; tests and benchmarks use a unique prefix so they can run beside a live stack and
/// check that they leave nothing behind.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IpcConfig {
    /// Prefix of every iceoryx2 file (shared memory, sockets, node and service records).
    pub prefix: String,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.to_owned(),
        }
    }
}

impl IpcConfig {
    /// The prefix from [`PREFIX_ENV`], or [`DEFAULT_PREFIX`].
    pub fn from_env() -> Self {
        Self {
            prefix: std::env::var(PREFIX_ENV).unwrap_or_else(|_| DEFAULT_PREFIX.to_owned()),
        }
    }

    /// The iceoryx2 configuration with this prefix: the file named by
    /// [`ICEORYX2_CONFIG_ENV`] when set, else iceoryx2's global one (which is read from
    /// `./config/iceoryx2.toml`, the user's or the system's iceoryx2 config when present).
    pub fn iceoryx2(&self) -> Result<Config, BusError> {
        let file = std::env::var_os(ICEORYX2_CONFIG_ENV).map(std::path::PathBuf::from);
        self.iceoryx2_from(file.as_deref())
    }

    /// The iceoryx2 configuration with this prefix, read from `file` (`None`: the global one).
    pub fn iceoryx2_from(&self, file: Option<&std::path::Path>) -> Result<Config, BusError> {
        let mut config = match file {
            Some(path) => load_iceoryx2_config(path)?,
            None => Config::global_config().clone(),
        };
        config.global.prefix =
            FileName::new(self.prefix.as_bytes()).map_err(|e| BusError::InvalidPrefix {
                prefix: self.prefix.clone(),
                detail: format!("{e:?}"),
            })?;
        Ok(config)
    }

    /// The prefix that stands for another host beside this one (`<prefix>remote_`): the
    /// processes that `motm run --remote` runs as if on another host, behind a zenoh bridge.
    /// Its files start with this prefix, so a check for leftovers of this prefix covers it.
    pub fn remote(&self) -> Self {
        Self {
            prefix: format!("{}remote_", self.prefix),
        }
    }

    /// Whether the publish-subscribe service `name` exists under this prefix.
    pub fn service_exists(&self, name: &str) -> Result<bool, BusError> {
        use iceoryx2::service::Service;
        let config = self.iceoryx2()?;
        ipc::Service::does_exist(
            &Bus::service_name(name)?,
            &config,
            iceoryx2::service::messaging_pattern::MessagingPattern::PublishSubscribe,
        )
        .map_err(|e| BusError::Service {
            service: name.to_owned(),
            detail: e.to_string(),
        })
    }
}

/// Environment variable naming the iceoryx2 config file every process of a stack reads (see
/// `config/iceoryx2.toml`); without it iceoryx2's own lookup applies.
pub const ICEORYX2_CONFIG_ENV: &str = "MOTM_ICEORYX2_CONFIG";

/// Reads an iceoryx2 config file; the error names the file.
fn load_iceoryx2_config(path: &std::path::Path) -> Result<Config, BusError> {
    let error = |detail: String| BusError::Config {
        file: path.display().to_string(),
        detail,
    };
    let name = FilePath::new(path.as_os_str().as_encoded_bytes())
        .map_err(|e| error(format!("not a valid file path: {e:?}")))?;
    Config::from_file(&name).map_err(|e| error(e.to_string()))
}

/// Something whose connections to remote ports can be refreshed.
trait Connectable {
    /// Connects to ports that appeared (or reappeared after a restart) since the last call.
    fn refresh(&self);
}

/// State shared between a [`Bus`] and the ports made from it.
#[derive(Default)]
struct BusShared {
    /// Ports to refresh in [`Bus::update_connections`]; dropped ports fall out.
    ports: RefCell<Vec<Weak<dyn Connectable>>>,
    /// Received messages dropped by validation, over all subscribers.
    rejected: Cell<u64>,
}

/// One process's attachment to the bus: its iceoryx2 node plus bookkeeping for its ports.
pub struct Bus {
    node: Node<ipc::Service>,
    process: String,
    ipc: IpcConfig,
    shared: Rc<BusShared>,
}

impl Bus {
    /// Creates the node of process `process` with the prefix from the environment
    /// ([`IpcConfig::from_env`]). Creating a node also cleans up resources of dead nodes.
    pub fn open(process: &str) -> Result<Self, BusError> {
        Self::open_with(process, &IpcConfig::from_env())
    }

    /// Creates the node of process `process` with an explicit configuration.
    pub fn open_with(process: &str, ipc: &IpcConfig) -> Result<Self, BusError> {
        let name = NodeName::new(process).map_err(|e| BusError::InvalidName {
            name: process.to_owned(),
            detail: format!("{e:?}"),
        })?;
        termination::install();
        let node = NodeBuilder::new()
            .name(&name)
            .config(&ipc.iceoryx2()?)
            // The service loop wakes on SIGINT/SIGTERM through its WaitSet and reads
            // `termination::termination_requested`.
            .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
            .create::<ipc::Service>()
            .map_err(|e| BusError::Node {
                process: process.to_owned(),
                detail: e.to_string(),
            })?;
        Ok(Self {
            node,
            process: process.to_owned(),
            ipc: ipc.clone(),
            shared: Rc::default(),
        })
    }

    /// The process (node) name.
    pub fn process(&self) -> &str {
        &self.process
    }

    /// The configuration this bus was opened with.
    pub fn ipc_config(&self) -> &IpcConfig {
        &self.ipc
    }

    /// The underlying iceoryx2 node, for patterns this crate does not wrap.
    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    /// Received messages dropped by validation so far, over all subscribers of this bus.
    pub fn rejected_messages(&self) -> u64 {
        self.shared.rejected.get()
    }

    /// Refreshes the connections of every live port of this bus, so that peers that started
    /// or restarted since are connected (and new subscribers get their history). The service
    /// loop calls this periodically.
    pub fn update_connections(&self) {
        let mut ports = self.shared.ports.borrow_mut();
        ports.retain(|port| match port.upgrade() {
            Some(port) => {
                port.refresh();
                true
            }
            None => false,
        });
    }

    /// Removes the resources of dead nodes (processes that died without cleaning up) from
    /// every service; returns how many were cleaned and how many could not be.
    pub fn try_cleanup_dead_nodes(&self) -> CleanupReport {
        let state = self.node.try_cleanup_dead_nodes();
        CleanupReport {
            cleaned: state.cleanups,
            failed: state.failed_cleanups,
        }
    }

    /// Registers a port for [`Bus::update_connections`].
    fn register(&self, port: Weak<dyn Connectable>) {
        self.shared.ports.borrow_mut().push(port);
    }

    /// Parses a service name.
    fn service_name(name: &str) -> Result<ServiceName, BusError> {
        ServiceName::new(name).map_err(|e| BusError::InvalidName {
            name: name.to_owned(),
            detail: format!("{e:?}"),
        })
    }
}
