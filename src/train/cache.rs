//! On-disk cache of preprocessed training frames: features, targets and the chosen patch
//! centres of one noisy frame in one safetensors file, so a second run (or a resumed one)
//! skips EXR decoding, channel mapping, preprocessing and patch selection.
//!
//! A cache file is keyed by the size and modification time of its two source files and
//! the cache format; any mismatch, or a damaged file, means it is rebuilt. Values are
//! stored as f32, so training from the cache equals training from the EXRs bit for bit,
//! and the file is deflated (fast level): the planes hold many zeros and repeats, so a
//! frame takes about a quarter of its f32 size — less than its EXRs.

use super::data::{CANDIDATES, DataError, Frame, KEPT};
use crate::features::Features;
use crate::model::ModelError;
use candle_core::{Device, Tensor};
use std::collections::HashMap;
use std::path::Path;

/// Bump when the stored planes or the patch selection change.
const FORMAT: &str = "kpcn-frame-cache-2";

/// First bytes of a cache file; a deflated safetensors file follows.
const MAGIC: &[u8] = b"kpcn-zcache\n";

/// The key a cache file must carry to be used for `noisy` + `reference`.
pub fn key(noisy: &Path, reference: &Path) -> Option<String> {
    let stamp = |p: &Path| -> Option<String> {
        let m = std::fs::metadata(p).ok()?;
        let t = m.modified().ok()?.duration_since(std::time::UNIX_EPOCH).ok()?;
        Some(format!("{}@{}", m.len(), t.as_nanos()))
    };
    Some(format!("{FORMAT};{CANDIDATES}/{KEPT};{};{}", stamp(noisy)?, stamp(reference)?))
}

fn planes(f: &Frame) -> Vec<(String, &[f32])> {
    let e = &f.features;
    let rgb: [(&str, &[Vec<f32>; 3]); 7] = [
        ("d_tilde", &e.d_tilde),
        ("s_tilde", &e.s_tilde),
        ("normal", &e.normal),
        ("albedo", &e.albedo),
        ("target_d", &f.target_d),
        ("target_s", &f.target_s),
        ("reference", &f.reference),
    ];
    let mut v: Vec<(String, &[f32])> = rgb
        .iter()
        .flat_map(|(n, p)| p.iter().enumerate().map(move |(c, p)| (format!("{n}.{c}"), p.as_slice())))
        .collect();
    let scalar: [(&str, &Vec<f32>); 6] = [
        ("depth", &e.depth),
        ("d_variance", &e.d_variance),
        ("s_variance", &e.s_variance),
        ("normal_variance", &e.normal_variance),
        ("albedo_variance", &e.albedo_variance),
        ("depth_variance", &e.depth_variance),
    ];
    v.extend(scalar.iter().map(|(n, p)| (n.to_string(), p.as_slice())));
    v
}

/// Writes `frame` to `path` (through a temporary file).
pub fn store(path: &Path, key: &str, frame: &Frame) -> Result<(), DataError> {
    let mut tensors: Vec<(String, Tensor)> = Vec::new();
    let t = |v: Vec<f32>| {
        let n = v.len();
        Tensor::from_vec(v, n, &Device::Cpu).map_err(ModelError::from)
    };
    for (name, p) in planes(frame) {
        tensors.push((name, t(p.to_vec())?));
    }
    for (name, importance) in [("centres.importance", true), ("centres.uniform", false)] {
        let c: Vec<f32> = frame.centres(importance).iter().flat_map(|&(x, y)| [x as f32, y as f32]).collect();
        tensors.push((name.into(), t(c)?));
    }
    let meta = HashMap::from([
        ("key".to_string(), key.to_string()),
        ("scene".to_string(), frame.scene.clone()),
        ("spp".to_string(), frame.spp.to_string()),
        ("width".to_string(), frame.features.width.to_string()),
        ("height".to_string(), frame.features.height.to_string()),
        // Its bits, so that the cached frame equals the fresh one exactly.
        ("exposure".to_string(), frame.features.exposure.to_bits().to_string()),
    ]);
    let bytes = safetensors::serialize(tensors.iter().map(|(n, t)| (n.as_str(), t)), Some(meta))
        .map_err(|e| ModelError::Format { origin: path.display().to_string(), what: e.to_string() })?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| ModelError::Io { path: dir.into(), source })?;
    }
    let mut z = flate2::write::ZlibEncoder::new(MAGIC.to_vec(), flate2::Compression::fast());
    let io = |source| ModelError::Io { path: path.into(), source };
    std::io::Write::write_all(&mut z, &bytes).map_err(io)?;
    crate::model::write_atomically(path, &z.finish().map_err(io)?)?;
    Ok(())
}

/// The cached frame at `path` if it exists, is intact and carries `key`.
pub fn load(path: &Path, key: &str) -> Option<Frame> {
    let file = std::fs::read(path).ok()?;
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut flate2::read::ZlibDecoder::new(file.strip_prefix(MAGIC)?), &mut bytes).ok()?;
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).ok()?;
    let meta = meta.metadata().as_ref()?;
    if meta.get("key").map(String::as_str) != Some(key) {
        return None;
    }
    let (w, h): (usize, usize) = (meta.get("width")?.parse().ok()?, meta.get("height")?.parse().ok()?);
    let tensors = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu).ok()?;
    let get = |n: &str| -> Option<Vec<f32>> { tensors.get(n)?.to_vec1::<f32>().ok() };
    let plane = |n: &str| get(n).filter(|v| v.len() == w * h);
    let rgb = |n: &str| -> Option<[Vec<f32>; 3]> {
        Some([plane(&format!("{n}.0"))?, plane(&format!("{n}.1"))?, plane(&format!("{n}.2"))?])
    };
    let centres = |n: &str| -> Option<Vec<(usize, usize)>> {
        Some(get(n)?.chunks_exact(2).map(|c| (c[0] as usize, c[1] as usize)).collect())
    };
    let features = Features {
        width: w,
        height: h,
        d_tilde: rgb("d_tilde")?,
        s_tilde: rgb("s_tilde")?,
        normal: rgb("normal")?,
        albedo: rgb("albedo")?,
        depth: plane("depth")?,
        d_variance: plane("d_variance")?,
        s_variance: plane("s_variance")?,
        normal_variance: plane("normal_variance")?,
        albedo_variance: plane("albedo_variance")?,
        depth_variance: plane("depth_variance")?,
        // Files from before auto-exposed models hold raw features.
        exposure: match meta.get("exposure") {
            Some(bits) => f32::from_bits(bits.parse().ok()?),
            None => 1.0,
        },
    };
    Some(Frame::from_parts(
        meta.get("scene")?.clone(),
        meta.get("spp")?.parse().ok()?,
        features,
        [rgb("target_d")?, rgb("target_s")?, rgb("reference")?],
        [centres("centres.importance")?, centres("centres.uniform")?],
    ))
}
