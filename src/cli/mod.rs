//! The `kpcn` command line: argument definitions and the commands, thin shells over the
//! library.

mod denoise;
mod docs;
mod eval;
mod info;
mod model;
mod render;
mod sequence;
mod signals;
mod speed;
mod study;
mod train;
mod zlib;

use clap::{Parser, Subcommand};

/// Command-line arguments of `kpcn`.
#[derive(Debug, Parser)]
#[command(
    name = "kpcn",
    version,
    about = "Kernel-predicting Monte Carlo render denoiser for layered EXRs",
    long_about = "kpcn reads layered EXRs (KPCN's native layout, Blender Cycles passes or RenderMan \
                  denoise AOVs) through OpenImageIO and denoises them with a kernel-predicting \
                  convolutional network (Bako et al. 2017).\n\n\
                  Exit status: 0 success; 1 runtime error (a file, the model, a failed frame: the \
                  message names the file and what to do); 2 usage error (bad arguments); 130 \
                  interrupted (SIGINT) and 143 terminated (SIGTERM), with partial outputs removed.",
    after_help = "Examples:\n  kpcn info render.0001.exr\n  kpcn info --layout cycles shot/*.exr"
)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Describe files: resolution, parts, channels by layer, the detected layout and which
    /// KPCN inputs are present, derived, estimated or missing.
    ///
    /// Exits with status 1 when a file cannot be read or lacks inputs the network needs, so
    /// it can gate a pipeline step.
    Info(info::InfoArgs),
    /// Denoise a layered EXR or an image sequence, adding a denoised layer to a copy of each
    /// input (every channel and all metadata kept; written atomically).
    ///
    /// The embedded models are KPCNs trained on simulator scenes (`kpcn model info NAME`
    /// describes them): by default `default` runs on files with variances and `spatial` on
    /// files without (Blender's); `--model` picks one.
    #[command(
        after_help = "Examples:\n  kpcn denoise frame.exr -o frame.denoised.exr\n  kpcn denoise shot/render.####.exr -o out/render.####.exr --frames 1001-1100 --aovs\n  kpcn denoise render.%04d.exr -o den.%04d.exr -n"
    )]
    Denoise(denoise::DenoiseArgs),
    /// Score images against a reference: relMSE, PSNR and 1 − SSIM (tonemapped as the team's
    /// Cycles baseline) and brightness (the image's mean over the reference's), per file and
    /// averaged; optional false-colour error maps.
    #[command(
        after_help = "Examples:\n  kpcn eval --reference shot-ref.exr shot-00016spp.exr shot.den.exr\n  kpcn eval -r ref.exr den.exr --format json --error-maps maps/"
    )]
    Eval(eval::EvalArgs),
    /// Render a scene with the simulator into layered EXRs: noisy frames at several sample
    /// counts from one run, and optionally an independent high-sample reference.
    ///
    /// Files are named `<scene>-<spp, 5 digits>spp.exr` and `<scene>-ref.exr`.
    #[command(
        after_help = "Examples:\n  kpcn render --family cornell --seed 1 --spp 4,16,64 --reference-spp 1024 --resolution 320x180 -o out/\n  kpcn scenes --example > my.toml && kpcn render my.toml -o out/"
    )]
    Render(render::RenderArgs),
    /// List the simulator's scene families, or print one permutation as a scene file.
    Scenes(render::ScenesArgs),
    /// Render a training/test set: N permutations of each family, noisy frames and
    /// references, with a manifest.csv.
    ///
    /// Rerunning into the same folder resumes an interrupted run (scenes already listed
    /// with the same --spp and --sample-seed are kept) and extends a dataset with more
    /// families or seeds. Frames are sampled as Cycles does by default (Blackman-Harris
    /// pixel filter, Sobol' points); `--pixel-filter box --sampler random` gives the
    /// simulator's original sampling.
    #[command(
        after_help = "Examples:\n  kpcn dataset --count 10 --spp 2,4,16,64 --reference-spp 512 -o data/\n  kpcn dataset --families slit --count 10 --spp 2,4,16,64 --reference-spp 512 -o data/   # adds a family"
    )]
    Dataset(render::DatasetArgs),
    /// Train KPCN/DPCN weights on a `kpcn dataset` folder: importance-sampled patches, phase 1
    /// (each branch, L1 in its own domain), phase 2 (recomposed colour); checkpoints resume
    /// exactly; Ctrl-C saves one.
    #[command(
        after_help = "Example:\n  kpcn dataset --count 4 -o data/ && kpcn train --data data/ -o run/ --steps 2000\n  kpcn denoise frame.exr -o den.exr --model run/model.safetensors"
    )]
    Train(train::TrainArgs),
    /// Plot training runs: one run's smoothed losses and validation relMSE, or several runs'
    /// validation relMSE in one chart (e.g. KPCN against DPCN on the same data and budget).
    #[command(after_help = "Example:\n  kpcn curves runs/kpcn runs/dpcn -o kpcn-vs-dpcn.png")]
    Curves(train::CurvesArgs),
    /// What accuracy costs in time: render simulator scenes at rising sample counts, denoise
    /// each frame with every model (and OIDN when `pyoidn` is installed), and write a CSV,
    /// one log–log error-vs-seconds plot per scene and a markdown summary (time to reach
    /// Monte Carlo's best error, speed-up, and each model's FLOP/pixel, s/MPix, peak RSS).
    #[command(
        after_help = "Examples:\n  kpcn study -o study/\n  kpcn study -o study/ --families cornell,glass --spp 2,8,32 --models default,run/model.safetensors"
    )]
    Study(study::StudyArgs),
    /// Seconds per frame of each model's forward pass (in process, model loaded, after a
    /// warm-up) beside OIDN measured the same way in the same run on the same rendered frame.
    #[command(after_help = "Examples:\n  kpcn speed\n  kpcn speed --models default,small,paper --resolution 1920x1080")]
    Speed(speed::SpeedArgs),
    /// Inspect model files or write an untrained one.
    Model(model::ModelArgs),
    /// Print a shell's completion script (bash, zsh, fish, elvish, powershell).
    #[command(after_help = "Examples:\n  kpcn completions bash > ~/.local/share/bash-completion/completions/kpcn")]
    Completions(docs::CompletionsArgs),
    /// Write the man pages (kpcn.1 and one per command) into a folder.
    Manpages(docs::ManpagesArgs),
}

/// When set, `kpcn` prints `peak-rss-kb N` (its VmHWM) to stderr on exit: how `kpcn study`
/// measures a child's peak memory.
pub const PEAK_RSS_ENV: &str = "KPCN_REPORT_PEAK_RSS";

/// This process's peak resident memory in kB (VmHWM), where /proc has it.
pub fn peak_rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status.lines().find_map(|l| l.strip_prefix("VmHWM:")?.trim().strip_suffix("kB")?.trim().parse().ok())
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    // Both allocate and free the same large tensors over and over (before any thread
    // starts, so that every thread shares the one kept heap).
    if matches!(cli.command, Command::Train(_) | Command::Speed(_)) {
        kpcn::kernel::buffers::keep_freed_memory();
    }
    if matches!(cli.command, Command::Denoise(_)) {
        kpcn::kernel::buffers::return_large_blocks();
        // Memory, not speed: streamed bands read a few chunks at a time.
        kpcn::io::decode_exr_on_the_calling_thread().map_err(|e| anyhow::anyhow!("OpenImageIO: {e}"))?;
        // Speed: OpenEXRCore copies decoded samples whole (a 4K file's command 6 % fewer
        // CPU-seconds), its chunk buffers kept for reuse.
        kpcn::io::read_lossless_exr_with_openexr_core();
    }
    // `kpcn train` stops gracefully on Ctrl-C instead, after saving its checkpoint.
    if !matches!(cli.command, Command::Train(_)) {
        signals::exit_on_signals();
    }
    match cli.command {
        Command::Info(args) => info::run(&args),
        Command::Denoise(args) => denoise::run(&args),
        Command::Eval(args) => eval::run(&args),
        Command::Render(args) => render::run_render(&args),
        Command::Scenes(args) => render::run_scenes(&args),
        Command::Dataset(args) => render::run_dataset(&args),
        Command::Model(args) => model::run(&args),
        Command::Train(args) => train::run(&args),
        Command::Curves(args) => train::run_curves(&args),
        Command::Study(args) => study::run(&args),
        Command::Speed(args) => speed::run(&args),
        Command::Completions(args) => docs::run_completions(&args),
        Command::Manpages(args) => docs::run_manpages(&args),
    }
}

/// A usage error found after parsing (e.g. an input and output that are not both
/// sequences): exit status 2, like the parser's own.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// Errors already printed by a command; `main` only sets the exit status.
#[derive(Debug)]
pub struct Reported(pub usize);

/// `--threads N` checked against the machine: beyond its cores it is allowed with a
/// warning, beyond 4 per core (an absurd value) capped with one.
pub fn threads(requested: Option<usize>, quiet: bool) -> Option<usize> {
    let n = requested?;
    let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
    let max = kpcn::denoise::max_threads();
    if n > max {
        eprintln!("kpcn: warning: --threads {n} capped to {max} (4 per core on this {cores}-core machine)");
        return Some(max);
    }
    if n > cores && !quiet {
        eprintln!(
            "kpcn: warning: --threads {n} is more than this machine's {cores} cores; it will run slower, not faster"
        );
    }
    Some(n.max(1))
}

/// An error's message for the terminal: the library's text (which names no flags), plus
/// the command-line flag behind it where there is one.
pub fn describe_error(e: &anyhow::Error) -> String {
    use kpcn::io::IoError;
    // Transparent wrappers hide the I/O error from the source chain: look inside them.
    fn io<'a>(c: &'a (dyn std::error::Error + 'static)) -> Option<&'a IoError> {
        c.downcast_ref::<IoError>()
            .or_else(|| match c.downcast_ref::<kpcn::denoise::FileError>() {
                Some(kpcn::denoise::FileError::Io(io)) => Some(io),
                _ => None,
            })
            .or_else(|| match c.downcast_ref::<kpcn::sim::SimError>() {
                Some(kpcn::sim::SimError::Io(io)) => Some(io),
                _ => None,
            })
    }
    let refused = e.chain().any(|c| matches!(io(c), Some(IoError::Exists { .. })));
    let hint = if refused { " (--no-clobber was given; drop it to replace the file)" } else { "" };
    format!("{e:#}{hint}")
}

impl std::fmt::Display for Reported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} file(s) failed", self.0)
    }
}

impl std::error::Error for Reported {}
