//! Gaussian pixel noise for the palm camera, cheap enough to add to every channel of every pixel
//! of every frame.
//!
//! Each value is `σ·z` rounded to a whole 8-bit level, `z` standard normal, drawn by inversion
//! from a 16-bit uniform `u`: the level is the lowest level plus the number of thresholds `u`
//! reaches, the thresholds being where the rounded quantile `σ·Φ⁻¹((u + ½)/65536)` steps up. So
//! the draw is the rounded Gaussian to within 2⁻¹⁶ in probability (tails beyond ±4.3σ cut).
//!
//! Drawing ~230 000 values per frame costs more than rendering the frame, so the values are drawn
//! once per camera into a pool ([`PixelNoise::pool_len`]: at least four frames' worth, at least
//! 2¹⁶ values) and each frame adds the pool's values from an offset drawn uniformly from the
//! camera's seeded stream. Within a frame the values are independent draws; two frames take
//! overlapping stretches of the pool only shifted by a random amount, so the same pixel sees
//! independent values (unless the two offsets are equal). The pool's uniforms come from a wyrand
//! generator ([`NoiseStream`]) seeded from the camera's seeded ChaCha8 stream, so everything is
//! reproducible from the trial seed.

use std::ops::Range;

use rand::{Rng, RngExt};

/// Generator steps per block of noise values.
const WORDS: usize = 4;
/// Noise values drawn per block: four 16-bit uniforms per 64-bit word.
const BLOCK: usize = 4 * WORDS;
/// Number of 16-bit uniform values.
const UNIFORM_LEVELS: u32 = 1 << 16;
/// Smallest pool, values.
const MIN_POOL: usize = 1 << 16;
/// The pool holds at least this many frames' worth of values.
const POOL_FRAMES: usize = 4;

/// Rounded Gaussian noise of a given standard deviation, in whole 8-bit levels, drawn into a pool
/// that frames read from at random offsets.
#[derive(Debug, Clone)]
pub(crate) struct PixelNoise {
    /// Level drawn when the uniform reaches no threshold.
    lowest: i16,
    /// Thresholds in ascending order, stored as `u − 32768` so that signed 16-bit comparisons
    /// order them as the uniforms.
    thresholds: Vec<i16>,
    /// The pre-drawn values; empty when there is no noise.
    pool: Vec<i16>,
    /// The same values as bytes when every one fits in one (any σ of a real camera), so that
    /// a frame reads half the memory; empty otherwise.
    narrow: Vec<i8>,
}

impl PixelNoise {
    /// Noise of standard deviation `std` (8-bit levels; none when not positive) for frames of
    /// `frame_len` values, its pool drawn from `rng` (no draw without noise).
    pub(crate) fn new<R: Rng + ?Sized>(std: f64, frame_len: usize, rng: &mut R) -> Self {
        let mut noise = Self {
            lowest: 0,
            thresholds: Vec::new(),
            pool: Vec::new(),
            narrow: Vec::new(),
        };
        if std.is_nan() || std <= 0.0 {
            return noise;
        }
        let level = |u: u32| -> i16 {
            let p = (f64::from(u) + 0.5) / f64::from(UNIFORM_LEVELS);
            (std * normal_quantile(p)).round().clamp(-255.0, 255.0) as i16
        };
        noise.lowest = level(0);
        let highest = level(UNIFORM_LEVELS - 1);
        for step in noise.lowest..highest {
            // The first uniform whose level is above `step` (the level never falls as u grows).
            let (mut below, mut above) = (0u32, UNIFORM_LEVELS - 1);
            while above - below > 1 {
                let mid = (below + above) / 2;
                if level(mid) > step {
                    above = mid;
                } else {
                    below = mid;
                }
            }
            noise.thresholds.push((above as i32 - 32768) as i16);
        }
        let mut stream = NoiseStream::seeded(rng);
        let len = Self::pool_len(frame_len).div_ceil(BLOCK) * BLOCK;
        let levels = noise.levels();
        noise.pool = Vec::with_capacity(len);
        while noise.pool.len() < len {
            let block = Self::block(&levels, &mut stream);
            noise.pool.extend_from_slice(&block);
        }
        if let Ok(narrow) = noise.pool.iter().map(|&v| i8::try_from(v)).collect() {
            noise.narrow = narrow;
        }
        noise
    }

    /// The noise level of every 16-bit uniform, indexed by the uniform: the lowest level plus
    /// the number of thresholds the uniform reaches (one pass over the sorted thresholds, not a
    /// search per drawn value).
    fn levels(&self) -> Vec<i16> {
        let mut levels = Vec::with_capacity(UNIFORM_LEVELS as usize);
        let (mut level, mut passed) = (self.lowest, 0);
        for u in 0..UNIFORM_LEVELS {
            let shifted = (u as i32 - 32768) as i16;
            while self.thresholds.get(passed).is_some_and(|&t| t <= shifted) {
                passed += 1;
                level += 1;
            }
            levels.push(level);
        }
        levels
    }

    /// Pool size for frames of `frame_len` values.
    pub(crate) fn pool_len(frame_len: usize) -> usize {
        (POOL_FRAMES * frame_len).max(MIN_POOL)
    }

    /// The noise values of one frame of `frame_len` values (at most the pool's frame length), at
    /// an offset drawn from `rng`; `None` (and no draw) without noise.
    #[cfg(test)]
    pub(crate) fn frame<R: Rng + ?Sized>(&self, frame_len: usize, rng: &mut R) -> Option<&[i16]> {
        let offset = self.offset(frame_len, rng)?;
        Some(&self.pool[offset..offset + frame_len])
    }

    /// Where one frame of `frame_len` values starts in the pool, drawn from `rng`; `None` (and
    /// no draw) without noise.
    #[inline(always)]
    fn offset<R: Rng + ?Sized>(&self, frame_len: usize, rng: &mut R) -> Option<usize> {
        (!self.pool.is_empty()).then(|| rng.random_range(0..=self.pool.len() - frame_len))
    }

    /// Adds one frame's noise (the values [`PixelNoise::frame`] draws, in order) to the byte
    /// ranges `runs` of `image`, `frame_len` bytes in all; nothing (and no draw) without noise.
    /// Always inlined, so it is compiled for the target features of its caller.
    #[inline(always)]
    pub(crate) fn add_frame<R: Rng + ?Sized>(
        &self,
        image: &mut [u8],
        runs: &[Range<usize>],
        frame_len: usize,
        rng: &mut R,
    ) {
        let Some(offset) = self.offset(frame_len, rng) else {
            return;
        };
        let frame = offset..offset + frame_len;
        if self.narrow.is_empty() {
            add_runs(image, runs, &self.pool[frame]);
        } else {
            add_runs(image, runs, &self.narrow[frame]);
        }
    }

    /// The noise level of the uniform `u` (< 65536).
    #[cfg(test)]
    fn level(&self, u: u32) -> i16 {
        let shifted = (u as i32 - 32768) as i16;
        self.lowest + self.thresholds.iter().filter(|&&t| shifted >= t).count() as i16
    }

    /// The next [`BLOCK`] noise values of `stream`, `levels` the level of every uniform
    /// ([`PixelNoise::levels`]).
    fn block(levels: &[i16], stream: &mut NoiseStream) -> [i16; BLOCK] {
        let words = stream.next_words();
        // The k-th 16-bit piece of the words is the k-th uniform.
        std::array::from_fn(|k| levels[usize::from((words[k / 4] >> (16 * (k % 4))) as u16)])
    }
}

/// Adds `noise` to the byte ranges `runs` of `image`, in order.
#[inline(always)]
fn add_runs<T: Copy + Into<i16>>(image: &mut [u8], runs: &[Range<usize>], mut noise: &[T]) {
    for run in runs {
        let (values, rest) = noise.split_at(run.len());
        add_noise(&mut image[run.clone()], values);
        noise = rest;
    }
}

/// Adds `noise` to `bytes` value by value, clamped to 0..=255 (compiles to SIMD).
#[inline(always)]
fn add_noise<T: Copy + Into<i16>>(bytes: &mut [u8], noise: &[T]) {
    for (byte, &value) in bytes.iter_mut().zip(noise) {
        *byte = (i16::from(*byte) + value.into()).clamp(0, 255) as u8;
    }
}

/// The wyrand generator (Wang Yi): a 64-bit Weyl sequence mixed by one 64×64→128-bit multiply,
/// four 16-bit uniforms per step. Fast and statistically sound (not cryptographic).
#[derive(Debug, Clone, Copy)]
pub(crate) struct NoiseStream {
    state: u64,
}

impl NoiseStream {
    /// A generator seeded with one word of `rng`.
    fn seeded<R: Rng + ?Sized>(rng: &mut R) -> Self {
        Self {
            state: rng.next_u64(),
        }
    }

    /// The next 64 random bits.
    #[inline(always)]
    fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0xa076_1d64_78bd_642f);
        let product = u128::from(self.state) * u128::from(self.state ^ 0xe703_7ed1_a0b4_28db);
        (product >> 64) as u64 ^ product as u64
    }

    /// [`WORDS`] steps of the generator.
    #[inline(always)]
    fn next_words(&mut self) -> [u64; WORDS] {
        [(); WORDS].map(|_| self.next_u64())
    }
}

/// The standard normal quantile (inverse CDF) at `p` in (0, 1), by Acklam's rational
/// approximation (relative error below 1.2·10⁻⁹).
fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    const LOW: f64 = 0.02425;
    if p < LOW {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - LOW {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn normal_quantile_matches_known_values() {
        assert!(normal_quantile(0.5).abs() < 1e-12);
        assert!((normal_quantile(0.975) - 1.959_963_984_540_054).abs() < 1e-8);
        assert!((normal_quantile(0.001) + 3.090_232_306_167_813).abs() < 1e-7);
    }

    fn noise(std: f64, seed: u64) -> PixelNoise {
        PixelNoise::new(std, 1000, &mut ChaCha8Rng::seed_from_u64(seed))
    }

    /// Noise with a pool of about a million values, so that sampling errors are small.
    fn big_noise(std: f64, seed: u64) -> PixelNoise {
        PixelNoise::new(std, 250_000, &mut ChaCha8Rng::seed_from_u64(seed))
    }

    #[test]
    fn thresholds_give_the_rounded_quantile_of_every_uniform() {
        for std in [0.4, 1.0, 3.0, 12.5] {
            let noise = noise(std, 1);
            for u in 0..UNIFORM_LEVELS {
                let p = (f64::from(u) + 0.5) / f64::from(UNIFORM_LEVELS);
                let expected = (std * normal_quantile(p)).round() as i16;
                assert_eq!(noise.level(u), expected, "σ {std}, u {u}");
            }
        }
    }

    #[test]
    fn the_table_of_levels_counts_the_thresholds_each_uniform_reaches() {
        for std in [0.4, 1.0, 3.0] {
            let noise = noise(std, 2);
            let levels = noise.levels();
            assert_eq!(levels.len(), UNIFORM_LEVELS as usize);
            for u in 0..UNIFORM_LEVELS {
                assert_eq!(levels[u as usize], noise.level(u), "σ {std}, u {u}");
            }
        }
    }

    /// Mean and standard deviation of the pool.
    fn moments(pool: &[i16]) -> (f64, f64) {
        let n = pool.len() as f64;
        let mean = pool.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let var = pool
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n;
        (mean, var.sqrt())
    }

    #[test]
    fn pool_has_the_configured_spread_and_depends_on_the_seed() {
        for std in [1.0, 3.0] {
            let noise = noise(std, 1);
            assert!(noise.pool.len() >= MIN_POOL);
            // Many more values than the moments need, so their sampling error is small.
            assert!(noise.pool.len() >= 60_000);
            let (mean, spread) = moments(&noise.pool);
            assert!(mean.abs() < 0.01, "σ {std}: mean {mean}");
            // Rounding to whole levels adds 1/12 to the variance.
            let expected = (std * std + 1.0 / 12.0).sqrt();
            assert!(
                (spread - expected).abs() < 0.01 * expected,
                "σ {std}: {spread}"
            );
        }
        assert_eq!(noise(1.0, 5).pool, noise(1.0, 5).pool);
        assert_ne!(noise(1.0, 5).pool, noise(1.0, 6).pool);
    }

    #[test]
    fn neighbouring_values_are_uncorrelated() {
        let noise = big_noise(2.0, 3);
        let (mean, spread) = moments(&noise.pool);
        // Five times the sampling error of a correlation.
        let bound = 5.0 / (noise.pool.len() as f64).sqrt();
        let centred: Vec<f64> = noise.pool.iter().map(|&v| f64::from(v) - mean).collect();
        for lag in [1, 3, 4, 16, 64] {
            let c = centred
                .iter()
                .zip(&centred[lag..])
                .map(|(a, b)| a * b)
                .sum::<f64>()
                / (centred.len() - lag) as f64
                / (spread * spread);
            assert!(c.abs() < bound, "lag {lag}: correlation {c}");
        }
    }

    #[test]
    fn frames_read_the_pool_at_random_offsets() {
        let noise = noise(1.0, 4);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let frames: Vec<Vec<i16>> = (0..8)
            .map(|_| noise.frame(1000, &mut rng).expect("noise on").to_vec())
            .collect();
        for (i, a) in frames.iter().enumerate() {
            assert_eq!(a.len(), 1000);
            for b in &frames[i + 1..] {
                assert_ne!(a, b);
            }
        }
    }

    #[test]
    fn no_noise_draws_nothing_and_changes_nothing() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let noise = PixelNoise::new(0.0, 1000, &mut rng);
        assert!(noise.frame(1000, &mut rng).is_none());
        let mut fresh = ChaCha8Rng::seed_from_u64(1);
        assert_eq!(rng.next_u64(), fresh.next_u64(), "no draw");
    }

    #[test]
    fn a_frame_adds_the_values_it_draws_whether_the_pool_is_narrow_or_not() {
        for (std, narrow) in [(1.0, true), (60.0, false)] {
            let noise = noise(std, 8);
            assert_eq!(!noise.narrow.is_empty(), narrow, "σ {std}");
            let runs = [3..40, 52..300, 310..1000];
            let image: Vec<u8> = (0..1200).map(|i| (i * 37 % 256) as u8).collect();
            let (mut drawn, mut expected) = (image.clone(), image.clone());
            let mut rng = ChaCha8Rng::seed_from_u64(5);
            noise.add_frame(&mut drawn, &runs, 985, &mut rng);
            let mut rng = ChaCha8Rng::seed_from_u64(5);
            let values = noise.frame(985, &mut rng).expect("noise on");
            add_runs(&mut expected, &runs, values);
            assert_eq!(drawn, expected, "σ {std}");
            assert_ne!(drawn, image);
        }
    }

    #[test]
    fn values_clamp_to_the_byte_range() {
        let mut bytes = [0, 3, 250, 255, 128];
        add_noise(&mut bytes, &[-5i16, -5, 9, 1, -2]);
        assert_eq!(bytes, [0, 0, 255, 255, 126]);
    }
}
