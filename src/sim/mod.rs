//! The simulator: a small physically based path tracer that writes the layered EXRs the
//! denoiser reads (ARCHITECTURE.md §Layout, §Simulator). Its parts are named for the physics, as in pbrt: `camera`,
//! `geometry` + `bvh`, `material` + `texture`, `light`, `integrator`, `film`; `scene` reads
//! scene files and enforces their declared effects; `families` generates scene permutations.

pub mod bvh;
pub mod camera;
pub mod families;
pub mod film;
pub mod geometry;
pub mod integrator;
pub mod light;
pub mod material;
pub mod rng;
pub mod scene;
pub mod texture;

use crate::io::{Attribute, FrameBuffers, IoError};
use film::{PixelStats, Snapshot};
use integrator::Counters;
use rayon::prelude::*;
use scene::Scene;

/// A tile's pixels: (pixel index, snapshots at each count).
type TilePixels = Vec<(usize, Vec<Snapshot>)>;

/// Tile edge in pixels: the unit of parallel work.
const TILE: usize = 16;

/// How to render.
#[derive(Debug, Clone)]
pub struct RenderOptions {
    /// Film width.
    pub width: usize,
    /// Film height.
    pub height: usize,
    /// Sample counts to write (each ≥ 2, so a variance and a half buffer exist).
    pub checkpoints: Vec<u32>,
    /// Seed of the Monte Carlo random streams.
    pub sample_seed: u64,
    /// Next-event estimation (off = brute-force path tracing, for tests).
    pub nee: bool,
    /// Pixel filter.
    pub filter: film::PixelFilter,
    /// Sample placement.
    pub sampler: rng::Sampler,
}

impl RenderOptions {
    /// Options with next-event estimation, the box filter and independent random samples
    /// (the simulator's original sampling, which tests of its statistics rely on).
    pub fn new(width: usize, height: usize, checkpoints: Vec<u32>, sample_seed: u64) -> RenderOptions {
        RenderOptions {
            width,
            height,
            checkpoints,
            sample_seed,
            nee: true,
            filter: film::PixelFilter::Box,
            sampler: rng::Sampler::Random,
        }
    }

    /// Like [`RenderOptions::new`], sampled as Cycles does by default: a Blackman–Harris
    /// pixel filter 1.5 px wide and scrambled Sobol' points.
    pub fn production(width: usize, height: usize, checkpoints: Vec<u32>, sample_seed: u64) -> RenderOptions {
        RenderOptions {
            filter: film::PixelFilter::default(),
            sampler: rng::Sampler::Sobol,
            ..RenderOptions::new(width, height, checkpoints, sample_seed)
        }
    }
}

/// Frames at each checkpoint and the work done.
pub struct RenderOutput {
    /// (spp, frame), in checkpoint order.
    pub frames: Vec<(u32, FrameBuffers)>,
    /// Rays and lobe work.
    pub counters: Counters,
}

/// Renders `scene`, calling `progress(samples_done)` as tiles finish (from worker threads).
/// Results do not depend on the number of threads.
pub fn render(
    scene: &Scene,
    opts: &RenderOptions,
    attributes: &[Attribute],
    progress: &(dyn Fn(u64) + Sync),
) -> Result<RenderOutput, IoError> {
    let (w, h) = (opts.width, opts.height);
    let counts = film::snapshot_counts(&opts.checkpoints);
    let max_spp = *opts.checkpoints.iter().max().unwrap_or(&1);
    let filter = opts.filter.sampler();
    let tiles: Vec<(usize, usize)> =
        (0..h.div_ceil(TILE)).flat_map(|ty| (0..w.div_ceil(TILE)).map(move |tx| (tx * TILE, ty * TILE))).collect();
    let results: Vec<(TilePixels, Counters)> = tiles
        .par_iter()
        .map(|&(x0, y0)| {
            let mut counters = Counters::default();
            let mut out = Vec::with_capacity(TILE * TILE);
            for y in y0..(y0 + TILE).min(h) {
                for x in x0..(x0 + TILE).min(w) {
                    let pixel = (y * w + x) as u64;
                    let mut stats = PixelStats::new(opts.sampler);
                    let mut snaps = Vec::with_capacity(counts.len());
                    for s in 0..max_spp {
                        let mut rng = rng::Rng::for_pixel_sample(opts.sampler, opts.sample_seed, pixel, s);
                        let [u, v] = rng.uniform2();
                        let (jx, jy) = (filter.jitter(u), filter.jitter(v));
                        let (sx, sy) = ((x as f32 + jx) / w as f32, (y as f32 + jy) / h as f32);
                        let sample = integrator::trace(scene, sx, sy, &mut rng, opts.nee, &mut counters);
                        stats.add(&sample);
                        if counts.contains(&(s + 1)) {
                            snaps.push(stats.snapshot());
                        }
                    }
                    out.push((y * w + x, snaps));
                }
            }
            progress((out.len() as u64) * max_spp as u64);
            (out, counters)
        })
        .collect();

    let mut counters = Counters::default();
    let mut snaps: Vec<Vec<Snapshot>> = vec![Vec::new(); w * h];
    for (tile, c) in results {
        counters.add(&c);
        for (i, s) in tile {
            snaps[i] = s;
        }
    }
    let frames = opts
        .checkpoints
        .iter()
        .map(|&spp| film::frame(w, h, spp, &counts, &snaps, attributes).map(|f| (spp, f)))
        .collect::<Result<_, _>>()?;
    Ok(RenderOutput { frames, counters })
}

/// The file name of ARCHITECTURE.md §Layout: `<scene>-<spp zero-padded to 5>spp.exr`.
pub fn frame_file_name(scene: &str, spp: u32) -> String {
    format!("{scene}-{spp:05}spp.exr")
}

/// The reference's random streams are independent of the noisy renders'.
const REFERENCE_SEED_SALT: u64 = 0x5EED_0F2E_F000;

/// Everything a render-to-folder run produced.
#[derive(Debug, Clone)]
pub struct Written {
    /// Noisy frames: (spp, path).
    pub noisy: Vec<(u32, std::path::PathBuf)>,
    /// The reference, when asked for.
    pub reference: Option<std::path::PathBuf>,
    /// Seconds spent rendering the noisy frames (all checkpoints come from one run).
    pub noisy_seconds: f64,
    /// Seconds spent on the reference.
    pub reference_seconds: f64,
    /// Work counters of the noisy run.
    pub counters: Counters,
}

/// Renders a scene's checkpoints (and optionally an independent reference with
/// `reference_spp` samples) into `dir`, with the file names of ARCHITECTURE.md §Layout.
pub fn render_to_dir(
    desc: &scene::SceneDesc,
    opts: &RenderOptions,
    reference_spp: Option<u32>,
    dir: &std::path::Path,
    write: &crate::io::WriteOptions,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Written, SimError> {
    let scene = desc.build(opts.width as f32 / opts.height as f32)?;
    std::fs::create_dir_all(dir).map_err(|source| IoError::Fs { path: dir.into(), source })?;
    let effects: Vec<&str> = desc.effects.iter().map(|e| e.name()).collect();
    let mut attrs = vec![
        Attribute::string("kpcn:scene", &desc.name),
        Attribute::string("kpcn:source", concat!("kpcn render ", env!("CARGO_PKG_VERSION"))),
        Attribute::string("kpcn:effects", &effects.join(",")),
        Attribute::string("kpcn:sample_seed", &opts.sample_seed.to_string()),
        Attribute::string("kpcn:pixel_filter", &opts.filter.name()),
        Attribute::string("kpcn:sampler", opts.sampler.name()),
    ];
    let t = std::time::Instant::now();
    let out = render(&scene, opts, &attrs, progress)?;
    let noisy_seconds = t.elapsed().as_secs_f64();
    let mut noisy = Vec::new();
    for (spp, mut fb) in out.frames {
        fb.set_attribute(Attribute::float("kpcn:render_seconds", noisy_seconds as f32));
        let path = dir.join(frame_file_name(&desc.name, spp));
        fb.write(&path, write)?;
        noisy.push((spp, path));
    }
    let (mut reference, mut reference_seconds) = (None, 0.0);
    if let Some(spp) = reference_spp {
        let ref_opts = RenderOptions {
            checkpoints: vec![spp],
            sample_seed: opts.sample_seed ^ REFERENCE_SEED_SALT,
            ..opts.clone()
        };
        attrs[3] = Attribute::string("kpcn:sample_seed", &ref_opts.sample_seed.to_string());
        let t = std::time::Instant::now();
        let r = render(&scene, &ref_opts, &attrs, progress)?;
        reference_seconds = t.elapsed().as_secs_f64();
        let path = dir.join(format!("{}-ref.exr", desc.name));
        if let Some((_, fb)) = r.frames.into_iter().next() {
            fb.write(&path, write)?;
            reference = Some(path);
        }
    }
    Ok(Written { noisy, reference, noisy_seconds, reference_seconds, counters: out.counters })
}

/// Errors of the simulator.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A scene problem.
    #[error(transparent)]
    Scene(#[from] scene::SceneError),
    /// Writing frames.
    #[error(transparent)]
    Io(#[from] IoError),
}
