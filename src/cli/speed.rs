//! `kpcn speed`: seconds per frame of each model's forward pass, in process, beside Intel
//! Open Image Denoise measured in the same run on the same frame (the machine is shared
//! and noisy, so only same-run ratios mean anything).

use super::eval::Format;
use super::study::{Oidn, oidn};
use anyhow::Context;
use candle_core::{Device, Tensor, Var};
use clap::Args;
use kpcn::denoise::{Denoiser, Options};
use kpcn::io::layout::Mapping;
use kpcn::io::{FrameBuffers, WriteOptions};
use kpcn::kernel::conv::{ConvLayer, conv};
use kpcn::kernel::ops::conv2d;
use kpcn::kernel::planes::Planes;
use kpcn::model::Model;
use kpcn::model::{Design, multiscale};
use kpcn::sim::families::generate;
use kpcn::sim::{RenderOptions, render_to_dir};

/// Arguments of `kpcn speed`.
#[derive(Debug, Args)]
pub struct SpeedArgs {
    /// Models, comma-separated: `default`, preset names, or .safetensors files.
    #[arg(long, default_value = "default", value_name = "M,M,…")]
    pub models: String,
    /// Frame sizes, comma-separated (e.g. `1280x720,1920x1080,3840x2160`); `--layers`
    /// uses the first.
    #[arg(long, default_value = "1280x720", value_delimiter = ',', value_parser = super::render::parse_resolution, value_name = "WxH,…")]
    pub resolution: Vec<(usize, usize)>,
    /// Scene family of the frame (`kpcn scenes` lists them).
    #[arg(long, default_value = "product")]
    pub family: String,
    /// Timed runs per model, and of OIDN, after a warm-up on the frame; the fastest counts.
    #[arg(long, default_value_t = 3, value_name = "N")]
    pub repeat: usize,
    /// OIDN (hdr + albedo + normal, quality high, via `pyoidn`) as the peer.
    #[arg(long, value_enum, default_value_t = Oidn::Auto)]
    pub oidn: Oidn,
    /// Thread counts, comma-separated (e.g. `1,2` for the scaling); `--layers` uses the
    /// first.
    #[arg(long, default_value = "2", value_delimiter = ',', value_name = "N,…")]
    pub threads: Vec<usize>,
    /// Instead of whole frames, time each convolution shape of the first model: forward at
    /// the frame size's scales (as `kpcn denoise` runs it) and forward + backward on a
    /// training batch (6 patches of 64² plus context). GFLOP/s counts a direct
    /// convolution's multiply-adds, so 3×3 layers that `kpcn denoise` runs by Winograd's
    /// minimal filtering (F(4, 3) at full and half resolution from 16 input channels,
    /// F(2, 3) below from 32) read up to 2× or 1.5× the machine's peak.
    /// `benches/conv_vs_torch.py` sets PyTorch beside these numbers.
    #[arg(long)]
    pub layers: bool,
    /// Output format of `--layers`.
    #[arg(long, value_enum, default_value_t = Format::Table)]
    pub format: Format,
}

/// Runs `kpcn speed`.
pub fn run(args: &SpeedArgs) -> anyhow::Result<()> {
    if args.layers {
        return layers(args);
    }
    let desc = generate(&args.family, 1).with_context(|| format!("--family: no family `{}`", args.family))?;
    let use_oidn = args.oidn.enabled()?;
    let dir = std::env::temp_dir().join(format!("kpcn-speed-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let result = (|| -> anyhow::Result<()> {
        let models: Vec<(&str, Model)> = args
            .models
            .split(',')
            .map(str::trim)
            .map(|m| Ok((m, Model::resolve(m)?)))
            .collect::<anyhow::Result<_>>()?;
        println!(
            "{}, fastest of {} after a warm-up, OIDN's the same way in the same run",
            desc.name,
            args.repeat.max(1)
        );
        println!(
            "{:<11} {:>7} {:<24} {:>9} {:>9} {:>9} {:>9}",
            "frame", "threads", "method", "kFLOP/px", "seconds", "MPix/s", "× OIDN"
        );
        for &(w, h) in &args.resolution {
            let opts = RenderOptions::new(w, h, vec![16], 1);
            let written = render_to_dir(&desc, &opts, None, &dir, &WriteOptions::default(), &|_| {})?;
            let fb = FrameBuffers::read(&written.noisy[0].1)?;
            let k = Mapping::for_frame(&fb, None).extract(&fb)?;
            drop(fb);
            let mpix = (w * h) as f64 / 1e6;
            for &threads in &args.threads {
                let threads = threads.max(1);
                let mut rows = Vec::new();
                for (m, model) in &models {
                    let flops = model.arch.flops_per_pixel();
                    let d = Denoiser::new(model.clone(), Options { threads: Some(threads), ..Options::default() })?;
                    let secs = fastest(args.repeat, || {
                        d.denoise(&k, &|_| true)?;
                        Ok(())
                    })?;
                    rows.push((format!("kpcn {m}"), Some(flops / 1e3), secs));
                }
                let oidn_secs = if use_oidn {
                    let (_, secs, _) = oidn(&k, &dir, threads, args.repeat)?;
                    rows.push(("oidn (high)".into(), None, secs));
                    Some(secs)
                } else {
                    None
                };
                for (name, kflop, secs) in rows {
                    let kflop = kflop.map_or("—".into(), |f| format!("{f:.1}"));
                    let ratio = oidn_secs.map_or("—".into(), |o| format!("{:.2}", secs / o));
                    println!(
                        "{:<11} {threads:>7} {name:<24} {kflop:>9} {secs:>9.3} {:>9.2} {ratio:>9}",
                        format!("{w}×{h}"),
                        mpix / secs
                    );
                }
            }
        }
        Ok(())
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// One timed convolution shape.
struct LayerTime {
    /// `fwd` (inference) or `fwd+bwd` (a training batch).
    pass: &'static str,
    cin: usize,
    cout: usize,
    k: usize,
    batch: usize,
    w: usize,
    h: usize,
    seconds: f64,
}

impl LayerTime {
    /// Useful FLOPs: 2·cout·cin·k² per pixel forward, three times that forward + backward.
    fn gflop(&self) -> f64 {
        let pass = if self.pass == "fwd" { 1.0 } else { 3.0 };
        pass * 2.0 * (self.cout * self.cin * self.k * self.k * self.batch * self.w * self.h) as f64 / 1e9
    }
}

/// The fastest of `repeat` runs of `f`, after one warm-up run.
fn fastest(repeat: usize, mut f: impl FnMut() -> anyhow::Result<()>) -> anyhow::Result<f64> {
    f()?;
    let mut best = f64::INFINITY;
    for _ in 0..repeat.max(1) {
        let t = std::time::Instant::now();
        f()?;
        best = best.min(t.elapsed().as_secs_f64());
    }
    Ok(best)
}

/// A scalar whose backward pass hands `g` (times the incoming gradient) to its operand
/// `y`: seeds a backward pass with a given output gradient, as PyTorch's `y.backward(g)`
/// does, so the timing is the convolution's and not that of candle's generic ops. Its
/// value (zero) is never used.
struct Seed(Tensor);

impl candle_core::CustomOp1 for Seed {
    fn name(&self) -> &'static str {
        "kpcn-speed-seed"
    }

    fn cpu_fwd(
        &self,
        _: &candle_core::CpuStorage,
        _: &candle_core::Layout,
    ) -> candle_core::Result<(candle_core::CpuStorage, candle_core::Shape)> {
        Ok((candle_core::CpuStorage::F32(vec![0.0]), candle_core::Shape::from(())))
    }

    fn bwd(&self, _: &Tensor, _: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        Ok(Some(self.0.affine(f64::from(grad.to_scalar::<f32>()?), 0.0)?))
    }
}

/// `kpcn speed --layers`.
fn layers(args: &SpeedArgs) -> anyhow::Result<()> {
    let name = args.models.split(',').next().unwrap_or("default").trim();
    let model = Model::resolve(name)?;
    let arch = model.arch;
    anyhow::ensure!(arch.design == Design::MultiScale, "--layers times the multi-scale design; `{name}` is flat");
    let threads = args.threads.first().copied().unwrap_or(2).max(1);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
    let (fw, fh) = args.resolution.first().copied().unwrap_or((1280, 720));
    let (m, _) = arch.train_margins();
    let (batch, side) = (6, 64 + 2 * m);
    let shapes = multiscale::layer_shapes(&arch);
    // Inference runs the full-resolution head split in two (see model::pyramid).
    let (_, head) = multiscale::layer_offsets(&arch);
    let last = shapes.len() - 1;
    let (c1, outs) = (multiscale::width(&arch, 1), shapes[last].0);
    let mut inference: Vec<(usize, usize, usize, usize)> = Vec::new();
    for (i, &(o, n, k)) in shapes.iter().enumerate() {
        let s = multiscale::layer_scale(&arch, i);
        if i == last && i >= head && s == 0 {
            inference.push((o, c1, 1, 1));
            inference.push((outs, n - c1, 1, 0));
        } else {
            inference.push((o, n, k, s));
        }
    }
    let mut rows = Vec::new();
    let mut seen = std::collections::HashSet::new();
    pool.install(|| -> anyhow::Result<()> {
        for &(cout, cin, k, s) in &inference {
            let (w, h) = (fw >> s, fh >> s);
            if !seen.insert(("fwd", cout, cin, k, w, h)) {
                continue;
            }
            let x = Planes::from_vec(cin, w, h, kpcn::rng::SplitMix64(1).centred(cin * w * h));
            let layer = ConvLayer::new(&kpcn::rng::SplitMix64(2).centred(cout * cin * k * k), &vec![0.0; cout], cin, k);
            let layer = multiscale::inference_layer(&arch, s, layer);
            let seconds = fastest(args.repeat, || {
                std::hint::black_box(conv(&x, &layer, true));
                Ok(())
            })?;
            rows.push(LayerTime { pass: "fwd", cin, cout, k, batch: 1, w, h, seconds });
        }
        for (i, &(cout, cin, k)) in shapes.iter().enumerate() {
            let w = side >> multiscale::layer_scale(&arch, i);
            if !seen.insert(("fwd+bwd", cout, cin, k, w, w)) {
                continue;
            }
            let dev = Device::Cpu;
            let x = Var::from_vec(kpcn::rng::SplitMix64(3).centred(batch * cin * w * w), (batch, cin, w, w), &dev)?;
            let wt = Var::from_vec(kpcn::rng::SplitMix64(4).centred(cout * cin * k * k), (cout, cin, k, k), &dev)?;
            let b = Var::from_vec(vec![0.01f32; cout], cout, &dev)?;
            let g =
                Tensor::from_vec(kpcn::rng::SplitMix64(5).centred(batch * cout * w * w), (batch, cout, w, w), &dev)?;
            let seconds = fastest(args.repeat, || {
                let y = conv2d(x.as_tensor(), wt.as_tensor(), b.as_tensor(), true)?;
                std::hint::black_box(y.apply_op1(Seed(g.clone()))?.backward()?);
                Ok(())
            })?;
            rows.push(LayerTime { pass: "fwd+bwd", cin, cout, k, batch, w, h: w, seconds });
        }
        Ok(())
    })?;
    match args.format {
        Format::Json => {
            let items: Vec<serde_json::Value> = rows
                .iter()
                .map(|r| {
                    serde_json::json!({
                        "pass": r.pass, "cin": r.cin, "cout": r.cout, "k": r.k, "batch": r.batch,
                        "width": r.w, "height": r.h, "seconds": r.seconds, "gflops": r.gflop() / r.seconds,
                    })
                })
                .collect();
            println!(
                "{}",
                serde_json::to_string_pretty(
                    &serde_json::json!({ "model": name, "threads": threads, "layers": items })
                )?
            );
        }
        Format::Table | Format::Csv => {
            println!("{name}: each convolution shape, {threads} threads, fastest of {}", args.repeat.max(1));
            println!("{:<8} {:>10} {:>4} {:>14} {:>10} {:>9}", "pass", "cin→cout", "k", "batch×W×H", "ms", "GFLOP/s");
            for r in &rows {
                let shape = format!("{}→{}", r.cin, r.cout);
                let size = format!("{}×{}×{}", r.batch, r.w, r.h);
                println!(
                    "{:<8} {shape:>10} {:>4} {size:>14} {:>10.2} {:>9.1}",
                    r.pass,
                    r.k,
                    r.seconds * 1e3,
                    r.gflop() / r.seconds
                );
            }
        }
    }
    Ok(())
}
