//! `kpcn train`: train KPCN/DPCN weights on a `kpcn dataset` folder.

use super::model::Preset;
use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use kpcn::eval::plot::write_png;
use kpcn::features::Branch;
use kpcn::kernel::ops::Ops;
use kpcn::model::{Clamp, Design, DiffuseInput, Exposure, Kind, Model, Preprocessing, ScaleBlend, Specular, Variances};
use kpcn::train::data::{CheckSet, Dataset};
use kpcn::train::{CHECKPOINT, Fireflies, LogRow, Loss, LossScale, TrainOptions, Trainer};
use kpcn::train::{curves, records};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Arguments of `kpcn train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// A folder written by `kpcn dataset` (with manifest.csv).
    #[arg(long, value_name = "DIR")]
    pub data: PathBuf,
    /// Output folder: checkpoint.safetensors, model.safetensors, log.csv.
    #[arg(short, long, value_name = "DIR")]
    pub output: PathBuf,
    /// Architecture of a fresh model.
    #[arg(long, value_enum, default_value_t = Preset::Small)]
    pub preset: Preset,
    /// Kernel prediction or direct prediction.
    #[arg(long, value_enum, default_value_t = Kind::Kpcn)]
    pub kind: Kind,
    /// Start from this model file instead of a fresh Xavier initialisation.
    #[arg(long, value_name = "FILE")]
    pub init: Option<PathBuf>,
    /// Firefly clamp of a multi-scale colour pyramid: `hard` (the excess is lost),
    /// `spread` (shared over the 3×3 neighbourhood), `coarse` (averaged into the
    /// coarsest scale), `fine`, `fine-pairs`, `fine-pairs-twice` or `significant`
    /// (`kpcn model clamp --help` says what each does; `significant` reads the variance,
    /// which training batches do not carry, so it trains as `fine-pairs-twice` and is
    /// stored as `significant`). Default: the preset's or the --init model's.
    #[arg(long, value_enum, value_name = "CLAMP")]
    pub clamp: Option<Clamp>,
    /// How a multi-scale network blends each scale with the coarser one: `lerp`
    /// (`(1 − α)·fine + α·up(coarse)`) or `detail` (`fine + α·up(coarse − down(fine))`,
    /// Vogels et al. 2018: detail finer than the coarse scale stays). Recorded in the
    /// model. Default: the preset's (lerp) or the --init model's.
    #[arg(long, value_enum, value_name = "lerp|detail")]
    pub blend: Option<ScaleBlend>,
    /// A multi-scale network's full-resolution head also predicts a per-pixel gain
    /// `2σ(g)` on each branch's result (between 0 and 2): shading the kernels' averages
    /// cannot reach. An --init model without one gains it at exactly 1 (zero weights), so
    /// training starts from that model's outputs. Recorded in the model (`kpcn:gain`).
    #[arg(long)]
    pub gain: bool,
    /// How the diffuse branch's network sees d̃: `linear`, or `log` (`ln(1 + d̃)`, its
    /// gradients and its variance alike, as the specular branch sees s̃); its kernels
    /// filter d̃ either way. Recorded in the model. Default: the --init model's, else
    /// linear. A branch trained on one does not know the other: give it with `--fresh
    /// diffuse`.
    #[arg(long, value_enum, value_name = "linear|log")]
    pub diffuse_input: Option<DiffuseInput>,
    /// What the specular kernels filter: `log` (ln(1 + s), as Bako et al.) or `linear`
    /// radiance (energy-preserving, but harder to learn: BENCHMARKS.md). Default: log, or
    /// the --init model's.
    #[arg(long, value_enum, value_name = "log|linear")]
    pub specular: Option<Specular>,
    /// Variance features to train on: `file` (the dataset's own per-pixel variances) or
    /// `spatial` (3×3 spatial estimates, what files without variances, such as Blender's,
    /// give at inference). Recorded in the model, which is then always fed that kind.
    /// Default: the --init model's, else file. Give it again with --resume.
    #[arg(long, value_enum, value_name = "file|spatial")]
    pub variances: Option<Variances>,
    /// Radiance the network sees: `raw` (as rendered) or `auto` (each frame scaled so its
    /// geometric-mean 16×16 block luminance is 0.18, as OIDN's autoexposure; the output is
    /// scaled back). Recorded in the model. Default: the --init model's, else raw. Give it
    /// again with --resume.
    #[arg(long, value_enum, value_name = "raw|auto")]
    pub exposure: Option<Exposure>,
    /// Phase-1 steps: each branch alone, L1 in its transformed domain.
    #[arg(long, default_value_t = 1000, value_name = "N")]
    pub steps: u64,
    /// Phase-2 steps: both branches on the recomposed colour.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub phase2_steps: u64,
    /// Patches per step.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Output patch side in pixels (the network also sees its halo).
    #[arg(long, default_value_t = 65)]
    pub patch: usize,
    /// Adam learning rate, phase 1.
    #[arg(long, default_value_t = 1e-4)]
    pub lr: f64,
    /// Adam learning rate, phase 2.
    #[arg(long, default_value_t = 1e-5)]
    pub lr_phase2: f64,
    /// Learning-rate schedule within each phase: `constant`, or `cosine` decay from
    /// --lr (--lr-phase2) down to 5 % of it by the phase's last step. Give it again with
    /// --resume.
    #[arg(long, value_enum, default_value_t = Schedule::Constant)]
    pub schedule: Schedule,
    /// Loss: `l1` (Bako et al.: L1 on each branch's transformed target, then on the colour),
    /// `relative` (relMSE with the prediction as its denominator, which seeks the mean and
    /// so keeps brightness, plus L1 on tonemapped radiance) or `relmse` (the same with the
    /// reference as denominator, as the evaluator scores: for clean references, since noise
    /// in them pulls it dark). Give it again with --resume.
    #[arg(long, value_enum, default_value_t = Loss::L1)]
    pub loss: Loss,
    /// With `--loss relmse-light`: the weight of its block term (the relative L2 of 8×8
    /// block means), against the per-pixel relMSE's 1. At 64 a block's error counts as
    /// much as each of its pixels' would; larger holds each block's light more firmly,
    /// where the per-pixel term alone erodes thin bright structures. Give it again with
    /// --resume.
    #[arg(long, default_value_t = 1.0, value_name = "W")]
    pub block_weight: f64,
    /// Where the loss charges errors. With --exposure auto, `exposed` charges them at the
    /// autoexposed scale, where relMSE's 0.01 in the denominator weighs a brightened dim
    /// frame's errors more than `kpcn eval` does; `rendered` charges them as `kpcn eval`
    /// does. Give it again with --resume.
    #[arg(long, value_enum, default_value_t = LossScale::Exposed)]
    pub loss_scale: LossScale,
    /// Show each patch mirrored and/or transposed at random (8 orientations), so the
    /// network learns from 8 times the content. Give it again with --resume.
    #[arg(long)]
    pub augment: bool,
    /// Show each patch with its colour channels in one of the 6 orders, at random (colour,
    /// albedo and reference alike), so no hue is learnt as special. Give it again with
    /// --resume.
    #[arg(long)]
    pub permute_channels: bool,
    /// Add single-pixel fireflies (log-uniform from --firefly-min-gain to 10,000× the
    /// patch's mean) to each patch's noisy input, never to its reference, so the network
    /// learns to remove outliers that a mean-seeking loss (`--loss relative`) would keep as
    /// light. Give it again with --resume, with the same --firefly-* values.
    #[arg(long)]
    pub fireflies: bool,
    /// With --fireflies: each patch gets 0 to N of them, as many patches with each count.
    #[arg(long, default_value_t = 3, value_name = "N", requires = "fireflies")]
    pub firefly_most: u64,
    /// With --fireflies: the dimmest, as a multiple of the patch's mean (default 10^1.5 ≈
    /// 32). Brighter outliers are surer to be noise: real highlights reach 10²–10³.
    #[arg(long, value_name = "GAIN", value_parser = firefly_gain, requires = "fireflies")]
    pub firefly_min_gain: Option<f64>,
    /// Phase 1 trains only this branch; the other keeps its weights (phase 2 trains
    /// both). With --fresh, to retrain one branch of a model. Give it again with --resume.
    #[arg(long, value_enum, value_name = "diffuse|specular")]
    pub only: Option<Branch>,
    /// With --init: this branch starts afresh (Xavier initialisation from --seed) and the
    /// other keeps the model's weights.
    #[arg(long, value_enum, value_name = "diffuse|specular", requires = "init")]
    pub fresh: Option<Branch>,
    /// Seed of initialisation and patch sampling: a run is reproducible from it.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Patch selection.
    #[arg(long, value_enum, default_value_t = Patches::Importance)]
    pub patches: Patches,
    /// A check set scored at every validation and never trained on: a folder of
    /// SCENE-NNNNNspp.exr files beside their SCENE-ref.exr, such as the team's Cycles dev
    /// set (../shared/data/cycles-dev). Its geometric-mean relMSE goes to log.csv
    /// (`dev_relmse_geomean`) and training.png. For watching generalisation only: never
    /// choose a model by it.
    #[arg(long, value_name = "DIR")]
    pub dev: Option<PathBuf>,
    /// Hold out every N-th scene (whole scenes) for validation.
    #[arg(long, default_value_t = 5, value_name = "N")]
    pub holdout: usize,
    /// Steps between checkpoints (and after the last step, and on Ctrl-C).
    #[arg(long, default_value_t = 50, value_name = "N")]
    pub checkpoint_every: u64,
    /// Steps between validations on the held-out scenes.
    #[arg(long, default_value_t = 100, value_name = "N")]
    pub validate_every: u64,
    /// Do not read or write the preprocessed-frame cache (DATA/cache/).
    #[arg(long)]
    pub no_cache: bool,
    /// Continue from OUTPUT/checkpoint.safetensors exactly where it stopped.
    #[arg(long)]
    pub resume: bool,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Run candle's stock conv2d and composed kernel application (several times slower)
    /// instead of kpcn's kernels: only to measure the two against each other.
    #[arg(long)]
    pub stock_candle: bool,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Patch selection strategies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Patches {
    /// ARCHITECTURE.md §Training: 400 dart-thrown candidates per frame, pruned to 100 by error diffusion over
    /// the importance map (relative colour variance + normal variance), 10 % floor.
    Importance,
    /// 100 dart-thrown candidates per frame, unpruned (evenly spread).
    Uniform,
}

/// Redraws DIR/training.png from DIR/log.csv. A plot is a convenience: failing to draw
/// one (no font) is said once and never stops training.
fn plot(dir: &Path, bar: &ProgressBar) {
    static WARNED: std::sync::Once = std::sync::Once::new();
    let text = std::fs::read_to_string(dir.join("log.csv")).unwrap_or_default();
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let chart = curves::chart(&[(name, curves::parse(&text))]);
    if let Err(e) = write_png(&chart, &dir.join("training.png"), 900, 540) {
        WARNED.call_once(|| bar.suspend(|| eprintln!("kpcn train: warning: no training.png: {e}")));
    }
}

/// `--schedule` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Schedule {
    /// The same rate throughout each phase.
    Constant,
    /// Cosine decay to 5 % within each phase.
    Cosine,
}

/// Runs `kpcn train`.
pub fn run(args: &TrainArgs) -> anyhow::Result<()> {
    if args.batch == 0 || args.patch < 8 {
        bail!("--batch must be ≥ 1 and --patch ≥ 8");
    }
    std::fs::create_dir_all(&args.output).with_context(|| format!("{}: cannot create", args.output.display()))?;
    // The --init model, read once: its variances and exposure are the defaults, and
    // training starts from it.
    let init = if args.resume { None } else { args.init.as_deref().map(Model::load).transpose()? };
    let variances = args.variances.or(init.as_ref().map(|m| m.arch.variances)).unwrap_or(Variances::File);
    let exposure = args.exposure.or(init.as_ref().map(|m| m.arch.exposure)).unwrap_or(Exposure::Raw);
    let prep = Preprocessing { variances, exposure };
    let data = Dataset::load(&args.data, args.holdout.max(2), !args.no_cache, prep)?;
    let dev = args.dev.as_deref().map(|d| CheckSet::load(d, prep)).transpose()?;
    let opts = TrainOptions {
        phase1_steps: args.steps,
        phase2_steps: args.phase2_steps,
        batch: args.batch,
        patch: args.patch,
        lr: args.lr,
        lr_phase2: args.lr_phase2,
        seed: args.seed,
        importance: args.patches == Patches::Importance,
        checkpoint_every: args.checkpoint_every.max(1),
        validate_every: args.validate_every.max(1),
        ops: if args.stock_candle { Ops::StockCandle } else { Ops::Kpcn },
        cosine: args.schedule == Schedule::Cosine,
        loss: args.loss,
        block_weight: args.block_weight,
        loss_scale: args.loss_scale,
        augment: args.augment,
        fireflies: args.fireflies.then(|| {
            let d = Fireflies::default();
            Fireflies { most: args.firefly_most, min_decades: args.firefly_min_gain.map_or(d.min_decades, f64::log10) }
        }),
        permute_channels: args.permute_channels,
        only: args.only,
    };
    let checkpoint = args.output.join(CHECKPOINT);
    let log_path = args.output.join("log.csv");
    let mut trainer = if args.resume {
        let t = Trainer::resume(&checkpoint, &data, opts.clone())
            .with_context(|| format!("{}: cannot resume (drop --resume to start afresh)", checkpoint.display()))?;
        if t.model.base.arch.variances != variances {
            bail!(
                "{}: trained on {:?} variances; resume with --variances {}",
                checkpoint.display(),
                t.model.base.arch.variances,
                if variances == Variances::File { "spatial" } else { "file" }
            );
        }
        if t.model.base.arch.exposure != exposure {
            bail!(
                "{}: trained on {} radiance; resume with --exposure {}",
                checkpoint.display(),
                if exposure == Exposure::Auto { "raw" } else { "auto-exposed" },
                if exposure == Exposure::Auto { "raw" } else { "auto" }
            );
        }
        // Steps logged after the checkpoint by an interrupted run are redone: drop them.
        // Rewritten in the current format: a log from an older kpcn gains the newer columns.
        let mut rows = records::read_log(&std::fs::read_to_string(&log_path).unwrap_or_default());
        rows.retain(|r| r.step <= t.step);
        records::write_log(&log_path, &rows)?;
        t
    } else {
        let mut model = match init {
            Some(m) => m,
            None => Model::xavier(args.preset.architecture(args.kind)?, args.seed)?,
        };
        if let Some(branch) = args.fresh {
            let fresh = Model::xavier(model.arch, args.seed)?;
            match branch {
                Branch::Diffuse => model.diffuse = fresh.diffuse,
                Branch::Specular => model.specular = fresh.specular,
            }
        }
        if let Some(c) = args.clamp {
            model.arch.clamp = c;
        }
        if let Some(b) = args.blend {
            model.arch.blend = b;
        }
        if args.gain {
            if model.arch.design != Design::MultiScale {
                bail!(
                    "--gain: a gain is for multi-scale networks, and this model is flat (drop --gain, or start from a multi-scale model or --preset)"
                );
            }
            model = model.with_gain()?;
        }
        if let Some(d) = args.diffuse_input {
            model.arch.diffuse_input = d;
        }
        if let Some(d) = args.specular {
            model.arch.specular = d;
        }
        model.arch.variances = variances;
        model.arch.exposure = exposure;
        model.arch.validate("kpcn train")?;
        records::write_log(&log_path, &[])?;
        Trainer::new(&model, &data, opts.clone())?
    };
    let mut log = std::fs::OpenOptions::new()
        .append(true)
        .open(&log_path)
        .with_context(|| format!("{}: cannot open", log_path.display()))?;

    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    // A second Ctrl-C while saving is not special: the checkpoint is written atomically.
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));

    let total = args.steps + args.phase2_steps;
    let bar = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(total) };
    bar.set_style(
        ProgressStyle::with_template("{pos}/{len} [{bar:30}] {msg} ETA {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_position(trainer.step);
    if !args.quiet {
        bar.suspend(|| {
            eprintln!(
                "kpcn train: {} training frames, {} held-out frames ({} from the cache); {:?} {}x{} ch; start at step {}",
                data.train.len(),
                data.validation.len(),
                data.cached,
                trainer.model.base.arch.kind,
                trainer.model.base.arch.layers,
                trainer.model.base.arch.channels,
                trainer.step
            )
        });
    }
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(n) = super::threads(args.threads, args.quiet) {
        pool = pool.num_threads(n);
    }
    let pool = pool.build().context("cannot start worker threads")?;
    let started = std::time::Instant::now();
    pool.install(|| -> anyhow::Result<()> {
        while !trainer.finished() && !stop.load(Ordering::SeqCst) {
            let mut row: LogRow = trainer.train_step()?;
            if (row.step.is_multiple_of(opts.validate_every) || trainer.finished())
                && let Some(v) = trainer.validate()?
            {
                row.validation_relmse = Some(v.mean);
                row.validation_median_relmse = Some(v.median);
                if let Some(dev) = &dev {
                    row.dev_relmse = trainer.check(dev)?;
                }
            }
            let loss = if row.phase == 1 { row.loss_diffuse + row.loss_specular } else { row.loss_combined };
            let mut val =
                row.validation_median_relmse.map(|v| format!(", val relMSE median {v:.4}")).unwrap_or_default();
            if let Some(v) = row.dev_relmse {
                val.push_str(&format!(", dev {v:.4}"));
            }
            bar.set_message(format!(
                "phase {} loss {loss:.4}{val}, {:.1} patches/s",
                row.phase, row.patches_per_second
            ));
            bar.set_position(row.step);
            writeln!(log, "{}", row.to_line())?;
            if row.step.is_multiple_of(opts.checkpoint_every) {
                trainer.save(&checkpoint)?;
                plot(&args.output, &bar);
            }
        }
        Ok(())
    })?;
    trainer.save(&checkpoint)?;
    plot(&args.output, &bar);
    bar.finish_and_clear();
    if stop.load(Ordering::SeqCst) {
        eprintln!("kpcn train: interrupted at step {}; checkpoint saved — continue with --resume", trainer.step);
        return Ok(());
    }
    let a = trainer.model.base.arch;
    let description = format!(
        "trained by kpcn train: {:?} {:?} {}x{}ch {}x{} conv {}x{} kernels; {} + {} steps, batch {}, patch {}, lr {}/{} {:?}, loss {:?}{}, seed {}, {} patches; data {} ({} frames, {} held out)",
        a.design,
        a.kind,
        a.layers,
        a.channels,
        a.conv_size,
        a.conv_size,
        a.kernel_size,
        a.kernel_size,
        args.steps,
        args.phase2_steps,
        args.batch,
        args.patch,
        args.lr,
        args.lr_phase2,
        args.schedule,
        args.loss,
        [
            (args.augment, ", oriented"),
            (args.permute_channels, ", channels permuted"),
            (args.fireflies, ", fireflies added"),
            (a.exposure == Exposure::Auto, ", auto-exposed"),
            (a.diffuse_input == DiffuseInput::Log, ", diffuse seen in log"),
            (a.gain, ", with a gain"),
            (args.fresh == Some(Branch::Diffuse), ", diffuse branch afresh"),
            (args.fresh == Some(Branch::Specular), ", specular branch afresh"),
            (args.only == Some(Branch::Diffuse), ", phase 1 on the diffuse branch alone"),
            (args.only == Some(Branch::Specular), ", phase 1 on the specular branch alone"),
        ]
        .iter()
        .filter_map(|&(on, what)| on.then_some(what))
        .collect::<String>(),
        args.seed,
        if opts.importance { "importance" } else { "uniform" },
        args.data.display(),
        data.train.len(),
        data.validation.len()
    );
    let model = trainer.model.snapshot(&description)?;
    let out = args.output.join("model.safetensors");
    model.save(&out)?;
    println!("{} ({} steps in {:.0} s this run)", out.display(), trainer.step, started.elapsed().as_secs_f64());
    Ok(())
}

/// Arguments of `kpcn curves`.
#[derive(Debug, Args)]
pub struct CurvesArgs {
    /// Training run folders (or their log.csv files).
    #[arg(required = true, value_name = "RUN")]
    pub runs: Vec<PathBuf>,
    /// Output PNG.
    #[arg(short, long, value_name = "PNG")]
    pub output: PathBuf,
}

/// Runs `kpcn curves`: one chart of several training runs' validation relMSE (or one
/// run's losses too), e.g. KPCN against DPCN on the same data and budget.
pub fn run_curves(args: &CurvesArgs) -> anyhow::Result<()> {
    let mut runs = Vec::new();
    for r in &args.runs {
        let (dir, log) =
            if r.is_dir() { (r.clone(), r.join("log.csv")) } else { (r.parent().unwrap_or(r).into(), r.clone()) };
        let text = std::fs::read_to_string(&log).with_context(|| {
            format!("{}: cannot read — give a `kpcn train` output folder or its log.csv", log.display())
        })?;
        let name =
            dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| dir.display().to_string());
        runs.push((name, curves::parse(&text)));
    }
    write_png(&curves::chart(&runs), &args.output, 900, 540)?;
    println!("{}", args.output.display());
    Ok(())
}

/// A firefly gain for `--firefly-min-gain`: 1 to 10⁴ times the patch's mean.
fn firefly_gain(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(g) if (1.0..1e4).contains(&g) => Ok(g),
        _ => Err(format!("{s:?}: give a multiple of the patch's mean from 1 to below 10000, such as 300")),
    }
}
