//! The palm camera's renderer: real RGB8 images of the scene through the equidistant fisheye
//! model, with pixel noise, frame rate, latency and calibration error.
//!
//! The scene is a set of oriented boxes (the red cube, the platforms, the container's walls)
//! above a floor plane at z = 0, lit by one directional light plus ambient light. Each pixel's
//! ray (pre-computed once per camera, camera frame) is cast against the floor and the boxes
//! (slab test). To keep a frame near a millisecond, the image is split into 16×16 tiles whose
//! rays lie in a pre-computed cone; per frame, each box is tested only in the tiles whose cone
//! meets the box's bounding-sphere cone. The gripper's fingers are not rendered. Pixel noise:
//! [`crate::pixel_noise`].

use std::collections::VecDeque;

use motm_core::camera::{CameraCalibration, CameraConfig, CameraModel};
use nalgebra::{Isometry3, Matrix3, Vector2, Vector3};
use rand::{Rng, RngExt, SeedableRng};

use crate::pixel_noise::PixelNoise;
use rand_chacha::ChaCha8Rng;

/// Colour of the cube to pick: saturated red.
pub const CUBE_RED: [u8; 3] = [210, 28, 24];
/// Colour of the marking on top of a button's cap: red, so perception finds it as it finds a
/// cube (the two are told apart by nearness to the task's prior).
pub const BUTTON_RED: [u8; 3] = [200, 30, 30];
/// Colour of the body of a button's cap below its red marking: dark grey plastic.
pub const BUTTON_BODY: [u8; 3] = [60, 60, 64];
/// Colour of platforms and tables: light wood.
pub const PLATFORM_WOOD: [u8; 3] = [168, 160, 146];
/// Colour of the container: blue plastic.
pub const CONTAINER_BLUE: [u8; 3] = [40, 80, 170];
/// Colour of the floor.
pub const FLOOR_GREY: [u8; 3] = [120, 120, 116];
/// Colour seen where a ray hits nothing (walls and ceiling far away).
pub const BACKGROUND: [u8; 3] = [196, 204, 214];

/// Ambient share of the lighting; the directional light adds up to `1 − AMBIENT`.
const AMBIENT: f32 = 0.55;
/// Seed of the noise pool of a [`Renderer::new`] (a [`PalmCamera`] draws its own from its seed).
const NOISE_POOL_SEED: u64 = 0x9e37_79b9_7f4a_7c15;
/// Side of the square pixel tiles used to cull boxes, pixels.
const TILE: usize = 16;

/// An oriented, solid box in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneBox {
    /// World pose of the box centre (the box's edges run along its local axes).
    pub pose: Isometry3<f64>,
    /// Edge lengths along the local x, y, z axes, m.
    pub size: Vector3<f64>,
    /// Surface colour (before lighting), RGB8.
    pub colour: [u8; 3],
}

impl SceneBox {
    /// A red cube of edge `edge` (m) centred at `centre`, turned by `yaw` (rad) about world z.
    pub fn cube(centre: Vector3<f64>, yaw: f64, edge: f64) -> Self {
        Self {
            pose: Isometry3::new(centre, Vector3::z() * yaw),
            size: Vector3::repeat(edge),
            colour: CUBE_RED,
        }
    }

    /// An axis-aligned box standing on the floor whose top face is centred at `top_centre`, with
    /// horizontal extent `length × width` (m) and `colour`: a platform or table.
    pub fn platform(top_centre: Vector3<f64>, length: f64, width: f64, colour: [u8; 3]) -> Self {
        let height = top_centre.z.max(1e-3);
        Self {
            pose: Isometry3::translation(top_centre.x, top_centre.y, top_centre.z - 0.5 * height),
            size: Vector3::new(length, width, height),
            colour,
        }
    }
}

/// Everything the camera can see.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The boxes, in any order.
    pub boxes: Vec<SceneBox>,
    /// Colour of the floor plane z = 0.
    pub floor_colour: [u8; 3],
    /// Colour where a ray hits nothing.
    pub background: [u8; 3],
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            boxes: Vec::new(),
            floor_colour: FLOOR_GREY,
            background: BACKGROUND,
        }
    }
}

impl Scene {
    /// Adds an open-topped container: a floor slab and four walls of thickness `wall` (m), the
    /// outer footprint `length × width` (m) centred at `rim_centre` (x, y), rim at `rim_centre.z`,
    /// standing on the floor, turned by `yaw` (rad).
    pub fn add_container(
        &mut self,
        rim_centre: Vector3<f64>,
        yaw: f64,
        length: f64,
        width: f64,
        wall: f64,
        colour: [u8; 3],
    ) {
        let height = rim_centre.z.max(wall);
        let frame = Isometry3::new(
            Vector3::new(rim_centre.x, rim_centre.y, 0.0),
            Vector3::z() * yaw,
        );
        let mut part = |centre: Vector3<f64>, size: Vector3<f64>| {
            self.boxes.push(SceneBox {
                pose: frame * Isometry3::translation(centre.x, centre.y, centre.z),
                size,
                colour,
            });
        };
        let (hl, hw) = (0.5 * length, 0.5 * width);
        part(
            Vector3::new(0.0, 0.0, 0.5 * wall),
            Vector3::new(length, width, wall),
        );
        for side in [-1.0, 1.0] {
            part(
                Vector3::new(side * (hl - 0.5 * wall), 0.0, 0.5 * height),
                Vector3::new(wall, width, height),
            );
            part(
                Vector3::new(0.0, side * (hw - 0.5 * wall), 0.5 * height),
                Vector3::new(length - 2.0 * wall, wall, height),
            );
        }
    }
}

/// A tile of the image and the cone that contains all its pixels' rays.
#[derive(Debug, Clone, Copy)]
struct Tile {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
    /// Index of the tile's first row in [`Renderer::ray_rows`] (its rows follow in order).
    first_row: usize,
    /// Whether every pixel of the tile is inside the image circle.
    full: bool,
    /// The cone that contains every ray of the tile.
    cone: Cone,
}

impl Tile {
    /// Whether a box inside `cone` may be seen by a pixel of this tile: the angle between the
    /// two cone axes is at most the sum of the half-angles. Compared through cosines (no `acos`
    /// per tile and box), with a small margin so rounding never drops a box the exact test keeps.
    #[inline]
    fn may_see(&self, cone: &Cone) -> bool {
        let own = &self.cone;
        own.half_angle + cone.half_angle >= std::f64::consts::PI
            || own.axis.dot(&cone.axis)
                >= own.cos_half * cone.cos_half - own.sin_half * cone.sin_half - 1e-9
    }

    /// What every pixel of this tile sees when no box is in view, if it is the same surface
    /// for all of them ([`RowHits::floor`]'s floor or background), the camera `height` (m) above
    /// the floor, `up` the floor's normal in the camera frame. Decided from the tile's cone with
    /// a margin far above the f32 rounding of the per-pixel test, so a surface returned here is
    /// exactly the one that test gives every pixel; `None` when the tile is not wholly inside
    /// the image circle or its cone may straddle the horizon.
    fn sees_only(&self, up: &Vector3<f64>, height: f32) -> Option<u32> {
        /// Least |cosine| between `up` and a ray for its side of the horizon to count as sure.
        const MARGIN: f64 = 1e-5;
        if !self.full {
            return None;
        }
        if height.is_nan() || height <= 0.0 {
            return Some(SURFACE_BACKGROUND);
        }
        let cone = &self.cone;
        let cos_axis = up.dot(&cone.axis);
        let sin_axis = (1.0 - cos_axis * cos_axis).max(0.0).sqrt();
        // The cosines of the angles from `up` to the nearest and farthest rays of the cone
        // (valid when the cone does not contain `up`, resp. the direction opposite it).
        let nearest = cos_axis * cone.cos_half + sin_axis * cone.sin_half;
        let farthest = cos_axis * cone.cos_half - sin_axis * cone.sin_half;
        let small = cone.half_angle < std::f64::consts::FRAC_PI_2;
        if small && cos_axis <= cone.cos_half && nearest < -MARGIN {
            Some(SURFACE_FLOOR)
        } else if small && cos_axis >= -cone.cos_half && farthest > MARGIN {
            Some(SURFACE_BACKGROUND)
        } else {
            None
        }
    }
}

/// A circular cone of directions from the camera: its axis (unit) and half-angle.
#[derive(Debug, Clone, Copy)]
struct Cone {
    axis: Vector3<f64>,
    half_angle: f64,
    cos_half: f64,
    sin_half: f64,
}

impl Cone {
    fn new(axis: Vector3<f64>, half_angle: f64) -> Self {
        Self {
            axis,
            half_angle,
            cos_half: half_angle.cos(),
            sin_half: half_angle.sin(),
        }
    }
}

/// Number of pixels handled together in the ray loops: one row of a tile.
const LANES: usize = TILE;

/// The camera-frame unit rays of one tile row, one array per coordinate; zero outside the
/// lens' image circle and beyond the image's right edge (so a pixel is inside the circle
/// exactly when its ray is not zero). One cache line per array.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
struct RayRow {
    x: [f32; LANES],
    y: [f32; LANES],
    z: [f32; LANES],
}

/// What each pixel of a tile row sees so far: distance and surface (index into the palette).
struct RowHits {
    depth: [f32; LANES],
    surface: [u32; LANES],
}

impl RowHits {
    /// What the rays of a tile row see of the floor plane z = 0, the camera `height` (m) above
    /// it, `up` the floor's normal in the camera frame: the floor where a ray points down from
    /// above it, the background elsewhere, and nothing outside the image circle. The depths (the division) only when `DEPTH` (boxes
    /// to compare them with), infinite otherwise. Written lane by lane with every quotient
    /// computed (as [`PreparedBox::hit_row`]), so that it compiles to SIMD.
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "lane loops index several arrays at once, the form that compiles to SIMD"
    )]
    fn floor<const DEPTH: bool>(rays: &RayRow, up: &[f32; 3], height: f32) -> Self {
        let mut hits = RowHits {
            depth: [f32::INFINITY; LANES],
            surface: [SURFACE_BACKGROUND; LANES],
        };
        let above_floor = height > 0.0;
        for k in 0..LANES {
            let down = up[0] * rays.x[k] + up[1] * rays.y[k] + up[2] * rays.z[k];
            let floor = (down < 0.0) & above_floor;
            if DEPTH {
                let t = -height / down;
                hits.depth[k] = if floor { t } else { f32::INFINITY };
            }
            // A pixel outside the image circle has a zero ray, which no box's slab test hits.
            let inside = (rays.x[k] != 0.0) | (rays.y[k] != 0.0) | (rays.z[k] != 0.0);
            hits.surface[k] = if !inside {
                SURFACE_OUTSIDE
            } else if floor {
                SURFACE_FLOOR
            } else {
                SURFACE_BACKGROUND
            };
        }
        hits
    }
}

/// Palette index of a pixel outside the lens' image circle (black).
const SURFACE_OUTSIDE: u32 = 0;
/// Palette index of the background.
const SURFACE_BACKGROUND: u32 = 1;
/// Palette index of the floor.
const SURFACE_FLOOR: u32 = 2;
/// Palette index of the first face of the first box (each box has six).
const SURFACE_FIRST_BOX: u32 = 3;

/// A box prepared for one frame: its pose relative to the camera in f32.
#[derive(Debug, Clone, Copy)]
struct PreparedBox {
    /// Rows of the rotation from camera to box frame.
    box_from_camera: [[f32; 3]; 3],
    /// Slab bounds relative to the camera position, per axis: `−half − o` and `half − o`.
    slab_low: [f32; 3],
    slab_high: [f32; 3],
}

impl PreparedBox {
    fn new(
        box_from_camera: &Matrix3<f32>,
        camera_in_box: &Vector3<f32>,
        half: &Vector3<f32>,
    ) -> Self {
        Self {
            box_from_camera: [0, 1, 2].map(|r| [0, 1, 2].map(|c| box_from_camera[(r, c)])),
            slab_low: [0, 1, 2].map(|a| -half[a] - camera_in_box[a]),
            slab_high: [0, 1, 2].map(|a| half[a] - camera_in_box[a]),
        }
    }

    /// Casts the rays of a tile row at the box (slab test), keeping the nearest surface per
    /// pixel: a ray that enters the box in front of the camera, nearer than what the pixel saw
    /// so far, sees the face it enters through (−x, +x, −y, +y, −z, +z are palette entries
    /// `first_face..first_face + 6`); returns what `seen` becomes. Written lane by lane (one loop per step over the whole
    /// row) so that it compiles to SIMD; always inlined, so it is compiled for the target
    /// features of [`Renderer::render_into`]'s version that calls it.
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "lane loops index several arrays at once, the form that compiles to SIMD"
    )]
    fn hit_row(&self, rays: &RayRow, seen: &RowHits, first_face: u32) -> RowHits {
        // Per axis, the ray parameters where each ray crosses the slab's two planes (ordered)
        // and the face it would enter through; then, per lane, the latest entry and the
        // earliest exit, combined in registers. The result goes to new arrays: updating arrays
        // in place compiles to masked stores, slow on some CPUs.
        let mut hits = RowHits {
            depth: [0.0; LANES],
            surface: [0; LANES],
        };
        let mut entry = [[0.0f32; LANES]; 3];
        let mut exit = [[0.0f32; LANES]; 3];
        let mut entry_face = [[0u32; LANES]; 3];
        for axis in 0..3 {
            let (low, high) = (self.slab_low[axis], self.slab_high[axis]);
            let row = self.box_from_camera[axis];
            for k in 0..LANES {
                let d = row[0] * rays.x[k] + row[1] * rays.y[k] + row[2] * rays.z[k];
                let inv = 1.0 / d;
                let t1 = low * inv;
                let t2 = high * inv;
                let ordered = t1 < t2;
                entry[axis][k] = if ordered { t1 } else { t2 };
                exit[axis][k] = if ordered { t2 } else { t1 };
                entry_face[axis][k] = 2 * axis as u32 + u32::from(d < 0.0);
            }
        }
        for k in 0..LANES {
            let (mut near, mut far, mut face) = (f32::NEG_INFINITY, f32::INFINITY, 0);
            for axis in 0..3 {
                let lo = entry[axis][k];
                let enters = lo > near;
                near = if enters { lo } else { near };
                face = if enters { entry_face[axis][k] } else { face };
                // As f32::min: a NaN exit leaves `far` as it is.
                let hi = exit[axis][k];
                far = if hi < far { hi } else { far };
            }
            let closer = (near <= far) & (near > 0.0) & (near < seen.depth[k]);
            hits.depth[k] = if closer { near } else { seen.depth[k] };
            hits.surface[k] = if closer {
                first_face + face
            } else {
                seen.surface[k]
            };
        }
        hits
    }
}

/// Renders RGB8 images of a [`Scene`] through a [`CameraModel`].
#[derive(Debug, Clone)]
pub struct Renderer {
    model: CameraModel,
    /// The rays of every row of every tile of [`Renderer::tiles`], tile by tile: read in the
    /// order they are stored, one frame streams through them once.
    ray_rows: Vec<RayRow>,
    /// Byte ranges of the image rows of the tiles wholly outside the image circle (always black).
    blank: Vec<std::ops::Range<usize>>,
    tiles: Vec<Tile>,
    noise: PixelNoise,
    /// Byte ranges of the image inside the image circle (runs of whole pixels within a row).
    inside_runs: Vec<std::ops::Range<usize>>,
}

impl Renderer {
    /// A renderer for `model` adding Gaussian noise of `pixel_noise_std` (8-bit levels) to every
    /// channel of every pixel, its noise pool drawn from a fixed seed ([`Renderer::with_noise`]).
    pub fn new(model: CameraModel, pixel_noise_std: f64) -> Self {
        Self::with_noise(
            model,
            pixel_noise_std,
            &mut ChaCha8Rng::seed_from_u64(NOISE_POOL_SEED),
        )
    }

    /// [`Renderer::new`] with the pool of pre-drawn noise values (see [`crate::pixel_noise`])
    /// drawn from `rng`; each frame then draws only its offset into the pool.
    pub fn with_noise<R: Rng + ?Sized>(
        model: CameraModel,
        pixel_noise_std: f64,
        rng: &mut R,
    ) -> Self {
        let (w, h) = (model.width as usize, model.height as usize);
        let rays: Vec<Option<Vector3<f32>>> = (0..w * h)
            .map(|i| {
                let pixel = Vector2::new((i % w) as f64, (i / w) as f64);
                model
                    .unproject(&pixel)
                    .map(|r| r.into_inner().cast::<f32>())
            })
            .collect();
        let mut ray_rows = Vec::new();
        let mut tiles = Vec::new();
        let mut blank = Vec::new();
        for y0 in (0..h).step_by(TILE) {
            for x0 in (0..w).step_by(TILE) {
                let (x1, y1) = ((x0 + TILE).min(w), (y0 + TILE).min(h));
                let tile_rays = || {
                    (y0..y1)
                        .flat_map(move |y| (x0..x1).map(move |x| y * w + x))
                        .filter_map(|i| rays[i].map(|r| r.cast::<f64>()))
                };
                let sum: Vector3<f64> = tile_rays().sum();
                let Some(axis) = sum.try_normalize(1e-12) else {
                    blank.extend((y0..y1).map(|y| (y * w + x0) * 3..(y * w + x1) * 3));
                    continue;
                };
                let half_angle = tile_rays()
                    .map(|r| r.dot(&axis).clamp(-1.0, 1.0).acos())
                    .fold(0.0, f64::max);
                tiles.push(Tile {
                    x0,
                    y0,
                    x1,
                    y1,
                    first_row: ray_rows.len(),
                    full: tile_rays().count() == (x1 - x0) * (y1 - y0),
                    // Margin for f32 rounding of the rays.
                    cone: Cone::new(axis, half_angle + 1e-4),
                });
                ray_rows.extend((y0..y1).map(|y| {
                    let mut row = RayRow::default();
                    for (k, ray) in rays[y * w + x0..y * w + x1].iter().enumerate() {
                        if let Some(r) = ray {
                            (row.x[k], row.y[k], row.z[k]) = (r.x, r.y, r.z);
                        }
                    }
                    row
                }));
            }
        }
        let inside_runs = inside_runs(&rays, w);
        let inside_len = inside_runs.iter().map(|run| run.len()).sum();
        Self {
            model,
            ray_rows,
            blank,
            tiles,
            noise: PixelNoise::new(pixel_noise_std, inside_len, rng),
            inside_runs,
        }
    }

    /// The camera model this renderer images through.
    pub fn model(&self) -> &CameraModel {
        &self.model
    }

    /// Renders `scene` seen from `world_from_camera` into a new row-major RGB8 image.
    pub fn render<R: Rng + ?Sized>(
        &self,
        scene: &Scene,
        world_from_camera: &Isometry3<f64>,
        rng: &mut R,
    ) -> Vec<u8> {
        let mut image = vec![0; self.model.width as usize * self.model.height as usize * 3];
        self.render_into(scene, world_from_camera, rng, &mut image);
        image
    }

    /// Renders `scene` seen from `world_from_camera` into `image` (row-major RGB8, exactly
    /// `width × height × 3` bytes). Pixels outside the lens' image circle are black. Noise draws
    /// come from `rng` (none when the noise is zero).
    ///
    /// # Panics
    /// If `image` has the wrong length.
    /// Uses AVX2 where the CPU has it (found at run time): the same code vectorised wider, and
    /// the same image to the bit (the lane loops are element-wise IEEE operations, no FMA).
    pub fn render_into<R: Rng + ?Sized>(
        &self,
        scene: &Scene,
        world_from_camera: &Isometry3<f64>,
        rng: &mut R,
        image: &mut [u8],
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            unsafe { self.render_into_avx2(scene, world_from_camera, rng, image) };
            return;
        }
        self.render_into_any(scene, world_from_camera, rng, image);
    }

    /// [`Renderer::render_into`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn render_into_avx2<R: Rng + ?Sized>(
        &self,
        scene: &Scene,
        world_from_camera: &Isometry3<f64>,
        rng: &mut R,
        image: &mut [u8],
    ) {
        self.render_into_any(scene, world_from_camera, rng, image);
    }

    /// [`Renderer::render_into`] for any CPU; inlined into each target's version.
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "lane loops index several arrays at once, the form that compiles to SIMD"
    )]
    fn render_into_any<R: Rng + ?Sized>(
        &self,
        scene: &Scene,
        world_from_camera: &Isometry3<f64>,
        rng: &mut R,
        image: &mut [u8],
    ) {
        let w = self.model.width as usize;
        assert_eq!(
            image.len(),
            w * self.model.height as usize * 3,
            "image size"
        );
        for range in &self.blank {
            image[range.clone()].fill(0);
        }
        let light = Vector3::new(0.3, -0.2, 1.0).normalize();
        let lit = |colour: [u8; 3], normal: Vector3<f64>| {
            let shade = AMBIENT + (1.0 - AMBIENT) * (normal.dot(&light) as f32).max(0.0);
            let [r, g, b] = colour.map(|c| (c as f32 * shade).round() as u8);
            u32::from_le_bytes([r, g, b, 0])
        };
        let camera_from_world = world_from_camera.inverse();
        // Palette: black outside the image circle, background, floor, then the six lit faces of
        // every box.
        let [r, g, b] = scene.background;
        let mut palette = vec![
            0,
            u32::from_le_bytes([r, g, b, 0]),
            lit(scene.floor_colour, Vector3::z()),
        ];
        let boxes: Vec<PreparedBox> = scene
            .boxes
            .iter()
            .map(|b| {
                let box_from_camera = b.pose.inverse() * world_from_camera;
                let r = b.pose.rotation;
                for a in [r * Vector3::x(), r * Vector3::y(), r * Vector3::z()] {
                    palette.push(lit(b.colour, -a));
                    palette.push(lit(b.colour, a));
                }
                PreparedBox::new(
                    &box_from_camera
                        .rotation
                        .to_rotation_matrix()
                        .matrix()
                        .cast(),
                    &box_from_camera.translation.vector.cast(),
                    &(0.5 * b.size).cast(),
                )
            })
            .collect();
        // Bounding cones of every box seen from the camera: a tile may see a box only when it
        // may see both.
        let cones: Vec<[Option<Cone>; 2]> = scene
            .boxes
            .iter()
            .map(|b| {
                let camera_from_box = camera_from_world * b.pose;
                [
                    sphere_cone(b, &camera_from_box),
                    corner_cone(b, &camera_from_box),
                ]
            })
            .collect();
        let up = camera_from_world.rotation * Vector3::z();
        let floor_normal: [f32; 3] = up.cast().into();
        let camera_height = world_from_camera.translation.z as f32;
        let mut candidates = Vec::with_capacity(boxes.len());
        for tile in &self.tiles {
            candidates.clear();
            candidates.extend(cones.iter().enumerate().filter_map(|(i, cones)| {
                cones
                    .iter()
                    .flatten()
                    .all(|cone| tile.may_see(cone))
                    .then_some(i)
            }));
            // A tile that sees one surface only needs neither its rays nor the palette per pixel.
            let only = if candidates.is_empty() {
                tile.sees_only(&up, camera_height)
            } else {
                None
            };
            let rows = &self.ray_rows[tile.first_row..tile.first_row + (tile.y1 - tile.y0)];
            for (y, rays) in (tile.y0..tile.y1).zip(rows) {
                // Every pixel of the tile row, black outside the image circle.
                let colours = if let Some(surface) = only {
                    [palette[surface as usize]; LANES]
                } else {
                    let mut hits = if candidates.is_empty() {
                        RowHits::floor::<false>(rays, &floor_normal, camera_height)
                    } else {
                        RowHits::floor::<true>(rays, &floor_normal, camera_height)
                    };
                    for &i in &candidates {
                        hits = boxes[i].hit_row(rays, &hits, SURFACE_FIRST_BOX + 6 * i as u32);
                    }
                    // Often the whole row sees one surface: one palette look-up then (told by
                    // a lane loop over all lanes, which compiles to whole-vector operations).
                    let first = hits.surface[0];
                    let mut differ = 0;
                    for k in 0..LANES {
                        differ |= hits.surface[k] ^ first;
                    }
                    if differ == 0 {
                        [palette[first as usize]; LANES]
                    } else {
                        hits.surface.map(|s| palette[s as usize])
                    }
                };
                let row = &mut image[(y * w + tile.x0) * 3..(y * w + tile.x1) * 3];
                if let Ok(whole) = <&mut [u8; 3 * LANES]>::try_from(&mut *row) {
                    // Stored four bytes at a time, each overwriting the spare byte of the one
                    // before, the last pixel three.
                    for (k, colour) in colours[..LANES - 1].iter().enumerate() {
                        whole[3 * k..3 * k + 4].copy_from_slice(&colour.to_le_bytes());
                    }
                    let last = colours[LANES - 1].to_le_bytes();
                    whole[3 * LANES - 3..].copy_from_slice(&last[..3]);
                } else {
                    for (pixel, colour) in row.chunks_exact_mut(3).zip(colours) {
                        pixel.copy_from_slice(&colour.to_le_bytes()[..3]);
                    }
                }
            }
        }
        let inside_len = self.inside_runs.iter().map(|run| run.len()).sum();
        self.noise
            .add_frame(image, &self.inside_runs, inside_len, rng);
    }
}

type Point = nalgebra::Point3<f64>;

/// The cone from the camera around the bounding sphere of `b`, `camera_from_box` its pose in
/// the camera frame; `None` when the camera is inside the sphere (the box may be anywhere in
/// the image).
fn sphere_cone(b: &SceneBox, camera_from_box: &Isometry3<f64>) -> Option<Cone> {
    let centre = camera_from_box.translation.vector;
    let distance = centre.norm();
    let radius = 0.5 * b.size.norm();
    (distance > radius * 1.001).then(|| Cone::new(centre / distance, (radius / distance).asin()))
}

/// A cone from the camera containing every ray that hits `b` (`camera_from_box` its pose in the
/// camera frame), tighter than [`sphere_cone`] for a flat or long box or a near one: the cone
/// around the directions to the corners of the box grown by far more than the f32 rounding of
/// the slab test, which contains every direction to a point of the box (the box is the convex
/// hull of its corners, and a cone narrower than a half-space is convex). `None` when the
/// camera is inside the grown box or the cone would be a half-space or wider.
fn corner_cone(b: &SceneBox, camera_from_box: &Isometry3<f64>) -> Option<Cone> {
    let camera_in_box = camera_from_box.inverse().translation.vector;
    let grow = 1e-4 * (1.0 + camera_in_box.norm() + b.size.norm());
    let half = b.size.map(|s| 0.5 * s + grow);
    if (0..3).all(|a| camera_in_box[a].abs() <= half[a]) {
        return None;
    }
    let corners = [0u8, 1, 2, 3, 4, 5, 6, 7].map(|c| {
        let sign = |bit: u8| if c & bit == 0 { -1.0 } else { 1.0 };
        let corner = Vector3::new(sign(1) * half.x, sign(2) * half.y, sign(4) * half.z);
        (camera_from_box * Point::from(corner)).coords.normalize()
    });
    let axis = corners.iter().sum::<Vector3<f64>>().try_normalize(1e-12)?;
    let half_angle = corners
        .iter()
        .map(|c| c.dot(&axis).clamp(-1.0, 1.0).acos())
        .fold(0.0, f64::max)
        + 1e-4;
    (half_angle < std::f64::consts::FRAC_PI_2 - 1e-3).then(|| Cone::new(axis, half_angle))
}

/// The byte ranges of a row-major RGB8 image of width `w` covered by runs of pixels whose ray
/// exists, each run within one row.
fn inside_runs(rays: &[Option<Vector3<f32>>], w: usize) -> Vec<std::ops::Range<usize>> {
    let mut runs = Vec::new();
    for (y, row) in rays.chunks(w).enumerate() {
        let mut x = 0;
        while x < w {
            if row[x].is_none() {
                x += 1;
                continue;
            }
            let start = x;
            while x < w && row[x].is_some() {
                x += 1;
            }
            runs.push((y * w + start) * 3..(y * w + x) * 3);
        }
    }
    runs
}

/// One image from the palm camera.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFrame {
    /// RGB8 pixels, row-major.
    pub image: Vec<u8>,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Capture (exposure) time, s.
    pub stamp: f64,
}

/// The simulated palm camera: captures at its frame rate, delivers each frame after its latency,
/// and hands perception a calibration that is off by the configured extrinsic error.
#[derive(Debug, Clone)]
pub struct PalmCamera {
    config: CameraConfig,
    renderer: Renderer,
    rng: ChaCha8Rng,
    calibration: CameraCalibration,
    next_capture: f64,
    in_flight: VecDeque<Exposure>,
}

impl PalmCamera {
    /// A camera with `config` (assumed valid, see [`CameraConfig::validate`]); `seed` seeds the
    /// pixel noise and the calibration error drawn here.
    pub fn new(config: &CameraConfig, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let offset = random_unit_vector(&mut rng) * config.extrinsic_error;
        Self {
            config: *config,
            renderer: Renderer::with_noise(config.model(), config.pixel_noise_std, &mut rng),
            calibration: config.calibration().with_position_offset(offset),
            rng,
            next_capture: 0.0,
            in_flight: VecDeque::new(),
        }
    }

    /// The calibration perception should use (the true one plus the calibration error).
    pub fn calibration(&self) -> CameraCalibration {
        self.calibration
    }

    /// Time of the next capture, s: a scene passed to [`PalmCamera::step`] before then is not
    /// rendered.
    pub fn next_capture(&self) -> f64 {
        self.next_capture
    }

    /// The renderer (true intrinsics).
    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }

    /// Advances the camera to time `now` (s): captures a frame of `scene` from the true tool pose
    /// `world_from_tool` when one is due, and returns the newest frame whose latency has passed
    /// (older undelivered frames are dropped, as a driver that keeps only the latest would).
    pub fn step(
        &mut self,
        scene: &Scene,
        world_from_tool: &Isometry3<f64>,
        now: f64,
    ) -> Option<CameraFrame> {
        self.step_rendering(scene, world_from_tool, now, true)
    }

    /// [`PalmCamera::step`], but the frame due for delivery is rendered (and returned) only when
    /// `render` is true: a frame nobody reads need not be rendered. A frame is rendered when it
    /// is delivered, from the scene, pose and noise seed kept at its capture, so captures,
    /// delivery times and the seeded draws are the same whatever `render` says, and every frame
    /// that is rendered is bit for bit the one [`PalmCamera::step`] gives.
    pub fn step_rendering(
        &mut self,
        scene: &Scene,
        world_from_tool: &Isometry3<f64>,
        now: f64,
        render: bool,
    ) -> Option<CameraFrame> {
        let exposure = self
            .expose(scene, world_from_tool, now)
            .filter(|_| render)?;
        Some(self.frame(&exposure))
    }

    /// `exposure` drawn into a new image ([`PalmCamera::render`]).
    pub fn frame(&self, exposure: &Exposure) -> CameraFrame {
        let mut image = vec![0; self.config.width as usize * self.config.height as usize * 3];
        self.render(exposure, &mut image);
        CameraFrame {
            image,
            width: self.config.width,
            height: self.config.height,
            stamp: exposure.stamp,
        }
    }

    /// [`PalmCamera::step`] without the rendering: captures what is due at `now` (s) and returns
    /// the newest capture whose latency has passed, for [`PalmCamera::render`] to draw into a
    /// buffer of the caller's (a frame nobody reads is then never drawn). The captures, the
    /// delivery times and the seeded draws are those of [`PalmCamera::step`].
    pub fn expose(
        &mut self,
        scene: &Scene,
        world_from_tool: &Isometry3<f64>,
        now: f64,
    ) -> Option<Exposure> {
        if now >= self.next_capture {
            self.in_flight.push_back(Exposure {
                scene: scene.clone(),
                world_from_camera: world_from_tool * self.config.tool_from_camera.isometry(),
                noise_seed: self.rng.next_u64(),
                stamp: now,
            });
            let period = 1.0 / self.config.rate_hz;
            self.next_capture = (self.next_capture + period).max(now + 0.5 * period);
        }
        let mut ready = None;
        while self
            .in_flight
            .front()
            .is_some_and(|f| f.stamp + self.config.latency <= now)
        {
            ready = self.in_flight.pop_front();
        }
        ready
    }

    /// Draws `exposure` into `image` (row-major RGB8, `width × height × 3` bytes, every byte
    /// written): bit for bit the frame [`PalmCamera::step`] delivers for it.
    ///
    /// # Panics
    /// If `image` has the wrong length.
    pub fn render(&self, exposure: &Exposure, image: &mut [u8]) {
        self.renderer.render_into(
            &exposure.scene,
            &exposure.world_from_camera,
            &mut ChaCha8Rng::seed_from_u64(exposure.noise_seed),
            image,
        );
    }

    /// Image width and height, pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.config.width, self.config.height)
    }
}

/// A frame captured and delivered but not yet drawn ([`PalmCamera::expose`]): the scene and pose
/// at its exposure and the seed of its noise.
#[derive(Debug, Clone)]
pub struct Exposure {
    scene: Scene,
    world_from_camera: Isometry3<f64>,
    noise_seed: u64,
    stamp: f64,
}

impl Exposure {
    /// Capture (exposure) time, s.
    pub fn stamp(&self) -> f64 {
        self.stamp
    }
}

/// A direction drawn uniformly on the unit sphere.
fn random_unit_vector<R: Rng + ?Sized>(rng: &mut R) -> Vector3<f64> {
    loop {
        let v = Vector3::from_fn(|_, _| 2.0 * rng.random::<f64>() - 1.0);
        let n = v.norm();
        if n > 1e-3 && n <= 1.0 {
            return v / n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_test_finds_the_entry_face() {
        let cube = PreparedBox::new(
            &Matrix3::identity(),
            &Vector3::new(0.0, 0.0, 1.0),
            &Vector3::repeat(0.1),
        );
        // Lane 0 looks straight down at the cube, lane 1 up (behind), lane 2 beside it.
        let beside = Vector3::new(1.0f32, 0.0, -1.0).normalize();
        let (mut x, mut y, mut z) = ([0.0; LANES], [0.0; LANES], [-1.0f32; LANES]);
        z[1] = 1.0;
        (x[2], y[2], z[2]) = (beside.x, beside.y, beside.z);
        let rays = RayRow { x, y, z };
        let nothing = RowHits {
            depth: [f32::INFINITY; LANES],
            surface: [SURFACE_BACKGROUND; LANES],
        };
        let hits = cube.hit_row(&rays, &nothing, SURFACE_FIRST_BOX);
        assert!((hits.depth[0] - 0.9).abs() < 1e-6);
        assert_eq!(hits.surface[0], SURFACE_FIRST_BOX + 5, "+z face");
        assert_eq!(hits.surface[1], SURFACE_BACKGROUND, "behind");
        assert_eq!(hits.surface[2], SURFACE_BACKGROUND, "beside");
        // A nearer surface already seen hides the cube.
        let nearer = RowHits {
            depth: [0.5; LANES],
            surface: [SURFACE_FLOOR; LANES],
        };
        let nearer = cube.hit_row(&rays, &nearer, SURFACE_FIRST_BOX);
        assert_eq!(nearer.surface[0], SURFACE_FLOOR);
    }

    #[test]
    fn camera_delivers_frames_after_the_latency_at_the_frame_rate() {
        let config = CameraConfig {
            width: 32,
            height: 24,
            ..Default::default()
        };
        let mut camera = PalmCamera::new(&config, 7);
        let scene = Scene::default();
        let pose = Isometry3::translation(0.0, 0.0, 1.0);
        let mut stamps = Vec::new();
        for k in 0..=1000 {
            let now = k as f64 * 0.001;
            if let Some(frame) = camera.step(&scene, &pose, now) {
                assert!(now - frame.stamp >= config.latency - 1e-12);
                assert!(now - frame.stamp < config.latency + 0.002);
                assert_eq!(frame.image.len(), 32 * 24 * 3);
                stamps.push(frame.stamp);
            }
        }
        // 30 Hz for 1 s, minus the frames still in flight.
        assert!((29..=31).contains(&stamps.len()), "{} frames", stamps.len());
        let offset = camera.calibration().tool_from_camera.translation.vector
            - config.tool_from_camera.isometry().translation.vector;
        assert!((offset.norm() - config.extrinsic_error).abs() < 1e-12);
    }

    #[test]
    fn frames_left_unrendered_leave_the_rendered_ones_unchanged() {
        let config = CameraConfig {
            width: 48,
            height: 32,
            pixel_noise_std: 2.0,
            ..Default::default()
        };
        let mut scene = Scene::default();
        scene
            .boxes
            .push(SceneBox::cube(Vector3::new(0.05, 0.0, 0.5), 0.3, 0.05));
        let mut always = PalmCamera::new(&config, 3);
        let mut sometimes = PalmCamera::new(&config, 3);
        let (mut compared, mut skipped) = (0, 0);
        for k in 0..=600 {
            let now = k as f64 * 0.001;
            let pose = Isometry3::new(
                Vector3::new(0.0002 * k as f64, 0.0, 1.0),
                Vector3::new(std::f64::consts::PI, 0.0, 0.0),
            );
            let render = (k / 100) % 2 == 0;
            let full = always.step(&scene, &pose, now);
            let partial = sometimes.step_rendering(&scene, &pose, now, render);
            match (full, partial) {
                (Some(a), Some(b)) => {
                    assert_eq!(a, b);
                    compared += 1;
                }
                (Some(_), None) => {
                    assert!(!render);
                    skipped += 1;
                }
                (None, None) => {}
                (None, Some(_)) => panic!("a frame the full camera did not deliver"),
            }
        }
        assert!(
            compared >= 5 && skipped >= 5,
            "{compared} compared, {skipped} skipped"
        );
    }

    #[test]
    fn the_avx2_renderer_draws_the_same_image_as_the_portable_one() {
        let config = CameraConfig {
            pixel_noise_std: 2.0,
            ..Default::default()
        };
        let renderer = Renderer::new(config.model(), config.pixel_noise_std);
        let mut scene = Scene::default();
        scene
            .boxes
            .push(SceneBox::cube(Vector3::new(0.05, 0.02, 0.5), 0.3, 0.05));
        scene.boxes.push(SceneBox::platform(
            Vector3::new(0.1, 0.0, 0.475),
            0.6,
            0.4,
            PLATFORM_WOOD,
        ));
        scene.add_container(
            Vector3::new(-0.3, 0.3, 0.4),
            0.2,
            0.4,
            0.3,
            0.01,
            CONTAINER_BLUE,
        );
        let (w, h) = (config.width as usize, config.height as usize);
        let mut with_cube = 0;
        for k in 0..20 {
            let pose = Isometry3::new(
                Vector3::new(0.02 * k as f64, -0.01 * k as f64, 1.0),
                Vector3::new(std::f64::consts::PI - 0.03 * k as f64, 0.02 * k as f64, 0.1),
            );
            let mut dispatched = vec![0; w * h * 3];
            let mut portable = vec![0; w * h * 3];
            renderer.render_into(
                &scene,
                &pose,
                &mut ChaCha8Rng::seed_from_u64(k),
                &mut dispatched,
            );
            renderer.render_into_any(
                &scene,
                &pose,
                &mut ChaCha8Rng::seed_from_u64(k),
                &mut portable,
            );
            assert!(dispatched == portable, "pose {k}");
            let red = |p: &[u8]| {
                let [r, g, b] = [p[0], p[1], p[2]].map(u16::from);
                r > 80 && r > g + 50 && r > b + 50
            };
            with_cube += usize::from(dispatched.chunks_exact(3).any(red));
        }
        assert!(
            with_cube >= 10,
            "the cube is in view in {with_cube} of 20 frames"
        );
    }
}
