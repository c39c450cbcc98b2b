//! The C ABI: `include/kpcn.h` (generated from this module by cbindgen), in the shape users of
//! Intel Open Image Denoise know. A thin shell over [`crate::denoise::Denoiser`]:
//!
//! ```c
//! KpcnDenoiser* d = NULL;
//! if (kpcn_denoiser_new(NULL, &d) != KPCN_OK) { fprintf(stderr, "%s\n", kpcn_last_error()); return 1; }
//! kpcn_set_image(d, "color", color, KPCN_FORMAT_FLOAT3, w, h, 0, 0);  /* … diffuse, albedo, normal, depth */
//! kpcn_set_image(d, "output", out, KPCN_FORMAT_FLOAT3, w, h, 0, 0);
//! KpcnStatus s = kpcn_execute(d);
//! kpcn_denoiser_free(d);
//! ```
//!
//! Every export catches panics, checks its handle against the live ones (so a freed or
//! forged handle is an error, not a crash) and reads C enums as integers. Calls on one
//! denoiser are serialised; different denoisers run in parallel, each in its own pool.
#![deny(missing_docs)]

mod image;
mod status;

pub use image::KpcnFormat;
pub use status::{KpcnStatus, kpcn_last_error, kpcn_status_string};

use crate::denoise::{Bands, Component, Denoisers, FileJob, FileOptions, Options, Progress};
use crate::io::layout::{KpcnInputs, Layout};
use crate::io::{NamedImages, WriteOptions};
use crate::model::{Model, registry};
use image::HostImage;
use status::{Failure, guard};
use std::cell::Cell;
use std::collections::HashMap;
use std::ffi::{CStr, c_char, c_void};
use std::path::Path;
use std::sync::{Arc, Mutex, PoisonError};

/// Called between tiles on the thread that called [`kpcn_execute`] or
/// [`kpcn_denoise_file`], with the fraction done (0 to 1). Return `false` to cancel. It must
/// not call kpcn functions on the same denoiser.
pub type KpcnProgressFn = Option<unsafe extern "C" fn(user: *mut c_void, progress: f64) -> bool>;

/// Called when a call on a denoiser fails, on the failing thread, with the status and
/// message (valid during the callback only).
pub type KpcnErrorFn = Option<unsafe extern "C" fn(user: *mut c_void, status: KpcnStatus, message: *const c_char)>;

/// How to create a denoiser. Fill it with [`kpcn_options_init`] first, then change fields.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct KpcnOptions {
    /// `sizeof(KpcnOptions)`, set by [`kpcn_options_init`]: the version of this struct.
    pub struct_size: usize,
    /// Worker threads of this denoiser's own pool; 0 = one per core.
    pub threads: u32,
    /// Working-memory budget in MB, as `kpcn denoise --max-memory`: `kpcn_execute` reads the
    /// host's images in bands of rows within it (and holds 12 bytes per pixel and output
    /// until the end); 0 = the default (512).
    pub max_memory_mb: u32,
    /// A model by name, or NULL for `"default"`: `"auto"`, which picks per frame as
    /// `kpcn denoise` does (the default model when the frame has a colour variance, a
    /// `colorVariance` image or in a file per-pixel variances or half buffers; `"spatial"`
    /// when it has none), or a shipped model's name (`kpcn denoise --help` lists them;
    /// `"default"` is `"balanced"`).
    pub model_name: *const c_char,
    /// A model file (`.safetensors` written by `kpcn train`), or NULL.
    pub model_path: *const c_char,
    /// A model file's bytes already in memory (copied), or NULL.
    pub model_data: *const u8,
    /// Bytes at `model_data`.
    pub model_size: usize,
    /// Accept an untrained model (an architecture preset such as `"small"`), which gives
    /// useless images; for testing only.
    pub allow_untrained: bool,
}

/// Channel naming convention of an input file.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(clippy::enum_variant_names)] // the C names (KPCN_LAYOUT_AUTO, …) come from these
pub enum KpcnLayout {
    /// Detected from the channel names.
    KpcnLayoutAuto = 0,
    /// kpcn's own (ARCHITECTURE.md §Layout).
    KpcnLayoutNative = 1,
    /// Blender Cycles passes.
    KpcnLayoutCycles = 2,
    /// RenderMan denoise AOVs.
    KpcnLayoutRenderman = 3,
}

/// What [`kpcn_denoise_file`] writes. Fill it with [`kpcn_file_options_init`] first.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct KpcnFileOptions {
    /// `sizeof(KpcnFileOptions)`, set by [`kpcn_file_options_init`].
    pub struct_size: usize,
    /// Name of the denoised layer (`NAME.R/G/B`); NULL = `"denoised"`.
    pub layer: *const c_char,
    /// Also write `NAME_diffuse` and `NAME_specular`, which add up to `NAME`.
    pub aovs: bool,
    /// Write only the new layers, not a copy of the input's channels.
    pub separate: bool,
    /// Refuse to replace an existing output.
    pub no_clobber: bool,
    /// A [`KpcnLayout`] value.
    pub layout: i32,
    /// Allow `output` to be `input` itself (the same file, links followed): the denoised
    /// layer is added to the render atomically. Without it such an output is refused with
    /// `KPCN_ERROR_INVALID_ARGUMENT`; it cannot be combined with `separate`.
    pub in_place: bool,
}

/// A denoiser: a model, its thread pool, and the images set on it. Opaque to C.
pub struct KpcnDenoiser {
    state: Mutex<State>,
}

struct State {
    /// The named model, or `"auto"`'s two.
    denoisers: Denoisers,
    inputs: Vec<(String, HostImage)>,
    outputs: Vec<(String, HostImage)>,
    progress: (KpcnProgressFn, *mut c_void),
    error: (KpcnErrorFn, *mut c_void),
}

// SAFETY: the host's pointers (images, callback data) are its to keep valid; kpcn.h says so.
unsafe impl Send for State {}

/// Output image names and which part of the result each receives.
const OUTPUTS: [(&str, Component); 3] =
    [("output", Component::Color), ("outputDiffuse", Component::Diffuse), ("outputSpecular", Component::Specular)];

/// Whether `name` is an output image's.
fn is_output(name: &str) -> bool {
    OUTPUTS.iter().any(|(n, _)| *n == name)
}

/// The output image names, for messages.
fn output_names() -> String {
    OUTPUTS.map(|(n, _)| n).join(", ")
}

/// Live handles by address: a freed, forged or doubly freed handle is found missing here.
static LIVE: Mutex<Option<HashMap<usize, Arc<KpcnDenoiser>>>> = Mutex::new(None);

thread_local! {
    /// The handle a call on this thread is running on, so a callback calling back into it
    /// gets an error instead of a deadlock.
    static RUNNING: Cell<usize> = const { Cell::new(0) };
}

/// Clears [`RUNNING`] when a call ends, panicking or not.
struct Running;

impl Drop for Running {
    fn drop(&mut self) {
        RUNNING.with(|r| r.set(0));
    }
}

fn live() -> std::sync::MutexGuard<'static, Option<HashMap<usize, Arc<KpcnDenoiser>>>> {
    LIVE.lock().unwrap_or_else(PoisonError::into_inner)
}

fn lookup(d: *const KpcnDenoiser) -> Result<Arc<KpcnDenoiser>, Failure> {
    if d.is_null() {
        return Err(Failure::invalid("the denoiser is NULL"));
    }
    live()
        .as_ref()
        .and_then(|m| m.get(&(d as usize)).cloned())
        .ok_or_else(|| Failure::state(format!("{d:p} is not a live denoiser (freed, or never created)")))
}

/// Runs `body` on denoiser `d`'s state and reports a failure to its error callback.
fn on(d: *const KpcnDenoiser, body: impl FnOnce(&mut State) -> Result<(), Failure>) -> KpcnStatus {
    let mut callback: (KpcnErrorFn, *mut c_void) = (None, std::ptr::null_mut());
    let status = guard(|| {
        let handle = lookup(d)?;
        if RUNNING.with(Cell::get) == d as usize {
            return Err(Failure::state("called from inside this denoiser's own callback"));
        }
        let mut state = handle.state.lock().unwrap_or_else(PoisonError::into_inner);
        callback = state.error;
        RUNNING.with(|r| r.set(d as usize));
        let _running = Running;
        body(&mut state)
    });
    if let (Some(f), user) = callback
        && status != KpcnStatus::KpcnOk
    {
        // SAFETY: the host registered `f` for exactly this.
        unsafe { f(user, status, kpcn_last_error()) };
    }
    status
}

/// A C string argument, or an error naming it.
fn text<'a>(p: *const c_char, what: &str) -> Result<&'a str, Failure> {
    if p.is_null() {
        return Err(Failure::invalid(format!("{what} is NULL")));
    }
    // SAFETY: the host passes a NUL-terminated string (kpcn.h).
    unsafe { CStr::from_ptr(p) }.to_str().map_err(|_| Failure::invalid(format!("{what} is not UTF-8")))
}

fn optional_text<'a>(p: *const c_char, what: &str) -> Result<Option<&'a str>, Failure> {
    if p.is_null() { Ok(None) } else { text(p, what).map(Some) }
}

fn check_size(struct_size: usize, expected: usize, what: &str) -> Result<(), Failure> {
    if struct_size != expected {
        return Err(Failure::new(
            KpcnStatus::KpcnErrorUnsupportedVersion,
            format!(
                "{what}.struct_size is {struct_size}, this library's is {expected}: fill it with its _init function"
            ),
        ));
    }
    Ok(())
}

/// Fills `options` with the defaults: the embedded model, every core, 512 MB.
///
/// # Safety
/// `options` is NULL or points to writable storage for a `KpcnOptions`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_options_init(options: *mut KpcnOptions) -> KpcnStatus {
    // SAFETY: the caller's promise above.
    guard(|| unsafe { write_defaults(options, "options") })
}

impl Default for KpcnOptions {
    fn default() -> Self {
        KpcnOptions {
            struct_size: size_of::<KpcnOptions>(),
            threads: 0,
            max_memory_mb: 0,
            model_name: std::ptr::null(),
            model_path: std::ptr::null(),
            model_data: std::ptr::null(),
            model_size: 0,
            allow_untrained: false,
        }
    }
}

impl Default for KpcnFileOptions {
    fn default() -> Self {
        KpcnFileOptions {
            struct_size: size_of::<KpcnFileOptions>(),
            layer: std::ptr::null(),
            aovs: false,
            separate: false,
            no_clobber: false,
            layout: KpcnLayout::KpcnLayoutAuto as i32,
            in_place: false,
        }
    }
}

/// Fills the host's options struct at `p` with the defaults.
///
/// # Safety
/// `p` is NULL or writable storage for a `T`.
unsafe fn write_defaults<T: Default>(p: *mut T, what: &str) -> Result<(), Failure> {
    if p.is_null() {
        return Err(Failure::invalid(format!("{what} is NULL")));
    }
    // SAFETY: non-NULL, and the host's storage for a T.
    unsafe { p.write(T::default()) };
    Ok(())
}

/// The host's options struct at `p` (the defaults when NULL), once its `struct_size` (the
/// first field of every options struct) says it is this library's version.
///
/// # Safety
/// `p` is NULL or points to a struct whose first field is its `struct_size`.
unsafe fn read_options<T: Default>(p: *const T, what: &str) -> Result<T, Failure> {
    if p.is_null() {
        return Ok(T::default());
    }
    // SAFETY: the size first (readable whatever the version), then the whole struct.
    let size = unsafe { (p as *const usize).read_unaligned() };
    check_size(size, size_of::<T>(), what)?;
    // SAFETY: the host's struct is at least `size_of::<T>()` bytes (checked above).
    Ok(unsafe { p.read_unaligned() })
}

/// The model the options name; `None` for `"auto"`, which loads its own two.
fn load_model(o: &KpcnOptions) -> Result<Option<Model>, Failure> {
    let name = optional_text(o.model_name, "options.model_name")?;
    let path = optional_text(o.model_path, "options.model_path")?;
    let data = !o.model_data.is_null();
    if [name.is_some(), path.is_some(), data].iter().filter(|&&b| b).count() > 1 {
        return Err(Failure::invalid("set at most one of model_name, model_path and model_data"));
    }
    let model = if data {
        // SAFETY: the host says `model_size` bytes live at `model_data`.
        let bytes = unsafe { std::slice::from_raw_parts(o.model_data, o.model_size) };
        Model::from_bytes(bytes, "options.model_data")?
    } else if let Some(p) = path {
        Model::load(Path::new(p))?
    } else if name == Some(registry::AUTO) {
        return Ok(None);
    } else {
        Model::resolve(name.unwrap_or(registry::DEFAULT))?
    };
    if model.is_untrained() && !o.allow_untrained {
        return Err(Failure::invalid(format!(
            "model `{}` is an untrained preset and gives useless images; set allow_untrained to use it anyway",
            name.unwrap_or("?")
        )));
    }
    Ok(Some(model))
}

/// Creates a denoiser (`options` NULL = the defaults) into `*out`; `*out` is NULL on failure.
///
/// # Safety
/// `options` is NULL or a `KpcnOptions` filled by `kpcn_options_init` (its strings NUL-terminated, `model_data` holding `model_size` bytes); `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_denoiser_new(options: *const KpcnOptions, out: *mut *mut KpcnDenoiser) -> KpcnStatus {
    guard(|| {
        if out.is_null() {
            return Err(Failure::invalid("out is NULL"));
        }
        // SAFETY: non-NULL.
        unsafe { out.write(std::ptr::null_mut()) };
        // SAFETY: the caller's promise above.
        let o = unsafe { read_options(options, "options") }?;
        let model = load_model(&o)?;
        let opts = Options {
            threads: (o.threads > 0).then_some(o.threads as usize),
            max_memory_mb: if o.max_memory_mb == 0 {
                Options::default().max_memory_mb
            } else {
                o.max_memory_mb as usize
            },
            tile_size: None,
        };
        let denoisers = match model {
            Some(m) => Denoisers::one(m, opts)?,
            None => Denoisers::auto(opts)?,
        };
        let state = State {
            denoisers,
            inputs: Vec::new(),
            outputs: Vec::new(),
            progress: (None, std::ptr::null_mut()),
            error: (None, std::ptr::null_mut()),
        };
        let handle = Arc::new(KpcnDenoiser { state: Mutex::new(state) });
        let ptr = Arc::as_ptr(&handle) as *mut KpcnDenoiser;
        live().get_or_insert_with(HashMap::new).insert(ptr as usize, handle);
        // SAFETY: non-NULL (checked above).
        unsafe { out.write(ptr) };
        Ok(())
    })
}

/// Frees a denoiser. NULL is ignored (`KPCN_OK`); a handle that is not live (freed twice,
/// never created) gives `KPCN_ERROR_INVALID_STATE` and is not touched.
///
/// # Safety
/// `d` may be anything: handles that are not live are refused, not touched.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_denoiser_free(d: *mut KpcnDenoiser) -> KpcnStatus {
    guard(|| {
        if d.is_null() {
            return Ok(());
        }
        if RUNNING.with(Cell::get) == d as usize {
            return Err(Failure::state("cannot free a denoiser from inside its own callback"));
        }
        let handle = live().as_mut().and_then(|m| m.remove(&(d as usize)));
        match handle {
            // A call on another thread may still hold it; the last holder frees it.
            Some(h) => {
                drop(h);
                Ok(())
            }
            None => Err(Failure::state(format!("{d:p} is not a live denoiser (freed twice, or never created)"))),
        }
    })
}

/// Sets (or replaces) the image called `name`. Inputs: `color`, `diffuse`, `specular`,
/// `albedo`, `normal` (3 channels), `depth` (1) and their variances `colorVariance`, …,
/// `depthVariance` (1 or 3, averaged). Outputs (3 channels): `output` (the beauty),
/// `outputDiffuse` and `outputSpecular`, which add up to it. Sample `c` of pixel `(x, y)` is
/// at `ptr + y * row_stride + x * pixel_stride + c * sample_size` bytes; strides of 0 mean
/// packed, negative ones run backwards (bottom-up rows). The memory is read (inputs) or
/// written (outputs) by [`kpcn_execute`] and must stay valid until then.
///
/// # Safety
/// `name` is NULL or NUL-terminated. `ptr` addresses every sample the size, format and strides describe, and stays valid (and, for an output, unshared) until `kpcn_execute` returns.
#[unsafe(no_mangle)]
#[allow(clippy::too_many_arguments)] // the shape of oidnSetSharedFilterImage
pub unsafe extern "C" fn kpcn_set_image(
    d: *mut KpcnDenoiser,
    name: *const c_char,
    ptr: *mut c_void,
    format: i32,
    width: usize,
    height: usize,
    pixel_byte_stride: isize,
    row_byte_stride: isize,
) -> KpcnStatus {
    on(d, |s| {
        let name = text(name, "name")?;
        let image = HostImage::new(name, ptr as *mut u8, format, width, height, pixel_byte_stride, row_byte_stride)?;
        let needs = if is_output(name) {
            3
        } else {
            let allowed = NamedImages::channels_of(name).ok_or_else(|| {
                Failure::invalid(format!(
                    "unknown image `{name}`: inputs are {}; outputs are {}",
                    crate::io::IMAGE_NAMES.join(", "),
                    output_names()
                ))
            })?;
            allowed[0]
        };
        if image.channels() < needs {
            return Err(Failure::invalid(format!("image `{name}` needs {needs} channels, its format has 1")));
        }
        let list = if is_output(name) { &mut s.outputs } else { &mut s.inputs };
        list.retain(|(n, _)| n != name);
        list.push((name.to_string(), image));
        Ok(())
    })
}

/// Forgets the image called `name` (an error if it was not set).
///
/// # Safety
/// `name` is NULL or NUL-terminated.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_unset_image(d: *mut KpcnDenoiser, name: *const c_char) -> KpcnStatus {
    on(d, |s| {
        let name = text(name, "name")?;
        let before = s.inputs.len() + s.outputs.len();
        s.inputs.retain(|(n, _)| n != name);
        s.outputs.retain(|(n, _)| n != name);
        if s.inputs.len() + s.outputs.len() == before {
            return Err(Failure::invalid(format!("image `{name}` is not set")));
        }
        Ok(())
    })
}

/// Sets the progress callback (NULL removes it); `user` is passed back to it.
///
/// # Safety
/// `f` stays callable with `user` while it is set.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_set_progress_callback(
    d: *mut KpcnDenoiser,
    f: KpcnProgressFn,
    user: *mut c_void,
) -> KpcnStatus {
    on(d, |s| {
        s.progress = (f, user);
        Ok(())
    })
}

/// Sets the error callback (NULL removes it); `user` is passed back to it.
///
/// # Safety
/// `f` stays callable with `user` while it is set.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_set_error_callback(
    d: *mut KpcnDenoiser,
    f: KpcnErrorFn,
    user: *mut c_void,
) -> KpcnStatus {
    on(d, |s| {
        s.error = (f, user);
        Ok(())
    })
}

impl State {
    /// The progress callback as a closure; `true` (go on) without one.
    fn progress(&self) -> impl Fn(Progress) -> bool + '_ {
        move |p: Progress| match self.progress {
            // SAFETY: the host registered `f` for exactly this.
            (Some(f), user) => unsafe { f(user, p.done as f64 / p.total.max(1) as f64) },
            (None, _) => true,
        }
    }

    fn execute(&mut self) -> Result<(), Failure> {
        let Some((_, first)) = self.inputs.first() else {
            return Err(Failure::state("no input images are set"));
        };
        if self.outputs.is_empty() {
            return Err(Failure::state(format!("no output image is set (set one of {})", output_names())));
        }
        let (w, h) = (first.width, first.height);
        if let Some((n, i)) = self.inputs.iter().chain(&self.outputs).find(|(_, i)| (i.width, i.height) != (w, h)) {
            return Err(Failure::state(format!(
                "image `{n}` is {}x{} but `{}` is {w}x{h}: every image of a frame has one size",
                i.width, i.height, self.inputs[0].0
            )));
        }
        let (denoiser, _) = self.denoisers.pick(self.inputs.iter().any(|(n, _)| n == "colorVariance"));
        // Streamed in bands, as files are: the host's images are copied a band at a time
        // (with its context rows), never whole. The results are held until the end so that
        // a failure or cancel leaves the outputs untouched: 3 floats per pixel and output.
        let bands = Bands::new(denoiser, w, h, None);
        let copied: usize = self.inputs.iter().map(|(_, i)| i.channels()).sum();
        bands.reserve(denoiser, copied, self.outputs.len() * 3 * w * h * 4)?;
        let component = |name: &str| OUTPUTS.iter().find(|(n, _)| *n == name).map_or(Component::Color, |o| o.1);
        let mut results: Vec<[Vec<f32>; 3]> =
            self.outputs.iter().map(|_| std::array::from_fn(|_| vec![0f32; w * h])).collect();
        let inputs = &self.inputs;
        let mut read = |rows: std::ops::Range<usize>| -> Result<KpcnInputs, Failure> {
            let mut images = NamedImages::new(w, rows.len());
            for (name, image) in inputs {
                // A variance may come as 1 channel or 3 (averaged); the means take what they need.
                let wanted = NamedImages::channels_of(name)
                    .map_or(1, |c| *c.iter().rev().find(|&&k| k <= image.channels()).unwrap_or(&c[0]));
                images.insert(name, image.read_rows(wanted, rows.clone()))?;
            }
            Ok(images.inputs()?)
        };
        let outputs = &self.outputs;
        let mut write = |rows: std::ops::Range<usize>, d: crate::denoise::Denoised| -> Result<(), Failure> {
            for ((name, _), result) in outputs.iter().zip(&mut results) {
                for (r, p) in result.iter_mut().zip(d.component(component(name))) {
                    r[rows.start * w..rows.end * w].copy_from_slice(p);
                }
            }
            Ok(())
        };
        denoiser.denoise_streamed(&bands, &mut read, &mut write, &self.progress())?;
        for ((_, image), result) in self.outputs.iter().zip(&results) {
            image.write(result);
        }
        Ok(())
    }
}

/// Denoises the images set on `d` into its output images. On failure or cancel, the output
/// images are untouched.
///
/// # Safety
/// The images set on `d` are still valid (see `kpcn_set_image`).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_execute(d: *mut KpcnDenoiser) -> KpcnStatus {
    on(d, State::execute)
}

/// Fills `options` with the defaults: layer `denoised`, layout detected, a copy of every
/// input channel, replace an existing output.
///
/// # Safety
/// `options` is NULL or points to writable storage for a `KpcnFileOptions`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_file_options_init(options: *mut KpcnFileOptions) -> KpcnStatus {
    // SAFETY: the caller's promise above.
    guard(|| unsafe { write_defaults(options, "options") })
}

/// Denoises the layered EXR `input` into `output` (`options` NULL = the defaults), as
/// `kpcn denoise` does: in bands of rows, atomically (nothing appears at `output` on failure
/// or cancel). Images set on `d` are not used.
///
/// # Safety
/// `input` and `output` are NULL or NUL-terminated; `options` is NULL or a `KpcnFileOptions` filled by `kpcn_file_options_init`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn kpcn_denoise_file(
    d: *mut KpcnDenoiser,
    input: *const c_char,
    output: *const c_char,
    options: *const KpcnFileOptions,
) -> KpcnStatus {
    on(d, |s| {
        let (input, output) = (text(input, "input")?, text(output, "output")?);
        // SAFETY: the caller's promise above.
        let o = unsafe { read_options(options, "options") }?;
        let layout = match o.layout {
            0 => None,
            1 => Some(Layout::Native),
            2 => Some(Layout::Cycles),
            3 => Some(Layout::RenderMan),
            v => return Err(Failure::invalid(format!("options.layout: unknown layout {v}"))),
        };
        let opts = FileOptions {
            layer: optional_text(o.layer, "options.layer")?.unwrap_or("denoised").to_string(),
            aovs: o.aovs,
            separate: o.separate,
            in_place: o.in_place,
            write: WriteOptions { no_clobber: o.no_clobber, ..WriteOptions::default() },
            band_rows: None,
        };
        let job = FileJob::open(Path::new(input), layout)?;
        let (denoiser, _) = s.denoisers.pick(job.mapping().colour_variance_in_file());
        job.run(denoiser, Path::new(output), &opts, &s.progress())?;
        Ok(())
    })
}

/// The loaded library's version as `major * 10000 + minor * 100 + patch`.
#[unsafe(no_mangle)]
pub extern "C" fn kpcn_version() -> u32 {
    let part = |s: &str| s.parse::<u32>().unwrap_or(0);
    part(env!("CARGO_PKG_VERSION_MAJOR")) * 10000
        + part(env!("CARGO_PKG_VERSION_MINOR")) * 100
        + part(env!("CARGO_PKG_VERSION_PATCH"))
}

/// The loaded library's version, e.g. `"0.1.0"`. Never NULL.
#[unsafe(no_mangle)]
pub extern "C" fn kpcn_version_string() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr() as *const c_char
}
