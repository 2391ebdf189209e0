//! Trial metrics of the paper (section IV): task time, success rate, mean transports per hour,
//! and end-effector acceleration.

use nalgebra::Vector3;
use serde::Deserialize;

/// How end-effector acceleration is measured.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AccelerationFilterConfig {
    /// Cut-off frequency of the second-order Butterworth low-pass filter applied to the sampled
    /// world-frame EE position before differentiating, Hz. 5 Hz keeps the motion (a grasp lasts
    /// seconds) and removes the sample-to-sample jitter that double differencing amplifies.
    pub cutoff_hz: f64,
}

impl Default for AccelerationFilterConfig {
    fn default() -> Self {
        Self { cutoff_hz: 5.0 }
    }
}

/// A second-order Butterworth low-pass filter (bilinear transform), one per axis.
#[derive(Debug, Clone)]
struct Butterworth2 {
    b: [f64; 3],
    a: [f64; 2],
    x: [Vector3<f64>; 2],
    y: [Vector3<f64>; 2],
    primed: bool,
}

impl Butterworth2 {
    fn new(cutoff_hz: f64, sample_hz: f64) -> Self {
        let k = (std::f64::consts::PI * cutoff_hz / sample_hz).tan();
        let q = std::f64::consts::FRAC_1_SQRT_2;
        let norm = 1.0 / (1.0 + k / q + k * k);
        let b0 = k * k * norm;
        Self {
            b: [b0, 2.0 * b0, b0],
            a: [2.0 * (k * k - 1.0) * norm, (1.0 - k / q + k * k) * norm],
            x: [Vector3::zeros(); 2],
            y: [Vector3::zeros(); 2],
            primed: false,
        }
    }

    fn filter(&mut self, input: Vector3<f64>) -> Vector3<f64> {
        if !self.primed {
            // Start at rest at the first sample, so the filter adds no start-up transient.
            self.x = [input; 2];
            self.y = [input; 2];
            self.primed = true;
        }
        let out = self.b[0] * input + self.b[1] * self.x[0] + self.b[2] * self.x[1]
            - self.a[0] * self.y[0]
            - self.a[1] * self.y[1];
        self.x = [input, self.x[0]];
        self.y = [out, self.y[0]];
        out
    }
}

/// Mean and maximum EE acceleration magnitude from positions sampled at a fixed rate.
///
/// The positions go through [`AccelerationFilterConfig`]'s low-pass filter, then the acceleration
/// is the second central difference of the filtered positions.
#[derive(Debug, Clone)]
pub struct AccelerationMeter {
    dt: f64,
    filter: Butterworth2,
    history: [Vector3<f64>; 3],
    samples: usize,
    sum: f64,
    max: f64,
    count: usize,
    description: String,
}

impl AccelerationMeter {
    /// A meter for positions sampled every `dt` seconds.
    pub fn new(config: &AccelerationFilterConfig, dt: f64) -> Self {
        Self {
            dt,
            filter: Butterworth2::new(config.cutoff_hz, 1.0 / dt),
            history: [Vector3::zeros(); 3],
            samples: 0,
            sum: 0.0,
            max: 0.0,
            count: 0,
            description: format!(
                "2nd-order Butterworth low-pass at {} Hz on EE position sampled at {:.0} Hz, then second central difference",
                config.cutoff_hz,
                1.0 / dt
            ),
        }
    }

    /// Adds one EE position sample (world frame, m).
    pub fn push(&mut self, position: Vector3<f64>) {
        let filtered = self.filter.filter(position);
        self.history = [self.history[1], self.history[2], filtered];
        self.samples += 1;
        if self.samples >= 3 {
            let a =
                (self.history[2] - 2.0 * self.history[1] + self.history[0]) / (self.dt * self.dt);
            let magnitude = a.norm();
            self.sum += magnitude;
            self.max = self.max.max(magnitude);
            self.count += 1;
        }
    }

    /// Mean |a| so far, m/s².
    pub fn mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum / self.count as f64
        }
    }

    /// Maximum |a| so far, m/s².
    pub fn max(&self) -> f64 {
        self.max
    }

    /// A sentence stating the filter, for reports.
    pub fn description(&self) -> &str {
        &self.description
    }
}

/// Mean transports per hour: `3600 / t × sr`, where `t` is the mean task time of the successful
/// trials and `sr` the success rate. Zero when nothing succeeded.
pub fn mtph(successful_task_times: &[f64], trials: usize) -> f64 {
    if successful_task_times.is_empty() || trials == 0 {
        return 0.0;
    }
    let mean = successful_task_times.iter().sum::<f64>() / successful_task_times.len() as f64;
    let success_rate = successful_task_times.len() as f64 / trials as f64;
    3600.0 / mean * success_rate
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_velocity_has_no_acceleration() {
        let mut meter = AccelerationMeter::new(&AccelerationFilterConfig::default(), 0.005);
        for k in 0..2000 {
            meter.push(Vector3::new(0.3 * k as f64 * 0.005, 0.0, 0.5));
        }
        // The filter starts at rest at the first sample, so only its start-up shows.
        assert!(meter.mean() < 0.05, "mean {}", meter.mean());
    }

    #[test]
    fn sinusoid_acceleration_is_measured() {
        // x = A(1 − cos ωt) starts at rest, like a robot; |a| = Aω²|cos ωt| peaks at Aω² and
        // averages 2Aω²/π. At 0.5 Hz the 5 Hz filter passes it.
        let (amp, w, dt) = (0.1, std::f64::consts::TAU * 0.5, 0.005);
        let mut meter = AccelerationMeter::new(&AccelerationFilterConfig::default(), dt);
        for k in 0..4000 {
            let t = k as f64 * dt;
            meter.push(Vector3::new(amp * (1.0 - (w * t).cos()), 0.0, 0.0));
        }
        let peak = amp * w * w;
        assert!(
            (meter.max() - peak).abs() < 0.05 * peak,
            "max {} vs {peak}",
            meter.max()
        );
        let mean = 2.0 / std::f64::consts::PI * peak;
        assert!(
            (meter.mean() - mean).abs() < 0.05 * mean,
            "mean {} vs {mean}",
            meter.mean()
        );
    }

    #[test]
    fn mtph_counts_only_successes() {
        assert!((mtph(&[12.0, 12.0], 2) - 300.0).abs() < 1e-9);
        assert!((mtph(&[12.0], 2) - 150.0).abs() < 1e-9);
        assert_eq!(mtph(&[], 10), 0.0);
    }
}
