//! A multi-scale model's network streamed down a whole frame: each band's features go
//! into one [`Stream`] per branch, whose region is the whole frame's, and a band's
//! result comes out once the rows below it that it depends on have gone in. No row is
//! evaluated twice, so bands need only the few context rows their features need
//! ([`crate::features::CONTEXT`]), and the result is the whole frame's bit for bit.

use super::bounds::{BandPlanes, Detail, Take, add_detail};
use super::{Bounds, Denoised, Denoiser, recompose};
use crate::features::{Branch, Features, INPUT_CHANNELS};
use crate::io::layout::Remainder;
use crate::kernel::planes::Planes;
use crate::model::Specular;
use crate::model::stream::Stream;
use std::collections::VecDeque;
use std::ops::Range;

/// Region rows pushed into a stream at a time.
pub(super) const PUSH_ROWS: usize = 32;

/// The network of a multi-scale [`Denoiser`] over one `width × height` frame, fed band
/// by band, top to bottom.
pub(super) struct FrameStream<'a> {
    denoiser: &'a Denoiser,
    /// The diffuse and the specular branch.
    streams: [Stream<'a>; 2],
    /// The region along each axis: first pixel (negative: mirrored beyond the frame),
    /// length, and where the frame starts in it.
    x: (isize, usize, usize),
    y: (isize, usize, usize),
    width: usize,
    height: usize,
    /// Region rows pushed.
    pushed: usize,
    /// Each branch's output rows from `emitted` on, the frame's columns only.
    out: [[Vec<f32>; 3]; 2],
    /// Bands pushed and not yet emitted.
    pending: VecDeque<Pending>,
    /// The diffuse ceiling's take of the last rows of the band emitted last (as many as
    /// its diffuse output reads, [`Bounds::diffuse_context`]), where the model spreads it,
    tail: Take,
    /// and what its detail is restored from, where the model restores it.
    detail_tail: Detail,
    exposure: f32,
}

impl<'a> FrameStream<'a> {
    /// The stream of `denoiser` over a `width × height` frame; `None` where it does not
    /// stream such frames ([`Denoiser::streams`]).
    pub(super) fn new(denoiser: &'a Denoiser, width: usize, height: usize) -> Option<FrameStream<'a>> {
        if !denoiser.streams(width) {
            return None;
        }
        let [diffuse, specular] = denoiser.pyramid.as_ref()?;
        let reach = denoiser.reach();
        let (x, y) = (reach.columns(0, width, width), reach.rows(0, height, height));
        let arch = &denoiser.model.arch;
        Some(FrameStream {
            denoiser,
            streams: [Stream::new(arch, diffuse, x.1, y.1), Stream::new(arch, specular, x.1, y.1)],
            x,
            y,
            width,
            height,
            pushed: 0,
            out: Default::default(),
            pending: VecDeque::new(),
            tail: Default::default(),
            detail_tail: Default::default(),
            exposure: 1.0,
        })
    }

    /// Rows a band's features are read beyond the frame's top and bottom edges (mirrored),
    /// so the first and the last band must be taller than this.
    pub(super) fn mirrored_rows(denoiser: &Denoiser, height: usize) -> usize {
        let (y0, rh, _) = denoiser.reach().rows(0, height, height);
        (y0.unsigned_abs()).max((y0 + rh as isize) as usize - height)
    }

    /// Pushes the rows of `band`: `f` holds the features of rows from `f_start` on (the
    /// band and its context rows), `remainder` what the band's beauty holds beyond its
    /// components. The first band also pushes the mirrored rows above the frame, the last
    /// those below it.
    pub(super) fn push(&mut self, f: &Features, f_start: usize, band: Range<usize>, remainder: Remainder) {
        let (w, (x0, rw, ox), (y0, rh, oy)) = (self.width, self.x, self.y);
        let end = if band.end == self.height { rh } else { (band.end as isize - y0) as usize };
        let albedo =
            std::array::from_fn(|c| f.albedo[c][(band.start - f_start) * w..(band.end - f_start) * w].to_vec());
        let rows = band.start - f_start..band.end - f_start;
        let bounds = self.denoiser.pool.install(|| Bounds::of(&self.denoiser.model.arch, f, rows));
        self.pending.push_back(Pending { rows: band, albedo, remainder, bounds, settled: None });
        self.exposure = f.exposure;
        let (arch, height) = (&self.denoiser.model.arch, self.height);
        while self.pushed < end {
            let n = PUSH_ROWS.min(end - self.pushed);
            let local = y0 + self.pushed as isize - f_start as isize;
            let win = Window { x0, rw, ox, w, keep: oy..oy + height };
            let run = |b: Branch, stream: &mut Stream, out: &mut [Vec<f32>; 3]| {
                feed(arch, f, b, stream, &win, (local, n), out)
            };
            let ([ds, ss], [dout, sout]) = (&mut self.streams, &mut self.out);
            // The branches side by side: a stream alone leaves cores idle between its
            // small steps.
            self.denoiser
                .pool
                .install(|| rayon::join(|| run(Branch::Diffuse, ds, dout), || run(Branch::Specular, ss, sout)));
            self.pushed += n;
        }
    }

    /// The next band whose result is complete, in order. Where the model's diffuse output
    /// reads its neighbours' (a spread of what its ceiling takes, its detail restored), a
    /// band is complete once the next one is too (or it is the last): the next band's
    /// first rows send it light and detail.
    pub(super) fn ready(&mut self) -> Option<(Range<usize>, Denoised)> {
        // On the denoiser's threads: what finishes a band runs pixel by pixel in parallel.
        let denoiser = self.denoiser;
        denoiser.pool.install(|| self.finish_front())
    }

    /// [`FrameStream::ready`], on the calling threads.
    fn finish_front(&mut self) -> Option<(Range<usize>, Denoised)> {
        let w = self.width;
        let rows = self.out[0][0].len().min(self.out[1][0].len()) / w.max(1);
        let band = self.pending.front()?.rows.clone();
        let neighbours = Bounds::reads_neighbours(&self.denoiser.model.arch);
        let needed = if neighbours && band.end < self.height { self.pending.get(1)?.rows.end } else { band.end };
        if band.start + rows < needed {
            return None;
        }
        if neighbours {
            self.settle();
        }
        let (spread, detail) = (self.pending[0].bounds.spread, self.pending[0].bounds.detail);
        let glow = spread.map(|r| {
            let (all, keep) = self.around(|s| &s.taken, |t| &mut t.tail);
            all.spread(w, r).map(|p| p[keep.clone()].to_vec())
        });
        let restored = detail.map(|r| {
            let (all, keep) = self.around(|s| &s.detail, |t| &mut t.detail_tail);
            all.restore(w, r).map(|p| p[keep.clone()].to_vec())
        });
        let Pending { rows: band, albedo, remainder, bounds, .. } = self.pending.pop_front()?;
        let n = band.len() * w;
        let take = |o: &mut [Vec<f32>; 3]| -> [Vec<f32>; 3] { std::array::from_fn(|c| o[c].drain(..n).collect()) };
        let (mut d_hat, s_hat) = (take(&mut self.out[0]), take(&mut self.out[1]));
        if !neighbours {
            // Otherwise the rows are within the ceiling already (`settle`).
            bounds.bound_diffuse(&albedo, &mut d_hat);
        }
        if let Some(detail) = restored {
            add_detail(&mut d_hat, &detail);
        }
        let domain = self.denoiser.model.arch.specular;
        let mut d = self.denoiser.pool.install(|| {
            recompose(&albedo, d_hat, &s_hat, (w, band.len()), domain, self.exposure, &bounds, glow.as_ref())
        });
        d.carry(&remainder);
        Some((band, d))
    }

    /// Bounds the rows of the front band and the next (complete, unless the front is the
    /// last) within the ceiling in the output, once, and keeps what their neighbours read:
    /// what the ceiling took ([`Take`]) and what the detail is restored from ([`Detail`]).
    fn settle(&mut self) {
        let w = self.width;
        let mut at = 0;
        for p in self.pending.iter_mut().take(2) {
            let n = p.rows.len() * w;
            if at + n > self.out[0][0].len() {
                break;
            }
            if p.settled.is_none() {
                let mut d_hat: [Vec<f32>; 3] = std::array::from_fn(|c| self.out[0][c][at..at + n].to_vec());
                let taken = p.bounds.bound_diffuse(&p.albedo, &mut d_hat).unwrap_or_default();
                let detail = p.bounds.detail_inputs(&d_hat).unwrap_or_default();
                (0..3).for_each(|c| self.out[0][c][at..at + n].copy_from_slice(&d_hat[c]));
                p.settled = Some(Settled { taken, detail });
            }
            at += n;
        }
    }

    /// The front band's settled planes (`of`) with the rows before it its diffuse output
    /// reads (`tail`, [`Bounds::diffuse_context`]) and the next band's first as many, and
    /// where the front band's pixels lie in them; the tail becomes its own last rows.
    fn around<const N: usize>(
        &mut self,
        of: impl Fn(&Settled) -> &BandPlanes<N>,
        tail: impl Fn(&mut Self) -> &mut BandPlanes<N>,
    ) -> (BandPlanes<N>, Range<usize>) {
        let context = Bounds::diffuse_context(&self.denoiser.model.arch);
        let w = self.width;
        let band = self.pending[0].rows.clone();
        let above = std::mem::take(tail(self));
        let own = of(self.pending[0].settled.as_ref().expect("settled"));
        debug_assert_eq!(above.height(w), band.start.min(context), "bands are at least the context tall");
        let first = above.height(w);
        let rows = own.height(w);
        let new_tail = own.rows(rows - rows.min(context)..rows, w);
        let mut all = above.then(own);
        if let Some(next) = self.pending.get(1).and_then(|p| p.settled.as_ref()).map(&of) {
            all = all.then(&next.rows(0..next.height(w).min(context), w));
        }
        *tail(self) = new_tail;
        (all, first * w..(first + rows) * w)
    }
}

/// What a band's neighbours read of its diffuse output once it is within the ceiling
/// ([`FrameStream::settle`]); each empty where the model does not read it.
struct Settled {
    taken: Take,
    detail: Detail,
}

/// A band pushed into a [`FrameStream`] whose result has not come out.
struct Pending {
    rows: Range<usize>,
    albedo: [Vec<f32>; 3],
    remainder: Remainder,
    /// What bounds the branches, where the model does.
    bounds: Bounds,
    /// Where the model's diffuse output reads its neighbours', what they read: known once
    /// its rows have come out of the stream, which then hold them within the ceiling.
    settled: Option<Settled>,
}

/// Where a stream's region lies and what of its output is kept: the region's first column
/// (negative: mirrored) and width; the kept columns `[ox, ox + w)` and region rows `keep`.
pub(super) struct Window {
    pub(super) x0: isize,
    pub(super) rw: usize,
    pub(super) ox: usize,
    pub(super) w: usize,
    pub(super) keep: Range<usize>,
}

/// Pushes `n` rows of branch `b` into `stream`, from row `y` of `f` (the columns of
/// `win`'s region), and appends to `out` the output rows that came out within `win`.
pub(super) fn feed(
    arch: &crate::model::Architecture,
    f: &Features,
    b: Branch,
    stream: &mut Stream,
    win: &Window,
    (y, n): (isize, usize),
    out: &mut [Vec<f32>; 3],
) {
    let (x0, rw) = (win.x0, win.rw);
    let mut input = f.branch_input(b, x0, y, rw, n);
    arch.prepare_input(b, &mut input);
    // The colour, and its variance where the clamp reads it (that of s̃ is of the log
    // radiance, so linear specular kernels clamp without it).
    let linear = b == Branch::Specular && arch.specular == Specular::Linear;
    let mut planes: Vec<&[f32]> = f.colour(b).iter().map(Vec::as_slice).collect();
    if arch.clamp.reads_variance() && !linear {
        planes.push(f.variance(b));
    }
    let mut noisy = f.region(&planes, x0, y, rw, n);
    if linear {
        noisy[..3 * rw * n].iter_mut().for_each(|v| *v = Specular::Linear.kernel_input(*v));
    }
    stream.push(Planes::from_vec(INPUT_CHANNELS, rw, n, input), Planes::from_vec(planes.len(), rw, n, noisy));
    while let Some((first, rows)) = stream.take() {
        for r in first.max(win.keep.start)..(first + rows.h).min(win.keep.end) {
            for (c, o) in out.iter_mut().enumerate() {
                o.extend_from_slice(&rows.plane(c)[(r - first) * rw + win.ox..][..win.w]);
            }
        }
    }
}
