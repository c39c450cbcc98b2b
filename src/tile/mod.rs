//! Splitting a frame into tiles whose working memory fits a budget. Halos are not stored
//! here: `features` extracts each tile's input with its halo (reflected at the frame
//! border), so a tile's result equals the same region of the untiled result.

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

/// The largest tile side (a multiple of 16, at least 16, at most the frame's larger side)
/// whose working memory, `tile_bytes(side)`, fits `budget` bytes.
pub fn size_for_budget(tile_bytes: impl Fn(usize) -> usize, budget: usize, width: usize, height: usize) -> usize {
    let cap = width.max(height).max(16).next_multiple_of(16);
    let mut t = 16;
    while t + 16 <= cap && tile_bytes(t + 16) <= budget {
        t += 16;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn the_budget_picks_the_largest_side_that_fits() {
        // A quadratic cost: 4 bytes per pixel of the tile plus a 16-pixel halo.
        let bytes = |t: usize| 4 * (t + 32) * (t + 32);
        let t = size_for_budget(bytes, 1 << 20, 1920, 1080);
        assert!(t % 16 == 0 && bytes(t) <= 1 << 20 && bytes(t + 16) > 1 << 20, "{t}");
        assert_eq!(size_for_budget(bytes, usize::MAX, 40, 20), 48);
        assert_eq!(size_for_budget(bytes, 0, 40, 20), 16);
    }
}
