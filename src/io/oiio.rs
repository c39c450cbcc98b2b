//! Safe wrapper over the C++ shim: RAII handles, `Result`s carrying OIIO's error text.

use super::ffi;
use std::ffi::{CStr, CString};
use std::os::raw::c_char;
use std::path::Path;

/// Sample format of one channel in a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleFormat {
    /// 16-bit float.
    Half,
    /// 32-bit float.
    Float,
    /// 32-bit unsigned integer (e.g. object ids).
    Uint,
    /// Anything else OpenImageIO reads (8/16-bit integer formats, …).
    Other,
}

impl SampleFormat {
    fn from_code(code: i32) -> Self {
        match code as u32 {
            ffi::kpcn_format_KPCN_FORMAT_HALF => Self::Half,
            ffi::kpcn_format_KPCN_FORMAT_FLOAT => Self::Float,
            ffi::kpcn_format_KPCN_FORMAT_UINT => Self::Uint,
            _ => Self::Other,
        }
    }

    /// The format used when writing this channel to EXR: half, float and uint stay what
    /// they are (a uint channel's plane holds its bits, see [`Input::read_rows`]), all else
    /// becomes float.
    pub(crate) fn exr_code(self) -> i32 {
        match self {
            Self::Half => ffi::kpcn_format_KPCN_FORMAT_HALF as i32,
            Self::Uint => ffi::kpcn_format_KPCN_FORMAT_UINT as i32,
            _ => ffi::kpcn_format_KPCN_FORMAT_FLOAT as i32,
        }
    }

    /// Bytes of one sample as written to EXR ([`SampleFormat::exr_code`]).
    pub(crate) fn exr_bytes(self) -> usize {
        if self == Self::Half { 2 } else { 4 }
    }

    /// Short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Half => "half",
            Self::Float => "float",
            Self::Uint => "uint",
            Self::Other => "other",
        }
    }
}

/// One metadata attribute, kept typed so that it survives a round trip.
#[derive(Debug, Clone, PartialEq)]
pub struct Attribute {
    /// Attribute name, e.g. `kpcn:spp` or `screenWindowWidth`.
    pub name: String,
    /// OpenImageIO type spelling, e.g. `int`, `string`, `matrix`.
    pub type_name: String,
    /// The value as text (for reports).
    pub text: String,
    /// Raw bytes of a non-string value; `None` for a single string (taken from `text`).
    pub raw: Option<Vec<u8>>,
}

impl Attribute {
    /// A string attribute.
    pub fn string(name: &str, value: &str) -> Self {
        Self { name: name.into(), type_name: "string".into(), text: value.into(), raw: None }
    }

    /// An `int` attribute.
    pub fn int(name: &str, value: i32) -> Self {
        Self {
            name: name.into(),
            type_name: "int".into(),
            text: value.to_string(),
            raw: Some(value.to_ne_bytes().to_vec()),
        }
    }

    /// A `float` attribute.
    pub fn float(name: &str, value: f32) -> Self {
        Self {
            name: name.into(),
            type_name: "float".into(),
            text: value.to_string(),
            raw: Some(value.to_ne_bytes().to_vec()),
        }
    }
}

fn last_error() -> String {
    // SAFETY: the shim always returns a valid NUL-terminated thread-local string.
    unsafe { CStr::from_ptr(ffi::kpcn_oiio_last_error()) }.to_string_lossy().into_owned()
}

/// The error text of a shim call that ran out of memory (a C++ `std::bad_alloc`): the
/// callers turn it into [`super::IoError::OutOfMemory`], never into "corrupt file".
pub(crate) const OUT_OF_MEMORY: &str = "out of memory";

fn check(status: i32) -> Result<(), String> {
    match status {
        0 => Ok(()),
        ffi::KPCN_SHIM_OUT_OF_MEMORY => Err(OUT_OF_MEMORY.into()),
        _ => Err(last_error()),
    }
}

fn cstr(p: *const c_char) -> String {
    if p.is_null() {
        return String::new();
    }
    // SAFETY: the shim hands out NUL-terminated strings that live as long as the handle.
    unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
}

fn path_cstring(path: &Path) -> Result<CString, String> {
    CString::new(path.as_os_str().as_encoded_bytes()).map_err(|_| "the path contains a NUL byte".to_string())
}

/// OpenImageIO's version, e.g. `2.4.7`.
pub fn oiio_version() -> String {
    // SAFETY: no arguments, no state.
    let v = unsafe { ffi::kpcn_oiio_version() };
    format!("{}.{}.{}", v / 10000, v / 100 % 100, v % 100)
}

/// Runs OpenEXR's (de)compression on the calling thread instead of its own thread pool,
/// which keeps two compressed and decoded chunks per pool thread for each open file (a
/// 3840-wide file of 41 float channels held 115 MB for reading and 125 MB for writing).
/// Reads are spread over cores by handles of their own instead
/// ([`FrameReader::set_decoders`](super::FrameReader::set_decoders)); writes that ask for
/// it use the pool ([`WriteOptions::encoders`](super::WriteOptions::encoders)).
/// Process-wide: for the CLI, never the library on a host's behalf.
pub fn decode_exr_on_the_calling_thread() -> Result<(), String> {
    // SAFETY: sets one OIIO global attribute; no pointers.
    check(unsafe { ffi::kpcn_oiio_set_exr_threads(-1) })
}

/// Geometry of one subimage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SubimageInfo {
    /// Data window origin.
    pub x: i32,
    /// Data window origin.
    pub y: i32,
    /// Data window size.
    pub width: usize,
    /// Data window size.
    pub height: usize,
    /// Display window.
    pub full_x: i32,
    /// Display window.
    pub full_y: i32,
    /// Display window.
    pub full_width: usize,
    /// Display window.
    pub full_height: usize,
    /// Channel count.
    pub nchannels: usize,
    /// Tile height (0 for scanline files).
    pub tile_height: usize,
    /// Deep data.
    pub deep: bool,
}

/// An open image file.
pub struct Input {
    raw: *mut ffi::kpcn_input,
}

// SAFETY: the handle is owned exclusively; OIIO's ImageInput may be used from any
// thread as long as calls are not concurrent, which `&mut self` on reads ensures.
unsafe impl Send for Input {}

impl Input {
    /// Opens `path` and reads all subimage headers.
    pub fn open(path: &Path) -> Result<Self, String> {
        Self::open_with(path, false)
    }

    /// Opens `path` as [`Input::open`] does, an EXR with OpenImageIO's OpenEXRCore reader
    /// (see `exr_core`), whose reads decode on the calling thread.
    pub(crate) fn open_with_openexr_core(path: &Path) -> Result<Self, String> {
        Self::open_with(path, true)
    }

    fn open_with(path: &Path, openexr_core: bool) -> Result<Self, String> {
        let c = path_cstring(path)?;
        let mut raw = std::ptr::null_mut();
        // SAFETY: valid C string, out-pointer to a local.
        check(unsafe { ffi::kpcn_input_open(c.as_ptr(), i32::from(openexr_core), &mut raw) })?;
        Ok(Self { raw })
    }

    /// Whether `other` (a handle on the same file) lists the same parts: geometry,
    /// channels and formats.
    pub(crate) fn lists_the_same_parts_as(&self, other: &Input) -> bool {
        self.subimages() == other.subimages()
            && (0..self.subimages()).all(|s| {
                matches!((self.info(s), other.info(s)), (Ok(x), Ok(y)) if x == y)
                    && matches!((self.channels(s), other.channels(s)), (Ok(x), Ok(y)) if x == y)
            })
    }

    /// OpenImageIO's format name, e.g. `openexr`.
    pub fn format_name(&self) -> String {
        // SAFETY: handle is valid while self lives.
        cstr(unsafe { ffi::kpcn_input_format_name(self.raw) })
    }

    /// Number of subimages (EXR parts).
    pub fn subimages(&self) -> usize {
        // SAFETY: handle is valid.
        unsafe { ffi::kpcn_input_subimages(self.raw) as usize }
    }

    /// Geometry of subimage `s`.
    pub fn info(&self, s: usize) -> Result<SubimageInfo, String> {
        let mut i = ffi::kpcn_subimage_info::default();
        // SAFETY: handle valid; the shim range-checks `s`.
        check(unsafe { ffi::kpcn_input_subimage_info(self.raw, s as i32, &mut i) })?;
        let u = |v: i32| v.max(0) as usize;
        Ok(SubimageInfo {
            x: i.x,
            y: i.y,
            width: u(i.width),
            height: u(i.height),
            full_x: i.full_x,
            full_y: i.full_y,
            full_width: u(i.full_width),
            full_height: u(i.full_height),
            nchannels: u(i.nchannels),
            tile_height: u(i.tile_height),
            deep: i.deep != 0,
        })
    }

    /// Part name of subimage `s` (may be empty). `s` must be in range.
    pub fn subimage_name(&self, s: usize) -> String {
        assert!(s < self.subimages());
        // SAFETY: index checked above.
        cstr(unsafe { ffi::kpcn_input_subimage_name(self.raw, s as i32) })
    }

    /// Channel names and formats of subimage `s`.
    pub fn channels(&self, s: usize) -> Result<Vec<(String, SampleFormat)>, String> {
        let n = self.info(s)?.nchannels;
        Ok((0..n)
            .map(|c| {
                // SAFETY: `s` validated by `info`, `c` < nchannels.
                let name = cstr(unsafe { ffi::kpcn_input_channel_name(self.raw, s as i32, c as i32) });
                // SAFETY: as above.
                let fmt = unsafe { ffi::kpcn_input_channel_format(self.raw, s as i32, c as i32) };
                (name, SampleFormat::from_code(fmt))
            })
            .collect())
    }

    /// Metadata of subimage `s`.
    pub fn attributes(&self, s: usize) -> Result<Vec<Attribute>, String> {
        self.info(s)?;
        // SAFETY: `s` validated.
        let n = unsafe { ffi::kpcn_input_attribute_count(self.raw, s as i32) };
        let mut out = Vec::with_capacity(n.max(0) as usize);
        for i in 0..n {
            let mut a = ffi::kpcn_attribute {
                name: std::ptr::null(),
                type_: std::ptr::null(),
                data: std::ptr::null(),
                size: 0,
                text: std::ptr::null(),
                is_string: 0,
            };
            // SAFETY: indices in range; the shim fills `a` with pointers owned by the handle.
            check(unsafe { ffi::kpcn_input_attribute(self.raw, s as i32, i, &mut a) })?;
            let raw = if a.is_string != 0 || a.data.is_null() {
                None
            } else {
                // SAFETY: `data` points at `size` bytes owned by the handle.
                Some(unsafe { std::slice::from_raw_parts(a.data as *const u8, a.size) }.to_vec())
            };
            // String arrays carry neither raw bytes nor a single string: report, don't copy.
            if a.is_string == 0 && raw.is_none() {
                continue;
            }
            out.push(Attribute { name: cstr(a.name), type_name: cstr(a.type_), text: cstr(a.text), raw });
        }
        Ok(out)
    }

    /// Reads rows `[y0, y1)` (absolute) of channels `[c0, c1)` interleaved into `buf`.
    /// A uint channel's samples are its bits (`f32::from_bits`), so that writing them back
    /// keeps every id exactly; converted, 2654435761 would become 0.618.
    pub fn read_rows(
        &mut self,
        s: usize,
        y0: i32,
        y1: i32,
        c0: usize,
        c1: usize,
        buf: &mut [f32],
    ) -> Result<(), String> {
        let info = self.info(s)?;
        let need = (y1 - y0).max(0) as usize * info.width * (c1 - c0);
        if buf.len() < need || c1 > info.nchannels || c0 >= c1 {
            return Err(format!("read of {need} samples into a buffer of {}", buf.len()));
        }
        // SAFETY: bounds checked above; the shim writes exactly `need` floats.
        check(unsafe { ffi::kpcn_input_read_rows(self.raw, s as i32, y0, y1, c0 as i32, c1 as i32, buf.as_mut_ptr()) })
    }
}

impl Drop for Input {
    fn drop(&mut self) {
        // SAFETY: the handle was created by kpcn_input_open and is freed once.
        unsafe { ffi::kpcn_input_close(self.raw) }
    }
}

/// What an EXR writer needs up front, per part.
pub struct OutputSpec<'a> {
    /// EXR part name (empty for none).
    pub part_name: &'a str,
    /// Geometry (data and display windows), taken from the frame.
    pub info: SubimageInfo,
    /// Channel names and formats in file order.
    pub channels: Vec<(&'a str, SampleFormat)>,
    /// EXR compression name.
    pub compression: &'a str,
    /// Metadata to write.
    pub attributes: &'a [Attribute],
}

fn c_string(s: &str, what: &str) -> Result<CString, String> {
    CString::new(s).map_err(|_| format!("{what} `{s}` contains a NUL byte"))
}

/// The C strings and arrays behind one `kpcn_output_spec`, kept alive while it is used.
struct SpecStorage {
    part_name: CString,
    names: Vec<CString>,
    name_ptrs: Vec<*const c_char>,
    formats: Vec<i32>,
    compression: CString,
    attr_strings: Vec<[CString; 3]>,
    attrs: Vec<ffi::kpcn_attribute>,
}

impl SpecStorage {
    fn new(spec: &OutputSpec) -> Result<Self, String> {
        let names: Vec<CString> =
            spec.channels.iter().map(|(n, _)| c_string(n, "channel name")).collect::<Result<_, _>>()?;
        let attr_strings: Vec<[CString; 3]> = spec
            .attributes
            .iter()
            .map(|a| {
                Ok([
                    c_string(&a.name, "attribute name")?,
                    c_string(&a.type_name, "attribute type")?,
                    c_string(&a.text, "attribute value")?,
                ])
            })
            .collect::<Result<_, String>>()?;
        let mut s = SpecStorage {
            part_name: c_string(spec.part_name, "part name")?,
            name_ptrs: names.iter().map(|n| n.as_ptr()).collect(),
            names,
            formats: spec.channels.iter().map(|(_, f)| f.exr_code()).collect(),
            compression: c_string(spec.compression, "compression")?,
            attr_strings,
            attrs: Vec::new(),
        };
        s.attrs = spec
            .attributes
            .iter()
            .zip(&s.attr_strings)
            .map(|(a, [n, t, x])| ffi::kpcn_attribute {
                name: n.as_ptr(),
                type_: t.as_ptr(),
                data: a.raw.as_ref().map_or(std::ptr::null(), |r| r.as_ptr().cast()),
                size: a.raw.as_ref().map_or(0, |r| r.len()),
                text: x.as_ptr(),
                is_string: a.raw.is_none() as i32,
            })
            .collect();
        Ok(s)
    }

    fn c_spec(&self, info: &SubimageInfo) -> ffi::kpcn_output_spec {
        ffi::kpcn_output_spec {
            part_name: self.part_name.as_ptr(),
            x: info.x,
            y: info.y,
            width: info.width as i32,
            height: info.height as i32,
            full_x: info.full_x,
            full_y: info.full_y,
            full_width: info.full_width as i32,
            full_height: info.full_height as i32,
            nchannels: self.names.len() as i32,
            channel_names: self.name_ptrs.as_ptr(),
            channel_formats: self.formats.as_ptr(),
            compression: self.compression.as_ptr(),
            attributes: self.attrs.as_ptr(),
            nattributes: self.attrs.len() as i32,
        }
    }
}

/// An EXR being written part by part, row band by row band.
pub struct Output {
    raw: *mut ffi::kpcn_output,
}

// SAFETY: the handle is owned exclusively; OIIO's ImageOutput may be used from any
// thread as long as calls are not concurrent, which `&mut self` on writes ensures.
unsafe impl Send for Output {}

impl Output {
    /// Creates the file with one part per spec and starts the first part. `encoders` > 1
    /// compresses on that many threads of OpenEXR's pool, which is process-wide (see
    /// [`WriteOptions::encoders`](super::WriteOptions::encoders)).
    pub fn create(path: &Path, specs: &[OutputSpec], encoders: usize) -> Result<Self, String> {
        let c = path_cstring(path)?;
        let storage: Vec<SpecStorage> = specs.iter().map(SpecStorage::new).collect::<Result<_, _>>()?;
        let c_specs: Vec<ffi::kpcn_output_spec> =
            storage.iter().zip(specs).map(|(s, spec)| s.c_spec(&spec.info)).collect();
        let mut raw = std::ptr::null_mut();
        let encoders = encoders.min(64) as i32;
        // SAFETY: every pointer in `c_specs` points into `storage`, alive for the call;
        // the shim copies what it keeps.
        check(unsafe {
            ffi::kpcn_output_open(c.as_ptr(), c_specs.as_ptr(), c_specs.len() as i32, encoders, &mut raw)
        })?;
        Ok(Self { raw })
    }

    /// Finishes the current part and starts the next.
    pub fn next_part(&mut self) -> Result<(), String> {
        // SAFETY: open handle.
        check(unsafe { ffi::kpcn_output_next_part(self.raw) })
    }

    /// Writes rows `[y0, y1)`; `data` holds all channels interleaved.
    pub fn write_rows(&mut self, y0: i32, y1: i32, data: &[f32]) -> Result<(), String> {
        // SAFETY: the caller sized `data` from the spec; the shim reads that many floats.
        check(unsafe { ffi::kpcn_output_write_rows(self.raw, y0, y1, data.as_ptr()) })
    }

    /// Flushes and closes the file.
    pub fn close(mut self) -> Result<(), String> {
        let raw = std::mem::replace(&mut self.raw, std::ptr::null_mut());
        // SAFETY: closes and frees the handle exactly once.
        check(unsafe { ffi::kpcn_output_close(raw) })
    }
}

impl Drop for Output {
    fn drop(&mut self) {
        if !self.raw.is_null() {
            // SAFETY: not yet closed.
            unsafe { ffi::kpcn_output_close(self.raw) };
        }
    }
}
