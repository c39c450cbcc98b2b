//! kpcn: a kernel-predicting Monte Carlo render denoiser (Bako et al. 2017) for production
//! pipelines.
//!
//! Data flows one way: file → [`io::FrameBuffers`] → [`io::layout::KpcnInputs`] → network →
//! kernels → buffers → file.
//!
//! The library core (`io`, `features`, `model`, `kernel`, `tile`, `denoise` and the C ABI in
//! `capi`) builds alone with `--no-default-features`; the `tools` feature (default) adds the
//! simulator, trainer and evaluator above it; the `kpcn` command line is the binary's own.
//! `docs/ARCHITECTURE.md` is the map.
//!
//! Denoise a file as `kpcn denoise --model auto` does:
//!
//! ```
//! use kpcn::denoise::{Denoisers, FileJob, FileOptions, Options};
//! use std::path::Path;
//!
//! let out = std::env::temp_dir().join("kpcn-doc-example.exr");
//! let denoisers = Denoisers::auto(Options::default())?;
//! let job = FileJob::open(Path::new("examples/data/spheres-crop-00016spp.exr"), None)?;
//! // `auto` picks the model by whether the file has colour variances.
//! let (denoiser, _) = denoisers.pick(job.mapping().colour_variance_in_file());
//! let report = job.run(denoiser, &out, &FileOptions::default(), &|_progress| true)?;
//! println!("{report:?}");
//! # std::fs::remove_file(&out)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod capi;
pub mod denoise;
#[cfg(feature = "tools")]
pub mod eval;
pub mod features;
pub mod io;
pub mod kernel;
pub mod model;
pub mod rng;
#[cfg(feature = "tools")]
pub mod sim;
pub mod tile;
#[cfg(feature = "tools")]
pub mod train;
