//! The palm camera: an equidistant fisheye model (r = f·θ), its configuration and calibration.
//!
//! Camera frame: z along the optical axis (out of the lens), x to the right of the image, y down
//! the image. Pixel coordinates: `u` along the columns, `v` along the rows, and the centre of
//! pixel `(column i, row j)` sits at `(u, v) = (i, j)`, so the image centre is
//! `((width − 1)/2, (height − 1)/2)`.

use std::path::Path;

use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector2, Vector3};
use serde::Deserialize;

use crate::error::ModelError;

/// A rigid pose written as in URDF: translation `xyz` (m), then roll, pitch, yaw `rpy` (rad,
/// fixed axes x, y, z).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MountPose {
    /// Translation, m.
    pub xyz: [f64; 3],
    /// Roll, pitch, yaw, rad.
    pub rpy: [f64; 3],
}

impl MountPose {
    /// The pose as an isometry (parent from child).
    pub fn isometry(&self) -> Isometry3<f64> {
        let [x, y, z] = self.xyz;
        let [roll, pitch, yaw] = self.rpy;
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(roll, pitch, yaw),
        )
    }
}

/// The palm camera's configuration (the `[camera]` table of a configuration file). Every key is
/// optional; unknown keys are errors.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Image width, pixels. Default 320 (docs/algorithms.md §4): at 0.5 m a 30 mm cube then covers
    /// about 6×6 pixels, enough for a centroid good to a millimetre, and a frame renders in about
    /// a millisecond.
    pub width: u32,
    /// Image height, pixels. Default 240 (4:3).
    pub height: u32,
    /// Full field of view of the lens, rad. Default π (180°). The focal length is chosen so that
    /// this field spans the image width: f = (width / 2) / (field_of_view / 2). Rays further than
    /// `field_of_view / 2` from the optical axis are outside the lens' image circle (black).
    pub field_of_view: f64,
    /// Pose of the camera in the tool frame. Default: `xyz = [0.04, 0, −0.0434]`, `rpy = 0`:
    /// in the palm of the Franka Hand, 6 cm beyond the flange (the tool point is 10.34 cm beyond
    /// it), 4 cm off the finger axis, looking along the tool z axis (the approach direction),
    /// with image x along tool x.
    pub tool_from_camera: MountPose,
    /// Standard deviation of the additive Gaussian noise on every channel of every pixel, in 8-bit
    /// intensity levels. Default 1.0 (the scenario key `camera_pixel_std`).
    pub pixel_noise_std: f64,
    /// Extrinsic calibration error, m: the distance between the true camera position in the tool
    /// frame and the calibrated one that perception uses, in a random direction drawn per trial.
    /// Default 0.005 (the scenario key `camera_extrinsic_error`).
    pub extrinsic_error: f64,
    /// Time from exposure to the image being available to perception, s. Default 0.03 (about
    /// one frame at 30 Hz, typical of a USB camera).
    pub latency: f64,
    /// Frame rate, Hz. Default 30 (docs/architecture.md: perception runs on each camera frame).
    pub rate_hz: f64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            width: 320,
            height: 240,
            field_of_view: std::f64::consts::PI,
            tool_from_camera: MountPose {
                xyz: [0.04, 0.0, -0.0434],
                rpy: [0.0; 3],
            },
            pixel_noise_std: 1.0,
            extrinsic_error: 0.005,
            latency: 0.03,
            rate_hz: 30.0,
        }
    }
}

impl CameraConfig {
    /// Checks every value; `file` and `table` (e.g. `camera`) name the place in the error.
    pub fn validate(&self, file: &Path, table: &str) -> Result<(), ModelError> {
        let key = |name: &str| format!("{table}.{name}");
        let bad = |name: &str, message: &str| Err(ModelError::invalid(file, key(name), message));
        if self.width < 2 || self.width > 4096 {
            return bad("width", "must be between 2 and 4096 pixels");
        }
        if self.height < 2 || self.height > 4096 {
            return bad("height", "must be between 2 and 4096 pixels");
        }
        if !(self.field_of_view > 0.0 && self.field_of_view <= 2.0 * std::f64::consts::PI) {
            return bad("field_of_view", "must be in (0, 2π] rad");
        }
        let mount = self.tool_from_camera;
        if !mount
            .xyz
            .iter()
            .chain(mount.rpy.iter())
            .all(|v| v.is_finite())
        {
            return bad("tool_from_camera", "xyz and rpy must be finite");
        }
        if !(self.pixel_noise_std.is_finite() && self.pixel_noise_std >= 0.0) {
            return bad("pixel_noise_std", "must be a finite value ≥ 0");
        }
        if !(self.extrinsic_error.is_finite() && self.extrinsic_error >= 0.0) {
            return bad("extrinsic_error", "must be a finite value ≥ 0 m");
        }
        if !(self.latency.is_finite() && self.latency >= 0.0) {
            return bad("latency", "must be a finite value ≥ 0 s");
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return bad("rate_hz", "must be a finite value > 0 Hz");
        }
        Ok(())
    }

    /// The intrinsic model these settings describe.
    pub fn model(&self) -> CameraModel {
        CameraModel::new(self.width, self.height, self.field_of_view)
    }

    /// The true calibration (intrinsics and mount pose) of a camera with these settings.
    pub fn calibration(&self) -> CameraCalibration {
        CameraCalibration {
            model: self.model(),
            tool_from_camera: self.tool_from_camera.isometry(),
        }
    }
}

/// Intrinsics of an equidistant fisheye camera: a ray at angle θ from the optical axis and
/// azimuth φ images at `(u, v) = (cx + fx·θ·cos φ, cy + fy·θ·sin φ)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraModel {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length along u, pixels per radian.
    pub fx: f64,
    /// Focal length along v, pixels per radian.
    pub fy: f64,
    /// Principal point, column coordinate (pixels).
    pub cx: f64,
    /// Principal point, row coordinate (pixels).
    pub cy: f64,
    /// Largest angle from the optical axis the lens images, rad (half the field of view).
    pub max_theta: f64,
}

impl CameraModel {
    /// A model whose `field_of_view` (rad) spans the image width, with square pixels and the
    /// principal point at the image centre.
    pub fn new(width: u32, height: u32, field_of_view: f64) -> Self {
        let f = 0.5 * width as f64 / (0.5 * field_of_view);
        Self {
            width,
            height,
            fx: f,
            fy: f,
            cx: 0.5 * (width as f64 - 1.0),
            cy: 0.5 * (height as f64 - 1.0),
            max_theta: 0.5 * field_of_view,
        }
    }

    /// The pixel at which the camera-frame point `point` images, or `None` when it is at the
    /// camera centre, outside the lens' field of view, outside the image or not finite.
    pub fn project(&self, point: &Vector3<f64>) -> Option<Vector2<f64>> {
        let pixel = self.project_unbounded(point)?;
        let inside = pixel.x >= -0.5
            && pixel.y >= -0.5
            && pixel.x <= self.width as f64 - 0.5
            && pixel.y <= self.height as f64 - 0.5;
        inside.then_some(pixel)
    }

    /// Like [`CameraModel::project`], but the pixel may lie outside the image rectangle.
    pub fn project_unbounded(&self, point: &Vector3<f64>) -> Option<Vector2<f64>> {
        let rho = point.x.hypot(point.y);
        let theta = rho.atan2(point.z);
        if !theta.is_finite() || theta > self.max_theta || point.norm() == 0.0 {
            return None;
        }
        // θ/ρ → 1/z on the optical axis; use the limit to stay finite there.
        let scale = if rho > 1e-12 * point.z.abs() {
            theta / rho
        } else {
            1.0 / point.z
        };
        Some(Vector2::new(
            self.cx + self.fx * scale * point.x,
            self.cy + self.fy * scale * point.y,
        ))
    }

    /// The unit ray (camera frame) of `pixel`, or `None` when the pixel is outside the lens'
    /// image circle or not finite. Pixels outside the image rectangle are allowed.
    pub fn unproject(&self, pixel: &Vector2<f64>) -> Option<Unit<Vector3<f64>>> {
        let a = (pixel.x - self.cx) / self.fx;
        let b = (pixel.y - self.cy) / self.fy;
        let theta = a.hypot(b);
        if !theta.is_finite() || theta > self.max_theta {
            return None;
        }
        // sin(θ)/θ → 1 at the centre.
        let sinc = if theta > 1e-12 {
            theta.sin() / theta
        } else {
            1.0
        };
        Some(Unit::new_unchecked(Vector3::new(
            a * sinc,
            b * sinc,
            theta.cos(),
        )))
    }
}

/// Everything perception needs to turn a pixel into a tool-frame ray: intrinsics and the pose of
/// the camera in the tool frame. Perception uses the calibrated values, which differ from the true
/// ones by the calibration error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraCalibration {
    /// Intrinsics.
    pub model: CameraModel,
    /// Pose of the camera in the tool frame.
    pub tool_from_camera: Isometry3<f64>,
}

/// The palm camera's calibration file in the config folder.
pub const CALIBRATION_FILE: &str = "cameras/palm.toml";

/// A camera calibration file (`config/cameras/palm.toml`): the intrinsics and the camera's pose
/// in the tool frame, as a calibration procedure writes them.
///
/// ```toml
/// [intrinsics]            # equidistant fisheye: (u, v) = (cx + fx·θ·cos φ, cy + fy·θ·sin φ)
/// width = 320             # pixels
/// height = 240
/// fx = 145.2              # pixels per radian
/// fy = 145.2
/// cx = 159.5              # pixels
/// cy = 119.5
/// max_theta = 1.1         # rad, half the field of view
///
/// [tool_from_camera]
/// translation = [0.05, 0.0, -0.04]      # m, tool frame
/// rotation = [1.0, 0.0, 0.0, 0.0]       # unit quaternion [w, x, y, z]
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct CalibrationFile {
    intrinsics: IntrinsicsFile,
    tool_from_camera: ExtrinsicsFile,
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct IntrinsicsFile {
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    max_theta: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExtrinsicsFile {
    translation: [f64; 3],
    rotation: [f64; 4],
}

/// How far a calibration file's rotation quaternion may be from unit length, and still be
/// taken as written (farther is an error; a written-out unit quaternion is within 1e-15).
const QUATERNION_NORM_TOLERANCE: f64 = 1e-6;

impl CameraCalibration {
    /// Reads a calibration file (see [`CameraCalibration::to_toml`] for the format); the error
    /// names the file and the key.
    pub fn from_file(file: &Path) -> Result<Self, ModelError> {
        let text = ModelError::read_to_string(file)?;
        Self::from_toml_str(file, &text)
    }

    /// Parses and checks calibration text that came from `file`.
    pub fn from_toml_str(file: &Path, text: &str) -> Result<Self, ModelError> {
        let raw: CalibrationFile = ModelError::parse_toml_str(file, text)?;
        let bad = |key: &str, message: String| Err(ModelError::invalid(file, key, message));
        let i = raw.intrinsics;
        if i.width == 0 || i.height == 0 {
            return bad(
                "intrinsics.width",
                format!("the image must have pixels, got {}×{}", i.width, i.height),
            );
        }
        ModelError::check_positive(
            file,
            &[
                ("intrinsics.fx", i.fx),
                ("intrinsics.fy", i.fy),
                ("intrinsics.max_theta", i.max_theta),
            ],
        )?;
        for (key, value, size) in [
            ("intrinsics.cx", i.cx, i.width),
            ("intrinsics.cy", i.cy, i.height),
        ] {
            if !(value.is_finite() && (0.0..=f64::from(size)).contains(&value)) {
                return bad(
                    key,
                    format!("must lie on the image (0 to {size}), got {value}"),
                );
            }
        }
        if i.max_theta > std::f64::consts::PI {
            return bad(
                "intrinsics.max_theta",
                format!("must be at most π, got {}", i.max_theta),
            );
        }
        let e = raw.tool_from_camera;
        if !e.translation.iter().all(|v| v.is_finite()) {
            return bad(
                "tool_from_camera.translation",
                format!("must be finite, got {:?}", e.translation),
            );
        }
        let [w, x, y, z] = e.rotation;
        let q = nalgebra::Quaternion::new(w, x, y, z);
        if !(q.coords.iter().all(|v| v.is_finite())
            && (q.norm() - 1.0).abs() <= QUATERNION_NORM_TOLERANCE)
        {
            return bad(
                "tool_from_camera.rotation",
                format!(
                    "must be a unit quaternion [w, x, y, z], got {:?} (norm {})",
                    e.rotation,
                    q.norm()
                ),
            );
        }
        Ok(Self {
            model: CameraModel {
                width: i.width,
                height: i.height,
                fx: i.fx,
                fy: i.fy,
                cx: i.cx,
                cy: i.cy,
                max_theta: i.max_theta,
            },
            tool_from_camera: Isometry3::from_parts(
                Translation3::new(e.translation[0], e.translation[1], e.translation[2]),
                UnitQuaternion::new_unchecked(q),
            ),
        })
    }

    /// The calibration as a file's text, every value written so that it reads back exactly.
    pub fn to_toml(&self) -> String {
        let m = &self.model;
        let t = self.tool_from_camera.translation.vector;
        let q = self.tool_from_camera.rotation.quaternion();
        format!(
            "# Palm camera calibration: intrinsics (equidistant fisheye) and the camera's pose in\n\
             # the tool frame.\n\
             [intrinsics]\n\
             width = {}\nheight = {}\nfx = {:?}\nfy = {:?}\ncx = {:?}\ncy = {:?}\nmax_theta = {:?}\n\n\
             [tool_from_camera]\n\
             translation = [{:?}, {:?}, {:?}]  # m\n\
             rotation = [{:?}, {:?}, {:?}, {:?}]  # unit quaternion [w, x, y, z]\n",
            m.width,
            m.height,
            m.fx,
            m.fy,
            m.cx,
            m.cy,
            m.max_theta,
            t.x,
            t.y,
            t.z,
            q.w,
            q.i,
            q.j,
            q.k
        )
    }

    /// The same calibration with the camera position moved by `offset` (tool frame, m): how an
    /// extrinsic calibration error is modelled.
    pub fn with_position_offset(&self, offset: Vector3<f64>) -> Self {
        let mut shifted = *self;
        shifted.tool_from_camera.translation.vector += offset;
        shifted
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> CameraModel {
        CameraConfig::default().model()
    }

    #[test]
    fn default_focal_length_spans_the_width_with_the_field_of_view() {
        let m = model();
        // A ray 90° off axis along x lands on the image's right edge.
        let edge = m
            .project_unbounded(&Vector3::new(1.0, 0.0, 0.0))
            .expect("90° is inside a 180° lens");
        assert!((edge.x - (m.cx + 160.0)).abs() < 1e-9);
        assert!((edge.y - m.cy).abs() < 1e-9);
        // The optical axis images at the principal point.
        let centre = m.project(&Vector3::new(0.0, 0.0, 2.0)).unwrap();
        assert!((centre - Vector2::new(m.cx, m.cy)).norm() < 1e-12);
    }

    #[test]
    fn projection_is_equidistant() {
        let m = model();
        for &theta in &[0.1_f64, 0.5, 1.0, 1.4] {
            let p = Vector3::new(theta.sin(), 0.0, theta.cos()) * 3.0;
            let pixel = m.project(&p).unwrap();
            assert!((pixel.x - m.cx - m.fx * theta).abs() < 1e-9, "θ = {theta}");
        }
    }

    #[test]
    fn project_then_unproject_returns_the_ray() {
        let m = model();
        let mut worst: f64 = 0.0;
        for i in -10..=10 {
            for j in -10..=10 {
                for &z in &[1.0, 0.2, -0.1] {
                    let p = Vector3::new(i as f64 * 0.1, j as f64 * 0.07, z);
                    let Some(pixel) = m.project(&p) else { continue };
                    let ray = m.unproject(&pixel).expect("a projected pixel unprojects");
                    worst = worst.max((ray.into_inner() - p.normalize()).norm());
                }
            }
        }
        assert!(worst < 1e-12, "worst ray error {worst}");
    }

    #[test]
    fn unproject_then_project_returns_the_pixel() {
        let m = model();
        for u in (0..320).step_by(17) {
            for v in (0..240).step_by(13) {
                let pixel = Vector2::new(u as f64, v as f64);
                let Some(ray) = m.unproject(&pixel) else {
                    continue;
                };
                let back = m.project(&ray).expect("ray inside the field of view");
                assert!((back - pixel).norm() < 1e-9, "pixel {pixel:?} → {back:?}");
            }
        }
    }

    #[test]
    fn rays_outside_the_field_of_view_do_not_project() {
        let m = model();
        assert!(m.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(m.project(&Vector3::new(1.0, 0.0, -0.01)).is_none());
        assert!(m.project(&Vector3::zeros()).is_none());
        assert!(m.project(&Vector3::new(f64::NAN, 0.0, 1.0)).is_none());
        // Inside the lens' field but beyond the image's top edge (the image is 4:3).
        assert!(m.project(&Vector3::new(0.0, 1.0, 0.0)).is_none());
        assert!(m.project_unbounded(&Vector3::new(0.0, 1.0, 0.0)).is_some());
        // A corner pixel is outside the 180° image circle.
        assert!(m.unproject(&Vector2::new(0.0, 0.0)).is_none());
        assert!(m.unproject(&Vector2::new(f64::NAN, 3.0)).is_none());
    }

    #[test]
    fn default_config_is_valid_and_bad_values_name_the_key() {
        let file = Path::new("scenario.toml");
        CameraConfig::default().validate(file, "camera").unwrap();
        let config = CameraConfig {
            rate_hz: 0.0,
            ..Default::default()
        };
        let message = config.validate(file, "camera").unwrap_err().to_string();
        assert!(message.contains("scenario.toml"), "{message}");
        assert!(message.contains("camera.rate_hz"), "{message}");
    }

    #[test]
    fn config_parses_from_toml_and_rejects_unknown_keys() {
        let config: CameraConfig = toml::from_str(
            "width = 160\nheight = 120\ntool_from_camera = { xyz = [0, 0, 0.1], rpy = [0, 0, 0] }",
        )
        .unwrap();
        assert_eq!(config.width, 160);
        assert_eq!(config.tool_from_camera.xyz[2], 0.1);
        assert_eq!(config.latency, CameraConfig::default().latency);
        assert!(toml::from_str::<CameraConfig>("widht = 160").is_err());
    }

    #[test]
    fn position_offset_moves_only_the_mount_translation() {
        let calibration = CameraConfig::default().calibration();
        let shifted = calibration.with_position_offset(Vector3::new(0.0, 0.005, 0.0));
        let delta = shifted.tool_from_camera.translation.vector
            - calibration.tool_from_camera.translation.vector;
        assert!((delta - Vector3::new(0.0, 0.005, 0.0)).norm() < 1e-15);
        assert_eq!(shifted.model, calibration.model);
    }

    #[test]
    fn a_calibration_file_reads_back_exactly_and_the_shipped_one_is_the_nominal_camera() {
        let nominal = CameraConfig::default().calibration();
        let shifted = nominal.with_position_offset(Vector3::new(0.0031, -0.0017, 0.0023));
        for calibration in [nominal, shifted] {
            let text = calibration.to_toml();
            let read = CameraCalibration::from_toml_str(Path::new("cal.toml"), &text).unwrap();
            assert_eq!(read, calibration, "{text}");
        }
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/cameras/palm.toml");
        assert_eq!(CameraCalibration::from_file(&shipped).unwrap(), nominal);
    }

    #[test]
    fn a_bad_calibration_file_names_the_file_and_the_key() {
        let good = CameraConfig::default().calibration().to_toml();
        let cases = [
            ("fx = ", "fx = -1.0 #", "intrinsics.fx"),
            ("cx = ", "cx = 1e9 #", "intrinsics.cx"),
            ("width = ", "width = 0 #", "intrinsics.width"),
            ("max_theta = ", "max_theta = 4.0 #", "intrinsics.max_theta"),
            (
                "rotation = ",
                "rotation = [1.0, 0.5, 0.0, 0.0] #",
                "tool_from_camera.rotation",
            ),
            (
                "translation = ",
                "translation = [0.0, nan, 0.0] #",
                "tool_from_camera.translation",
            ),
            ("fy = ", "fyy = 1.0\nfy = ", "fyy"),
        ];
        for (find, replace, key) in cases {
            assert!(good.contains(find));
            let text = good.replacen(find, replace, 1);
            let err = CameraCalibration::from_toml_str(Path::new("cal.toml"), &text)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("cal.toml") && err.contains(key),
                "{key}: {err}"
            );
        }
        let missing = CameraCalibration::from_file(Path::new("/nonexistent/cal.toml"));
        assert!(
            missing
                .unwrap_err()
                .to_string()
                .contains("/nonexistent/cal.toml")
        );
    }
}
