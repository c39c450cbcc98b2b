//! `kpcn model`: inspect model files and create initial (untrained) ones.

use anyhow::{Context, bail};
use clap::{Args, Subcommand, ValueEnum};
use kpcn::features::Branch;
use kpcn::model::{
    Architecture, Clamp, Design, Kind, Model, Quality, model_file_with_bound, model_file_with_clamp,
    model_file_with_detail, model_file_with_spread, registry, write_atomically,
};
use std::path::PathBuf;

/// Arguments of `kpcn model`.
#[derive(Debug, Args)]
pub struct ModelArgs {
    /// What to do.
    #[command(subcommand)]
    pub action: ModelAction,
}

/// `kpcn model` actions.
#[derive(Debug, Subcommand)]
pub enum ModelAction {
    /// Describe a model: `default`, a preset or a .safetensors file.
    Info {
        /// Model name or file.
        #[arg(default_value = "default")]
        model: String,
    },
    /// Rewrite a model with its weights in half precision (f16): half the file, for
    /// shipping (the ladder's models/*.safetensors); outputs change by f16 rounding only.
    Half {
        /// Model name or file.
        model: String,
        /// Output file (.safetensors).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Rewrite a multi-scale model with another firefly clamp: an inference-time choice,
    /// so every weight is kept bit for bit (the shipped models' last build step).
    Clamp {
        /// Model name or file.
        model: String,
        /// The clamp: `hard` (the excess is lost), `spread` (shared over the 3×3
        /// neighbourhood), `coarse` (averaged into the coarsest scale), `fine` (full
        /// resolution only; the coarser scales pool the unclamped colour), `fine-pairs` (as
        /// fine, to the second-brightest neighbour), `fine-pairs-twice` (fine-pairs run
        /// twice: clusters of three go too) or `significant` (fine-pairs-twice, and a
        /// pixel far above its 3×3 median keeps only what it shows beyond three standard
        /// errors of its mean: clusters of one-sample hits of a small light go too).
        /// `kpcn model info` shows a model's.
        #[arg(long, value_enum, value_name = "CLAMP")]
        clamp: Clamp,
        /// Output file (.safetensors).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Rewrite a model with one branch bounded: an inference-time choice, so every weight is
    /// kept bit for bit (the default's last build steps)
    Bound {
        /// Model name or file.
        model: String,
        /// The branch to bound.
        #[arg(long, value_enum)]
        branch: Branch,
        /// The bound, in standard errors of a pixel's mean (from the variances). Specular:
        /// the most the branch moves a pixel from its noisy value, so a firefly, whose error
        /// is about its value, still goes, while a dark pixel beside it cannot take its
        /// energy and a texture every sample saw keeps its detail. Diffuse: the most the
        /// branch brightens a pixel beyond the mean noisy value of its similar neighbours
        /// (albedo, normal and noisy value alike, within 3 pixels), so light does not bleed
        /// across an edge into the dark side. 0 lifts the bound.
        #[arg(long, value_name = "ERRORS")]
        errors: u8,
        /// Diffuse only: where the light the ceiling takes goes. Shared out over the
        /// (2 RADIUS + 1)² window around the pixel it came from, in proportion to the noisy
        /// light there (each pixel's 3×3 median) and at most that light again per pixel, so
        /// that light carried off a sun patch goes back to it and a lit frame keeps its light
        /// (what dark pixels would take is dropped); 0 (the default) drops it all. At most 15.
        #[arg(long, value_name = "RADIUS", default_value_t = 0)]
        spread: u8,
        /// Output file (.safetensors).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Rewrite a model with the diffuse detail restored (or not): an inference-time choice,
    /// so every weight is kept bit for bit. Over the (2 RADIUS + 1)² window around each
    /// pixel, what the noisy diffuse shows beyond the denoised one (each channel held
    /// within ± the denoised value) is fitted to the shading normals by least squares, and
    /// that fit, the shading of bumps and grooves the kernels smoothed flat, is added back;
    /// the noise, which does not follow the normals, stays out.
    Detail {
        /// Model name or file.
        model: String,
        /// The windows' radius, at most 15; 0 removes the step.
        #[arg(long, value_name = "RADIUS")]
        radius: u8,
        /// Output file (.safetensors).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Write an untrained, Xavier-initialised model of a preset architecture.
    Init {
        /// Architecture.
        #[arg(long, value_enum, default_value_t = Preset::Small)]
        preset: Preset,
        /// Kernel prediction or direct prediction.
        #[arg(long, value_enum, default_value_t = Kind::Kpcn)]
        kind: Kind,
        /// Initialisation seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output file (.safetensors).
        #[arg(short, long)]
        output: PathBuf,
    },
}

/// Architecture presets.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Preset {
    /// 9 layers × 100 channels, 5×5, 21×21 kernels (Bako et al. 2017).
    Paper,
    /// 6 layers × 32 channels, 3×3, 11×11 kernels.
    Small,
    /// U-Net with 3 pooling levels (16…64 channels), 5×5 kernels at 3 scales, blended
    /// (KPCN only; 93 kFLOP per pixel against `small`'s 319 k).
    Multiscale,
    /// The quality ladder's `fast` rung: U-Net with 5 pooling levels (8…48 channels),
    /// 5×5 kernels at 5 scales (`kpcn model info fast` gives its reach).
    Fast,
    /// The ladder's `balanced` rung: 5 levels, 16…96 channels.
    Balanced,
    /// The ladder's `high` rung: 5 levels, 24…144 channels.
    High,
}

impl Preset {
    /// The architecture of this preset and kind.
    pub fn architecture(self, kind: Kind) -> anyhow::Result<Architecture> {
        Ok(match self {
            Preset::Paper => Architecture::paper(kind),
            Preset::Small => Architecture::small(kind),
            Preset::Multiscale if kind == Kind::Kpcn => Architecture::multiscale(),
            Preset::Fast if kind == Kind::Kpcn => Architecture::ladder(Quality::Fast),
            Preset::Balanced if kind == Kind::Kpcn => Architecture::ladder(Quality::Balanced),
            Preset::High if kind == Kind::Kpcn => Architecture::ladder(Quality::High),
            Preset::Multiscale | Preset::Fast | Preset::Balanced | Preset::High => {
                anyhow::bail!("multi-scale presets predict kernels only: drop --kind dpcn")
            }
        })
    }
}

/// Prints what a model is.
pub fn describe(m: &Model) {
    let a = &m.arch;
    match a.design {
        Design::Flat => println!(
            "  architecture  {:?}: {} layers × {} channels, {}×{} convolutions",
            a.kind, a.layers, a.channels, a.conv_size, a.conv_size
        ),
        Design::MultiScale => println!(
            "  architecture  multi-scale {:?}: {} pooling levels, {}…{} channels, {}×{} convolutions",
            a.kind,
            a.layers,
            a.channels,
            a.channels * (a.layers + 1),
            a.conv_size,
            a.conv_size
        ),
    }
    if a.kind == Kind::Kpcn {
        let scales = if a.design == Design::MultiScale { a.layers } else { 1 };
        println!("  kernels       {}×{} at {scales} scale(s)", a.kernel_size, a.kernel_size);
        if a.design == Design::MultiScale {
            let clamp = match a.clamp {
                Clamp::Hard => "hard (8-neighbour maximum; the excess is lost)",
                Clamp::Spread => "spread (the excess shared over the 3×3 neighbourhood)",
                Clamp::Coarse => "coarse (the excess averaged into the coarsest scale)",
                Clamp::Fine => "fine (full resolution only; coarser scales pool the unclamped colour)",
                Clamp::FinePairs => "fine-pairs (as fine, to the second-brightest neighbour)",
                Clamp::FinePairsTwice => "fine-pairs-twice (fine-pairs applied twice: clusters of three go)",
                Clamp::Significant => {
                    "significant (fine-pairs-twice, and rare bright samples: what stands out keeps only its excess beyond 3 standard errors)"
                }
            };
            println!("  firefly clamp {clamp}");
            let blend = match a.blend {
                kpcn::model::ScaleBlend::Lerp => "lerp: (1 − α)·fine + α·up(coarse)",
                kpcn::model::ScaleBlend::Detail => "detail: fine + α·up(coarse − down(fine)) (Vogels et al. 2018)",
            };
            println!("  scale blend   {blend}");
            if a.diffuse_input == kpcn::model::DiffuseInput::Log {
                println!("  diffuse       the network sees ln(1 + d̃); its kernels filter d̃");
            }
            if a.gain {
                println!("  gain          each branch's result times 2σ(g), g from the full-resolution head");
            }
            let specular = match a.specular {
                kpcn::model::Specular::Log => "log radiance ln(1 + s), output exp(ŝ) − 1 (biased dark)",
                kpcn::model::Specular::Linear => "linear radiance (energy-preserving)",
            };
            println!("  specular      kernels filter {specular}");
            match a.specular_bound {
                Some(k) => println!("  specular      moved at most {k} standard errors of each pixel's mean"),
                None => println!("  specular      unbounded (as far as its kernels take it)"),
            }
            match a.diffuse_bound {
                Some(k) => println!(
                    "  diffuse       brightened at most {k} standard errors past its similar neighbours' noisy mean{}",
                    match a.variances {
                        kpcn::model::Variances::File => " (errors from their median variance)",
                        kpcn::model::Variances::Spatial => " (errors from the median variance of the neighbours alike)",
                    }
                ),
                None => println!("  diffuse       unbounded (as far as its kernels take it)"),
            }
            match a.diffuse_spread {
                Some(r) => println!(
                    "  diffuse       what the ceiling takes spread over the {0}×{0} window around it (the light kept)",
                    2 * r as usize + 1
                ),
                None if a.diffuse_bound.is_some() => println!("  diffuse       what the ceiling takes is dropped"),
                None => {}
            }
            if let Some(r) = a.diffuse_detail {
                println!(
                    "  diffuse       detail that follows the normals restored over {0}×{0} windows",
                    2 * r as usize + 1
                );
            }
        }
    }
    let variances = match a.variances {
        kpcn::model::Variances::File => "the file's own (spatial estimates where it has none)",
        kpcn::model::Variances::Spatial => "3×3 spatial estimates, always (trained on them)",
    };
    println!("  variances     {variances}");
    let exposure = match a.exposure {
        kpcn::model::Exposure::Raw => "raw radiance, as rendered",
        kpcn::model::Exposure::Auto => "auto (each frame scaled to a key of 0.18, the output scaled back)",
    };
    println!("  exposure      {exposure}");
    println!("  reach         {} px (how far each side an output pixel depends on the input)", a.reach());
    println!("  cost          {:.1} kFLOP per pixel (both branches)", a.flops_per_pixel() / 1e3);
    println!("  description   {}", m.description);
    if m.is_untrained() {
        println!("  WARNING       this model is UNTRAINED: its output is not a useful denoise");
    }
}

/// Runs `kpcn model`.
pub fn run(args: &ModelArgs) -> anyhow::Result<()> {
    match &args.action {
        ModelAction::Info { model } => {
            let m = Model::resolve(model)?;
            println!("{model}");
            describe(&m);
        }
        ModelAction::Half { model, output } => {
            let m = Model::resolve(model)?;
            m.save_half(output).with_context(|| format!("{}: cannot write the model", output.display()))?;
            println!("{}", output.display());
        }
        ModelAction::Clamp { model, clamp, output } => {
            let rewritten = model_file_with_clamp(&model_bytes(model)?, *clamp, model)?;
            write_atomically(output, &rewritten)
                .with_context(|| format!("{}: cannot write the model", output.display()))?;
            println!("{}", output.display());
        }
        ModelAction::Bound { model, branch, errors, spread, output } => {
            let errors = Some(*errors).filter(|&k| k > 0);
            let spread = Some(*spread).filter(|&r| r > 0);
            if spread.is_some() && (*branch != Branch::Diffuse || errors.is_none()) {
                bail!(
                    "--spread spreads what the diffuse ceiling takes: give it with --branch diffuse and --errors 1 or more"
                );
            }
            let mut rewritten = model_file_with_bound(&model_bytes(model)?, *branch, errors, model)?;
            if *branch == Branch::Diffuse && errors.is_some() {
                rewritten = model_file_with_spread(&rewritten, spread, model)?;
            }
            write_atomically(output, &rewritten)
                .with_context(|| format!("{}: cannot write the model", output.display()))?;
            println!("{}", output.display());
        }
        ModelAction::Detail { model, radius, output } => {
            let radius = Some(*radius).filter(|&r| r > 0);
            let rewritten = model_file_with_detail(&model_bytes(model)?, radius, model)?;
            write_atomically(output, &rewritten)
                .with_context(|| format!("{}: cannot write the model", output.display()))?;
            println!("{}", output.display());
        }
        ModelAction::Init { preset, kind, seed, output } => {
            let m = Model::xavier(preset.architecture(*kind)?, *seed)?;
            m.save(output).with_context(|| format!("{}: cannot write the model", output.display()))?;
            println!("{}", output.display());
            describe(&m);
        }
    }
    Ok(())
}

/// The bytes of a shipped model by name, or of a model file.
fn model_bytes(model: &str) -> anyhow::Result<Vec<u8>> {
    match registry::shipped(model) {
        Some(s) => Ok(s.bytes().to_vec()),
        None => std::fs::read(model).with_context(|| format!("{model}: cannot read the model")),
    }
}
