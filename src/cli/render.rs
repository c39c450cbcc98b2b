//! `kpcn render`, `kpcn scenes` and `kpcn dataset`: the simulator's commands.

use anyhow::{Context, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use kpcn::io::WriteOptions;
use kpcn::sim::families::{FAMILIES, generate};
use kpcn::sim::film::PixelFilter;
use kpcn::sim::rng::Sampler;
use kpcn::sim::scene::SceneDesc;
use kpcn::sim::{RenderOptions, Written, render_to_dir};
use kpcn::train::records::{ManifestRow, read_manifest, write_manifest};
use std::path::{Path, PathBuf};

/// Options shared by `render` and `dataset`.
#[derive(Debug, Args, Clone)]
pub struct SamplingArgs {
    /// Sample counts to write, comma-separated; each ≥ 2 (a variance needs two samples).
    /// All come from one run: the 16-spp frame holds the first 16 samples of the 64-spp one.
    #[arg(long, default_value = "4,16,64", value_delimiter = ',', value_name = "N,N,…")]
    pub spp: Vec<u32>,
    /// Also render an independent reference (different random streams) with this many samples.
    #[arg(long, value_name = "N")]
    pub reference_spp: Option<u32>,
    /// Film size.
    #[arg(long, default_value = "320x180", value_parser = parse_resolution, value_name = "WxH")]
    pub resolution: (usize, usize),
    /// Monte Carlo random stream: render one permutation independently many times.
    #[arg(long, default_value_t = 0, value_name = "S")]
    pub sample_seed: u64,
    /// Pixel filter, sampled by importance as Cycles does: `blackman-harris` (Cycles'
    /// default, ±1.5 px), `blackman-harris:WIDTH`, or `box` (uniform over the pixel).
    #[arg(long, default_value = "blackman-harris", value_parser = PixelFilter::parse, value_name = "FILTER")]
    pub pixel_filter: PixelFilter,
    /// Sample placement: `sobol` (scrambled low-discrepancy points, like production
    /// renderers, in 4 independent scrambles per pixel, whose spread gives the written
    /// variances) or `random` (independent samples, like the Cycles layout's independent
    /// 1-spp renders). Either way the variances match the frames' real error.
    #[arg(long, default_value = "sobol", value_parser = parse_sampler, value_name = "SAMPLER")]
    pub sampler: Sampler,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Refuse to overwrite existing files.
    #[arg(long)]
    pub no_clobber: bool,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Arguments of `kpcn render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// A TOML scene file (see `kpcn scenes --example`); or use --family.
    #[arg(value_name = "SCENE.toml", required_unless_present = "family", conflicts_with = "family")]
    pub scene: Option<PathBuf>,
    /// A scene family (`kpcn scenes` lists them).
    #[arg(long, value_name = "NAME")]
    pub family: Option<String>,
    /// Which permutation of the family.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub seed: u64,
    /// Output folder.
    #[arg(short, long, value_name = "DIR")]
    pub output: PathBuf,
    #[command(flatten)]
    pub sampling: SamplingArgs,
}

/// Arguments of `kpcn scenes`.
#[derive(Debug, Args)]
pub struct ScenesArgs {
    /// Print permutation --seed of this family as a TOML scene file.
    #[arg(long, value_name = "NAME")]
    pub dump: Option<String>,
    /// Permutation for --dump.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print a complete example scene file.
    #[arg(long)]
    pub example: bool,
}

/// Arguments of `kpcn dataset`.
#[derive(Debug, Args)]
pub struct DatasetArgs {
    /// Output folder; gets one sub-folder per scene and `manifest.csv`.
    #[arg(short, long, value_name = "DIR")]
    pub output: PathBuf,
    /// Permutations per family.
    #[arg(long, default_value_t = 4, value_name = "N")]
    pub count: u64,
    /// First permutation seed.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub first_seed: u64,
    /// Families, comma-separated, or `all`.
    #[arg(long, default_value = "all", value_delimiter = ',')]
    pub families: Vec<String>,
    #[command(flatten)]
    pub sampling: SamplingArgs,
}

/// A clap parser for `--sampler`.
fn parse_sampler(s: &str) -> Result<Sampler, String> {
    [Sampler::Sobol, Sampler::Random]
        .into_iter()
        .find(|k| k.name() == s)
        .ok_or_else(|| format!("sampler `{s}`: use sobol or random"))
}

/// A clap parser for `WxH`.
pub(super) fn parse_resolution(s: &str) -> Result<(usize, usize), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("`{s}` is not WxH, e.g. 320x180"))?;
    let p = |v: &str| v.trim().parse::<usize>().ok().filter(|&n| n > 0 && n <= 16384);
    match (p(w), p(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!("`{s}` is not WxH with sizes 1…16384, e.g. 320x180")),
    }
}

impl SamplingArgs {
    fn options(&self) -> anyhow::Result<RenderOptions> {
        if self.spp.is_empty() || self.spp.iter().any(|&n| n < 2) {
            bail!("--spp {:?}: every sample count must be at least 2 — a variance needs two samples", self.spp);
        }
        if self.reference_spp.is_some_and(|n| n < 2) {
            bail!("--reference-spp must be at least 2");
        }
        Ok(RenderOptions {
            filter: self.pixel_filter,
            sampler: self.sampler,
            ..RenderOptions::new(self.resolution.0, self.resolution.1, self.spp.clone(), self.sample_seed)
        })
    }

    fn pool(&self) -> anyhow::Result<rayon::ThreadPool> {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(n) = super::threads(self.threads, self.quiet) {
            b = b.num_threads(n);
        }
        b.build().context("cannot start worker threads")
    }

    fn render(&self, desc: &SceneDesc, dir: &Path) -> anyhow::Result<Written> {
        let opts = self.options()?;
        let max = *opts.checkpoints.iter().max().unwrap_or(&1) as u64 + self.reference_spp.unwrap_or(0) as u64;
        let total = (opts.width * opts.height) as u64 * max;
        let bar = if self.quiet { ProgressBar::hidden() } else { ProgressBar::new(total) };
        bar.set_style(
            ProgressStyle::with_template("{msg:>14} [{bar:30}] {percent:>3}% {per_sec} samples, ETA {eta}")
                .expect("valid template")
                .progress_chars("=> "),
        );
        bar.set_message(desc.name.clone());
        let write = WriteOptions { no_clobber: self.no_clobber, ..WriteOptions::default() };
        let done =
            self.pool()?.install(|| render_to_dir(desc, &opts, self.reference_spp, dir, &write, &|n| bar.inc(n)));
        bar.finish_and_clear();
        Ok(done?)
    }
}

fn report(w: &Written, pixels: usize) {
    let spp = w.noisy.iter().map(|n| n.0).max().unwrap_or(0) as f64;
    println!(
        "{} frames in {:.2} s ({:.2} Msamples/s)",
        w.noisy.len(),
        w.noisy_seconds,
        pixels as f64 * spp / w.noisy_seconds.max(1e-9) / 1e6
    );
    for (_, p) in &w.noisy {
        println!("  {}", p.display());
    }
    if let Some(r) = &w.reference {
        println!("  {} (reference, {:.2} s)", r.display(), w.reference_seconds);
    }
}

fn family(name: &str, seed: u64) -> anyhow::Result<SceneDesc> {
    generate(name, seed).with_context(|| {
        let names: Vec<&str> = FAMILIES.iter().map(|f| f.0).collect();
        format!("unknown scene family `{name}` — choose one of {}", names.join(", "))
    })
}

/// Runs `kpcn render`.
pub fn run_render(args: &RenderArgs) -> anyhow::Result<()> {
    let desc = match (&args.scene, &args.family) {
        (Some(path), _) => SceneDesc::load(path)?,
        (None, Some(f)) => family(f, args.seed)?,
        (None, None) => bail!("give a scene file or --family NAME"),
    };
    let w = args.sampling.render(&desc, &args.output)?;
    report(&w, args.sampling.resolution.0 * args.sampling.resolution.1);
    Ok(())
}

const EXAMPLE_HEADER: &str = "\
# A kpcn scene file. The renderer simulates only the effects listed in `effects`:
#   depth_of_field (camera aperture > 0), glossy (conductor, plastic, rough dielectric),
#   transmission (dielectric), environment, sun, textures (checker, noise, stripes, wood,
#   marble), area_lights (emissive materials), point_lights (point/spot), indirect
#   (paths past the first bounce; without it, direct lighting only).
# Shapes: sphere, quad, box, torus, cylinder (unit size; place them with translate,
# rotate in degrees, scale). Material types: diffuse, conductor, plastic, dielectric, emissive.";

/// Runs `kpcn scenes`.
pub fn run_scenes(args: &ScenesArgs) -> anyhow::Result<()> {
    if args.example {
        println!("{EXAMPLE_HEADER}");
        print!("{}", family("cornell", 0)?.to_toml());
    } else if let Some(f) = &args.dump {
        print!("{}", family(f, args.seed)?.to_toml());
    } else {
        println!("Scene families (kpcn render --family NAME --seed N):");
        for (name, about) in FAMILIES {
            let effects: Vec<&str> = family(name, 0)?.effects.iter().map(|e| e.name()).collect();
            println!("  {name:<10} {about}\n  {:<10} effects of seed 0: {}", "", effects.join(", "));
        }
    }
    Ok(())
}

/// Runs `kpcn dataset`: families × permutations, resumable, with a manifest.
pub fn run_dataset(args: &DatasetArgs) -> anyhow::Result<()> {
    let families: Vec<&str> = if args.families.iter().any(|f| f == "all") {
        FAMILIES.iter().map(|f| f.0).collect()
    } else {
        args.families.iter().map(String::as_str).collect()
    };
    let manifest_path = args.output.join("manifest.csv");
    // An existing manifest is extended: its scenes stay listed, and a scene already there
    // with the same sample counts, sample seed and files on disk is not rendered again, so
    // an interrupted run resumes and a dataset grows family by family.
    let mut rows: Vec<ManifestRow> = if manifest_path.is_file() {
        read_manifest(&manifest_path).with_context(|| {
            format!("{}: cannot extend this dataset (move it away to start afresh)", manifest_path.display())
        })?
    } else {
        Vec::new()
    };
    let mut wanted = args.sampling.spp.clone();
    wanted.sort_unstable();
    let t = std::time::Instant::now();
    let (mut rendered, mut kept) = (0usize, 0usize);
    for f in &families {
        for seed in args.first_seed..args.first_seed + args.count {
            let desc = family(f, seed)?;
            let listed: Vec<&ManifestRow> = rows.iter().filter(|r| r.scene == desc.name).collect();
            let mut spps: Vec<u32> = listed.iter().map(|r| r.spp).collect();
            spps.sort_unstable();
            let complete = spps == wanted
                && listed.iter().all(|r| {
                    r.sample_seed == args.sampling.sample_seed
                        && args.output.join(&r.file).is_file()
                        && (args.sampling.reference_spp.is_none() || args.output.join(&r.reference).is_file())
                });
            if complete {
                kept += 1;
                continue;
            }
            let dir = args.output.join(&desc.name);
            let w = args.sampling.render(&desc, &dir)?;
            rows.retain(|r| r.scene != desc.name);
            let rel = |p: &Path| p.strip_prefix(&args.output).unwrap_or(p).display().to_string();
            let reference = w.reference.as_deref().map(rel).unwrap_or_default();
            for (spp, p) in &w.noisy {
                rows.push(ManifestRow {
                    scene: desc.name.clone(),
                    family: f.to_string(),
                    seed,
                    sample_seed: args.sampling.sample_seed,
                    spp: *spp,
                    file: rel(p),
                    reference: reference.clone(),
                    render_seconds: w.noisy_seconds,
                });
            }
            rendered += 1;
            // Rewritten after every scene, so an interrupted run keeps a valid manifest.
            write_manifest(&manifest_path, &rows)?;
        }
    }
    if kept > 0 {
        println!("{kept} scenes already in {} with these settings: kept", manifest_path.display());
    }
    println!(
        "{rendered} scenes rendered in {:.1} s; manifest {} lists {} frames",
        t.elapsed().as_secs_f64(),
        manifest_path.display(),
        rows.len()
    );
    Ok(())
}
