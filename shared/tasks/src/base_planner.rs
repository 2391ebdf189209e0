//! The base-planner task: the MotM base controller for the supervisor's current task at the
//! measured odometry; publishes the base velocity target and the plan (t_R, range-entry pose,
//! closest approach).

use motm_core::mission::MissionTask;
use motm_core::stack::base_planner::{BasePlannerCycle, BasePlannerInput};
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, topics};

use crate::view::{ControlView, Raw};
use crate::{ControlSetup, convert};

ports! {
    /// What the base planner reads.
    pub struct BasePlannerInputs {
        /// The supervisor's mission.
        latest mission: msgs::MissionState = topics::MISSION_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// Perception's estimate.
        latest target: msgs::TargetEstimate = topics::PERCEPTION_TARGET,
    }
}

ports! {
    /// What the base planner publishes.
    pub struct BasePlannerOutputs {
        /// The base velocity target.
        latest target: msgs::BaseVelocityCommand = topics::BASE_VELOCITY_TARGET,
        /// The plan.
        latest plan: msgs::BasePlan = topics::BASE_PLAN,
    }
}

/// The base-planner task.
pub struct BasePlannerTask {
    view: ControlView,
    planner: BasePlannerCycle,
    dt: f64,
}

impl BasePlannerTask {
    /// The planner of `setup` (its `forward_speed` is the scenario's base speed) for a mission
    /// over `tasks`, whose known positions its routes keep clear of (none known: no layout).
    pub fn new(setup: &ControlSetup, tasks: &[MissionTask]) -> Self {
        let layout: Vec<_> = tasks.iter().map(|t| t.position).collect();
        Self {
            view: ControlView::new(setup.config.mission.run_out_distance),
            planner: BasePlannerCycle::new(&setup.robot, setup.config.base.clone(), &layout),
            dt: setup.dt(),
        }
    }

    /// Cycles whose input was not finite.
    pub fn refused(&self) -> u64 {
        self.planner.refused()
    }
}

impl Task for BasePlannerTask {
    type Inputs = BasePlannerInputs;
    type Outputs = BasePlannerOutputs;

    fn name(&self) -> &'static str {
        motm_graph::BASE_PLANNER.name
    }

    fn step(&mut self, now_ns: u64, inputs: &BasePlannerInputs) -> BasePlannerOutputs {
        // The base controller needs no joint state.
        let snapshot = self.view.snapshot(Raw {
            mission: inputs.mission.as_ref(),
            joints: Some(None),
            odometry: inputs.odometry.as_ref(),
            target: inputs.target.as_ref(),
        });
        let (Some(mission), Some(measured), Some(target)) =
            (snapshot.mission, snapshot.measured, snapshot.target)
        else {
            return BasePlannerOutputs::default();
        };
        match self.planner.step(&BasePlannerInput {
            mission,
            base: measured.base,
            target,
            dt: self.dt,
        }) {
            Some(out) => BasePlannerOutputs {
                target: Some(convert::stamped(
                    convert::base_command(&out.plan.command),
                    now_ns,
                )),
                plan: Some(convert::stamped(convert::plan_message(&out), now_ns)),
            },
            None => BasePlannerOutputs::default(),
        }
    }
}
