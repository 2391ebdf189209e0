//! The logger's pure step: turns the samples read off the bus into log records. Every sample
//! becomes a JSON record on its service's own channel (for plots); the robot state also
//! becomes foxglove records for the 3D view (transforms, joint states, poses, scene), and
//! the camera a decimated `foxglove.RawImage`. Each record carries the stamp of the sample it
//! comes from (the header's `CLOCK_MONOTONIC` stamp); nothing here reads a clock.

use std::collections::{BTreeSet, HashMap, VecDeque};

use motm_core::kinematics::BasePose;
use motm_core::robot::Robot;
use motm_msgs as msgs;
use motm_sim::Scenario;
use motm_sim::objects::ObjectConfig;
use nalgebra::{DVector, Isometry3, UnitQuaternion};
use serde::Deserialize;
use serde_json::{Value, json};

use crate::foxglove as fg;
use crate::json::ToJson;

/// Topics of the derived channels.
pub mod topics {
    /// World → base → arm joint frames → tool (`foxglove.FrameTransforms`).
    pub const TF: &str = "/tf";
    /// Arm joint states (`foxglove.JointStates`).
    pub const JOINT_STATES: &str = "/joint_states";
    /// Tool pose in the world (`foxglove.PoseInFrame`).
    pub const EE_POSE: &str = "/ee_pose";
    /// Perceived target pose in the world (`foxglove.PoseInFrame`).
    pub const TARGET_POSE: &str = "/target_pose";
    /// Cubes, platforms, containers, closest approach, reach twist and tool trail
    /// (`foxglove.SceneUpdate`).
    pub const SCENE: &str = "/scene";
    /// Palm camera, decimated (`foxglove.RawImage`).
    pub const CAMERA_IMAGE: &str = "/camera/image";
    /// Tool speed, base speed and arm manipulability (JSON).
    pub const KINEMATICS: &str = "/kinematics";
    /// The logger's own counters: samples read and lost per service (JSON).
    pub const LOGGER_STATS: &str = "/logger/stats";
}

/// Frame ids of the 3D view.
pub mod frames {
    /// The world (odometry) frame.
    pub const WORLD: &str = "world";
    /// The mobile base (footprint) frame.
    pub const BASE: &str = "base";
    /// The tool (grasp point) frame.
    pub const TOOL: &str = "tool";
    /// The palm camera frame (images only: the camera mount is not part of the robot model).
    pub const CAMERA: &str = "camera";
}

/// The logger's choices. Rates are upper bounds on how often a derived channel is written
/// (the bus samples themselves all go to their JSON channels).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoggerConfig {
    /// How often the logger drains its subscribers, Hz. 250 Hz reads every sample of the
    /// control-rate (200 Hz) services; the 1 kHz services overflow their 4-sample queues now
    /// and then (counted in `/logger/stats`), which never slows a publisher.
    pub poll_rate_hz: f64,
    /// Highest rate of a JSON service channel and of the joint states, Hz: faster services are
    /// thinned to it. 250 Hz keeps every sample of the 200 Hz control services (every QP
    /// solve, command and twist) and every 4th of the 1 kHz hardware, driver and watchdog
    /// streams, which keeps the logger's CPU use small.
    pub raw_rate_hz: f64,
    /// Whether the logger runs under Linux's `SCHED_IDLE` policy and the idle I/O class: it
    /// then gets a CPU only when no normal process wants one, and the disk only when no one
    /// else uses it, so it never delays a control process; under full load its queues
    /// overflow instead (counted). `false` runs it at normal priority.
    pub idle_scheduling: bool,
    /// Transforms, tool pose and kinematics, Hz (50 Hz: smooth in the 3D view, a few kB/s).
    pub tf_rate_hz: f64,
    /// Scene updates, Hz.
    pub scene_rate_hz: f64,
    /// Keep every n-th camera image (30 Hz camera / 5 = 6 Hz, 230 kB each).
    pub image_every: u32,
    /// Tool positions kept for the trail in the scene.
    pub trail_points: usize,
    /// Target size of an MCAP chunk, bytes: a killed logger loses at most the chunk being
    /// filled (and at most `flush_interval_s` of data).
    pub chunk_bytes: u64,
    /// Longest time a chunk stays open before it is written out, s.
    pub flush_interval_s: f64,
    /// The logger writes the file's pages back to disk itself every this many bytes (see
    /// [`crate::writeback`]) instead of leaving it to the kernel's normal-priority flusher
    /// threads; 0 leaves it to the kernel.
    pub writeback_bytes: u64,
    /// The live view's settings (`[live]`; used with `logger --live ADDR`).
    pub live: crate::live::LiveConfig,
    /// Whether the file also holds the replay log ([`crate::replay_log`]): every sample's raw
    /// bytes, unthinned, and every task cycle's record. Camera images then cost about
    /// 7 MB/s (every 230 kB frame at 30 Hz), so it is off unless asked for (`logger
    /// --replay`, which `motm run --mcap` passes). With it the logger creates the graph's
    /// services itself (so it reads from the first sample) and runs at normal priority (so it
    /// keeps up), whatever `idle_scheduling` says.
    pub replay: bool,
}

impl Default for LoggerConfig {
    fn default() -> Self {
        Self {
            poll_rate_hz: 250.0,
            raw_rate_hz: 250.0,
            idle_scheduling: true,
            tf_rate_hz: 50.0,
            scene_rate_hz: 10.0,
            image_every: 5,
            trail_points: 400,
            chunk_bytes: 512 * 1024,
            flush_interval_s: 1.0,
            writeback_bytes: 1024 * 1024,
            live: crate::live::LiveConfig::default(),
            replay: false,
        }
    }
}

/// What a log record holds.
#[derive(Debug, Clone, PartialEq)]
pub enum Payload {
    /// A protobuf message of a foxglove schema.
    Protobuf(fg::Schema, Vec<u8>),
    /// A JSON message (the channel's jsonschema is inferred from the first one).
    Json(Value),
    /// A sample's raw `#[repr(C)]` bytes, for replay (file only: no viewer decodes them).
    Raw(&'static str, Vec<u8>),
}

/// One message for the log.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    /// Channel topic.
    pub topic: String,
    /// The source sample's monotonic stamp, ns.
    pub stamp_ns: u64,
    /// Content.
    pub payload: Payload,
}

impl Record {
    /// A protobuf record.
    fn protobuf(
        topic: &str,
        stamp_ns: u64,
        schema: fg::Schema,
        message: &impl prost::Message,
    ) -> Self {
        Self {
            topic: topic.to_owned(),
            stamp_ns,
            payload: Payload::Protobuf(schema, message.encode_to_vec()),
        }
    }
}

/// Static scene geometry from the scenario file: platforms and containers.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SceneLayout {
    /// Boxes `(centre, size)` of the platforms the cubes start on.
    pub platforms: Vec<([f64; 3], [f64; 3])>,
    /// Boxes `(centre, size)` of the containers the cubes go into.
    pub containers: Vec<([f64; 3], [f64; 3])>,
    /// Cube side, m.
    pub cube_size: f64,
}

impl SceneLayout {
    /// The layout of `scenario` with the simulator's object sizes: one platform under each
    /// cube's start position (top at the cube's bottom) and one container per drop point (rim
    /// at the drop point's height).
    pub fn from_scenario(scenario: &Scenario) -> Self {
        let objects = ObjectConfig::default();
        let boxed = |x: f64, y: f64, side: f64, top: f64| {
            let top = top.max(0.01);
            ([x, y, top / 2.0], [side, side, top])
        };
        Self {
            platforms: scenario
                .objects
                .iter()
                .map(|o| {
                    let top = o.position[2] - objects.cube_size / 2.0;
                    boxed(o.position[0], o.position[1], objects.platform_size, top)
                })
                .collect(),
            containers: scenario
                .objects
                .iter()
                .map(|o| boxed(o.place[0], o.place[1], objects.container_size, o.place[2]))
                .collect(),
            cube_size: objects.cube_size,
        }
    }
}

/// Turns samples into records; keeps the latest robot state for the derived channels.
pub struct Recorder {
    robot: Robot,
    layout: SceneLayout,
    config: LoggerConfig,
    odometry: Option<msgs::BaseOdometry>,
    truth: Option<msgs::SimTruth>,
    plan: Option<msgs::BasePlan>,
    target: Option<msgs::TargetEstimate>,
    reach_twist: Option<msgs::TwistCommand>,
    tool: Option<Isometry3<f64>>,
    trail: VecDeque<[f64; 3]>,
    last_tf_ns: Option<u64>,
    last_scene_ns: Option<u64>,
    images_seen: u64,
    /// Stamp of the last record written per thinned topic ([`LoggerConfig::raw_rate_hz`]).
    last_raw_ns: HashMap<String, u64>,
    /// Task names by the index a [`msgs::TaskCycle`] carries.
    replay_tasks: Vec<&'static str>,
    /// Topic names by the index a [`msgs::SampleRef`] carries.
    replay_topics: Vec<&'static str>,
    /// Cycle records dropped for an unknown index.
    bad_cycle_records: u64,
    /// Unix minus monotonic time, ns, for the foxglove header timestamps.
    unix_offset_ns: i128,
    /// Every process name seen in the supervisor's table.
    supervised: BTreeSet<String>,
    /// Names first seen since the last [`Recorder::take_new_processes`].
    new_processes: Vec<String>,
}

/// Whether at least `1 / rate_hz` passed between `last_ns` and `now_ns`.
fn due(last_ns: Option<u64>, now_ns: u64, rate_hz: f64) -> bool {
    last_ns.is_none_or(|last| now_ns.saturating_sub(last) as f64 >= 1e9 / rate_hz)
}

/// A foxglove vector.
fn vector(v: &nalgebra::Vector3<f64>) -> fg::Vector3 {
    fg::Vector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

/// A foxglove quaternion.
fn quaternion(q: &UnitQuaternion<f64>) -> fg::Quaternion {
    fg::Quaternion {
        x: q.i,
        y: q.j,
        z: q.k,
        w: q.w,
    }
}

/// A foxglove pose.
fn pose(iso: &Isometry3<f64>) -> fg::Pose {
    fg::Pose {
        position: Some(vector(&iso.translation.vector)),
        orientation: Some(quaternion(&iso.rotation)),
    }
}

/// A pose at `p` with heading `yaw` about z.
fn planar_pose(p: [f64; 3], yaw: f64) -> fg::Pose {
    pose(&Isometry3::new(
        nalgebra::Vector3::new(p[0], p[1], p[2]),
        nalgebra::Vector3::z() * yaw,
    ))
}

/// An RGBA color.
const fn rgba(r: f64, g: f64, b: f64, a: f64) -> Option<fg::Color> {
    Some(fg::Color { r, g, b, a })
}

/// An axis-aligned box.
fn cube(centre: [f64; 3], size: [f64; 3], color: Option<fg::Color>) -> fg::CubePrimitive {
    fg::CubePrimitive {
        pose: Some(planar_pose(centre, 0.0)),
        size: Some(fg::Vector3 {
            x: size[0],
            y: size[1],
            z: size[2],
        }),
        color,
    }
}

/// An arrow from `tail` with heading `yaw` and pitch `pitch`.
fn arrow(
    tail: [f64; 3],
    rotation: UnitQuaternion<f64>,
    length: f64,
    color: Option<fg::Color>,
) -> fg::ArrowPrimitive {
    fg::ArrowPrimitive {
        pose: Some(fg::Pose {
            position: Some(fg::Vector3 {
                x: tail[0],
                y: tail[1],
                z: tail[2],
            }),
            orientation: Some(quaternion(&rotation)),
        }),
        shaft_length: length * 0.8,
        shaft_diameter: 0.01,
        head_length: length * 0.2,
        head_diameter: 0.03,
        color,
    }
}

impl Recorder {
    /// A recorder for `robot` with the static scene `layout`.
    pub fn new(robot: Robot, layout: SceneLayout, config: LoggerConfig) -> Self {
        Self {
            robot,
            layout,
            config,
            odometry: None,
            truth: None,
            plan: None,
            target: None,
            reach_twist: None,
            tool: None,
            trail: VecDeque::new(),
            last_tf_ns: None,
            last_scene_ns: None,
            images_seen: 0,
            last_raw_ns: HashMap::new(),
            supervised: BTreeSet::new(),
            new_processes: Vec::new(),
            replay_tasks: motm_graph::GRAPH.iter().map(|t| t.name).collect(),
            replay_topics: motm_graph::published_topics()
                .iter()
                .map(|t| t.name)
                .collect(),
            bad_cycle_records: 0,
            unix_offset_ns: 0,
        }
    }

    /// Moves the foxglove messages' header timestamps from `CLOCK_MONOTONIC` to Unix time by
    /// `offset_ns` (Unix minus monotonic, taken once at start, as the log times are).
    pub fn set_unix_offset(&mut self, offset_ns: i128) {
        self.unix_offset_ns = offset_ns;
    }

    /// The foxglove header timestamp of monotonic `stamp_ns`: the sample's own time, in Unix
    /// time (so it matches the record's log time).
    fn timestamp(&self, stamp_ns: u64) -> Option<fg::Timestamp> {
        let unix = (i128::from(stamp_ns) + self.unix_offset_ns).max(0) as u64;
        Some(fg::Timestamp::from_ns(unix))
    }

    /// With [`LoggerConfig::replay`]: the raw bytes of `sample` of `service` on its replay
    /// channel.
    pub fn replay_sample<M: msgs::Message>(
        &mut self,
        service: &str,
        sample: &M,
        out: &mut Vec<Record>,
    ) {
        // The cycle records themselves go to the cycles channel instead.
        if self.config.replay && service != msgs::services::REPLAY_CYCLES {
            out.push(Record {
                topic: crate::replay_log::raw_channel(service),
                stamp_ns: sample.header().stamp_ns,
                payload: Payload::Raw(M::NAME, motm_graph::replay::raw_bytes(sample)),
            });
        }
    }

    /// With [`LoggerConfig::replay`]: a task cycle's record on the cycles channel, its indices
    /// turned into names (a record with an unknown index is counted and dropped, with a
    /// message).
    pub fn task_cycle(&mut self, sample: &msgs::TaskCycle, out: &mut Vec<Record>) {
        if !self.config.replay {
            return;
        }
        match crate::replay_log::CycleJson::from_message(
            sample,
            &self.replay_tasks,
            &self.replay_topics,
        ) {
            Ok(json) => out.push(Record {
                topic: crate::replay_log::CYCLES_TOPIC.into(),
                stamp_ns: sample.header.stamp_ns,
                payload: Payload::Json(serde_json::to_value(json).unwrap_or_default()),
            }),
            Err(e) => {
                if self.bad_cycle_records == 0 {
                    motm_bus::say!("logger: {e}");
                }
                self.bad_cycle_records += 1;
            }
        }
    }

    /// Cycle records dropped for an unknown index.
    pub fn bad_cycle_records(&self) -> u64 {
        self.bad_cycle_records
    }

    /// Whether a record on `topic` stamped `stamp_ns` is kept under
    /// [`LoggerConfig::raw_rate_hz`].
    fn admit(&mut self, topic: &str, stamp_ns: u64) -> bool {
        let last = self.last_raw_ns.get(topic).copied();
        if !due(last, stamp_ns, self.config.raw_rate_hz) {
            return false;
        }
        match self.last_raw_ns.get_mut(topic) {
            Some(last) => *last = stamp_ns,
            None => {
                self.last_raw_ns.insert(topic.to_owned(), stamp_ns);
            }
        }
        true
    }

    /// The JSON record of a sample on its service's channel (`/` + the service name), at most
    /// at [`LoggerConfig::raw_rate_hz`].
    pub fn raw<M: msgs::Message + ToJson>(
        &mut self,
        service: &str,
        sample: &M,
        out: &mut Vec<Record>,
    ) {
        let stamp_ns = sample.header().stamp_ns;
        if self.admit(service, stamp_ns) {
            out.push(Record {
                topic: format!("/{service}"),
                stamp_ns,
                payload: Payload::Json(sample.to_json()),
            });
        }
    }

    /// The supervisor's table: process names not seen before are kept for
    /// [`Recorder::take_new_processes`] (their heartbeats are then tapped).
    pub fn supervisor_status(&mut self, sample: &msgs::SupervisorStatus) {
        for process in sample.processes() {
            let name = process.name();
            if !name.is_empty() && !self.supervised.contains(name) {
                self.supervised.insert(name.to_owned());
                self.new_processes.push(name.to_owned());
            }
        }
    }

    /// Process names that appeared in the supervisor's table since the last call.
    pub fn take_new_processes(&mut self) -> Vec<String> {
        std::mem::take(&mut self.new_processes)
    }

    /// Base odometry: kept for the transforms.
    pub fn odometry(&mut self, sample: &msgs::BaseOdometry) {
        self.odometry = Some(*sample);
    }

    /// Sim truth: kept for the scene (cube positions); the scene is written at its rate.
    pub fn truth(&mut self, sample: &msgs::SimTruth, out: &mut Vec<Record>) {
        self.truth = Some(*sample);
        self.scene(sample.header.stamp_ns, out);
    }

    /// Base plan: kept for the scene (closest approach).
    pub fn plan(&mut self, sample: &msgs::BasePlan) {
        self.plan = Some(*sample);
    }

    /// The reacher's twist: kept for the scene (where the tool is sent).
    pub fn reach_twist(&mut self, sample: &msgs::TwistCommand) {
        self.reach_twist = Some(*sample);
    }

    /// Perception's target estimate: the target pose record.
    pub fn target(&mut self, sample: &msgs::TargetEstimate, out: &mut Vec<Record>) {
        self.target = Some(*sample);
        let stamp = sample.header.stamp_ns;
        let message = fg::PoseInFrame {
            timestamp: self.timestamp(stamp),
            frame_id: frames::WORLD.into(),
            pose: Some(planar_pose(sample.position, 0.0)),
        };
        out.push(Record::protobuf(
            topics::TARGET_POSE,
            stamp,
            fg::POSE_IN_FRAME,
            &message,
        ));
    }

    /// Arm joint state: the joint states record (at most at `raw_rate_hz`), and (at
    /// `tf_rate_hz`, once odometry is known) the transforms, the tool pose and the kinematics.
    pub fn joint_state(&mut self, sample: &msgs::JointState, out: &mut Vec<Record>) {
        let stamp = sample.header.stamp_ns;
        let n = (sample.joint_count as usize).min(self.robot.arm_dof());
        if self.admit(topics::JOINT_STATES, stamp) {
            self.joint_states(sample, n, out);
        }
        let Some(odometry) = self.odometry else {
            return;
        };
        if n != self.robot.arm_dof() || !due(self.last_tf_ns, stamp, self.config.tf_rate_hz) {
            return;
        }
        self.last_tf_ns = Some(stamp);
        let q = &sample.position[..n];
        let base = BasePose::new(odometry.x, odometry.y, odometry.yaw);
        out.push(Record::protobuf(
            topics::TF,
            stamp,
            fg::FRAME_TRANSFORMS,
            &self.transforms(stamp, &base, q),
        ));
        let fk = self.robot.forward(&base, q);
        let mut rates = DVector::zeros(fk.jacobian.ncols());
        rates[0] = odometry.omega;
        rates[1] = odometry.v;
        for i in 0..n {
            rates[2 + i] = sample.velocity[i];
        }
        let twist = &fk.jacobian * rates;
        let ee_speed = twist.fixed_rows::<3>(0).norm();
        let manipulability =
            motm_core::kinematics::manipulability(&Robot::arm_jacobian(&fk.jacobian));
        out.push(Record {
            topic: topics::KINEMATICS.into(),
            stamp_ns: stamp,
            payload: Payload::Json(json!({
                "ee_speed": ee_speed,
                "ee_velocity": [twist[0], twist[1], twist[2]],
                "base_speed": odometry.v,
                "base_yaw_rate": odometry.omega,
                "manipulability": manipulability,
            })),
        });
        let ee = fg::PoseInFrame {
            timestamp: self.timestamp(stamp),
            frame_id: frames::WORLD.into(),
            pose: Some(pose(&fk.tool_pose)),
        };
        out.push(Record::protobuf(
            topics::EE_POSE,
            stamp,
            fg::POSE_IN_FRAME,
            &ee,
        ));
        let p = fk.tool_pose.translation.vector;
        if self.trail.len() == self.config.trail_points.max(1) {
            self.trail.pop_front();
        }
        self.trail.push_back([p.x, p.y, p.z]);
        self.tool = Some(fk.tool_pose);
    }

    /// The joint states record of the first `n` joints of `sample`.
    fn joint_states(&self, sample: &msgs::JointState, n: usize, out: &mut Vec<Record>) {
        let joints = self
            .robot
            .arm_joints()
            .take(n)
            .enumerate()
            .map(|(i, joint)| fg::JointState {
                name: joint.name.clone(),
                position: Some(sample.position[i]),
                velocity: Some(sample.velocity[i]),
            })
            .collect();
        let states = fg::JointStates {
            timestamp: self.timestamp(sample.header.stamp_ns),
            joints,
        };
        out.push(Record::protobuf(
            topics::JOINT_STATES,
            sample.header.stamp_ns,
            fg::JOINT_STATES,
            &states,
        ));
    }

    /// World → base → each arm joint's frame (named after the joint) → tool, at monotonic
    /// time `stamp_ns`.
    pub fn transforms(&self, stamp_ns: u64, base: &BasePose, arm_q: &[f64]) -> fg::FrameTransforms {
        let timestamp = self.timestamp(stamp_ns);
        let transform = |parent: &str, child: &str, iso: &Isometry3<f64>| fg::FrameTransform {
            timestamp,
            parent_frame_id: parent.to_owned(),
            child_frame_id: child.to_owned(),
            translation: Some(vector(&iso.translation.vector)),
            rotation: Some(quaternion(&iso.rotation)),
        };
        let mut transforms = vec![transform(frames::WORLD, frames::BASE, &base.isometry())];
        let q = self.robot.full_q(arm_q);
        let base_joints = self.robot.chain.dof() - self.robot.arm_dof();
        // The virtual base joints sit at zero: their fixed part is folded into the first link.
        let mut pending = Isometry3::identity();
        let mut parent = frames::BASE.to_owned();
        for (i, (joint, &qi)) in self.robot.chain.joints.iter().zip(&q).enumerate() {
            pending = pending * joint.origin * joint.motion(qi);
            if i >= base_joints {
                transforms.push(transform(&parent, &joint.name, &pending));
                parent.clone_from(&joint.name);
                pending = Isometry3::identity();
            }
        }
        transforms.push(transform(
            &parent,
            frames::TOOL,
            &(pending * self.robot.chain.tool),
        ));
        fg::FrameTransforms { transforms }
    }

    /// The camera image as a `foxglove.RawImage`, every `image_every`-th one.
    pub fn camera(&mut self, sample: &msgs::CameraImage, out: &mut Vec<Record>) {
        self.images_seen += 1;
        if !(self.images_seen - 1).is_multiple_of(u64::from(self.config.image_every.max(1))) {
            return;
        }
        let image = fg::RawImage {
            timestamp: self.timestamp(sample.header.stamp_ns),
            frame_id: frames::CAMERA.into(),
            width: sample.width,
            height: sample.height,
            encoding: "rgb8".into(),
            step: sample.width * msgs::CAMERA_CHANNELS as u32,
            data: sample.pixels.to_vec(),
        };
        out.push(Record::protobuf(
            topics::CAMERA_IMAGE,
            sample.header.stamp_ns,
            fg::RAW_IMAGE,
            &image,
        ));
    }

    /// The scene at `stamp_ns`, at most at `scene_rate_hz`.
    fn scene(&mut self, stamp_ns: u64, out: &mut Vec<Record>) {
        if !due(self.last_scene_ns, stamp_ns, self.config.scene_rate_hz) {
            return;
        }
        self.last_scene_ns = Some(stamp_ns);
        let timestamp = self.timestamp(stamp_ns);
        let entity = |id: &str| fg::SceneEntity {
            timestamp,
            frame_id: frames::WORLD.into(),
            id: id.into(),
            arrows: Vec::new(),
            cubes: Vec::new(),
            spheres: Vec::new(),
            lines: Vec::new(),
        };
        let mut fixtures = entity("fixtures");
        for (centre, size) in &self.layout.platforms {
            fixtures
                .cubes
                .push(cube(*centre, *size, rgba(0.55, 0.45, 0.35, 1.0)));
        }
        for (centre, size) in &self.layout.containers {
            fixtures
                .cubes
                .push(cube(*centre, *size, rgba(0.2, 0.4, 0.8, 0.5)));
        }
        let mut cubes = entity("cubes");
        if let Some(truth) = &self.truth {
            let count = (truth.object_count as usize).min(msgs::MAX_SIM_OBJECTS);
            let side = self.layout.cube_size.max(0.01);
            for p in truth.object_positions[..3 * count].chunks_exact(3) {
                cubes.cubes.push(cube(
                    [p[0], p[1], p[2]],
                    [side; 3],
                    rgba(0.9, 0.1, 0.1, 1.0),
                ));
            }
        }
        let mut target = entity("target_estimate");
        if let Some(t) = &self.target {
            target.spheres.push(fg::SpherePrimitive {
                pose: Some(planar_pose(t.position, 0.0)),
                size: Some(fg::Vector3 {
                    x: 0.05,
                    y: 0.05,
                    z: 0.05,
                }),
                color: rgba(1.0, 0.8, 0.0, 0.6),
            });
        }
        let mut approach = entity("closest_approach");
        if let Some(plan) = &self.plan {
            // A planar pose `[x, y, yaw]` as an arrow just above the floor.
            let pose_arrow = |[x, y, yaw]: [f64; 3], length, color| {
                arrow(
                    [x, y, 0.02],
                    UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
                    length,
                    color,
                )
            };
            approach.arrows.push(pose_arrow(
                plan.closest_approach,
                0.4,
                rgba(0.1, 0.8, 0.2, 1.0),
            ));
            approach.arrows.push(pose_arrow(
                plan.range_entry_pose,
                0.25,
                rgba(0.1, 0.5, 0.9, 1.0),
            ));
        }
        let mut reacher = entity("reacher");
        reacher.lines.push(fg::LinePrimitive {
            r#type: fg::LINE_STRIP,
            pose: Some(planar_pose([0.0; 3], 0.0)),
            thickness: 2.0,
            scale_invariant: true,
            points: self
                .trail
                .iter()
                .map(|p| fg::Point3 {
                    x: p[0],
                    y: p[1],
                    z: p[2],
                })
                .collect(),
            color: rgba(0.9, 0.9, 0.9, 0.8),
        });
        if let (Some(tool), Some(twist)) = (&self.tool, &self.reach_twist) {
            let v = nalgebra::Vector3::new(twist.twist[0], twist.twist[1], twist.twist[2]);
            let speed = v.norm();
            if speed > 1e-6
                && let Some(rotation) =
                    UnitQuaternion::rotation_between(&nalgebra::Vector3::x(), &v)
            {
                let t = tool.translation.vector;
                // 1 s of motion at the commanded speed.
                reacher.arrows.push(arrow(
                    [t.x, t.y, t.z],
                    rotation,
                    speed,
                    rgba(1.0, 0.4, 0.0, 1.0),
                ));
            }
        }
        let update = fg::SceneUpdate {
            entities: vec![fixtures, cubes, target, approach, reacher],
        };
        out.push(Record::protobuf(
            topics::SCENE,
            stamp_ns,
            fg::SCENE_UPDATE,
            &update,
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::Message as _;

    fn recorder() -> Recorder {
        let dir = motm_core::resolve_config_dir(None);
        let robot = Robot::load(&dir, "frankie").unwrap();
        let scenario = Scenario::from_file(&motm_sim::scenario_path(&dir, "exp1-dynamic")).unwrap();
        Recorder::new(
            robot,
            SceneLayout::from_scenario(&scenario),
            LoggerConfig::default(),
        )
    }

    /// Composes a transform chain from `world` to `child`.
    fn world_from(transforms: &fg::FrameTransforms, child: &str) -> Isometry3<f64> {
        let t = transforms
            .transforms
            .iter()
            .find(|t| t.child_frame_id == child)
            .unwrap_or_else(|| panic!("no transform to {child}"));
        let v = t.translation.unwrap();
        let q = t.rotation.unwrap();
        let local = Isometry3::from_parts(
            nalgebra::Translation3::new(v.x, v.y, v.z),
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.x, q.y, q.z)),
        );
        if t.parent_frame_id == frames::WORLD {
            local
        } else {
            world_from(transforms, &t.parent_frame_id) * local
        }
    }

    #[test]
    fn processes_of_the_supervisor_table_are_reported_once_each() {
        let mut r = recorder();
        let mut status = msgs::SupervisorStatus::zeroed();
        status.process_count = 2;
        status.processes[0].set_name("reacher");
        status.processes[1].set_name("watchdog");
        r.supervisor_status(&status);
        assert_eq!(r.take_new_processes(), ["reacher", "watchdog"]);
        r.supervisor_status(&status);
        assert!(r.take_new_processes().is_empty());
        status.process_count = 3;
        status.processes[2].set_name("final-phase");
        r.supervisor_status(&status);
        assert_eq!(r.take_new_processes(), ["final-phase"]);
    }

    #[test]
    fn the_transform_tree_goes_world_base_every_arm_joint_tool_and_ends_at_the_tool_pose() {
        let r = recorder();
        let base = BasePose::new(1.0, -0.5, 0.3);
        let q = r.robot.config.ready_pose.clone();
        let tf = r.transforms(0, &base, &q);
        // world → base, one per arm joint, → tool.
        assert_eq!(tf.transforms.len(), 2 + r.robot.arm_dof());
        assert_eq!(tf.transforms[0].parent_frame_id, frames::WORLD);
        assert_eq!(tf.transforms[0].child_frame_id, frames::BASE);
        let tool = world_from(&tf, frames::TOOL);
        let expected = r.robot.tool_pose(&base, &q);
        assert!((tool.translation.vector - expected.translation.vector).norm() < 1e-9);
        assert!(tool.rotation.angle_to(&expected.rotation) < 1e-9);
    }

    #[test]
    fn foxglove_header_timestamps_are_the_samples_own_stamps_in_unix_time() {
        use prost::Message as _;
        let mut r = recorder();
        r.set_unix_offset(1_700_000_000_000_000_000);
        let mut odometry = msgs::BaseOdometry::zeroed();
        odometry.header.stamp_ns = 5;
        r.odometry(&odometry);
        let mut state = msgs::JointState::zeroed();
        state.joint_count = r.robot.arm_dof() as u32;
        state.header.stamp_ns = 2_500_000_001;
        let mut out = Vec::new();
        r.joint_state(&state, &mut out);
        let mut target = msgs::TargetEstimate::zeroed();
        target.header.stamp_ns = state.header.stamp_ns;
        r.target(&target, &mut out);
        let expected = fg::Timestamp {
            seconds: 1_700_000_002,
            nanos: 500_000_001,
        };
        let mut checked = Vec::new();
        for record in &out {
            let Payload::Protobuf(schema, bytes) = &record.payload else {
                continue;
            };
            let stamps: Vec<Option<fg::Timestamp>> = match schema.name {
                "foxglove.JointStates" => {
                    vec![fg::JointStates::decode(bytes.as_slice()).unwrap().timestamp]
                }
                "foxglove.PoseInFrame" => {
                    vec![fg::PoseInFrame::decode(bytes.as_slice()).unwrap().timestamp]
                }
                "foxglove.FrameTransforms" => fg::FrameTransforms::decode(bytes.as_slice())
                    .unwrap()
                    .transforms
                    .iter()
                    .map(|t| t.timestamp)
                    .collect(),
                other => panic!("unexpected schema {other}"),
            };
            assert!(!stamps.is_empty());
            for stamp in stamps {
                assert_eq!(stamp, Some(expected), "{}", record.topic);
            }
            checked.push(record.topic.clone());
        }
        for topic in [
            topics::JOINT_STATES,
            topics::TF,
            topics::EE_POSE,
            topics::TARGET_POSE,
        ] {
            assert!(checked.iter().any(|t| t == topic), "{topic}: {checked:?}");
        }
    }

    #[test]
    fn joint_states_come_at_once_and_transforms_wait_for_odometry_then_follow_their_rate() {
        let mut r = recorder();
        let mut state = msgs::JointState::zeroed();
        state.joint_count = r.robot.arm_dof() as u32;
        state.position[..7].copy_from_slice(&r.robot.config.ready_pose);
        state.header.stamp_ns = 1_000_000_000;
        let mut out = Vec::new();
        r.joint_state(&state, &mut out);
        let topics_of = |out: &[Record]| out.iter().map(|r| r.topic.clone()).collect::<Vec<_>>();
        assert_eq!(topics_of(&out), [topics::JOINT_STATES]);
        let mut odometry = msgs::BaseOdometry::zeroed();
        odometry.v = 0.3;
        r.odometry(&odometry);
        out.clear();
        state.header.stamp_ns += 10_000_000;
        r.joint_state(&state, &mut out);
        assert_eq!(
            topics_of(&out),
            [
                topics::JOINT_STATES,
                topics::TF,
                topics::KINEMATICS,
                topics::EE_POSE
            ]
        );
        // Every record carries the joint state's own stamp.
        assert!(out.iter().all(|rec| rec.stamp_ns == state.header.stamp_ns));
        let Payload::Json(kinematics) = &out[2].payload else {
            panic!("kinematics is JSON");
        };
        // Arm at rest, base at 0.3 m/s straight ahead: the tool moves at 0.3 m/s.
        assert!((kinematics["ee_speed"].as_f64().unwrap() - 0.3).abs() < 1e-9);
        assert!(kinematics["manipulability"].as_f64().unwrap() > 0.0);
        // 5 ms later: past the 250 Hz joint-state period, within the 50 Hz transform period.
        state.header.stamp_ns += 5_000_000;
        out.clear();
        r.joint_state(&state, &mut out);
        assert_eq!(topics_of(&out), [topics::JOINT_STATES]);
        // 1 ms later still: within both periods, nothing.
        state.header.stamp_ns += 1_000_000;
        out.clear();
        r.joint_state(&state, &mut out);
        assert!(out.is_empty());
        // The trail grew by one tool position.
        assert_eq!(r.trail.len(), 1);
    }

    #[test]
    fn every_fifth_camera_image_is_kept_as_rgb8() {
        let mut r = recorder();
        let mut image: Box<msgs::CameraImage> = Box::new(msgs::CameraImage::zeroed());
        image.width = msgs::CAMERA_WIDTH as u32;
        image.height = msgs::CAMERA_HEIGHT as u32;
        let mut out = Vec::new();
        for _ in 0..10 {
            r.camera(&image, &mut out);
        }
        assert_eq!(out.len(), 2);
        let Payload::Protobuf(schema, bytes) = &out[0].payload else {
            panic!("images are protobuf");
        };
        assert_eq!(*schema, fg::RAW_IMAGE);
        let decoded = <fg::RawImage as prost::Message>::decode(bytes.as_slice()).unwrap();
        assert_eq!(decoded.encoding, "rgb8");
        assert_eq!(decoded.step, 3 * msgs::CAMERA_WIDTH as u32);
        assert_eq!(decoded.data.len(), msgs::CAMERA_IMAGE_BYTES);
    }
}
