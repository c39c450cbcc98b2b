//! The model file: safetensors with the weights of both branches and the architecture in
//! its metadata (`kpcn:*` keys), read and written atomically.

use super::{
    Architecture, BranchWeights, Clamp, Design, DiffuseInput, Exposure, Kind, Model, ModelError, ScaleBlend, Specular,
    Variances,
};
use crate::features::{Branch, INPUT_LAYOUT};
use candle_core::{DType, Device, Tensor};
use std::collections::HashMap;
use std::path::Path;

/// Model file format version written in the metadata.
pub const FORMAT_VERSION: &str = "1";
impl Architecture {
    pub(super) fn metadata(&self) -> HashMap<String, String> {
        let kind = match self.kind {
            Kind::Kpcn => "kpcn",
            Kind::Dpcn => "dpcn",
        };
        [
            ("kpcn:format", FORMAT_VERSION.to_string()),
            ("kpcn:input_layout", INPUT_LAYOUT.to_string()),
            ("kpcn:kind", kind.to_string()),
            ("kpcn:design", (if self.design == Design::MultiScale { "multiscale" } else { "flat" }).to_string()),
            ("kpcn:layers", self.layers.to_string()),
            ("kpcn:channels", self.channels.to_string()),
            ("kpcn:conv_size", self.conv_size.to_string()),
            ("kpcn:kernel_size", self.kernel_size.to_string()),
            ("kpcn:clamp", self.clamp.name().to_string()),
            ("kpcn:blend", self.blend.name().to_string()),
            ("kpcn:variances", (if self.variances == Variances::Spatial { "spatial" } else { "file" }).to_string()),
            ("kpcn:specular", (if self.specular == Specular::Linear { "linear" } else { "log" }).to_string()),
            ("kpcn:exposure", (if self.exposure == Exposure::Auto { "auto" } else { "raw" }).to_string()),
            ("kpcn:diffuse_input", self.diffuse_input.name().to_string()),
        ]
        .into_iter()
        .chain(self.specular_bound.map(|k| (bound_key(Branch::Specular), k.to_string())))
        .chain(self.diffuse_bound.map(|k| (bound_key(Branch::Diffuse), k.to_string())))
        .chain(self.diffuse_spread.map(|r| (SPREAD_KEY, r.to_string())))
        .chain(self.diffuse_detail.map(|r| (DETAIL_KEY, r.to_string())))
        .chain(self.gain.then(|| (GAIN_KEY, "on".to_string())))
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }

    fn from_metadata(m: &HashMap<String, String>, origin: &str) -> Result<Self, ModelError> {
        let err = |what: String| ModelError::Format { origin: origin.into(), what };
        let get = |k: &str| m.get(k).ok_or_else(|| err(format!("metadata lacks `{k}` (not a kpcn model file?)")));
        let bound = |b: Branch| match m.get(bound_key(b)) {
            None => Ok(None),
            Some(k) => k.parse().ok().filter(|&k| k > 0).map(Some).ok_or_else(|| {
                err(format!(
                    "metadata `{}` is `{k}`, not a whole number of standard errors from 1 to 255",
                    bound_key(b)
                ))
            }),
        };
        let radius = |key: &str| match m.get(key) {
            None => Ok(None),
            Some(r) => r
                .parse()
                .ok()
                .filter(|&r| r > 0)
                .map(Some)
                .ok_or_else(|| err(format!("metadata `{key}` is `{r}`, not a radius of 1 pixel or more"))),
        };
        let version = get("kpcn:format")?;
        if version != FORMAT_VERSION {
            return Err(err(format!("model format {version}, this kpcn reads format {FORMAT_VERSION}")));
        }
        let layout = get("kpcn:input_layout")?;
        if layout != INPUT_LAYOUT {
            return Err(err(format!("input layout `{layout}`, this kpcn feeds `{INPUT_LAYOUT}`")));
        }
        let num = |k: &str| -> Result<usize, ModelError> {
            get(k)?.parse().map_err(|_| err(format!("metadata `{k}` is not a number")))
        };
        let kind = match get("kpcn:kind")?.as_str() {
            "kpcn" => Kind::Kpcn,
            "dpcn" => Kind::Dpcn,
            other => return Err(err(format!("unknown network kind `{other}`"))),
        };
        // Files from before multi-scale networks have no design: flat.
        let design = match m.get("kpcn:design").map(String::as_str) {
            None | Some("flat") => Design::Flat,
            Some("multiscale") => Design::MultiScale,
            Some(other) => return Err(err(format!("unknown network design `{other}`"))),
        };
        let a = Architecture {
            kind,
            design,
            layers: num("kpcn:layers")?,
            channels: num("kpcn:channels")?,
            conv_size: num("kpcn:conv_size")?,
            kernel_size: num("kpcn:kernel_size")?,
            // Files from before the choice clamp hard.
            clamp: match m.get("kpcn:clamp").map(String::as_str) {
                None | Some("hard") => Clamp::Hard,
                Some("spread") => Clamp::Spread,
                Some("coarse") => Clamp::Coarse,
                Some("fine") => Clamp::Fine,
                Some("fine-pairs") => Clamp::FinePairs,
                Some("fine-pairs-twice") => Clamp::FinePairsTwice,
                Some("significant") => Clamp::Significant,
                Some(other) => return Err(err(format!("unknown firefly clamp `{other}`"))),
            },
            // Files from before the choice blend by interpolation.
            blend: match m.get("kpcn:blend").map(String::as_str) {
                None | Some("lerp") => ScaleBlend::Lerp,
                Some("detail") => ScaleBlend::Detail,
                Some(other) => return Err(err(format!("unknown scale blend `{other}`"))),
            },
            // Files from before the choice were trained on the files' variances.
            variances: match m.get("kpcn:variances").map(String::as_str) {
                None | Some("file") => Variances::File,
                Some("spatial") => Variances::Spatial,
                Some(other) => return Err(err(format!("unknown variance features `{other}`"))),
            },
            // Files from before the choice filter log specular.
            specular: match m.get("kpcn:specular").map(String::as_str) {
                None | Some("log") => Specular::Log,
                Some("linear") => Specular::Linear,
                Some(other) => return Err(err(format!("unknown specular domain `{other}`"))),
            },
            // Files from before the choice see raw radiance.
            exposure: match m.get("kpcn:exposure").map(String::as_str) {
                None | Some("raw") => Exposure::Raw,
                Some("auto") => Exposure::Auto,
                Some(other) => return Err(err(format!("unknown exposure `{other}`"))),
            },
            // Files from before the choice leave the branches unbounded.
            specular_bound: bound(Branch::Specular)?,
            diffuse_bound: bound(Branch::Diffuse)?,
            // Files from before the choice lose what the ceiling takes.
            diffuse_spread: radius(SPREAD_KEY)?,
            // Files from before the choice keep d̂ as it is.
            diffuse_detail: radius(DETAIL_KEY)?,
            // Files from before the choice see linear d̃.
            diffuse_input: match m.get("kpcn:diffuse_input").map(String::as_str) {
                None | Some("linear") => DiffuseInput::Linear,
                Some("log") => DiffuseInput::Log,
                Some(other) => return Err(err(format!("unknown diffuse input `{other}`"))),
            },
            // Files from before the choice have no gain.
            gain: match m.get(GAIN_KEY).map(String::as_str) {
                None => false,
                Some("on") => true,
                Some(other) => return Err(err(format!("metadata `{GAIN_KEY}` is `{other}`, not `on`"))),
            },
        };
        a.validate(origin)?;
        Ok(a)
    }
}

impl Model {
    /// Reads a model file.
    pub fn load(path: &Path) -> Result<Model, ModelError> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io { path: path.into(), source })?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Parses model-file bytes (`origin` names them in errors).
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Model, ModelError> {
        let err = |what: String| ModelError::Format { origin: origin.into(), what };
        let (_, meta) =
            safetensors::SafeTensors::read_metadata(bytes).map_err(|e| err(format!("not a safetensors file ({e})")))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let arch = Architecture::from_metadata(&meta, origin)?;
        // Checked first, so that a process short of memory gets an error, not an abort.
        let needed = bytes.len().saturating_mul(4).saturating_add(super::LOADING_HEADROOM);
        if !crate::kernel::buffers::can_allocate(needed) {
            return Err(ModelError::OutOfMemory(needed));
        }
        let tensors = candle_core::safetensors::load_buffer(bytes, &Device::Cpu)?;
        let branch = |name: &str| -> Result<BranchWeights, ModelError> {
            let layers = arch
                .layer_shapes()
                .into_iter()
                .enumerate()
                .map(|(l, (o, i, k))| {
                    let get = |t: &str, shape: &[usize]| -> Result<Tensor, ModelError> {
                        let key = format!("{name}.{l}.{t}");
                        let v = tensors.get(&key).ok_or_else(|| err(format!("tensor `{key}` is missing")))?;
                        if v.dims() != shape {
                            return Err(err(format!("tensor `{key}` has shape {:?}, expected {shape:?}", v.dims())));
                        }
                        Ok(v.to_dtype(DType::F32)?)
                    };
                    Ok((get("weight", &[o, i, k, k])?, get("bias", &[o])?))
                })
                .collect::<Result<_, ModelError>>()?;
            Ok(BranchWeights { layers })
        };
        Ok(Model {
            arch,
            diffuse: branch("diffuse")?,
            specular: branch("specular")?,
            description: meta.get("kpcn:description").cloned().unwrap_or_default(),
        })
    }

    /// Serialises the model with its metadata.
    pub fn to_bytes(&self) -> Result<Vec<u8>, ModelError> {
        self.to_bytes_with(Vec::new(), HashMap::new())
    }

    /// Serialises the model plus extra tensors and metadata (training checkpoints); the
    /// result still loads as a model.
    pub fn to_bytes_with(
        &self,
        extra: Vec<(String, Tensor)>,
        extra_meta: HashMap<String, String>,
    ) -> Result<Vec<u8>, ModelError> {
        let mut meta = self.arch.metadata();
        meta.insert("kpcn:description".into(), self.description.clone());
        meta.extend(extra_meta);
        let mut named = extra;
        for (name, b) in [("diffuse", &self.diffuse), ("specular", &self.specular)] {
            for (l, (w, bias)) in b.layers.iter().enumerate() {
                named.push((format!("{name}.{l}.weight"), w.clone()));
                named.push((format!("{name}.{l}.bias"), bias.clone()));
            }
        }
        let views: Vec<(String, Tensor)> = named;
        safetensors::serialize(views.iter().map(|(n, t)| (n.as_str(), t)), Some(meta))
            .map_err(|e| ModelError::Format { origin: "serialise".into(), what: e.to_string() })
    }

    /// Writes the model file (through a temporary file, renamed into place).
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        write_atomically(path, &self.to_bytes()?)
    }

    /// Writes the model file with every weight rounded to half precision (f16): half the
    /// bytes, for shipping. Loading widens the weights back to f32.
    pub fn save_half(&self, path: &Path) -> Result<(), ModelError> {
        let half = |b: &BranchWeights| -> Result<BranchWeights, ModelError> {
            let layers = b
                .layers
                .iter()
                .map(|(w, bias)| Ok((w.to_dtype(DType::F16)?, bias.to_dtype(DType::F16)?)))
                .collect::<Result<_, ModelError>>()?;
            Ok(BranchWeights { layers })
        };
        let m = Model { diffuse: half(&self.diffuse)?, specular: half(&self.specular)?, ..self.clone() };
        write_atomically(path, &m.to_bytes()?)
    }
}

/// A model file's bytes with its firefly clamp set to `clamp` (a multi-scale model's):
/// every tensor and every other metadata entry kept byte for byte.
pub fn model_file_with_clamp(bytes: &[u8], clamp: Clamp, origin: &str) -> Result<Vec<u8>, ModelError> {
    let model = Model::from_bytes(bytes, origin)?;
    let err = |what: String| ModelError::Format { origin: origin.into(), what };
    if model.arch.design != Design::MultiScale {
        return Err(err("a flat network has no firefly clamp".into()));
    }
    with_metadata(bytes, origin, "kpcn:clamp", Some(clamp.name().into()))
}

/// The metadata key of a branch's bound.
fn bound_key(b: Branch) -> &'static str {
    match b {
        Branch::Diffuse => "kpcn:diffuse_bound",
        Branch::Specular => "kpcn:specular_bound",
    }
}

/// The metadata key of [`Architecture::diffuse_spread`].
const SPREAD_KEY: &str = "kpcn:diffuse_spread";

/// The model file `bytes` with the light its diffuse ceiling takes spread over the
/// (2r + 1)² window around where it was taken (`Some(r)`), or lost (`None`)
/// ([`Architecture::diffuse_spread`]), every weight kept bit for bit.
pub fn model_file_with_spread(bytes: &[u8], radius: Option<u8>, origin: &str) -> Result<Vec<u8>, ModelError> {
    let rewritten = with_metadata(bytes, origin, SPREAD_KEY, radius.map(|r| r.to_string()))?;
    Model::from_bytes(&rewritten, origin)?;
    Ok(rewritten)
}

/// The metadata key of [`Architecture::diffuse_detail`].
const DETAIL_KEY: &str = "kpcn:diffuse_detail";

/// The metadata key of [`Architecture::gain`].
const GAIN_KEY: &str = "kpcn:gain";

/// The model file `bytes` with the diffuse detail restored over (2r + 1)² windows
/// (`Some(r)`) or not (`None`) ([`Architecture::diffuse_detail`]), every weight kept bit
/// for bit.
pub fn model_file_with_detail(bytes: &[u8], radius: Option<u8>, origin: &str) -> Result<Vec<u8>, ModelError> {
    let rewritten = with_metadata(bytes, origin, DETAIL_KEY, radius.map(|r| r.to_string()))?;
    Model::from_bytes(&rewritten, origin)?;
    Ok(rewritten)
}

/// The model file `bytes` with branch `b` bounded by `errors` standard errors
/// ([`Architecture::specular_bound`], [`Architecture::diffuse_bound`]; `None` lifts the
/// bound, and the diffuse bound's spread with it), every weight kept bit for bit.
pub fn model_file_with_bound(bytes: &[u8], b: Branch, errors: Option<u8>, origin: &str) -> Result<Vec<u8>, ModelError> {
    Model::from_bytes(bytes, origin)?;
    let bounded = with_metadata(bytes, origin, bound_key(b), errors.map(|k| k.to_string()))?;
    // Without its ceiling there is nothing for a spread to spread.
    if b == Branch::Diffuse && errors.is_none() {
        with_metadata(&bounded, origin, SPREAD_KEY, None)
    } else {
        Ok(bounded)
    }
}

/// `bytes` with metadata `key` set to `value` (removed for `None`), tensors unchanged.
fn with_metadata(bytes: &[u8], origin: &str, key: &str, value: Option<String>) -> Result<Vec<u8>, ModelError> {
    let err = |what: String| ModelError::Format { origin: origin.into(), what };
    let (_, meta) = safetensors::SafeTensors::read_metadata(bytes).map_err(|e| err(e.to_string()))?;
    let mut meta = meta.metadata().clone().unwrap_or_default();
    match value {
        Some(v) => meta.insert(key.into(), v),
        None => meta.remove(key),
    };
    let tensors = safetensors::SafeTensors::deserialize(bytes).map_err(|e| err(e.to_string()))?;
    safetensors::serialize(tensors.tensors(), Some(meta)).map_err(|e| err(e.to_string()))
}

/// Writes `bytes` to `path` through a temporary file renamed into place.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), ModelError> {
    crate::io::atomic::write_atomically(path, bytes).map_err(|source| ModelError::Io { path: path.into(), source })
}
