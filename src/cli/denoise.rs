//! `kpcn denoise`: files and image sequences, a thin shell over `Denoiser`.

use super::Usage;
use super::sequence::{Pattern, gaps, parse_frames};
use anyhow::bail;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use kpcn::denoise::{Denoisers, FileOptions, FileRequest, Note, Options, Progress, ViewLayers, check_output};
use kpcn::io::{FrameReader, WriteOptions};
use kpcn::model::{Model, Quality, registry};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The most frames of a sequence in flight at once (each within its share of
/// `--max-memory`).
const FRAMES_IN_FLIGHT: usize = 2;

/// Arguments of `kpcn denoise`.
#[derive(Debug, Args)]
pub struct DenoiseArgs {
    /// Input EXR, or a sequence pattern: render.####.exr, render.@@@.exr, render.%04d.exr.
    #[arg(value_name = "IN")]
    pub input: String,
    /// Output EXR (a pattern when IN is one). Holds a copy of the input plus the new layer.
    #[arg(short, long, value_name = "OUT")]
    pub output: String,
    /// Frames of a sequence: 1-100, 1-100x5, 1,3,5 (default: every frame whose file exists).
    #[arg(long, value_name = "LIST")]
    pub frames: Option<String>,
    /// Name of the denoised layer (`NAME.R/G/B`). Default: `denoised`, or for Blender
    /// files `<ViewLayer>.Denoised`, which Blender's compositor lists as a pass.
    #[arg(long, value_name = "NAME")]
    pub layer: Option<String>,
    /// Blender view layer to denoise (Cycles layout): a name, or `all` to denoise each one
    /// into its own `<ViewLayer>.Denoised`. Default: the first by name (said when there
    /// are several).
    #[arg(long, value_name = "NAME|all")]
    pub view_layer: Option<String>,
    /// The model: `auto` (picks per file), a shipped model's name, or a .safetensors file.
    #[arg(long, default_value = registry::AUTO, value_name = "MODEL", long_help = model_help())]
    pub model: String,
    /// A rung of the quality ladder instead of --model, like OIDN's quality modes (the
    /// same U-Net at three widths; `kpcn model info RUNG` gives its reach and cost).
    #[arg(long, value_enum, conflicts_with = "model", value_name = "fast|balanced|high")]
    pub quality: Option<Quality>,
    /// Run an untrained preset (its images are useless: it only tests the pipeline).
    #[arg(long)]
    pub allow_untrained: bool,
    /// Also write NAME_diffuse and NAME_specular layers; they add up to NAME exactly.
    #[arg(long)]
    pub aovs: bool,
    /// Write only the new layers (and the metadata), not a copy of every input channel.
    #[arg(long, conflicts_with = "in_place")]
    pub separate: bool,
    /// Allow OUT to be IN itself (the same file, links followed): the denoised layer is
    /// added to the render in place, atomically. Without it, such an OUT is refused.
    #[arg(long)]
    pub in_place: bool,
    /// Channel naming convention; detected when omitted.
    #[arg(long, value_name = "native|cycles|renderman", value_parser = clap::value_parser!(super::info::LayoutArg))]
    pub layout: Option<super::info::LayoutArg>,
    /// Keep going past frames that fail, and report them at the end (exit status stays 1).
    #[arg(long)]
    pub skip_bad_frames: bool,
    /// Print what would be done, do nothing.
    #[arg(short = 'n', long)]
    pub dry_run: bool,
    /// EXR compression of the output: none, rle, zips, zip, piz, pxr24, b44, b44a, dwaa,
    /// dwab. Default: the input's when it is lossless, else zip, so that the channels copied
    /// from a lossy (DWA, B44) input are not re-encoded lossily.
    #[arg(long, value_name = "NAME")]
    pub compression: Option<String>,
    /// Refuse to overwrite existing outputs.
    #[arg(long)]
    pub no_clobber: bool,
    /// Skip frames whose output already exists and is a complete EXR (a farm task re-run
    /// after preemption resumes where it stopped); exit 0 when all are done.
    #[arg(long)]
    pub skip_existing: bool,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Working memory in MB that grows with the frame: a band of rows in flight (its
    /// network inputs and features), the rows the network holds as it streams down the
    /// frame (about half its reach, `kpcn model info`, times the frame's width, for each
    /// branch) and a band being written share it (from twice the default, a sequence keeps
    /// two frames in flight, half each). Where the rest of it holds them, the channels a
    /// band copies to the output are kept from its one decode until it is written (for
    /// 41 channels: a 1920-wide frame at the default, a 3840-wide one from 1024); else
    /// they are decoded again then. Below what the streams need (a 3840-wide frame: about
    /// 390 MB), bands run in tiles with the network's context rows instead, never thinner
    /// than twice the reach: slower, within the budget. Not counted: the process's fixed
    /// cost (program, libraries, model, OpenEXR's row buffers for each decoding and
    /// encoding thread, thread stacks; 200-450 MB), and the diffuse detail step's working
    /// rows (chunks of about 2^18 pixels: 50-80 MB). Measured peak RSS with the default:
    /// 1920x1080 with 41 channels 769-821 MiB, 3840x2160 975-992 MiB (from run to run).
    #[arg(long, default_value_t = 512, value_name = "MB")]
    pub max_memory: usize,
    /// No progress bar or notes, errors only.
    #[arg(short, long)]
    pub quiet: bool,
    /// Per-frame details (layout, estimated variances, tiles, seconds).
    #[arg(short, long)]
    pub verbose: bool,
}

/// The (input, output) pairs to process.
fn jobs(args: &DenoiseArgs) -> anyhow::Result<Vec<(PathBuf, PathBuf)>> {
    match (Pattern::parse(&args.input), Pattern::parse(&args.output)) {
        (None, None) => Ok(vec![(args.input.clone().into(), args.output.clone().into())]),
        (Some(_), None) => Err(Usage(format!(
            "{}: the input is a sequence but the output has no frame field — use e.g. out.####.exr",
            args.output
        ))
        .into()),
        (None, Some(_)) => {
            Err(Usage(format!("{}: the output is a sequence but the input is one file", args.output)).into())
        }
        (Some(i), Some(o)) => {
            let frames = match &args.frames {
                Some(spec) => parse_frames(spec).map_err(|e| Usage(format!("--frames: {e}")))?,
                None => {
                    let found = i.existing_frames();
                    let holes = gaps(&found);
                    if !holes.is_empty() && !args.quiet {
                        let spans: Vec<String> = holes
                            .iter()
                            .map(|&(a, b)| if a == b { a.to_string() } else { format!("{a}-{b}") })
                            .collect();
                        eprintln!(
                            "kpcn: warning: {}: frames {} are missing between {} and {} (they are skipped)",
                            args.input,
                            spans.join(", "),
                            found[0],
                            found[found.len() - 1]
                        );
                    }
                    found
                }
            };
            if frames.is_empty() {
                bail!(
                    "{}: no frames found — check the pattern (its padding must match the files': #### or @@@@ for 0001) or give --frames",
                    args.input
                );
            }
            Ok(frames.into_iter().map(|f| (i.path(f), o.path(f))).collect())
        }
    }
}

/// Refuses, before any work, outputs that cannot be written or that would replace their
/// input without `--in-place` ([`check_output`]); every problem is listed.
fn check_outputs(jobs: &[(PathBuf, PathBuf)], args: &DenoiseArgs) -> anyhow::Result<()> {
    let opts = FileOptions { in_place: args.in_place, separate: args.separate, ..FileOptions::default() };
    let problems: Vec<String> = jobs
        .iter()
        .filter_map(|(input, output)| check_output(input, output, &opts).err())
        .map(|e| e.to_string())
        .collect();
    match problems.len() {
        0 => Ok(()),
        1 => bail!("{}", problems[0]),
        n => bail!("{n} outputs cannot be written:\n  {}", problems.join("\n  ")),
    }
}

/// Runs `kpcn denoise`.
pub fn run(args: &DenoiseArgs) -> anyhow::Result<()> {
    let mut jobs = jobs(args)?;
    let threads = super::threads(args.threads, args.quiet);
    let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
    let request = FileRequest {
        layout: args.layout.map(|l| l.0),
        view_layers: ViewLayers::parse(args.view_layer.as_deref()),
        layer: args.layer.clone(),
        aovs: args.aovs,
        separate: args.separate,
        in_place: args.in_place,
        // The CLI owns its OpenImageIO: outputs compress on the denoiser's threads.
        write: WriteOptions {
            compression: args.compression.clone(),
            no_clobber: args.no_clobber,
            encoders: threads.unwrap_or(cores),
        },
    };
    request.check().map_err(Usage)?;
    if let Some(c) = args.compression.as_deref().filter(|c| !kpcn::io::COMPRESSIONS.contains(c)) {
        return Err(
            Usage(format!("--compression {c}: unknown — use one of {}", kpcn::io::COMPRESSIONS.join(", "))).into()
        );
    }
    check_outputs(&jobs, args)?;
    if args.skip_existing {
        let before = jobs.len();
        jobs.retain(|(_, o)| !FrameReader::is_complete(o));
        if !args.quiet && jobs.len() < before {
            eprintln!("kpcn: skipping {} of {before} frames whose output is complete", before - jobs.len());
        }
        if jobs.is_empty() {
            return Ok(());
        }
    }
    let name = match args.quality {
        Some(q) => q.name(),
        None => args.model.as_str(),
    };
    // `auto` loads its two models below; any other name is one model.
    let model = if name == registry::AUTO { None } else { Some(Model::resolve(name)?) };
    if let Some(m) = model.as_ref().filter(|m| m.is_untrained() && !args.allow_untrained) {
        return Err(Usage(format!(
            "--model {}: an untrained architecture preset ({}) gives useless images — use a shipped model ({}) or a trained .safetensors file, or give --allow-untrained to test the pipeline with it",
            args.model,
            m.description,
            registry::shipped_names()
        ))
        .into());
    }
    if args.dry_run {
        // The same checks as a real run, so `-n` exits as the run would.
        let (mut missing, mut clobbered) = (0, 0);
        for (i, o) in &jobs {
            let note = if !i.exists() {
                missing += 1;
                "  (input missing)"
            } else if args.no_clobber && o.exists() {
                clobbered += 1;
                "  (output exists: --no-clobber refuses it)"
            } else {
                ""
            };
            println!("{} -> {}{note}", i.display(), o.display());
        }
        if missing + clobbered > 0 {
            bail!("the run would fail: {missing} input(s) missing, {clobbered} output(s) refused by --no-clobber");
        }
        return Ok(());
    }
    if let Some(m) = model.as_ref().filter(|m| m.is_untrained() && !args.quiet) {
        eprintln!(
            "kpcn: warning: model `{}` is UNTRAINED ({}): the result is not a useful denoise — use the default or a trained file",
            args.model, m.description
        );
    }
    // A sequence keeps two frames in flight when the budget gives each at least the default
    // budget, so that one frame's reading and writing overlap the other's network. With
    // less, a frame would take more bands (a 1280×720 frame: two at 256 MB, each reading
    // and running context rows twice) and the pair is slower than one frame at a time
    // (measured: BENCHMARKS.md). Bands and tiles do not change the images, so the outputs
    // are the same bits.
    let per_frame = Options::default().max_memory_mb;
    let in_flight = if jobs.len() > 1 { (args.max_memory / per_frame).clamp(1, FRAMES_IN_FLIGHT) } else { 1 };
    let options = Options { threads, max_memory_mb: (args.max_memory / in_flight).max(16), tile_size: None };
    let denoiser = match model {
        Some(m) => Denoisers::one(m, options)?,
        None => Denoisers::auto(options)?,
    };
    let bar = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(jobs.len() as u64 * 1000) };
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {percent:>3}% ETA {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let failed = Mutex::new(Vec::new());
    // Without --skip-bad-frames the run stops at the first bad frame, as frame after frame
    // would: earlier frames in flight finish, later ones are cancelled (nothing written).
    let first_error: Mutex<Option<(usize, anyhow::Error)>> = Mutex::new(None);
    let (next, stop_at, warned) = (AtomicUsize::new(0), AtomicUsize::new(usize::MAX), AtomicBool::new(false));
    // Per frame, thousandths done: the bar shows their sum.
    let done: Vec<AtomicUsize> = jobs.iter().map(|_| AtomicUsize::new(0)).collect();
    // Farm schedulers capture stderr to a file: one line per frame (and per quarter of a
    // long frame) instead of a bar that only a terminal can draw.
    let farm = !args.quiet && !std::io::stderr().is_terminal();
    let work = || {
        loop {
            let k = next.fetch_add(1, Ordering::SeqCst);
            if k >= jobs.len() || k > stop_at.load(Ordering::SeqCst) {
                return;
            }
            let (input, output) = &jobs[k];
            bar.set_message(format!("frame {}/{}", k + 1, jobs.len()));
            let t = std::time::Instant::now();
            let quarter = AtomicUsize::new(0);
            let step = |p: Progress| {
                done[k].store(1000 * p.done / p.total.max(1), Ordering::Relaxed);
                bar.set_position(done.iter().map(|d| d.load(Ordering::Relaxed) as u64).sum());
                let q = 4 * p.done / p.total.max(1);
                if farm && p.total >= 8 && q > quarter.load(Ordering::Relaxed) && q < 4 {
                    quarter.store(q, Ordering::Relaxed);
                    eprintln!("kpcn: frame {}/{} {}: {}%", k + 1, jobs.len(), input.display(), 25 * q);
                }
                // An earlier frame failed: this one stops at its next tile.
                k < stop_at.load(Ordering::SeqCst)
            };
            match denoise_file(&denoiser, &request, args, (input, output), &step, &warned, &bar) {
                Ok(()) => {
                    done[k].store(1000, Ordering::Relaxed);
                    if farm {
                        eprintln!(
                            "kpcn: frame {}/{} {} -> {} ({:.1} s)",
                            k + 1,
                            jobs.len(),
                            input.display(),
                            output.display(),
                            t.elapsed().as_secs_f64()
                        );
                    }
                }
                Err(e) if args.skip_bad_frames => {
                    bar.suspend(|| eprintln!("kpcn: error: {} (skipped)", super::describe_error(&e)));
                    failed.lock().expect("not poisoned").push((k, input.clone()));
                }
                Err(_) if k > stop_at.load(Ordering::SeqCst) => return, // cancelled
                Err(e) => {
                    stop_at.fetch_min(k, Ordering::SeqCst);
                    let mut first = first_error.lock().expect("not poisoned");
                    if first.as_ref().is_none_or(|(at, _)| k < *at) {
                        *first = Some((k, e));
                    }
                    return;
                }
            }
        }
    };
    std::thread::scope(|s| {
        for _ in 1..in_flight {
            s.spawn(work);
        }
        work();
    });
    if let Some((_, e)) = first_error.into_inner().expect("not poisoned") {
        bar.finish_and_clear();
        return Err(e);
    }
    let mut failed = failed.into_inner().expect("not poisoned");
    failed.sort();
    let failed: Vec<PathBuf> = failed.into_iter().map(|(_, p)| p).collect();
    bar.finish_and_clear();
    if !failed.is_empty() {
        let list: Vec<String> = failed.iter().map(|p| p.display().to_string()).collect();
        bail!("{} of {} frames failed: {}", failed.len(), jobs.len(), list.join(", "));
    }
    if !args.quiet && jobs.len() > 1 {
        println!("{} frames denoised", jobs.len());
    }
    Ok(())
}

/// `--model`'s long help, from the registry of shipped models.
fn model_help() -> String {
    let list: String = registry::SHIPPED.iter().map(|m| format!("\n  {:<11} {}", m.name, m.about)).collect();
    format!(
        "The model. `{auto}` (the default) picks per file: `{with}` when the file has per-pixel variances or half buffers, `{without}` when it has neither (Blender's own output). Or a shipped model by name:{list}\n`default` is `{default}`. Or a .safetensors file from `kpcn train`, or with --allow-untrained an untrained architecture preset ({presets}) to test the pipeline. `kpcn model info NAME` describes any of them.",
        auto = registry::AUTO,
        with = registry::auto_choice(true),
        without = registry::auto_choice(false),
        default = registry::DEFAULT,
        presets = registry::PRESETS.map(|p| format!("`{p}`")).join(", "),
    )
}

/// One file (each of its view layers) with the CLI's notes: warnings unless `--quiet`
/// (the estimated variances once per run unless `--verbose`), the rest with `--verbose`.
fn denoise_file(
    denoiser: &Denoisers,
    request: &FileRequest,
    args: &DenoiseArgs,
    (input, output): (&Path, &Path),
    progress: &dyn Fn(Progress) -> bool,
    warned: &AtomicBool,
    bar: &ProgressBar,
) -> anyhow::Result<()> {
    let t = std::time::Instant::now();
    let mut note = |n: Note| {
        let say = match &n {
            _ if args.quiet => false,
            Note::EstimatedVariances { .. } => args.verbose || !warned.swap(true, Ordering::SeqCst),
            Note::ViewLayerChosen { .. } => true,
            n => n.is_warning() || args.verbose,
        };
        match (say, &n) {
            (false, _) => {}
            (true, Note::ViewLayerChosen { .. }) => bar.suspend(|| eprintln!("kpcn: note: {n}")),
            (true, n) if n.is_warning() => bar.suspend(|| eprintln!("kpcn: warning: {n}")),
            (true, n) => bar.suspend(|| println!("{n}")),
        }
    };
    let outcomes = request.run(denoiser, input, output, progress, &mut note)?;
    if args.verbose {
        for o in &outcomes {
            let (w, h) = o.size;
            let tile = o.tile.map_or("none".to_string(), |(tw, th)| format!("{tw}x{th}"));
            let s = &o.report.stages;
            bar.suspend(|| {
                println!(
                    "{} -> {} ({w}x{h}, layout {}, bands of {} rows, tiles of up to {tile} px, {:.2} s)",
                    input.display(),
                    output.display(),
                    o.layout.name(),
                    o.band_rows,
                    t.elapsed().as_secs_f64()
                );
                println!(
                    "{}: read {:.2} s{}, features {:.2} s, network {:.2} s, write {:.2} s",
                    input.display(),
                    s.read.as_secs_f64(),
                    if o.report.openexr_core { " (OpenEXRCore)" } else { "" },
                    s.features.as_secs_f64(),
                    s.network.as_secs_f64(),
                    s.write.as_secs_f64()
                )
            });
        }
    }
    Ok(())
}
