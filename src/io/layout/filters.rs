//! Per-pixel averages and 3×3 neighbourhood filters: the variance estimates.

/// Per-pixel mean over several planes.
pub(super) fn average<'a>(planes: impl Iterator<Item = &'a [f32]>, n: usize) -> Vec<f32> {
    let mut sum = vec![0f32; n];
    let mut k = 0;
    for p in planes {
        sum.iter_mut().zip(p).for_each(|(s, v)| *s += v);
        k += 1;
    }
    let inv = 1.0 / k.max(1) as f32;
    sum.iter_mut().for_each(|s| *s *= inv);
    sum
}

/// Visits the 3×3 neighbourhood of every pixel, clamped at the frame border.
fn neighbourhood3(w: usize, h: usize, mut f: impl FnMut(usize, &mut dyn Iterator<Item = usize>)) {
    for y in 0..h {
        for x in 0..w {
            let ys = y.saturating_sub(1)..=(y + 1).min(h - 1);
            let mut it = ys.flat_map(|yy| (x.saturating_sub(1)..=(x + 1).min(w - 1)).map(move |xx| yy * w + xx));
            f(y * w + x, &mut it);
        }
    }
}

/// 3×3 box filter, clamped at the border.
pub fn box3(v: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0f32; v.len()];
    neighbourhood3(w, h, |i, nb| {
        let (s, k) = nb.fold((0f64, 0u32), |(s, k), j| (s + v[j] as f64, k + 1));
        out[i] = (s / k as f64) as f32;
    });
    out
}

/// Local 3×3 sample variance, averaged over components.
pub fn spatial_variance(planes: &[Vec<f32>], w: usize, h: usize) -> Vec<f32> {
    let per_plane = planes.iter().map(|p| {
        let mut out = vec![0f32; p.len()];
        neighbourhood3(w, h, |i, nb| {
            let (mut s, mut s2, mut k) = (0f64, 0f64, 0u32);
            for j in nb {
                let v = p[j] as f64;
                s += v;
                s2 += v * v;
                k += 1;
            }
            out[i] = if k > 1 { ((s2 - s * s / k as f64) / (k - 1) as f64).max(0.0) as f32 } else { 0.0 };
        });
        out
    });
    let per_plane: Vec<Vec<f32>> = per_plane.collect();
    average(per_plane.iter().map(Vec::as_slice), w * h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spatial_variance_of_a_constant_is_zero_and_of_a_checker_is_positive() {
        let flat = vec![vec![2.0f32; 12]];
        assert!(spatial_variance(&flat, 4, 3).iter().all(|&v| v == 0.0));
        let checker = vec![(0..12).map(|i| ((i % 4 + i / 4) % 2) as f32).collect::<Vec<_>>()];
        assert!(spatial_variance(&checker, 4, 3).iter().all(|&v| v > 0.2));
    }

    #[test]
    fn box3_preserves_a_constant_and_averages_neighbours() {
        assert_eq!(box3(&[5.0; 6], 3, 2), vec![5.0; 6]);
        // 1×3 row [0, 3, 6]: centre averages all three, ends average two.
        assert_eq!(box3(&[0.0, 3.0, 6.0], 3, 1), vec![1.5, 3.0, 4.5]);
    }
}
