//! A container's centre from the outline of its silhouette (docs/algorithms.md §4).
//!
//! A container is an open box of known outer half-size standing on the floor, its rim at a
//! known height. Seen from the palm camera its silhouette's edges are its rim's outer edges
//! (where the view is from above them) or its walls' bottom edges on the floor (where the
//! camera sees an outer wall); vertical edges are few pixels. So the ray of each pixel on the
//! silhouette's edge meets the rim plane or the floor on the box's square outline. The centre
//! (and the yaw) is the square that puts the most edge rays on it: each ray's residual is the
//! nearer of its two plane points' distances to the square, and a few Gauss-Newton steps with
//! a shrinking inlier band fit it. Edges of the image are not edges of the box: the caller
//! leaves them out.
//!
//! The centroid of the blob, put on the rim plane, is biased wherever the container does not
//! fit in the view: near the drop it fills the image, and the centroid is then where the camera
//! looks, not the container's centre.

use nalgebra::{Matrix3, Rotation2, Vector2, Vector3};

/// A pixel's ray in the world: origin and unit direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Where the ray starts (the camera's centre), m.
    pub origin: Vector3<f64>,
    /// Unit direction.
    pub direction: Vector3<f64>,
}

impl Ray {
    /// The ray's point at height `z`, if it points toward it.
    fn at_height(&self, z: f64) -> Option<Vector2<f64>> {
        let distance = (z - self.origin.z) / self.direction.z;
        (distance.is_finite() && distance > 0.0)
            .then(|| (self.origin + distance * self.direction).xy())
    }
}

/// The fitted square: centre and yaw (in −π/4..π/4: a square repeats every quarter turn).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SquareFit {
    /// Centre of the box, m.
    pub centre: Vector2<f64>,
    /// Yaw of its sides, rad.
    pub yaw: f64,
    /// How many edge rays lie on it (within [`INLIER_BAND`]).
    pub inliers: usize,
}

/// Final inlier band, m: a ray whose plane points are farther than this from the square is not
/// one of its edges (a vertical edge, a cube in the container, noise).
pub const INLIER_BAND: f64 = 0.02;

/// Inlier bands of the fit's rounds, m: wide first (the start may be tens of centimetres off),
/// then down to [`INLIER_BAND`].
const BANDS: [f64; 5] = [0.3, 0.15, 0.08, 0.04, INLIER_BAND];

/// Gauss-Newton steps per round.
const STEPS_PER_BAND: usize = 3;

/// Least share of the edge rays on the fitted square (a wrong fit leaves many off it).
const MIN_INLIER_SHARE: f64 = 0.6;

/// Fewest inlier rays for a fit.
const MIN_INLIERS: usize = 20;

/// Least information along the centre's worst direction (the smallest eigenvalue of the
/// inliers' JᵀJ on the centre, about as many rays' worth of edge across that direction): a
/// single straight edge leaves the centre free along it.
const MIN_CROSS_INFORMATION: f64 = 8.0;

/// Signed distance of `p` from the outline of the square at `centre`, turned by `yaw`, of
/// half-size `half` (negative inside).
fn square_distance(p: Vector2<f64>, centre: Vector2<f64>, yaw: f64, half: f64) -> f64 {
    let q = Rotation2::new(-yaw) * (p - centre);
    let d = Vector2::new(q.x.abs() - half, q.y.abs() - half);
    let outside = Vector2::new(d.x.max(0.0), d.y.max(0.0)).norm();
    outside + d.x.max(d.y).min(0.0)
}

/// The residual of one ray: the nearer of its plane points to the outline.
fn residual(points: &[Vector2<f64>], centre: Vector2<f64>, yaw: f64, half: f64) -> f64 {
    points
        .iter()
        .map(|p| square_distance(*p, centre, yaw, half).abs())
        .fold(f64::INFINITY, f64::min)
}

/// Fits the square of half-size `half` to the edge `rays` of a box whose outline is at the
/// heights `planes` (its rim and the floor), starting from `start`. None when too few rays lie
/// on the fitted square, or they do not fix the centre in both directions.
pub fn fit_square(
    rays: &[Ray],
    planes: [f64; 2],
    half: f64,
    start: Vector2<f64>,
) -> Option<SquareFit> {
    let points: Vec<Vec<Vector2<f64>>> = rays
        .iter()
        .map(|ray| planes.iter().filter_map(|&z| ray.at_height(z)).collect())
        .filter(|p: &Vec<Vector2<f64>>| !p.is_empty())
        .collect();
    if points.len() < MIN_INLIERS {
        return None;
    }
    // Starts: the given centre and four around it half a side away (a view from outside the
    // box puts its near wall's foot where a fit from the centre alone can settle on the wrong
    // side), each at three yaws.
    let yaws = [
        0.0,
        std::f64::consts::FRAC_PI_8,
        -std::f64::consts::FRAC_PI_8,
    ];
    let shifts = [(0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)];
    let fit = shifts
        .iter()
        .flat_map(|&(sx, sy)| {
            yaws.iter()
                .map(move |&yaw| (Vector2::new(sx, sy) * half, yaw))
        })
        .filter_map(|(shift, yaw)| fit_from(&points, half, start + shift, yaw))
        .max_by_key(|fit| fit.inliers)?;
    (fit.inliers as f64 >= MIN_INLIER_SHARE * points.len() as f64).then_some(fit)
}

/// One fit from `(centre, yaw)`.
fn fit_from(
    points: &[Vec<Vector2<f64>>],
    half: f64,
    mut centre: Vector2<f64>,
    mut yaw: f64,
) -> Option<SquareFit> {
    const H: f64 = 1e-5;
    let mut information = Matrix3::zeros();
    let mut inliers = 0;
    for band in BANDS {
        for _ in 0..STEPS_PER_BAND {
            let mut jtj = Matrix3::zeros();
            let mut jtr = Vector3::zeros();
            inliers = 0;
            for p in points {
                let r = residual(p, centre, yaw, half);
                if r > band {
                    continue;
                }
                inliers += 1;
                let dx = (residual(p, centre + Vector2::new(H, 0.0), yaw, half) - r) / H;
                let dy = (residual(p, centre + Vector2::new(0.0, H), yaw, half) - r) / H;
                let dyaw = (residual(p, centre, yaw + H, half) - r) / H;
                let j = Vector3::new(dx, dy, dyaw);
                jtj += j * j.transpose();
                jtr += j * r;
            }
            information = jtj;
            // A little damping keeps a step bounded where the rays say little.
            let step = (jtj + Matrix3::identity() * 1e-3).lu().solve(&(-jtr))?;
            centre += step.xy();
            yaw += step.z;
            if step.norm() < 1e-6 {
                break;
            }
        }
    }
    let quarter = std::f64::consts::FRAC_PI_2;
    yaw = (yaw + quarter / 2.0).rem_euclid(quarter) - quarter / 2.0;
    let cross = information
        .fixed_view::<2, 2>(0, 0)
        .into_owned()
        .symmetric_eigenvalues()
        .min();
    (inliers >= MIN_INLIERS
        && cross >= MIN_CROSS_INFORMATION
        && centre.iter().all(|v| v.is_finite()))
    .then_some(SquareFit {
        centre,
        yaw,
        inliers,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rays from `eye` through points of the square's outline at height `z`.
    fn rays_to_outline(
        eye: Vector3<f64>,
        centre: Vector2<f64>,
        yaw: f64,
        half: f64,
        z: f64,
        sides: &[usize],
    ) -> Vec<Ray> {
        let corners = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
        let corner = |k: usize| {
            let (a, b) = corners[k % 4];
            let local = Vector2::new(a * half, b * half);
            centre + Rotation2::new(yaw) * local
        };
        let mut rays = Vec::new();
        for &side in sides {
            for i in 0..40 {
                let s = i as f64 / 40.0;
                let p = corner(side) + (corner(side + 1) - corner(side)) * s;
                let target = Vector3::new(p.x, p.y, z);
                rays.push(Ray {
                    origin: eye,
                    direction: (target - eye).normalize(),
                });
            }
        }
        rays
    }

    #[test]
    fn the_centre_is_found_from_rim_and_floor_edges_starting_far_off() {
        let centre = Vector2::new(3.0, -1.0);
        let yaw = 0.2;
        let eye = Vector3::new(2.5, -1.0, 0.9);
        // The far rim edges and the near wall's bottom edge, as a camera outside the box sees.
        let mut rays = rays_to_outline(eye, centre, yaw, 0.16, 0.35, &[1, 2]);
        rays.extend(rays_to_outline(eye, centre, yaw, 0.16, 0.0, &[3]));
        let fit =
            fit_square(&rays, [0.35, 0.0], 0.16, centre + Vector2::new(-0.2, 0.15)).expect("a fit");
        assert!((fit.centre - centre).norm() < 0.005, "{fit:?}");
        assert!((fit.yaw - yaw).abs() < 0.02, "{fit:?}");
    }

    #[test]
    fn a_single_straight_edge_gives_no_fit() {
        let centre = Vector2::new(1.0, 1.0);
        let eye = Vector3::new(1.0, 0.5, 0.8);
        let rays = rays_to_outline(eye, centre, 0.0, 0.16, 0.35, &[2]);
        assert_eq!(fit_square(&rays, [0.35, 0.0], 0.16, centre), None);
    }

    #[test]
    fn too_few_rays_or_rays_pointing_up_give_no_fit() {
        let up = Ray {
            origin: Vector3::zeros(),
            direction: Vector3::z(),
        };
        assert_eq!(
            fit_square(&[up; 100], [0.35, 0.0], 0.16, Vector2::zeros()),
            None
        );
        let centre = Vector2::new(1.0, 1.0);
        let eye = Vector3::new(1.0, 1.0, 0.8);
        let few = rays_to_outline(eye, centre, 0.0, 0.16, 0.35, &[0, 1]);
        assert_eq!(fit_square(&few[..15], [0.35, 0.0], 0.16, centre), None);
    }
}
