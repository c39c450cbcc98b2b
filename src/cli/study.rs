//! `kpcn study`: what accuracy costs in time. Renders simulator scenes at rising sample
//! counts, denoises every frame with each model (and OIDN when `pyoidn` is installed, as an
//! external peer), and writes a CSV, one log–log plot per scene and a markdown summary.

use super::PEAK_RSS_ENV;
use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use kpcn::denoise::{Denoiser, Options};
use kpcn::eval::plot::write_png;
use kpcn::eval::study::{self, Cost, MONTE_CARLO, Row};
use kpcn::eval::{metrics, rgb};
use kpcn::io::layout::{KpcnInputs, Mapping};
use kpcn::io::{FrameBuffers, WriteOptions};
use kpcn::model::Model;
use kpcn::sim::families::{FAMILIES, generate};
use kpcn::sim::{RenderOptions, render_to_dir};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Arguments of `kpcn study`.
#[derive(Debug, Args)]
pub struct StudyArgs {
    /// Output folder: study.csv, summary.md, one PNG per scene, frames/.
    #[arg(short, long, value_name = "DIR")]
    pub output: PathBuf,
    /// Scene families to render, comma-separated (`kpcn scenes` lists them).
    #[arg(long, default_value = "cornell,interior,product", value_name = "A,B,…")]
    pub families: String,
    /// Which permutation of each family.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub seed: u64,
    /// Sample counts, each rendered (and timed) on its own; each ≥ 2.
    #[arg(long, default_value = "2,4,8,16,32,64,128,256", value_name = "N,N,…")]
    pub spp: String,
    /// Samples of the reference render (not timed).
    #[arg(long, default_value_t = 1024, value_name = "N")]
    pub reference_spp: u32,
    /// Film size.
    #[arg(long, default_value = "320x180", value_parser = super::render::parse_resolution, value_name = "WxH")]
    pub resolution: (usize, usize),
    /// Models to compare, comma-separated: `default`, preset names, or .safetensors files.
    #[arg(long, default_value = "default", value_name = "M,M,…")]
    pub models: String,
    /// Intel Open Image Denoise as a peer (hdr + albedo + normal, quality high) through the
    /// Python package `pyoidn`: `auto` uses it when installed.
    #[arg(long, value_enum, default_value_t = Oidn::Auto)]
    pub oidn: Oidn,
    /// Threads for rendering and denoising.
    #[arg(long, default_value_t = 2, value_name = "N")]
    pub threads: usize,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Whether to run OIDN.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Oidn {
    /// When `python3 -c "import pyoidn"` works.
    Auto,
    /// Always; fail if it cannot run.
    On,
    /// Never.
    Off,
}

impl Oidn {
    /// Whether OIDN runs: `on` fails when it cannot.
    pub(super) fn enabled(self) -> anyhow::Result<bool> {
        Ok(match self {
            Oidn::Off => false,
            Oidn::Auto => oidn_available(),
            Oidn::On if oidn_available() => true,
            Oidn::On => bail!("--oidn on: `python3 -c \"import pyoidn, numpy\"` fails — pip install pyoidn numpy"),
        })
    }
}

/// Reads raw f32 colour/albedo/normal (h × w × 3), denoises with OIDN, writes raw f32 and
/// prints the filter's seconds (after a warm-up on a tiny image, as kpcn's model is loaded
/// before timing too).
const OIDN_SCRIPT: &str = r#"
import os, sys, time
w, h, threads, repeat = (int(a) for a in sys.argv[1:5])
prefix, out = sys.argv[5], sys.argv[6]
# pyoidn has no thread option; OIDN's TBB pool follows the CPU affinity mask.
os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:threads])
import numpy as np, pyoidn
load = lambda n: np.fromfile(prefix + n, dtype=np.float32).reshape(h, w, 3)
color, albedo, normal = load("color"), load("albedo"), load("normal")
# A warm-up on the frame itself (weights, threads, buffers of its size), then the fastest
# of `repeat` runs: what kpcn's side of a comparison gets.
res = pyoidn.denoise(color, albedo, normal, hdr=True, quality="high")
best = float("inf")
for _ in range(repeat):
    s = time.perf_counter()
    res = pyoidn.denoise(color, albedo, normal, hdr=True, quality="high")
    best = min(best, time.perf_counter() - s)
print(best)
np.ascontiguousarray(res, dtype=np.float32).tofile(out)
hwm = [l.split()[1] for l in open("/proc/self/status") if l.startswith("VmHWM:")]
print("peak-rss-kb", hwm[0] if hwm else 0, file=sys.stderr)
"#;

/// A child process's standard output and peak RSS in MB.
struct Measured {
    stdout: String,
    peak_mb: f64,
}

/// Runs `cmd` to completion; the child reports its own peak RSS on stderr
/// (`peak-rss-kb N`, from /proc/self/status VmHWM). `wait4`'s rusage cannot be used: on
/// Linux a child's maxrss includes its parent's peak at the time of the fork/exec.
fn run_measured(cmd: &mut Command) -> anyhow::Result<Measured> {
    let out = cmd.env(PEAK_RSS_ENV, "1").output().context("cannot start")?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() {
        bail!("failed: {}", stderr.trim());
    }
    let kb: f64 = stderr
        .lines()
        .find_map(|l| l.strip_prefix("peak-rss-kb ").and_then(|v| v.trim().parse().ok()))
        .context("the child reported no peak-rss-kb line")?;
    Ok(Measured { stdout: String::from_utf8_lossy(&out.stdout).into_owned(), peak_mb: kb / 1024.0 })
}

fn parse_list<T: std::str::FromStr>(s: &str, what: &str) -> anyhow::Result<Vec<T>> {
    s.split(',')
        .map(|v| v.trim().parse::<T>().map_err(|_| anyhow::anyhow!("--{what}: `{v}` is not valid in `{s}`")))
        .collect()
}

fn interleave(p: &[Vec<f32>; 3]) -> Vec<u8> {
    (0..p[0].len()).flat_map(|i| (0..3).flat_map(move |c| p[c][i].to_le_bytes())).collect()
}

/// Denoises `k` with OIDN; returns the colour planes, the filter's seconds (the fastest of
/// `repeat` runs after a warm-up on the frame) and the process's peak RSS.
pub(super) fn oidn(
    k: &KpcnInputs,
    dir: &Path,
    threads: usize,
    repeat: usize,
) -> anyhow::Result<([Vec<f32>; 3], f64, f64)> {
    let prefix = dir.join("oidn-");
    for (name, p) in [("color", &k.color), ("albedo", &k.albedo), ("normal", &k.normal)] {
        std::fs::write(format!("{}{name}", prefix.display()), interleave(p))?;
    }
    let out = dir.join("oidn-out");
    let m = run_measured(Command::new("python3").args([
        "-c",
        OIDN_SCRIPT,
        &k.width.to_string(),
        &k.height.to_string(),
        &threads.to_string(),
        &repeat.max(1).to_string(),
        &prefix.display().to_string(),
        &out.display().to_string(),
    ]))
    .context("OIDN (python3 + pyoidn)")?;
    let seconds: f64 = m.stdout.trim().parse().context("OIDN printed no time")?;
    let bytes = std::fs::read(&out)?;
    let v: Vec<f32> = bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    let planes = std::array::from_fn(|c| v.iter().skip(c).step_by(3).copied().collect());
    Ok((planes, seconds, m.peak_mb))
}

pub(super) fn oidn_available() -> bool {
    Command::new("python3")
        .args(["-c", "import pyoidn, numpy"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// A model and the name its rows carry.
struct Method {
    name: String,
    arg: String,
    denoiser: Denoiser,
}

/// Runs `kpcn study`.
pub fn run(args: &StudyArgs) -> anyhow::Result<()> {
    let spps: Vec<u32> = parse_list(&args.spp, "spp")?;
    if spps.iter().any(|&s| s < 2) || spps.is_empty() {
        bail!("--spp: every sample count must be ≥ 2 (a variance needs two samples)");
    }
    let (w, h) = args.resolution;
    let families: Vec<&str> = args.families.split(',').map(str::trim).collect();
    for f in &families {
        if !FAMILIES.iter().any(|(n, _)| n == f) {
            let all: Vec<&str> = FAMILIES.iter().map(|(n, _)| *n).collect();
            bail!("--families: no family `{f}` — one of {}", all.join(", "));
        }
    }
    let use_oidn = args.oidn.enabled()?;
    let threads = args.threads.max(1);
    let mut methods = Vec::new();
    for m in args.models.split(',').map(str::trim) {
        let model = Model::resolve(m)?;
        if model.is_untrained() && !args.quiet {
            eprintln!("kpcn study: warning: model `{m}` is UNTRAINED; its curve shows an untrained network");
        }
        let name = match Path::new(m).file_stem() {
            Some(s) if m.ends_with(".safetensors") => format!("kpcn-{}", s.to_string_lossy()),
            _ => format!("kpcn-{m}"),
        };
        let denoiser = Denoiser::new(model, Options { threads: Some(threads), ..Options::default() })?;
        methods.push(Method { name, arg: m.to_string(), denoiser });
    }
    let frames_dir = args.output.join("frames");
    std::fs::create_dir_all(&frames_dir).with_context(|| format!("{}: cannot create", frames_dir.display()))?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().context("cannot start threads")?;

    let steps = families.len() * spps.len();
    let bar = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(steps as u64) };
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ETA {eta}").expect("valid").progress_chars("=> "),
    );
    let mut rows: Vec<Row> = Vec::new();
    let mut sample_frame: Option<PathBuf> = None;
    let mut oidn_peak: Option<f64> = None;
    let mut denoise_time: Vec<(String, f64, f64)> = Vec::new(); // (method, seconds, megapixels)
    for family in &families {
        let desc = generate(family, args.seed).expect("checked above");
        let dir = frames_dir.join(&desc.name);
        let mut reference: Option<KpcnInputs> = None;
        for (i, &spp) in spps.iter().enumerate() {
            bar.set_message(format!("{} {spp} spp", desc.name));
            let opts = RenderOptions::new(w, h, vec![spp], args.seed);
            let written = pool.install(|| {
                render_to_dir(
                    &desc,
                    &opts,
                    (i == 0).then_some(args.reference_spp),
                    &dir,
                    &WriteOptions::default(),
                    &|_| {},
                )
            })?;
            if let Some(r) = &written.reference {
                let fb = FrameBuffers::read(r)?;
                reference = Some(Mapping::for_frame(&fb, None).extract(&fb)?);
            }
            let r = reference.as_ref().context("the reference is rendered with the first sample count")?;
            let (_, path) = &written.noisy[0];
            let fb = FrameBuffers::read(path)?;
            let k = Mapping::for_frame(&fb, None).extract(&fb)?;
            let row = |method: &str, denoise: f64, m: kpcn::eval::Metrics| Row {
                scene: desc.name.clone(),
                spp,
                method: method.to_string(),
                render_seconds: written.noisy_seconds,
                denoise_seconds: denoise,
                relmse: m.relmse,
                psnr: m.psnr,
                one_minus_ssim: m.one_minus_ssim,
            };
            rows.push(row(MONTE_CARLO, 0.0, metrics(rgb(&k.color), rgb(&r.color), w, h)));
            for m in &methods {
                if rows.len() == 1 {
                    // Warm-up (allocator, caches), untimed, as OIDN's is.
                    m.denoiser.denoise(&k, &|_| true)?;
                }
                let t = std::time::Instant::now();
                let d = m.denoiser.denoise(&k, &|_| true)?;
                let secs = t.elapsed().as_secs_f64();
                denoise_time.push((m.name.clone(), secs, (w * h) as f64 / 1e6));
                rows.push(row(&m.name, secs, metrics(rgb(&d.color), rgb(&r.color), w, h)));
            }
            if use_oidn {
                let (c, secs, peak) = oidn(&k, &dir, threads, 1)?;
                denoise_time.push(("oidn".into(), secs, (w * h) as f64 / 1e6));
                oidn_peak = Some(oidn_peak.unwrap_or(0f64).max(peak));
                rows.push(row("oidn", secs, metrics(rgb(&c), rgb(&r.color), w, h)));
            }
            sample_frame = Some(path.clone());
            bar.inc(1);
        }
        for f in ["oidn-color", "oidn-albedo", "oidn-normal", "oidn-out"] {
            let _ = std::fs::remove_file(dir.join(f));
        }
    }
    bar.finish_and_clear();

    // Costs: FLOP from the architecture, speed from the timings above, peak memory of a
    // whole `kpcn denoise` process on one study frame.
    let exe = std::env::current_exe().context("cannot find the kpcn executable")?;
    let mut costs = Vec::new();
    let per_mpix = |name: &str| {
        let (s, mp) = denoise_time.iter().filter(|t| t.0 == name).fold((0.0, 0.0), |a, t| (a.0 + t.1, a.1 + t.2));
        if mp > 0.0 { s / mp } else { 0.0 }
    };
    for m in &methods {
        let peak = match &sample_frame {
            Some(frame) => {
                let out = frames_dir.join("peak-memory.exr");
                let mut cmd = Command::new(&exe);
                cmd.arg("denoise").arg(frame).arg("-o").arg(&out);
                // The study chose its models (presets too, to compare): no second refusal here.
                cmd.args([
                    "--model",
                    &m.arg,
                    "--allow-untrained",
                    "--threads",
                    &threads.to_string(),
                    "-q",
                    "--separate",
                ]);
                let peak = run_measured(&mut cmd).with_context(|| format!("measuring {}", m.name))?.peak_mb;
                let _ = std::fs::remove_file(out);
                Some(peak)
            }
            None => None,
        };
        costs.push(Cost {
            method: m.name.clone(),
            flop_per_pixel: Some(m.denoiser.model().arch.flops_per_pixel()),
            seconds_per_mpix: per_mpix(&m.name),
            peak_mb: peak,
        });
    }
    if use_oidn {
        costs.push(Cost {
            method: "oidn".into(),
            flop_per_pixel: None,
            seconds_per_mpix: per_mpix("oidn"),
            peak_mb: oidn_peak,
        });
    }

    let csv = args.output.join("study.csv");
    std::fs::write(&csv, study::to_csv(&rows)).with_context(|| format!("{}: cannot write", csv.display()))?;
    let mut summary = study::summary(&rows, &costs);
    summary.push_str(&format!(
        "\n{w}×{h}, {threads} threads, sample counts {}, reference {} spp; render seconds are the simulator's, denoise \
         seconds the filter alone (kpcn: model loaded; OIDN: after a warm-up); peak RSS is a whole `kpcn denoise --separate` \
         process (OIDN: the Python process, numpy included).\n",
        args.spp, args.reference_spp
    ));
    let md = args.output.join("summary.md");
    std::fs::write(&md, &summary).with_context(|| format!("{}: cannot write", md.display()))?;
    for (scene, chart) in study::charts(&rows) {
        let png = args.output.join(format!("{scene}.png"));
        if let Err(e) = write_png(&chart, &png, 800, 520) {
            eprintln!("kpcn study: warning: {e}");
        }
    }
    if !args.quiet {
        println!("{summary}");
        println!("wrote {}, {} and one PNG per scene", csv.display(), md.display());
    }
    Ok(())
}
