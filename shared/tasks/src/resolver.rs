//! The QP-resolver task: picks the tool twist of the active phase (the reacher's, or the
//! active final-phase controller's), resolves it with the base planner's velocity target at
//! the measured joint state and odometry, and publishes the arm and base velocity commands and
//! the QP status, which carries the twist it resolved (the stack's one twist-rate state).

use motm_core::TargetEstimate;
use motm_core::stack::resolver::{
    MeasuredState, ResolverCycle, ResolverCycleConfig, ResolverCycleInput, TwistSource,
};
use motm_graph::{Task, ports};
use motm_msgs::{self as msgs, topics};

use crate::controllers::{PRIMARY_RESOLVER_ID, PerController};
use crate::view::{ControlView, Raw, read_joints};
use crate::{ControlSetup, convert};

ports! {
    /// What the QP resolver reads.
    pub struct ResolverInputs {
        /// The supervisor's mission.
        latest mission: msgs::MissionState = topics::MISSION_STATE,
        /// Joint state.
        latest joints: msgs::JointState = topics::ARM_JOINT_STATE,
        /// Odometry.
        latest odometry: msgs::BaseOdometry = topics::BASE_ODOMETRY,
        /// Perception's estimate.
        latest target: msgs::TargetEstimate = topics::PERCEPTION_TARGET,
        /// The reacher's twist.
        latest reach: msgs::TwistCommand = topics::CONTROL_REACH_TWIST,
        /// The final-phase controllers' twists of the cycle (two during a hot swap).
        queue final_twists: msgs::TwistCommand = topics::CONTROL_FINAL_TWIST,
        /// The active final-phase controller.
        latest active: msgs::ActiveController = topics::CONTROL_ACTIVE_CONTROLLER,
        /// The base planner's velocity target.
        latest base_target: msgs::BaseVelocityCommand = topics::BASE_VELOCITY_TARGET,
    }
}

ports! {
    /// What the QP resolver publishes.
    pub struct ResolverOutputs {
        /// Arm joint velocity command.
        latest arm: msgs::ArmVelocityCommand = topics::ARM_VELOCITY_COMMAND,
        /// Base twist command.
        latest base: msgs::BaseVelocityCommand = topics::BASE_VELOCITY_COMMAND,
        /// The QP status with the resolved twist.
        latest status: msgs::QpStatus = topics::CONTROL_QP_STATUS,
    }
}

/// The QP-resolver task.
pub struct ResolverTask {
    view: ControlView,
    final_twists: PerController<msgs::TwistCommand>,
    cycle: ResolverCycle,
    resolver_id: u32,
}

impl ResolverTask {
    /// The resolver of `setup` with staleness `limits`.
    pub fn new(setup: &ControlSetup, limits: ResolverCycleConfig) -> Self {
        Self {
            view: ControlView::new(setup.config.mission.run_out_distance),
            final_twists: PerController::default(),
            cycle: ResolverCycle::new(
                setup.robot.clone(),
                setup.config.clone(),
                limits,
                setup.dt(),
            ),
            resolver_id: PRIMARY_RESOLVER_ID,
        }
    }

    /// The same task as the instance `resolver_id` ([`PRIMARY_RESOLVER_ID`] by default, or
    /// [`crate::controllers::STANDBY_RESOLVER_ID`] for the hot standby), which its commands
    /// carry.
    pub fn with_resolver_id(mut self, resolver_id: u32) -> Self {
        self.resolver_id = resolver_id;
        self
    }

    /// The resolver cycle (QP error count, fallbacks, stops).
    pub fn cycle(&self) -> &ResolverCycle {
        &self.cycle
    }
}

impl Task for ResolverTask {
    type Inputs = ResolverInputs;
    type Outputs = ResolverOutputs;

    fn name(&self) -> &'static str {
        motm_graph::QP_RESOLVER.name
    }

    fn step(&mut self, now_ns: u64, inputs: &ResolverInputs) -> ResolverOutputs {
        self.final_twists.extend(&inputs.final_twists);
        let snapshot = self.view.snapshot(Raw {
            mission: inputs.mission.as_ref(),
            joints: read_joints(&inputs.joints),
            odometry: inputs.odometry.as_ref(),
            target: inputs.target.as_ref(),
        });
        let active = inputs.active.as_ref().map(|m| m.controller_id);
        // The one wall-clock value a task reports: the solve time, for the logs (replay
        // ignores it).
        let started = std::time::Instant::now();
        let out = self.cycle.step(&ResolverCycleInput {
            mission: snapshot.mission,
            state: snapshot.measured.map(|m| MeasuredState {
                base: m.base,
                arm_q: m.arm_q,
                base_velocity: m.base_velocity,
                age_ns: now_ns.saturating_sub(m.stamp_ns),
            }),
            target: snapshot
                .target
                .unwrap_or_else(|| TargetEstimate::fixed(Default::default())),
            reach: inputs
                .reach
                .as_ref()
                .and_then(|m| convert::twist_sample(m, now_ns)),
            final_twist: self
                .final_twists
                .get(active)
                .and_then(|m| convert::twist_sample(m, now_ns)),
            active_controller: active,
            base_target: inputs.base_target.as_ref().map(|m| {
                (
                    convert::base_velocity_of(m),
                    now_ns.saturating_sub(m.header.stamp_ns),
                )
            }),
        });
        let solve_ns = started.elapsed().as_nanos() as u64;
        let mut status = convert::qp_status(
            &out.resolved,
            solve_ns,
            snapshot.image_stamp_ns,
            snapshot.image_published_ns,
        );
        status.twist = out.twist.into();
        // A stale robot state sends no command (see `TwistSource::Withheld`).
        let send = out.source != TwistSource::Withheld;
        let id = self.resolver_id;
        ResolverOutputs {
            arm: send.then(|| {
                let mut m = convert::arm_command(&out.resolved.arm_qd);
                m.resolver_id = id;
                convert::stamped(m, now_ns)
            }),
            base: send.then(|| {
                let mut m = convert::base_command(&out.resolved.base);
                m.resolver_id = id;
                convert::stamped(m, now_ns)
            }),
            // Never stamped before the frame behind its target (see perception's stamp).
            status: Some(convert::stamped(
                status,
                now_ns.max(status.image_published_ns),
            )),
        }
    }
}
