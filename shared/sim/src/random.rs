//! Seeded random draws for the simulated world.
//!
//! Every random number in a trial comes from a [`SimRng`] seeded with the trial seed. Each part of
//! the world draws from its own [`Stream`], so that adding a draw in one part (say the camera)
//! does not change the draws of another (say the object motion). Uniform and normal variates are
//! computed here from raw 64-bit words, so the sequence depends only on ChaCha8 and this code.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The independent random streams of one trial.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    /// Per-trial constants: velocity gain errors, odometry errors, initial object yaw and heading.
    TrialConstants = 0,
    /// Per-step base velocity noise.
    BaseNoise = 1,
    /// Per-step arm joint velocity noise.
    ArmNoise = 2,
    /// Random smooth paths of moving objects.
    ObjectMotion = 3,
    /// Camera pixel noise and calibration error (for the renderer).
    Camera = 4,
    /// A generated mission layout ([`crate::generated`]).
    Layout = 5,
}

/// A seeded random number generator for one stream of one trial.
#[derive(Debug, Clone)]
pub struct SimRng {
    rng: ChaCha8Rng,
    spare_normal: Option<f64>,
}

impl SimRng {
    /// The generator of `stream` for the trial with `seed`.
    pub fn new(seed: u64, stream: Stream) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream as u64);
        Self {
            rng,
            spare_normal: None,
        }
    }

    /// A uniform variate in [0, 1) with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A uniform variate in [low, high).
    pub fn uniform_in(&mut self, low: f64, high: f64) -> f64 {
        low + (high - low) * self.uniform()
    }

    /// A standard normal variate (Box–Muller; the second value of each pair is kept for the next call).
    pub fn standard_normal(&mut self) -> f64 {
        if let Some(z) = self.spare_normal.take() {
            return z;
        }
        // 1 − u lies in (0, 1], so the logarithm is finite.
        let radius = (-2.0 * (1.0 - self.uniform()).ln()).sqrt();
        let angle = std::f64::consts::TAU * self.uniform();
        self.spare_normal = Some(radius * angle.sin());
        radius * angle.cos()
    }

    /// A normal variate with mean 0 and standard deviation `std` (0 when `std` is 0).
    pub fn normal(&mut self, std: f64) -> f64 {
        if std == 0.0 {
            return 0.0;
        }
        std * self.standard_normal()
    }

    /// A normal variate with standard deviation `std`, truncated to ±`limit` standard deviations
    /// by clamping. Used for per-trial error factors, so that no trial draws an absurd error.
    pub fn clamped_normal(&mut self, std: f64, limit: f64) -> f64 {
        self.normal(std).clamp(-limit * std, limit * std)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_and_stream_repeat_and_streams_differ() {
        let mut a = SimRng::new(7, Stream::BaseNoise);
        let mut b = SimRng::new(7, Stream::BaseNoise);
        let mut c = SimRng::new(7, Stream::ArmNoise);
        let xs: Vec<f64> = (0..16).map(|_| a.standard_normal()).collect();
        let ys: Vec<f64> = (0..16).map(|_| b.standard_normal()).collect();
        let zs: Vec<f64> = (0..16).map(|_| c.standard_normal()).collect();
        assert_eq!(xs, ys);
        assert_ne!(xs, zs);
    }

    #[test]
    fn normal_has_the_requested_moments() {
        let mut rng = SimRng::new(1, Stream::TrialConstants);
        let n = 20_000;
        let draws: Vec<f64> = (0..n).map(|_| rng.normal(2.0)).collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(mean.abs() < 0.05, "mean {mean}");
        assert!((var.sqrt() - 2.0).abs() < 0.05, "std {}", var.sqrt());
    }

    #[test]
    fn uniform_stays_in_range() {
        let mut rng = SimRng::new(3, Stream::ObjectMotion);
        for _ in 0..10_000 {
            let u = rng.uniform_in(-0.5, 0.25);
            assert!((-0.5..0.25).contains(&u));
        }
    }
}
