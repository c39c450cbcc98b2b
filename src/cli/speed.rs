//! `kpcn speed`: seconds per frame of each model's forward pass, in process, beside Intel
//! Open Image Denoise measured in the same run on the same frame (the machine is shared
//! and noisy, so only same-run ratios mean anything).

use super::study::{Oidn, oidn};
use crate::denoise::{Denoiser, Options};
use crate::io::layout::Mapping;
use crate::io::{FrameBuffers, WriteOptions};
use crate::model::Model;
use crate::sim::families::generate;
use crate::sim::{RenderOptions, render_to_dir};
use anyhow::Context;
use clap::Args;

/// Arguments of `kpcn speed`.
#[derive(Debug, Args)]
pub struct SpeedArgs {
    /// Models, comma-separated: `default`, preset names, or .safetensors files.
    #[arg(long, default_value = "default", value_name = "M,M,…")]
    pub models: String,
    /// Frame size.
    #[arg(long, default_value = "1280x720", value_parser = super::render::parse_resolution, value_name = "WxH")]
    pub resolution: (usize, usize),
    /// Scene family of the frame (`kpcn scenes` lists them).
    #[arg(long, default_value = "product")]
    pub family: String,
    /// Timed runs per model after a warm-up; the fastest counts.
    #[arg(long, default_value_t = 3, value_name = "N")]
    pub repeat: usize,
    /// OIDN (hdr + albedo + normal, quality high, via `pyoidn`) as the peer.
    #[arg(long, value_enum, default_value_t = Oidn::Auto)]
    pub oidn: Oidn,
    /// Threads.
    #[arg(long, default_value_t = 2, value_name = "N")]
    pub threads: usize,
}

/// Runs `kpcn speed`.
pub fn run(args: &SpeedArgs) -> anyhow::Result<()> {
    let (w, h) = args.resolution;
    let desc = generate(&args.family, 1).with_context(|| format!("--family: no family `{}`", args.family))?;
    let use_oidn = args.oidn.enabled()?;
    let threads = args.threads.max(1);
    let dir = std::env::temp_dir().join(format!("kpcn-speed-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let result = (|| -> anyhow::Result<()> {
        let opts = RenderOptions { width: w, height: h, checkpoints: vec![16], sample_seed: 1, nee: true };
        let written = render_to_dir(&desc, &opts, None, &dir, &WriteOptions::default(), &|_| {})?;
        let fb = FrameBuffers::read(&written.noisy[0].1)?;
        let k = Mapping::for_frame(&fb, None).extract(&fb)?;
        let mpix = (w * h) as f64 / 1e6;
        println!("{} {w}×{h}, {threads} threads, fastest of {} after a warm-up", desc.name, args.repeat.max(1));
        println!("{:<28} {:>12} {:>9} {:>9} {:>9}", "method", "kFLOP/px", "seconds", "MPix/s", "× OIDN");
        let mut rows = Vec::new();
        for m in args.models.split(',').map(str::trim) {
            let model = Model::resolve(m)?;
            let flops = model.arch.flops_per_pixel();
            let d = Denoiser::new(model, Options { threads: Some(threads), ..Options::default() })?;
            d.denoise(&k, &|_| true)?;
            let mut best = f64::INFINITY;
            for _ in 0..args.repeat.max(1) {
                let t = std::time::Instant::now();
                d.denoise(&k, &|_| true)?;
                best = best.min(t.elapsed().as_secs_f64());
            }
            rows.push((format!("kpcn {m}"), Some(flops / 1e3), best));
        }
        let oidn_secs = if use_oidn {
            let (_, secs, _) = oidn(&k, &dir, threads)?;
            rows.push(("oidn (high)".into(), None, secs));
            Some(secs)
        } else {
            None
        };
        for (name, kflop, secs) in rows {
            let kflop = kflop.map_or("—".into(), |f| format!("{f:.1}"));
            let ratio = oidn_secs.map_or("—".into(), |o| format!("{:.2}", secs / o));
            println!("{name:<28} {kflop:>12} {secs:>9.3} {:>9.2} {ratio:>9}", mpix / secs);
        }
        Ok(())
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}
