//! The things in the world besides the robot: 30 mm cubes on platforms (static, on a random
//! smooth path, or on a line), the containers they are dropped into, and buttons.
//!
//! The layout is derived from the scenario: each cube stands on its own square platform centred
//! under its start position, each distinct drop point is the rim centre of a square container
//! standing on the floor, and each button sits on a small pedestal.

use nalgebra::{Isometry3, UnitQuaternion, Vector2, Vector3};
use serde::Deserialize;

use crate::geometry::OrientedBox;
use crate::random::SimRng;
use crate::scenario::{Motion, Scenario, ScenarioObject};
use motm_core::wrap_angle;

/// Sizes of the objects and the parameters of their motion.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObjectConfig {
    /// Edge length of the cubes, m (30 mm in the paper).
    pub cube_size: f64,
    /// Side of the square platform under each cube, m. 0.3 m: a small stand, so a base passing
    /// the cube at r_C = 0.6 m clears it wherever the cube has moved on it.
    pub platform_size: f64,
    /// Half side of the square, centred on the cube's start, within which a moving cube travels,
    /// m. Chosen well inside the platform so a moving cube never falls off on its own.
    pub travel_half_extent: f64,
    /// Standard deviation of the turn rate of a random path, rad/s (an Ornstein–Uhlenbeck
    /// process: smooth, different for each seed).
    pub random_turn_rate_std: f64,
    /// Correlation time of the random turn rate, s.
    pub random_turn_time_constant: f64,
    /// Gain that steers a random path back toward its start when it nears the edge of its
    /// travel square, rad/s per rad of heading error.
    pub random_return_gain: f64,
    /// Standard deviation of a cube's initial yaw about world z, rad (cubes are set down square
    /// to the world axes, by hand, within this error).
    pub initial_yaw_std: f64,
    /// Inner side of the square containers, m.
    pub container_size: f64,
    /// Wall thickness of the containers, m.
    pub container_wall: f64,
    /// Radius of a button's cap, m: the tool point must be within it to push the button.
    pub button_radius: f64,
    /// Height of a button's cap above its pedestal, m.
    pub button_height: f64,
    /// Side of the square pedestal under each button, m.
    pub button_pedestal_size: f64,
    /// Thickness of the red marking on top of a button's cap, m. The rest of the cap is dark
    /// grey, so the palm camera sees (almost) only the top face in red and perception, which
    /// intersects the blob's ray with the plane of the cap's top, is off by at most this times
    /// the tangent of the viewing angle (0.002: under 2 mm at 45°).
    pub button_marking_thickness: f64,
    /// How far a knocked-off cube lands beyond the edge of its platform, m.
    pub knock_off_throw: f64,
    /// Gravity for falling cubes, m/s².
    pub gravity: f64,
}

impl Default for ObjectConfig {
    fn default() -> Self {
        Self {
            cube_size: 0.03,
            platform_size: 0.3,
            travel_half_extent: 0.1,
            random_turn_rate_std: 0.5,
            random_turn_time_constant: 1.0,
            random_return_gain: 2.0,
            initial_yaw_std: 0.05,
            container_size: 0.3,
            container_wall: 0.01,
            button_radius: 0.03,
            button_height: 0.02,
            button_pedestal_size: 0.15,
            button_marking_thickness: 0.002,
            knock_off_throw: 0.1,
            gravity: 9.81,
        }
    }
}

/// Where a cube is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjectState {
    /// On its platform, static or moving.
    OnPlatform,
    /// Held between the gripper fingers.
    Held,
    /// Released and falling.
    Falling,
    /// Landed in its container (a successful drop).
    Placed,
    /// Landed outside its container (a failed drop).
    DroppedOutside,
    /// Knocked off its platform by the gripper.
    KnockedOff,
}

/// The true state of one cube.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectTruth {
    /// World pose of the cube centre (orientation included: a held cube tilts with the tool).
    pub pose: Isometry3<f64>,
    /// World velocity of the cube centre, m/s.
    pub velocity: Vector3<f64>,
    /// Where the cube is.
    pub state: ObjectState,
    /// Simulation time at which the cube landed in its container, s.
    pub placed_time: Option<f64>,
}

impl ObjectTruth {
    /// World position of the cube centre.
    pub fn position(&self) -> Vector3<f64> {
        self.pose.translation.vector
    }

    /// Yaw of the cube about world z (heading of its x face normal projected on the floor).
    pub fn yaw(&self) -> f64 {
        let x_axis = self.pose.rotation * Vector3::x();
        x_axis.y.atan2(x_axis.x)
    }
}

/// A square container standing on the floor, open at the top.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Container {
    /// World position of the centre of the opening, at rim height, m.
    pub rim_center: Vector3<f64>,
    /// Half the inner side, m.
    pub inner_half: f64,
    /// Wall thickness, m.
    pub wall: f64,
}

impl Container {
    /// Whether a cube of half size `cube_half` centred at `position` fits inside the opening
    /// (horizontally).
    pub fn footprint_holds(&self, position: &Vector3<f64>, cube_half: f64) -> bool {
        let limit = self.inner_half - cube_half;
        (position.x - self.rim_center.x).abs() <= limit
            && (position.y - self.rim_center.y).abs() <= limit
    }

    /// The container's outer box, as an obstacle for the base.
    pub fn obstacle(&self) -> OrientedBox {
        let half = self.inner_half + self.wall;
        OrientedBox::upright(
            self.rim_center.x,
            self.rim_center.y,
            0.0,
            half,
            half,
            self.rim_center.z,
        )
    }
}

/// A push button on a pedestal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Button {
    /// World position of the centre of the cap's top face when not pushed, m.
    pub top_center: Vector3<f64>,
    /// Travel that counts as a press, m.
    pub depth: f64,
    /// Cap radius, m.
    pub radius: f64,
    /// Height of the cap above its pedestal (its full stroke), m.
    pub height: f64,
}

/// The true state of one button.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ButtonTruth {
    /// How far the cap is pushed down now, m.
    pub travel: f64,
    /// Whether the button has been pressed (latched).
    pub pressed: bool,
    /// Simulation time of the press, s.
    pub pressed_time: Option<f64>,
}

/// The fixed geometry of the world: platforms, containers and buttons.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Edge length of the cubes, m.
    pub cube_size: f64,
    /// Platforms under the cubes and pedestals under the buttons (upright boxes on the floor).
    pub platforms: Vec<OrientedBox>,
    /// The containers, one per distinct drop point.
    pub containers: Vec<Container>,
    /// For each object, the index of its container in `containers`.
    pub object_container: Vec<usize>,
    /// The buttons.
    pub buttons: Vec<Button>,
}

impl Layout {
    /// The layout of `scenario`.
    pub fn new(scenario: &Scenario, config: &ObjectConfig) -> Self {
        let half_cube = 0.5 * config.cube_size;
        let half_platform = 0.5 * config.platform_size;
        let mut platforms: Vec<OrientedBox> = scenario
            .objects
            .iter()
            .map(|o| {
                let [x, y, z] = o.position;
                OrientedBox::upright(
                    x,
                    y,
                    0.0,
                    half_platform,
                    half_platform,
                    (z - half_cube).max(0.0),
                )
            })
            .collect();
        let half_pedestal = 0.5 * config.button_pedestal_size;
        platforms.extend(scenario.buttons.iter().map(|b| {
            let [x, y, z] = b.position;
            OrientedBox::upright(
                x,
                y,
                0.0,
                half_pedestal,
                half_pedestal,
                z - config.button_height,
            )
        }));
        let mut containers: Vec<Container> = Vec::new();
        let object_container = scenario
            .objects
            .iter()
            .map(|o| {
                let rim_center = Vector3::from(o.place);
                match containers.iter().position(|c| c.rim_center == rim_center) {
                    Some(index) => index,
                    None => {
                        containers.push(Container {
                            rim_center,
                            inner_half: 0.5 * config.container_size,
                            wall: config.container_wall,
                        });
                        containers.len() - 1
                    }
                }
            })
            .collect();
        let buttons = scenario
            .buttons
            .iter()
            .map(|b| Button {
                top_center: Vector3::from(b.position),
                depth: b.depth,
                radius: config.button_radius,
                height: config.button_height,
            })
            .collect();
        Self {
            cube_size: config.cube_size,
            platforms,
            containers,
            object_container,
            buttons,
        }
    }

    /// Every obstacle the base may collide with: platforms, pedestals and containers.
    pub fn obstacles(&self) -> impl Iterator<Item = OrientedBox> + '_ {
        self.platforms
            .iter()
            .copied()
            .chain(self.containers.iter().map(Container::obstacle))
    }
}

/// How a cube on its platform moves: the hidden motion model the robot is never told.
#[derive(Debug, Clone)]
pub(crate) struct CubeMover {
    motion: Motion,
    speed: f64,
    heading: f64,
    turn_rate: f64,
    home: Vector2<f64>,
}

impl CubeMover {
    /// The mover of `object`; draws a random path's initial heading from `constants` when the
    /// scenario gives none.
    pub(crate) fn new(object: &ScenarioObject, constants: &mut SimRng) -> Self {
        let drawn_heading = constants.uniform_in(-std::f64::consts::PI, std::f64::consts::PI);
        Self {
            motion: object.motion,
            speed: object.motion_speed(),
            heading: object.heading.unwrap_or(drawn_heading),
            turn_rate: 0.0,
            home: Vector2::new(object.position[0], object.position[1]),
        }
    }

    /// Moves a cube on its platform by one step of `dt` seconds; returns its new velocity.
    pub(crate) fn step(
        &mut self,
        position: &mut Vector3<f64>,
        dt: f64,
        rng: &mut SimRng,
        config: &ObjectConfig,
    ) -> Vector3<f64> {
        if self.motion == Motion::Static || self.speed == 0.0 {
            return Vector3::zeros();
        }
        if self.motion == Motion::Random {
            self.turn(position, dt, rng, config);
        }
        let extent = config.travel_half_extent;
        let start = Vector2::new(position.x, position.y);
        let step = Vector2::new(self.heading.cos(), self.heading.sin()) * (self.speed * dt);
        let mut next = start + step;
        for axis in 0..2 {
            let offset = next[axis] - self.home[axis];
            if offset.abs() > extent {
                next[axis] = self.home[axis] + extent * offset.signum();
                match self.motion {
                    // A random path bounces off the edge of its travel square.
                    Motion::Random => {
                        self.heading = if axis == 0 {
                            wrap_angle(std::f64::consts::PI - self.heading)
                        } else {
                            -self.heading
                        }
                    }
                    // A line stops at the end of its travel.
                    _ => self.speed = 0.0,
                }
            }
        }
        position.x = next.x;
        position.y = next.y;
        let moved = next - start;
        Vector3::new(moved.x / dt, moved.y / dt, 0.0)
    }

    /// Updates the random path's heading: an Ornstein–Uhlenbeck turn rate plus a pull back
    /// toward the start when the cube nears the edge of its travel square.
    fn turn(&mut self, position: &Vector3<f64>, dt: f64, rng: &mut SimRng, config: &ObjectConfig) {
        let tau = config.random_turn_time_constant;
        let diffusion = config.random_turn_rate_std * (2.0 * dt / tau).sqrt();
        self.turn_rate += -self.turn_rate / tau * dt + diffusion * rng.standard_normal();
        let offset = Vector2::new(position.x, position.y) - self.home;
        let near_edge = offset.amax() > 0.6 * config.travel_half_extent;
        let pull = if near_edge {
            let home_heading = (-offset.y).atan2(-offset.x);
            config.random_return_gain * wrap_angle(home_heading - self.heading)
        } else {
            0.0
        };
        self.heading = wrap_angle(self.heading + (self.turn_rate + pull) * dt);
    }
}

/// The pose of a cube resting flat with the given yaw.
pub(crate) fn resting_pose(position: Vector3<f64>, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        position.into(),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Stream;

    fn object(motion: Motion, speed: Option<f64>, heading: Option<f64>) -> ScenarioObject {
        ScenarioObject {
            position: [2.0, 0.0, 0.45],
            motion,
            speed,
            heading,
            place: [4.0, 0.0, 0.35],
        }
    }

    fn run(object: &ScenarioObject, seed: u64, seconds: f64) -> Vec<Vector3<f64>> {
        let config = ObjectConfig::default();
        let mut constants = SimRng::new(seed, Stream::TrialConstants);
        let mut rng = SimRng::new(seed, Stream::ObjectMotion);
        let mut mover = CubeMover::new(object, &mut constants);
        let mut position = Vector3::from(object.position);
        let dt = 0.001;
        (0..(seconds / dt) as usize)
            .map(|_| {
                mover.step(&mut position, dt, &mut rng, &config);
                position
            })
            .collect()
    }

    #[test]
    fn random_path_keeps_speed_stays_in_travel_square_and_depends_on_seed() {
        let cube = object(Motion::Random, Some(0.03), None);
        let path = run(&cube, 11, 30.0);
        let home = Vector3::from(cube.position);
        let extent = ObjectConfig::default().travel_half_extent;
        for p in &path {
            assert!(
                (p.x - home.x).abs() <= extent + 1e-12 && (p.y - home.y).abs() <= extent + 1e-12
            );
            assert_eq!(p.z, home.z);
        }
        // Average speed over each second is the set speed, less a little for curvature.
        for second in 1..30 {
            let d = (path[second * 1000 - 1] - path[(second - 1) * 1000]).norm();
            assert!(d > 0.02 && d <= 0.0301, "second {second}: moved {d}");
        }
        let other = run(&cube, 12, 30.0);
        assert!((path[29_999] - other[29_999]).norm() > 1e-3);
        assert_eq!(path, run(&cube, 11, 30.0));
    }

    #[test]
    fn line_moves_along_heading_then_stops_at_end_of_travel() {
        let cube = object(Motion::Line, Some(0.03), Some(std::f64::consts::FRAC_PI_2));
        let path = run(&cube, 1, 10.0);
        assert!((path[999] - Vector3::new(2.0, 0.03, 0.45)).norm() < 1e-9);
        let end = Vector3::new(2.0, ObjectConfig::default().travel_half_extent, 0.45);
        assert!((path[9_999] - end).norm() < 1e-9);
    }

    #[test]
    fn static_cube_does_not_move() {
        let cube = object(Motion::Static, None, None);
        assert!(
            run(&cube, 5, 2.0)
                .iter()
                .all(|p| *p == Vector3::new(2.0, 0.0, 0.45))
        );
    }

    #[test]
    fn container_footprint_accounts_for_cube_size() {
        let c = Container {
            rim_center: Vector3::new(4.0, 0.0, 0.35),
            inner_half: 0.15,
            wall: 0.01,
        };
        assert!(c.footprint_holds(&Vector3::new(4.13, 0.0, 0.2), 0.015));
        assert!(!c.footprint_holds(&Vector3::new(4.14, 0.0, 0.2), 0.015));
    }
}
