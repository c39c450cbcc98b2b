//! Per-sample random streams: every (seed, pixel, sample) gets its own PCG32 stream, so
//! images do not depend on the thread count or tile order. With [`Sampler::Sobol`] the
//! first dimensions of each sample come from a scrambled low-discrepancy sequence instead.

/// PCG32 (O'Neill), a small fast generator with good statistics, optionally led by
/// scrambled Sobol' points.
pub struct Rng {
    state: u64,
    inc: u64,
    sobol: Option<Sobol>,
}

use crate::rng::mix;

impl Rng {
    /// The stream for one sample of one pixel.
    pub fn for_sample(seed: u64, pixel: u64, sample: u64) -> Self {
        let a = mix(seed ^ 0x9E37_79B9_7F4A_7C15);
        let b = mix(a ^ pixel.wrapping_mul(0xD6E8_FEB8_6659_FD93));
        let c = mix(b ^ sample.wrapping_mul(0xA076_1D64_78BD_642F));
        let mut r = Rng { state: 0, inc: (mix(c ^ 0x5851_F42D) << 1) | 1, sobol: None };
        r.next_u32();
        r.state = r.state.wrapping_add(c);
        r.next_u32();
        r
    }

    /// The numbers of one sample of one pixel under `sampler`. With [`Sampler::Sobol`] the
    /// pixel's samples are the points of [`SCRAMBLES`] independently scrambled sequences,
    /// interleaved: sample `s` is point `s / SCRAMBLES` of scramble `s % SCRAMBLES`
    /// ([`scramble_of`]).
    pub fn for_pixel_sample(sampler: Sampler, seed: u64, pixel: u64, sample: u32) -> Self {
        let mut r = Rng::for_sample(seed, pixel, sample as u64);
        if sampler == Sampler::Sobol {
            let scramble = scramble_of(sample) as u64;
            let pixel_seed = mix(mix(seed ^ 0x50B0_1D00 ^ scramble.wrapping_mul(0x2545_F491_4F6C_DD1D))
                ^ pixel.wrapping_mul(0xD6E8_FEB8_6659_FD93));
            r.sobol = Some(Sobol { index: sample / SCRAMBLES, seed: pixel_seed, dim: 0 });
        }
        r
    }

    /// Next 32 random bits.
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f32 {
        if let Some(s) = self.sobol.as_mut().filter(|s| s.dim < SOBOL_DIMENSIONS) {
            let d = s.dim;
            s.dim += 1;
            return s.value(d / 2, d % 2);
        }
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Two uniforms; from the Sobol' sampler, one 2D-stratified pair.
    pub fn uniform2(&mut self) -> [f32; 2] {
        if let Some(s) = self.sobol.as_mut() {
            // Start pairs on an even dimension so both components share one 2D point.
            s.dim += s.dim % 2;
            if s.dim < SOBOL_DIMENSIONS {
                let pair = s.dim / 2;
                s.dim += 2;
                return [s.value(pair, 0), s.value(pair, 1)];
            }
        }
        [self.uniform(), self.uniform()]
    }
}

/// How a pixel's samples are placed in the sample space.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Sampler {
    /// Independent uniform numbers for every sample (PCG32 streams).
    #[default]
    Random,
    /// Owen-scrambled Sobol' points, padded per dimension pair, for the first
    /// [`SOBOL_DIMENSIONS`] dimensions of a path, then independent streams (the kind of
    /// low-discrepancy sampler production renderers use: Cycles' Sobol-Burley, pbrt's
    /// padded Sobol'), in [`SCRAMBLES`] independent scrambles per pixel, interleaved: each
    /// scramble's first 2ᵏ points stratify every pair of dimensions.
    Sobol,
}

impl Sampler {
    /// The name used on the command line and in file metadata.
    pub fn name(self) -> &'static str {
        match self {
            Sampler::Random => "random",
            Sampler::Sobol => "sobol",
        }
    }
}

/// Independent scrambles of a pixel's Sobol' samples. The points of one scramble are
/// correlated by design (stratified), so their sample variance overstates the error of
/// their mean (2–10× in our scenes); the means of independent scrambles are independent,
/// and their spread is an honest estimate of it (`film::PixelStats`). Four: 3 degrees of
/// freedom per pixel, and each scramble still stratifies 2ᵏ⁻² of a pixel's 2ᵏ samples.
pub const SCRAMBLES: u32 = 4;

/// Which of a pixel's [`SCRAMBLES`] a Sobol' sample comes from.
pub fn scramble_of(sample: u32) -> u32 {
    sample % SCRAMBLES
}

/// Dimensions of a path drawn from Sobol' points before the independent streams take over:
/// the film position, the lens and the first bounces.
pub const SOBOL_DIMENSIONS: u32 = 32;

/// The Sobol' state of one sample: which point of the pixel's sequence, its scrambling
/// seed, and the next dimension to hand out.
struct Sobol {
    index: u32,
    seed: u64,
    dim: u32,
}

impl Sobol {
    /// Component `comp` (0 or 1) of dimension pair `pair`.
    fn value(&self, pair: u32, comp: u32) -> f32 {
        let pair_seed = mix(self.seed ^ (pair as u64).wrapping_mul(0x9E6C_63D0_676A_9A99));
        // Each pair gets its own shuffle of the point order (padding), so pairs are
        // decorrelated while each pair keeps its 2D stratification.
        let index = nested_uniform_scramble(self.index, pair_seed as u32);
        let x = sobol_2d(index, comp);
        let x = nested_uniform_scramble(x, (pair_seed >> 32) as u32 ^ comp.wrapping_mul(0x68E3_1DA4));
        (x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
}

/// The first two dimensions of the Sobol' sequence as 32-bit fractions: the van der Corput
/// sequence and its Pascal-matrix partner.
fn sobol_2d(index: u32, comp: u32) -> u32 {
    if comp == 0 {
        return index.reverse_bits();
    }
    let (mut x, mut v, mut i) = (0u32, 1u32 << 31, index);
    while i != 0 {
        if i & 1 != 0 {
            x ^= v;
        }
        i >>= 1;
        v ^= v >> 1;
    }
    x
}

/// An Owen scramble of a 32-bit fraction: a hash-based nested uniform permutation of its
/// bits (Laine–Karras, with Burley's constants), which keeps a net a net.
fn nested_uniform_scramble(x: u32, seed: u32) -> u32 {
    let mut v = x.reverse_bits();
    v = v.wrapping_add(seed);
    v ^= v.wrapping_mul(0x6C50_B47C);
    v ^= v.wrapping_mul(0xB82F_1E52);
    v ^= v.wrapping_mul(0xC7AF_E638);
    v ^= v.wrapping_mul(0x8D22_F6E6);
    v.reverse_bits()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first `n` points of a pixel's scramble `scramble`.
    fn points(pixel: u64, scramble: u32, n: u32) -> Vec<[f32; 2]> {
        (0..n).map(|i| Rng::for_pixel_sample(Sampler::Sobol, 7, pixel, i * SCRAMBLES + scramble).uniform2()).collect()
    }

    #[test]
    fn sobol_pairs_are_stratified_in_2d_and_1d() {
        for (pixel, scramble) in [(0, 0), (1, 3), (12345, 2)] {
            let p = points(pixel, scramble, 16);
            let mut cells = [0u32; 16];
            let (mut xs, mut ys) = ([0u32; 16], [0u32; 16]);
            for [x, y] in &p {
                cells[(x * 4.0) as usize * 4 + (y * 4.0) as usize] += 1;
                xs[(x * 16.0) as usize] += 1;
                ys[(y * 16.0) as usize] += 1;
            }
            assert!(cells.iter().all(|&c| c == 1), "pixel {pixel}: {cells:?}");
            assert!(xs.iter().chain(&ys).all(|&c| c == 1), "pixel {pixel}: {xs:?} {ys:?}");
        }
        assert_ne!(points(0, 0, 4), points(1, 0, 4), "pixels are scrambled independently");
        assert_ne!(points(0, 0, 4), points(0, 1, 4), "and so are a pixel's scrambles");
        let interleaved: Vec<u32> = (0..8).map(scramble_of).collect();
        assert_eq!(interleaved, [0, 1, 2, 3, 0, 1, 2, 3], "every 4 samples visit every scramble");
    }

    #[test]
    fn later_pairs_are_stratified_and_unbiased() {
        // Dimension pair 3 (after a lone uniform, which pads to the next pair).
        let mut sum = 0f64;
        for pixel in 0..64u64 {
            let mut xs = [0u32; 8];
            for i in 0..8 {
                let mut r = Rng::for_pixel_sample(Sampler::Sobol, 3, pixel, i * SCRAMBLES + 1);
                r.uniform2();
                r.uniform();
                r.uniform2();
                let [x, y] = r.uniform2();
                xs[(x * 8.0) as usize] += 1;
                sum += (x + y) as f64;
            }
            assert!(xs.iter().all(|&c| c == 1), "{xs:?}");
        }
        let mean = sum / (64.0 * 8.0 * 2.0);
        assert!((mean - 0.5).abs() < 0.02, "{mean}");
    }

    #[test]
    fn past_the_sobol_dimensions_samples_are_independent_streams() {
        let mut a = Rng::for_pixel_sample(Sampler::Sobol, 1, 2, 3);
        let mut b = Rng::for_sample(1, 2, 3);
        for _ in 0..SOBOL_DIMENSIONS {
            a.uniform();
        }
        assert_eq!(a.uniform(), b.uniform(), "the PCG stream is untouched by the Sobol' dimensions");
        let mut r = Rng::for_pixel_sample(Sampler::Random, 1, 2, 3);
        assert_eq!(r.uniform(), Rng::for_sample(1, 2, 3).uniform());
    }
}
