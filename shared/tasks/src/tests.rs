//! Each task's ports are its row of the graph table.

use motm_graph::{GRAPH, PortSet, TaskSpec};
use motm_msgs::TopicSpec;

use crate::{base_planner, driver, final_phase, mission, perception, reacher, resolver, watchdog};

fn same_topics(spec: &TaskSpec, inputs: &[TopicSpec], outputs: &[TopicSpec]) {
    let sorted = |topics: &[TopicSpec]| {
        let mut v: Vec<&str> = topics.iter().map(|t| t.name).collect();
        v.sort_unstable();
        v
    };
    assert_eq!(sorted(spec.inputs), sorted(inputs), "{} inputs", spec.name);
    assert_eq!(
        sorted(spec.outputs),
        sorted(outputs),
        "{} outputs",
        spec.name
    );
}

#[test]
fn every_tasks_ports_are_its_row_of_the_graph() {
    let rows: Vec<(&str, &[TopicSpec], &[TopicSpec])> = vec![
        (
            "perception",
            perception::PerceptionInputs::TOPICS,
            perception::PerceptionOutputs::TOPICS,
        ),
        (
            "base-planner",
            base_planner::BasePlannerInputs::TOPICS,
            base_planner::BasePlannerOutputs::TOPICS,
        ),
        (
            "reacher",
            reacher::ReacherInputs::TOPICS,
            reacher::ReacherOutputs::TOPICS,
        ),
        (
            "final-phase",
            final_phase::FinalPhaseInputs::TOPICS,
            final_phase::FinalPhaseOutputs::TOPICS,
        ),
        (
            "qp-resolver",
            resolver::ResolverInputs::TOPICS,
            resolver::ResolverOutputs::TOPICS,
        ),
        (
            "mission",
            mission::MissionInputs::TOPICS,
            mission::MissionOutputs::TOPICS,
        ),
        (
            "panda-driver",
            driver::ArmDriverInputs::TOPICS,
            driver::ArmDriverOutputs::TOPICS,
        ),
        (
            "ld60-driver",
            driver::BaseDriverInputs::TOPICS,
            driver::BaseDriverOutputs::TOPICS,
        ),
        (
            "watchdog",
            watchdog::WatchdogInputs::TOPICS,
            watchdog::WatchdogOutputs::TOPICS,
        ),
    ];
    for (name, inputs, outputs) in rows {
        let spec = GRAPH.iter().find(|t| t.name == name).unwrap();
        same_topics(spec, inputs, outputs);
    }
}
