//! What a model name runs: one model for every frame, or with `auto`
//! ([`registry::AUTO`]) the model [`registry::auto_choice`] picks for each frame.

use super::{DenoiseError, Denoiser, Options};
use crate::model::{Model, registry};

/// One denoiser, or `auto`'s two. Every entrance (CLI, C ABI, plugins) picks through it.
pub struct Denoisers {
    /// The named model, or under `auto` the one for frames with a colour variance.
    first: Denoiser,
    /// Under `auto`, the one for frames without.
    without_variances: Option<Denoiser>,
}

impl Denoisers {
    /// `model` for every frame.
    pub fn one(model: Model, options: Options) -> Result<Denoisers, DenoiseError> {
        Ok(Denoisers { first: Denoiser::new(model, options)?, without_variances: None })
    }

    /// `auto`: both models [`registry::auto_choice`] picks between.
    pub fn auto(options: Options) -> Result<Denoisers, DenoiseError> {
        let load = |colour_variance| Model::resolve(registry::auto_choice(colour_variance));
        Ok(Denoisers {
            first: Denoiser::new(load(true)?, options.clone())?,
            without_variances: Some(Denoiser::new(load(false)?, options)?),
        })
    }

    /// `auto` ([`registry::AUTO`]) or one model by name (shipped, preset or file).
    pub fn named(name: &str, options: Options) -> Result<Denoisers, DenoiseError> {
        match name {
            registry::AUTO => Denoisers::auto(options),
            _ => Denoisers::one(Model::resolve(name)?, options),
        }
    }

    /// Whether this is `auto`.
    pub fn is_auto(&self) -> bool {
        self.without_variances.is_some()
    }

    /// The denoiser for a frame that has (or lacks) a colour variance, and under `auto`
    /// the name of the model picked.
    pub fn pick(&self, colour_variance: bool) -> (&Denoiser, Option<&'static str>) {
        match &self.without_variances {
            Some(without) if !colour_variance => (without, Some(registry::auto_choice(false))),
            Some(_) => (&self.first, Some(registry::auto_choice(true))),
            None => (&self.first, None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_picks_by_colour_variance_and_one_model_never_does() {
        let auto = Denoisers::auto(Options::default()).unwrap();
        for v in [true, false] {
            let (d, name) = auto.pick(v);
            let expected = Model::resolve(registry::auto_choice(v)).unwrap();
            assert_eq!((d.model().arch, name), (expected.arch, Some(registry::auto_choice(v))));
        }
        let one = Denoisers::one(Model::resolve("compact").unwrap(), Options::default()).unwrap();
        assert!(!one.is_auto() && one.pick(false).1.is_none());
    }
}
