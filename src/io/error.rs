//! Typed I/O errors. Each message reads `<file>: <what> — <what to do>`.

use std::path::PathBuf;

/// Everything that can go wrong reading or writing frames.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// OpenImageIO could not open the file at all.
    #[error("{}: cannot open: {reason} — check the path and that it is an image OpenImageIO reads (e.g. EXR)", path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// OpenImageIO's error text.
        reason: String,
    },
    /// A header no render has (a corrupt or forged file): refused before allocating.
    #[error("{}: {what}, beyond kpcn's limits (16384x16384 pixels, 4096 channels) — the file is corrupt or not a render", path.display())]
    Implausible {
        /// The file.
        path: PathBuf,
        /// What the header claims.
        what: String,
    },
    /// A Blender view layer asked for is not in the file.
    #[error("{}: no view layer `{name}` — the file has {}", path.display(), if available.is_empty() { "none".to_string() } else { available.join(", ") })]
    NoSuchViewLayer {
        /// The file.
        path: PathBuf,
        /// The layer asked for.
        name: String,
        /// The file's view layers.
        available: Vec<String>,
    },
    /// A zero-byte file: a write that never happened or was cut off at once.
    #[error("{}: the file is empty (0 bytes) — it was never written completely; re-render or copy it again", path.display())]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// The header opened but pixels could not be decoded.
    #[error("{}: cannot read the pixels of part {subimage}: {reason} — the file is truncated or corrupt; re-render or copy it again", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Subimage (EXR part) index.
        subimage: usize,
        /// OpenImageIO's error text.
        reason: String,
    },
    /// Parts of one multi-part file disagree in resolution.
    #[error("{}: part {subimage} (`{name}`) is {width}x{height} but part 0 is {width0}x{height0} — write every AOV of a frame at one resolution", path.display())]
    PartSizeMismatch {
        /// The file.
        path: PathBuf,
        /// The offending part.
        subimage: usize,
        /// Its name.
        name: String,
        /// Its size.
        width: usize,
        /// Its size.
        height: usize,
        /// Part 0's size.
        width0: usize,
        /// Part 0's size.
        height0: usize,
    },
    /// Deep (multi-sample) images are not supported.
    #[error("{}: part {subimage} is a deep image — flatten it first (`oiiotool IN --flatten -o OUT`)", path.display())]
    Deep {
        /// The file.
        path: PathBuf,
        /// The part.
        subimage: usize,
    },
    /// Writing failed.
    #[error("{}: cannot write: {reason} — check that the folder exists, is writable and has free space", path.display())]
    Write {
        /// The target file.
        path: PathBuf,
        /// What failed.
        reason: String,
    },
    /// The target exists and replacing it was refused.
    #[error("{}: already exists and overwriting was refused — remove it or choose another name", path.display())]
    Exists {
        /// The target file.
        path: PathBuf,
    },
    /// Layered output needs EXR.
    #[error("{}: output must be an OpenEXR file ending in .exr — layered channels can only be written to EXR", path.display())]
    NotExr {
        /// The target file.
        path: PathBuf,
    },
    /// A channel buffer of the wrong length was handed to a frame.
    #[error("{}: channel `{channel}` has {got} samples but the frame is {width}x{height} — give one sample per pixel", path.display())]
    ChannelSize {
        /// The frame's file, or `<memory>`.
        path: PathBuf,
        /// The channel.
        channel: String,
        /// Samples given.
        got: usize,
        /// Frame size.
        width: usize,
        /// Frame size.
        height: usize,
    },
    /// A channel asked for by name is not in the frame.
    #[error("{}: no channel `{channel}` in the frame — check the name against the file's channel list", path.display())]
    NoSuchChannel {
        /// The file.
        path: PathBuf,
        /// The channel.
        channel: String,
    },
    /// Channels a layout needs are absent.
    #[error("{}: missing {} for the {layout} layout — {hint}", path.display(), describe_missing(missing))]
    MissingChannels {
        /// The file.
        path: PathBuf,
        /// Layout name.
        layout: String,
        /// Channel names (or alternatives) that were looked for.
        missing: Vec<String>,
        /// What to do.
        hint: String,
    },
    /// An in-memory image handed to the denoiser does not fit.
    #[error("<memory>: image `{name}` {msg} — pass images of the frame's size with valid strides")]
    BadImage {
        /// Which image.
        name: String,
        /// What is wrong.
        msg: String,
    },
    /// In-memory images the network needs were not given.
    #[error("<memory>: missing input {} {} — set them (the network needs diffuse, albedo, normal, depth, and color or specular)", if missing.len() == 1 { "image" } else { "images" }, missing.join(", "))]
    MissingImages {
        /// The images' names.
        missing: Vec<String>,
    },
    /// An unknown compression name.
    #[error("unknown EXR compression `{0}` — use one of none, rle, zips, zip, piz, pxr24, b44, b44a, dwaa, dwab")]
    Compression(String),
    /// Memory ran out while reading, denoising or writing: the file is fine, the budget or
    /// the machine is not.
    #[error("{}: out of memory {what} — lower --max-memory (the C ABI's max_memory_mb, the plugins' max_memory) or free memory; the file itself is fine", path.display())]
    OutOfMemory {
        /// The file, or `<memory>`.
        path: PathBuf,
        /// What needed the memory, with its size when known.
        what: String,
    },
    /// An input that is not a regular file (a folder, a FIFO, a device): refused before it
    /// is opened, since it could hang or be read only once.
    #[error("{}: is {what}, not an image file — give the path of an image file", path.display())]
    NotAFile {
        /// The path.
        path: PathBuf,
        /// What it is.
        what: &'static str,
    },
    /// Anything else from the file system.
    #[error("{}: {source}", path.display())]
    Fs {
        /// The path involved.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
}

impl IoError {
    /// The error of a failed OpenImageIO call on `path`: [`IoError::OutOfMemory`] when the
    /// shim (or the planes it decodes into) ran out of memory, else `or(reason)`.
    pub(crate) fn from_oiio(path: &std::path::Path, reason: String, or: impl FnOnce(String) -> IoError) -> IoError {
        if reason == super::oiio::OUT_OF_MEMORY {
            IoError::OutOfMemory { path: path.into(), what: "decoding or encoding its pixels".into() }
        } else {
            or(reason)
        }
    }
}

fn describe_missing(missing: &[String]) -> String {
    let noun = if missing.len() == 1 { "channel" } else { "channels" };
    format!("{noun} {}", missing.join(", "))
}
