//! Cube perception from the palm camera (paper section III-B, docs/algorithms.md §4).
//!
//! Each image is thresholded for red pixels; the red pixels are grouped into connected blobs
//! (8-connectivity); the centroid of the chosen blob is un-projected through the calibration to a
//! ray, the ray is taken to the world with the tool pose at image time, and it is intersected
//! with the horizontal plane at the known height of the cube's centre. The world velocity comes
//! from the successive fixes.
//!
//! **Why the cube's centre height.** The silhouette of a cube is centrally symmetric about the
//! image of its centre (exactly in an orthographic view, closely for a 30 mm cube at a few
//! decimetres), so the blob centroid lies on the ray through the cube's centre whether the camera
//! sees only the top face (straight above) or the top and two sides (oblique). Intersecting at
//! the top-face height would be right only straight above.
//!
//! **Limits.** A cube cut by the edge of the image circle gives a centroid biased towards the
//! image centre (the 180° lens makes this rare). Anything red in view is a candidate, so the
//! scene keeps red for cubes; several cubes are told apart by nearness to the prediction.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Vector2, Vector3};
use serde::Deserialize;

use crate::camera::CameraCalibration;
use crate::error::ModelError;
use crate::outline::{Ray, fit_square};
use crate::types::TargetEstimate;

/// Settings of [`Perception`]. Every key is optional; unknown keys are errors.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerceptionConfig {
    /// A pixel is red when its red channel is at least this (8-bit). Default 80: the cube's face
    /// in shadow renders at about 120, so 80 leaves margin for noise and darker lighting.
    pub min_red: u8,
    /// ... and its red channel exceeds both green and blue by at least this. Default 50: the
    /// grey, light-wood and blue surfaces of the scene have margins below 25, so even pixel noise
    /// of σ = 10 levels seldom lifts a pixel over (and never four neighbours together), while the
    /// cube's darkest face is about 100 above.
    pub min_red_margin: u8,
    /// Fewest red pixels a blob needs to count as the cube; with fewer the cube is "not visible".
    /// Default 4 (a 30 mm cube at 1.5 m still covers about 2×2 pixels in the default camera).
    pub min_pixels: usize,
    /// Length of the sliding window of fixes the velocity is fitted over, s. The velocity is the
    /// slope of the least-squares line through the fixes of the last `velocity_window` seconds:
    /// a low-pass differentiator whose noise falls as window^(−3/2) and whose lag for a ramp is
    /// half the window. Default 0.5 s: with 1 mm of fix noise at 30 Hz the velocity noise is about
    /// 2 mm/s, and a 30 mm/s cube moves 7.5 mm during the lag (which is only a velocity lag: the
    /// reported position is the latest fix).
    pub velocity_window: f64,
    /// Shortest time span of the fixes in the window before a new velocity is fitted, s. Until
    /// then the previous velocity (zero at the start) is held. Default 0.1 s.
    pub min_velocity_span: f64,
    /// Fixes farther than this from the camera are discarded (rays grazing the plane), m.
    /// Default 5.
    pub max_range: f64,
    /// Container fixes farther than this from the camera are discarded, m. Default 0.7: a
    /// container seen from afar shows mostly its near outer wall, whose centroid put on the rim
    /// plane lies tens of centimetres short of the centre (measured: 0.4 m short from 1.2 m);
    /// close in, the view is from above. Until then the known position is used.
    pub max_container_range: f64,
    /// Fixes whose ray meets the object's plane at less than this angle are discarded, rad.
    /// Default 0.17 (about 10°). A camera near the plane's height sees the object side-on: its
    /// silhouette no longer centres on the ray through its centre, and a pixel of centroid moves
    /// the fix by range/sin² of this angle. Reaching low beside a row at 0.4 m/s, the palm
    /// camera came within a centimetre of the cubes' centre plane, and fixes 0.25 m off the
    /// cube led the arm away from it (Exp 2). From 0.3 m above the plane, views out to 1.7 m
    /// (beyond `max_range`) pass; at the grasp, straight above, the ray meets it at 45° or more.
    pub min_ray_angle: f64,
    /// A blob whose fix is farther than this from the prior (the last estimate, predicted to
    /// now, or the hint) is another object and is ignored, m. 0.3 m: a cube moving at 3 cm/s
    /// stays well inside it between fixes, while cubes already placed (metres away) are out.
    /// A blob within this distance of the last fix is accepted too, so that a wrong velocity
    /// (whose prediction runs away) can never lock the object out.
    pub max_prior_distance: f64,
    /// A container's fix farther than this from its known position is something else, m. 0.6 m:
    /// wider than `max_prior_distance`, because the known position is in the world frame while
    /// the fixes are in the odometry frame, which drifts by about 1 % of the distance driven
    /// (tens of centimetres over a long mission). Cubes and button caps keep the narrower gate
    /// even for their first fix: far, grazing views of a cap put its fix half a metre off.
    pub max_hint_distance: f64,
    /// Consecutive images whose container fixes agree (within
    /// [`CONTAINER_CONFIRMATION_DISTANCE`]) before a container's first fix is taken. Default 3
    /// (0.1 s at 30 Hz): a container at the edge of the container range, seen from the side,
    /// gives a fix in a single image now and then, up to half a metre short of it (its near
    /// wall), which sent the base round a new pass; the fixes of a container in range come in
    /// every image. 1 takes the first fix at once.
    pub container_confirmations: usize,
    /// Consecutive images whose fixes agree (within `constellation_tolerance`) before the first
    /// fix of an object with known neighbours (a row's cube) is taken. Default 3 (0.1 s): the
    /// first image of a row, at the edge of the range, may hold all its cubes but the target
    /// (below the blob size), and a whole spacing's shift then explains the view; an image
    /// later the target's blob is in it and the constellation tells. A wrong first fix is
    /// tracked for good. 1 takes the first fix at once.
    pub row_confirmations: usize,
    /// A pixel is blue (a container) when its blue channel is at least this (8-bit). Default 80.
    pub min_blue: u8,
    /// ... and its blue channel exceeds both red and green by at least this. Default 50: the
    /// containers render at about (40, 80, 170), the wood and grey surfaces have margins below 25.
    pub min_blue_margin: u8,
    /// How many standard errors a fitted velocity must exceed to be believed. The fit's
    /// standard error comes from the residuals of the fixes about the fitted line; the velocity
    /// is shrunk by `1 − (k·se/|v|)²` (to zero below `k·se`). Fixes of a far object at a
    /// grazing angle scatter by centimetres (a pixel of centroid is `range²/height` metres per
    /// radian along the ray), and a line through a few of them would otherwise report a static
    /// cube as moving at metres per second. Default 2.
    pub velocity_significance: f64,
    /// Fastest an object is believed to move, m/s: a faster fitted velocity is scaled down to
    /// it. Default 0.5 (objects on a table, well above the 30 mm/s of the moving cubes).
    pub max_object_speed: f64,
    /// Before the first fix, each blob near the hint is tried as the target: the known
    /// neighbours, moved by the same offset from the hint, are then looked for among the other
    /// blobs. A neighbour counts as found within this distance of a blob, m; a blob with no
    /// object predicted within it counts against. The blob that explains the view best wins
    /// (ties: the one nearest the hint). Default 0.04 m: a third of the 12 cm between cubes in
    /// a row, several times the fix noise at the 1.5 m range.
    pub constellation_tolerance: f64,
    /// Once tracked, a blob more than this many times the pixels of the target's last blob (and
    /// at least [`MERGE_MIN_EXTRA_PIXELS`] more), whose fix is no nearer the prior than half its
    /// distance to a known neighbour, is the target merged with that neighbour, seen along a
    /// row at a grazing angle: its centroid lies between the two, and is not taken.
    /// Default 1.6: approaching at the reach's speed, a cube's blob grows by a few per cent a
    /// frame, while a merge about doubles it.
    pub max_blob_growth: f64,
    /// Outer half-size of a container, m (its square outline, [`crate::outline`]). Default
    /// 0.16: 0.15 inside and walls 0.01 thick. A container's fix is the square fitted to its
    /// silhouette's edges, not its blob's centroid, which near the drop (the container filling
    /// the view) is where the camera looks.
    pub container_half_size: f64,
}

/// Farthest apart successive container fixes may be and still confirm each other
/// ([`PerceptionConfig::container_confirmations`]), m: the fixes of a container in range, from a
/// camera moving at up to 0.4 m/s, move by a few centimetres from one image to the next.
pub const CONTAINER_CONFIRMATION_DISTANCE: f64 = 0.1;

/// Most edge pixels a container's outline fit uses ([`crate::outline`]).
pub const MAX_OUTLINE_RAYS: usize = 240;

/// Fewest extra pixels over the target's last blob for a blob to count as a merge (blobs of a
/// few pixels grow by whole pixels from one frame to the next).
pub const MERGE_MIN_EXTRA_PIXELS: usize = 4;

/// How far inside the edge of the view (the image border, the lens' image circle) a point must
/// image to count as in view, as a share of the image width (6 pixels of 320).
pub const IN_VIEW_MARGIN: f64 = 0.02;

impl Default for PerceptionConfig {
    fn default() -> Self {
        Self {
            min_red: 80,
            min_red_margin: 50,
            min_pixels: 4,
            velocity_window: 0.5,
            min_velocity_span: 0.1,
            max_range: 1.5,
            max_container_range: 0.7,
            min_ray_angle: 0.17,
            max_prior_distance: 0.3,
            max_hint_distance: 0.6,
            container_confirmations: 3,
            row_confirmations: 3,
            min_blue: 80,
            min_blue_margin: 50,
            velocity_significance: 2.0,
            max_object_speed: 0.5,
            constellation_tolerance: 0.04,
            max_blob_growth: 1.6,
            container_half_size: 0.16,
        }
    }
}

impl PerceptionConfig {
    /// Checks every value (the `[perception]` table of `file`); the error names the key.
    pub fn validate(&self, file: &std::path::Path) -> Result<(), ModelError> {
        let positive = [
            ("perception.velocity_window", self.velocity_window),
            ("perception.min_velocity_span", self.min_velocity_span),
            ("perception.max_range", self.max_range),
            ("perception.max_container_range", self.max_container_range),
            ("perception.max_prior_distance", self.max_prior_distance),
            ("perception.max_hint_distance", self.max_hint_distance),
            (
                "perception.velocity_significance",
                self.velocity_significance,
            ),
            ("perception.max_object_speed", self.max_object_speed),
            (
                "perception.constellation_tolerance",
                self.constellation_tolerance,
            ),
            ("perception.max_blob_growth", self.max_blob_growth),
            ("perception.container_half_size", self.container_half_size),
        ];
        ModelError::check_positive(file, &positive)?;
        if !(0.0..std::f64::consts::FRAC_PI_2).contains(&self.min_ray_angle) {
            return Err(ModelError::invalid(
                file,
                "perception.min_ray_angle",
                format!(
                    "must be at least 0 and below π/2 rad, got {}",
                    self.min_ray_angle
                ),
            ));
        }
        if self.max_blob_growth <= 1.0 {
            return Err(ModelError::invalid(
                file,
                "perception.max_blob_growth",
                format!("must exceed 1, got {}", self.max_blob_growth),
            ));
        }
        for (key, count) in [
            (
                "perception.container_confirmations",
                self.container_confirmations,
            ),
            ("perception.row_confirmations", self.row_confirmations),
        ] {
            if count == 0 {
                return Err(ModelError::invalid(file, key, "must be at least 1"));
            }
        }
        if self.min_pixels == 0 {
            return Err(ModelError::invalid(
                file,
                "perception.min_pixels",
                "must be at least 1",
            ));
        }
        if self.min_velocity_span > self.velocity_window {
            return Err(ModelError::invalid(
                file,
                "perception.min_velocity_span",
                format!(
                    "must not exceed perception.velocity_window ({} s), got {} s",
                    self.velocity_window, self.min_velocity_span
                ),
            ));
        }
        Ok(())
    }

    /// Whether an RGB pixel counts as red under these thresholds.
    pub fn is_red(&self, r: u8, g: u8, b: u8) -> bool {
        let margin = self.min_red_margin as i16;
        // `&` rather than `&&`: no branches, so that the image loop compiles to SIMD.
        (r >= self.min_red) & (r as i16 - g as i16 >= margin) & (r as i16 - b as i16 >= margin)
    }

    /// Whether an RGB pixel counts as blue under these thresholds.
    pub fn is_blue(&self, r: u8, g: u8, b: u8) -> bool {
        let margin = self.min_blue_margin as i16;
        (b >= self.min_blue) & (b as i16 - r as i16 >= margin) & (b as i16 - g as i16 >= margin)
    }
}

/// The colour of the target's blob: the scene keeps red for cubes and button caps and blue for
/// containers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BlobColour {
    /// A cube or a button cap.
    #[default]
    Red,
    /// A container.
    Blue,
}

/// One camera image and what perception needs to interpret it.
#[derive(Debug, Clone, Copy)]
pub struct PerceptionInput<'a> {
    /// RGB8 pixels, row-major, `width × height × 3` bytes.
    pub image: &'a [u8],
    /// Image width, pixels; must equal the calibration's.
    pub width: u32,
    /// Image height, pixels; must equal the calibration's.
    pub height: u32,
    /// Capture time of the image, s (monotonic).
    pub stamp: f64,
    /// World pose of the tool at capture time (as the robot's state estimate knows it).
    pub tool_pose: Isometry3<f64>,
    /// World height of the cube's centre, m (known a priori, as in the paper).
    pub object_height: f64,
    /// Where the cube is expected (e.g. the task's target position), used to choose between
    /// several red blobs before the first fix. After a fix, the blob nearest to the prediction
    /// from the last estimate is chosen; with neither, the largest blob.
    pub target_hint: Option<Vector3<f64>>,
    /// The colour of the target's blob.
    pub colour: BlobColour,
    /// Where the other objects of the target's colour still stand, as the mission knows them
    /// (in the same frame as the hint): the first fix is the blob that, taken for the target,
    /// best explains the blobs around it ([`PerceptionConfig::constellation_tolerance`]).
    pub neighbours: &'a [Vector3<f64>],
    /// The hint and the neighbours are good to well under half the spacing of the objects
    /// (the odometry correction predicts its drift): before the first fix, a blob nearer a
    /// neighbour than the hint is then that neighbour. Otherwise the known layout may be a
    /// whole spacing or more off, and the view decides.
    pub layout_trusted: bool,
}

/// What perception reports after each image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectEstimate {
    /// World position of the cube's centre from the latest fix, m (zero before the first fix).
    pub position: Vector3<f64>,
    /// World velocity of the cube, m/s (zero until fixes span `min_velocity_span`).
    pub velocity: Vector3<f64>,
    /// Whether the cube was found in this image.
    pub visible: bool,
    /// Whether `position` comes from a fix at all (this image's or an earlier one's).
    pub valid: bool,
    /// Capture time of the image that gave `position`, s.
    pub stamp: f64,
}

impl Default for ObjectEstimate {
    fn default() -> Self {
        Self {
            position: Vector3::zeros(),
            velocity: Vector3::zeros(),
            visible: false,
            valid: false,
            stamp: 0.0,
        }
    }
}

impl ObjectEstimate {
    /// The estimate as the controllers' target type.
    pub fn target(&self) -> TargetEstimate {
        TargetEstimate {
            position: self.position,
            velocity: self.velocity,
        }
    }
}

/// A connected group of pixels of the target's colour: its size and the sums of its pixel
/// coordinates (exact integers).
#[derive(Debug, Clone, Copy, Default)]
struct Blob {
    pixels: usize,
    sum_u: u64,
    sum_v: u64,
}

impl Blob {
    fn centroid(&self) -> Vector2<f64> {
        Vector2::new(self.sum_u as f64, self.sum_v as f64) / self.pixels as f64
    }
}

/// A run of pixels of the target's colour in one image row: columns `start..end`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Run {
    row: u32,
    start: u32,
    end: u32,
}

/// Appends to `runs` (cleared first) the runs of pixels of `image` (RGB8, `width` a row) that
/// `has_colour`; returns the number of such pixels. Each row is first turned into a byte mask
/// (branch-free, so that it compiles to SIMD), and the mask is then scanned eight pixels at a
/// time, skipping the runs of pixels without the colour. The mask is at least one zero byte
/// longer than a row, so every run ends inside it.
fn find_runs(
    image: &[u8],
    width: usize,
    runs: &mut Vec<Run>,
    mask: &mut Vec<u8>,
    has_colour: impl Fn(u8, u8, u8) -> bool,
) -> usize {
    runs.clear();
    mask.clear();
    // Bytes past `width` are never written: they stay 0.
    mask.resize((width / 8 + 1) * 8, 0);
    let mut count = 0;
    for (row, pixels) in image.chunks_exact(width * 3).enumerate() {
        fill_mask(mask, pixels, &has_colour);
        let mut start = None;
        for (chunk, bytes) in mask.chunks_exact(8).enumerate() {
            let word = u64::from_ne_bytes(bytes.try_into().expect("chunks of 8"));
            if word == 0 && start.is_none() {
                continue;
            }
            for (k, &m) in bytes.iter().enumerate() {
                let u = chunk * 8 + k;
                match (m != 0, start) {
                    (true, None) => start = Some(u),
                    (false, Some(s)) => {
                        runs.push(Run {
                            row: row as u32,
                            start: s as u32,
                            end: u as u32,
                        });
                        count += u - s;
                        start = None;
                    }
                    _ => {}
                }
            }
        }
    }
    count
}

/// Sets `mask[u]` to 1 where pixel `u` of the RGB8 row `pixels` `has_colour`, else 0. Uses
/// AVX2 where the CPU has it (the same code, vectorised wider), found at run time.
fn fill_mask(mask: &mut [u8], pixels: &[u8], has_colour: &impl Fn(u8, u8, u8) -> bool) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        unsafe { fill_mask_avx2(mask, pixels, has_colour) };
        return;
    }
    fill_mask_any(mask, pixels, has_colour);
}

/// [`fill_mask`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn fill_mask_avx2(mask: &mut [u8], pixels: &[u8], has_colour: &impl Fn(u8, u8, u8) -> bool) {
    fill_mask_any(mask, pixels, has_colour);
}

/// [`fill_mask`] for any CPU; inlined into each target's version.
#[inline(always)]
fn fill_mask_any(mask: &mut [u8], pixels: &[u8], has_colour: &impl Fn(u8, u8, u8) -> bool) {
    for (m, p) in mask.iter_mut().zip(pixels.chunks_exact(3)) {
        *m = u8::from(has_colour(p[0], p[1], p[2]));
    }
}

/// The root of `i` in the union-find `parent`, halving the path on the way.
fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let up = parent[parent[i as usize] as usize];
        parent[i as usize] = up;
        i = up;
    }
    i
}

/// Merges the sets of `a` and `b`; the smaller root (the earlier run) becomes the root.
fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    let (low, high) = (ra.min(rb), ra.max(rb));
    parent[high as usize] = low;
}

/// The cube perception step function; it keeps the recent fixes for the velocity estimate and
/// scratch buffers, so a step allocates nothing once warmed up.
#[derive(Debug, Clone)]
pub struct Perception {
    config: PerceptionConfig,
    calibration: CameraCalibration,
    fixes: VecDeque<(f64, Vector3<f64>)>,
    estimate: ObjectEstimate,
    runs: Vec<Run>,
    mask: Vec<u8>,
    parent: Vec<u32>,
    blob_of_root: Vec<u32>,
    blobs: Vec<Blob>,
    /// Pixels of the blob of the last fix (0 before the first).
    last_pixels: usize,
    /// Before a container's first fix: the latest fix and how many images in a row agreed
    /// with it.
    unconfirmed: Option<(Vector3<f64>, usize)>,
}

impl Perception {
    /// Perception with `config`, using `calibration` (the calibrated camera, which may differ from
    /// the true one) to turn pixels into rays.
    pub fn new(config: PerceptionConfig, calibration: CameraCalibration) -> Self {
        Self {
            config,
            calibration,
            fixes: VecDeque::new(),
            estimate: ObjectEstimate::default(),
            runs: Vec::new(),
            mask: Vec::new(),
            parent: Vec::new(),
            blob_of_root: Vec::new(),
            blobs: Vec::new(),
            last_pixels: 0,
            unconfirmed: None,
        }
    }

    /// The latest estimate.
    pub fn estimate(&self) -> ObjectEstimate {
        self.estimate
    }

    /// Processes one image. When the cube is not found (or the input is unusable: wrong size,
    /// non-finite pose, height or stamp) the previous estimate is returned with `visible = false`.
    pub fn step(&mut self, input: &PerceptionInput) -> ObjectEstimate {
        self.estimate.visible = false;
        let located = self.locate(input);
        if let Some((pixels, position)) = self.confirmed(input, located) {
            self.last_pixels = pixels;
            self.record_fix(input.stamp, position);
            // Containers stand still: the fixes of one seen from a moving base shift as the
            // view changes, and a velocity fitted through them would carry the estimate away.
            if input.colour == BlobColour::Blue {
                self.estimate.velocity = Vector3::zeros();
            }
        }
        self.estimate
    }

    /// This image's fix, `located`, where it may be taken: always, except for a container's
    /// first fix, which needs `container_confirmations` images in a row with agreeing fixes,
    /// and the first fix of an object with known neighbours, which needs `row_confirmations`
    /// (agreeing within `constellation_tolerance`).
    /// Called for every image; an image without a fix starts the count again.
    fn confirmed(
        &mut self,
        input: &PerceptionInput,
        located: Option<(usize, Vector3<f64>)>,
    ) -> Option<(usize, Vector3<f64>)> {
        let (needed, agreement) = match input.colour {
            BlobColour::Blue => (
                self.config.container_confirmations,
                CONTAINER_CONFIRMATION_DISTANCE,
            ),
            BlobColour::Red if !input.neighbours.is_empty() => (
                self.config.row_confirmations,
                self.config.constellation_tolerance,
            ),
            BlobColour::Red => return located,
        };
        if self.estimate.valid {
            return located;
        }
        let Some((_, position)) = located else {
            self.unconfirmed = None;
            return None;
        };
        let count = match self.unconfirmed {
            Some((last, n)) if (position - last).norm() <= agreement => n + 1,
            _ => 1,
        };
        let done = count >= needed;
        self.unconfirmed = (!done).then_some((position, count));
        located.filter(|_| done)
    }

    /// The world position of the cube in this image, if it is seen.
    fn locate(&mut self, input: &PerceptionInput) -> Option<(usize, Vector3<f64>)> {
        let model = &self.calibration.model;
        let pixels = model.width as usize * model.height as usize;
        let usable = input.width == model.width
            && input.height == model.height
            && input.image.len() == pixels * 3
            && input.stamp.is_finite()
            && input.object_height.is_finite()
            && isometry_is_finite(&input.tool_pose)
            && input
                .target_hint
                .is_none_or(|h| h.iter().all(|v| v.is_finite()));
        if !usable
            || self.threshold(input.image, input.width as usize, input.colour)
                < self.config.min_pixels
        {
            return None;
        }
        self.label_blobs();
        // The prediction from the last estimate and the last fix itself (or the hint before
        // the first fix): a blob near either is the object.
        // A container stands still: its fixes are always gated by its known position (the
        // odometry drift is all that separates them), so biased fixes cannot walk it away.
        let tracked = self.estimate.valid && input.colour != BlobColour::Blue;
        let priors = if tracked {
            [
                Some(
                    self.estimate
                        .target()
                        .predict(input.stamp - self.estimate.stamp),
                ),
                Some(self.estimate.position),
            ]
        } else {
            [input.target_hint, None]
        };
        let distance = |fix: Vector3<f64>| {
            priors
                .iter()
                .flatten()
                .map(|p| (fix - p).norm())
                .reduce(f64::min)
        };
        let max_range = self.max_range(input.colour);
        // Nearest to the prior wins (blobs too far from it are other objects, e.g. cubes
        // already in a container); without a prior, the largest blob.
        let gate = match input.colour {
            BlobColour::Red => self.config.max_prior_distance,
            BlobColour::Blue => self.config.max_hint_distance,
        };
        let mut blob_of_fix = Vec::new();
        let fixes: Vec<(usize, Vector3<f64>)> = self
            .blobs
            .iter()
            .enumerate()
            .filter(|(_, b)| b.pixels >= self.config.min_pixels)
            .filter_map(|(k, blob)| {
                let fix = self.intersect(
                    blob.centroid(),
                    &input.tool_pose,
                    input.object_height,
                    max_range,
                )?;
                blob_of_fix.push(k);
                Some((blob.pixels, fix))
            })
            .collect();
        let hint = input
            .target_hint
            .filter(|_| !tracked && !input.neighbours.is_empty());
        // The known neighbours are where the mission knows them (once tracked, moved by the
        // offset the target's estimate shows from its own known position; before, only when
        // the layout is trusted): a blob nearer one of them than the target's prior is that
        // neighbour. In a row of cubes the target may be out of the view while the cubes
        // beside it, within the gate, are in it; a view of the row's far end then explains a
        // shift of whole spacings as well as none.
        let offset = input.target_hint.and_then(|h| {
            if tracked {
                Some(self.estimate.position - h)
            } else {
                input.layout_trusted.then(Vector3::zeros)
            }
        });
        let nearest_neighbour = |fix: &Vector3<f64>| {
            offset.and_then(|offset| {
                input
                    .neighbours
                    .iter()
                    .map(|n| (fix - (n + offset)).xy().norm())
                    .reduce(f64::min)
            })
        };
        // A merge's centroid lies between the target and a neighbour: no nearer the prior than
        // half its distance to the neighbour.
        let merged = |pixels: usize, fix: &Vector3<f64>| {
            tracked
                && self.last_pixels > 0
                && pixels as f64 > self.config.max_blob_growth * self.last_pixels as f64
                && pixels >= self.last_pixels + MERGE_MIN_EXTRA_PIXELS
                && nearest_neighbour(fix)
                    .zip(distance(*fix))
                    .is_some_and(|(n, d)| n < 2.0 * d)
        };
        // Before the first fix with an untrusted layout, while the hint itself is out of the
        // view: a blob nearer a known neighbour than the hint is taken for that neighbour. The
        // view then holds only part of the row, which explains a shift of whole spacings as
        // well as none; once the hint comes into view, the constellation decides.
        let hint_unseen = hint.is_some_and(|h| !input.layout_trusted && !self.in_view(&h, input));
        let neighbour_nearer = |fix: &Vector3<f64>| {
            let d = input
                .target_hint
                .map_or(f64::INFINITY, |h| (fix - h).xy().norm());
            input.neighbours.iter().any(|n| (fix - n).xy().norm() < d)
        };
        // (explained, score, pixels, fix, blob)
        let mut best: Option<(f64, f64, usize, Vector3<f64>, usize)> = None;
        for (i, &(pixels, fix)) in fixes.iter().enumerate() {
            if merged(pixels, &fix) || (hint_unseen && neighbour_nearer(&fix)) {
                continue;
            }
            let (explained, score) = match distance(fix) {
                Some(d) if d > gate => continue,
                Some(d) if nearest_neighbour(&fix).is_some_and(|n| n < d) => continue,
                Some(d) => (
                    hint.map_or(0.0, |h| {
                        self.explained(fix - h, &fix, &fixes, input.neighbours)
                    }),
                    d,
                ),
                None => (0.0, -(pixels as f64)),
            };
            if best.is_none_or(|(e, s, ..)| explained > e || (explained == e && score < s)) {
                best = Some((explained, score, pixels, fix, blob_of_fix[i]));
            }
        }
        let (_, _, pixels, fix, blob) = best?;
        match input.colour {
            BlobColour::Red => Some((pixels, fix)),
            BlobColour::Blue => self.outline_fix(blob, input, fix).map(|fix| (pixels, fix)),
        }
    }

    /// A container's fix from the outline of its blob `blob` ([`crate::outline`]): the rays of
    /// the blob's outer edge pixels (each row's and each column's extreme pixels, leaving out
    /// those at the edge of the view: the image's border or the lens' image circle) fitted
    /// with the container's square at its rim's height and on the floor, from the centroid's
    /// fix `rough`. None when the outline does not fix the centre and the blob is cut by the
    /// edge of the view (its centroid is then only where the camera looks); the centroid's fix
    /// when the whole blob is in view.
    fn outline_fix(
        &mut self,
        blob: usize,
        input: &PerceptionInput,
        rough: Vector3<f64>,
    ) -> Option<Vector3<f64>> {
        let (width, height) = (input.width as usize, input.height as usize);
        // Each row's leftmost and rightmost pixel, each column's top and bottom one.
        let mut rows = vec![(u32::MAX, 0u32); height];
        let mut columns = vec![(u32::MAX, 0u32); width];
        for i in 0..self.runs.len() {
            let root = find(&mut self.parent, i as u32) as usize;
            if self.blob_of_root[root] as usize != blob {
                continue;
            }
            let run = self.runs[i];
            let row = &mut rows[run.row as usize];
            *row = (row.0.min(run.start), row.1.max(run.end));
            for column in &mut columns[run.start as usize..run.end as usize] {
                *column = (column.0.min(run.row), column.1.max(run.row));
            }
        }
        // An edge pixel is the silhouette's only where the pixel two steps further out is still
        // imaged (inside the image and the lens' image circle): elsewhere the blob is cut by the
        // view's edge, not by the box's.
        let mut edges = Vec::new();
        let mut cut = false;
        let mut edge = |pixel: Vector2<f64>, probe: (i64, i64)| {
            if self.imaged(&Vector2::new(probe.0 as f64, probe.1 as f64), input) {
                edges.push(pixel);
            } else {
                cut = true;
            }
        };
        for (v, &(first, end)) in rows.iter().enumerate().filter(|(_, r)| r.0 != u32::MAX) {
            let (v, first, last) = (v as i64, first as i64, end as i64 - 1);
            edge(Vector2::new(first as f64 - 0.5, v as f64), (first - 2, v));
            edge(Vector2::new(last as f64 + 0.5, v as f64), (last + 2, v));
        }
        for (u, &(top, bottom)) in columns.iter().enumerate().filter(|(_, c)| c.0 != u32::MAX) {
            let (u, top, bottom) = (u as i64, top as i64, bottom as i64);
            edge(Vector2::new(u as f64, top as f64 - 0.5), (u, top - 2));
            edge(Vector2::new(u as f64, bottom as f64 + 0.5), (u, bottom + 2));
        }
        let world_from_camera = input.tool_pose * self.calibration.tool_from_camera;
        let origin = world_from_camera.translation.vector;
        // At most MAX_OUTLINE_RAYS, evenly through the edge (the fit's cost grows with them).
        let stride = edges.len().div_ceil(MAX_OUTLINE_RAYS).max(1);
        let rays: Vec<Ray> = edges
            .iter()
            .step_by(stride)
            .filter_map(|pixel| self.calibration.model.unproject(pixel))
            .map(|ray| Ray {
                origin,
                direction: world_from_camera.rotation * ray.into_inner(),
            })
            .collect();
        let planes = [input.object_height, 0.0];
        match fit_square(&rays, planes, self.config.container_half_size, rough.xy()) {
            Some(fit) => Some(Vector3::new(fit.centre.x, fit.centre.y, rough.z)),
            None => (!cut).then_some(rough),
        }
    }

    /// How well taking `target` for the target explains the view: with the known `neighbours`
    /// moved by `offset` (where the target's blob is against the hint), the neighbours found
    /// among the other `fixes` minus the other fixes that no object accounts for (see
    /// [`PerceptionConfig::constellation_tolerance`]).
    fn explained(
        &self,
        offset: Vector3<f64>,
        target: &Vector3<f64>,
        fixes: &[(usize, Vector3<f64>)],
        neighbours: &[Vector3<f64>],
    ) -> f64 {
        let tolerance = self.config.constellation_tolerance;
        let near = |a: &Vector3<f64>, b: &Vector3<f64>| (a - b).xy().norm() <= tolerance;
        let others = || fixes.iter().map(|(_, f)| f).filter(|f| !near(f, target));
        let predicted = || neighbours.iter().map(|n| n + offset);
        let found = predicted().filter(|p| others().any(|f| near(f, p))).count();
        let unexplained = others()
            .filter(|f| !predicted().any(|p| near(f, &p)))
            .count();
        found as f64 - unexplained as f64
    }

    /// Finds the runs of pixels of `colour` in each row of `image` (`width` pixels a row) into
    /// `runs`; returns how many pixels there are.
    fn threshold(&mut self, image: &[u8], width: usize, colour: BlobColour) -> usize {
        let config = self.config;
        match colour {
            BlobColour::Red => {
                find_runs(image, width, &mut self.runs, &mut self.mask, |r, g, b| {
                    config.is_red(r, g, b)
                })
            }
            BlobColour::Blue => {
                find_runs(image, width, &mut self.runs, &mut self.mask, |r, g, b| {
                    config.is_blue(r, g, b)
                })
            }
        }
    }

    /// Groups the runs into 8-connected blobs, filling `blobs` in the raster order of each
    /// blob's first pixel. Runs of neighbouring rows that touch (diagonals included) are merged
    /// with a union-find whose root is the blob's first run.
    fn label_blobs(&mut self) {
        let runs = &self.runs;
        let parent = &mut self.parent;
        parent.clear();
        parent.extend(0..runs.len() as u32);
        // Runs of the row above the current one: `above..row_start`.
        let (mut above, mut row_start) = (0, 0);
        for i in 0..runs.len() {
            let run = runs[i];
            if i > 0 && runs[i - 1].row != run.row {
                above = if runs[i - 1].row + 1 == run.row {
                    row_start
                } else {
                    i
                };
                row_start = i;
            }
            // Runs of the row above overlapping [start − 1, end] (end exclusive) touch this one.
            // Runs wholly left of this one are wholly left of the rest of the row too.
            let mut next_above = above;
            for (j, prev) in runs.iter().enumerate().take(row_start).skip(above) {
                if prev.end < run.start {
                    next_above = j + 1;
                    continue;
                }
                if prev.start > run.end {
                    break;
                }
                union(parent, i as u32, j as u32);
            }
            above = next_above;
        }
        self.blobs.clear();
        self.blob_of_root.clear();
        self.blob_of_root.resize(runs.len(), u32::MAX);
        for (i, run) in runs.iter().enumerate() {
            let root = find(parent, i as u32) as usize;
            if self.blob_of_root[root] == u32::MAX {
                self.blob_of_root[root] = self.blobs.len() as u32;
                self.blobs.push(Blob::default());
            }
            let blob = &mut self.blobs[self.blob_of_root[root] as usize];
            let len = (run.end - run.start) as u64;
            blob.pixels += len as usize;
            // Σ u over start..end, exactly, in integers.
            blob.sum_u += (run.start as u64 + run.end as u64 - 1) * len / 2;
            blob.sum_v += run.row as u64 * len;
        }
    }

    /// Whether `pixel` is imaged: inside `input`'s image and the lens' image circle.
    fn imaged(&self, pixel: &Vector2<f64>, input: &PerceptionInput) -> bool {
        (0.0..f64::from(input.width)).contains(&pixel.x)
            && (0.0..f64::from(input.height)).contains(&pixel.y)
            && self.calibration.model.unproject(pixel).is_some()
    }

    /// The longest range a fix of a `colour` object is taken from, m.
    fn max_range(&self, colour: BlobColour) -> f64 {
        match colour {
            BlobColour::Red => self.config.max_range,
            BlobColour::Blue => self.config.max_container_range,
        }
    }

    /// Whether an object at the world point `point` would give a fix at `input`'s tool pose: it
    /// images inside the camera's view by [`IN_VIEW_MARGIN`] (a cube at the view's edge is cut
    /// below the blob size, or not imaged yet, while its neighbours further in are), and its
    /// ray meets the object's plane within the range and at the angle [`Self::intersect`]
    /// accepts. A point imaged at a grazing angle is out of view: its blob gives no fix, while
    /// a neighbour nearer the camera does.
    fn in_view(&self, point: &Vector3<f64>, input: &PerceptionInput) -> bool {
        let world_from_camera = input.tool_pose * self.calibration.tool_from_camera;
        let local = world_from_camera.inverse_transform_point(&(*point).into());
        let ray = point - world_from_camera.translation.vector;
        let range = ray.norm();
        let margin = IN_VIEW_MARGIN * f64::from(input.width);
        let inside = self
            .calibration
            .model
            .project(&local.coords)
            .is_some_and(|pixel| {
                [[-margin, 0.0], [margin, 0.0], [0.0, -margin], [0.0, margin]]
                    .iter()
                    .all(|[du, dv]| self.imaged(&(pixel + Vector2::new(*du, *dv)), input))
            });
        inside
            && range <= self.max_range(input.colour)
            && ray.z.abs() >= self.config.min_ray_angle.sin() * range
    }

    /// Intersects the calibrated ray of `pixel` with the plane `z = height` (world), if the ray
    /// meets it at `min_ray_angle` or more and within `max_range`.
    fn intersect(
        &self,
        pixel: Vector2<f64>,
        tool_pose: &Isometry3<f64>,
        height: f64,
        max_range: f64,
    ) -> Option<Vector3<f64>> {
        let ray = self.calibration.model.unproject(&pixel)?;
        let world_from_camera = tool_pose * self.calibration.tool_from_camera;
        let origin = world_from_camera.translation.vector;
        let direction = world_from_camera.rotation * ray.into_inner();
        // `direction` is a unit vector: its z is the sine of its angle to the plane.
        if direction.z.abs() < self.config.min_ray_angle.sin().max(1e-9) {
            return None;
        }
        let distance = (height - origin.z) / direction.z;
        if !(distance > 0.0 && distance <= max_range) {
            return None;
        }
        let fix = origin + distance * direction;
        fix.iter().all(|v| v.is_finite()).then_some(fix)
    }

    /// Adds a fix and refits the velocity over the window.
    fn record_fix(&mut self, stamp: f64, position: Vector3<f64>) {
        match self.fixes.back() {
            // The same frame again: the newer fix replaces the older.
            Some(&(t, _)) if stamp == t => {
                self.fixes.pop_back();
            }
            // Time went backwards (a restart): the old fixes say nothing about now.
            Some(&(t, _)) if stamp < t => self.fixes.clear(),
            _ => {}
        }
        self.fixes.push_back((stamp, position));
        while self
            .fixes
            .front()
            .is_some_and(|&(t, _)| t < stamp - self.config.velocity_window)
        {
            self.fixes.pop_front();
        }
        if let Some(velocity) = self.fit_velocity() {
            self.estimate.velocity = velocity;
        }
        self.estimate.position = position;
        self.estimate.stamp = stamp;
        self.estimate.visible = true;
        self.estimate.valid = true;
    }

    /// Slope of the least-squares line through the fixes in the window, if they span long enough
    /// (and are at least three), shrunk by its significance and capped at `max_object_speed`.
    fn fit_velocity(&self) -> Option<Vector3<f64>> {
        let (first, _) = *self.fixes.front()?;
        let (last, _) = *self.fixes.back()?;
        if last - first < self.config.min_velocity_span || self.fixes.len() < 3 {
            return None;
        }
        let n = self.fixes.len() as f64;
        let mean_t = self.fixes.iter().map(|&(t, _)| t - first).sum::<f64>() / n;
        let mean_p = self.fixes.iter().map(|&(_, p)| p).sum::<Vector3<f64>>() / n;
        let (mut stt, mut stp) = (0.0, Vector3::zeros());
        for &(t, p) in &self.fixes {
            let dt = t - first - mean_t;
            stt += dt * dt;
            stp += dt * (p - mean_p);
        }
        let slope = stp / stt;
        // The residuals about the line give the slope's standard error.
        let residual: f64 = self
            .fixes
            .iter()
            .map(|&(t, p)| (p - mean_p - (t - first - mean_t) * slope).norm_squared())
            .sum();
        let standard_error = (residual / (n - 2.0) / stt).sqrt();
        let speed = slope.norm();
        let significant = if speed > 0.0 {
            (1.0 - (self.config.velocity_significance * standard_error / speed).powi(2)).max(0.0)
        } else {
            0.0
        };
        let cap = if speed * significant > self.config.max_object_speed {
            self.config.max_object_speed / (speed * significant)
        } else {
            1.0
        };
        let velocity = slope * (significant * cap);
        velocity.iter().all(|v| v.is_finite()).then_some(velocity)
    }
}

fn isometry_is_finite(pose: &Isometry3<f64>) -> bool {
    pose.translation.vector.iter().all(|v| v.is_finite())
        && pose.rotation.coords.iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraConfig;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A camera straight above `(0, 0)` at height 0.5 looking down (tool z = −world z).
    fn looking_down() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 0.5),
            UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0),
        )
    }

    fn calibration() -> CameraCalibration {
        let mut c = CameraConfig::default().calibration();
        c.tool_from_camera = Isometry3::identity();
        c
    }

    /// A grey image with red squares of `half` pixels half-size at the given pixel centres.
    /// The fix of a lone red square of half-size `half` centred on pixel `centre`.
    fn fix_of_square(centre: (usize, usize), half: usize) -> Vector3<f64> {
        let mut p = Perception::new(PerceptionConfig::default(), calibration());
        p.step(&input(&image_with_squares(&[centre], half), 0.0))
            .position
    }

    fn image_with_squares(centres: &[(usize, usize)], half: usize) -> Vec<u8> {
        let (w, h) = (320, 240);
        let mut image = vec![100u8; w * h * 3];
        for &(cu, cv) in centres {
            for v in cv - half..=cv + half {
                for u in cu - half..=cu + half {
                    image[(v * w + u) * 3..(v * w + u) * 3 + 3].copy_from_slice(&[200, 20, 20]);
                }
            }
        }
        image
    }

    fn input(image: &[u8], stamp: f64) -> PerceptionInput<'_> {
        PerceptionInput {
            image,
            width: 320,
            height: 240,
            stamp,
            tool_pose: looking_down(),
            object_height: 0.0,
            target_hint: None,
            neighbours: &[],
            layout_trusted: false,
            colour: BlobColour::Red,
        }
    }

    #[test]
    fn red_square_at_the_principal_point_is_below_the_camera() {
        // The square is centred on pixel (159, 119), half a pixel from the principal point
        // (159.5, 119.5) in u and in v.
        let image = image_with_squares(&[(159, 119)], 2);
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        let estimate = perception.step(&input(&image, 0.0));
        assert!(estimate.visible && estimate.valid);
        let expected = 0.5 * (0.5 / calibration().model.fx);
        assert!(
            (estimate.position.x.abs() - expected).abs() < 1e-4,
            "{estimate:?}"
        );
        assert!(estimate.position.z.abs() < 1e-12);
    }

    #[test]
    fn a_ray_grazing_the_object_s_plane_gives_no_fix() {
        // The camera 5 cm above the plane: a square 84° off the optical axis lies 0.5 m away,
        // within max_range, but its ray meets the plane at 6°; one 60° off meets it at 30°.
        let f = calibration().model.fx;
        let off_axis = |theta: f64| (159 + (theta * f).round() as usize, 119);
        for (theta, seen) in [(84f64.to_radians(), false), (60f64.to_radians(), true)] {
            let image = image_with_squares(&[off_axis(theta)], 2);
            let mut perception = Perception::new(PerceptionConfig::default(), calibration());
            let estimate = perception.step(&PerceptionInput {
                object_height: 0.45,
                ..input(&image, 0.0)
            });
            assert_eq!(estimate.valid, seen, "{theta} rad: {estimate:?}");
            if seen {
                let range = (estimate.position - Vector3::new(0.0, 0.0, 0.5)).norm();
                assert!((range - 0.05 / theta.cos()).abs() < 0.01, "{range}");
            }
            // With the gate off, the grazing square gives its fix.
            let mut ungated = Perception::new(
                PerceptionConfig {
                    min_ray_angle: 0.0,
                    ..PerceptionConfig::default()
                },
                calibration(),
            );
            let estimate = ungated.step(&PerceptionInput {
                object_height: 0.45,
                ..input(&image, 0.0)
            });
            assert!(estimate.valid, "{theta} rad ungated: {estimate:?}");
        }
    }

    #[test]
    fn a_containers_first_fix_takes_three_agreeing_images_in_a_row() {
        let blue = |centre: (usize, usize)| -> Vec<u8> {
            image_with_squares(&[centre], 4)
                .chunks_exact(3)
                .flat_map(|p| {
                    if p[0] == 200 {
                        [20, 40, 200]
                    } else {
                        [p[0], p[1], p[2]]
                    }
                })
                .collect()
        };
        let grey = vec![100u8; 320 * 240 * 3];
        let step = |p: &mut Perception, image: &[u8], k: u32| {
            p.step(&PerceptionInput {
                colour: BlobColour::Blue,
                ..input(image, f64::from(k) / 30.0)
            })
        };
        let (here, there) = (blue((159, 119)), blue((110, 119)));
        // A lone fix, then none, then one 0.27 m off, then another: nothing is taken.
        let mut p = Perception::new(PerceptionConfig::default(), calibration());
        for (k, image) in [&here, &grey, &here, &there, &here].into_iter().enumerate() {
            let estimate = step(&mut p, image, k as u32);
            assert!(!estimate.valid && !estimate.visible, "image {k}");
        }
        // Two more agreeing images make three: the fix is taken, and from then on every one.
        assert!(!step(&mut p, &here, 5).valid);
        let estimate = step(&mut p, &here, 6);
        assert!(estimate.valid && estimate.visible);
        assert!(step(&mut p, &there, 7).visible);
        // A red target is never held back; with 1 neither is a container.
        let mut p = Perception::new(PerceptionConfig::default(), calibration());
        assert!(
            p.step(&input(&image_with_squares(&[(159, 119)], 4), 0.0))
                .valid
        );
        let once = PerceptionConfig {
            container_confirmations: 1,
            ..PerceptionConfig::default()
        };
        assert!(step(&mut Perception::new(once, calibration()), &here, 0).valid);
    }

    #[test]
    fn a_row_cube_s_first_fix_takes_three_agreeing_images_in_a_row() {
        // The far view of a row holds the two cubes beyond the target, which a shift of one
        // spacing explains as the target and its neighbour; the next images hold all three.
        let centres = [(100, 119), (160, 119), (220, 119)];
        let fix_of = |c: (usize, usize)| fix_of_square(c, 3);
        let row: Vec<_> = centres.iter().map(|&c| fix_of(c)).collect();
        let config = PerceptionConfig {
            max_prior_distance: 10.0,
            constellation_tolerance: (row[1] - row[0]).norm() / 3.0,
            ..PerceptionConfig::default()
        };
        let (far, whole) = (
            image_with_squares(&centres[1..], 3),
            image_with_squares(&centres, 3),
        );
        let neighbours = [row[1], row[2]];
        fn at<'a>(
            image: &'a [u8],
            k: usize,
            hint: Vector3<f64>,
            neighbours: &'a [Vector3<f64>],
        ) -> PerceptionInput<'a> {
            let mut frame = input(image, k as f64 / 30.0);
            frame.target_hint = Some(hint);
            frame.neighbours = neighbours;
            frame
        }
        let frame = |image, k| at(image, k, row[0], &neighbours);
        let (far, whole) = (far.as_slice(), whole.as_slice());
        // Taken at once, the far view's fix is the wrong cube.
        let once = PerceptionConfig {
            row_confirmations: 1,
            ..config
        };
        let wrong = Perception::new(once, calibration()).step(&frame(far, 0));
        assert!(
            wrong.valid && (wrong.position - row[1]).norm() < 1e-9,
            "{wrong:?}"
        );
        // With three: the far view and the first two whole ones give nothing, the third the
        // target, and the estimate follows it from then on.
        let mut p = Perception::new(config, calibration());
        for (k, image) in [far, whole, whole].into_iter().enumerate() {
            assert!(!p.step(&frame(image, k)).valid, "image {k}");
        }
        let estimate = p.step(&frame(whole, 3));
        assert!(estimate.valid && (estimate.position - row[0]).norm() < 1e-9);
        // Without neighbours a cube's first fix is taken at once.
        let mut lone = frame(whole, 0);
        lone.neighbours = &[];
        assert!(Perception::new(config, calibration()).step(&lone).valid);
    }

    #[test]
    fn the_first_fix_is_the_blob_whose_neighbours_are_where_the_mission_knows_them() {
        // A row of three cubes; the target is the one at the row's end, and the mission's
        // positions are all off by 0.6 of the spacing toward the middle cube, which is so the
        // nearest to the hint.
        let centres = [(100, 119), (160, 119), (220, 119)];
        let image = image_with_squares(&centres, 3);
        let fix_of = |c: (usize, usize)| fix_of_square(c, 3);
        let row: Vec<_> = centres.iter().map(|&c| fix_of(c)).collect();
        let step = row[1] - row[0];
        let error = 0.6 * step;
        let config = PerceptionConfig {
            max_prior_distance: 10.0,
            constellation_tolerance: step.norm() / 3.0,
            row_confirmations: 1,
            ..PerceptionConfig::default()
        };
        let neighbours = [row[1] + error, row[2] + error];
        let mut first = input(&image, 0.0);
        first.target_hint = Some(row[0] + error);
        first.neighbours = &neighbours;
        let with = Perception::new(config, calibration()).step(&first).position;
        assert!((with - row[0]).norm() < 1e-9, "{with} (row {row:?})");
        // Without the neighbours, the nearest blob to the hint: the wrong cube.
        first.neighbours = &[];
        let without = Perception::new(config, calibration()).step(&first).position;
        assert!((without - row[1]).norm() < 1e-9, "{without}");
    }

    #[test]
    fn with_a_trusted_layout_a_blob_nearer_a_neighbour_than_the_hint_is_that_neighbour() {
        // The target is out of the view; two cubes of the row beyond it are in it. Taken for the
        // target shifted by two spacings, the nearer one explains the other as its neighbour.
        let centres = [(160, 119), (220, 119)];
        let image = image_with_squares(&centres, 3);
        let fix_of = |c: (usize, usize)| fix_of_square(c, 3);
        let (a, b) = (fix_of(centres[0]), fix_of(centres[1]));
        let step = b - a;
        let config = PerceptionConfig {
            max_prior_distance: 10.0,
            constellation_tolerance: step.norm() / 3.0,
            row_confirmations: 1,
            ..PerceptionConfig::default()
        };
        let neighbours = [a - step, a, b];
        let mut first = input(&image, 0.0);
        first.target_hint = Some(a - 2.0 * step);
        first.neighbours = &neighbours;
        let untrusted = Perception::new(config, calibration()).step(&first);
        assert!(untrusted.valid && (untrusted.position - a).norm() < 1e-9);
        first.layout_trusted = true;
        let trusted = Perception::new(config, calibration()).step(&first);
        assert!(!trusted.valid, "{trusted:?}");
    }

    #[test]
    fn a_tracked_target_is_not_taken_for_its_merge_with_a_neighbour() {
        let (target, neighbour) = ((140, 119), (200, 119));
        let fix_of = |c: (usize, usize)| fix_of_square(c, 2);
        let neighbours = [fix_of(neighbour)];
        let config = PerceptionConfig {
            max_prior_distance: 10.0,
            row_confirmations: 1,
            ..PerceptionConfig::default()
        };
        let track = || {
            let mut p = Perception::new(config, calibration());
            let both = image_with_squares(&[target, neighbour], 2);
            let mut first = input(&both, 0.0);
            first.target_hint = Some(fix_of(target));
            first.neighbours = &neighbours;
            let fix = p.step(&first);
            assert!(fix.visible && (fix.position - fix_of(target)).norm() < 1e-9);
            p
        };
        fn next<'a>(
            image: &'a [u8],
            hint: Vector3<f64>,
            neighbours: &'a [Vector3<f64>],
        ) -> PerceptionInput<'a> {
            let mut frame = input(image, 0.1);
            frame.target_hint = Some(hint);
            frame.neighbours = neighbours;
            frame
        }
        // The two run together into one blob of four times the pixels, centred between them:
        // not a fix, the estimate is held.
        let merged = image_with_squares(&[(170, 119)], 4);
        let mut p = track();
        let held = p.step(&next(&merged, fix_of(target), &neighbours));
        assert!(!held.visible && (held.position - fix_of(target)).norm() < 1e-9);
        // The target's own blob growing as fast (the camera closing in) is still the target.
        let grown = image_with_squares(&[target], 4);
        let mut p = track();
        assert!(p.step(&next(&grown, fix_of(target), &neighbours)).visible);
    }

    #[test]
    fn chooses_the_blob_nearest_the_hint_then_tracks_it() {
        let image = image_with_squares(&[(60, 119), (260, 119)], 3);
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        let mut first = input(&image, 0.0);
        // Camera x is world x here (roll by π flips y and z), so u > cx is +x.
        first.target_hint = Some(Vector3::new(1.0, 0.0, 0.0));
        let estimate = perception.step(&first);
        assert!(estimate.position.x > 0.1, "{estimate:?}");
        let again = perception.step(&input(&image, 0.1));
        assert!((again.position - estimate.position).norm() < 1e-12);
        let mut other = Perception::new(PerceptionConfig::default(), calibration());
        first.target_hint = Some(Vector3::new(-1.0, 0.0, 0.0));
        assert!(other.step(&first).position.x < -0.1);
    }

    #[test]
    fn few_red_pixels_are_not_visible_and_the_last_fix_is_held() {
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        let seen = image_with_squares(&[(200, 100)], 2);
        let fix = perception.step(&input(&seen, 1.0));
        assert!(fix.visible);
        // A single red pixel (below min_pixels).
        let speck = image_with_squares(&[(200, 100)], 0);
        let lost = perception.step(&input(&speck, 1.1));
        assert!(!lost.visible && lost.valid);
        assert_eq!(lost.position, fix.position);
        assert_eq!(lost.stamp, 1.0);
    }

    #[test]
    fn non_finite_or_mismatched_input_never_yields_nan() {
        let image = image_with_squares(&[(200, 100)], 2);
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        let mut bad = input(&image, f64::NAN);
        assert!(!perception.step(&bad).visible);
        bad.stamp = 0.0;
        bad.object_height = f64::INFINITY;
        assert!(!perception.step(&bad).visible);
        bad.object_height = 0.0;
        bad.tool_pose.translation.vector.x = f64::NAN;
        assert!(!perception.step(&bad).visible);
        bad.tool_pose = looking_down();
        bad.width = 319;
        assert!(!perception.step(&bad).visible);
        bad.width = 320;
        bad.image = &image[3..];
        let estimate = perception.step(&bad);
        assert!(!estimate.visible && !estimate.valid);
        assert!(
            estimate
                .position
                .iter()
                .chain(estimate.velocity.iter())
                .all(|v| v.is_finite())
        );
        // The plane above the camera is never hit by a downward ray.
        let mut above = input(&image, 0.0);
        above.object_height = 1.0;
        assert!(!perception.step(&above).visible);
    }

    #[test]
    fn velocity_is_the_slope_of_the_fixes() {
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        // Feed fixes directly: 0.1 m/s along x, 30 Hz.
        for k in 0..30 {
            let t = k as f64 / 30.0;
            perception.record_fix(t, Vector3::new(0.1 * t, 0.0, 0.0));
        }
        let v = perception.estimate().velocity;
        assert!((v - Vector3::new(0.1, 0.0, 0.0)).norm() < 1e-9, "{v:?}");
        // The same frame twice replaces the fix rather than restarting the window.
        let last = 29.0 / 30.0;
        perception.record_fix(last, Vector3::new(0.1 * last, 0.0, 0.0));
        assert_eq!(perception.fixes.len(), 15 + 1);
        assert!((perception.estimate().velocity.x - 0.1).abs() < 1e-9);
        // Time going backwards restarts the window; the velocity is held until it spans enough.
        perception.record_fix(0.0, Vector3::zeros());
        assert!((perception.estimate().velocity.x - 0.1).abs() < 1e-9);
    }

    #[test]
    fn scattered_fixes_of_a_static_object_give_no_velocity() {
        // A far cube at a grazing angle: fixes scattered by ±12 cm about x = 6.5 (the pattern of
        // a deployed run's first fixes), 30 Hz. The plain slope of the first three is about
        // 1.9 m/s.
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        let scatter = [
            -0.07, -0.13, 0.11, 0.0, 0.08, -0.1, 0.12, -0.04, 0.05, -0.12,
        ];
        for (k, dx) in scatter.iter().enumerate() {
            let t = k as f64 * 0.035;
            perception.record_fix(t, Vector3::new(6.5 + dx, 1.0, 0.45));
            let v = perception.estimate().velocity;
            assert!(v.norm() < 0.25, "fix {k}: {v:?}");
        }
        let plain = PerceptionConfig {
            velocity_significance: 0.0,
            max_object_speed: f64::INFINITY,
            ..PerceptionConfig::default()
        };
        let mut unshrunk = Perception::new(plain, calibration());
        for (k, dx) in scatter.iter().take(3).enumerate() {
            unshrunk.record_fix(k as f64 * 0.05, Vector3::new(6.5 + dx, 1.0, 0.45));
        }
        assert!(unshrunk.estimate().velocity.norm() > 1.0);
    }

    #[test]
    fn a_clean_moving_fix_stream_keeps_its_velocity_and_speed_is_capped() {
        // 30 mm/s with 1 mm of noise: well above its standard error, so barely shrunk.
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        let noise = [0.001, -0.001, 0.0005, -0.0005, 0.0];
        for k in 0..30 {
            let t = k as f64 / 30.0;
            let x = 0.03 * t + noise[k % noise.len()];
            perception.record_fix(t, Vector3::new(x, 0.0, 0.0));
        }
        let v = perception.estimate().velocity;
        assert!((v.x - 0.03).abs() < 0.005, "{v:?}");
        // A clean line faster than any object on a table is scaled down to the cap.
        let mut fast = Perception::new(PerceptionConfig::default(), calibration());
        for k in 0..30 {
            let t = k as f64 / 30.0;
            fast.record_fix(t, Vector3::new(3.0 * t, 0.0, 0.0));
        }
        let v = fast.estimate().velocity;
        assert!((v.norm() - 0.5).abs() < 1e-9 && v.x > 0.0, "{v:?}");
    }

    #[test]
    fn a_wrong_velocity_never_locks_the_object_out() {
        let image = image_with_squares(&[(200, 100)], 2);
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        let fix = perception.step(&input(&image, 0.0));
        assert!(fix.visible);
        // A velocity the object does not have: one second later its prediction is 2 m away.
        perception.estimate.velocity = Vector3::new(2.0, 0.0, 0.0);
        let again = perception.step(&input(&image, 1.0));
        assert!(again.visible, "{again:?}");
        assert!((again.position - fix.position).norm() < 1e-9);
    }

    /// The 8-connected blobs of a mask by flood fill from each unvisited pixel in raster order:
    /// (pixels, Σu, Σv) per blob, in the order of their first pixel.
    fn flood_fill_blobs(mask: &[bool], w: usize, h: usize) -> Vec<(usize, u64, u64)> {
        let mut seen = vec![false; mask.len()];
        let mut blobs = Vec::new();
        for start in 0..mask.len() {
            if !mask[start] || seen[start] {
                continue;
            }
            seen[start] = true;
            let (mut stack, mut blob) = (vec![start], (0, 0, 0));
            while let Some(i) = stack.pop() {
                let (u, v) = (i % w, i / w);
                blob = (blob.0 + 1, blob.1 + u as u64, blob.2 + v as u64);
                for nv in v.saturating_sub(1)..=(v + 1).min(h - 1) {
                    for nu in u.saturating_sub(1)..=(u + 1).min(w - 1) {
                        let n = nv * w + nu;
                        if mask[n] && !seen[n] {
                            seen[n] = true;
                            stack.push(n);
                        }
                    }
                }
            }
            blobs.push(blob);
        }
        blobs
    }

    #[test]
    fn run_labelling_finds_the_blobs_a_flood_fill_finds() {
        use rand::{RngExt, SeedableRng};
        // Widths of 37 (rows end inside a mask word) and 40 (rows of whole words); random masks
        // of several densities give touching diagonals, U shapes merging late and runs at the row
        // ends.
        let h = 23;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut perception = Perception::new(PerceptionConfig::default(), calibration());
        for trial in 0..300 {
            let density = [0.05, 0.3, 0.5, 0.7][trial % 4];
            // A width of whole mask words too: a run then reaches the last word of a row.
            let w = [37, 40][(trial / 4) % 2];
            let mask: Vec<bool> = (0..w * h).map(|_| rng.random::<f64>() < density).collect();
            let image: Vec<u8> = mask
                .iter()
                .flat_map(|&red| if red { [200, 20, 20] } else { [100, 100, 100] })
                .collect();
            let count = perception.threshold(&image, w, BlobColour::Red);
            assert_eq!(count, mask.iter().filter(|&&m| m).count());
            perception.label_blobs();
            let found: Vec<(usize, u64, u64)> = perception
                .blobs
                .iter()
                .map(|b| (b.pixels, b.sum_u, b.sum_v))
                .collect();
            assert_eq!(found, flood_fill_blobs(&mask, w, h), "trial {trial}");
        }
    }
}
