//! A file denoised as `kpcn denoise` does it, for every entrance that takes a file and its
//! options by name (the CLI, the Python module): which Blender view layers run, what the
//! new layer is called, and what the user is told on the way ([`Note`]).

use super::{Denoisers, FileError, FileJob, FileOptions, FileReport, Progress};
use crate::io::WriteOptions;
use crate::io::layout::Layout;
use std::path::{Path, PathBuf};

/// Which Blender view layers of a file to denoise (files without view layers have one input).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub enum ViewLayers {
    /// The first by name.
    #[default]
    First,
    /// This one.
    Named(String),
    /// Each into its own `<ViewLayer>.Denoised`.
    All,
}

impl ViewLayers {
    /// `None` → the first; `"all"` → all; any other name → that one.
    pub fn parse(name: Option<&str>) -> ViewLayers {
        match name {
            None => ViewLayers::First,
            Some("all") => ViewLayers::All,
            Some(n) => ViewLayers::Named(n.to_string()),
        }
    }
}

/// A file denoise's options, as `kpcn denoise` takes them.
#[derive(Debug, Clone, Default)]
pub struct FileRequest {
    /// Channel naming convention; detected when `None`.
    pub layout: Option<Layout>,
    /// Which view layers.
    pub view_layers: ViewLayers,
    /// The new layer's name; default `denoised`, or for Blender files `<ViewLayer>.Denoised`.
    pub layer: Option<String>,
    /// Also write `NAME_diffuse` and `NAME_specular`.
    pub aovs: bool,
    /// Write only the new layers.
    pub separate: bool,
    /// Allow the output to be the input (the layer is added in place).
    pub in_place: bool,
    /// Compression and overwrite policy.
    pub write: WriteOptions,
}

/// What a file denoise tells its user beside the result. The CLI prints warnings with
/// `kpcn: warning: ` and the rest as its verbosity asks; the Python module raises warnings.
#[derive(Debug, Clone, PartialEq)]
pub enum Note {
    /// `auto` picked this model for the file.
    Picked {
        /// The file.
        input: PathBuf,
        /// The model's name.
        model: &'static str,
    },
    /// The file has several view layers and one was taken.
    ViewLayerChosen {
        /// The file.
        input: PathBuf,
        /// The one denoised.
        chosen: String,
        /// All of them.
        all: Vec<String>,
    },
    /// Inputs without a variance in the file, estimated (name and how).
    EstimatedVariances {
        /// The file.
        input: PathBuf,
        /// `quantity (how)` per input.
        estimated: Vec<String>,
    },
    /// Samples of an input were NaN/Inf or out of range and were repaired.
    Repaired {
        /// The file.
        input: PathBuf,
        /// The input.
        name: &'static str,
        /// What was done.
        what: String,
    },
    /// Diffuse + specular exceed the beauty beyond rounding.
    PassesDisagree {
        /// The file.
        input: PathBuf,
        /// By how much, in % of the beauty.
        excess: f64,
        /// Pixels where the beauty is not diffuse + specular.
        pixels: usize,
    },
    /// The beauty holds energy beyond diffuse + specular, carried undenoised.
    Remainder {
        /// The file.
        input: PathBuf,
        /// In % of the beauty's energy.
        share: f64,
        /// Pixels that hold it.
        pixels: usize,
    },
}

impl Note {
    /// Whether the image may not be what the user expects (said unless asked to be quiet).
    pub fn is_warning(&self) -> bool {
        matches!(self, Note::EstimatedVariances { .. } | Note::Repaired { .. } | Note::PassesDisagree { .. })
    }
}

impl std::fmt::Display for Note {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Note::Picked { input, model } => write!(f, "{}: --model auto: `{model}`", input.display()),
            Note::ViewLayerChosen { input, chosen, all } => write!(
                f,
                "{}: denoising view layer `{chosen}` of {} ({}); --view-layer NAME or all picks",
                input.display(),
                all.len(),
                all.join(", ")
            ),
            Note::EstimatedVariances { input, estimated } => write!(
                f,
                "{}: no variance for {} — estimated: {}",
                input.display(),
                estimated.len(),
                estimated.join("; ")
            ),
            Note::Repaired { input, name, what } => write!(f, "{}: {name}: {what}", input.display()),
            Note::PassesDisagree { input, excess, pixels } => write!(
                f,
                "{}: diffuse + specular exceed the beauty by {excess:.1} % in {pixels} pixels — the passes disagree (written from different renders or samples?); the difference is kept in the output as it was",
                input.display()
            ),
            Note::Remainder { input, share, pixels } => write!(
                f,
                "{}: the beauty holds {share:.2} % of its energy beyond diffuse + specular (emission, volumes, …) in {pixels} pixels: carried to the output undenoised",
                input.display()
            ),
        }
    }
}

/// One view layer (or the only input) denoised.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The view layer, for Blender files.
    pub view_layer: Option<String>,
    /// The layer written.
    pub layer: String,
    /// The model that ran (its description).
    pub model: String,
    /// The layout the channels were read by.
    pub layout: Layout,
    /// Width and height.
    pub size: (usize, usize),
    /// Rows per band.
    pub band_rows: usize,
    /// A middle band's tile size (its context rows share the budget).
    pub tile: Option<(usize, usize)>,
    /// Repairs, remainder and stage times.
    pub report: FileReport,
}

impl FileRequest {
    /// Refuses options that contradict each other, before any file is touched.
    pub fn check(&self) -> Result<(), String> {
        if self.view_layers == ViewLayers::All && self.separate {
            return Err("--view-layer all adds each layer to a copy of the input: drop --separate".into());
        }
        if self.view_layers == ViewLayers::All && self.layer.is_some() {
            return Err("--view-layer all names each result <ViewLayer>.Denoised: drop --layer".into());
        }
        if self.separate && self.in_place {
            return Err(
                "a separate output holds only the new layers and cannot be the input: drop one of separate, in-place"
                    .into(),
            );
        }
        Ok(())
    }

    /// The file options of one view layer; `first` is false when the output already holds
    /// an earlier view layer's result (it is then added to in place).
    fn file_options(&self, view_layer: Option<&str>, first: bool) -> FileOptions {
        FileOptions {
            layer: match (&self.layer, view_layer) {
                (Some(l), _) => l.clone(),
                (None, Some(v)) => format!("{v}.Denoised"),
                (None, None) => "denoised".into(),
            },
            aovs: self.aovs,
            separate: self.separate,
            in_place: self.in_place || !first,
            write: WriteOptions {
                compression: self.write.compression.clone(),
                no_clobber: self.write.no_clobber && first,
                encoders: self.write.encoders,
            },
            band_rows: None,
        }
    }

    /// Denoises `input` into `output` (atomically per view layer), telling `note` what the
    /// user should know. `progress` counts tiles of each view layer; `false` cancels.
    pub fn run(
        &self,
        denoisers: &Denoisers,
        input: &Path,
        output: &Path,
        progress: &dyn Fn(Progress) -> bool,
        note: &mut dyn FnMut(Note),
    ) -> Result<Vec<Outcome>, FileError> {
        let layers: Vec<Option<String>> = match &self.view_layers {
            ViewLayers::All => {
                let all = FileJob::open(input, self.layout)?.mapping().view_layers.clone();
                if all.is_empty() { vec![None] } else { all.into_iter().map(Some).collect() }
            }
            ViewLayers::Named(l) => vec![Some(l.clone())],
            ViewLayers::First => vec![None],
        };
        let mut outcomes = Vec::new();
        for (i, layer) in layers.iter().enumerate() {
            // Later view layers are added to the output written by the first, in place.
            let source = if i == 0 { input } else { output };
            outcomes.push(self.run_view_layer(denoisers, source, output, layer.as_deref(), i == 0, progress, note)?);
        }
        Ok(outcomes)
    }

    #[allow(clippy::too_many_arguments)]
    fn run_view_layer(
        &self,
        denoisers: &Denoisers,
        input: &Path,
        output: &Path,
        view_layer: Option<&str>,
        first: bool,
        progress: &dyn Fn(Progress) -> bool,
        note: &mut dyn FnMut(Note),
    ) -> Result<Outcome, FileError> {
        let job = FileJob::open_view_layer(input, self.layout, view_layer)?;
        let mapping = job.mapping().clone();
        let (denoiser, picked) = denoisers.pick(mapping.colour_variance_in_file());
        let input = input.to_path_buf();
        if let Some(model) = picked {
            note(Note::Picked { input: input.clone(), model });
        }
        if let (Some(chosen), true) = (&mapping.view_layer, mapping.view_layers.len() > 1) {
            note(Note::ViewLayerChosen {
                input: input.clone(),
                chosen: chosen.clone(),
                all: mapping.view_layers.clone(),
            });
        }
        let estimated: Vec<String> = mapping
            .estimated_variances()
            .iter()
            .map(|e| format!("{} ({})", e.quantity.name(), e.variance_description()))
            .collect();
        if !estimated.is_empty() {
            note(Note::EstimatedVariances { input: input.clone(), estimated });
        }
        let opts = self.file_options(mapping.view_layer.as_deref(), first);
        let (w, h) = job.size();
        let band = job.bands(denoiser, &opts).rows();
        let report = job.run(denoiser, output, &opts, progress)?;
        for (name, range, r) in &report.repairs {
            let mut what = Vec::new();
            if r.nonfinite > 0 {
                what.push(format!("{} NaN/Inf samples set to 0", r.nonfinite));
            }
            if r.out_of_range > 0 {
                what.push(format!("{} samples outside {range} clamped", r.out_of_range));
            }
            note(Note::Repaired { input: input.clone(), name, what: what.join(", ") });
        }
        let remainder = &report.remainder;
        if remainder.pixels > 0 {
            note(match remainder.disagreement() {
                Some(excess) => Note::PassesDisagree { input: input.clone(), excess, pixels: remainder.pixels },
                None => Note::Remainder { input: input.clone(), share: remainder.share(), pixels: remainder.pixels },
            });
        }
        let (rows, total) = (band.min(h), (band + 2 * denoiser.halo(w)).min(h));
        let c0 = (total - rows) / 2;
        let tile = denoiser.band_tiles(w, c0..c0 + rows, total).first().map(|t| (t.w, t.h));
        Ok(Outcome {
            view_layer: mapping.view_layer.clone(),
            layer: opts.layer,
            model: denoiser.model().description.clone(),
            layout: mapping.layout,
            size: (w, h),
            band_rows: band,
            tile,
            report,
        })
    }
}
