//! Splitting a frame into tiles whose working memory fits a budget, and the region of
//! context each tile is evaluated on ([`Reach`]). Halos are not stored here: `features`
//! extracts each tile's input with its halo (reflected at the frame border), so a tile's
//! result equals the same region of the untiled result.

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

/// Tiles of at most `tw`×`th` covering a `width`×`height` frame, row by row.
pub fn plan(width: usize, height: usize, tw: usize, th: usize) -> Vec<Tile> {
    let (tw, th) = (tw.max(1), th.max(1));
    (0..height.div_ceil(th))
        .flat_map(|ty| {
            (0..width.div_ceil(tw)).map(move |tx| {
                let (x, y) = (tx * tw, ty * th);
                Tile { x, y, w: tw.min(width - x), h: th.min(height - y) }
            })
        })
        .collect()
}

/// How far the region a tile is evaluated on reaches beyond the tile: `radius` pixels
/// above and below, `column_radius` left and right, but at most `border` beyond the
/// frame's edges, its length rounded up to `align` (the network's pooling grid).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reach {
    /// Context each side across rows inside the frame.
    pub radius: usize,
    /// Context each side across columns inside the frame: `radius`, or more where the
    /// network's rounding reads further along rows
    /// ([`crate::model::multiscale::column_radius`]).
    pub column_radius: usize,
    /// Context each side beyond the frame's edges (at most either radius).
    pub border: usize,
    /// Region lengths are multiples of this.
    pub align: usize,
}

impl Reach {
    /// The same context each way.
    pub fn square(radius: usize, border: usize, align: usize) -> Reach {
        Reach { radius, column_radius: radius, border, align }
    }

    /// The region `(start, length, offset of the span in it)` of rows around the rows
    /// `[at, at + len)` of a frame `total` rows high. Each end depends only on where the
    /// span lies against the frame's edges, so a tile sees what the whole frame would.
    pub fn rows(&self, at: usize, len: usize, total: usize) -> (isize, usize, usize) {
        self.region(self.radius, at, len, total)
    }

    /// [`Reach::rows`] across columns: around the columns `[at, at + len)` of a frame
    /// `total` wide.
    pub fn columns(&self, at: usize, len: usize, total: usize) -> (isize, usize, usize) {
        self.region(self.column_radius, at, len, total)
    }

    fn region(&self, radius: usize, at: usize, len: usize, total: usize) -> (isize, usize, usize) {
        let (r, border) = (radius as isize, self.border.min(radius) as isize);
        let start = (at as isize - r).max(-border);
        let end = (at as isize + len as isize + r).min(total as isize + border);
        (start, ((end - start) as usize).next_multiple_of(self.align.max(1)), (at as isize - start) as usize)
    }
}

/// One axis of a frame (or of a band with context rows) to be tiled: pixels
/// `[start, start + len)` of `total`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Axis {
    /// First pixel to tile.
    pub start: usize,
    /// Pixels to tile.
    pub len: usize,
    /// The axis's length, context included.
    pub total: usize,
}

impl Axis {
    /// A whole axis of `len` pixels.
    pub fn whole(len: usize) -> Axis {
        Axis { start: 0, len, total: len }
    }

    /// For each tile length (multiples of `step`): (length, summed and largest region
    /// length over the tiles), with `region` one of [`Reach`]'s.
    fn costs(
        &self,
        region: impl Fn(usize, usize, usize) -> (isize, usize, usize),
        step: usize,
    ) -> Vec<(usize, usize, usize)> {
        (1..=self.len.max(1).div_ceil(step))
            .map(|k| {
                let t = k * step;
                let (sum, max) = (0..self.len.max(1).div_ceil(t)).fold((0, 0), |(sum, max), i| {
                    let len = t.min(self.len.saturating_sub(i * t)).max(1);
                    let (_, r, _) = region(self.start + i * t, len, self.total);
                    (sum + r, max.max(r))
                });
                (t, sum, max)
            })
            .collect()
    }
}

/// The tile size `(w, h)` (multiples of `step`) that evaluates the fewest region pixels
/// in all while every region's working memory, `bytes(region_w, region_h, tile_w,
/// tile_h)`, fits `budget`; ties go to fewer tiles. When nothing fits, the smallest
/// tiles. A network whose reach is large against the frame (a U-Net seeing 192 px)
/// gets wide, flat tiles or the whole frame rather than squares that each recompute a
/// wide halo.
pub fn size_for_regions(
    x: Axis,
    y: Axis,
    reach: &Reach,
    step: usize,
    bytes: impl Fn(usize, usize, usize, usize) -> usize,
    budget: usize,
) -> (usize, usize) {
    let step = step.max(1);
    let (cx, cy) = (x.costs(|a, l, t| reach.columns(a, l, t), step), y.costs(|a, l, t| reach.rows(a, l, t), step));
    let mut best: Option<((usize, usize), (usize, usize))> = None;
    for &(tw, sw, mw) in &cx {
        for &(th, sh, mh) in &cy {
            if bytes(mw, mh, tw, th) > budget {
                continue;
            }
            // Least region area, then fewest tiles.
            let key = (sw * sh, usize::MAX - tw.min(x.len) * th.min(y.len));
            if best.is_none_or(|(k, _)| key < k) {
                best = Some((key, (tw, th)));
            }
        }
    }
    best.map_or((step, step), |(_, size)| size)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_frame_exactly_once() {
        for (w, h, s) in [(1, 1, 16), (37, 5, 16), (64, 64, 32), (100, 33, 7)] {
            let mut hits = vec![0u8; w * h];
            for t in plan(w, h, s, s) {
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
    fn regions_stop_at_the_border_radius_and_sit_on_the_grid() {
        let reach = Reach { radius: 192, column_radius: 224, border: 64, align: 32 };
        // The whole axis: 64 px beyond each end, rounded up to the grid, either way.
        assert_eq!(reach.rows(0, 720, 720), (-64, 864, 64));
        assert_eq!(reach.columns(0, 720, 720), (-64, 864, 64));
        // An inner tile gets the full radius; one at the end stops where the whole axis's does.
        assert_eq!(reach.rows(320, 64, 720), (128, 448, 192));
        assert_eq!(reach.columns(320, 64, 720), (96, 512, 224));
        let (start, len, _) = reach.rows(640, 80, 720);
        assert_eq!((start, start + len as isize), (448, -64 + 864));
        // Inside a band with context rows (start 200 of 900): no border cut applies.
        assert_eq!(reach.rows(200, 100, 900), (8, 512, 192));
    }

    #[test]
    fn wide_reach_prefers_whole_rows_and_the_whole_frame() {
        let reach = Reach { radius: 192, column_radius: 208, border: 64, align: 32 };
        let bytes = |rw: usize, rh: usize, _: usize, _: usize| 536 * rw * rh;
        let (x, y) = (Axis::whole(1280), Axis::whole(720));
        // Enough memory: one tile.
        assert_eq!(size_for_regions(x, y, &reach, 32, bytes, 1 << 30), (1280, 736));
        // Not enough for the whole frame: fewer region pixels than any square tiling.
        let (tw, th) = size_for_regions(x, y, &reach, 32, bytes, 512 << 20);
        let sum = |a: Axis, t: usize, region: &dyn Fn(usize, usize, usize) -> (isize, usize, usize)| -> usize {
            (0..a.len.div_ceil(t)).map(|i| region(i * t, t.min(a.len - i * t), a.total).1).sum()
        };
        let area = |tw: usize, th: usize| {
            sum(x, tw, &|a, l, t| reach.columns(a, l, t)) * sum(y, th, &|a, l, t| reach.rows(a, l, t))
        };
        let plan = plan(1280, 720, tw, th);
        assert!(plan.len() > 1);
        for t in &plan {
            let (_, rw, _) = reach.columns(t.x, t.w, 1280);
            let (_, rh, _) = reach.rows(t.y, t.h, 720);
            assert!(bytes(rw, rh, t.w, t.h) <= 512 << 20, "{t:?}");
        }
        for side in (32..=1280).step_by(32) {
            let fits = (0..1280usize.div_ceil(side)).all(|i| {
                (0..720usize.div_ceil(side)).all(|j| {
                    let (_, rw, _) = reach.columns(i * side, side.min(1280 - i * side), 1280);
                    let (_, rh, _) = reach.rows(j * side, side.min(720 - j * side), 720);
                    bytes(rw, rh, side, side) <= 512 << 20
                })
            });
            if fits {
                assert!(area(tw, th) <= area(side, side), "{tw}x{th} against {side}");
            }
        }
        // Nothing fits: the smallest tiles.
        assert_eq!(size_for_regions(x, y, &reach, 32, bytes, 0), (32, 32));
    }
}
