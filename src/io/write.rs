//! Atomic EXR writing: a temporary file in the target folder, renamed into place, so a
//! failed or interrupted run never leaves a truncated output.

use super::error::IoError;
use super::frame::{FrameBuffers, Plane};
use super::oiio::{Attribute, Output, OutputSpec, SubimageInfo};
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// EXR compressions OpenImageIO accepts.
pub const COMPRESSIONS: &[&str] = &["none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab"];

/// Rows interleaved and handed to the writer at once.
const ROW_BAND: usize = 64;

/// How to write a frame.
#[derive(Debug, Clone, Default)]
pub struct WriteOptions {
    /// EXR compression; `None` keeps the frame's own (`compression` attribute) or uses zip.
    pub compression: Option<String>,
    /// Refuse to replace an existing file.
    pub no_clobber: bool,
}

/// Attributes describing the file rather than the image: OpenImageIO sets them itself.
fn is_file_structure(name: &str) -> bool {
    matches!(name, "compression" | "oiio:subimages" | "oiio:subimagename" | "name" | "type" | "version" | "chunkCount")
        || name.starts_with("openexr:")
        || name.starts_with("oiio:BitsPerSample")
}

/// Removes the temporary file unless disarmed.
struct TempGuard(Option<PathBuf>);

impl Drop for TempGuard {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            let _ = fs::remove_file(p);
        }
    }
}

fn temp_path(target: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    // Ends in .exr so OpenImageIO's writer accepts it; hidden so tools ignore it.
    target.with_file_name(format!(".{name}.kpcn-{}-{n}.tmp.exr", std::process::id()))
}

/// One part of a multi-part EXR: a name and the frame channels it holds.
#[derive(Debug, Clone)]
pub struct Part<'a> {
    /// Part name (e.g. `beauty`, `denoised`).
    pub name: &'a str,
    /// Channel names of the frame, in the order to write.
    pub channels: Vec<&'a str>,
}

impl FrameBuffers {
    /// Writes every channel and attribute to a single-part EXR at `path`, atomically.
    pub fn write(&self, path: &Path, opts: &WriteOptions) -> Result<(), IoError> {
        let all = Part { name: "", channels: self.channel_names().collect() };
        self.write_parts(path, &[all], opts)
    }

    /// Writes the frame as a multi-part EXR, one part per [`Part`], atomically. Every
    /// part carries the frame's attributes.
    pub fn write_parts(&self, path: &Path, parts: &[Part], opts: &WriteOptions) -> Result<(), IoError> {
        let is_exr = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
        if !is_exr {
            return Err(IoError::NotExr { path: path.into() });
        }
        let compression = match &opts.compression {
            Some(c) if COMPRESSIONS.contains(&c.as_str()) => c.clone(),
            Some(c) => return Err(IoError::Compression(c.clone())),
            None => self.attribute("compression").filter(|c| COMPRESSIONS.contains(c)).unwrap_or("zip").to_string(),
        };
        if opts.no_clobber && path.exists() {
            return Err(IoError::Exists { path: path.into() });
        }
        let planes: Vec<Vec<&Plane>> = parts
            .iter()
            .map(|part| {
                part.channels
                    .iter()
                    .map(|c| {
                        self.plane(c)
                            .ok_or_else(|| IoError::NoSuchChannel { path: path.into(), channel: c.to_string() })
                    })
                    .collect()
            })
            .collect::<Result<_, _>>()?;
        let attributes: Vec<Attribute> =
            self.attributes.iter().filter(|a| !is_file_structure(&a.name)).cloned().collect();
        let specs: Vec<OutputSpec> = parts
            .iter()
            .zip(&planes)
            .map(|(part, planes)| OutputSpec {
                part_name: part.name,
                info: SubimageInfo { nchannels: planes.len(), ..self.subimage_info() },
                channels: planes.iter().map(|p| (p.name.as_str(), p.format)).collect(),
                compression: &compression,
                attributes: &attributes,
            })
            .collect();

        let write_err = |reason: String| IoError::Write { path: path.into(), reason };
        let tmp = temp_path(path);
        let mut guard = TempGuard(Some(tmp.clone()));
        let mut out = Output::create(&tmp, &specs).map_err(write_err)?;
        for (i, planes) in planes.iter().enumerate() {
            if i > 0 {
                out.next_part().map_err(write_err)?;
            }
            self.write_part(&mut out, planes).map_err(write_err)?;
        }
        out.close().map_err(write_err)?;

        let fs_err = |e: std::io::Error| write_err(e.to_string());
        fs::File::open(&tmp).and_then(|f| f.sync_all()).map_err(fs_err)?;
        if opts.no_clobber {
            // A hard link fails if the target appeared meanwhile: no race with other writers.
            fs::hard_link(&tmp, path).map_err(|e| match e.kind() {
                std::io::ErrorKind::AlreadyExists => IoError::Exists { path: path.into() },
                _ => fs_err(e),
            })?;
        } else {
            fs::rename(&tmp, path).map_err(fs_err)?;
            guard.0 = None;
        }
        drop(guard);
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            // Make the rename durable; failure here loses nothing already written.
            let _ = fs::File::open(dir).and_then(|d| d.sync_all());
        }
        Ok(())
    }

    fn write_part(&self, out: &mut Output, planes: &[&Plane]) -> Result<(), String> {
        let (w, h) = (self.width(), self.height());
        let mut band = Vec::with_capacity(ROW_BAND * w * planes.len());
        for r0 in (0..h).step_by(ROW_BAND) {
            let r1 = (r0 + ROW_BAND).min(h);
            band.clear();
            for i in r0 * w..r1 * w {
                band.extend(planes.iter().map(|p| p.data[i]));
            }
            let y = self.window.y;
            out.write_rows(y + r0 as i32, y + r1 as i32, &band)?;
        }
        Ok(())
    }
}
