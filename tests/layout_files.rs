//! Renderer layouts map real files' channels onto the KPCN inputs.

use crate::util::{Rng, cycles_dev, native_frame, write};
use kpcn::io::layout::{Layout, Mapping, Quantity, VarianceStatus};
use kpcn::io::{FrameBuffers, IoError, SampleFormat};

/// A Cycles multilayer frame with the given pass spelling (`DiffDir` or `Diffuse Direct`).
fn cycles_frame(w: usize, h: usize, long_names: bool) -> FrameBuffers {
    let mut fb = FrameBuffers::new(w, h);
    let mut rng = Rng(11);
    let passes: &[(&str, &str, &[&str])] = &[
        ("Combined", "Combined", &["R", "G", "B", "A"]),
        ("DiffDir", "Diffuse Direct", &["R", "G", "B"]),
        ("DiffInd", "Diffuse Indirect", &["R", "G", "B"]),
        ("DiffCol", "Diffuse Color", &["R", "G", "B"]),
        ("GlossDir", "Glossy Direct", &["R", "G", "B"]),
        ("Normal", "Normal", &["X", "Y", "Z"]),
        ("Depth", "Depth", &["Z"]),
    ];
    for (short, long, comps) in passes {
        let pass = if long_names { long } else { short };
        for c in *comps {
            let data = (0..w * h).map(|_| 2.0 * rng.uniform_f32()).collect();
            fb.insert(&format!("ViewLayer.{pass}.{c}"), SampleFormat::Float, data).unwrap();
        }
    }
    // One camera miss.
    let mut depth = fb.channel("ViewLayer.Depth.Z").unwrap().to_vec();
    depth[0] = 1e10;
    fb.insert("ViewLayer.Depth.Z", SampleFormat::Float, depth).unwrap();
    fb
}

#[test]
fn cycles_passes_map_onto_the_kpcn_inputs() {
    let dir = tempfile::tempdir().unwrap();
    for long_names in [false, true] {
        let path = write(&cycles_frame(9, 5, long_names), dir.path(), "cycles.exr");
        let fb = FrameBuffers::read(&path).unwrap();
        let m = Mapping::for_frame(&fb, None);
        assert_eq!(m.layout, Layout::Cycles, "long names: {long_names}");
        assert!(m.missing_required().is_empty(), "{:?}", m.missing_required());
        let k = m.extract(&fb).unwrap();
        let pass = |short: &str, long: &str, c: &str| {
            let p = if long_names { long } else { short };
            fb.channel(&format!("ViewLayer.{p}.{c}")).unwrap().to_vec()
        };
        for (i, c) in ["R", "G", "B"].iter().enumerate() {
            let dir_ = pass("DiffDir", "Diffuse Direct", c);
            let ind = pass("DiffInd", "Diffuse Indirect", c);
            let col = pass("DiffCol", "Diffuse Color", c);
            let comb = pass("Combined", "Combined", c);
            for p in 0..45 {
                let diffuse = (dir_[p] + ind[p]) * col[p];
                assert_eq!(k.diffuse[i][p], diffuse);
                assert_eq!(k.specular[i][p], comb[p] - diffuse);
                assert_eq!(k.color[i][p], comb[p]);
                assert_eq!(k.albedo[i][p], col[p]);
            }
        }
        assert_eq!(k.normal[1], pass("Normal", "Normal", "Y"));
        assert_eq!(k.depth[0], 0.0, "a 1e10 miss becomes 0");
        assert_eq!(k.depth[1], pass("Depth", "Depth", "Z")[1]);
        assert!(k.visibility.is_none());
        assert_eq!(m.entry_for(Quantity::Diffuse).variance_status(), VarianceStatus::Estimated);
        assert!(k.diffuse_variance.iter().all(|v| v.is_finite() && *v >= 0.0));
    }
}

#[test]
fn native_variances_come_from_the_file_or_the_half_buffer() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&native_frame(6, 4, 12, &["diffuseVariance"]), dir.path(), "n.exr");
    let fb = FrameBuffers::read(&path).unwrap();
    let m = Mapping::for_frame(&fb, None);
    assert_eq!(m.entry_for(Quantity::Specular).variance_status(), VarianceStatus::Present);
    assert_eq!(m.entry_for(Quantity::Diffuse).variance_status(), VarianceStatus::Estimated);
    let k = m.extract(&fb).unwrap();
    assert_eq!(k.specular_variance, fb.channel("specularVariance.Z").unwrap());
    // Centre pixel: 3×3 box of the channel-averaged (mean − half)².
    let (w, x, y) = (6, 2, 1);
    let mut expect = 0f64;
    for yy in y - 1..=y + 1 {
        for xx in x - 1..=x + 1 {
            let i = yy * w + xx;
            let mut s = 0f64;
            for c in ["R", "G", "B"] {
                let d =
                    fb.channel(&format!("diffuse.{c}")).unwrap()[i] - fb.channel(&format!("diffuseA.{c}")).unwrap()[i];
                s += (d * d) as f64;
            }
            expect += s / 3.0;
        }
    }
    let got = k.diffuse_variance[y * w + x] as f64;
    assert!((got - expect / 9.0).abs() < 1e-6, "{got} vs {}", expect / 9.0);
}

#[test]
fn missing_channels_are_an_error_that_names_them() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&native_frame(4, 4, 13, &["albedo", "depth"]), dir.path(), "partial.exr");
    let fb = FrameBuffers::read(&path).unwrap();
    let e = Mapping::for_frame(&fb, None).extract(&fb).unwrap_err();
    assert!(matches!(e, IoError::MissingChannels { .. }));
    let msg = e.to_string();
    for c in ["albedo.R", "albedo.G", "albedo.B", "depth.Z"] {
        assert!(msg.contains(c), "{msg}");
    }
    assert!(msg.contains("partial.exr") && msg.contains(" — "), "{msg}");
}

#[test]
fn the_cycles_dev_set_has_every_input() {
    let Some(dir) = cycles_dev() else { return };
    let (mut checked, mut scenes) = (0, 0);
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        scenes += usize::from(name.ends_with("-ref.exr"));
        let is_frame = name.ends_with("spp.exr") || name.ends_with("-ref.exr");
        if !is_frame {
            continue;
        }
        let fb = FrameBuffers::read(&path).unwrap();
        let m = Mapping::for_frame(&fb, None);
        assert_eq!(m.layout, Layout::Native, "{name}");
        assert!(m.missing_required().is_empty(), "{name}: {:?}", m.missing_required());
        if name.ends_with("spp.exr") {
            for q in Quantity::ALL.iter().filter(|q| q.required()) {
                assert_eq!(m.entry_for(*q).variance_status(), VarianceStatus::Present, "{name} {q:?}");
            }
        }
        let k = m.extract(&fb).unwrap();
        assert_eq!((k.width, k.height), (320, 180));
        checked += 1;
    }
    assert!(scenes >= 2, "{scenes} scenes");
    assert_eq!(checked, scenes * 4, "3 noisy frames and a reference for each of the {scenes} scenes");
}
