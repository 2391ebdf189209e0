//! The fault schedule of `motm run --fault`: which fault to inject into the running stack, on
//! what, and when. Pure parsing and ordering; the CLI carries the faults out.
//!
//! Forms (times in seconds of the simulated task: sim-world's clock, which starts with the
//! world and runs in real time, so a fault lands at the same point of the task from run to run
//! whatever the start-up took; durations in wall-clock seconds):
//! - `kill:SERVICE@SECONDS`: SIGKILL the service's process (the supervisor restarts it).
//! - `stop:SERVICE@SECONDS+DURATION`: SIGSTOP the process (a hang), SIGCONT it `DURATION`
//!   seconds later.
//! - `nan:TOPIC@SECONDS`: publish one sample with a NaN value on the topic.
//!
//! Names are checked here only for form (non-empty, no whitespace); whether a service or topic
//! exists is the CLI's business, since it knows the stack.

use std::fmt;

/// What a fault does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// SIGKILL the process.
    Kill,
    /// SIGSTOP the process, SIGCONT it after the duration.
    Stop,
    /// Publish a NaN sample on a topic.
    Nan,
}

impl FaultKind {
    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            FaultKind::Kill => "kill",
            FaultKind::Stop => "stop",
            FaultKind::Nan => "nan",
        }
    }
}

/// One scheduled fault.
#[derive(Debug, Clone, PartialEq)]
pub struct Fault {
    /// What the fault does.
    pub kind: FaultKind,
    /// The service (kill, stop) or topic (nan) it hits.
    pub target: String,
    /// When, simulated s.
    pub at_s: f64,
    /// How long a stop lasts, s (0 for kill and nan).
    pub duration_s: f64,
}

impl Fault {
    /// When the fault is over, s on the same clock as `at_s` (a stop ends with SIGCONT).
    pub fn end_s(&self) -> f64 {
        self.at_s + self.duration_s
    }
}

/// Why a `--fault` value could not be parsed; the message quotes the value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FaultParseError {
    /// The value as given.
    pub value: String,
    /// What is wrong with it.
    pub reason: String,
}

impl fmt::Display for FaultParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "--fault {:?}: {} (expected kill:SERVICE@SECONDS, stop:SERVICE@SECONDS+DURATION or nan:TOPIC@SECONDS)",
            self.value, self.reason
        )
    }
}

impl std::error::Error for FaultParseError {}

/// Parses a finite, non-negative number of seconds named `what`.
fn seconds(text: &str, what: &str) -> Result<f64, String> {
    let value: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{what} {text:?} is not a number"))?;
    if !value.is_finite() || value < 0.0 {
        return Err(format!("{what} must be a finite number >= 0, got {text}"));
    }
    Ok(value)
}

/// Parses one `--fault` value.
pub fn parse_fault(value: &str) -> Result<Fault, FaultParseError> {
    let fail = |reason: String| FaultParseError {
        value: value.to_owned(),
        reason,
    };
    let (kind, rest) = value
        .split_once(':')
        .ok_or_else(|| fail("missing ':' after the fault kind".into()))?;
    let kind = match kind {
        "kill" => FaultKind::Kill,
        "stop" => FaultKind::Stop,
        "nan" => FaultKind::Nan,
        other => return Err(fail(format!("unknown fault kind {other:?}"))),
    };
    let (target, when) = rest
        .rsplit_once('@')
        .ok_or_else(|| fail("missing '@SECONDS'".into()))?;
    if target.is_empty() || target.chars().any(char::is_whitespace) {
        return Err(fail(format!(
            "the {} name must be non-empty without spaces",
            if kind == FaultKind::Nan {
                "topic"
            } else {
                "service"
            }
        )));
    }
    let (at, duration) = match (kind, when.split_once('+')) {
        (FaultKind::Stop, Some((at, duration))) => (at, Some(duration)),
        (FaultKind::Stop, None) => return Err(fail("a stop needs '+DURATION'".into())),
        (_, Some(_)) => return Err(fail("'+DURATION' is for stop only".into())),
        (_, None) => (when, None),
    };
    let at_s = seconds(at, "the time").map_err(fail)?;
    let duration_s = match duration {
        Some(d) => {
            let d = seconds(d, "the duration").map_err(fail)?;
            if d == 0.0 {
                return Err(fail("the duration must be > 0".into()));
            }
            d
        }
        None => 0.0,
    };
    Ok(Fault {
        kind,
        target: target.to_owned(),
        at_s,
        duration_s,
    })
}

/// Parses every `--fault` value and orders the faults by time (stable for equal times).
pub fn parse_schedule<S: AsRef<str>>(values: &[S]) -> Result<Vec<Fault>, FaultParseError> {
    let mut faults = values
        .iter()
        .map(|v| parse_fault(v.as_ref()))
        .collect::<Result<Vec<_>, _>>()?;
    faults.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
    Ok(faults)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_three_forms_parse() {
        assert_eq!(
            parse_fault("kill:qp-resolver@4.5").unwrap(),
            Fault {
                kind: FaultKind::Kill,
                target: "qp-resolver".into(),
                at_s: 4.5,
                duration_s: 0.0
            }
        );
        let stop = parse_fault("stop:reacher@3+0.3").unwrap();
        assert_eq!(
            (stop.kind, stop.at_s, stop.duration_s),
            (FaultKind::Stop, 3.0, 0.3)
        );
        assert!((stop.end_s() - 3.3).abs() < 1e-12);
        let nan = parse_fault("nan:motm/v1/arm/velocity_command@2").unwrap();
        assert_eq!(nan.kind, FaultKind::Nan);
        assert_eq!(nan.target, "motm/v1/arm/velocity_command");
        assert_eq!(FaultKind::Stop.name(), "stop");
    }

    #[test]
    fn malformed_values_are_rejected_with_the_reason() {
        for (value, reason) in [
            ("kill-qp@1", "missing ':'"),
            ("crash:qp@1", "unknown fault kind"),
            ("kill:qp", "missing '@SECONDS'"),
            ("kill:@1", "non-empty"),
            ("kill:qp resolver@1", "non-empty"),
            ("kill:qp@soon", "not a number"),
            ("kill:qp@-1", ">= 0"),
            ("kill:qp@inf", ">= 0"),
            ("kill:qp@NaN", ">= 0"),
            ("stop:qp@1", "needs '+DURATION'"),
            ("stop:qp@1+0", "must be > 0"),
            ("stop:qp@1+x", "not a number"),
            ("nan:topic@1+2", "for stop only"),
        ] {
            let err = parse_fault(value).unwrap_err();
            assert_eq!(err.value, value);
            assert!(err.reason.contains(reason), "{value}: {}", err.reason);
            assert!(err.to_string().starts_with("--fault"), "{err}");
        }
    }

    #[test]
    fn a_schedule_is_ordered_by_time() {
        let faults = parse_schedule(&["nan:a@5", "kill:b@1", "stop:c@3+1", "kill:d@1"]).unwrap();
        let order: Vec<&str> = faults.iter().map(|f| f.target.as_str()).collect();
        assert_eq!(order, ["b", "d", "c", "a"]);
        assert!(parse_schedule(&["kill:b@1", "bad"]).is_err());
        assert!(parse_schedule::<&str>(&[]).unwrap().is_empty());
    }
}
