//! Shared fixtures: small deterministic frames written through our own writer.
#![allow(dead_code)]

use kpcn::io::{Attribute, FrameBuffers, Output, OutputSpec, SampleFormat, SubimageInfo, WriteOptions};
use std::path::{Path, PathBuf};

/// The library's seeded generator, for fixtures.
pub use kpcn::rng::SplitMix64 as Rng;

/// Every channel of the native layout (ARCHITECTURE.md §Layout), with half buffers and variances.
pub fn native_channels() -> Vec<String> {
    let mut v: Vec<String> = ["R", "G", "B"].map(String::from).to_vec();
    v.extend(["R", "G", "B"].map(|c| format!("colorA.{c}")));
    v.push("colorVariance.Z".into());
    for q in ["diffuse", "specular", "albedo", "normal"] {
        for l in [q.to_string(), format!("{q}A")] {
            v.extend(["R", "G", "B"].map(|c| format!("{l}.{c}")));
        }
        v.push(format!("{q}Variance.Z"));
    }
    for q in ["depth", "visibility"] {
        v.extend([format!("{q}.Z"), format!("{q}A.Z"), format!("{q}Variance.Z")]);
    }
    v
}

/// A native-layout frame with random content and the channels starting with `drop` left out.
pub fn native_frame(w: usize, h: usize, seed: u64, drop: &[&str]) -> FrameBuffers {
    let mut fb = FrameBuffers::new(w, h);
    let mut rng = Rng(seed);
    for name in native_channels().iter().filter(|n| !drop.iter().any(|d| n.starts_with(d))) {
        let data = (0..w * h).map(|_| rng.uniform_f32()).collect();
        fb.insert(name, SampleFormat::Float, data).expect("size matches");
    }
    fb.set_attribute(Attribute::string("kpcn:scene", "fixture"));
    fb.set_attribute(Attribute::int("kpcn:spp", 16));
    fb
}

/// Writes `fb` into `dir/name` and returns the path.
pub fn write(fb: &FrameBuffers, dir: &Path, name: &str) -> PathBuf {
    let path = dir.join(name);
    fb.write(&path, &WriteOptions::default()).expect("fixture writes");
    path
}

/// The shared Cycles dev set, when this checkout has it beside it.
pub fn cycles_dev() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/cycles-dev");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("note: {} is absent; skipping the Cycles dev-set checks", dir.display());
        None
    }
}

/// Files in `dir` other than `keep` (to prove no temporary file was left behind).
pub fn stray_files(dir: &Path, keep: &[&str]) -> Vec<String> {
    std::fs::read_dir(dir)
        .expect("dir readable")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| !keep.contains(&n.as_str()))
        .collect()
}

/// A two-part EXR whose second part's data window (8×4) differs from the first's (16×8).
pub fn mismatched_parts(path: &Path) {
    let spec = |name, w: usize, h: usize| OutputSpec {
        part_name: name,
        info: SubimageInfo {
            x: 0,
            y: 0,
            width: w,
            height: h,
            full_x: 0,
            full_y: 0,
            // OpenEXR wants one display window for all parts; the data windows differ.
            full_width: 16,
            full_height: 8,
            nchannels: 1,
            tile_height: 0,
            deep: false,
        },
        channels: vec![("Y", SampleFormat::Float)],
        compression: "zip",
        attributes: &[],
    };
    let mut out = Output::create(path, &[spec("full", 16, 8), spec("half", 8, 4)], 1).unwrap();
    out.write_rows(0, 8, &[0.5; 16 * 8]).unwrap();
    out.next_part().unwrap();
    out.write_rows(0, 4, &[0.5; 8 * 4]).unwrap();
    out.close().unwrap();
}

/// Bytes no image reader accepts.
pub fn garbage(path: &Path) {
    std::fs::write(path, (0..4096u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect::<Vec<_>>()).unwrap();
}

/// A tiny multi-scale KPCN (2 pooling levels, 4…12 channels, 3×3 kernels): fast in tests.
pub fn tiny_multiscale(seed: u64) -> kpcn::model::Model {
    tiny_multiscale_levels(seed, 2)
}

/// [`tiny_multiscale`] with `levels` pooling levels: 5 gives the ladder's 192-px receptive
/// radius, beyond the 64 px a region reaches past the frame's edges.
pub fn tiny_multiscale_levels(seed: u64, levels: usize) -> kpcn::model::Model {
    multiscale_levels(seed, levels, 4)
}

/// A multi-scale KPCN of `levels` pooling levels and `channels` at full resolution (from
/// 32 its 3×3 layers take the convolutions' Winograd path).
pub fn multiscale_levels(seed: u64, levels: usize, channels: usize) -> kpcn::model::Model {
    use kpcn::model::{Architecture, Design, Kind, Model};
    let arch = Architecture {
        kind: Kind::Kpcn,
        design: Design::MultiScale,
        layers: levels,
        channels,
        conv_size: 3,
        kernel_size: 3,
        clamp: Default::default(),
        blend: Default::default(),
        variances: Default::default(),
        specular: Default::default(),
        exposure: Default::default(),
        specular_bound: None,
        diffuse_bound: None,
        diffuse_spread: None,
        diffuse_detail: None,
        gain: false,
        diffuse_input: Default::default(),
    };
    Model::xavier(arch, seed).unwrap()
}
