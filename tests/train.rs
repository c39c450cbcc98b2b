//! The trainer on a tiny generated dataset: it learns, and a checkpoint resumes bit-exactly.

use kpcn::features::Branch;
use kpcn::model::{Architecture, Design, Exposure, Kind, Model, Preprocessing, Variances};
use kpcn::train::augment::{ChannelOrder, Orientation};
use kpcn::train::data::{Augmentation, Dataset, Firefly, batch, batch_augmented};
use kpcn::train::{Loss, LossScale, TrainOptions, Trainer, l1};
use std::path::Path;
use std::process::Command;

fn kpcn(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kpcn")).args(args).output().unwrap()
}

/// Three small scenes (one held out), 2 and 4 spp, 16-spp references.
fn dataset(dir: &Path) {
    let out = kpcn(&[
        "dataset",
        "--families",
        "cornell,product,glass",
        "--count",
        "1",
        "--spp",
        "2,4",
        "--reference-spp",
        "16",
        "--resolution",
        "32x24",
        // The simulator's original sampling: this test is about training, not sampling.
        "--pixel-filter",
        "box",
        "--sampler",
        "random",
        "-q",
        "-o",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// [`dataset`] in a fresh folder, loaded with every 3rd scene held out and no cache: the
/// folder comes back too, since the dataset's files live as long as it does.
fn loaded_dataset() -> (tempfile::TempDir, Dataset) {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path());
    let data = Dataset::load(dir.path(), 3, false, Default::default()).unwrap();
    (dir, data)
}

fn options(steps: u64) -> TrainOptions {
    TrainOptions {
        phase1_steps: steps,
        phase2_steps: 2,
        batch: 2,
        patch: 12,
        lr: 1e-3,
        lr_phase2: 1e-4,
        seed: 5,
        importance: true,
        checkpoint_every: 100,
        validate_every: 100,
        ops: Default::default(),
        // The schedule is a function of the step: resuming must follow it exactly.
        cosine: true,
        loss: Default::default(),
        block_weight: 1.0,
        loss_scale: Default::default(),
        augment: false,
        fireflies: None,
        permute_channels: false,
        only: None,
    }
}

fn tiny() -> Model {
    Model::xavier(
        Architecture {
            kind: Kind::Kpcn,
            design: Design::Flat,
            layers: 3,
            channels: 8,
            conv_size: 3,
            kernel_size: 5,
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
        },
        1,
    )
    .unwrap()
}

fn weights(m: &Model) -> Vec<u32> {
    m.diffuse
        .layers
        .iter()
        .chain(&m.specular.layers)
        .flat_map(|(w, b)| [w, b])
        .flat_map(|t| t.flatten_all().unwrap().to_vec1::<f32>().unwrap())
        .map(f32::to_bits)
        .collect()
}

#[test]
fn training_lowers_the_loss_and_resumes_bit_exactly() {
    let (dir, data) = loaded_dataset();
    assert_eq!((data.train.len(), data.validation.len()), (4, 2), "whole scenes are held out");

    // The loss on a fixed batch goes down.
    let frames: Vec<_> = data.train.iter().collect();
    let origins = vec![(4, 4); frames.len()];
    let fixed = batch(&frames, &origins, 12, &tiny().arch, Branch::Diffuse).unwrap();
    let mut t = Trainer::new(&tiny(), &data, options(60)).unwrap();
    let loss = |t: &Trainer| {
        let l = l1(&t.model.predict(Branch::Diffuse, &fixed.input, &fixed.noisy).unwrap(), &fixed.target).unwrap();
        l.to_scalar::<f32>().unwrap()
    };
    let before = loss(&t);
    for _ in 0..60 {
        t.train_step().unwrap();
    }
    let after = loss(&t);
    assert!(after < 0.9 * before, "loss {before} → {after}");
    let v = t.validate().unwrap().unwrap();
    // Relative errors are ≥ 0, so at least half of them lie at or above the median: median ≤ 2 × mean.
    assert!(v.mean.is_finite() && v.median.is_finite() && v.median <= 2.0 * v.mean + 1e-12, "{v:?}");

    // 4 + 2 steps straight through equal 3 steps, a checkpoint, a resume and 3 more
    // (phase 2 included), with the relative loss and augmentation.
    let opts = || TrainOptions {
        loss: Loss::Relative,
        augment: true,
        fireflies: Some(Default::default()),
        permute_channels: true,
        only: None,
        ..options(4)
    };
    let mut straight = Trainer::new(&tiny(), &data, opts()).unwrap();
    while !straight.finished() {
        straight.train_step().unwrap();
    }
    let ckpt = dir.path().join("ckpt.safetensors");
    let mut first = Trainer::new(&tiny(), &data, opts()).unwrap();
    for _ in 0..3 {
        first.train_step().unwrap();
    }
    first.save(&ckpt).unwrap();
    let mut resumed = Trainer::resume(&ckpt, &data, opts()).unwrap();
    assert_eq!(resumed.step, 3);
    while !resumed.finished() {
        resumed.train_step().unwrap();
    }
    let a = weights(&straight.model.snapshot("a").unwrap());
    let b = weights(&resumed.model.snapshot("b").unwrap());
    assert!(a == b, "resumed weights differ");
    // A checkpoint is also a loadable model.
    Model::load(&ckpt).unwrap();
}

/// The test dataset, loaded with `prep`, in a folder that lives as long as the guard.
fn loaded(prep: Preprocessing) -> (tempfile::TempDir, Dataset) {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path());
    let data = Dataset::load(dir.path(), 3, false, prep).unwrap();
    (dir, data)
}

/// A tensor's values, flattened.
fn v(t: &candle_core::Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
}

#[test]
fn a_channel_ordered_batch_is_the_batch_with_its_planes_reordered() {
    let (_dir, data) = loaded(Default::default());
    let frames: Vec<_> = data.train.iter().take(1).collect();
    let arch = tiny().arch;
    let (p, (rf, rk)) = (8, arch.train_margins());
    let order = ChannelOrder::from_index(4);
    let aug = Augmentation { channels: order, ..Default::default() };
    for b in [Branch::Diffuse, Branch::Specular] {
        let plain = batch(&frames, &[(4, 4)], p, &arch, b).unwrap();
        let swapped = batch_augmented(&frames, &[(4, 4)], std::slice::from_ref(&aug), p, &arch, b).unwrap();
        for (a, s, side) in [
            (&plain.target, &swapped.target, p),
            (&plain.albedo, &swapped.albedo, p),
            (&plain.reference, &swapped.reference, p),
            (&plain.noisy, &swapped.noisy, p + 2 * rk),
            (&plain.input, &swapped.input, p + 2 * rf),
        ] {
            let (a, s) = (v(a), v(s));
            let n = side * side;
            for (c, &from) in order.0.iter().enumerate() {
                assert_eq!(s[c * n..(c + 1) * n], a[from * n..(from + 1) * n], "{b:?} plane {c}");
            }
        }
    }
}

#[test]
fn an_oriented_batch_is_the_batch_mirrored_and_transposed_alike() {
    let (_dir, data) = loaded_dataset();
    let frames: Vec<_> = data.train.iter().take(2).collect();
    let origins = vec![(4, 4), (6, 2)];
    let arch = tiny().arch;
    let (p, rk) = (8, arch.train_margins().1);
    let o = [Orientation::from_index(5), Orientation::from_index(2)];
    let augs: Vec<Augmentation> =
        o.iter().map(|&orientation| Augmentation { orientation, ..Default::default() }).collect();
    for b in [Branch::Diffuse, Branch::Specular] {
        let plain = batch(&frames, &origins, p, &arch, b).unwrap();
        let turned = batch_augmented(&frames, &origins, &augs, p, &arch, b).unwrap();
        for (a, t, side) in [
            (&plain.target, &turned.target, p),
            (&plain.albedo, &turned.albedo, p),
            (&plain.reference, &turned.reference, p),
            (&plain.noisy, &turned.noisy, p + 2 * rk),
        ] {
            let (a, t) = (v(a), v(t));
            let half = a.len() / 2;
            assert_eq!(o[0].apply(&a[..half], side), t[..half]);
            assert_eq!(o[1].apply(&a[half..], side), t[half..]);
        }
        // The colour planes of the input are oriented alike (gradients are re-taken:
        // `features` tests them against a mirrored frame).
        let (a, t) = (v(&plain.input), v(&turned.input));
        let n = a.len() / 2 / 27;
        let side = (n as f64).sqrt() as usize;
        assert_eq!(o[0].apply(&a[..3 * n], side), t[..3 * n]);
        assert_ne!(a, t);
    }
}

#[test]
fn fireflies_are_added_to_the_noisy_input_only() {
    let (_dir, data) = loaded(Default::default());
    let frames: Vec<_> = data.train.iter().take(1).collect();
    let arch = tiny().arch;
    let (p, (rf, rk)) = (8, arch.train_margins());
    for (b, diffuse) in [(Branch::Diffuse, true), (Branch::Specular, false)] {
        let ff = Firefly { x: 3, y: 5, gain: 1000.0, diffuse };
        let aug = Augmentation { fireflies: vec![ff], ..Default::default() };
        let plain = batch(&frames, &[(4, 4)], p, &arch, b).unwrap();
        let hit = batch_augmented(&frames, &[(4, 4)], &[aug], p, &arch, b).unwrap();
        for (a, h) in [(&plain.target, &hit.target), (&plain.albedo, &hit.albedo), (&plain.reference, &hit.reference)] {
            assert_eq!(v(a), v(h), "the reference side is untouched");
        }
        let (a, h) = (v(&plain.input), v(&hit.input));
        let si = p + 2 * rf;
        let at = |ch: usize, x: usize, y: usize| ch * si * si + (y + rf) * si + x + rf;
        let rise = h[at(0, 3, 5)] - a[at(0, 3, 5)];
        assert!(rise > 1.0, "{b:?}: the pixel brightens ({rise})");
        // Its gradients change with it, and only where a backward difference touches it.
        assert_eq!(h[at(3, 3, 5)] - a[at(3, 3, 5)], rise);
        assert_eq!(a[at(3, 4, 5)] - h[at(3, 4, 5)], rise);
        assert!(h[at(23, 3, 5)] > a[at(23, 3, 5)], "its variance grows");
        let changed = a.iter().zip(&h).filter(|(x, y)| x != y).count();
        assert_eq!(changed, 3 * 5 + 1, "3 colours × (value, 2 x- and 2 y-differences) + variance");
        let sn = p + 2 * rk;
        let (na, nh) = (v(&plain.noisy), v(&hit.noisy));
        assert!(nh[(5 + rk) * sn + 3 + rk] > na[(5 + rk) * sn + 3 + rk]);
        assert_eq!(na.iter().zip(&nh).filter(|(x, y)| x != y).count(), 3);
        // A firefly of the other branch leaves this one alone.
        let other = Augmentation { fireflies: vec![Firefly { diffuse: !diffuse, ..ff }], ..Default::default() };
        assert_eq!(v(&batch_augmented(&frames, &[(4, 4)], &[other], p, &arch, b).unwrap().input), a);
    }
}

#[test]
fn auto_exposed_frames_train_on_targets_at_their_exposure_and_validate_as_rendered() {
    let (_dir, raw) = loaded(Default::default());
    let (_dir2, auto) = loaded(Preprocessing { exposure: Exposure::Auto, ..Default::default() });
    let (fr, fa) = (&raw.train[0], &auto.train[0]);
    let e = fa.features.exposure;
    assert!(e > 0.0 && (e - 1.0).abs() > 0.05 && fr.features.exposure == 1.0, "{e}");
    // Frames keep their references as rendered: validation compares the scaled-back output.
    assert_eq!(fa.reference, fr.reference);
    let arch = Architecture { exposure: Exposure::Auto, ..tiny().arch };
    let close = |a: f32, b: f32| (a - b).abs() <= 1e-5 * (1.0 + a.abs().max(b.abs()));
    for b in [Branch::Diffuse, Branch::Specular] {
        let (r, a) = (batch(&[fr], &[(4, 4)], 8, &arch, b).unwrap(), batch(&[fa], &[(4, 4)], 8, &arch, b).unwrap());
        let scale = |x: f32| match b {
            Branch::Diffuse => x * e,
            Branch::Specular => (e * x.exp_m1()).ln_1p(),
        };
        for (x, y) in v(&r.target).into_iter().zip(v(&a.target)) {
            assert!(close(scale(x), y), "{b:?} target {x} → {y}");
        }
        for (x, y) in v(&r.reference).into_iter().zip(v(&a.reference)) {
            assert!(close(x * e, y), "reference {x} → {y}");
        }
        // The noisy colour the kernels filter is at the same exposure as the targets.
        for (x, y) in v(&r.noisy).into_iter().zip(v(&a.noisy)) {
            assert!(close(scale(x), y), "{b:?} noisy {x} → {y}");
        }
        assert_eq!(v(&r.albedo), v(&a.albedo));
        // What `--loss-scale rendered` divides by.
        assert_eq!((v(&r.exposure), v(&a.exposure)), (vec![1.0], vec![e]));
    }
    // On raw radiance the loss's scale changes nothing, bit for bit.
    let trained = |loss_scale| {
        let opts = TrainOptions { loss: Loss::Relative, loss_scale, ..options(3) };
        let mut t = Trainer::new(&tiny(), &raw, opts).unwrap();
        while !t.finished() {
            t.train_step().unwrap();
        }
        weights(&t.model.snapshot("raw").unwrap())
    };
    assert!(trained(LossScale::Rendered) == trained(LossScale::Exposed), "the rendered scale changed raw training");
    // Training and validation run; the validation error is of the scaled-back output.
    let model = Model::xavier(arch, 1).unwrap();
    let mut t = Trainer::new(&model, &auto, options(4)).unwrap();
    for _ in 0..4 {
        t.train_step().unwrap();
    }
    assert!(t.validate().unwrap().unwrap().mean.is_finite());
    let m = t.model.snapshot("test").unwrap();
    assert_eq!(Model::from_bytes(&m.to_bytes().unwrap(), "mem").unwrap().arch.exposure, Exposure::Auto);
}

#[test]
fn kpcn_train_writes_a_model_log_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path());
    let run = dir.path().join("run");
    let (d, r) = (dir.path().to_str().unwrap(), run.to_str().unwrap());
    let common = ["--preset", "small", "--batch", "1", "--patch", "16", "--holdout", "3", "-q"];
    // A scene folder of the dataset stands in for the dev set (its layout is the same).
    let dev = dir.path().join("glass-0000");
    let train =
        ["train", "--data", d, "-o", r, "--steps", "2", "--validate-every", "2", "--dev", dev.to_str().unwrap()];
    let out = kpcn(&[&train[..], &common[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let model = run.join("model.safetensors");
    assert!(model.is_file() && run.join("checkpoint.safetensors").is_file());
    assert!(run.join("training.png").is_file(), "the curves are drawn beside the checkpoint");
    assert!(Model::load(&model).unwrap().description.starts_with("trained by kpcn train"));
    let log = std::fs::read_to_string(run.join("log.csv")).unwrap();
    assert_eq!(log.lines().count(), 3, "{log}");
    let validated: Vec<&str> = log.lines().nth(2).unwrap().split(',').collect();
    assert!(validated[5].parse::<f64>().is_ok() && validated[7].parse::<f64>().is_ok(), "validated: {log}");
    assert!(validated[8].parse::<f64>().is_ok_and(|v| v > 0.0), "the dev set is scored: {log}");
    assert!(log.lines().nth(1).unwrap().ends_with(','), "and only when validating: {log}");
    // A dev folder without frames is refused, naming it.
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let refused = kpcn(&["train", "--data", d, "-o", r, "--steps", "1", "--dev", empty.to_str().unwrap(), "-q"]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && err.contains("empty") && err.contains("SCENE-ref.exr"), "{err}");
    // A row logged after the checkpoint (an interrupted run) is dropped on resume.
    let log_path = run.join("log.csv");
    std::fs::write(&log_path, log.clone() + "3,1,0.5,0.5,,,1.0\n").unwrap();
    let out = kpcn(&[&["train", "--data", d, "-o", r, "--steps", "4", "--resume"], &common[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let log = std::fs::read_to_string(&log_path).unwrap();
    let steps: Vec<&str> = log.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(steps, ["1", "2", "3", "4"], "{log}");
    assert!(!log.contains("0.5,0.5"), "{log}");
    // Several runs' curves in one chart; a folder without a log is an error naming it.
    let png = dir.path().join("cmp.png");
    let out = kpcn(&["curves", r, r, "-o", png.to_str().unwrap()]);
    assert!(out.status.success() && png.is_file(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = kpcn(&["curves", d, "-o", png.to_str().unwrap()]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("log.csv"));
    // The trained model denoises.
    let frame = std::fs::read_dir(dir.path().join("cornell-0000")).unwrap().next().unwrap().unwrap().path();
    let out = kpcn(&[
        "denoise",
        frame.to_str().unwrap(),
        "-o",
        dir.path().join("d.exr").to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
        "-q",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // An auto-exposed fine-tune of it records the choice, its own fine-tune inherits it,
    // and a resume that forgets it is refused with the fix.
    let (auto, again) = (dir.path().join("auto"), dir.path().join("again"));
    let tune = |out: &Path, extra: &[&str]| {
        let init = [
            "train",
            "--data",
            d,
            "-o",
            out.to_str().unwrap(),
            "--steps",
            "1",
            "--holdout",
            "3",
            "--patch",
            "16",
            "-q",
        ];
        kpcn(&[&init[..], extra].concat())
    };
    let out = tune(&auto, &["--init", model.to_str().unwrap(), "--exposure", "auto", "--variances", "spatial"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let auto_model = auto.join("model.safetensors");
    assert_eq!(Model::load(&auto_model).unwrap().arch.exposure, Exposure::Auto);
    assert!(tune(&again, &["--init", auto_model.to_str().unwrap()]).status.success());
    // Its variances too: a spatial model fine-tuned without --variances stays spatial.
    let arch = Model::load(&again.join("model.safetensors")).unwrap().arch;
    assert_eq!((arch.exposure, arch.variances), (Exposure::Auto, Variances::Spatial));
    let out = tune(&auto, &["--resume"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--variances spatial"), "{err}");
    let out = tune(&auto, &["--resume", "--variances", "spatial"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--exposure auto"), "{err}");
    // One branch retrained afresh: the other keeps the model's weights exactly.
    let fresh = dir.path().join("fresh");
    let out = tune(&fresh, &["--init", model.to_str().unwrap(), "--fresh", "specular", "--only", "specular"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (before, after) = (Model::load(&model).unwrap(), Model::load(&fresh.join("model.safetensors")).unwrap());
    assert!(branch_bits(&after, Branch::Diffuse) == branch_bits(&before, Branch::Diffuse));
    assert!(branch_bits(&after, Branch::Specular) != branch_bits(&before, Branch::Specular));
    assert!(after.description.contains("specular branch afresh"), "{}", after.description);
}

/// Every file under `dir`.
fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .flat_map(|p| if p.is_dir() { walk(&p) } else { vec![p] })
        .collect()
}

#[test]
fn the_frame_cache_returns_the_same_frames_and_notices_changed_sources() {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path());
    let fresh = Dataset::load(dir.path(), 3, true, Default::default()).unwrap();
    assert_eq!(fresh.cached, 0);
    let again = Dataset::load(dir.path(), 3, true, Default::default()).unwrap();
    assert_eq!(again.cached, 6);
    for (a, b) in fresh.train.iter().chain(&fresh.validation).zip(again.train.iter().chain(&again.validation)) {
        assert_eq!((&a.scene, a.spp), (&b.scene, b.spp));
        assert!(a.features == b.features && a.target_d == b.target_d && a.target_s == b.target_s);
        assert!(a.reference == b.reference);
        assert_eq!(a.centres(true), b.centres(true));
        assert_eq!(a.centres(false), b.centres(false));
        assert!(!a.centres(true).is_empty());
    }
    // A damaged cache file and a re-rendered source are both rebuilt, not trusted.
    let cache = dir.path().join("cache");
    let mut files: Vec<_> = std::fs::read_dir(&cache).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    // Compact: the whole cache is smaller than the EXRs it replaces.
    let size = |paths: &mut dyn Iterator<Item = std::path::PathBuf>| -> u64 {
        paths.map(|p| std::fs::metadata(p).unwrap().len()).sum()
    };
    let exrs = walk(dir.path()).into_iter().filter(|p| p.extension().is_some_and(|e| e == "exr"));
    let (cached, sources) = (size(&mut files.clone().into_iter()), size(&mut exrs.into_iter()));
    assert!(cached < sources, "cache {cached} B vs EXRs {sources} B");
    std::fs::write(&files[0], b"garbage").unwrap();
    let manifest = std::fs::read_to_string(dir.path().join("manifest.csv")).unwrap();
    let noisy = manifest.lines().nth(2).unwrap().split(',').nth(5).unwrap().to_string();
    let bytes = std::fs::read(dir.path().join(&noisy)).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(20));
    std::fs::write(dir.path().join(&noisy), bytes).unwrap();
    let third = Dataset::load(dir.path(), 3, true, Default::default()).unwrap();
    assert_eq!(third.cached, 4);
}

#[test]
fn the_multiscale_network_trains_and_refuses_patches_off_its_grid() {
    let (_dir, data) = loaded_dataset();
    let ms = crate::util::tiny_multiscale(2);
    // 9 + 2 × 16 context pixels is not a multiple of 4.
    let e = Trainer::new(&ms, &data, TrainOptions { patch: 9, ..options(10) }).err().expect("refused").to_string();
    assert!(e.contains("--patch 9") && e.contains("try --patch 12"), "{e}");

    let opts = TrainOptions { patch: 8, lr: 1e-2, ..options(40) };
    let frames: Vec<_> = data.train.iter().collect();
    let origins = vec![(4, 4); frames.len()];
    let fixed = batch(&frames, &origins, 8, &ms.arch, Branch::Diffuse).unwrap();
    assert_eq!(fixed.input.dims(), [frames.len(), 27, 40, 40], "patch + the training margins");
    let mut t = Trainer::new(&ms, &data, opts).unwrap();
    let loss = |t: &Trainer| {
        let p = t.model.predict(Branch::Diffuse, &fixed.input, &fixed.noisy).unwrap();
        assert_eq!(p.dims(), fixed.target.dims());
        l1(&p, &fixed.target).unwrap().to_scalar::<f32>().unwrap()
    };
    let before = loss(&t);
    while !t.finished() {
        t.train_step().unwrap();
    }
    let after = loss(&t);
    assert!(after < 0.9 * before, "loss {before} → {after}");
    assert!(t.validate().unwrap().unwrap().median.is_finite());

    // Linear specular kernels train through both phases too (the loss stays in log).
    let mut linear = crate::util::tiny_multiscale(2);
    linear.arch.specular = kpcn::model::Specular::Linear;
    let spec = batch(&frames, &origins, 8, &linear.arch, Branch::Specular).unwrap();
    let log_spec = batch(&frames, &origins, 8, &ms.arch, Branch::Specular).unwrap();
    let (a, b) = (spec.noisy.flatten_all().unwrap(), log_spec.noisy.flatten_all().unwrap());
    let back = (b.exp().unwrap() - 1.0).unwrap();
    let gap = (a - back).unwrap().abs().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap();
    assert!(gap < 1e-3, "the linear batch is exp(s̃) − 1: {gap}");
    let mut t = Trainer::new(&linear, &data, TrainOptions { patch: 8, lr: 1e-2, ..options(6) }).unwrap();
    while !t.finished() {
        let row = t.train_step().unwrap();
        assert!(row.loss_specular.is_finite() || row.loss_combined.is_finite(), "{row:?}");
    }
    let m = t.model.snapshot("linear").unwrap();
    assert_eq!(Model::from_bytes(&m.to_bytes().unwrap(), "mem").unwrap().arch.specular, linear.arch.specular);
}

/// A gain added to a model starts at exactly 1 (the model's own outputs, bit for bit)
/// and trains; the CLI adds it to an --init model, and refuses it for a flat one.
#[test]
fn a_gain_starts_at_one_and_trains() {
    let (dir, data) = loaded_dataset();
    let plain = crate::util::tiny_multiscale(2);
    let gained = plain.clone().with_gain().unwrap();
    let frames: Vec<_> = data.train.iter().collect();
    let fixed = batch(&frames, &vec![(4, 4); frames.len()], 8, &plain.arch, Branch::Diffuse).unwrap();
    let opts = TrainOptions { patch: 8, lr: 1e-2, ..options(20) };
    let predict = |t: &Trainer| v(&t.model.predict(Branch::Diffuse, &fixed.input, &fixed.noisy).unwrap());
    let mut t = Trainer::new(&gained, &data, opts.clone()).unwrap();
    let bits = |x: Vec<f32>| x.into_iter().map(f32::to_bits).collect::<Vec<_>>();
    assert!(bits(predict(&Trainer::new(&plain, &data, opts).unwrap())) == bits(predict(&t)));
    while !t.finished() {
        t.train_step().unwrap();
    }
    let m = t.model.snapshot("gain").unwrap();
    let (w, _) = m.diffuse.layers.last().unwrap();
    let gain_row = v(&w.narrow(0, w.dim(0).unwrap() - 1, 1).unwrap());
    assert!(gain_row.iter().any(|&x| x != 0.0), "the gain's weights did not train");
    assert!(Model::from_bytes(&m.to_bytes().unwrap(), "mem").unwrap().arch.gain);

    let init = dir.path().join("init.safetensors");
    plain.save(&init).unwrap();
    let (d, run) = (dir.path().to_str().unwrap(), dir.path().join("run"));
    let train = |init: &Path| {
        let args = ["train", "--data", d, "-o", run.to_str().unwrap(), "--steps", "1", "--holdout", "3"];
        kpcn(&[&args[..], &["--patch", "16", "-q", "--gain", "--init", init.to_str().unwrap()]].concat())
    };
    let out = train(&init);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(Model::load(&run.join("model.safetensors")).unwrap().arch.gain);
    let flat = dir.path().join("flat.safetensors");
    Model::xavier(Architecture::small(Kind::Kpcn), 0).unwrap().save(&flat).unwrap();
    std::fs::remove_dir_all(&run).unwrap();
    let out = train(&flat);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--gain: a gain is for multi-scale networks"), "{err}");
}

/// The branch's weights, as bits.
fn branch_bits(m: &Model, b: Branch) -> Vec<u32> {
    let layers = if b == Branch::Diffuse { &m.diffuse.layers } else { &m.specular.layers };
    layers.iter().flat_map(|(w, b)| [w, b]).flat_map(v).map(f32::to_bits).collect()
}

/// `--only specular` retrains one branch of a model: phase 1 leaves the other's weights
/// exactly as they were (phase 2 then trains both).
#[test]
fn phase_one_can_train_one_branch_alone() {
    let (_dir, data) = loaded(Default::default());
    let start = tiny();
    for only in [Branch::Specular, Branch::Diffuse] {
        let mut t = Trainer::new(&start, &data, TrainOptions { only: Some(only), ..options(3) }).unwrap();
        for _ in 0..3 {
            let row = t.train_step().unwrap();
            assert_eq!(row.loss_diffuse.is_nan(), only == Branch::Specular, "{row:?}");
        }
        let m = t.model.snapshot("one").unwrap();
        let other = if only == Branch::Diffuse { Branch::Specular } else { Branch::Diffuse };
        assert!(branch_bits(&m, other) == branch_bits(&start, other), "{other:?} changed while training {only:?}");
        assert!(branch_bits(&m, only) != branch_bits(&start, only), "{only:?} did not train");
        t.train_step().unwrap();
        let both = t.model.snapshot("both").unwrap();
        assert!(branch_bits(&both, other) != branch_bits(&start, other), "phase 2 trains {other:?} too");
    }
}
