//! The public pipeline: `Denoiser::new(model, options)` and `denoise(&inputs, progress)`.
//!
//! frame → features → per tile: network (+ kernels) per branch → recomposition
//! `(albedo + ε) ⊙ d̂ + ŝ` (`exp(ŝ) − 1` for log-specular models). Safe to share between
//! threads (`&self`); the work runs in the denoiser's own rayon pool, so a host
//! application's pool is left alone.

use crate::features::{Branch, EPSILON, Features, FrameStats, INPUT_CHANNELS, sanitize};
use crate::io::layout::{KpcnInputs, Remainder};
use crate::kernel;
use crate::model::{Design, Exposure, Kind, Model, ModelError, Specular};
use crate::tile::{self, Tile};
use candle_core::{Device, Tensor};
use rayon::prelude::*;
use std::borrow::Cow;

mod bands;
mod bounds;
mod choice;
mod file;
mod request;
mod stream;

pub use bands::Bands;
use bounds::Bounds;
pub use choice::Denoisers;
pub use file::{FileError, FileJob, FileOptions, FileReport, Stages, check_output};
pub use request::{FileRequest, Note, Outcome, ViewLayers};

/// How to run.
#[derive(Debug, Clone)]
pub struct Options {
    /// Worker threads (default: all cores). More than [`max_threads`] are capped to it.
    pub threads: Option<usize>,
    /// Working-memory budget for one tile's network evaluation, in MB.
    pub max_memory_mb: usize,
    /// Force a tile side (testing; normally derived from the budget).
    pub tile_size: Option<usize>,
}

impl Default for Options {
    fn default() -> Self {
        Options { threads: None, max_memory_mb: 512, tile_size: None }
    }
}

/// The most worker threads a denoiser starts: 4 per available core. More only thrash (a
/// request for 10,000 threads once ran for minutes at a load average of 500).
pub fn max_threads() -> usize {
    4 * std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Progress: tiles done of total.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Progress {
    /// Tiles finished.
    pub done: usize,
    /// Tiles in the frame.
    pub total: usize,
}

/// Errors of a denoise call.
#[derive(Debug, thiserror::Error)]
pub enum DenoiseError {
    /// The network failed.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The progress callback asked to stop.
    #[error("cancelled")]
    Cancelled,
    /// The thread pool could not start.
    #[error("cannot start {0} worker threads")]
    Threads(usize),
    /// An empty frame.
    #[error("the frame is empty (0 pixels)")]
    Empty,
    /// The working memory could not be had: refused before any work, instead of an abort
    /// half-way through.
    #[error("out of memory: the denoise needs about {} MB of working memory and the process cannot get it — lower --max-memory (the C ABI's max_memory_mb, the plugins' max_memory) or free memory; the input itself is fine", .0 >> 20)]
    OutOfMemory(usize),
}

/// Checks that `bytes` of working memory can be had ([`kernel::buffers::can_allocate`]):
/// a denoise that would run out half-way is refused before it starts with
/// [`DenoiseError::OutOfMemory`].
pub fn reserve_working_memory(bytes: usize) -> Result<(), DenoiseError> {
    // A quarter more: the allocator's own overhead and the small buffers around the big ones.
    let bytes = bytes.saturating_add(bytes / 4);
    if kernel::buffers::can_allocate(bytes) { Ok(()) } else { Err(DenoiseError::OutOfMemory(bytes)) }
}

/// A denoised frame: colour and the two components it is the exact sum of.
#[derive(Debug, Clone, PartialEq)]
pub struct Denoised {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Denoised beauty = diffuse + specular.
    pub color: [Vec<f32>; 3],
    /// Denoised diffuse, `(albedo + ε) ⊙ d̂`.
    pub diffuse: [Vec<f32>; 3],
    /// Denoised specular radiance.
    pub specular: [Vec<f32>; 3],
}

/// One of a [`Denoised`]'s results, as the outputs that carry it name it (a file's
/// `NAME`, `NAME_diffuse`, `NAME_specular`; the C ABI's `output`, `outputDiffuse`,
/// `outputSpecular`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Component {
    /// The colour.
    Color,
    /// Its diffuse part.
    Diffuse,
    /// Its specular part (the rest of the colour).
    Specular,
}

impl Denoised {
    /// Rows `rows` of it.
    fn rows(self, rows: std::ops::Range<usize>) -> Denoised {
        let (w, h) = (self.width, rows.len());
        let cut = |p: [Vec<f32>; 3]| p.map(|v| v[rows.start * w..rows.end * w].to_vec());
        Denoised {
            width: w,
            height: h,
            color: cut(self.color),
            diffuse: cut(self.diffuse),
            specular: cut(self.specular),
        }
    }

    /// The planes of `component`.
    pub fn component(&self, component: Component) -> &[Vec<f32>; 3] {
        match component {
            Component::Color => &self.color,
            Component::Diffuse => &self.diffuse,
            Component::Specular => &self.specular,
        }
    }

    /// Adds what the beauty held beyond diffuse + specular, undenoised, to the specular
    /// (as Cycles' specular, the beauty minus the diffuse, holds emission) and so to the
    /// colour, which stays exactly diffuse + specular.
    pub fn carry(&mut self, remainder: &Remainder) {
        let Some(planes) = &remainder.planes else { return };
        for (c, r) in planes.iter().enumerate() {
            for (((col, d), s), r) in self.color[c].iter_mut().zip(&self.diffuse[c]).zip(&mut self.specular[c]).zip(r) {
                *s += r;
                *col = d + *s;
            }
        }
    }
}

/// A model plus how to run it.
pub struct Denoiser {
    model: Model,
    options: Options,
    pool: rayon::ThreadPool,
    /// The diffuse and specular weights as plain arrays, for a multi-scale model.
    pyramid: Option<[crate::model::pyramid::Weights; 2]>,
}

impl Denoiser {
    /// A denoiser running `model`.
    pub fn new(model: Model, options: Options) -> Result<Denoiser, DenoiseError> {
        let mut b = rayon::ThreadPoolBuilder::new().thread_name(|i| format!("kpcn-{i}"));
        if let Some(n) = options.threads {
            b = b.num_threads(n.clamp(1, max_threads()));
        }
        // The weights are copied into plain arrays below: checked first, so that a process
        // short of memory gets an error instead of an abort.
        let weights: usize = model.arch.layer_shapes().iter().map(|&(o, i, k)| o * (i * k * k + 1)).sum();
        let bytes = 2 * 2 * 4 * weights + crate::model::LOADING_HEADROOM;
        if !kernel::buffers::can_allocate(bytes) {
            return Err(ModelError::OutOfMemory(bytes).into());
        }
        let pool = b.build().map_err(|_| DenoiseError::Threads(options.threads.unwrap_or(0)))?;
        let pyramid = match model.arch.design {
            Design::MultiScale => {
                let w = |b| crate::model::pyramid::Weights::new(&model.arch, b);
                Some([w(&model.diffuse)?, w(&model.specular)?])
            }
            Design::Flat => None,
        };
        Ok(Denoiser { model, options, pool, pyramid })
    }

    /// Whether `width`-wide frames run through the network as one stream of rows down the
    /// frame: a multi-scale model's do when both branches' streams fit `max_memory_mb`;
    /// narrower budgets run the bands in tiles, with context rows.
    pub fn streams(&self, width: usize) -> bool {
        self.pyramid.is_some() && self.stream_bytes(width) <= self.options.max_memory_mb << 20
    }

    /// What both branches' streams hold on a `width`-wide frame.
    fn stream_bytes(&self, width: usize) -> usize {
        let (rw, held) = self.stream_region(width);
        2 * self.model.arch.region_bytes(rw, held, rw, held)
    }

    /// The width of the region a stream runs down on a `width`-wide frame (the frame with
    /// the network's reach each side), and the rows it holds at most.
    fn stream_region(&self, width: usize) -> (usize, usize) {
        let (_, rw, _) = self.reach().columns(0, width, width);
        (rw, crate::model::stream::held_rows(&self.model.arch, rw))
    }

    /// The threads it runs on.
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// How far a tile's region reaches beyond it (the network's context), for
    /// [`tile::size_for_regions`] and the multi-scale regions.
    pub fn reach(&self) -> tile::Reach {
        let arch = &self.model.arch;
        let radius = arch.feature_radius().max(arch.kernel_radius());
        match arch.design {
            Design::MultiScale => tile::Reach {
                radius,
                column_radius: radius.max(crate::model::multiscale::column_radius(arch)),
                border: arch.border_radius(),
                align: arch.alignment(),
            },
            Design::Flat => tile::Reach::square(radius, radius, arch.alignment()),
        }
    }

    /// The tiles of rows `rows` of a `width`×`total_rows` frame (or band with context
    /// rows): `Options::tile_size` squares when given, else the sizes of least work within
    /// `max_memory_mb` ([`tile::size_for_regions`]). Positions are relative to `rows.start`.
    pub fn tiles(&self, width: usize, rows: std::ops::Range<usize>, total_rows: usize) -> Vec<Tile> {
        self.tiles_within(width, rows, total_rows, self.options.max_memory_mb << 20)
    }

    /// The tiles [`Denoiser::denoise_band`] runs: [`Denoiser::tiles`] within what the
    /// band's features leave of `max_memory_mb` (at least a quarter of it), so that a band
    /// and its tiles share the budget.
    pub fn band_tiles(&self, width: usize, rows: std::ops::Range<usize>, total_rows: usize) -> Vec<Tile> {
        let budget = self.options.max_memory_mb << 20;
        let left = budget.saturating_sub(Features::bytes(width, total_rows)).max(budget / 4);
        self.tiles_within(width, rows, total_rows, left)
    }

    fn tiles_within(&self, width: usize, rows: std::ops::Range<usize>, total_rows: usize, budget: usize) -> Vec<Tile> {
        let arch = &self.model.arch;
        // Never tiles smaller than twice the network's reach, whose regions would be
        // mostly context (the default's 192 px at a 64 MB budget: 32-px tiles, 24× slower):
        // over budget rather than several times slower, as bands are.
        let side = (2 * self.reach().column_radius).next_multiple_of(arch.alignment());
        let budget = budget.max(BRANCHES_AT_ONCE * arch.region_bytes(2 * side, 2 * side, side, side));
        let h = rows.end.saturating_sub(rows.start);
        let (tw, th) = match self.options.tile_size {
            Some(t) => (t.next_multiple_of(arch.alignment()), t.next_multiple_of(arch.alignment())),
            None => tile::size_for_regions(
                tile::Axis::whole(width),
                tile::Axis { start: rows.start, len: h, total: total_rows },
                &self.reach(),
                16usize.max(arch.alignment()),
                |rw, rh, tw, th| BRANCHES_AT_ONCE * arch.region_bytes(rw, rh, tw, th),
                budget,
            ),
        };
        tile::plan(width, h, tw, th)
    }

    /// Working bytes of a band of `total_rows` rows (context included) of a `width`-wide
    /// frame whose `rows` are denoised, beyond its inputs: the features, the largest tile's
    /// network evaluation, and the results. [`Denoiser::denoise`] on a whole frame is one
    /// band.
    pub fn working_bytes(&self, width: usize, rows: std::ops::Range<usize>, total_rows: usize) -> usize {
        if self.streams(width) {
            // Both branches' streams, their output rows held until a band is complete (as
            // many as a stream holds, and the next band's where its diffuse output reads
            // them), and a band's result of nine planes.
            let (_, held) = self.stream_region(width);
            let next = if Bounds::reads_neighbours(&self.model.arch) { rows.len() } else { 0 };
            return Features::bytes(width, total_rows)
                + self.stream_bytes(width)
                + width * (6 * (held + next) + 9 * rows.len()) * 4;
        }
        let rows = self.diffuse_rows(rows, total_rows);
        let tile =
            self.band_tiles(width, rows.clone(), total_rows).iter().map(|t| self.tile_bytes(t)).max().unwrap_or(0);
        // Three results of three planes each.
        Features::bytes(width, total_rows) + tile + width * rows.len() * 4 * 9
    }

    /// The network's working bytes on tile `t` (its region with context).
    fn tile_bytes(&self, t: &Tile) -> usize {
        let r = self.reach();
        BRANCHES_AT_ONCE * self.model.arch.region_bytes(t.w + 2 * r.column_radius, t.h + 2 * r.radius, t.w, t.h)
    }

    /// Denoises one frame. `progress` is called after every tile, on the calling thread;
    /// returning `false` cancels.
    pub fn denoise(&self, inputs: &KpcnInputs, progress: &dyn Fn(Progress) -> bool) -> Result<Denoised, DenoiseError> {
        if inputs.width == 0 || inputs.height == 0 {
            return Err(DenoiseError::Empty);
        }
        reserve_working_memory(self.working_bytes(inputs.width, 0..inputs.height, inputs.height))?;
        let mut d = self.denoise_features(&self.features(Cow::Borrowed(inputs), None), progress)?;
        d.carry(&inputs.remainder(0..inputs.height));
        Ok(d)
    }

    /// Preprocesses `inputs` in this denoiser's threads; `whole` holds the whole frame's
    /// statistics when `inputs` is a band of it (measured when [`Denoiser::auto_exposed`]).
    /// Owned inputs are changed in place where the model needs it; borrowed ones are copied
    /// only then.
    pub fn features(&self, inputs: Cow<'_, KpcnInputs>, whole: Option<FrameStats>) -> Features {
        self.pool.install(|| self.model.arch.preprocessing().features(inputs, whole))
    }

    /// Whether the model sees auto-exposed radiance, so that a streamed frame's exposure
    /// must be measured over the whole frame first.
    pub fn auto_exposed(&self) -> bool {
        self.model.arch.exposure == Exposure::Auto
    }

    /// Denoises already preprocessed features (the trainer validates this way).
    pub fn denoise_features(
        &self,
        f: &Features,
        progress: &dyn Fn(Progress) -> bool,
    ) -> Result<Denoised, DenoiseError> {
        self.denoise_rows(f, 0..f.height, progress)
    }

    /// Denoises rows `rows` of `f`; rows outside it serve as context only. A band of a
    /// frame with [`Denoiser::halo`] context rows on each side (or the frame edge) gives
    /// exactly the rows the whole frame would.
    pub fn denoise_rows(
        &self,
        f: &Features,
        rows: std::ops::Range<usize>,
        progress: &dyn Fn(Progress) -> bool,
    ) -> Result<Denoised, DenoiseError> {
        self.denoise_tiles(f, rows, Self::tiles, progress)
    }

    /// [`Denoiser::denoise_rows`] of a band of a streamed frame, in [`Denoiser::band_tiles`].
    pub fn denoise_band(
        &self,
        f: &Features,
        rows: std::ops::Range<usize>,
        progress: &dyn Fn(Progress) -> bool,
    ) -> Result<Denoised, DenoiseError> {
        self.denoise_tiles(f, rows, Self::band_tiles, progress)
    }

    fn denoise_tiles(
        &self,
        f: &Features,
        rows: std::ops::Range<usize>,
        plan: fn(&Self, usize, std::ops::Range<usize>, usize) -> Vec<Tile>,
        progress: &dyn Fn(Progress) -> bool,
    ) -> Result<Denoised, DenoiseError> {
        let w = f.width;
        let rows = rows.start..rows.end.min(f.height);
        if w == 0 || rows.is_empty() {
            return Err(DenoiseError::Empty);
        }
        // The rows whose diffuse output that of `rows` reads are denoised too.
        let (y0, h) = {
            let e = self.diffuse_rows(rows.clone(), f.height);
            (e.start, e.len())
        };
        // The tile loop runs on the caller's thread, so `progress` does too (a C host's
        // callback may touch its UI); each tile's work runs in the pool.
        let tiles = plan(self, w, y0..y0 + h, f.height);
        // Idle activations are kept for reuse within what the budget leaves beside the
        // features and the largest tile, and a quarter of that tile at most.
        let tile = tiles.iter().map(|t| self.tile_bytes(t)).max().unwrap_or(0);
        let left = (self.options.max_memory_mb << 20).saturating_sub(Features::bytes(w, f.height) + tile);
        let _reuse = kernel::buffers::Lease::new(left.min(tile / 4));
        let mut d_hat = [vec![0f32; w * h], vec![0f32; w * h], vec![0f32; w * h]];
        let mut s_hat = d_hat.clone();
        for (i, t) in tiles.iter().enumerate() {
            let t_frame = Tile { y: t.y + y0, ..*t };
            let (d, s) = self.pool.install(|| -> Result<_, DenoiseError> {
                // The branches side by side: a streamed branch alone leaves cores idle
                // between its small steps.
                let (d, s) = rayon::join(
                    || self.branch(f, Branch::Diffuse, &t_frame),
                    || self.branch(f, Branch::Specular, &t_frame),
                );
                Ok((d?, s?))
            })?;
            for c in 0..3 {
                for y in 0..t.h {
                    let at = (t.y + y) * w + t.x;
                    d_hat[c][at..at + t.w].copy_from_slice(&d[c][y * t.w..(y + 1) * t.w]);
                    s_hat[c][at..at + t.w].copy_from_slice(&s[c][y * t.w..(y + 1) * t.w]);
                }
            }
            if !progress(Progress { done: i + 1, total: tiles.len() }) {
                return Err(DenoiseError::Cancelled);
            }
        }
        let albedo = std::array::from_fn(|c| f.albedo[c][y0 * w..(y0 + h) * w].to_vec());
        let bounds = self.pool.install(|| Bounds::of(&self.model.arch, f, y0..y0 + h));
        let glow = self.pool.install(|| {
            let take = bounds.bound_diffuse(&albedo, &mut d_hat)?;
            Some(take.spread(w, bounds.spread?))
        });
        self.pool.install(|| bounds.restore_detail(w, &mut d_hat));
        let d = self.pool.install(|| {
            recompose(&albedo, d_hat, &s_hat, (w, h), self.model.arch.specular, f.exposure, &bounds, glow.as_ref())
        });
        Ok(if h == rows.len() { d } else { d.rows(rows.start - y0..rows.end - y0) })
    }

    /// Rows `rows` of a region `total_rows` tall, with the rows beyond them whose diffuse
    /// output theirs reads (`diffuse_margin`): the rows a band denoises.
    pub(crate) fn diffuse_rows(&self, rows: std::ops::Range<usize>, total_rows: usize) -> std::ops::Range<usize> {
        let r = self.diffuse_margin();
        rows.start.saturating_sub(r)..(rows.end + r).min(total_rows)
    }

    /// The rows a band denoises beyond its own for its diffuse output
    /// ([`Bounds::diffuse_context`]), rounded up to the network's pooling grid: the rows it
    /// denoises start on the grid, as a band does, so each comes out as in the whole frame.
    fn diffuse_margin(&self) -> usize {
        Bounds::diffuse_context(&self.model.arch).next_multiple_of(self.model.arch.alignment())
    }

    /// Context rows each band of a streamed `width`-wide frame is read with: where the
    /// network runs down the whole frame ([`Denoiser::streams`]), only its features'
    /// context ([`crate::features::CONTEXT`]) and what its bounds read beyond a band
    /// (`Bounds::context`); else the model's reach
    /// ([`crate::model::Architecture::reach`]), or that if it is more.
    pub fn halo(&self, width: usize) -> usize {
        let bounds = crate::features::CONTEXT + Bounds::context(&self.model.arch);
        if self.streams(width) {
            return bounds;
        }
        // A band also denoises the rows its diffuse output reads (`diffuse_rows`), each
        // with its own context.
        self.model.arch.reach().max(bounds) + self.diffuse_margin()
    }

    /// One branch on one tile: d̂ or ŝ for the tile's pixels.
    fn branch(&self, f: &Features, b: Branch, t: &Tile) -> Result<[Vec<f32>; 3], DenoiseError> {
        let arch = &self.model.arch;
        if arch.design == Design::MultiScale {
            return self.branch_multiscale(f, b, t);
        }
        let (rf, rk) = (arch.feature_radius() as isize, arch.kernel_radius() as isize);
        let (iw, ih) = (t.w + 2 * rf as usize, t.h + 2 * rf as usize);
        let mut x = f.branch_input(b, t.x as isize - rf, t.y as isize - rf, iw, ih);
        arch.prepare_input(b, &mut x);
        let x = Tensor::from_vec(x, (1, INPUT_CHANNELS, ih, iw), &Device::Cpu).map_err(ModelError::from)?;
        let weights = match b {
            Branch::Diffuse => &self.model.diffuse,
            Branch::Specular => &self.model.specular,
        };
        let out = weights.forward(&x)?.flatten_all().and_then(|o| o.to_vec1::<f32>()).map_err(ModelError::from)?;
        let n = t.w * t.h;
        Ok(match arch.kind {
            Kind::Dpcn => [0, 1, 2].map(|c| out[c * n..(c + 1) * n].to_vec()),
            Kind::Kpcn => {
                let (nw, nh) = (t.w + 2 * rk as usize, t.h + 2 * rk as usize);
                let colour = f.colour(b);
                let region =
                    f.region(&colour.each_ref().map(Vec::as_slice), t.x as isize - rk, t.y as isize - rk, nw, nh);
                let m = nw * nh;
                let noisy = [0, 1, 2].map(|c| region[c * m..(c + 1) * m].to_vec());
                kernel::apply(&out, &noisy, arch.kernel_size, t.w, t.h)
            }
        })
    }
}

impl Denoiser {
    /// [`Denoiser::branch`] of a multi-scale network: the tile plus the receptive radius,
    /// but at most [`crate::model::Architecture::border_radius`] beyond the frame's edges,
    /// extended right and down to the pooling grid, streamed through the network in rows
    /// ([`crate::model::stream::Stream`]); the tile's pixels kept. Each end of the region
    /// depends only on the tile's position against the frame, never on the tile size, so
    /// tiles give the whole frame's result.
    fn branch_multiscale(&self, f: &Features, b: Branch, t: &Tile) -> Result<[Vec<f32>; 3], DenoiseError> {
        let arch = &self.model.arch;
        let reach = self.reach();
        let ((x0, rw, ox), (y0, rh, oy)) = (reach.columns(t.x, t.w, f.width), reach.rows(t.y, t.h, f.height));
        let [diffuse, specular] = self.pyramid.as_ref().expect("built in new for a multi-scale model");
        let weights = match b {
            Branch::Diffuse => diffuse,
            Branch::Specular => specular,
        };
        let mut stream = crate::model::stream::Stream::new(arch, weights, rw, rh);
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| Vec::with_capacity(t.w * t.h));
        let win = stream::Window { x0, rw, ox, w: t.w, keep: oy..oy + t.h };
        for y in (0..rh).step_by(stream::PUSH_ROWS) {
            let n = stream::PUSH_ROWS.min(rh - y);
            stream::feed(arch, f, b, &mut stream, &win, (y0 + y as isize, n), &mut out);
        }
        Ok(out)
    }
}

/// Branches a tile evaluates at once: both, side by side ([`Denoiser::denoise_rows`]).
const BRANCHES_AT_ONCE: usize = 2;

/// `(albedo + ε) ⊙ d̂` (`d_hat` already within its ceiling, [`Bounds::bound_diffuse`]) with
/// the `glow` the ceiling's spread brings each pixel, and the specular radiance of `ŝ`
/// ([`Specular::radiance`]) within its bound, both divided by the inputs' `exposure`, and
/// their sum, all finite.
#[allow(clippy::too_many_arguments)]
fn recompose(
    albedo: &[Vec<f32>; 3],
    d_hat: [Vec<f32>; 3],
    s_hat: &[Vec<f32>; 3],
    (w, h): (usize, usize),
    domain: Specular,
    exposure: f32,
    bounds: &Bounds,
    glow: Option<&[Vec<f32>; 3]>,
) -> Denoised {
    // Division by exactly 1 changes nothing, so raw models keep their images bit for bit.
    let diffuse: [Vec<f32>; 3] = std::array::from_fn(|c| {
        let radiance = d_hat[c].par_iter().zip(&albedo[c]).map(|(d, a)| sanitize((a + EPSILON) * d));
        match glow {
            Some(g) => radiance.zip(&g[c]).map(|(d, g)| sanitize(sanitize(d + g) / exposure)).collect(),
            None => radiance.map(|d| sanitize(d / exposure)).collect(),
        }
    });
    let mut specular: [Vec<f32>; 3] =
        std::array::from_fn(|c| s_hat[c].par_iter().map(|&s| domain.radiance(s)).collect());
    if let Some(b) = &bounds.specular {
        b.apply(&mut specular);
    }
    specular.iter_mut().for_each(|p| p.par_iter_mut().for_each(|s| *s = sanitize(*s / exposure)));
    let color = std::array::from_fn(|c| diffuse[c].par_iter().zip(&specular[c]).map(|(d, s)| d + s).collect());
    Denoised { width: w, height: h, color, diffuse, specular }
}
