//! The fault schedule of `motm run --fault`: which fault to inject into the running stack, on
//! what, and when. Pure parsing, ordering and event timing; the CLI carries the faults out.
//!
//! Forms (times in seconds of the simulated task: sim-world's clock, which starts with the
//! world and runs in real time, so a fault lands at the same point of the task from run to run
//! whatever the start-up took; durations in wall-clock seconds):
//! - `kill:SERVICE@WHEN`: SIGKILL the service's process (the supervisor restarts it).
//! - `stop:SERVICE@WHEN+DURATION`: SIGSTOP the process (a hang), SIGCONT it `DURATION`
//!   seconds later (for a stop, the last `+` is always the duration).
//! - `nan:TOPIC@WHEN`: publish one sample with a NaN value on the topic.
//!
//! `WHEN` is a simulated time in seconds, or a mission event with an optional delay after it:
//! `grasp`, `place` or `press`, then `#N` for the N-th such event (default the first), then
//! `+SECONDS`. So `kill:qp-resolver@grasp+0.25` kills the resolver a quarter second into the
//! first grasp closure, on any scenario. The events ([`MissionEvents`]) come from sim-world's
//! truth:
//! - **grasp**: the gripper starts closing while it holds nothing;
//! - **place**: the held object is let go;
//! - **press**: a button registers its press.
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

/// A mission event that a fault time can follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventKind {
    /// The gripper starts closing on an object.
    Grasp,
    /// The held object is let go.
    Place,
    /// A button registers its press.
    Press,
}

impl EventKind {
    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            EventKind::Grasp => "grasp",
            EventKind::Place => "place",
            EventKind::Press => "press",
        }
    }
}

/// The `nth` (1-based) occurrence of a mission event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MissionEvent {
    /// Which event.
    pub kind: EventKind,
    /// Which occurrence, from 1.
    pub nth: u32,
}

/// One scheduled fault.
#[derive(Debug, Clone, PartialEq)]
pub struct Fault {
    /// What the fault does.
    pub kind: FaultKind,
    /// The service (kill, stop) or topic (nan) it hits.
    pub target: String,
    /// When, simulated s: an absolute time, or the delay after `after` when that is set.
    pub at_s: f64,
    /// The mission event the time counts from (`None`: from the start of the world).
    pub after: Option<MissionEvent>,
    /// How long a stop lasts, s (0 for kill and nan).
    pub duration_s: f64,
}

impl Fault {
    /// The time as given: `4.5`, `grasp+0.25` or `place#2`.
    pub fn when(&self) -> String {
        match self.after {
            None => format!("{}", self.at_s),
            Some(e) => {
                let nth = if e.nth == 1 {
                    String::new()
                } else {
                    format!("#{}", e.nth)
                };
                let delay = if self.at_s == 0.0 {
                    String::new()
                } else {
                    format!("+{}", self.at_s)
                };
                format!("{}{nth}{delay}", e.kind.name())
            }
        }
    }

    /// The simulated time the fault is due at, once it is known (`events` so far).
    pub fn due_s(&self, events: &MissionEvents) -> Option<f64> {
        match self.after {
            None => Some(self.at_s),
            Some(e) => events.time_of(e).map(|t| t + self.at_s),
        }
    }
}

/// Mission events as they happen, from sim-world's truth: the simulated times of every grasp
/// start, place and press so far (see the module doc for what each is).
#[derive(Debug, Clone, Default)]
pub struct MissionEvents {
    grasps: Vec<f64>,
    places: Vec<f64>,
    presses: Vec<f64>,
    last_opening: Option<f64>,
    closing: bool,
    last_held: Option<i32>,
    last_pressed: u32,
}

/// Change of the gripper opening between two observations that counts as motion, m.
const OPENING_MOTION_M: f64 = 1e-5;

impl MissionEvents {
    /// Takes in one observation of the world: the simulated time, the gripper opening (m), the
    /// held object (−1 for none) and how many buttons have registered a press.
    pub fn observe(&mut self, sim_time: f64, opening: f64, held_object: i32, pressed: u32) {
        if let Some(last) = self.last_opening {
            if opening < last - OPENING_MOTION_M {
                if !self.closing && held_object < 0 {
                    self.grasps.push(sim_time);
                }
                self.closing = true;
            } else if opening > last + OPENING_MOTION_M {
                self.closing = false;
            }
        }
        self.last_opening = Some(opening);
        if self.last_held.is_some_and(|h| h >= 0) && held_object < 0 {
            self.places.push(sim_time);
        }
        self.last_held = Some(held_object);
        for _ in self.last_pressed..pressed {
            self.presses.push(sim_time);
        }
        self.last_pressed = self.last_pressed.max(pressed);
    }

    /// The simulated time of `event`, once it has happened.
    pub fn time_of(&self, event: MissionEvent) -> Option<f64> {
        let times = match event.kind {
            EventKind::Grasp => &self.grasps,
            EventKind::Place => &self.places,
            EventKind::Press => &self.presses,
        };
        times.get(event.nth.checked_sub(1)? as usize).copied()
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
            "--fault {:?}: {} (expected kill:SERVICE@WHEN, stop:SERVICE@WHEN+DURATION or nan:TOPIC@WHEN, WHEN being SECONDS or grasp|place|press[#N][+SECONDS])",
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
    let (when, duration) = match (kind, when.rsplit_once('+')) {
        (FaultKind::Stop, Some((when, duration))) => (when, Some(duration)),
        (FaultKind::Stop, None) => return Err(fail("a stop needs '+DURATION'".into())),
        (_, _) => (when, None),
    };
    let (at_s, after) = parse_when(when, kind).map_err(fail)?;
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
        after,
        duration_s,
    })
}

/// Parses `WHEN` (without a stop's duration): seconds, or `EVENT[#N][+SECONDS]`.
fn parse_when(when: &str, kind: FaultKind) -> Result<(f64, Option<MissionEvent>), String> {
    let (head, delay) = match when.split_once('+') {
        Some((head, delay)) => (head, Some(delay)),
        None => (when, None),
    };
    let (name, nth) = match head.split_once('#') {
        Some((name, nth)) => (name, Some(nth)),
        None => (head, None),
    };
    let event = match name {
        "grasp" => EventKind::Grasp,
        "place" => EventKind::Place,
        "press" => EventKind::Press,
        _ if delay.is_some() && kind != FaultKind::Stop => {
            return Err("'+DURATION' is for stop only (after a time in seconds)".into());
        }
        _ if nth.is_some() => return Err(format!("unknown event {name:?}")),
        _ => return Ok((seconds(when, "the time")?, None)),
    };
    let nth = match nth {
        None => 1,
        Some(n) => n
            .parse::<u32>()
            .ok()
            .filter(|&n| n >= 1)
            .ok_or_else(|| format!("the event number {n:?} must be a whole number >= 1"))?,
    };
    let delay = delay.map_or(Ok(0.0), |d| seconds(d, "the delay after the event"))?;
    Ok((delay, Some(MissionEvent { kind: event, nth })))
}

/// Parses every `--fault` value and orders the faults by time (stable for equal times).
pub fn parse_schedule<S: AsRef<str>>(values: &[S]) -> Result<Vec<Fault>, FaultParseError> {
    let mut faults = values
        .iter()
        .map(|v| parse_fault(v.as_ref()))
        .collect::<Result<Vec<_>, _>>()?;
    // Absolute times first, by time; then the event-timed ones, by delay.
    faults.sort_by(|a, b| {
        (a.after.is_some(), a.at_s)
            .partial_cmp(&(b.after.is_some(), b.at_s))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
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
                after: None,
                duration_s: 0.0
            }
        );
        let stop = parse_fault("stop:reacher@3+0.3").unwrap();
        assert_eq!(
            (stop.kind, stop.at_s, stop.duration_s),
            (FaultKind::Stop, 3.0, 0.3)
        );
        let nan = parse_fault("nan:motm/v1/arm/velocity_command@2").unwrap();
        assert_eq!(nan.kind, FaultKind::Nan);
        assert_eq!(nan.target, "motm/v1/arm/velocity_command");
        assert_eq!(FaultKind::Stop.name(), "stop");
    }

    #[test]
    fn times_can_follow_mission_events() {
        let kill = parse_fault("kill:qp-resolver@grasp+0.25").unwrap();
        let grasp = MissionEvent {
            kind: EventKind::Grasp,
            nth: 1,
        };
        assert_eq!((kill.after, kill.at_s), (Some(grasp), 0.25));
        assert_eq!(kill.when(), "grasp+0.25");
        let stop = parse_fault("stop:ld60-driver@place#2+0.1+0.3").unwrap();
        assert_eq!(
            (
                stop.after.map(|e| (e.kind, e.nth)),
                stop.at_s,
                stop.duration_s
            ),
            (Some((EventKind::Place, 2)), 0.1, 0.3)
        );
        assert_eq!(stop.when(), "place#2+0.1");
        let stop = parse_fault("stop:reacher@press+0.3").unwrap();
        assert_eq!((stop.at_s, stop.duration_s), (0.0, 0.3));
        let nan = parse_fault("nan:motm/v1/arm/velocity_command@grasp").unwrap();
        assert_eq!((nan.at_s, nan.when().as_str()), (0.0, "grasp"));
    }

    #[test]
    fn events_are_read_from_the_gripper_the_held_object_and_the_buttons() {
        let mut events = MissionEvents::default();
        let mut t = 0.0;
        let mut observe = |e: &mut MissionEvents, opening: f64, held: i32, pressed: u32| {
            t += 0.002;
            e.observe(t, opening, held, pressed);
            t
        };
        // Open and still; then closing (the grasp starts) on nothing held.
        observe(&mut events, 0.08, -1, 0);
        observe(&mut events, 0.08, -1, 0);
        let grasp = observe(&mut events, 0.0798, -1, 0);
        // Still closing, then holding (no new grasp); the cube is let go (place).
        observe(&mut events, 0.0796, -1, 0);
        observe(&mut events, 0.05, 0, 0);
        observe(&mut events, 0.05, 0, 0);
        let place = observe(&mut events, 0.051, -1, 0);
        // Open again, a second grasp; then a button press.
        observe(&mut events, 0.08, -1, 0);
        let grasp2 = observe(&mut events, 0.07, -1, 0);
        let press = observe(&mut events, 0.07, -1, 1);
        let at = |kind, nth| events.time_of(MissionEvent { kind, nth });
        assert_eq!(at(EventKind::Grasp, 1), Some(grasp));
        assert_eq!(at(EventKind::Grasp, 2), Some(grasp2));
        assert_eq!(at(EventKind::Grasp, 3), None);
        assert_eq!(at(EventKind::Place, 1), Some(place));
        assert_eq!(at(EventKind::Press, 1), Some(press));
        let fault = parse_fault("kill:reacher@grasp#2+0.5").unwrap();
        assert_eq!(fault.due_s(&events), Some(grasp2 + 0.5));
        assert_eq!(
            parse_fault("kill:reacher@place#2").unwrap().due_s(&events),
            None
        );
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
            ("kill:qp@grip+1", "for stop only"),
            ("kill:qp@grip#2", "unknown event"),
            ("kill:qp@grasp#0", ">= 1"),
            ("kill:qp@grasp#x", ">= 1"),
            ("kill:qp@grasp+x", "not a number"),
            ("kill:qp@grasp+-1", ">= 0"),
            ("stop:qp@grasp", "needs '+DURATION'"),
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
