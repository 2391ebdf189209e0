//! `motm swap PROCESS VARIANT`: hot-swaps a controller process of a running stack. It sends a
//! `SwapRequest` to the supervisor on the bus and waits for the supervisor's `SwapStatus`
//! (see `motm_supervisor::swap` for the sequence); `motm run --swap` uses the same client.

use std::time::{Duration, Instant};

use clap::Args;
use motm_bus::{Bus, BusError, IpcConfig, Publisher, Qos, Subscriber};
use motm_core::final_phase::FinalPhaseKind;
use motm_msgs::{
    Message, SwapFailureCode, SwapRequest, SwapStageCode, SwapStatus, SwappableProcess, services,
};
use motm_supervisor::swap::variant_of;
use serde::Serialize;

use crate::CliError;
use crate::status::stack_prefix;

/// Arguments of `motm swap`.
#[derive(Args, Debug)]
pub struct SwapArgs {
    /// Process to replace (`final-phase`).
    pub process: String,
    /// Variant of the new controller: grasp, drop or press-button.
    pub variant: String,
    /// iceoryx2 prefix of the stack (default: $MOTM_IPC_PREFIX, else the one running `motm run`).
    #[arg(long)]
    pub prefix: Option<String>,
    /// Longest wait for the new controller's first command, ms (default: the stack's
    /// `hot_swap.command_timeout_ms`). A fixed variant commands only tasks of its kind.
    #[arg(long)]
    pub command_timeout_ms: Option<u64>,
    /// Give up waiting for the supervisor's answer after this long, s.
    #[arg(long, default_value_t = 60.0)]
    pub timeout: f64,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// What a swap did, as `motm swap --json` and `motm run --json` (`swaps`) print it.
#[derive(Debug, Clone, Serialize)]
pub struct SwapReport {
    /// Process replaced.
    pub process: String,
    /// Variant of the new controller.
    pub variant: String,
    /// `done`, `failed`, `pending` (no final answer yet) or `not_sent` (the run ended first).
    pub outcome: String,
    /// Why it failed (`None` unless failed).
    pub failure: Option<String>,
    /// When the request was sent, s after the start of `motm run` (0 for `motm swap`).
    pub requested_at_s: f64,
    /// Pid of the replaced process.
    pub old_pid: u32,
    /// Pid of the new process.
    pub new_pid: u32,
    /// Controller id of the replaced process.
    pub old_controller_id: u32,
    /// Controller id of the new process.
    pub new_controller_id: u32,
    /// From starting the new process to its first `Running` heartbeat, ms.
    pub heartbeat_wait_ms: f64,
    /// From starting the new process to its first command, ms.
    pub command_wait_ms: f64,
    /// The gap the swap made in the command stream, ms: the longer of the old controller's
    /// last command → flip and flip → the new one's first command (under one control period).
    pub command_gap_ms: f64,
    /// Old controller's last command before the flip to the new one's first after it, ms.
    pub stamp_gap_ms: f64,
    /// Base forward speed at the flip, m/s.
    pub base_speed: f64,
}

/// Parses `final-phase` and a variant name; errors are bad input.
pub fn parse_target(
    process: &str,
    variant: &str,
) -> Result<(SwappableProcess, FinalPhaseKind), CliError> {
    let p = SwappableProcess::from_name(process).ok_or_else(|| {
        CliError::BadInput(format!(
            "cannot swap '{process}': only {} can be hot-swapped",
            SwappableProcess::FinalPhase.name()
        ))
    })?;
    let kind = variant.parse::<FinalPhaseKind>().map_err(|_| {
        CliError::BadInput(format!(
            "unknown variant '{variant}' for {process}: expected one of {}",
            FinalPhaseKind::ALL.map(FinalPhaseKind::name).join(", ")
        ))
    })?;
    Ok((p, kind))
}

/// One swap request on the bus and the supervisor's answers to it.
pub struct SwapClient {
    process: SwappableProcess,
    kind: FinalPhaseKind,
    request_id: u64,
    command_timeout_ms: u64,
    requests: Publisher<SwapRequest>,
    answers: Subscriber<SwapStatus>,
    requested_at_s: Option<f64>,
    last: Option<SwapStatus>,
}

impl SwapClient {
    /// Opens the ports on `bus` for one request (`command_timeout_ms` 0: the stack's default).
    pub fn new(
        bus: &Bus,
        process: SwappableProcess,
        kind: FinalPhaseKind,
        command_timeout_ms: u64,
    ) -> Result<Self, BusError> {
        static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(1);
        let serial = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let qos = Qos::default();
        Ok(Self {
            process,
            kind,
            request_id: (u64::from(std::process::id()) << 32) | u64::from(serial),
            command_timeout_ms,
            requests: Publisher::new(bus, services::SUPERVISOR_SWAP_REQUEST, &qos)?,
            answers: Subscriber::new(bus, services::SUPERVISOR_SWAP_STATUS, &qos)?,
            requested_at_s: None,
            last: None,
        })
    }

    /// Sends the request; `at_s` is recorded in the report.
    pub fn send(&mut self, at_s: f64) -> Result<(), BusError> {
        let mut request = SwapRequest::zeroed();
        request.request_id = self.request_id;
        request.process = self.process.into();
        request.variant = variant_of(self.kind).into();
        request.command_timeout_ms = self.command_timeout_ms;
        self.requests.update_connections();
        self.requests.publish(request)?;
        self.requested_at_s = Some(at_s);
        Ok(())
    }

    /// Whether the request was sent.
    pub fn sent(&self) -> bool {
        self.requested_at_s.is_some()
    }

    /// Takes in the supervisor's answers; returns whether the swap is over.
    pub fn update(&mut self) -> bool {
        while let Ok(Some(status)) = self.answers.receive() {
            if status.request_id == self.request_id {
                self.last = Some(*status);
            }
        }
        self.last.is_some_and(|s| s.is_final())
    }

    /// The report so far.
    pub fn report(&self) -> SwapReport {
        let ms = |ns: u64| ns as f64 / 1e6;
        let s = self.last.unwrap_or_else(SwapStatus::zeroed);
        let outcome = match (self.sent(), self.last.and_then(|s| s.stage())) {
            (false, _) => "not_sent",
            (true, Some(SwapStageCode::Done)) => "done",
            (true, Some(SwapStageCode::Failed)) => "failed",
            (true, _) => "pending",
        };
        SwapReport {
            process: self.process.name().into(),
            variant: self.kind.name().into(),
            outcome: outcome.into(),
            failure: self
                .last
                .and_then(|s| s.failure())
                .filter(|f| *f != SwapFailureCode::None)
                .map(|f| format!("{f:?}")),
            requested_at_s: self.requested_at_s.unwrap_or(0.0),
            old_pid: s.old_pid,
            new_pid: s.new_pid,
            old_controller_id: s.old_controller_id,
            new_controller_id: s.new_controller_id,
            heartbeat_wait_ms: ms(s.heartbeat_wait_ns),
            command_wait_ms: ms(s.command_wait_ns),
            command_gap_ms: ms(s.command_gap_ns),
            stamp_gap_ms: ms(s.stamp_gap_ns),
            base_speed: s.base_speed,
        }
    }
}

/// `motm swap`.
pub fn run(args: &SwapArgs) -> Result<(), CliError> {
    let (process, kind) = parse_target(&args.process, &args.variant)?;
    if !(args.timeout.is_finite() && args.timeout > 0.0) {
        return Err(CliError::BadInput(format!(
            "--timeout must be a finite number > 0, got {}",
            args.timeout
        )));
    }
    let ipc = IpcConfig {
        prefix: stack_prefix(args.prefix.clone())?,
    };
    let failed = |e: BusError| CliError::Failed(e.to_string());
    let bus = Bus::open_with(&format!("motm-swap-{}", std::process::id()), &ipc).map_err(failed)?;
    let mut client = SwapClient::new(&bus, process, kind, args.command_timeout_ms.unwrap_or(0))
        .map_err(failed)?;
    client.send(0.0).map_err(failed)?;
    let start = Instant::now();
    let wait = Duration::from_secs_f64(args.timeout);
    // A one-shot client: poll for the supervisor's answer.
    while !client.update() && start.elapsed() < wait {
        bus.update_connections();
        std::thread::sleep(Duration::from_millis(10));
    }
    let report = client.report();
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| CliError::Failed(e.to_string()))?
        );
    } else {
        println!(
            "swap {} -> {}: {}{}",
            report.process,
            report.variant,
            report.outcome,
            report
                .failure
                .as_ref()
                .map_or_else(String::new, |f| format!(" ({f})"))
        );
        println!(
            "pid {} (controller id {}) -> pid {} (controller id {}); heartbeat after {:.0} ms, first command after {:.0} ms; command gap {:.2} ms",
            report.old_pid,
            report.old_controller_id,
            report.new_pid,
            report.new_controller_id,
            report.heartbeat_wait_ms,
            report.command_wait_ms,
            report.command_gap_ms
        );
    }
    match report.outcome.as_str() {
        "done" => Ok(()),
        "pending" | "not_sent" => Err(CliError::Failed(format!(
            "no final answer from the supervisor on prefix {} within {} s",
            ipc.prefix, args.timeout
        ))),
        _ => Err(CliError::Failed(format!(
            "swap failed: {}",
            report.failure.unwrap_or_default()
        ))),
    }
}

/// A `--swap PROCESS:VARIANT@SECONDS` plan of `motm run`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SwapPlan {
    /// Process to replace.
    pub process: SwappableProcess,
    /// New variant.
    pub kind: FinalPhaseKind,
    /// When to send the request, s after the stack started.
    pub at_s: f64,
}

/// Parses `PROCESS:VARIANT@SECONDS` (e.g. `final-phase:press-button@12.5`).
pub fn parse_plan(text: &str) -> Result<SwapPlan, CliError> {
    let bad = |why: &str| {
        CliError::BadInput(format!(
            "--swap '{text}': {why}; expected PROCESS:VARIANT@SECONDS, e.g. final-phase:press-button@12"
        ))
    };
    let (target, at) = text.split_once('@').ok_or_else(|| bad("no '@SECONDS'"))?;
    let (process, variant) = target.split_once(':').ok_or_else(|| bad("no ':VARIANT'"))?;
    let at_s: f64 = at.parse().map_err(|_| bad("SECONDS is not a number"))?;
    if !(at_s.is_finite() && at_s >= 0.0) {
        return Err(bad("SECONDS must be a finite number >= 0"));
    }
    let (process, kind) = parse_target(process, variant)?;
    Ok(SwapPlan {
        process,
        kind,
        at_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn swap_plans_parse_and_bad_ones_say_why() {
        let plan = parse_plan("final-phase:press-button@12.5").unwrap();
        assert_eq!(plan.process, SwappableProcess::FinalPhase);
        assert_eq!(plan.kind, FinalPhaseKind::PressButton);
        assert_eq!(plan.at_s, 12.5);
        for (text, needle) in [
            ("final-phase:press-button", "@SECONDS"),
            ("final-phase@3", ":VARIANT"),
            ("final-phase:push@3", "unknown variant 'push'"),
            ("reacher:grasp@3", "only final-phase"),
            ("final-phase:grasp@-1", ">= 0"),
            ("final-phase:grasp@soon", "not a number"),
        ] {
            let err = parse_plan(text).unwrap_err();
            assert_eq!(err.exit_code(), crate::EXIT_BAD_INPUT, "{text}");
            assert!(err.to_string().contains(needle), "{text}: {err}");
        }
    }
}
