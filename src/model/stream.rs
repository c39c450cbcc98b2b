//! The multi-scale network on a region streamed in rows: features and noisy colour go in
//! a few rows at a time, denoised rows come out some rows behind, and each layer keeps
//! only the rows its consumers still need. A region as wide as a 4K frame then costs the
//! network a few hundred rows of activations rather than the whole region's, so frames
//! are evaluated in full-width regions, whose context rows and columns are never
//! evaluated twice.
//!
//! The network is recorded once from [`multiscale::run`] (its only definition) into a
//! graph of operations, each evaluated on windows of its inputs' rows by the same
//! functions the whole region's evaluation calls (`pyramid::forward`, in tests); a window
//! holds every row the operation's outputs depend on, or stops where the region does, so
//! each row equals the whole region's bit for bit.

use super::Architecture;
use super::multiscale::{self, Backend, CLAMP_CONTEXT};
use super::pyramid::{Region, Weights, apply_rows, blend_scales};
use crate::kernel::buffers;
use crate::kernel::planes::{Planes, repeat_pairs};
use std::borrow::Cow;
use std::cell::RefCell;
use std::collections::VecDeque;

/// Full-resolution rows evaluated per step on a `w`-wide region (a frame's width and the
/// network's reach each side): whole rows of the coarsest scale of a 5-level network. A
/// stream holds two steps beside its reach, so regions wider than 2560 (a 4K frame's, not
/// a 2048-wide frame's) take 16 rows rather than 32: on a 3840-wide frame that lowers
/// the command's peak by about 50 MB at the same speed, while on a 1280-wide one 16 rows
/// cost a tenth more time (BENCHMARKS.md, whole command).
fn step_rows(w: usize) -> usize {
    if w > 2560 { 16 } else { 32 }
}

/// Rows (of [`super::pyramid::bytes_per_pixel`] each) a stream on a `w`-wide region
/// holds at most, its working rows included: each layer keeps the rows its consumers
/// still read, about half the reach in all (measured by the test below), plus two steps.
pub fn held_rows(arch: &Architecture, w: usize) -> usize {
    held_rows_with(arch, step_rows(w))
}

fn held_rows_with(arch: &Architecture, step: usize) -> usize {
    arch.reach() / 2 + 2 * step
}

/// An operation of the recorded network; inputs are node indices.
#[derive(Debug, Clone, Copy)]
enum Op {
    /// Rows pushed by the caller: the features or the noisy colour.
    Source,
    Conv {
        x: usize,
        layer: usize,
        relu: bool,
    },
    Pool {
        x: usize,
    },
    UpConcat {
        coarse: usize,
        skip: usize,
        layer: usize,
        relu: bool,
    },
    /// Scale `s` of [`multiscale::colour_pyramid`] of the noisy colour.
    Colour {
        noisy: usize,
        s: usize,
    },
    Apply {
        logits: usize,
        colour: usize,
    },
    /// `a − b`, rows alike.
    Sub {
        a: usize,
        b: usize,
    },
    /// `x·2σ(g)`, rows alike ([`Backend::gain`]).
    Gain {
        x: usize,
        logits: usize,
    },
    Blend {
        fine: usize,
        coarse: usize,
        logits: usize,
    },
}

/// The rows of one node computed and still held: chunks in order, each with its first row.
#[derive(Debug, Default)]
struct Store {
    chunks: VecDeque<(usize, Planes)>,
}

impl Store {
    /// Rows `[lo, hi)`: the chunk that holds just them, or a copy into one block
    /// (appended, never zeroed first: the chunks hold consecutive rows, and `from_vec`
    /// checks that every row came). Operations stepping alike read their input's chunks
    /// whole, without copies.
    fn rows(&self, lo: usize, hi: usize) -> Cow<'_, Planes> {
        if let Some((_, p)) = self.chunks.iter().find(|(s, p)| *s == lo && s + p.h == hi) {
            return Cow::Borrowed(p);
        }
        let first = &self.chunks.front().expect("rows are held before they are read").1;
        let (c, w) = (first.c, first.w);
        debug_assert!(self.chunks.front().is_some_and(|(s, _)| *s <= lo), "row {lo} was dropped");
        let mut data = buffers::with_capacity(c * w * (hi - lo));
        for ch in 0..c {
            for (start, p) in &self.chunks {
                let (a, b) = (lo.max(*start), hi.min(start + p.h));
                if a < b {
                    data.extend_from_slice(&p.data[(ch * p.h + a - start) * w..(ch * p.h + b - start) * w]);
                }
            }
        }
        Cow::Owned(Planes::from_vec(c, w, hi - lo, data))
    }

    /// Row `y` of channel `ch`, where one chunk holds it.
    fn row(&self, ch: usize, y: usize) -> &[f32] {
        let (start, p) =
            self.chunks.iter().find(|(s, p)| (*s..s + p.h).contains(&y)).expect("rows are held before they are read");
        &p.data[(ch * p.h + y - start) * p.w..][..p.w]
    }

    /// The width of the rows held.
    fn width(&self) -> usize {
        self.chunks.front().map_or(0, |(_, p)| p.w)
    }

    /// The channels of the rows held.
    fn channels(&self) -> usize {
        self.chunks.front().map_or(0, |(_, p)| p.c)
    }

    /// Drops the chunks wholly above row `row`.
    fn drop_below(&mut self, row: usize) {
        while self.chunks.front().is_some_and(|(s, p)| s + p.h <= row) {
            self.chunks.pop_front();
        }
    }
}

#[derive(Debug)]
struct Node {
    op: Op,
    /// Scale: rows and columns are the region's `>> level`.
    level: usize,
    /// Rows computed (or pushed) so far.
    done: usize,
    store: Store,
}

/// Records [`multiscale::run`] as a graph.
struct Recorder {
    nodes: RefCell<Vec<(Op, usize)>>,
}

impl Recorder {
    fn add(&self, op: Op, level: usize) -> usize {
        let mut n = self.nodes.borrow_mut();
        n.push((op, level));
        n.len() - 1
    }

    fn level(&self, i: usize) -> usize {
        self.nodes.borrow()[i].1
    }
}

impl Backend for Recorder {
    type Value = usize;
    type Error = std::convert::Infallible;

    fn conv(&self, x: &usize, layer: usize, relu: bool) -> Result<usize, Self::Error> {
        Ok(self.add(Op::Conv { x: *x, layer, relu }, self.level(*x)))
    }

    fn pool(&self, x: &usize) -> Result<usize, Self::Error> {
        Ok(self.add(Op::Pool { x: *x }, self.level(*x) + 1))
    }

    fn conv_up_concat(&self, coarse: &usize, skip: &usize, layer: usize, relu: bool) -> Result<usize, Self::Error> {
        Ok(self.add(Op::UpConcat { coarse: *coarse, skip: *skip, layer, relu }, self.level(*skip)))
    }

    fn colour(&self, noisy: usize, levels: usize) -> Result<Vec<usize>, Self::Error> {
        Ok((0..levels).map(|s| self.add(Op::Colour { noisy, s }, s)).collect())
    }

    fn apply(&self, logits: &usize, colour: &usize) -> Result<usize, Self::Error> {
        Ok(self.add(Op::Apply { logits: *logits, colour: *colour }, self.level(*logits)))
    }

    fn sub(&self, a: &usize, b: &usize) -> Result<usize, Self::Error> {
        Ok(self.add(Op::Sub { a: *a, b: *b }, self.level(*a)))
    }

    fn blend(&self, fine: usize, coarse: &usize, logits: &usize) -> Result<usize, Self::Error> {
        Ok(self.add(Op::Blend { fine, coarse: *coarse, logits: *logits }, self.level(fine)))
    }

    fn gain(&self, x: usize, logits: &usize) -> Result<usize, Self::Error> {
        Ok(self.add(Op::Gain { x, logits: *logits }, self.level(x)))
    }
}

/// One branch of a multi-scale network evaluated on a `w × h` region (sides multiples
/// of [`Architecture::alignment`]) streamed in rows: [`Stream::push`] the region's rows
/// top to bottom, [`Stream::take`] the denoised rows as they are ready.
pub struct Stream<'a> {
    arch: &'a Architecture,
    region: Region<'a>,
    nodes: Vec<Node>,
    /// The features, the noisy colour and the output.
    input: usize,
    noisy: usize,
    out: usize,
    /// Each node's consumers.
    consumers: Vec<Vec<usize>>,
    /// Output rows already taken.
    taken: usize,
    /// Each layer's convolution radius.
    radii: Vec<usize>,
    h: usize,
    /// Full-resolution rows evaluated per step ([`step_rows`]).
    step: usize,
}

impl<'a> Stream<'a> {
    /// A stream of `weights` on a region of `w × h`.
    pub fn new(arch: &'a Architecture, weights: &'a Weights, w: usize, h: usize) -> Stream<'a> {
        let align = arch.alignment();
        assert!(w.is_multiple_of(align) && h.is_multiple_of(align), "a {w}×{h} region off the pooling grid of {align}");
        let rec = Recorder { nodes: RefCell::new(Vec::new()) };
        let (input, noisy) = (rec.add(Op::Source, 0), rec.add(Op::Source, 0));
        let out = match multiscale::run(arch, &rec, input, noisy) {
            Ok(out) => out,
            Err(e) => match e {},
        };
        let nodes: Vec<Node> = rec
            .nodes
            .into_inner()
            .into_iter()
            .map(|(op, level)| Node { op, level, done: 0, store: Store::default() })
            .collect();
        let mut consumers = vec![Vec::new(); nodes.len()];
        for (i, n) in nodes.iter().enumerate() {
            for j in inputs(&n.op) {
                consumers[j].push(i);
            }
        }
        let radii = arch.layer_shapes().iter().map(|s| s.2 / 2).collect();
        let step = step_rows(w);
        Stream { arch, region: Region { arch, weights }, nodes, input, noisy, out, consumers, taken: 0, radii, h, step }
    }

    /// Appends the region's next rows: `input` its feature planes, `noisy` its colour
    /// (the same rows), and evaluates every layer as far as the rows so far allow.
    pub fn push(&mut self, input: Planes, noisy: Planes) {
        assert_eq!(input.h, noisy.h, "features and colour of different rows");
        let start = self.nodes[self.input].done;
        assert!(start + input.h <= self.h, "rows beyond the region");
        for (i, p) in [(self.input, input), (self.noisy, noisy)] {
            let n = &mut self.nodes[i];
            n.done += p.h;
            n.store.chunks.push_back((start, p));
        }
        self.advance();
    }

    /// The output rows computed since the last call: their first row and the planes.
    pub fn take(&mut self) -> Option<(usize, Planes)> {
        let done = self.nodes[self.out].done;
        if done == self.taken {
            return None;
        }
        let rows = self.nodes[self.out].store.rows(self.taken, done).into_owned();
        let first = std::mem::replace(&mut self.taken, done);
        self.nodes[self.out].store.drop_below(done);
        Some((first, rows))
    }

    /// Bytes of the rows held now.
    pub fn held_bytes(&self) -> usize {
        self.nodes.iter().flat_map(|n| &n.store.chunks).map(|(_, p)| 4 * p.data.len()).sum()
    }

    /// Rows of node `i`.
    fn height(&self, i: usize) -> usize {
        self.h >> self.nodes[i].level
    }

    /// The rows `[lo, hi)` of each input that rows `[a, b)` of node `i` read (clipped
    /// to the region).
    fn needs(&self, i: usize, a: usize, b: usize) -> Vec<(usize, usize, usize)> {
        let clip = |j: usize, lo: isize, hi: usize| (j, lo.max(0) as usize, hi.min(self.height(j)));
        let radius = |layer: usize| self.radii[layer];
        let (ai, b2) = (a as isize, b);
        match self.nodes[i].op {
            Op::Source => Vec::new(),
            Op::Conv { x, layer, .. } => {
                let r = radius(layer);
                vec![clip(x, ai - r as isize, b2 + r)]
            }
            Op::Pool { x } => vec![clip(x, 2 * ai, 2 * b2)],
            Op::UpConcat { coarse, skip, layer, .. } => {
                let (lo, hi) = self.even_window(i, a, b, radius(layer));
                vec![(skip, lo, hi), (coarse, lo / 2, hi / 2)]
            }
            Op::Colour { noisy, s } => {
                let (lo, hi) = self.colour_window(s, a, b);
                vec![(noisy, lo, hi)]
            }
            Op::Apply { logits, colour } => {
                let r = self.arch.kernel_size / 2;
                vec![(logits, a, b), clip(colour, ai - r as isize, b2 + r)]
            }
            Op::Sub { a: x, b: y } | Op::Gain { x, logits: y } => vec![(x, a, b), (y, a, b)],
            Op::Blend { fine, coarse, logits } => {
                vec![(fine, a, b), (logits, a, b), clip(coarse, (a / 2) as isize - 1, (b - 1) / 2 + 2)]
            }
        }
    }

    /// Skip rows an up-concat convolution of radius `r` reads for rows `[a, b)`: the
    /// window widened by `r`, on even rows (each coarse row is two fine ones).
    fn even_window(&self, i: usize, a: usize, b: usize, r: usize) -> (usize, usize) {
        let lo = a.saturating_sub(r) & !1;
        (lo, (b + r).next_multiple_of(2).min(self.height(i)))
    }

    /// Full-resolution colour rows read for rows `[a, b)` of colour scale `s`: those rows
    /// and two rows of context for the clamp ([`multiscale::colour_pyramid_rows`]; the
    /// coarser scales pool the rows themselves, whose first is on the grid of the
    /// coarsest scale, see [`Stream::step_colour`]).
    fn colour_window(&self, s: usize, a: usize, b: usize) -> (usize, usize) {
        ((a << s).saturating_sub(CLAMP_CONTEXT), ((b << s) + CLAMP_CONTEXT).min(self.h))
    }

    /// Evaluates every node as far as its inputs allow, in rounds of one step per node in
    /// the recorded (topological) order, dropping after each round the rows no consumer
    /// will read again: when the last rows go in, every layer's remaining rows are then
    /// held a step at a time rather than all at once.
    fn advance(&mut self) {
        loop {
            let mut moved = false;
            for i in 0..self.nodes.len() {
                match self.nodes[i].op {
                    // Sources are pushed; scales below the first of the colour pyramid are
                    // filled with it (one pyramid per window, not one per scale).
                    Op::Source | Op::Colour { s: 1.., .. } => {}
                    Op::Colour { s: 0, .. } => moved |= self.step_colour(i),
                    _ => {
                        let (a, target) = (self.nodes[i].done, self.frontier(i));
                        if a < target {
                            let b = (a + (self.step >> self.nodes[i].level).max(1)).min(target);
                            let rows = self.compute(i, a, b);
                            let n = &mut self.nodes[i];
                            n.store.chunks.push_back((a, rows));
                            n.done = b;
                            moved = true;
                        }
                    }
                }
            }
            self.drop_read_rows();
            if !moved {
                break;
            }
        }
    }

    /// Drops every node's rows that no consumer will read again.
    fn drop_read_rows(&mut self) {
        for i in 0..self.nodes.len() {
            if i == self.out {
                continue;
            }
            let keep = self.consumers[i]
                .iter()
                .filter_map(|&c| {
                    let (d, hc) = (self.nodes[c].done, self.height(c));
                    (d < hc).then(|| self.needs(c, d, d + 1).into_iter().find(|n| n.0 == i).map_or(usize::MAX, |n| n.1))
                })
                .min()
                .unwrap_or(usize::MAX);
            self.nodes[i].store.drop_below(keep);
        }
    }

    /// Advances the colour pyramid (node `i` its full-resolution scale) one step as far
    /// as the noisy rows allow, on the grid of its coarsest scale, filling every scale;
    /// whether it moved.
    fn step_colour(&mut self, i: usize) -> bool {
        let grid = 1 << (self.arch.layers - 1);
        let (h, target) = (self.h, self.frontier(i));
        let target = if target == h { h } else { target / grid * grid };
        let a = self.nodes[i].done;
        if a >= target {
            return false;
        }
        let b = (a + self.step.max(grid)).min(target);
        let (noisy, lo) = match self.needs(i, a, b)[..] {
            [(j, lo, hi)] => (self.nodes[j].store.rows(lo, hi).into_owned(), lo),
            _ => unreachable!("the colour reads the noisy colour"),
        };
        let levels = multiscale::colour_pyramid_rows(noisy, self.arch.layers, self.arch.clamp, a - lo..b - lo);
        let scales = (0..self.nodes.len()).filter(|&j| matches!(self.nodes[j].op, Op::Colour { .. }));
        for (j, rows) in scales.collect::<Vec<_>>().into_iter().zip(levels) {
            let s = self.nodes[j].level;
            let n = &mut self.nodes[j];
            n.store.chunks.push_back((a >> s, rows));
            n.done = b >> s;
        }
        true
    }

    /// The most rows of node `i` its inputs' rows so far allow.
    fn frontier(&self, i: usize) -> usize {
        let ready = |b: usize| self.needs(i, self.nodes[i].done, b).iter().all(|&(j, _, hi)| hi <= self.nodes[j].done);
        let (mut lo, mut hi) = (self.nodes[i].done, self.height(i));
        if ready(hi) {
            return hi;
        }
        // ready(lo) holds trivially for an empty range; find the largest b with ready(b).
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if ready(mid) { lo = mid } else { hi = mid }
        }
        lo
    }

    /// Rows `[a, b)` of node `i`.
    fn compute(&self, i: usize, a: usize, b: usize) -> Planes {
        let needs = self.needs(i, a, b);
        let window = |k: usize| {
            let (j, lo, hi) = needs[k];
            (self.nodes[j].store.rows(lo, hi), lo)
        };
        let r = &self.region;
        let ok = |v: Result<Planes, std::convert::Infallible>| match v {
            Ok(p) => p,
            Err(e) => match e {},
        };
        match self.nodes[i].op {
            Op::Source => unreachable!("sources are pushed"),
            // Convolutions read their window's rows where the store holds them and compute
            // just rows [a, b): the window's context rows cost no multiply-adds.
            Op::Conv { x, layer, relu } => {
                let (_, lo, hi) = needs[0];
                let x = &self.nodes[x].store;
                let row_of = |ch: usize, y: usize, dst: &mut [f32]| dst.copy_from_slice(x.row(ch, lo + y));
                r.conv_rows(layer, relu, (x.width(), hi - lo), a - lo..b - lo, row_of)
            }
            Op::Pool { .. } => ok(r.pool(&window(0).0)),
            // The full-resolution head: 1×1, so its window is its rows.
            Op::UpConcat { layer, relu, .. } if r.splits(layer) => {
                let ((skip, lo), (coarse, _)) = (window(0), window(1));
                ok(r.conv_up_concat(&coarse, &skip, layer, relu)).crop_rows(a - lo..b - lo)
            }
            Op::UpConcat { coarse, skip, layer, relu } => {
                let (_, lo, hi) = needs[0];
                let (coarse, skip) = (&self.nodes[coarse].store, &self.nodes[skip].store);
                let cc = coarse.channels();
                // A coarse row is two fine ones; `lo` is even (see `even_window`).
                let row_of = |ch: usize, y: usize, dst: &mut [f32]| {
                    if ch < cc {
                        repeat_pairs(dst, coarse.row(ch, (lo + y) / 2));
                    } else {
                        dst.copy_from_slice(skip.row(ch - cc, lo + y));
                    }
                };
                r.conv_rows(layer, relu, (skip.width(), hi - lo), a - lo..b - lo, row_of)
            }
            Op::Colour { .. } => unreachable!("the colour pyramid is advanced whole"),
            Op::Apply { colour, .. } => {
                let logits = window(0).0;
                let store = &self.nodes[colour].store;
                apply_rows(&logits, &|c, y| store.row(c, y), a, self.height(colour), self.arch.kernel_size)
            }
            Op::Sub { .. } => ok(r.sub(&window(0).0, &window(1).0)),
            Op::Gain { .. } => ok(r.gain(window(0).0.into_owned(), &window(1).0)),
            Op::Blend { .. } => {
                let (mut fine, logits, (coarse, lo)) = (window(0).0.into_owned(), window(1).0, window(2));
                let up = coarse.up_bilinear_rows(a - 2 * lo..b - 2 * lo);
                blend_scales(self.arch, &mut fine, &up, &logits);
                fine
            }
        }
    }
}

/// The nodes `op` reads.
fn inputs(op: &Op) -> Vec<usize> {
    match *op {
        Op::Source => vec![],
        Op::Conv { x, .. } | Op::Pool { x } => vec![x],
        Op::UpConcat { coarse, skip, .. } => vec![skip, coarse],
        Op::Colour { noisy, .. } => vec![noisy],
        Op::Apply { logits, colour } => vec![logits, colour],
        Op::Sub { a, b } | Op::Gain { x: a, logits: b } => vec![a, b],
        Op::Blend { fine, coarse, logits } => vec![fine, logits, coarse],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::INPUT_CHANNELS;
    use crate::model::{Model, pyramid};

    #[test]
    fn a_stream_holds_at_most_its_estimate() {
        use crate::model::ScaleBlend;
        let presets = ["balanced", "compact", "high", "fast"].map(|p| (p, ScaleBlend::Lerp));
        for (preset, blend) in presets.into_iter().chain([("balanced", ScaleBlend::Detail)]) {
            let model = Model::resolve(preset).unwrap();
            let arch = Architecture { blend, ..model.arch };
            let weights = Weights::new(&arch, &model.specular).unwrap();
            let (w, h) = (256, 1024);
            // Both steps a frame's width may choose, on a narrow region to stay quick.
            for step in [16, 32] {
                let mut s = Stream::new(&arch, &weights, w, h);
                s.step = step;
                let mut most = 0;
                for _ in 0..h / 32 {
                    s.push(Planes::zeros(INPUT_CHANNELS, w, 32), Planes::zeros(3, w, 32));
                    while s.take().is_some() {}
                    most = most.max(s.held_bytes());
                }
                let estimate = held_rows_with(&arch, step) * w * pyramid::bytes_per_pixel(&arch);
                println!("{preset} ({blend:?}), steps of {step} rows: held at most {most} B, estimated {estimate} B");
                assert!(
                    most <= estimate,
                    "{preset} ({blend:?}), steps of {step}: held {most} B, estimated {estimate} B"
                );
                // And far below the whole region's.
                assert!(8 * most < h * w * pyramid::bytes_per_pixel(&arch), "{preset}: held {most} B");
            }
        }
    }

    #[test]
    fn a_streamed_region_equals_the_whole_region_bit_for_bit() {
        use crate::model::ScaleBlend;
        let cases = [
            ("balanced", ScaleBlend::Lerp, false, 0),
            ("compact", ScaleBlend::Lerp, false, 1),
            ("balanced", ScaleBlend::Detail, false, 2),
            ("balanced", ScaleBlend::Lerp, true, 3),
        ];
        for (preset, blend, gain, seed) in cases {
            let shipped = Model::resolve(preset).unwrap();
            let arch = Architecture { blend, gain, ..shipped.arch };
            // A gain needs weights that move it: Xavier's.
            let model = if gain { Model::xavier(arch, seed).unwrap() } else { shipped };
            let (w, h) = (64, 6 * arch.alignment().max(32));
            let mut rng = crate::rng::SplitMix64(seed);
            let input: Vec<f32> = (0..INPUT_CHANNELS * w * h).map(|_| rng.uniform_f32() - 0.5).collect();
            // Sparse bright samples, so the clamp and the kernels have outliers to handle;
            // and a variance where the clamp reads one (`balanced`'s), large and small.
            let channels = if arch.clamp.reads_variance() { 4 } else { 3 };
            let noisy: Vec<f32> = (0..channels * w * h)
                .map(|_| if rng.uniform_f32() < 0.02 { 50.0 } else { rng.uniform_f32() })
                .collect();
            let weights = Weights::new(&arch, &model.specular).unwrap();
            let whole = pyramid::forward(&arch, &weights, input.clone(), noisy.clone(), w, h);
            // Both steps a frame's width may choose ([`step_rows`]).
            for (rows_per_push, step) in [(7, 16), (7, 32), (32, 16), (h, 32)] {
                let mut s = Stream::new(&arch, &weights, w, h);
                s.step = step;
                let mut got = vec![Vec::new(); 3];
                let mut y = 0;
                while y < h {
                    let n = rows_per_push.min(h - y);
                    let part = |planes: &[f32], c: usize| {
                        let mut v = Vec::with_capacity(c * n * w);
                        for ch in 0..c {
                            v.extend_from_slice(&planes[(ch * h + y) * w..(ch * h + y + n) * w]);
                        }
                        Planes::from_vec(c, w, n, v)
                    };
                    s.push(part(&input, INPUT_CHANNELS), part(&noisy, channels));
                    while let Some((first, rows)) = s.take() {
                        assert_eq!(first * w, got[0].len(), "rows in order");
                        for (c, g) in got.iter_mut().enumerate() {
                            g.extend_from_slice(rows.plane(c));
                        }
                    }
                    y += n;
                }
                for c in 0..3 {
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert!(
                        bits(&got[c]) == bits(&whole[c]),
                        "{preset} ({blend:?}, gain {gain}), {rows_per_push} rows a push, steps of {step}: channel {c} differs"
                    );
                }
            }
        }
    }
}
