//! Frames in and out: OpenImageIO through our own C++ shim, the layered-EXR contract
//! (`layout`), and atomic writes (`atomic`, the one home of temporary-file-then-rename).

pub mod atomic;
mod error;
mod exr_core;
mod ffi;
mod frame;
pub mod layout;
mod oiio;
mod view;
mod write;

pub use error::IoError;
pub use exr_core::read_lossless_exr_with_openexr_core;
pub use frame::{FrameBuffers, FrameReader, PartLayout, Plane, Window};
pub use oiio::{
    Attribute, Input, Output, OutputSpec, SampleFormat, SubimageInfo, decode_exr_on_the_calling_thread, oiio_version,
};
pub use view::{IMAGE_NAMES, NamedImages};
pub use write::{COMPRESSIONS, FrameWriter, LOSSLESS_COMPRESSIONS, Part, WriteOptions};

/// Rows of `channels` interleaved channels that one OpenImageIO read or write call moves:
/// whole 16-row chunks (zip's) of at most 1024 samples per column (64 rows of 16
/// channels, 16 of 64), so that the scratch buffer stays small and no chunk is split.
fn rows_per_call(channels: usize) -> usize {
    (1024 / channels.max(1) / 16).max(1) * 16
}
