//! Frames survive write → read exactly: samples, formats, windows, metadata, parts.

use crate::util::{Rng, native_frame, stray_files, write};
use kpcn::io::{Attribute, FrameBuffers, FrameReader, IoError, Part, SampleFormat, Window, WriteOptions};

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn f32_channels_round_trip_bit_exact() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (37, 23);
    let mut rng = Rng(7);
    // Random bit patterns cover normals, denormals, huge values and both signs;
    // NaN payloads are not promised, so patterns that are NaN become +Inf.
    let special = [0.0, -0.0, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, f32::MIN_POSITIVE, 1e-45, 1e30];
    let data: Vec<f32> = (0..w * h)
        .map(|i| {
            let v = special.get(i).copied().unwrap_or_else(|| f32::from_bits(rng.next_u64() as u32));
            if v.is_nan() { f32::INFINITY } else { v }
        })
        .collect();
    let mut fb = FrameBuffers::new(w, h);
    fb.insert("R", SampleFormat::Float, data.clone()).unwrap();
    let path = write(&fb, dir.path(), "f32.exr");
    let back = FrameBuffers::read(&path).unwrap();
    assert_eq!(bits(back.channel("R").unwrap()), bits(&data));
    assert_eq!(back.plane("R").unwrap().format, SampleFormat::Float);
}

#[test]
fn f16_channels_round_trip_bit_exact_for_every_half_value() {
    let dir = tempfile::tempdir().unwrap();
    // 256×256 pixels hold all 65536 half bit patterns.
    let data: Vec<f32> = (0..=u16::MAX).map(|b| half::f16::from_bits(b).to_f32()).collect();
    let mut fb = FrameBuffers::new(256, 256);
    fb.insert("diffuse.R", SampleFormat::Half, data.clone()).unwrap();
    fb.insert("diffuse.G", SampleFormat::Float, data.clone()).unwrap();
    let path = write(&fb, dir.path(), "f16.exr");
    let back = FrameBuffers::read(&path).unwrap();
    let r = back.plane("diffuse.R").unwrap();
    assert_eq!(r.format, SampleFormat::Half);
    assert_eq!(back.plane("diffuse.G").unwrap().format, SampleFormat::Float);
    for (i, (a, b)) in data.iter().zip(&r.data).enumerate() {
        if a.is_nan() {
            assert!(b.is_nan(), "pattern {i:#06x}");
        } else {
            assert_eq!(a.to_bits(), b.to_bits(), "pattern {i:#06x}");
        }
    }
}

#[test]
fn float_channels_read_natively_beside_half_ones_keep_their_bits() {
    // Float channels between half ones: a read of just those is OpenImageIO's native path
    // (no conversion buffer), of all of them its converting one; both give the same bits.
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (19, 40);
    let mut rng = Rng(11);
    let mut fb = FrameBuffers::new(w, h);
    let mut values = Vec::new();
    for (name, format) in
        [("a", SampleFormat::Half), ("b", SampleFormat::Float), ("c", SampleFormat::Float), ("d", SampleFormat::Half)]
    {
        let v: Vec<f32> = (0..w * h).map(|_| (rng.next_u64() % 60_000) as f32 / 7.0 - 4000.0).collect();
        let v: Vec<f32> =
            if format == SampleFormat::Half { v.iter().map(|&x| half::f16::from_f32(x).to_f32()).collect() } else { v };
        fb.insert(name, format, v.clone()).unwrap();
        values.push((name, v));
    }
    let path = write(&fb, dir.path(), "mixed.exr");
    let mut reader = FrameReader::open(&path).unwrap();
    let floats = reader.read_band(Some(&["b", "c"]), 5, 33).unwrap();
    let all = reader.read_band(None, 0, h).unwrap();
    for (name, v) in &values {
        assert_eq!(bits(all.channel(name).unwrap()), bits(v), "{name}");
        if ["b", "c"].contains(name) {
            assert_eq!(bits(floats.channel(name).unwrap()), bits(&v[5 * w..33 * w]), "{name}");
        }
    }
}

#[test]
fn metadata_survives_a_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let mut fb = native_frame(8, 4, 1, &[]);
    fb.set_attribute(Attribute::float("kpcn:exposure", 1.5));
    fb.set_attribute(Attribute::string("kpcn:note", "rendered by a fixture — ünïcode ok"));
    let m: Vec<u8> = (0..16).flat_map(|i| (i as f32).to_ne_bytes()).collect();
    fb.set_attribute(Attribute {
        name: "worldToCamera".into(),
        type_name: "matrix".into(),
        text: String::new(),
        raw: Some(m.clone()),
    });
    let path = write(&fb, dir.path(), "meta.exr");
    let back = FrameBuffers::read(&path).unwrap();
    assert_eq!(back.attribute("kpcn:scene"), Some("fixture"));
    assert_eq!(back.attribute("kpcn:spp"), Some("16"));
    assert_eq!(back.attribute("kpcn:exposure"), Some("1.5"));
    assert_eq!(back.attribute("kpcn:note"), Some("rendered by a fixture — ünïcode ok"));
    let matrix = back.attributes.iter().find(|a| a.name == "worldToCamera").expect("matrix kept");
    assert_eq!(matrix.type_name, "matrix");
    assert_eq!(matrix.raw.as_deref(), Some(m.as_slice()));

    // A second generation keeps them too (what a pipeline step does to a file).
    let path2 = dir.path().join("meta2.exr");
    back.write(&path2, &WriteOptions::default()).unwrap();
    let again = FrameBuffers::read(&path2).unwrap();
    assert_eq!(again.attributes, back.attributes);
}

#[test]
fn data_and_display_windows_survive() {
    let dir = tempfile::tempdir().unwrap();
    let mut fb = native_frame(10, 6, 2, &["visibility"]);
    fb.window = Window { x: 5, y: 3, full_x: 0, full_y: 0, full_width: 20, full_height: 12 };
    let path = write(&fb, dir.path(), "window.exr");
    let back = FrameBuffers::read(&path).unwrap();
    assert_eq!(back.window, fb.window);
    assert_eq!(back.channel("normal.G"), fb.channel("normal.G"));
}

#[test]
fn a_new_layer_is_added_to_a_copy_keeping_every_channel_and_attribute() {
    let dir = tempfile::tempdir().unwrap();
    let input = write(&native_frame(16, 9, 3, &[]), dir.path(), "in.exr");
    let original = FrameBuffers::read(&input).unwrap();
    let mut out = original.clone();
    let rgb = [0.25f32, 0.5, 0.75].map(|v| vec![v; 16 * 9]);
    out.insert_rgb("denoised", SampleFormat::Half, rgb).unwrap();
    let output = dir.path().join("out.exr");
    out.write(&output, &WriteOptions::default()).unwrap();
    let back = FrameBuffers::read(&output).unwrap();
    for p in original.planes() {
        assert_eq!(back.plane(&p.name), Some(p), "channel {} kept", p.name);
    }
    assert_eq!(back.channel("denoised.G").unwrap()[0], 0.5);
    assert_eq!(back.plane("denoised.B").unwrap().format, SampleFormat::Half);
    assert_eq!(back.attribute("kpcn:scene"), Some("fixture"));
    assert_eq!(back.planes().len(), original.planes().len() + 3);
}

#[test]
fn a_multi_part_file_reads_as_one_frame() {
    let dir = tempfile::tempdir().unwrap();
    let fb = native_frame(12, 7, 4, &[]);
    let names: Vec<&str> = fb.channel_names().collect();
    let (beauty, aux): (Vec<&str>, Vec<&str>) = names.iter().partition(|n| !n.contains('.'));
    let parts = [Part { name: "beauty", channels: beauty }, Part { name: "aux", channels: aux }];
    let path = dir.path().join("multi.exr");
    fb.write_parts(&path, &parts, &WriteOptions::default()).unwrap();
    let back = FrameBuffers::read(&path).unwrap();
    assert_eq!(back.parts, 2);
    assert_eq!(back.planes().len(), fb.planes().len());
    for p in fb.planes() {
        assert_eq!(back.channel(&p.name), Some(p.data.as_slice()), "{}", p.name);
    }
}

#[test]
fn repeated_channel_names_across_parts_get_the_part_name() {
    let dir = tempfile::tempdir().unwrap();
    let mut fb = FrameBuffers::new(4, 4);
    fb.insert("R", SampleFormat::Float, vec![1.0; 16]).unwrap();
    let path = dir.path().join("dup.exr");
    let parts = [Part { name: "left", channels: vec!["R"] }, Part { name: "right", channels: vec!["R"] }];
    fb.write_parts(&path, &parts, &WriteOptions::default()).unwrap();
    let back = FrameBuffers::read(&path).unwrap();
    let names: Vec<&str> = back.channel_names().collect();
    assert_eq!(names, ["R", "right.R"]);
}

#[test]
fn replacing_a_file_is_atomic_and_leaves_no_temporary_files() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&native_frame(8, 8, 5, &[]), dir.path(), "frame.exr");
    let newer = native_frame(8, 8, 6, &[]);
    newer.write(&path, &WriteOptions::default()).unwrap();
    assert_eq!(FrameBuffers::read(&path).unwrap().channel("R"), newer.channel("R"));
    assert!(stray_files(dir.path(), &["frame.exr"]).is_empty());
}

#[test]
fn no_clobber_refuses_and_keeps_the_existing_file() {
    let dir = tempfile::tempdir().unwrap();
    let first = native_frame(8, 8, 5, &[]);
    let path = write(&first, dir.path(), "frame.exr");
    let opts = WriteOptions { no_clobber: true, ..Default::default() };
    let err = native_frame(8, 8, 6, &[]).write(&path, &opts).unwrap_err();
    assert!(matches!(err, IoError::Exists { .. }), "{err}");
    assert!(err.to_string().contains("overwriting was refused"), "{err}");
    assert_eq!(FrameBuffers::read(&path).unwrap().channel("R"), first.channel("R"));
    assert!(stray_files(dir.path(), &["frame.exr"]).is_empty());
    // A fresh name is written.
    first.write(&dir.path().join("other.exr"), &opts).unwrap();
}

#[test]
fn a_failed_write_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    // The target is a non-empty directory: the final rename must fail.
    let target = dir.path().join("busy.exr");
    std::fs::create_dir(&target).unwrap();
    std::fs::write(target.join("keep"), b"x").unwrap();
    let err = native_frame(8, 8, 5, &[]).write(&target, &WriteOptions::default()).unwrap_err();
    assert!(matches!(err, IoError::Write { .. }), "{err}");
    assert!(stray_files(dir.path(), &["busy.exr"]).is_empty());
    assert!(target.join("keep").exists());
    // Into a folder that does not exist: an error naming the file, no crash.
    let err = native_frame(8, 8, 5, &[]).write(&dir.path().join("nope/x.exr"), &WriteOptions::default()).unwrap_err();
    assert!(err.to_string().contains("nope/x.exr"), "{err}");
}

#[test]
fn only_exr_outputs_and_known_compressions_are_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let fb = native_frame(4, 4, 1, &[]);
    let err = fb.write(&dir.path().join("x.png"), &WriteOptions::default()).unwrap_err();
    assert!(matches!(err, IoError::NotExr { .. }));
    let bad = WriteOptions { compression: Some("lzma".into()), ..Default::default() };
    assert!(matches!(fb.write(&dir.path().join("x.exr"), &bad).unwrap_err(), IoError::Compression(_)));
    for c in ["none", "piz", "dwaa"] {
        let o = WriteOptions { compression: Some(c.into()), ..Default::default() };
        let p = dir.path().join(format!("{c}.exr"));
        fb.write(&p, &o).unwrap();
        assert_eq!(FrameBuffers::read(&p).unwrap().attribute("compression"), Some(c));
    }
}

#[test]
fn wrong_length_channels_are_refused() {
    let mut fb = FrameBuffers::new(4, 4);
    let err = fb.insert("R", SampleFormat::Float, vec![0.0; 15]).unwrap_err();
    assert!(err.to_string().contains("15 samples"), "{err}");
}

#[test]
fn a_layer_can_go_to_a_separate_file_with_the_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let mut fb = native_frame(8, 6, 14, &[]);
    fb.insert_rgb("denoised", SampleFormat::Float, [0.1f32, 0.2, 0.3].map(|v| vec![v; 48])).unwrap();
    let only = fb.select(&["denoised.R", "denoised.G", "denoised.B"]).unwrap();
    let path = write(&only, dir.path(), "denoised.exr");
    let back = FrameBuffers::read(&path).unwrap();
    let mut names: Vec<&str> = back.channel_names().collect();
    names.sort();
    assert_eq!(names, ["denoised.B", "denoised.G", "denoised.R"]);
    assert_eq!(back.attribute("kpcn:scene"), Some("fixture"));
    assert!(matches!(fb.select(&["nope.R"]), Err(IoError::NoSuchChannel { .. })));
}

#[test]
fn bands_of_chosen_channels_read_like_the_whole_frame() {
    let dir = tempfile::tempdir().unwrap();
    let fb = native_frame(13, 150, 9, &[]);
    let path = write(&fb, dir.path(), "f.exr");
    let mut reader = FrameReader::open(&path).unwrap();
    assert_eq!(reader.channel_names().count(), fb.planes().len());
    // Far-apart channels, one asked for twice, across the 64-row read blocks, decoded on
    // one to three threads (each with its own rows).
    let names = ["R", "depthVariance.Z", "normal.G", "R"];
    for decoders in 1..=3 {
        reader.set_decoders(decoders).unwrap();
        for (y0, y1) in [(0, 150), (3, 4), (60, 131), (149, 150), (140, 500), (1, 149), (63, 129)] {
            let band = reader.read_band(Some(&names), y0, y1).unwrap();
            let y1 = y1.min(150);
            assert_eq!((band.width(), band.height(), band.window.y), (13, y1 - y0, y0 as i32));
            for (p, n) in band.planes().iter().zip(names) {
                assert_eq!(p.name, n);
                assert_eq!(
                    p.data,
                    fb.channel(n).unwrap()[y0 * 13..y1 * 13],
                    "{n} rows {y0}..{y1}, {decoders} decoders"
                );
            }
        }
    }
    let err = reader.read_band(Some(&["nope.R"]), 0, 1).unwrap_err().to_string();
    assert!(err.contains("nope.R") && err.contains("f.exr"), "{err}");
}

#[test]
fn a_band_after_carried_rows_reads_like_the_rows_read_at_once() {
    // A streamed frame's band carries the previous read's last rows and decodes only the
    // rest: the same rows, whatever the file's chunk height (zip 16, piz 32, none 1), the
    // data window's origin and the number of decoders (each starting where the last
    // read's last decoder stopped).
    let dir = tempfile::tempdir().unwrap();
    let mut fb = native_frame(11, 150, 9, &[]);
    fb.window = Window { y: -7, full_y: -7, ..fb.window };
    let names = ["R", "normal.G", "depthVariance.Z"];
    for compression in ["zip", "piz", "none"] {
        let o = WriteOptions { compression: Some(compression.into()), ..Default::default() };
        let path = dir.path().join(format!("{compression}.exr"));
        fb.write(&path, &o).unwrap();
        let mut reader = FrameReader::open(&path).unwrap();
        for decoders in 1..=3 {
            reader.set_decoders(decoders).unwrap();
            let (mut c0, mut band) = (0, reader.read_band(Some(&names), 0, 36).unwrap());
            // Context rows of 2 each side of 32-row bands, as a streamed frame reads them.
            for (next, end) in [(30, 68), (62, 100), (94, 132), (126, 150), (150, 150)] {
                let carried = band.copy_rows(next - c0..band.height());
                assert_eq!((carried.height(), carried.window.y), (band.height() - (next - c0), next as i32 - 7));
                band = reader.read_band_after(carried, end).unwrap();
                c0 = next;
                let what = format!("{compression}, {decoders} decoders, rows {next}..{end}");
                assert_eq!((band.height(), band.window.y), (end - next, next as i32 - 7), "{what}");
                for n in names {
                    assert_eq!(band.channel(n).unwrap(), &fb.channel(n).unwrap()[next * 11..end * 11], "{n}: {what}");
                }
            }
        }
    }
}

#[test]
fn several_encoders_write_the_same_pixels() {
    // Compressing on OpenEXR's pool (the CLI's outputs) changes how, not what.
    let dir = tempfile::tempdir().unwrap();
    let fb = native_frame(29, 200, 5, &[]);
    for encoders in [1, 3] {
        let path = dir.path().join(format!("e{encoders}.exr"));
        fb.write(&path, &WriteOptions { encoders, ..WriteOptions::default() }).unwrap();
        let back = FrameBuffers::read(&path).unwrap();
        for p in fb.planes() {
            assert_eq!(bits(back.channel(&p.name).unwrap()), bits(&p.data), "{} with {encoders} encoders", p.name);
        }
    }
}

#[test]
fn tiled_files_read_in_bands_that_do_not_align_with_tiles() {
    // tests/data/spheres-48x32-tiled16.exr = the golden input rewritten by
    // `oiiotool … --tile 16 16` (RenderMan and others write tiled EXRs).
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scan = FrameBuffers::read(&root.join("tests/golden/spheres-48x32-input.exr")).unwrap();
    let tiled_path = root.join("tests/data/spheres-48x32-tiled16.exr");
    let tiled = FrameBuffers::read(&tiled_path).unwrap();
    for p in scan.planes() {
        assert!(tiled.channel(&p.name) == Some(p.data.as_slice()), "{}", p.name);
    }
    let mut reader = FrameReader::open(&tiled_path).unwrap();
    for (y0, y1) in [(5, 21), (0, 1), (17, 32), (31, 32)] {
        let band = reader.read_band(Some(&["R", "albedo.G"]), y0, y1).unwrap();
        for n in ["R", "albedo.G"] {
            assert_eq!(band.channel(n).unwrap(), &scan.channel(n).unwrap()[y0 * 48..y1 * 48], "{n} {y0}..{y1}");
        }
    }
}
