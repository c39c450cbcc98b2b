//! Per-sample random streams: every (seed, pixel, sample) gets its own PCG32 stream, so
//! images do not depend on the thread count or tile order.

/// PCG32 (O'Neill), a small fast generator with good statistics.
pub struct Rng {
    state: u64,
    inc: u64,
}

use crate::rng::mix;

impl Rng {
    /// The stream for one sample of one pixel.
    pub fn for_sample(seed: u64, pixel: u64, sample: u64) -> Self {
        let a = mix(seed ^ 0x9E37_79B9_7F4A_7C15);
        let b = mix(a ^ pixel.wrapping_mul(0xD6E8_FEB8_6659_FD93));
        let c = mix(b ^ sample.wrapping_mul(0xA076_1D64_78BD_642F));
        let mut r = Rng { state: 0, inc: (mix(c ^ 0x5851_F42D) << 1) | 1 };
        r.next_u32();
        r.state = r.state.wrapping_add(c);
        r.next_u32();
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
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Two uniforms.
    pub fn uniform2(&mut self) -> [f32; 2] {
        [self.uniform(), self.uniform()]
    }
}
