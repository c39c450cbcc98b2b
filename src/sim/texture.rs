//! Procedural solid textures (functions of world position), so meshes need no UVs.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// Pattern families; all but `Constant` need the `textures` effect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Pattern {
    /// One colour.
    Constant,
    /// 3D checkerboard.
    Checker,
    /// Smooth value noise (fBm).
    Noise,
    /// Parallel stripes along X.
    Stripes,
    /// Concentric rings around the Y axis, perturbed by noise.
    Wood,
    /// Noise-warped veins.
    Marble,
}

/// A texture: a pattern blending two colours at a scale.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Texture {
    /// Pattern.
    pub pattern: Pattern,
    /// First colour.
    pub color: [f32; 3],
    /// Second colour (unused by `constant`).
    #[serde(default)]
    pub color2: [f32; 3],
    /// Features per world unit.
    #[serde(default = "one")]
    pub scale: f32,
}

fn one() -> f32 {
    1.0
}

impl Texture {
    /// A constant colour.
    pub fn constant(c: [f32; 3]) -> Self {
        Texture { pattern: Pattern::Constant, color: c, color2: c, scale: 1.0 }
    }

    /// The colour at world position `p`.
    pub fn eval(&self, p: Vec3) -> Vec3 {
        let q = p * self.scale;
        let t = match self.pattern {
            Pattern::Constant => 0.0,
            Pattern::Checker => ((q.x.floor() + q.y.floor() + q.z.floor()) as i64).rem_euclid(2) as f32,
            Pattern::Noise => fbm(q),
            Pattern::Stripes => 0.5 + 0.5 * (q.x * std::f32::consts::TAU).sin(),
            Pattern::Wood => {
                let r = (q.x * q.x + q.z * q.z).sqrt() + 0.4 * fbm(q * 2.0);
                (r * 6.0).fract()
            }
            Pattern::Marble => 0.5 + 0.5 * (q.x * 3.0 + 5.0 * fbm(q)).sin(),
        };
        Vec3::from(self.color).lerp(Vec3::from(self.color2), t)
    }
}

fn hash(x: i32, y: i32, z: i32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8DA6_B343)
        ^ (y as u32).wrapping_mul(0xD816_3841)
        ^ (z as u32).wrapping_mul(0xCB1A_B31F);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h & 0xFF_FFFF) as f32 / 0x100_0000 as f32
}

/// Trilinear value noise in [0, 1].
fn value_noise(p: Vec3) -> f32 {
    let i = p.floor();
    let f = p - i;
    let s = f * f * (Vec3::splat(3.0) - 2.0 * f);
    let (x, y, z) = (i.x as i32, i.y as i32, i.z as i32);
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let c = |dx, dy, dz| hash(x + dx, y + dy, z + dz);
    lerp(
        lerp(lerp(c(0, 0, 0), c(1, 0, 0), s.x), lerp(c(0, 1, 0), c(1, 1, 0), s.x), s.y),
        lerp(lerp(c(0, 0, 1), c(1, 0, 1), s.x), lerp(c(0, 1, 1), c(1, 1, 1), s.x), s.y),
        s.z,
    )
}

/// Four octaves of value noise, in [0, 1].
fn fbm(p: Vec3) -> f32 {
    let (mut sum, mut amp, mut freq, mut norm) = (0.0, 0.5, 1.0, 0.0);
    for _ in 0..4 {
        sum += amp * value_noise(p * freq);
        norm += amp;
        amp *= 0.5;
        freq *= 2.0;
    }
    sum / norm
}
