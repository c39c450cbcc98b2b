//! `FrameBuffers`: one frame as named f32 planes, read from and written to files.

use super::error::IoError;
use super::oiio::{Attribute, Input, SampleFormat, SubimageInfo};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Rows decoded per read call: bounds the interleaved scratch buffer.
const ROW_BAND: usize = 64;
/// Channels decoded per read call, for the same reason.
const CHANNEL_BLOCK: usize = 16;

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
        let open_err = |reason: String| IoError::Open { path: path.into(), reason };
        if !path.exists() {
            return Err(open_err("no such file".into()));
        }
        let mut input = Input::open(path).map_err(open_err)?;
        let info0 = input.info(0).map_err(open_err)?;
        let mut frame = FrameBuffers::new(info0.width, info0.height);
        frame.window = Window {
            x: info0.x,
            y: info0.y,
            full_x: info0.full_x,
            full_y: info0.full_y,
            full_width: info0.full_width,
            full_height: info0.full_height,
        };
        frame.source = Some(path.into());
        frame.parts = input.subimages();
        frame.attributes = input.attributes(0).map_err(open_err)?;
        let mut seen = HashSet::new();
        for s in 0..input.subimages() {
            let info = input.info(s).map_err(open_err)?;
            let part = input.subimage_name(s);
            if info.deep {
                return Err(IoError::Deep { path: path.into(), subimage: s });
            }
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
            let channels = input.channels(s).map_err(open_err)?;
            let planes = read_planes(&mut input, s, &info, channels.len()).map_err(|reason| IoError::Read {
                path: path.into(),
                subimage: s,
                reason,
            })?;
            for ((name, format), data) in channels.into_iter().zip(planes) {
                let name = if seen.contains(&name) && !part.is_empty() { format!("{part}.{name}") } else { name };
                seen.insert(name.clone());
                frame.planes.push(Plane { name, format, data });
            }
        }
        Ok(frame)
    }
}

/// Decodes all channels of subimage `s` into planes, a band of rows and a block of
/// channels at a time so the interleaved scratch stays small.
fn read_planes(input: &mut Input, s: usize, info: &SubimageInfo, nch: usize) -> Result<Vec<Vec<f32>>, String> {
    let (w, h) = (info.width, info.height);
    let mut planes = vec![vec![0f32; w * h]; nch];
    let band = if info.tile_height > 0 { info.tile_height * ROW_BAND.div_ceil(info.tile_height) } else { ROW_BAND };
    let mut scratch = Vec::new();
    for c0 in (0..nch).step_by(CHANNEL_BLOCK) {
        let c1 = (c0 + CHANNEL_BLOCK).min(nch);
        let k = c1 - c0;
        for r0 in (0..h).step_by(band) {
            let r1 = (r0 + band).min(h);
            scratch.resize((r1 - r0) * w * k, 0.0);
            input.read_rows(s, info.y + r0 as i32, info.y + r1 as i32, c0, c1, &mut scratch)?;
            for (i, px) in scratch.chunks_exact(k).enumerate() {
                let at = r0 * w + i;
                for (j, v) in px.iter().enumerate() {
                    planes[c0 + j][at] = *v;
                }
            }
        }
    }
    Ok(planes)
}
