//! `kpcn info`: what a file holds and what the denoiser can use.

use clap::Args;
use kpcn::io::layout::{Layout, Mapping, MeanStatus};
use kpcn::io::{FrameBuffers, FrameReader, IoError, SampleFormat};
use std::path::PathBuf;

/// Arguments of `kpcn info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// Image files to describe.
    #[arg(required = true, value_name = "FILE")]
    pub files: Vec<PathBuf>,
    /// Channel naming convention; detected from the channel names when omitted.
    #[arg(long, value_name = "native|cycles|renderman", value_parser = clap::value_parser!(LayoutArg))]
    pub layout: Option<LayoutArg>,
    /// Also list every metadata attribute.
    #[arg(long)]
    pub metadata: bool,
    /// `table` for people; `json` (one array, an object per file) for pipelines.
    #[arg(long, value_enum, default_value_t = InfoFormat::Table)]
    pub format: InfoFormat,
}

/// `kpcn info` output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum InfoFormat {
    /// Aligned columns.
    Table,
    /// One JSON array, an object per file.
    Json,
}

/// A `--layout` value.
#[derive(Debug, Clone, Copy)]
pub struct LayoutArg(pub Layout);

impl std::str::FromStr for LayoutArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        s.parse().map(LayoutArg)
    }
}

/// Prints a report per file; fails if any file is unreadable or incomplete.
pub fn run(args: &InfoArgs) -> anyhow::Result<()> {
    let mut failures = 0usize;
    if args.format == InfoFormat::Json {
        let mut all = Vec::new();
        for path in &args.files {
            let doc = match summarize(path) {
                Ok((fb, chans)) => json_report(&fb, &chans, args),
                Err(e) => serde_json::json!({ "file": path, "error": e.to_string() }),
            };
            failures += usize::from(doc.get("error").is_some() || doc["verdict"] == "incomplete");
            all.push(doc);
        }
        println!("{}", serde_json::to_string_pretty(&all)?);
        return match failures {
            0 => Ok(()),
            n => Err(crate::cli::Reported(n).into()),
        };
    }
    for (i, path) in args.files.iter().enumerate() {
        if i > 0 {
            println!();
        }
        let result = summarize(path).and_then(|(fb, chans)| report(&fb, &chans, args));
        if let Err(e) = result {
            eprintln!("kpcn: error: {e}");
            failures += 1;
        }
    }
    match failures {
        0 => Ok(()),
        n => Err(crate::cli::Reported(n).into()),
    }
}

/// One channel as `info` reports it.
struct Channel {
    name: String,
    format: SampleFormat,
    /// Samples that are NaN or ±Inf.
    nonfinite: usize,
}

/// A file's header and its channels' non-finite counts, read a band of rows at a time so
/// memory stays bounded whatever the frame's size (and a forged header cannot make it
/// allocate the size it claims: `FrameReader::open` checks that first).
fn summarize(path: &std::path::Path) -> Result<(FrameBuffers, Vec<Channel>), IoError> {
    let mut reader = FrameReader::open(path)?;
    let header = reader.header().clone();
    let mut channels: Vec<Channel> =
        reader.channel_formats().map(|(n, f)| Channel { name: n.to_string(), format: f, nonfinite: 0 }).collect();
    reader.for_each_band(64 << 20, |band| {
        for (c, p) in channels.iter_mut().zip(band.planes()) {
            c.nonfinite += p.data.iter().filter(|v| !v.is_finite()).count();
        }
    })?;
    Ok((header, channels))
}

/// Channels grouped by layer (the name before the last dot), in file order.
fn layers(channels: &[Channel]) -> Vec<(&str, Vec<&Channel>)> {
    let mut out: Vec<(&str, Vec<&Channel>)> = Vec::new();
    for c in channels {
        let layer = c.name.rsplit_once('.').map_or("", |(l, _)| l);
        match out.iter_mut().find(|(l, _)| *l == layer) {
            Some((_, v)) => v.push(c),
            None => out.push((layer, vec![c])),
        }
    }
    out
}

/// The verdict on a mapping: `complete`, `usable` (variances estimated) or `incomplete`.
fn verdict(mapping: &Mapping) -> &'static str {
    if !mapping.missing_required().is_empty() {
        "incomplete"
    } else if mapping.estimated_variances().is_empty() {
        "complete"
    } else {
        "usable"
    }
}

/// Everything the table shows, as JSON.
fn json_report(fb: &FrameBuffers, chans: &[Channel], args: &InfoArgs) -> serde_json::Value {
    use serde_json::json;
    let mapping = Mapping::new(chans.iter().map(|c| c.name.as_str()), args.layout.map(|l| l.0));
    let w = &fb.window;
    let channels: Vec<_> =
        chans.iter().map(|c| json!({ "name": c.name, "format": c.format.name(), "nonfinite": c.nonfinite })).collect();
    let inputs: Vec<_> = mapping
        .entries
        .iter()
        .map(|e| {
            json!({
                "input": e.quantity.name(),
                "required": e.quantity.required(),
                "mean": e.mean_status().to_string(),
                "mean_source": e.mean.to_string(),
                "variance": e.variance_status().to_string(),
                "variance_source": e.variance_description(),
            })
        })
        .collect();
    let mut doc = json!({
        "file": fb.display_path(),
        "width": fb.width(),
        "height": fb.height(),
        "data_window": { "x": w.x, "y": w.y },
        "display_window": { "x": w.full_x, "y": w.full_y, "width": w.full_width, "height": w.full_height },
        "parts": fb.parts,
        "channels": channels,
        "nonfinite_samples": chans.iter().map(|c| c.nonfinite).sum::<usize>(),
        "layout": mapping.layout.name(),
        "layout_detected": mapping.detected,
        "view_layer": mapping.view_layer,
        "view_layers": mapping.view_layers,
        "inputs": inputs,
        "missing": mapping.missing_required(),
        "verdict": verdict(&mapping),
    });
    if args.metadata {
        doc["metadata"] = fb.attributes.iter().map(|a| (a.name.clone(), json!(a.text))).collect();
    }
    doc
}

fn formats(planes: &[&Channel]) -> String {
    let first = planes[0].format;
    if planes.iter().all(|p| p.format == first) {
        first.name().to_string()
    } else {
        planes.iter().map(|p| p.format.name()).collect::<Vec<_>>().join(" ")
    }
}

fn report(fb: &FrameBuffers, chans: &[Channel], args: &InfoArgs) -> Result<(), IoError> {
    let w = &fb.window;
    println!("{}", fb.display_path().display());
    println!(
        "  resolution  {}x{} (data window at {},{}; display window {}x{} at {},{})",
        fb.width(),
        fb.height(),
        w.x,
        w.y,
        w.full_width,
        w.full_height,
        w.full_x,
        w.full_y
    );
    println!("  parts       {}", fb.parts);
    println!("  channels    {}", chans.len());
    let layers = layers(chans);
    // Blender's pass names run long ("ViewLayer.Denoising Albedo"): size the column to them.
    let width = layers.iter().map(|(l, _)| l.chars().count()).max().unwrap_or(0).max(22);
    for (layer, planes) in layers {
        let comps: Vec<&str> =
            planes.iter().map(|p| p.name.rsplit_once('.').map_or(p.name.as_str(), |(_, c)| c)).collect();
        let bad: usize = planes.iter().map(|p| p.nonfinite).sum();
        let bad = if bad > 0 { format!("  ({bad} NaN/Inf samples)") } else { String::new() };
        let name = if layer.is_empty() { "(root)" } else { layer };
        println!("    {name:<width$} {:<12} {}{bad}", comps.join(" "), formats(&planes));
    }
    if args.metadata {
        println!("  metadata");
        for a in &fb.attributes {
            println!("    {:<28} {:<8} {}", a.name, a.type_name, a.text);
        }
    }

    let mapping = Mapping::new(chans.iter().map(|c| c.name.as_str()), args.layout.map(|l| l.0));
    let how = if mapping.detected { "auto-detected" } else { "from --layout" };
    println!("  layout      {} ({how})", mapping.layout);
    if let Some(v) = &mapping.view_layer {
        println!("  view layer  {v} (of {}: {})", mapping.view_layers.len(), mapping.view_layers.join(", "));
    }
    println!("  KPCN inputs");
    for e in &mapping.entries {
        let q = e.quantity;
        let status = match (e.mean_status(), q.required()) {
            (MeanStatus::Missing, false) => "absent (optional: not a network input)".to_string(),
            (s, _) => format!("{s:<8} {}", e.mean),
        };
        println!("    {:<11} {status}", q.name());
        if e.mean_status() != MeanStatus::Missing {
            println!("    {:<11} variance {:<9} {}", "", e.variance_status(), e.variance_description());
        }
    }
    let missing = mapping.missing_required();
    let bad: usize = chans.iter().map(|c| c.nonfinite).sum();
    let bad = if bad > 0 {
        format!("; but {bad} samples are NaN/Inf (the denoiser treats them as 0)")
    } else {
        String::new()
    };
    if missing.is_empty() {
        let estimated: Vec<&str> = mapping.estimated_variances().iter().map(|e| e.quantity.name()).collect();
        if estimated.is_empty() {
            println!("  verdict     complete: every network input is in the file{bad}");
        } else {
            println!(
                "  verdict     usable: variance of {} will be estimated (less accurate than rendered variance){bad}",
                estimated.join(", ")
            );
        }
        Ok(())
    } else {
        println!("  verdict     incomplete: the denoiser cannot run on this file");
        Err(IoError::MissingChannels {
            path: fb.display_path(),
            layout: mapping.layout.to_string(),
            missing,
            hint: mapping.hint().into(),
        })
    }
}
