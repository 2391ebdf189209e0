//! The generic main of a control service: parse the common [`ServiceArgs`] and the service's
//! own flags, load the setup, build the task and run it with `motm-runtime` until SIGTERM.
//! Bad input (a flag, file or value) exits with code 2 and a message naming it; a failure at
//! run time (the bus) with code 1.

use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, Command, FromArgMatches};
use motm_bus::LoopConfig;
use motm_graph::{Task, TaskSpec};

use crate::{ServiceArgs, ServiceSetup};

/// Exit code for bad input.
pub const EXIT_BAD_INPUT: u8 = 2;

/// A service without flags of its own.
#[derive(Debug, Clone, Args)]
pub struct NoFlags {}

/// Parses the command line of process `name` into `A` (usage errors exit with code 2, help
/// with 0).
pub fn parse<A: Args>(name: &'static str, about: &'static str) -> A {
    let matches = A::augment_args(Command::new(name).about(about)).get_matches();
    A::from_arg_matches(&matches).unwrap_or_else(|e| e.exit())
}

/// A control service: the task row it runs and how its loop is timed.
#[derive(Debug, Clone, Copy)]
pub struct Service {
    spec: &'static TaskSpec,
    about: &'static str,
    deadline: Option<Duration>,
}

impl Service {
    /// The service running the task of row `spec`, described by `about` in `--help`.
    pub fn new(spec: &'static TaskSpec, about: &'static str) -> Self {
        Self {
            spec,
            about,
            deadline: None,
        }
    }

    /// A deadline longer than one period (a cycle with a camera image takes longer than one
    /// without).
    pub fn deadline(self, deadline: Duration) -> Self {
        Self {
            deadline: Some(deadline),
            ..self
        }
    }

    /// Parses [`ServiceArgs`] and the flags `E`, loads the setup, builds the task with
    /// `build` (its error is bad input) and runs it at `--rate`; `details` adds the task's
    /// own counts to the closing line.
    pub fn run<E: Args, T: Task>(
        self,
        build: impl FnOnce(&ServiceSetup, E) -> Result<T, String>,
        details: impl FnOnce(&T) -> String,
    ) -> ExitCode {
        let name = self.spec.name;
        let matches = E::augment_args(ServiceArgs::augment_args(
            Command::new(name).about(self.about),
        ))
        .get_matches();
        let common = ServiceArgs::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
        let extra = E::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
        let built = ServiceSetup::load(&common).and_then(|setup| {
            let task = build(&setup, extra)?;
            Ok((setup, task))
        });
        let (setup, mut task) = match built {
            Ok(built) => built,
            Err(e) => {
                motm_bus::say!("{name}: {e}");
                return ExitCode::from(EXIT_BAD_INPUT);
            }
        };
        let period = setup.period();
        let config = LoopConfig {
            deadline: self.deadline.map(|d| d.max(period)),
            ..LoopConfig::with_rate(setup.rate_hz)
        };
        motm_runtime::serve(self.spec, &mut task, config, details)
    }
}

/// Checks that a flag's value is finite and positive.
pub fn positive(flag: &str, value: f64) -> Result<f64, String> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(format!("{flag}: must be positive, got {value}"))
    }
}
