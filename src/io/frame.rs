//! `FrameBuffers`: one frame as named f32 planes, read from and written to files.

use super::error::IoError;
use super::exr_core;
use super::oiio::{Attribute, Input, SampleFormat, SubimageInfo};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// One named channel of a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    /// Full channel name, e.g. `diffuse.R`.
    pub name: String,
    /// Format in the file (kept when written back).
    pub format: SampleFormat,
    /// Row-major samples, `width * height`.
    pub data: Vec<f32>,
}

/// Data and display windows of a frame, as in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// Data window origin.
    pub x: i32,
    /// Data window origin.
    pub y: i32,
    /// Display window origin.
    pub full_x: i32,
    /// Display window origin.
    pub full_y: i32,
    /// Display window size.
    pub full_width: usize,
    /// Display window size.
    pub full_height: usize,
}

/// A frame: named f32 planes of one resolution plus the file's metadata.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameBuffers {
    width: usize,
    height: usize,
    /// Data and display windows.
    pub window: Window,
    planes: Vec<Plane>,
    /// Metadata (of the first part for multi-part files).
    pub attributes: Vec<Attribute>,
    /// The file it came from, for error messages.
    pub source: Option<PathBuf>,
    /// Number of parts (subimages) the file had; 1 for frames made in memory.
    pub parts: usize,
}

impl FrameBuffers {
    /// An empty frame of the given size (data window = display window at the origin).
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            window: Window { x: 0, y: 0, full_x: 0, full_y: 0, full_width: width, full_height: height },
            planes: Vec::new(),
            attributes: Vec::new(),
            source: None,
            parts: 1,
        }
    }

    /// Width in pixels (data window).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels (data window).
    pub fn height(&self) -> usize {
        self.height
    }

    /// All planes in file order.
    pub fn planes(&self) -> &[Plane] {
        &self.planes
    }

    /// Channel names in file order.
    pub fn channel_names(&self) -> impl Iterator<Item = &str> {
        self.planes.iter().map(|p| p.name.as_str())
    }

    /// The plane called `name`.
    pub fn plane(&self, name: &str) -> Option<&Plane> {
        self.planes.iter().find(|p| p.name == name)
    }

    /// Samples of channel `name`.
    pub fn channel(&self, name: &str) -> Option<&[f32]> {
        self.plane(name).map(|p| p.data.as_slice())
    }

    /// The path used in error messages.
    pub fn display_path(&self) -> PathBuf {
        self.source.clone().unwrap_or_else(|| PathBuf::from("<memory>"))
    }

    /// Adds channel `name`, replacing one of the same name in place.
    pub fn insert(&mut self, name: &str, format: SampleFormat, data: Vec<f32>) -> Result<(), IoError> {
        if data.len() != self.width * self.height {
            return Err(IoError::ChannelSize {
                path: self.display_path(),
                channel: name.into(),
                got: data.len(),
                width: self.width,
                height: self.height,
            });
        }
        let plane = Plane { name: name.into(), format, data };
        match self.planes.iter_mut().find(|p| p.name == name) {
            Some(p) => *p = plane,
            None => self.planes.push(plane),
        }
        Ok(())
    }

    /// Adds an RGB layer `layer.R/G/B` (e.g. the denoised result).
    pub fn insert_rgb(&mut self, layer: &str, format: SampleFormat, rgb: [Vec<f32>; 3]) -> Result<(), IoError> {
        for (c, data) in ["R", "G", "B"].iter().zip(rgb) {
            self.insert(&format!("{layer}.{c}"), format, data)?;
        }
        Ok(())
    }

    /// A frame with only the named channels (in that order) and all of this frame's
    /// metadata: e.g. the denoised layer alone, for writing to a separate file.
    pub fn select(&self, names: &[&str]) -> Result<FrameBuffers, IoError> {
        let planes = names
            .iter()
            .map(|n| {
                self.plane(n)
                    .cloned()
                    .ok_or_else(|| IoError::NoSuchChannel { path: self.display_path(), channel: n.to_string() })
            })
            .collect::<Result<_, _>>()?;
        Ok(FrameBuffers { planes, ..self.clone_header() })
    }

    fn clone_header(&self) -> FrameBuffers {
        FrameBuffers {
            width: self.width,
            height: self.height,
            window: self.window,
            planes: Vec::new(),
            attributes: self.attributes.clone(),
            source: self.source.clone(),
            parts: 1,
        }
    }

    /// Keeps only rows `rows` of every plane (a band read with context rows, cut to its own).
    pub fn keep_rows(&mut self, rows: std::ops::Range<usize>) {
        let (w, rows) = (self.width, rows.start.min(self.height)..rows.end.min(self.height));
        for p in &mut self.planes {
            p.data.truncate(rows.end * w);
            p.data.drain(..rows.start * w);
        }
        self.height = rows.len();
        self.window.y += rows.start as i32;
    }

    /// A copy of rows `rows` of every plane (clamped to the frame), as a frame of their own.
    pub fn copy_rows(&self, rows: std::ops::Range<usize>) -> FrameBuffers {
        let (w, rows) = (self.width, rows.start.min(self.height)..rows.end.min(self.height));
        let mut frame = FrameBuffers { height: rows.len(), ..self.clone_header() };
        frame.window.y += rows.start as i32;
        frame.parts = self.parts;
        frame.planes = self
            .planes
            .iter()
            .map(|p| Plane {
                name: p.name.clone(),
                format: p.format,
                data: p.data[rows.start * w..rows.end * w].to_vec(),
            })
            .collect();
        frame
    }

    /// Removes channel `name`, returning it.
    pub fn remove(&mut self, name: &str) -> Option<Plane> {
        let i = self.planes.iter().position(|p| p.name == name)?;
        Some(self.planes.remove(i))
    }

    /// Value of a metadata attribute as text.
    pub fn attribute(&self, name: &str) -> Option<&str> {
        self.attributes.iter().find(|a| a.name == name).map(|a| a.text.as_str())
    }

    /// Sets (or replaces) a metadata attribute.
    pub fn set_attribute(&mut self, attr: Attribute) {
        match self.attributes.iter_mut().find(|a| a.name == attr.name) {
            Some(a) => *a = attr,
            None => self.attributes.push(attr),
        }
    }

    /// Channels grouped by layer (the part before the last `.`; `""` for root channels),
    /// in order of first appearance.
    pub fn layers(&self) -> Vec<(String, Vec<&Plane>)> {
        let mut out: Vec<(String, Vec<&Plane>)> = Vec::new();
        for p in &self.planes {
            let layer = p.name.rsplit_once('.').map_or("", |(l, _)| l);
            match out.iter_mut().find(|(l, _)| l == layer) {
                Some((_, v)) => v.push(p),
                None => out.push((layer.to_string(), vec![p])),
            }
        }
        out
    }

    pub(crate) fn subimage_info(&self) -> SubimageInfo {
        let w = &self.window;
        SubimageInfo {
            x: w.x,
            y: w.y,
            width: self.width,
            height: self.height,
            full_x: w.full_x,
            full_y: w.full_y,
            full_width: w.full_width,
            full_height: w.full_height,
            nchannels: self.planes.len(),
            tile_height: 0,
            deep: false,
        }
    }

    /// Reads every channel of every part of `path`. Parts must share one resolution; a
    /// channel whose name repeats an earlier part's is prefixed with its part's name.
    pub fn read(path: &Path) -> Result<Self, IoError> {
        let mut reader = FrameReader::open(path)?;
        let h = reader.header().height;
        // Whole frames are allocated at once: one whose size no compression of this file
        // could hold (ZIP inflates at most ~1000:1) is a corrupt header, refused before
        // asking for memory it would never fill.
        let bytes = (reader.header().width * h).saturating_mul(reader.channels.len()).saturating_mul(4);
        let file = std::fs::metadata(path).map(|m| m.len() as usize).unwrap_or(0);
        if bytes > (1 << 30) && bytes / 1100 > file {
            return Err(IoError::Implausible {
                path: path.into(),
                what: format!("its header claims {} MB of pixels in a {} KB file", bytes >> 20, file >> 10),
            });
        }
        reader.read_band(None, 0, h)
    }
}

/// Where a channel of a [`FrameReader`] lives in the file.
#[derive(Debug, Clone)]
struct ChannelRef {
    name: String,
    /// The name inside its part (`name` gains the part's name when two parts share one).
    part_name: String,
    format: SampleFormat,
    subimage: usize,
    index: usize,
}

/// One part (subimage) of a file: its name and its channels, each as the frame names it
/// and as the part names it.
#[derive(Debug, Clone, PartialEq)]
pub struct PartLayout {
    /// The part's name (empty for single-part files).
    pub name: String,
    /// (frame channel name, name in the part, format), in the part's order.
    pub channels: Vec<(String, String, SampleFormat)>,
}

/// An open image file read a band of rows at a time, so a frame larger than memory
/// allows can be processed in pieces (`kpcn denoise` streams this way).
pub struct FrameReader {
    input: Input,
    /// More handles on the same file that decode other rows of a read at the same time
    /// ([`FrameReader::set_decoders`]).
    more: Vec<Input>,
    header: FrameBuffers,
    channels: Vec<ChannelRef>,
    /// Per subimage: tile height (0 for scanline files) and data-window origin y.
    subimages: Vec<SubimageInfo>,
    /// Per subimage: its name.
    part_names: Vec<String>,
    /// Rows of a compressed chunk of a scanline file (its compression's), which decoders'
    /// shares are cut on.
    chunk_rows: usize,
    /// The handle that decoded the last rows of the previous read (index into the input
    /// and [`FrameReader::more`]): it starts the next one, whose first rows a streamed
    /// band shares with them, so the chunk it holds decoded is not decoded again.
    last_decoder: usize,
    /// Whether the handles that decode are OpenEXRCore's (`exr_core`).
    openexr_core: bool,
}

/// The largest frame kpcn reads: 16384×16384 pixels (a 16K square; renders are smaller).
pub const MAX_PIXELS: usize = 1 << 28;
/// The most channels in one part.
pub const MAX_CHANNELS: usize = 4096;

/// Refuses a header whose size no render has, before anything is allocated from it: a
/// corrupt or forged header claiming 200000×200000 would otherwise ask for 160 GB.
fn check_size(path: &Path, w: usize, h: usize, channels: usize) -> Result<(), IoError> {
    let pixels = w.saturating_mul(h);
    if pixels > MAX_PIXELS || w > MAX_PIXELS || h > MAX_PIXELS || channels > MAX_CHANNELS {
        return Err(IoError::Implausible {
            path: path.into(),
            what: format!("its header claims {w}x{h} pixels and {channels} channels"),
        });
    }
    Ok(())
}

impl FrameReader {
    /// Opens `path` and reads its headers (no pixels yet).
    pub fn open(path: &Path) -> Result<Self, IoError> {
        let open_err =
            |reason: String| IoError::from_oiio(path, reason, |reason| IoError::Open { path: path.into(), reason });
        match std::fs::metadata(path) {
            Err(_) => return Err(open_err("no such file".into())),
            Ok(m) if m.is_file() && m.len() == 0 => return Err(IoError::Empty { path: path.into() }),
            Ok(m) if !m.is_file() => return Err(IoError::NotAFile { path: path.into(), what: file_kind(&m) }),
            Ok(_) => {}
        }
        let input = Input::open(path).map_err(open_err)?;
        let info0 = input.info(0).map_err(open_err)?;
        check_size(path, info0.width, info0.height, info0.nchannels)?;
        let mut header = FrameBuffers::new(info0.width, info0.height);
        header.window = Window {
            x: info0.x,
            y: info0.y,
            full_x: info0.full_x,
            full_y: info0.full_y,
            full_width: info0.full_width,
            full_height: info0.full_height,
        };
        header.source = Some(path.into());
        header.parts = input.subimages();
        header.attributes = input.attributes(0).map_err(open_err)?;
        let mut seen = HashSet::new();
        let mut channels = Vec::new();
        let mut subimages = Vec::new();
        let mut part_names = Vec::new();
        for s in 0..input.subimages() {
            let info = input.info(s).map_err(open_err)?;
            let part = input.subimage_name(s);
            if info.deep {
                return Err(IoError::Deep { path: path.into(), subimage: s });
            }
            check_size(path, info.width, info.height, info.nchannels)?;
            if (info.width, info.height) != (info0.width, info0.height) {
                return Err(IoError::PartSizeMismatch {
                    path: path.into(),
                    subimage: s,
                    name: part,
                    width: info.width,
                    height: info.height,
                    width0: info0.width,
                    height0: info0.height,
                });
            }
            for (index, (name, format)) in input.channels(s).map_err(open_err)?.into_iter().enumerate() {
                let part_name = name.clone();
                let name = if seen.contains(&name) && !part.is_empty() { format!("{part}.{name}") } else { name };
                seen.insert(name.clone());
                channels.push(ChannelRef { name, part_name, format, subimage: s, index });
            }
            subimages.push(info);
            part_names.push(part);
        }
        let chunk_rows = chunk_rows(header.attribute("compression"));
        // The headers and metadata come from the classic reader (what the output copies);
        // pixels, where the file qualifies, from OpenEXRCore, if it sees the same parts.
        let tiled = subimages.iter().any(|i| i.tile_height > 0);
        let core =
            exr_core::enabled() && exr_core::qualifies(&input.format_name(), header.attribute("compression"), tiled);
        let (input, openexr_core) = match core.then(|| Input::open_with_openexr_core(path)) {
            Some(Ok(core)) if core.lists_the_same_parts_as(&input) => (core, true),
            _ => (input, false),
        };
        Ok(FrameReader {
            input,
            more: Vec::new(),
            header,
            channels,
            subimages,
            part_names,
            chunk_rows,
            last_decoder: 0,
            openexr_core,
        })
    }

    /// Decodes each read on `n` threads, each with its own handle on the file (opened
    /// now) reading its own rows: the CLI has OpenEXR decompress on the calling thread
    /// ([`decode_exr_on_the_calling_thread`](super::decode_exr_on_the_calling_thread)),
    /// so this is what spreads it over cores. Each handle holds one chunk and one call's
    /// rows (a 3840-wide file of 41 float channels: about 30 MB), far less than OpenEXR's
    /// own pool keeps. 1 by default.
    pub fn set_decoders(&mut self, n: usize) -> Result<(), IoError> {
        let path = self.header.display_path();
        self.more.truncate(n.saturating_sub(1));
        self.last_decoder = 0;
        while self.more.len() + 1 < n {
            let handle = if self.openexr_core { Input::open_with_openexr_core(&path) } else { Input::open(&path) };
            let handle = handle.map_err(|reason| {
                IoError::from_oiio(&path, reason, |reason| IoError::Open { path: path.clone(), reason })
            })?;
            self.more.push(handle);
        }
        Ok(())
    }

    /// Whether pixels are decoded by OpenEXRCore
    /// ([`read_lossless_exr_with_openexr_core`](super::read_lossless_exr_with_openexr_core)).
    pub fn reads_with_openexr_core(&self) -> bool {
        self.openexr_core
    }

    /// Size, windows, metadata and source of the frame; no planes.
    pub fn header(&self) -> &FrameBuffers {
        &self.header
    }

    /// The most compressed chunks (or tiles) a read of `rows` rows starting on a chunk's
    /// first row spans in any part: more decoders than this never share such a read.
    pub fn chunks_in(&self, rows: usize) -> usize {
        self.subimages.iter().map(|i| rows.div_ceil(self.chunk_of(i).max(1))).max().unwrap_or(1).max(1)
    }

    /// Rows of one compressed chunk of a part: its tiles' height, or its compression's.
    fn chunk_of(&self, info: &SubimageInfo) -> usize {
        if info.tile_height > 0 { info.tile_height } else { self.chunk_rows }
    }

    /// Channel names in file order (as [`FrameBuffers::read`] names them).
    pub fn channel_names(&self) -> impl Iterator<Item = &str> {
        self.channels.iter().map(|c| c.name.as_str())
    }

    /// Reads every channel of the whole frame a band of rows at a time, each band at most
    /// about `budget` bytes, handing each to `f`: memory stays bounded whatever the size.
    pub fn for_each_band(&mut self, budget: usize, mut f: impl FnMut(&FrameBuffers)) -> Result<(), IoError> {
        let (w, h) = (self.header.width, self.header.height);
        let rows = (budget / (4 * w.max(1) * self.channels.len().max(1))).max(1);
        for a in (0..h).step_by(rows) {
            f(&self.read_band(None, a, a + rows)?);
        }
        Ok(())
    }

    /// Whether `path` is a complete image: every sample of every part decodes (read in
    /// bands of 64 MB, so even a 16K frame is checked in bounded memory).
    pub fn is_complete(path: &Path) -> bool {
        FrameReader::open(path).and_then(|mut r| r.for_each_band(64 << 20, |_| {})).is_ok()
    }

    /// The file's parts, with their channels, in file order.
    pub fn parts(&self) -> Vec<PartLayout> {
        (0..self.subimages.len())
            .map(|s| PartLayout {
                name: self.part_names[s].clone(),
                channels: self
                    .channels
                    .iter()
                    .filter(|c| c.subimage == s)
                    .map(|c| (c.name.clone(), c.part_name.clone(), c.format))
                    .collect(),
            })
            .collect()
    }

    /// Format of each channel in file order.
    pub fn channel_formats(&self) -> impl Iterator<Item = (&str, SampleFormat)> {
        self.channels.iter().map(|c| (c.name.as_str(), c.format))
    }

    /// Rows `[y0, y1)` (relative to the data window) of the named channels (all when
    /// `None`) as a frame of height `y1 − y0` whose data window starts at row `y0`.
    pub fn read_band(&mut self, names: Option<&[&str]>, y0: usize, y1: usize) -> Result<FrameBuffers, IoError> {
        self.read(names, y0, y1, None)
    }

    /// The rows of `carried` (a frame this reader read, such as the previous band's last
    /// rows) followed by the same channels' rows from its end to `y1`: a band that shares
    /// context rows with the one before decodes only the rows it does not share.
    pub fn read_band_after(&mut self, carried: FrameBuffers, y1: usize) -> Result<FrameBuffers, IoError> {
        let names: Vec<String> = carried.planes.iter().map(|p| p.name.clone()).collect();
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        let start = (carried.window.y - self.header.window.y).max(0) as usize;
        self.read(Some(&names), start + carried.height, y1.max(start + carried.height), Some(carried))
    }

    /// Rows `[y0, y1)` of the named channels, after the rows of `carried` when given (which
    /// then holds exactly those channels and ends at `y0`).
    fn read(
        &mut self,
        names: Option<&[&str]>,
        y0: usize,
        y1: usize,
        carried: Option<FrameBuffers>,
    ) -> Result<FrameBuffers, IoError> {
        let path = self.header.display_path();
        let y1 = y1.min(self.header.height);
        let y0 = y0.min(y1);
        let base = carried.as_ref().map_or(y0, |c| y0 - c.height.min(y0));
        let wanted: Vec<usize> = match names {
            None => (0..self.channels.len()).collect(),
            Some(names) => names
                .iter()
                .map(|n| {
                    self.channels
                        .iter()
                        .position(|c| c.name == *n)
                        .ok_or_else(|| IoError::NoSuchChannel { path: path.clone(), channel: n.to_string() })
                })
                .collect::<Result<_, _>>()?,
        };
        let mut frame = FrameBuffers { height: y1 - base, ..self.header.clone_header() };
        frame.window.y += base as i32;
        frame.parts = self.header.parts;
        let mut data: Vec<Option<Vec<f32>>> = vec![None; wanted.len()];
        for (s, info) in self.subimages.iter().enumerate() {
            let mut indices: Vec<(usize, usize)> = wanted
                .iter()
                .enumerate()
                .filter(|(_, c)| self.channels[**c].subimage == s)
                .map(|(k, c)| (self.channels[*c].index, k))
                .collect();
            indices.sort_unstable();
            if indices.is_empty() {
                continue;
            }
            let mut unique: Vec<usize> = indices.iter().map(|&(index, _)| index).collect();
            unique.dedup();
            let read_err = |reason| {
                IoError::from_oiio(&path, reason, |reason| IoError::Read { path: path.clone(), subimage: s, reason })
            };
            // A handle per decoder, for reads long enough to share (a chunk each at least),
            // starting with the one that decoded the previous read's last rows.
            let chunk = self.chunk_of(info);
            let chunks = (y1 - y0 + y0 % chunk).div_ceil(chunk);
            let count = self.more.len() + 1;
            let (decoders, start) = (count.min(chunks).max(1), self.last_decoder % count);
            self.last_decoder = (start + decoders - 1) % count;
            let mut handles: Vec<&mut Input> = std::iter::once(&mut self.input).chain(&mut self.more).collect();
            handles.rotate_left(start);
            handles.truncate(decoders);
            let mut planes = read_planes(&mut handles, s, info, chunk, base..y0, y1, &unique).map_err(read_err)?;
            for (p, &(index, k)) in indices.iter().enumerate() {
                // A channel asked for twice is copied; otherwise moved.
                let again = indices.get(p + 1).is_some_and(|n| n.0 == index);
                let plane = &mut planes[unique.binary_search(&index).expect("listed above")];
                data[k] = Some(if again { plane.clone() } else { std::mem::take(plane) });
            }
        }
        for (c, d) in wanted.iter().zip(data) {
            let ch = &self.channels[*c];
            let mut data = d.unwrap_or_default();
            if let Some(rows) = carried.as_ref().and_then(|f| f.channel(&ch.name)) {
                data[..rows.len()].copy_from_slice(rows);
            }
            frame.planes.push(Plane { name: ch.name.clone(), format: ch.format, data });
        }
        Ok(frame)
    }
}

/// What a path that is not a regular file is, for [`IoError::NotAFile`].
fn file_kind(m: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = m.file_type();
    if t.is_dir() {
        "a folder"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_block_device() || t.is_char_device() {
        "a device"
    } else {
        "not a regular file"
    }
}

/// Rows of one compressed chunk of a scanline EXR with this compression (OpenEXR's
/// table); 64, a multiple of all but dwab's, when the header does not say.
fn chunk_rows(compression: Option<&str>) -> usize {
    let name = compression.unwrap_or("").split(':').next().unwrap_or("");
    match name {
        "none" | "rle" | "zips" => 1,
        "zip" | "pxr24" => 16,
        "piz" | "b44" | "b44a" | "dwaa" => 32,
        "dwab" => 256,
        _ => 64,
    }
}

/// Decodes rows `[carried.end, y1)` of channels `channels` (sorted, distinct) of subimage
/// `s` into planes of rows `[carried.start, y1)`, one per channel (the `carried` rows left
/// for the caller to fill), the rows split between `handles` (each on its own thread but
/// the first, on the caller's) in shares of whole `chunk`s of rows, so that no chunk is
/// decoded by two of them. Allocated fallibly: a frame-sized plane that cannot be had is
/// an error, not an abort.
fn read_planes(
    handles: &mut [&mut Input],
    s: usize,
    info: &SubimageInfo,
    chunk: usize,
    carried: std::ops::Range<usize>,
    y1: usize,
    channels: &[usize],
) -> Result<Vec<Vec<f32>>, String> {
    let (w, y0) = (info.width, carried.end);
    let mut planes = Vec::new();
    for _ in channels {
        let mut plane: Vec<f32> = Vec::new();
        plane.try_reserve_exact(w * (y1 - carried.start)).map_err(|_| super::oiio::OUT_OF_MEMORY.to_string())?;
        plane.resize(w * (y1 - carried.start), 0.0);
        planes.push(plane);
    }
    // Rows of each decoder: as many whole chunks each as can be, cut on the file's chunk
    // boundaries.
    let n = handles.len();
    let first = y0 / chunk;
    let chunks = y1.div_ceil(chunk) - first;
    let mut cuts: Vec<usize> = (0..n).map(|i| ((first + i * chunks / n) * chunk).clamp(y0, y1)).collect();
    cuts.push(y1);
    // Each decoder's rows of every plane.
    let mut parts: Vec<Vec<&mut [f32]>> = (0..n).map(|_| Vec::new()).collect();
    for plane in &mut planes {
        let mut rest = &mut plane[carried.len() * w..];
        for (i, part) in parts.iter_mut().enumerate() {
            let (mine, after) = rest.split_at_mut((cuts[i + 1] - cuts[i]) * w);
            part.push(mine);
            rest = after;
        }
    }
    let mut jobs = handles.iter_mut().zip(parts).enumerate();
    let (_, (first, first_part)) = jobs.next().expect("one handle at least");
    std::thread::scope(|scope| {
        let others: Vec<_> = jobs
            .map(|(i, (h, part))| {
                let (a, b) = (cuts[i], cuts[i + 1]);
                scope.spawn(move || decode_rows(h, s, info, a, b, channels, part))
            })
            .collect();
        let mine = decode_rows(first, s, info, cuts[0], cuts[1], channels, first_part);
        others
            .into_iter()
            .map(|t| t.join().unwrap_or_else(|_| Err("a decoder panicked".into())))
            .fold(mine, Result::and)
    })?;
    Ok(planes)
}

/// Decodes rows `[y0, y1)` of channels `channels` into `planes` (those rows of one plane
/// each). Every call reads all of them at once, since a compressed chunk is decoded whole
/// whichever of its channels are asked for, a band of rows at a time so that the
/// interleaved scratch (the channels' span) stays small. Tiled files are read from tile
/// boundaries and cropped.
fn decode_rows(
    input: &mut Input,
    s: usize,
    info: &SubimageInfo,
    y0: usize,
    y1: usize,
    channels: &[usize],
    mut planes: Vec<&mut [f32]>,
) -> Result<(), String> {
    let (w, h) = (info.width, info.height);
    let (Some(&c0), Some(&last)) = (channels.first(), channels.last()) else { return Ok(()) };
    let (c1, k) = (last + 1, last + 1 - c0);
    let th = info.tile_height.max(1);
    let band = th * super::rows_per_call(k).div_ceil(th);
    let mut scratch = Vec::new();
    // Read from the tile boundary at or before y0.
    let mut r0 = y0 / th * th;
    while r0 < y1 {
        let r1 = (r0 + band).min(h);
        scratch.resize((r1 - r0) * w * k, 0.0);
        input.read_rows(s, info.y + r0 as i32, info.y + r1 as i32, c0, c1, &mut scratch)?;
        for r in r0.max(y0)..r1.min(y1) {
            let src = &scratch[(r - r0) * w * k..(r - r0 + 1) * w * k];
            let at = (r - y0) * w;
            for (i, px) in src.chunks_exact(k).enumerate() {
                for (plane, &c) in planes.iter_mut().zip(channels) {
                    plane[at + i] = px[c - c0];
                }
            }
        }
        r0 = r1;
    }
    Ok(())
}
