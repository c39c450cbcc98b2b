//! Splitting a frame into tiles whose working memory fits a budget. Halos are not stored
//! here: `features` extracts each tile's input with its halo (reflected at the frame
//! border), so a tile's result equals the same region of the untiled result.

use crate::model::Architecture;

/// A rectangle of output pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tile {
    /// Left.
    pub x: usize,
    /// Top.
    pub y: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
}

/// Tiles of at most `size`×`size` covering a `width`×`height` frame, row by row.
pub fn plan(width: usize, height: usize, size: usize) -> Vec<Tile> {
    let size = size.max(1);
    (0..height.div_ceil(size))
        .flat_map(|ty| {
            (0..width.div_ceil(size)).map(move |tx| {
                let (x, y) = (tx * size, ty * size);
                Tile { x, y, w: size.min(width - x), h: size.min(height - y) }
            })
        })
        .collect()
}

/// Estimated peak bytes to evaluate one branch on a `t`×`t` tile: the input with its halo,
/// the convolution's unfolded input (im2col), two activations, the logits and the noisy
/// colour region.
pub fn tile_bytes(arch: &Architecture, t: usize) -> usize {
    let p = (t + 2 * arch.feature_radius()).pow(2);
    if arch.design == crate::model::Design::MultiScale {
        return p * crate::kernel::pyramid::bytes_per_pixel(arch);
    }
    let widest = arch.channels.max(crate::features::INPUT_CHANNELS);
    let im2col = widest * arch.conv_size * arch.conv_size * p;
    let logits = arch.outputs() * t * t;
    let noisy = 3 * (t + 2 * arch.kernel_radius()).pow(2);
    4 * (crate::features::INPUT_CHANNELS * p + im2col + 2 * widest * p + 2 * logits + noisy)
}

/// The largest tile side (a multiple of 16, at least 16, at most the frame's larger side)
/// whose working memory fits `budget` bytes.
pub fn size_for_budget(arch: &Architecture, budget: usize, width: usize, height: usize) -> usize {
    let cap = width.max(height).max(16).next_multiple_of(16);
    let mut t = 16;
    while t + 16 <= cap && tile_bytes(arch, t + 16) <= budget {
        t += 16;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Kind;

    #[test]
    fn tiles_cover_the_frame_exactly_once() {
        for (w, h, s) in [(1, 1, 16), (37, 5, 16), (64, 64, 32), (100, 33, 7)] {
            let mut hits = vec![0u8; w * h];
            for t in plan(w, h, s) {
                for y in t.y..t.y + t.h {
                    for x in t.x..t.x + t.w {
                        hits[y * w + x] += 1;
                    }
                }
            }
            assert!(hits.iter().all(|&c| c == 1), "{w}x{h} in {s}");
        }
    }

    #[test]
    fn budgets_pick_smaller_tiles_for_bigger_networks() {
        let budget = 256 << 20;
        let paper = size_for_budget(&Architecture::paper(Kind::Kpcn), budget, 1920, 1080);
        let small = size_for_budget(&Architecture::small(Kind::Kpcn), budget, 1920, 1080);
        assert!(paper < small, "{paper} vs {small}");
        assert!(tile_bytes(&Architecture::paper(Kind::Kpcn), paper) <= budget);
        assert_eq!(size_for_budget(&Architecture::small(Kind::Kpcn), usize::MAX, 40, 20), 48);
    }
}
