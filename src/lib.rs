//! kpcn: a kernel-predicting Monte Carlo render denoiser (Bako et al. 2017) for production
//! pipelines.
//!
//! Data flows one way: file → [`io::FrameBuffers`] → [`io::layout::KpcnInputs`] → network →
//! kernels → buffers → file.
//!
//! The library core (`io`, `features`, `model`, `kernel`, `tile`, `denoise` and the C ABI in
//! `capi`) builds alone with `--no-default-features`; the `tools` feature (default) adds the
//! CLI, simulator, trainer and evaluator above it.
#![warn(missing_docs)]

pub mod capi;
#[cfg(feature = "tools")]
pub mod cli;
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
