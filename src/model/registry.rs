//! The names a model goes by: the trained models shipped inside the library, the default,
//! `auto`'s choice and the untrained presets. The one list that [`Model::resolve`], its
//! error, `--help`, `kpcn model info`, the C ABI and the plugins read.

use super::{Architecture, Kind, Model, ModelError, Quality};
use std::path::Path;

/// A trained model compiled into the library.
#[derive(Debug)]
pub struct Shipped {
    /// Its name (`--model NAME`, `KpcnOptions.model_name`).
    pub name: &'static str,
    /// What it is, in a line.
    pub about: &'static str,
    bytes: &'static [u8],
}

impl Shipped {
    /// Its model file's bytes.
    pub fn bytes(&self) -> &'static [u8] {
        self.bytes
    }

    /// Parses its weights.
    pub fn load(&self) -> Result<Model, ModelError> {
        Model::from_bytes(self.bytes, &format!("shipped model {}", self.name))
    }
}

/// A [`Shipped`] entry: its name, its file under `models/` (without `.safetensors`), what
/// it is.
macro_rules! shipped {
    ($name:expr, $file:literal, $about:literal) => {
        Shipped { name: $name, about: $about, bytes: include_bytes!(concat!("../../models/", $file, ".safetensors")) }
    };
}

/// Every shipped model, the default first, then the rest of the quality ladder.
pub static SHIPPED: [Shipped; 6] = [
    shipped!(Quality::Balanced.name(), "balanced", "the default: the quality ladder's middle rung, a 5-level U-Net"),
    shipped!(Quality::Fast.name(), "fast", "the ladder's narrowest rung: a third of balanced's FLOPs"),
    shipped!(Quality::High.name(), "high", "the ladder's widest rung: twice balanced's FLOPs"),
    shipped!("spatial", "spatial", "compact's network on spatial variance estimates: files without variances"),
    shipped!("compact", "compact", "a 3-level U-Net: the shortest reach, so the least memory per band"),
    shipped!("small-flat", "small-flat", "the flat KPCN, every layer at full resolution: slower"),
];

/// The model that runs when none is named; `default` is another name for it.
pub const DEFAULT: &str = Quality::Balanced.name();

/// The name that picks a model per frame ([`auto_choice`]).
pub const AUTO: &str = "auto";

/// `auto`'s pick for a frame: [`DEFAULT`] when it has a colour variance (per-pixel
/// variances or half buffers), else `spatial`, trained on the spatial estimates that such
/// a frame gets.
pub fn auto_choice(colour_variance: bool) -> &'static str {
    if colour_variance { DEFAULT } else { "spatial" }
}

/// Untrained architecture presets (Xavier-uniform, seed 0; [`Model::is_untrained`]): they
/// only test the pipeline.
pub const PRESETS: [&str; 5] = ["paper", "small", "multiscale", "paper-dpcn", "small-dpcn"];

/// The shipped model of this name (`default` included).
pub fn shipped(name: &str) -> Option<&'static Shipped> {
    let name = if name == "default" { DEFAULT } else { name };
    SHIPPED.iter().find(|s| s.name == name)
}

/// The shipped models' names, quoted, comma-separated: for messages.
pub fn shipped_names() -> String {
    SHIPPED.iter().map(|s| format!("`{}`", s.name)).collect::<Vec<_>>().join(", ")
}

impl Model {
    /// The default model ([`DEFAULT`]).
    pub fn embedded_default() -> Result<Model, ModelError> {
        Self::resolve(DEFAULT)
    }

    /// A shipped model by name ([`SHIPPED`], or `default`), an untrained preset
    /// ([`PRESETS`]) or a `.safetensors` file.
    pub fn resolve(name: &str) -> Result<Model, ModelError> {
        if let Some(s) = shipped(name) {
            return s.load();
        }
        match name {
            "paper" => Self::xavier(Architecture::paper(Kind::Kpcn), 0),
            "small" => Self::xavier(Architecture::small(Kind::Kpcn), 0),
            "multiscale" => Self::xavier(Architecture::multiscale(), 0),
            "paper-dpcn" => Self::xavier(Architecture::paper(Kind::Dpcn), 0),
            "small-dpcn" => Self::xavier(Architecture::small(Kind::Dpcn), 0),
            p if p.ends_with(".safetensors") => Self::load(Path::new(p)),
            other => Err(ModelError::UnknownPreset(other.into())),
        }
    }

    /// The shipped model of a rung of the quality ladder.
    pub fn shipped_rung(q: Quality) -> Result<Model, ModelError> {
        Self::resolve(q.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_resolves_once() {
        let mut names: Vec<&str> = SHIPPED.iter().map(|s| s.name).chain(PRESETS).chain([AUTO, "default"]).collect();
        let n = names.len();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), n, "a name is listed twice");
        for s in &SHIPPED {
            assert!(!Model::resolve(s.name).unwrap().is_untrained(), "{}", s.name);
        }
        for p in PRESETS {
            assert!(Model::resolve(p).unwrap().is_untrained(), "{p}");
        }
        for q in Quality::ALL {
            assert!(shipped(q.name()).is_some(), "rung {} is not shipped", q.name());
        }
        assert!(shipped(auto_choice(true)).is_some() && shipped(auto_choice(false)).is_some());
        let e = Model::resolve("nope").unwrap_err().to_string();
        assert!(SHIPPED.iter().all(|s| e.contains(s.name)), "{e}");
    }
}
