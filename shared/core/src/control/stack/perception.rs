//! The perception process: estimates of the current pick's cube, place's container or press's button cap from
//! palm-camera images (see [`TaskKind::is_perceived`]), each
//! image paired with the tool pose the robot believed it had when the image was taken.
//!
//! Choices: the tool-pose history keeps the last `history` poses (config, default 200: one
//! second of 200 Hz joint states); an image is paired with the pose whose stamp is nearest
//! its capture stamp (the runner's rule). Perception restarts, with the mission's target
//! position as its hint, whenever a new pick starts.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Vector3};

use crate::camera::CameraCalibration;
use crate::localization::world_to_odometry;
use crate::mission::{MissionTask, TaskKind};
use crate::perception::{
    BlobColour, ObjectEstimate, Perception, PerceptionConfig, PerceptionInput,
};

use super::{MissionView, seconds};

/// One camera image as received.
#[derive(Debug, Clone, Copy)]
pub struct CameraFrame<'a> {
    /// RGB8 pixels, row-major.
    pub pixels: &'a [u8],
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Capture (exposure) time, monotonic ns.
    pub stamp_ns: u64,
}

/// An estimate to publish.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PerceptionReport {
    /// The estimate (always `valid`).
    pub estimate: ObjectEstimate,
    /// Capture stamp of the image that gave the estimate's position, ns.
    pub image_stamp_ns: u64,
    /// The mission task the estimate is for.
    pub task_index: usize,
}

/// Perception plus the tool-pose history and the current task.
pub struct PerceptionCycle {
    config: PerceptionConfig,
    calibration: CameraCalibration,
    perception: Perception,
    history_len: usize,
    task: Option<usize>,
    history: VecDeque<(u64, Isometry3<f64>)>,
    fix_stamp_ns: u64,
    /// The mission's tasks (their kinds and known world positions), for the neighbours.
    layout: Vec<MissionTask>,
    /// Scratch: the current target's neighbours, in odometry.
    neighbours: Vec<Vector3<f64>>,
}

impl PerceptionCycle {
    /// Perception with `config` and the robot's camera `calibration`, keeping `history_len`
    /// tool poses.
    pub fn new(
        config: PerceptionConfig,
        calibration: CameraCalibration,
        history_len: usize,
    ) -> Self {
        Self {
            perception: Perception::new(config, calibration),
            config,
            calibration,
            history_len: history_len.max(1),
            task: None,
            history: VecDeque::new(),
            fix_stamp_ns: 0,
            layout: Vec::new(),
            neighbours: Vec::new(),
        }
    }

    /// The same, knowing the mission's `tasks`: the objects of later tasks still stand where
    /// the mission knows them, and tell the current target from its neighbours
    /// ([`PerceptionInput::neighbours`]).
    pub fn with_layout(mut self, tasks: &[MissionTask]) -> Self {
        self.layout = tasks.to_vec();
        self
    }

    /// The known positions, in odometry, of the objects of the target's colour that later tasks
    /// of `mission` name (other than the target itself).
    fn find_neighbours(&mut self, mission: &MissionView) {
        let red = |kind: TaskKind| kind != TaskKind::Place;
        self.neighbours.clear();
        for task in self.layout.iter().skip(mission.task_index + 1) {
            let p = world_to_odometry(&mission.odometry_offset, &task.position);
            let distinct = (p - mission.target).xy().norm() > 0.01
                && self.neighbours.iter().all(|n| (n - p).xy().norm() > 0.01);
            if red(task.kind) == red(mission.kind) && distinct {
                self.neighbours.push(p);
            }
        }
    }

    /// Records the tool pose believed at monotonic time `stamp_ns` (non-finite poses are
    /// ignored).
    pub fn record_tool(&mut self, stamp_ns: u64, pose: Isometry3<f64>) {
        let finite = pose.translation.vector.iter().all(|x| x.is_finite())
            && pose.rotation.coords.iter().all(|x| x.is_finite());
        if !finite {
            return;
        }
        self.history.push_back((stamp_ns, pose));
        while self.history.len() > self.history_len {
            self.history.pop_front();
        }
    }

    /// Follows the mission: a new task restarts perception.
    pub fn select(&mut self, mission: &MissionView) {
        if self.task != Some(mission.task_index) {
            self.task = Some(mission.task_index);
            self.perception = Perception::new(self.config, self.calibration);
            self.fix_stamp_ns = 0;
        }
    }

    /// Processes `frame` for the current task: `Some` estimate to publish while a pick's cube or
    /// a press's button cap has been seen at least once (held when it leaves the view), `None`
    /// otherwise.
    pub fn observe(
        &mut self,
        mission: &MissionView,
        frame: &CameraFrame<'_>,
    ) -> Option<PerceptionReport> {
        self.select(mission);
        if !mission.current_kind().is_some_and(TaskKind::is_perceived) {
            return None;
        }
        let &(_, tool_pose) = self
            .history
            .iter()
            .min_by_key(|(stamp, _)| stamp.abs_diff(frame.stamp_ns))?;
        self.find_neighbours(mission);
        let estimate = self.perception.step(&PerceptionInput {
            image: frame.pixels,
            width: frame.width,
            height: frame.height,
            stamp: seconds(frame.stamp_ns),
            tool_pose,
            object_height: mission.target.z,
            target_hint: Some(mission.target),
            colour: if mission.kind == TaskKind::Place {
                BlobColour::Blue
            } else {
                BlobColour::Red
            },
            neighbours: &self.neighbours,
            layout_trusted: mission.odometry_calibrated,
        });
        if estimate.visible {
            self.fix_stamp_ns = frame.stamp_ns;
        }
        estimate.valid.then_some(PerceptionReport {
            estimate,
            image_stamp_ns: self.fix_stamp_ns,
            task_index: mission.task_index,
        })
    }
}
