//! Integration tests, assembled into one binary so linking stays fast.

mod util;

mod capi;
mod cli;
mod cycles_crops;
mod deb;
mod denoise;
mod eval;
mod farm;
mod hard_cases;
mod integrity;
mod io_errors;
mod io_roundtrip;
mod layering;
mod layout_files;
mod plugins;
mod reliability;
mod sim;
mod train;
