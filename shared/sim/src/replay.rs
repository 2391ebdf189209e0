//! Replay of a MotM trial's log: every logged cycle of every control task fed again, from the
//! samples it consumed, through the same task built the same way (with the gains given, which
//! may be new ones), its outputs compared with the logged ones. "What would the new gains have
//! done on yesterday's run?"

use std::collections::HashMap;
use std::collections::hash_map::Entry;

use motm_core::Robot;
use motm_graph::replay::{Difference, SampleIndex};
use serde::Serialize;

use crate::experiment::TrialLog;
use crate::runner::{RunnerConfig, motm_graph};
use crate::scenario::Scenario;
use crate::sim_world::{SimWorld, SimWorldConfig};

/// Where a task's replay first differed from the log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FirstDifference {
    /// The task's cycle number.
    pub cycle: u64,
    /// The cycle's time, ns.
    pub now_ns: u64,
    /// The output topic.
    pub topic: String,
    /// The field.
    pub field: String,
    /// The logged value.
    pub logged: String,
    /// The replayed value.
    pub replayed: String,
}

/// One task's replay.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TaskReplay {
    /// The task.
    pub name: &'static str,
    /// Cycles replayed.
    pub cycles: u64,
    /// Cycles with an output that differs from the log.
    pub differing_cycles: u64,
    /// Consumed samples the log did not hold.
    pub missing_inputs: u64,
    /// The first difference.
    pub first_difference: Option<FirstDifference>,
}

/// Whether `name` is a control task (replayed), as opposed to the simulated hardware.
pub fn is_replayed(name: &str) -> bool {
    motm_graph::replayed_tasks().any(|spec| spec.name == name)
}

/// Replays `log` of a MotM trial of `scenario` with `seed` through tasks built with `config`
/// (all control tasks, or only `only`). `pids[i]` is the process that ran `log.cycles[i]`
/// (all 0 for an in-process log): each process is replayed by tasks of its own, built fresh
/// as a started or restarted process builds them. The result lists the tasks in graph order.
pub fn replay_log(
    robot: &Robot,
    scenario: &Scenario,
    seed: u64,
    config: &RunnerConfig,
    log: &TrialLog,
    pids: &[u32],
    only: Option<&str>,
) -> Result<Vec<TaskReplay>, String> {
    if let Some(name) = only
        && !is_replayed(name)
    {
        return Err(format!(
            "--task {name}: not a control task of the graph (one of {})",
            motm_graph::replayed_tasks()
                .map(|t| t.name)
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    let build = || -> Result<_, String> {
        let sim = SimWorld::new(robot, scenario, seed, config, SimWorldConfig::default())
            .map_err(|e| e.to_string())?;
        motm_graph(robot, scenario, sim, config)
    };
    let mut instances = HashMap::new();
    let index = SampleIndex::new(log.samples.iter().cloned());
    let mut reports: Vec<TaskReplay> = build()?
        .task_names()
        .into_iter()
        .filter(|name| is_replayed(name) && only.is_none_or(|o| o == *name))
        .map(|name| TaskReplay {
            name,
            cycles: 0,
            differing_cycles: 0,
            missing_inputs: 0,
            first_difference: None,
        })
        .collect();
    for (i, record) in log.cycles.iter().enumerate() {
        let Some(report) = reports.iter_mut().find(|r| r.name == record.task) else {
            continue;
        };
        let pid = pids.get(i).copied().unwrap_or(0);
        let scheduler = match instances.entry(pid) {
            Entry::Occupied(e) => e.into_mut(),
            Entry::Vacant(e) => e.insert(build()?),
        };
        let Some(replayed) = scheduler.replay(record, &index) else {
            continue;
        };
        report.cycles += 1;
        report.missing_inputs += replayed.missing_inputs as u64;
        if let Some(Difference {
            topic,
            field,
            logged,
            replayed,
        }) = replayed.difference
        {
            report.differing_cycles += 1;
            report.first_difference.get_or_insert(FirstDifference {
                cycle: record.cycle,
                now_ns: record.now_ns,
                topic,
                field,
                logged,
                replayed,
            });
        }
    }
    Ok(reports)
}
