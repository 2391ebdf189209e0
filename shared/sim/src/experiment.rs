//! The paper's experiments as data: which trials make up Table I, Exp 2 and the platforms sweep,
//! the per-trial result record, and the aggregation of trials into table rows.
//!
//! Running a trial is the runner's job; writing files and plots is the CLI's. This module only
//! says what to run and how to summarise it, so both the CLI and the tests share one definition.

use serde::Serialize;

use crate::metrics::mtph;

/// A control method under test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Reactive manipulation on-the-move (the four MotM modules and the augmented QP).
    Motm,
    /// The holistic stop-and-grasp baseline.
    Reactive,
    /// Plan once at t = 0, then track open-loop.
    Planning,
}

impl Method {
    /// Every method, in table order.
    pub const ALL: [Method; 3] = [Method::Motm, Method::Reactive, Method::Planning];

    /// The name used on the command line and in result files.
    pub fn name(self) -> &'static str {
        match self {
            Method::Motm => "motm",
            Method::Reactive => "reactive",
            Method::Planning => "planning",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown method {s:?}: expected motm, reactive or planning"))
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Whether the objects of a trial stand still or move.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ObjectMotion {
    /// Objects do not move.
    Static,
    /// Objects move along a random smooth path.
    Dynamic,
    /// Some objects stand still and some move, trial by trial (generated layouts).
    Mixed,
}

impl ObjectMotion {
    /// The name used in result files.
    pub fn name(self) -> &'static str {
        match self {
            ObjectMotion::Static => "static",
            ObjectMotion::Dynamic => "dynamic",
            ObjectMotion::Mixed => "mixed",
        }
    }
}

/// One trial to run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrialSpec {
    /// Experiment this trial belongs to ("exp1", "exp2" or "platforms").
    pub experiment: &'static str,
    /// Scenario name, resolved under `config/scenarios/<name>.toml`.
    pub scenario: String,
    /// Robot name, for grouping (the scenario names the robot it loads).
    pub robot: String,
    /// Control method.
    pub method: Method,
    /// Commanded base speed v_F, m/s.
    pub base_speed: f64,
    /// Static or moving objects.
    pub object: ObjectMotion,
    /// RNG seed of the trial.
    pub seed: u64,
}

/// What one trial produced: the `motm trial --json` record.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrialResult {
    /// Every task of the scenario completed.
    pub success: bool,
    /// Why the trial failed: null on success, else e.g. "knocked_off", "missed_grasp",
    /// "dropped_outside", "timeout".
    pub failure: Option<String>,
    /// Time from the start of robot motion to the last drop, s (the full simulated time when the
    /// trial failed).
    pub task_time_s: f64,
    /// Transports per hour of this trial alone: 3600 / t on success, else 0.
    pub mtph: f64,
    /// Mean |a| of the end effector, m/s².
    pub ee_acc_mean: f64,
    /// Maximum |a| of the end effector, m/s².
    pub ee_acc_max: f64,
    /// How the EE acceleration was filtered.
    pub ee_acc_filter: String,
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Wall-clock time the trial took, s.
    pub wall_time_s: f64,
    /// Round-trip time per pick-and-place cycle, s (one entry per completed drop).
    pub round_trips_s: Vec<f64>,
    /// Every failure as it happened, first to last (in-process trials; a deployed run's
    /// simulator reports only the first, in `failure`).
    pub mishaps: Vec<MishapRecord>,
}

/// One failure of a trial: when, why, which object and how.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MishapRecord {
    /// Simulated time, s.
    pub time_s: f64,
    /// Why, as in [`TrialResult::failure`].
    pub reason: String,
    /// Index of the object concerned in the scenario's `[[objects]]`, if one was.
    pub object: Option<usize>,
    /// How, for a knock-off: the gripper part and the closure's state; empty otherwise.
    pub detail: String,
}

impl From<&crate::world::Mishap> for MishapRecord {
    fn from(mishap: &crate::world::Mishap) -> Self {
        Self {
            time_s: mishap.time,
            reason: mishap.reason.as_str().to_string(),
            object: mishap.object,
            detail: mishap.detail.to_string(),
        }
    }
}

/// A top-down record of one trial, for the trajectory plot: world x, y of the base, the end
/// effector and the objects, sampled at the control rate (or decimated).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TrialTrace {
    /// Base position samples.
    pub base: Vec<(f64, f64)>,
    /// End-effector position samples.
    pub ee: Vec<(f64, f64)>,
    /// Position samples of each object, one list per object.
    pub objects: Vec<Vec<(f64, f64)>>,
    /// Container centres.
    pub containers: Vec<(f64, f64)>,
    /// One row per control cycle, columns as in [`CYCLE_COLUMNS`] (only when asked for).
    pub cycles: Vec<Vec<f64>>,
    /// The replay log of a MotM trial (only when asked for).
    #[serde(skip)]
    pub log: Option<TrialLog>,
    /// Wall-clock durations of each task's steps, ns (only when asked for:
    /// [`crate::runner::RunnerConfig::time_steps`]).
    #[serde(skip)]
    pub step_ns: Vec<(&'static str, Vec<u64>)>,
}

/// A MotM trial's replay log: every sample published on the in-memory bus and every task
/// cycle's record, in order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TrialLog {
    /// Every sample published, with its raw bytes.
    pub samples: Vec<motm_graph::replay::RawSample>,
    /// Every task cycle, in execution order.
    pub cycles: Vec<motm_graph::CycleRecord>,
}

/// Column names of [`TrialTrace::cycles`].
///
/// The last columns are MotM's internals (zero for the baselines): `phase` (0 reach, 1 final,
/// 2 complete), `stage` (the final-phase stage, −1 outside the final phase, else 0 approach,
/// 1 closing, 2 lifting, 3 releasing, 4 pushing, 5 retracting, 6 done), the world twist asked
/// of the QP, the tool-to-target distance, the first arm joint's position, and the mission's
/// estimate of the odometry frame in the world (`[x, y, yaw]`, `MissionState.odometry_offset`).
pub const CYCLE_COLUMNS: [&str; 33] = [
    "t",
    "task",
    "base_x",
    "base_y",
    "base_yaw",
    "odom_x",
    "odom_y",
    "odom_yaw",
    "base_v",
    "tool_x",
    "tool_y",
    "tool_z",
    "target_x",
    "target_y",
    "target_z",
    "cube_x",
    "cube_y",
    "cube_z",
    "gripper_opening",
    "command_v",
    "command_omega",
    "phase",
    "stage",
    "twist_vx",
    "twist_vy",
    "twist_vz",
    "tool_to_target",
    "qp_slack",
    "base_target_v",
    "arm_q1",
    "odom_offset_x",
    "odom_offset_y",
    "odom_offset_yaw",
];

/// One row of a results table: the trials of one method, speed, robot and object motion.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TableRow {
    /// Experiment ("exp1", "exp2", "platforms", "missions" or "generated").
    pub experiment: &'static str,
    /// Scenario name.
    pub scenario: String,
    /// Robot name.
    pub robot: String,
    /// Control method.
    pub method: Method,
    /// Commanded base speed, m/s.
    pub base_speed: f64,
    /// "static" or "dynamic".
    pub object: ObjectMotion,
    /// Trials run.
    pub trials: usize,
    /// Trials that succeeded.
    pub successes: usize,
    /// Mean task time over the successful trials, s (NaN-free: 0 when none succeeded).
    pub task_time_s: f64,
    /// Mean transports per hour, 3600 / t × sr.
    pub mtph: f64,
    /// Mean of the per-trial mean |a|, m/s².
    pub ee_acc_mean: f64,
    /// Largest per-trial maximum |a|, m/s².
    pub ee_acc_max: f64,
    /// Mean round-trip time per pick-and-place over the successful trials, s (Exp 2).
    pub round_trip_s: f64,
    /// Failure reasons and how often each occurred.
    pub failures: Vec<(String, usize)>,
}

/// A published figure from the paper's Table I, to print beside our own.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperRow {
    /// Method.
    pub method: Method,
    /// Base speed, m/s.
    pub base_speed: f64,
    /// Static-object task time, s.
    pub task_time_s: f64,
    /// Static-object successes out of 10.
    pub successes: usize,
    /// Static-object MTPH.
    pub mtph: f64,
    /// Mean |a|, m/s².
    pub ee_acc_mean: f64,
    /// Max |a|, m/s².
    pub ee_acc_max: f64,
    /// Dynamic-object task time, s.
    pub dynamic_task_time_s: f64,
    /// Dynamic-object successes out of 10.
    pub dynamic_successes: usize,
}

/// The paper's Table I (real robot, 10 trials per row).
pub const PAPER_TABLE_I: [PaperRow; 5] = [
    PaperRow {
        method: Method::Motm,
        base_speed: 0.2,
        task_time_s: 17.85,
        successes: 10,
        mtph: 201.7,
        ee_acc_mean: 0.15,
        ee_acc_max: 0.90,
        dynamic_task_time_s: 17.86,
        dynamic_successes: 10,
    },
    PaperRow {
        method: Method::Motm,
        base_speed: 0.3,
        task_time_s: 12.32,
        successes: 10,
        mtph: 292.3,
        ee_acc_mean: 0.26,
        ee_acc_max: 1.24,
        dynamic_task_time_s: 12.21,
        dynamic_successes: 10,
    },
    PaperRow {
        method: Method::Motm,
        base_speed: 0.4,
        task_time_s: 9.48,
        successes: 10,
        mtph: 379.9,
        ee_acc_mean: 0.46,
        ee_acc_max: 2.03,
        dynamic_task_time_s: 9.57,
        dynamic_successes: 9,
    },
    PaperRow {
        method: Method::Reactive,
        base_speed: 0.3,
        task_time_s: 18.32,
        successes: 10,
        mtph: 196.5,
        ee_acc_mean: 0.32,
        ee_acc_max: 2.27,
        dynamic_task_time_s: 18.09,
        dynamic_successes: 10,
    },
    PaperRow {
        method: Method::Planning,
        base_speed: 0.3,
        task_time_s: 11.67,
        successes: 7,
        mtph: 215.9,
        ee_acc_mean: 0.24,
        ee_acc_max: 0.93,
        dynamic_task_time_s: 11.62,
        dynamic_successes: 0,
    },
];

/// The paper's Exp 2 round-trip times: (method, base speed, seconds).
pub const PAPER_EXP2_ROUND_TRIP: [(Method, f64, f64); 3] = [
    (Method::Motm, 0.3, 18.0),
    (Method::Motm, 0.4, 13.7),
    (Method::Reactive, 0.3, 29.2),
];

/// The paper's figure for a table row, if it published one.
pub fn paper_row(method: Method, base_speed: f64) -> Option<&'static PaperRow> {
    PAPER_TABLE_I
        .iter()
        .find(|r| r.method == method && (r.base_speed - base_speed).abs() < 1e-9)
}

/// Base speeds of the platforms sweep, m/s.
pub const PLATFORM_SPEEDS: [f64; 4] = [0.1, 0.2, 0.3, 0.4];

/// Robots of the platforms sweep.
pub const PLATFORM_ROBOTS: [&str; 3] = ["frankie", "fetch", "husky_ur5"];

/// The mission library (`config/scenarios/mission-*.toml`) and the robot each names: multi-task
/// layouts (U-turns, places behind, zigzags, alternating sides, mixed static and moving objects,
/// a press between picks) run by `motm experiment missions`.
pub const MISSION_LIBRARY: [(&str, &str); 8] = [
    ("mission-u-turn-place", "frankie"),
    ("mission-place-behind", "frankie"),
    ("mission-zigzag", "frankie"),
    ("mission-alternating-sides", "frankie"),
    ("mission-three-mixed", "frankie"),
    ("mission-press-between", "frankie"),
    ("mission-husky-zigzag", "husky_ur5"),
    ("mission-fetch-u-turn", "fetch"),
];

/// The trials of an experiment: "exp1", "exp2", "platforms", "missions", "generated" or
/// "all" (every one but "generated").
///
/// Seeds are `seed + k` for the k-th trial of a row, so every row sees the same object paths.
pub fn plan(experiment: &str, trials: usize, seed: u64) -> Result<Vec<TrialSpec>, String> {
    let mut specs = Vec::new();
    let mut add = |experiment: &'static str,
                   scenario: &str,
                   robot: &str,
                   method: Method,
                   base_speed: f64,
                   object: ObjectMotion| {
        for k in 0..trials {
            specs.push(TrialSpec {
                experiment,
                scenario: scenario.to_string(),
                robot: robot.to_string(),
                method,
                base_speed,
                object,
                seed: seed + k as u64,
            });
        }
    };
    let wanted = |name: &str| experiment == name || experiment == "all";
    if !matches!(
        experiment,
        "exp1" | "exp2" | "platforms" | "missions" | "generated" | "all"
    ) {
        return Err(format!(
            "unknown experiment {experiment:?}: expected exp1, exp2, platforms, missions, \
             generated or all"
        ));
    }
    if wanted("exp1") {
        for object in [ObjectMotion::Static, ObjectMotion::Dynamic] {
            let scenario = format!("exp1-{}", object.name());
            for speed in [0.2, 0.3, 0.4] {
                add("exp1", &scenario, "frankie", Method::Motm, speed, object);
            }
            add("exp1", &scenario, "frankie", Method::Reactive, 0.3, object);
            add("exp1", &scenario, "frankie", Method::Planning, 0.3, object);
        }
    }
    if wanted("exp2") {
        for speed in [0.3, 0.4] {
            add(
                "exp2",
                "exp2",
                "frankie",
                Method::Motm,
                speed,
                ObjectMotion::Static,
            );
        }
        add(
            "exp2",
            "exp2",
            "frankie",
            Method::Reactive,
            0.3,
            ObjectMotion::Static,
        );
    }
    if wanted("platforms") {
        for robot in PLATFORM_ROBOTS {
            let scenario = format!("platforms-{robot}");
            for speed in PLATFORM_SPEEDS {
                add(
                    "platforms",
                    &scenario,
                    robot,
                    Method::Motm,
                    speed,
                    ObjectMotion::Static,
                );
            }
        }
    }
    if wanted("missions") {
        for (scenario, robot) in MISSION_LIBRARY {
            add(
                "missions",
                scenario,
                robot,
                Method::Motm,
                0.3,
                ObjectMotion::Static,
            );
        }
    }
    if experiment == "generated" {
        // One row per robot; trial k runs the layout of its seed ([`crate::generated`]).
        for robot in PLATFORM_ROBOTS {
            add(
                "generated",
                &format!("{}{robot}", crate::generated::PREFIX),
                robot,
                Method::Motm,
                0.3,
                ObjectMotion::Mixed,
            );
        }
    }
    Ok(specs)
}

/// Groups trial results into table rows, one per (experiment, scenario, robot, method, speed,
/// object), in the order the rows first appear in `trials`.
pub fn aggregate(trials: &[(TrialSpec, TrialResult)]) -> Vec<TableRow> {
    let mut rows: Vec<(TableRow, Vec<f64>, Vec<f64>)> = Vec::new();
    for (spec, result) in trials {
        let key_matches = |row: &TableRow| {
            row.experiment == spec.experiment
                && row.scenario == spec.scenario
                && row.robot == spec.robot
                && row.method == spec.method
                && row.base_speed == spec.base_speed
                && row.object == spec.object
        };
        let index = match rows.iter().position(|(row, _, _)| key_matches(row)) {
            Some(i) => i,
            None => {
                rows.push((
                    TableRow {
                        experiment: spec.experiment,
                        scenario: spec.scenario.clone(),
                        robot: spec.robot.clone(),
                        method: spec.method,
                        base_speed: spec.base_speed,
                        object: spec.object,
                        trials: 0,
                        successes: 0,
                        task_time_s: 0.0,
                        mtph: 0.0,
                        ee_acc_mean: 0.0,
                        ee_acc_max: 0.0,
                        round_trip_s: 0.0,
                        failures: Vec::new(),
                    },
                    Vec::new(),
                    Vec::new(),
                ));
                rows.len() - 1
            }
        };
        let (row, times, round_trips) = &mut rows[index];
        row.trials += 1;
        // Running mean of the per-trial mean acceleration.
        row.ee_acc_mean += (result.ee_acc_mean - row.ee_acc_mean) / row.trials as f64;
        row.ee_acc_max = row.ee_acc_max.max(result.ee_acc_max);
        if result.success {
            row.successes += 1;
            times.push(result.task_time_s);
            round_trips.extend(&result.round_trips_s);
        } else {
            let reason = result.failure.clone().unwrap_or_else(|| "unknown".into());
            match row.failures.iter_mut().find(|(r, _)| *r == reason) {
                Some((_, n)) => *n += 1,
                None => row.failures.push((reason, 1)),
            }
        }
    }
    rows.into_iter()
        .map(|(mut row, times, round_trips)| {
            row.task_time_s = mean(&times);
            row.mtph = mtph(&times, row.trials);
            row.round_trip_s = mean(&round_trips);
            row
        })
        .collect()
}

/// Mean of a slice, 0 when empty.
fn mean(values: &[f64]) -> f64 {
    if values.is_empty() {
        0.0
    } else {
        values.iter().sum::<f64>() / values.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(success: bool, t: f64, acc: f64) -> TrialResult {
        TrialResult {
            success,
            failure: (!success).then(|| "missed_grasp".to_string()),
            task_time_s: t,
            mtph: if success { 3600.0 / t } else { 0.0 },
            ee_acc_mean: acc,
            ee_acc_max: 2.0 * acc,
            ee_acc_filter: String::new(),
            sim_time_s: t,
            wall_time_s: 0.1,
            round_trips_s: vec![t],
            mishaps: Vec::new(),
        }
    }

    #[test]
    fn exp1_plan_has_ten_rows_of_n_trials() {
        let specs = plan("exp1", 3, 7).unwrap();
        assert_eq!(specs.len(), 10 * 3);
        assert_eq!(specs[0].seed, 7);
        assert_eq!(specs[2].seed, 9);
        assert!(plan("exp9", 1, 0).is_err());
        let all = plan("all", 1, 0).unwrap();
        assert_eq!(all.len(), 10 + 3 + 12 + MISSION_LIBRARY.len());
        // Every mission of the library is a scenario file naming the robot listed for it.
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/scenarios");
        for (name, robot) in MISSION_LIBRARY {
            let scenario = crate::scenario::Scenario::from_file(&dir.join(format!("{name}.toml")))
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(scenario.robot, robot, "{name}");
            assert!(scenario.mission_tasks().len() >= 2, "{name} has no tasks");
        }
    }

    #[test]
    fn aggregate_counts_successes_and_averages_only_successful_times() {
        let spec = plan("exp1", 1, 0).unwrap().remove(0);
        let trials = vec![
            (spec.clone(), result(true, 10.0, 0.2)),
            (spec.clone(), result(true, 14.0, 0.4)),
            (spec.clone(), result(false, 60.0, 0.6)),
        ];
        let rows = aggregate(&trials);
        assert_eq!(rows.len(), 1);
        let row = &rows[0];
        assert_eq!((row.trials, row.successes), (3, 2));
        assert!((row.task_time_s - 12.0).abs() < 1e-12);
        assert!((row.mtph - 3600.0 / 12.0 * 2.0 / 3.0).abs() < 1e-9);
        assert!((row.ee_acc_mean - 0.4).abs() < 1e-12);
        assert!((row.ee_acc_max - 1.2).abs() < 1e-12);
        assert_eq!(row.failures, vec![("missed_grasp".to_string(), 1)]);
    }

    #[test]
    fn paper_rows_are_found_by_method_and_speed() {
        assert_eq!(paper_row(Method::Motm, 0.3).unwrap().task_time_s, 12.32);
        assert!(paper_row(Method::Planning, 0.2).is_none());
        assert_eq!("planning".parse::<Method>().unwrap(), Method::Planning);
        assert!("fast".parse::<Method>().is_err());
    }
}
