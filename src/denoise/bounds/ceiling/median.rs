//! Medians of many pixels' 7×7 windows at once: each window's values are sorted by
//! a fixed network of compare-exchanges (Batcher's odd–even merge sort), the same for
//! every window, so that [`LANES`] pixels go through it side by side, one vector
//! instruction per exchange. A selection per pixel (`select_nth_unstable`) branches on
//! its data and cost the ceiling more than its similarity tests.

use super::CEILING_RADIUS;
use crate::kernel::avx2_or_compiled;

/// Values in a window.
pub(super) const WINDOW: usize = (2 * CEILING_RADIUS + 1) * (2 * CEILING_RADIUS + 1);

/// Pixels sorted side by side: 32-bit keys, one AVX2 register.
pub(in crate::denoise::bounds) const LANES: usize = 8;

/// Compare-exchanges a network may hold.
const MOST: usize = 1024;

/// Batcher's odd–even merge sort of `n` values as compare-exchanges `(i, j)`, `i < j`
/// (after one, `i` holds the smaller), and how many: the network of the next power of two
/// without the exchanges that reach past `n`, which would only ever leave a padding +∞
/// where it is.
const fn batcher(n: usize) -> ([(u8, u8); MOST], usize) {
    let mut pairs = [(0u8, 0u8); MOST];
    let mut len = 0;
    let mut p = 1;
    while p < n {
        let mut k = p;
        while k >= 1 {
            let mut j = k % p;
            while j + k < n {
                let mut i = 0;
                while i < k && i + j + k < n {
                    if (i + j) / (2 * p) == (i + j + k) / (2 * p) {
                        assert!(len < MOST && i + j + k < 256, "the network fits its table");
                        pairs[len] = ((i + j) as u8, (i + j + k) as u8);
                        len += 1;
                    }
                    i += 1;
                }
                j += 2 * k;
            }
            k /= 2;
        }
        p *= 2;
    }
    (pairs, len)
}

/// The network that sorts a window.
const NETWORK: ([(u8, u8); MOST], usize) = batcher(WINDOW);

/// `v`'s key in [`f32::total_cmp`]'s order, as a signed integer: the same flip of the
/// magnitude bits of negative values.
#[inline(always)]
fn key(v: f32) -> i32 {
    let b = v.to_bits() as i32;
    b ^ ((((b >> 31) as u32) >> 1) as i32)
}

/// The value of a [`key`] (the flip undoes itself).
#[inline(always)]
fn value(k: i32) -> f32 {
    f32::from_bits((k ^ ((((k >> 31) as u32) >> 1) as i32)) as u32)
}

/// Compare-exchange `K` of [`NETWORK`] on each lane of `keys` (none past its end). A
/// const parameter, so that every index is a constant once inlined and the compiler keeps
/// the keys in registers across exchanges instead of in memory.
#[inline(always)]
fn exchange<const K: usize>(keys: &mut [[i32; LANES]; WINDOW]) {
    let (pairs, len) = &NETWORK;
    if K < *len {
        let (i, j) = (usize::from(pairs[K].0), usize::from(pairs[K].1));
        let (a, b) = (keys[i], keys[j]);
        keys[i] = std::array::from_fn(|l| a[l].min(b[l]));
        keys[j] = std::array::from_fn(|l| a[l].max(b[l]));
    }
}

/// Every exchange of [`NETWORK`] in order: `exchange::<K>` for K below 64 × 8.
macro_rules! exchanges {
    ($keys:ident) => {
        exchanges!(@64 $keys; 0);
        exchanges!(@64 $keys; 64);
        exchanges!(@64 $keys; 128);
        exchanges!(@64 $keys; 192);
        exchanges!(@64 $keys; 256);
        exchanges!(@64 $keys; 320);
        exchanges!(@64 $keys; 384);
        exchanges!(@64 $keys; 448);
    };
    (@64 $keys:ident; $b:expr) => {
        exchanges!(@16 $keys; $b);
        exchanges!(@16 $keys; $b + 16);
        exchanges!(@16 $keys; $b + 32);
        exchanges!(@16 $keys; $b + 48);
    };
    (@16 $keys:ident; $b:expr) => {
        exchanges!(@4 $keys; $b);
        exchanges!(@4 $keys; $b + 4);
        exchanges!(@4 $keys; $b + 8);
        exchanges!(@4 $keys; $b + 12);
    };
    (@4 $keys:ident; $b:expr) => {
        exchange::<{ $b }>($keys);
        exchange::<{ $b + 1 }>($keys);
        exchange::<{ $b + 2 }>($keys);
        exchange::<{ $b + 3 }>($keys);
    };
}
const _: () = assert!(NETWORK.1 <= 512, "exchanges! reaches every exchange");

/// `keys` sorted lane by lane by [`NETWORK`].
#[inline(always)]
fn sort(keys: &mut [[i32; LANES]; WINDOW]) {
    exchanges!(keys);
}

avx2_or_compiled!(
    /// [`medians`], chosen once per bound.
    pub(in crate::denoise::bounds) type Medians;
    pub(in crate::denoise::bounds) fn medians_avx2_or_not() = medians(
        chosen: &[f32],
        w: usize,
        xs: &[usize],
        upper: bool,
        out: &mut [f32],
    )
);

/// For each pixel `x` of `xs` (at most [`LANES`]), the upper (or, where not `upper`,
/// the lower) median in [`f32::total_cmp`]'s order of the numbers among its window's
/// values `chosen[o · w + x]` (`o` < [`WINDOW`]; NaN: not counted), into `out` at the
/// same place: what `select_nth_unstable_by(n / 2, f32::total_cmp)` (lower:
/// `(n − 1) / 2`) of the `n` numbers gives, bit for bit; NaN where there are none.
#[inline(always)]
pub(in crate::denoise::bounds) fn medians(chosen: &[f32], w: usize, xs: &[usize], upper: bool, out: &mut [f32]) {
    assert!(xs.len() <= LANES && out.len() >= xs.len(), "{} pixels at a time", LANES);
    // NaNs become the largest key, after every number's.
    let mut keys = [[i32::MAX; LANES]; WINDOW];
    let mut numbers = [0u32; LANES];
    if xs.len() == LANES && xs[LANES - 1] == xs[0] + LANES - 1 {
        // A run of pixels (most of the ceiling's): each offset's values are one vector.
        for (o, k) in keys.iter_mut().enumerate() {
            let v = &chosen[o * w + xs[0]..][..LANES];
            for lane in 0..LANES {
                let number = !v[lane].is_nan();
                k[lane] = if number { key(v[lane]) } else { i32::MAX };
                numbers[lane] += u32::from(number);
            }
        }
    } else {
        for (lane, &x) in xs.iter().enumerate() {
            for (o, k) in keys.iter_mut().enumerate() {
                let v = chosen[o * w + x];
                if !v.is_nan() {
                    k[lane] = key(v);
                    numbers[lane] += 1;
                }
            }
        }
    }
    sort(&mut keys);
    for (lane, o) in out[..xs.len()].iter_mut().enumerate() {
        let n = numbers[lane] as usize;
        let at = if upper { n / 2 } else { n.saturating_sub(1) / 2 };
        *o = if n == 0 { f32::NAN } else { value(keys[at][lane]) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference: a selection per pixel, as the bounds' pixel-by-pixel medians.
    fn selected(chosen: &[f32], w: usize, x: usize, upper: bool) -> f32 {
        let mut v: Vec<f32> = (0..WINDOW).map(|o| chosen[o * w + x]).filter(|v| !v.is_nan()).collect();
        if v.is_empty() {
            return f32::NAN;
        }
        let at = if upper { v.len() / 2 } else { (v.len() - 1) / 2 };
        *v.select_nth_unstable_by(at, f32::total_cmp).1
    }

    #[test]
    fn the_network_sorts_every_sequence_of_zeros_and_ones() {
        // The 0–1 principle: a comparator network that sorts every 0/1 input sorts every
        // input. 2^49 inputs are too many; every input with one run of ones, and random
        // ones, are not.
        // The network as the medians run it (each input in every lane).
        let sorts = |v: [u8; WINDOW]| {
            let mut keys: [[i32; LANES]; WINDOW] = std::array::from_fn(|i| [i32::from(v[i]); LANES]);
            sort(&mut keys);
            keys.windows(2).all(|p| p[0][0] <= p[1][0])
        };
        for a in 0..WINDOW {
            for b in a..=WINDOW {
                assert!(sorts(std::array::from_fn(|i| u8::from((a..b).contains(&i)))), "ones at {a}..{b}");
            }
        }
        let mut rng = crate::rng::SplitMix64(11);
        for _ in 0..20_000 {
            let bits = rng.next_u64();
            assert!(sorts(std::array::from_fn(|i| (bits >> i & 1) as u8)), "{bits:#x}");
        }
    }

    #[test]
    fn medians_equal_a_selection_bit_for_bit() {
        // Windows of every fill, with NaNs of both signs, zeros of both signs, infinities,
        // ties and subnormals; more pixels than lanes, and a short last group.
        let w = 3 * LANES + 5;
        let mut rng = crate::rng::SplitMix64(3);
        let specials = [0.0, -0.0, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, -f32::NAN, 1e-42, 1.0];
        for trial in 0..200 {
            let chosen: Vec<f32> = (0..WINDOW * w)
                .map(|i| {
                    let u = rng.uniform_f32();
                    match (trial % 4, i % 7) {
                        (0, _) if u < 0.5 => f32::NAN,
                        (1, _) if u < 0.95 => f32::NAN,
                        (2, 3) => specials[(u * 8.0) as usize % 8],
                        (3, _) => (u * 4.0).floor(),
                        _ => u * 10.0 - 2.0,
                    }
                })
                .collect();
            // Runs of pixels, as the ceiling's dense ones come, or scattered ones, as the
            // specular bound's noisy ones.
            let xs: Vec<usize> = if trial / 4 % 2 == 0 { (0..w).collect() } else { (0..w).rev().step_by(3).collect() };
            for (pick, path) in [medians_avx2_or_not(), medians as Medians].into_iter().zip([0, 1]) {
                for (xs, upper) in xs.chunks(LANES).flat_map(|xs| [(xs, true), (xs, false)]) {
                    let mut out = [0f32; LANES];
                    pick(&chosen, w, xs, upper, &mut out);
                    for (&x, m) in xs.iter().zip(out) {
                        let want = selected(&chosen, w, x, upper);
                        assert_eq!(m.to_bits(), want.to_bits(), "trial {trial}, pixel {x}, path {path}, upper {upper}");
                    }
                }
            }
        }
    }
}
