//! EXR writing, atomic through [`AtomicFile`]: a failed or interrupted run never leaves a
//! truncated output.

use super::atomic::AtomicFile;
use super::error::IoError;
use super::frame::{FrameBuffers, Plane};
use super::oiio::{Attribute, Output, OutputSpec, SampleFormat, SubimageInfo};
use std::path::{Path, PathBuf};

/// EXR compressions OpenImageIO accepts.
pub const COMPRESSIONS: &[&str] = &["none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab"];

/// The lossless ones: an output keeps its input's compression only when it is one of
/// these, so that the channels copied from a lossy (DWA, B44, PXR24) input are not
/// re-encoded lossily a second time.
pub const LOSSLESS_COMPRESSIONS: &[&str] = &["none", "rle", "zips", "zip", "piz"];

/// How to write a frame.
#[derive(Debug, Clone, Default)]
pub struct WriteOptions {
    /// EXR compression; `None` keeps the frame's own (`compression` attribute) when it is
    /// lossless ([`LOSSLESS_COMPRESSIONS`]) and uses zip otherwise.
    pub compression: Option<String>,
    /// Refuse to replace an existing file.
    pub no_clobber: bool,
    /// Threads that compress at once (0 and 1: the calling thread alone). Several use
    /// OpenEXR's thread pool, which is process-wide: OpenImageIO's `exr_threads` is set
    /// to this while the file is created and put back after, and the pool stays that size
    /// until OpenImageIO next opens an EXR. For processes that own their OpenImageIO (the
    /// CLI), never on a host's behalf. Each thread holds two chunks of rows in flight (a
    /// 3840-wide file of 44 float channels: about 30 MB each). Rows too wide for
    /// OpenImageIO to pass two chunks to OpenEXR at once (over 512 KB: 3840 pixels of
    /// more than 34 float channels) use one, the pool's only cost there.
    pub encoders: usize,
}

/// The most bytes of rows OpenImageIO 2.4's EXR writer passes to OpenEXR in one call (it
/// splits larger writes): a 3840-wide row of 44 float channels is 676 KB, so 24 rows.
const OIIO_ROWS_BYTES: usize = 16 << 20;

/// Attributes describing the file rather than the image: OpenImageIO sets them itself.
fn is_file_structure(name: &str) -> bool {
    matches!(name, "compression" | "oiio:subimages" | "oiio:subimagename" | "name" | "type" | "version" | "chunkCount")
        || name.starts_with("openexr:")
        || name.starts_with("oiio:BitsPerSample")
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
        let layout: Vec<(&str, Vec<(&str, SampleFormat)>)> = parts
            .iter()
            .zip(&planes)
            .map(|(part, planes)| (part.name, planes.iter().map(|p| (p.name.as_str(), p.format)).collect()))
            .collect();
        let mut out = FrameWriter::create(path, self, &layout, opts)?;
        for (i, planes) in planes.iter().enumerate() {
            if i > 0 {
                out.next_part()?;
            }
            let data: Vec<&[f32]> = planes.iter().map(|p| p.data.as_slice()).collect();
            out.write_band(&data, self.height())?;
        }
        out.commit()
    }
}

/// An EXR written a band of rows at a time into a temporary file that replaces `path`
/// only on [`commit`](FrameWriter::commit): dropped uncommitted (an error, a panic, a
/// cancel), it leaves nothing behind.
pub struct FrameWriter {
    out: Option<Output>,
    path: PathBuf,
    file: AtomicFile,
    width: usize,
    y0: i32,
    /// Channels of each part, and the part being written.
    nchannels: Vec<usize>,
    part: usize,
    /// Next row of the current part (relative to the data window).
    row: usize,
    scratch: Vec<f32>,
    /// [`WriteOptions::encoders`]: each call hands OpenEXR a chunk per encoder.
    encoders: usize,
}

impl FrameWriter {
    /// Starts writing `path` with `header`'s size, windows and attributes, and these parts
    /// (name, channels with formats). Compression: `opts`, else the header's, else zip.
    pub fn create(
        path: &Path,
        header: &FrameBuffers,
        parts: &[(&str, Vec<(&str, SampleFormat)>)],
        opts: &WriteOptions,
    ) -> Result<FrameWriter, IoError> {
        let is_exr = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
        if !is_exr {
            return Err(IoError::NotExr { path: path.into() });
        }
        let compression = match &opts.compression {
            Some(c) if COMPRESSIONS.contains(&c.as_str()) => c.clone(),
            Some(c) => return Err(IoError::Compression(c.clone())),
            None => header
                .attribute("compression")
                .filter(|c| LOSSLESS_COMPRESSIONS.contains(c))
                .unwrap_or("zip")
                .to_string(),
        };
        if opts.no_clobber && path.exists() {
            return Err(IoError::Exists { path: path.into() });
        }
        super::atomic::check_writable(path).map_err(|reason| IoError::Write { path: path.into(), reason })?;
        let attributes: Vec<Attribute> =
            header.attributes.iter().filter(|a| !is_file_structure(&a.name)).cloned().collect();
        let specs: Vec<OutputSpec> = parts
            .iter()
            .map(|(name, channels)| OutputSpec {
                part_name: name,
                info: SubimageInfo { nchannels: channels.len(), ..header.subimage_info() },
                channels: channels.clone(),
                compression: &compression,
                attributes: &attributes,
            })
            .collect();
        let file = AtomicFile::new(path, opts.no_clobber);
        // Several encoders need calls of a chunk (16 rows) each, and OpenImageIO hands
        // OpenEXR at most OIIO_ROWS_BYTES of rows per call whatever it is given: a row
        // wider than that over 32 rows compresses one chunk at a time whichever the pool.
        let row_bytes: usize =
            parts.iter().map(|(_, c)| c.iter().map(|(_, f)| f.exr_bytes()).sum::<usize>()).max().unwrap_or(0)
                * header.width();
        let encoders = if 32 * row_bytes > OIIO_ROWS_BYTES { 1 } else { opts.encoders.max(1) };
        let out = Output::create(file.temp_path(), &specs, encoders).map_err(|reason| {
            IoError::from_oiio(path, reason, |reason| IoError::Write { path: path.into(), reason })
        })?;
        Ok(FrameWriter {
            out: Some(out),
            path: path.into(),
            file,
            width: header.width(),
            y0: header.window.y,
            nchannels: parts.iter().map(|(_, c)| c.len()).collect(),
            part: 0,
            row: 0,
            scratch: Vec::new(),
            encoders,
        })
    }

    fn err(&self, reason: String) -> IoError {
        IoError::from_oiio(&self.path, reason, |reason| IoError::Write { path: self.path.clone(), reason })
    }

    /// Writes the next `rows` rows of the current part: one plane per channel, in the
    /// part's channel order, each `rows × width` samples.
    pub fn write_band(&mut self, planes: &[&[f32]], rows: usize) -> Result<(), IoError> {
        let (w, nch) = (self.width, self.nchannels[self.part]);
        let n = rows * w;
        if planes.len() != nch || planes.iter().any(|p| p.len() != n) {
            return Err(
                self.err(format!("a band of {} channels × {n} samples; the part has {nch} channels", planes.len()))
            );
        }
        let band = self.rows_per_write();
        let out = self.out.as_mut().expect("open until commit");
        for r0 in (0..rows).step_by(band) {
            let r1 = (r0 + band).min(rows);
            self.scratch.clear();
            for i in r0 * w..r1 * w {
                self.scratch.extend(planes.iter().map(|p| p[i]));
            }
            let y = self.y0 + self.row as i32;
            if let Err(reason) = out.write_rows(y + r0 as i32, y + r1 as i32, &self.scratch) {
                return Err(self.err(reason));
            }
        }
        self.row += rows;
        Ok(())
    }

    /// Rows of the current part that one [`write_band`](FrameWriter::write_band) call
    /// hands OpenEXR at a time (a chunk per encoder): a caller that decodes what it writes
    /// can do so in pieces of this many rows without slowing the encoders.
    pub fn rows_per_write(&self) -> usize {
        self.rows_per_write_of(self.nchannels[self.part])
    }

    /// The most rows any part's [`rows_per_write`](FrameWriter::rows_per_write) is.
    pub fn most_rows_per_write(&self) -> usize {
        self.nchannels.iter().map(|&n| self.rows_per_write_of(n)).max().unwrap_or(1)
    }

    /// Rows per write of a part of `channels` channels.
    fn rows_per_write_of(&self, channels: usize) -> usize {
        super::rows_per_call(channels) * self.encoders
    }

    /// Width of the data window, in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Finishes the current part and starts the next.
    pub fn next_part(&mut self) -> Result<(), IoError> {
        let out = self.out.as_mut().expect("open until commit");
        if let Err(reason) = out.next_part() {
            return Err(self.err(reason));
        }
        self.part += 1;
        self.row = 0;
        Ok(())
    }

    /// Closes, syncs and moves the file into place.
    pub fn commit(mut self) -> Result<(), IoError> {
        let path = self.path.clone();
        let write_err =
            |reason: String| IoError::from_oiio(&path, reason, |reason| IoError::Write { path: path.clone(), reason });
        self.out.take().expect("open until commit").close().map_err(write_err)?;
        self.file.commit().map_err(|e| match e.kind() {
            std::io::ErrorKind::AlreadyExists => IoError::Exists { path: path.clone() },
            _ => write_err(e.to_string()),
        })
    }
}
