//! Routes the base can drive: Dubins paths (shortest paths of a forward-only vehicle with a
//! minimum turning radius between two poses) and the pure-pursuit look-ahead that follows them.
//!
//! A Dubins path is three segments, each a left arc (L), a right arc (R) or a straight line (S),
//! in one of the six words LSL, RSR, LSR, RSL, RLR, LRL; the shortest of them is the shortest
//! path (Dubins 1957). The closed forms are the standard ones of Shkel and Lumelsky (2001), in the
//! frame where the start is at the origin and the goal on the x axis, lengths in units of the
//! turning radius. The formulas are short, so they are written here rather than taken from a
//! crate (the maintained `dubins_paths` works on `glam` types, a second linear-algebra stack
//! beside nalgebra).

use std::f64::consts::TAU;

use nalgebra::Vector2;

use crate::kinematics::BasePose;
use crate::types::wrap_angle;

/// One segment's kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Segment {
    /// An arc turning left (counter-clockwise) at the turning radius.
    Left,
    /// A straight line.
    Straight,
    /// An arc turning right (clockwise) at the turning radius.
    Right,
}

/// A Dubins path: a start pose, a turning radius and three segments with their lengths in metres,
/// optionally after a straight lead (drive on first, then turn: among obstacles the shortest
/// clear route is often not a Dubins word from the start itself).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DubinsPath {
    /// Where the path starts.
    pub start: BasePose,
    /// Length of the straight driven from `start` before the three segments, m.
    pub lead: f64,
    /// Turning radius of the arcs, m.
    pub radius: f64,
    /// The three segments and their lengths, m.
    pub segments: [(Segment, f64); 3],
}

fn mod_tau(angle: f64) -> f64 {
    angle.rem_euclid(TAU)
}

impl DubinsPath {
    /// The shortest Dubins path from `start` to `goal` with turning radius `radius` (> 0).
    pub fn shortest(start: &BasePose, goal: &BasePose, radius: f64) -> Self {
        Self::words(start, goal, radius)
            .into_iter()
            .next()
            .unwrap_or(Self {
                start: *start,
                lead: 0.0,
                radius,
                segments: [(Segment::Straight, 0.0); 3],
            })
    }

    /// Every Dubins path (one per word that exists) from `start` to `goal`, shortest first: when
    /// the shortest is blocked, the next may not be.
    pub fn words(start: &BasePose, goal: &BasePose, radius: f64) -> Vec<Self> {
        use Segment::{Left as L, Right as R, Straight as S};
        let dx = goal.x - start.x;
        let dy = goal.y - start.y;
        let d = (dx * dx + dy * dy).sqrt() / radius;
        let theta = if d > 1e-12 {
            mod_tau(dy.atan2(dx))
        } else {
            0.0
        };
        let alpha = mod_tau(start.yaw - theta);
        let beta = mod_tau(goal.yaw - theta);
        let (sa, ca) = alpha.sin_cos();
        let (sb, cb) = beta.sin_cos();
        let c_ab = (alpha - beta).cos();
        let d_sq = d * d;
        let mut words: Vec<([Segment; 3], [f64; 3])> = Vec::with_capacity(6);
        // LSL
        let p_sq = 2.0 + d_sq - 2.0 * c_ab + 2.0 * d * (sa - sb);
        if p_sq >= 0.0 {
            let tmp = (cb - ca).atan2(d + sa - sb);
            words.push((
                [L, S, L],
                [mod_tau(tmp - alpha), p_sq.sqrt(), mod_tau(beta - tmp)],
            ));
        }
        // RSR
        let p_sq = 2.0 + d_sq - 2.0 * c_ab + 2.0 * d * (sb - sa);
        if p_sq >= 0.0 {
            let tmp = (ca - cb).atan2(d - sa + sb);
            words.push((
                [R, S, R],
                [mod_tau(alpha - tmp), p_sq.sqrt(), mod_tau(tmp - beta)],
            ));
        }
        // LSR
        let p_sq = -2.0 + d_sq + 2.0 * c_ab + 2.0 * d * (sa + sb);
        if p_sq >= 0.0 {
            let p = p_sq.sqrt();
            let tmp = (-ca - cb).atan2(d + sa + sb) - (-2.0f64).atan2(p);
            words.push(([L, S, R], [mod_tau(tmp - alpha), p, mod_tau(tmp - beta)]));
        }
        // RSL
        let p_sq = -2.0 + d_sq + 2.0 * c_ab - 2.0 * d * (sa + sb);
        if p_sq >= 0.0 {
            let p = p_sq.sqrt();
            let tmp = (ca + cb).atan2(d - sa - sb) - 2.0f64.atan2(p);
            words.push(([R, S, L], [mod_tau(alpha - tmp), p, mod_tau(beta - tmp)]));
        }
        // RLR
        let c = (6.0 - d_sq + 2.0 * c_ab + 2.0 * d * (sa - sb)) / 8.0;
        if c.abs() <= 1.0 {
            let phi = c.acos();
            let p = mod_tau(TAU - phi);
            let t = mod_tau(alpha - (ca - cb).atan2(d - sa + sb) + p / 2.0);
            words.push(([R, L, R], [t, p, mod_tau(alpha - beta - t + p)]));
        }
        // LRL
        let c = (6.0 - d_sq + 2.0 * c_ab + 2.0 * d * (sb - sa)) / 8.0;
        if c.abs() <= 1.0 {
            let phi = c.acos();
            let p = mod_tau(TAU - phi);
            let t = mod_tau(-alpha - (ca - cb).atan2(d + sa - sb) + p / 2.0);
            words.push(([L, R, L], [t, p, mod_tau(beta - alpha - t + p)]));
        }
        // LSL or RSR always exists (one of their p² is ≥ 0), so the list is never empty.
        let mut paths: Vec<Self> = words
            .into_iter()
            .map(|(kinds, lengths)| Self {
                start: *start,
                lead: 0.0,
                radius,
                segments: [
                    (kinds[0], lengths[0] * radius),
                    (kinds[1], lengths[1] * radius),
                    (kinds[2], lengths[2] * radius),
                ],
            })
            .collect();
        paths.sort_by(|a, b| a.length().total_cmp(&b.length()));
        paths
    }

    /// Every Dubins path from `start` driven `lead` metres straight on to `goal`, shortest
    /// first (the lead included in each).
    pub fn words_after(start: &BasePose, lead: f64, goal: &BasePose, radius: f64) -> Vec<Self> {
        let from = advance(start, Segment::Straight, lead, radius);
        let mut paths = Self::words(&from, goal, radius);
        for path in &mut paths {
            path.start = *start;
            path.lead = lead;
        }
        paths
    }

    /// Total length, m.
    pub fn length(&self) -> f64 {
        self.lead + self.segments.iter().map(|s| s.1).sum::<f64>()
    }

    /// Total turning along the path, rad (the arcs' lengths over the radius).
    pub fn turning(&self) -> f64 {
        self.segments
            .iter()
            .filter(|(kind, _)| *kind != Segment::Straight)
            .map(|(_, length)| length / self.radius)
            .sum()
    }

    /// The pose `distance` metres along the path (clamped to the path; beyond its end, straight
    /// on along the final heading).
    pub fn sample(&self, distance: f64) -> BasePose {
        let mut pose = self.start;
        let mut left = distance.max(0.0);
        for (kind, length) in self.pieces() {
            let s = left.min(length);
            pose = advance(&pose, kind, s, self.radius);
            left -= s;
            if left <= 0.0 {
                return pose;
            }
        }
        advance(&pose, Segment::Straight, left, self.radius)
    }

    /// A sampler of many poses along the path: each bit for bit [`DubinsPath::sample`]'s, the
    /// poses at the joints between the pieces worked out once rather than per sample.
    pub fn sampler(&self) -> PathSampler<'_> {
        let mut joints = [self.start; 5];
        for (i, (kind, length)) in self.pieces().enumerate() {
            joints[i + 1] = advance(&joints[i], kind, length, self.radius);
        }
        PathSampler { path: self, joints }
    }

    /// The straight lead and the three segments, in order.
    fn pieces(&self) -> impl Iterator<Item = (Segment, f64)> {
        std::iter::once((Segment::Straight, self.lead)).chain(self.segments)
    }
}

/// Poses along a [`DubinsPath`] ([`DubinsPath::sampler`]).
#[derive(Debug, Clone, Copy)]
pub struct PathSampler<'a> {
    path: &'a DubinsPath,
    /// The start and the pose at the end of each piece (lead, then the three segments).
    joints: [BasePose; 5],
}

impl PathSampler<'_> {
    /// [`DubinsPath::sample`] at `distance`, m: the same steps, but a piece driven whole (the
    /// same length, to the bit) ends at its stored joint.
    pub fn sample(&self, distance: f64) -> BasePose {
        let mut left = distance.max(0.0);
        for (i, (kind, length)) in self.path.pieces().enumerate() {
            let s = left.min(length);
            let pose = if s.to_bits() == length.to_bits() {
                self.joints[i + 1]
            } else {
                advance(&self.joints[i], kind, s, self.path.radius)
            };
            left -= s;
            if left <= 0.0 {
                return pose;
            }
        }
        advance(&self.joints[4], Segment::Straight, left, self.path.radius)
    }
}

/// The pose reached from `pose` along one segment of kind `kind` and length `s`, m.
pub fn advance(pose: &BasePose, kind: Segment, s: f64, radius: f64) -> BasePose {
    let (sin, cos) = pose.yaw.sin_cos();
    match kind {
        Segment::Straight => BasePose::new(pose.x + s * cos, pose.y + s * sin, pose.yaw),
        Segment::Left => {
            let yaw = pose.yaw + s / radius;
            BasePose::new(
                pose.x + radius * (yaw.sin() - sin),
                pose.y - radius * (yaw.cos() - cos),
                wrap_angle(yaw),
            )
        }
        Segment::Right => {
            let yaw = pose.yaw - s / radius;
            BasePose::new(
                pose.x - radius * (yaw.sin() - sin),
                pose.y + radius * (yaw.cos() - cos),
                wrap_angle(yaw),
            )
        }
    }
}

/// Pure pursuit: the yaw rate that brings a base at `base`, moving at `speed`, onto the arc
/// through `point` (the curvature `2·sin α / L`, α the bearing of the point, L its distance).
pub fn pursue(base: &BasePose, point: Vector2<f64>, speed: f64) -> f64 {
    let offset = point - Vector2::new(base.x, base.y);
    let distance = offset.norm();
    if distance < 1e-9 {
        return 0.0;
    }
    let alpha = wrap_angle(offset.y.atan2(offset.x) - base.yaw);
    2.0 * speed * alpha.sin() / distance
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Asserts that `path` ends on `goal`.
    fn assert_ends_at(path: &DubinsPath, goal: &BasePose) {
        let end = path.sample(path.length());
        assert!(close(&end, goal), "{path:?} ends at {end:?}, not {goal:?}");
    }

    fn close(a: &BasePose, b: &BasePose) -> bool {
        (a.x - b.x).abs() < 1e-6
            && (a.y - b.y).abs() < 1e-6
            && wrap_angle(a.yaw - b.yaw).abs() < 1e-6
    }

    #[test]
    fn every_shortest_path_ends_at_its_goal() {
        let starts = [
            BasePose::new(0.0, 0.0, 0.0),
            BasePose::new(1.0, -2.0, 2.5),
            BasePose::new(-0.3, 0.2, -1.2),
        ];
        for start in starts {
            for i in 0..12 {
                for j in 0..8 {
                    let r = 0.2 + 0.4 * i as f64;
                    let a = j as f64 * 0.8;
                    let goal = BasePose::new(
                        start.x + r * a.cos(),
                        start.y + r * a.sin(),
                        wrap_angle(1.3 * j as f64 - 0.7 * i as f64),
                    );
                    assert_ends_at(&DubinsPath::shortest(&start, &goal, 0.6), &goal);
                }
            }
        }
    }

    #[test]
    fn shortest_paths_between_scattered_poses_end_at_their_goals() {
        // A fixed pseudo-random sequence of starts and goals up to 8 m apart.
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..5000 {
            let start = BasePose::new(8.0 * next() - 4.0, 8.0 * next() - 4.0, TAU * next() - 3.2);
            let goal = BasePose::new(8.0 * next() - 4.0, 8.0 * next() - 4.0, TAU * next() - 3.2);
            let radius = 0.3 + next();
            let paths = DubinsPath::words(&start, &goal, radius);
            assert!(paths.windows(2).all(|w| w[0].length() <= w[1].length()));
            let led = DubinsPath::words_after(&start, 0.7, &goal, radius);
            assert!(led.iter().all(|p| p.lead == 0.7 && p.start == start));
            let paths = paths.into_iter().chain(led);
            for path in paths {
                assert_ends_at(&path, &goal);
            }
        }
    }

    #[test]
    fn a_goal_straight_ahead_is_a_straight_line_and_one_behind_a_turn_around() {
        let start = BasePose::new(0.0, 0.0, 0.0);
        let ahead = DubinsPath::shortest(&start, &BasePose::new(3.0, 0.0, 0.0), 0.5);
        assert!((ahead.length() - 3.0).abs() < 1e-9);
        let behind =
            DubinsPath::shortest(&start, &BasePose::new(0.0, 2.0, std::f64::consts::PI), 0.5);
        // Half a turn of radius 0.5 and the 1 m between the two half-circles' ends.
        assert!((behind.length() - (std::f64::consts::PI * 0.5 + 1.0)).abs() < 1e-6);
        assert_eq!(behind.segments[0].0, Segment::Left);
    }

    #[test]
    fn the_sampler_gives_the_poses_sample_gives_to_the_bit() {
        let start = BasePose::new(0.4, -1.1, 2.2);
        let goals = [
            BasePose::new(3.0, 1.0, -0.5),
            BasePose::new(-1.0, 0.5, 1.0),
            BasePose::new(0.4, -1.1, 2.2),
        ];
        for goal in goals {
            for path in DubinsPath::words_after(&start, 0.35, &goal, 0.6) {
                let sampler = path.sampler();
                for k in -3..700 {
                    let s = k as f64 * 0.0137;
                    let (a, b) = (path.sample(s), sampler.sample(s));
                    assert_eq!(
                        [a.x, a.y, a.yaw].map(f64::to_bits),
                        [b.x, b.y, b.yaw].map(f64::to_bits),
                        "{s} m along {path:?}"
                    );
                }
                // Exactly at the joints too.
                let mut at = 0.0;
                for (_, length) in path.pieces() {
                    at += length;
                    assert_eq!(path.sample(at), sampler.sample(at));
                }
            }
        }
    }

    #[test]
    fn pursuit_turns_toward_the_point() {
        let base = BasePose::new(0.0, 0.0, 0.0);
        assert!(pursue(&base, Vector2::new(1.0, 0.5), 0.3) > 0.0);
        assert!(pursue(&base, Vector2::new(1.0, -0.5), 0.3) < 0.0);
        assert_eq!(pursue(&base, Vector2::new(1.0, 0.0), 0.3), 0.0);
    }
}
