//! kpcn: a kernel-predicting Monte Carlo render denoiser (Bako et al. 2017) for production
//! pipelines.
//!
//! Data flows one way: file → [`io::FrameBuffers`] → [`io::layout::KpcnInputs`] → network →
//! kernels → buffers → file.
#![warn(missing_docs)]

pub mod cli;
pub mod denoise;
pub mod eval;
pub mod features;
pub mod io;
pub mod kernel;
pub mod model;
pub mod rng;
pub mod sim;
pub mod tile;
pub mod train;
