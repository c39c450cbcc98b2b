//! `kpcn eval`: error of images against a reference.

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use kpcn::eval::plot::write_rgb_png;
use kpcn::eval::{Metrics, false_colour, metrics, relmse_map};
use kpcn::io::FrameBuffers;
use std::path::{Path, PathBuf};

/// Arguments of `kpcn eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// The reference (by default its root `R,G,B` are compared against).
    #[arg(long, short, value_name = "REF.exr")]
    pub reference: PathBuf,
    /// Layer of the reference to compare against: `rgb` (the root `R,G,B`, default) or a
    /// layer name (e.g. `ViewLayer.Combined` of a Blender multilayer EXR).
    #[arg(long, default_value = "rgb", value_name = "LAYER")]
    pub reference_channels: String,
    /// Images to score.
    #[arg(required = true, value_name = "IN.exr")]
    pub inputs: Vec<PathBuf>,
    /// Layer of the inputs to score: `auto` (`denoised` if present, else root `R,G,B`),
    /// `rgb` for the root, or a layer name.
    #[arg(long, default_value = "auto", value_name = "LAYER")]
    pub channels: String,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Table)]
    pub format: Format,
    /// Write a false-colour per-pixel relMSE map (PNG) per input into this folder.
    #[arg(long, value_name = "DIR")]
    pub error_maps: Option<PathBuf>,
}

/// Output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// Aligned columns.
    Table,
    /// One JSON document.
    Json,
    /// Comma-separated values with a header.
    Csv,
}

/// The three channels of `layer` in `fb`; a missing one is an error naming `flag`, the
/// option that picks the layer.
fn rgb_names(fb: &FrameBuffers, layer: &str, flag: &str) -> anyhow::Result<[String; 3]> {
    let layer = match layer {
        "auto" if fb.channel("denoised.R").is_some() => "denoised",
        "auto" | "rgb" => "",
        l => l,
    };
    let names = ["R", "G", "B"].map(|c| if layer.is_empty() { c.to_string() } else { format!("{layer}.{c}") });
    for n in &names {
        if fb.channel(n).is_none() {
            bail!(
                "{}: no channel `{n}` — pick the layer with {flag} (`kpcn info` lists them)",
                fb.display_path().display()
            );
        }
    }
    Ok(names)
}

fn planes<'a>(fb: &'a FrameBuffers, names: &[String; 3]) -> [&'a [f32]; 3] {
    [0, 1, 2].map(|c| fb.channel(&names[c]).expect("checked by rgb_names"))
}

fn write_map(path: &Path, map: &[f32], w: usize, h: usize) -> anyhow::Result<()> {
    let pixels: Vec<u8> = map.iter().flat_map(|&e| false_colour(e)).collect();
    write_rgb_png(path, w, h, &pixels).with_context(|| format!("{}: cannot write", path.display()))
}

/// Runs `kpcn eval`.
pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let reference = FrameBuffers::read(&args.reference)?;
    let ref_names = rgb_names(&reference, &args.reference_channels, "--reference-channels")?;
    let y = planes(&reference, &ref_names);
    let (w, h) = (reference.width(), reference.height());
    let mut rows: Vec<(String, String, Metrics)> = Vec::new();
    for input in &args.inputs {
        let fb = FrameBuffers::read(input)?;
        if (fb.width(), fb.height()) != (w, h) {
            bail!(
                "{}: is {}x{} but the reference {} is {w}x{h} — compare images of one size",
                input.display(),
                fb.width(),
                fb.height(),
                args.reference.display()
            );
        }
        let names = rgb_names(&fb, &args.channels, "--channels")?;
        let x = planes(&fb, &names);
        if let Some(dir) = &args.error_maps {
            std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
            let stem = input.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            write_map(&dir.join(format!("{stem}.relmse.png")), &relmse_map(x, y), w, h)?;
        }
        let layer = names[0].rsplit_once('.').map_or("rgb", |(l, _)| l).to_string();
        rows.push((input.display().to_string(), layer, metrics(x, y, w, h)));
    }
    let n = rows.len() as f64;
    let mean = Metrics {
        relmse: rows.iter().map(|r| r.2.relmse).sum::<f64>() / n,
        psnr: rows.iter().map(|r| r.2.psnr).sum::<f64>() / n,
        one_minus_ssim: rows.iter().map(|r| r.2.one_minus_ssim).sum::<f64>() / n,
        relmse_trimmed: [0, 1].map(|k| rows.iter().map(|r| r.2.relmse_trimmed[k]).sum::<f64>() / n),
        brightness: rows.iter().map(|r| r.2.brightness).sum::<f64>() / n,
    };
    match args.format {
        Format::Table => {
            let width = rows.iter().map(|r| r.0.len()).max().unwrap_or(4).max(4);
            println!(
                "{:<width$}  {:<10} {:>10} {:>8} {:>8} {:>12} {:>12} {:>10}",
                "file", "layer", "relMSE", "PSNR", "1-SSIM", "relMSE-0.1%", "relMSE-1%", "brightness"
            );
            let line = |f: &str, l: &str, m: &Metrics| {
                println!(
                    "{f:<width$}  {l:<10} {:>10.5} {:>8.3} {:>8.5} {:>12.5} {:>12.5} {:>10.4}",
                    m.relmse, m.psnr, m.one_minus_ssim, m.relmse_trimmed[0], m.relmse_trimmed[1], m.brightness
                )
            };
            for (f, l, m) in &rows {
                line(f, l, m);
            }
            if rows.len() > 1 {
                line("mean", "", &mean);
            }
        }
        Format::Csv => {
            println!(
                "file,layer,relmse,psnr,one_minus_ssim,relmse_drop_worst_0.1pct,relmse_drop_worst_1pct,brightness"
            );
            for (f, l, m) in &rows {
                println!(
                    "{f},{l},{},{},{},{},{},{}",
                    m.relmse, m.psnr, m.one_minus_ssim, m.relmse_trimmed[0], m.relmse_trimmed[1], m.brightness
                );
            }
        }
        Format::Json => {
            let metrics = |m: &Metrics| {
                serde_json::json!({"relmse": m.relmse, "psnr": m.psnr, "one_minus_ssim": m.one_minus_ssim,
                    "relmse_drop_worst_0.1pct": m.relmse_trimmed[0], "relmse_drop_worst_1pct": m.relmse_trimmed[1],
                    "brightness": m.brightness})
            };
            let item = |f: &str, l: &str, m: &Metrics| {
                let mut v = metrics(m);
                v["file"] = f.into();
                v["layer"] = l.into();
                v
            };
            let doc = serde_json::json!({
                "reference": args.reference.display().to_string(),
                "files": rows.iter().map(|(f, l, m)| item(f, l, m)).collect::<Vec<_>>(),
                "mean": metrics(&mean),
            });
            println!("{doc:#}");
        }
    }
    Ok(())
}
