//! `kpcn._kpcn`: the native part of the `kpcn` Python module, a thin shell over the
//! library core as the C ABI is. Arrays go in as numpy views (any strides, float32 or
//! float16) and are read once into the library's planes; the denoise runs with the GIL
//! released, on a worker thread, while the calling thread watches for Ctrl-C and calls the
//! progress callback. `python/kpcn/__init__.py` holds the exception classes raised here.

use kpcn::denoise::{
    Bands, DenoiseError, Denoised, Denoisers, FileError, FileRequest, Options, Outcome, Progress, ViewLayers,
};
use kpcn::io::layout::{KpcnInputs, Layout};
use kpcn::io::{IoError, NamedImages, WriteOptions};
use kpcn::model::ModelError;
use numpy::ndarray::ArrayViewD;
use numpy::{IntoPyArray, PyArray3, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyUserWarning;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyType};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// The Python classes of `kpcn`'s errors (`Error`, `InputError`, `IoError`), defined in
/// `kpcn/__init__.py` so that they also derive from `ValueError` and `OSError`.
fn raise(py: Python<'_>, class: &str, message: String) -> PyErr {
    let class = py.import("kpcn").and_then(|m| m.getattr(class)).and_then(|c| Ok(c.cast_into::<PyType>()?));
    match class {
        Ok(c) => PyErr::from_type(c, message),
        Err(e) => e,
    }
}

/// The class of an I/O-layer error: the user's input (a file or an array) is wrong, or the
/// file system failed.
fn io_class(e: &IoError) -> &'static str {
    match e {
        IoError::Open { .. }
        | IoError::Empty { .. }
        | IoError::Read { .. }
        | IoError::Write { .. }
        | IoError::Exists { .. }
        | IoError::Fs { .. } => "IoError",
        IoError::OutOfMemory { .. } => "Error",
        _ => "InputError",
    }
}

fn denoise_class(e: &DenoiseError) -> &'static str {
    match e {
        DenoiseError::Model(ModelError::Io { .. }) => "IoError",
        DenoiseError::Model(ModelError::Format { .. } | ModelError::UnknownPreset(_)) | DenoiseError::Empty => {
            "InputError"
        }
        _ => "Error",
    }
}

fn denoise_err(py: Python<'_>, e: DenoiseError) -> PyErr {
    raise(py, denoise_class(&e), e.to_string())
}

fn io_err(py: Python<'_>, e: IoError) -> PyErr {
    raise(py, io_class(&e), e.to_string())
}

fn file_err(py: Python<'_>, e: FileError) -> PyErr {
    let class = match &e {
        FileError::Io(io) => io_class(io),
        FileError::Refused { .. } => "InputError",
        FileError::Denoise { cause, .. } => denoise_class(cause),
    };
    raise(py, class, e.to_string())
}

/// Runs `work` on a worker thread with the GIL released. Meanwhile the calling thread
/// checks for signals (Ctrl-C raises `KeyboardInterrupt` once the current tile is done)
/// and calls `progress(fraction)`; a `False` from it cancels (the work then fails with its
/// own "cancelled"), an exception from it or a signal's is raised once the work stopped.
fn run_detached<T: Send>(
    py: Python<'_>,
    progress: Option<&Bound<'_, PyAny>>,
    work: impl FnOnce(&(dyn Fn(Progress) -> bool + Sync)) -> T + Send,
) -> PyResult<T> {
    let cancel = AtomicBool::new(false);
    // The latest fraction done, as f64 bits; NaN while none is reported.
    let fraction = AtomicU64::new(f64::NAN.to_bits());
    let caller = std::thread::current();
    let (result, pending) = std::thread::scope(|s| {
        let worker = s.spawn(|| {
            let step = |p: Progress| {
                fraction.store((p.done as f64 / p.total.max(1) as f64).to_bits(), Ordering::Relaxed);
                !cancel.load(Ordering::Relaxed)
            };
            let out = work(&step);
            caller.unpark();
            out
        });
        let mut pending: Option<PyErr> = None;
        let mut reported = f64::NAN;
        loop {
            let finished = py.detach(|| {
                if !worker.is_finished() {
                    std::thread::park_timeout(std::time::Duration::from_millis(50));
                }
                worker.is_finished()
            });
            if let (None, Err(e)) = (&pending, py.check_signals()) {
                pending = Some(e);
            }
            let f = f64::from_bits(fraction.load(Ordering::Relaxed));
            if let (Some(callback), None, false) = (progress, &pending, f.is_nan() || f == reported) {
                reported = f;
                match callback.call1((f,)) {
                    // The work stops at its next tile and reports it (a `False` after the
                    // last tile changes nothing).
                    Ok(v) if v.is(&*pyo3::types::PyBool::new(py, false)) => cancel.store(true, Ordering::Relaxed),
                    Ok(_) => {}
                    Err(e) => pending = Some(e),
                }
            }
            if pending.is_some() {
                cancel.store(true, Ordering::Relaxed);
            }
            if finished {
                break;
            }
        }
        (worker.join(), pending)
    });
    if let Some(e) = pending {
        return Err(e);
    }
    result.map_err(|_| raise(py, "Error", "kpcn panicked (a bug): please report it with the input".into()))
}

/// Where a host image's samples lie, for the worker thread to read band by band.
#[derive(Clone, Copy)]
struct Samples {
    /// Sample (0, 0, 0).
    ptr: *const u8,
    /// Bytes between rows, pixels and channels (any sign).
    strides: [isize; 3],
    half: bool,
    width: usize,
    /// Channels to read (the first ones).
    channels: usize,
}

// SAFETY: read-only, and the calling thread keeps the array alive and borrowed (a numpy
// read-only borrow) until the worker thread that reads it has finished.
unsafe impl Send for Samples {}
// SAFETY: as above; reads only.
unsafe impl Sync for Samples {}

impl Samples {
    /// Rows `rows` as packed planes.
    fn rows(&self, rows: std::ops::Range<usize>) -> Vec<Vec<f32>> {
        (0..self.channels)
            .map(|c| {
                let mut plane = Vec::with_capacity(self.width * rows.len());
                for y in rows.clone() {
                    for x in 0..self.width {
                        let at =
                            y as isize * self.strides[0] + x as isize * self.strides[1] + c as isize * self.strides[2];
                        // SAFETY: (y, x, c) is inside the array's shape, which with its strides
                        // numpy vouches for; unaligned reads, as views may be.
                        let p = unsafe { self.ptr.offset(at) };
                        // SAFETY: as above.
                        plane.push(unsafe {
                            if self.half {
                                half::f16::from_bits(std::ptr::read_unaligned(p as *const u16)).to_f32()
                            } else {
                                std::ptr::read_unaligned(p as *const f32)
                            }
                        });
                    }
                }
                plane
            })
            .collect()
    }
}

/// A numpy array's read-only borrow, held while its [`Samples`] are read.
#[allow(dead_code)] // held, never read
enum Borrow<'py> {
    F32(numpy::PyReadonlyArrayDyn<'py, f32>),
    F16(numpy::PyReadonlyArrayDyn<'py, half::f16>),
}

/// A host image: a (H, W) or (H, W, C) float32/float16 numpy array, checked and borrowed.
struct Image<'py> {
    name: String,
    height: usize,
    width: usize,
    samples: Samples,
    _borrow: Borrow<'py>,
}

impl<'py> Image<'py> {
    fn new(name: &str, array: &Bound<'py, PyAny>) -> PyResult<Image<'py>> {
        let py = array.py();
        let bad = |msg: String| raise(py, "InputError", format!("{name}: {msg}"));
        let Some(allowed) = NamedImages::channels_of(name) else {
            let known: Vec<&str> = kpcn::io::IMAGE_NAMES.iter().filter_map(|n| n.strip_suffix("Variance")).collect();
            return Err(raise(
                py,
                "InputError",
                format!(
                    "variances: no input `{}` — use keys among {}",
                    name.trim_end_matches("Variance"),
                    known.join(", ")
                ),
            ));
        };
        let Ok(a) = array.cast::<numpy::PyUntypedArray>() else {
            return Err(bad(format!("expected a numpy array of shape (H, W, C), got {}", array.get_type().name()?)));
        };
        let shape = a.shape().to_vec();
        let (height, width, c) = match shape[..] {
            [h, w] => (h, w, 1),
            [h, w, c] => (h, w, c),
            _ => return Err(bad(format!("expected shape (H, W) or (H, W, C), got {shape:?}"))),
        };
        let Some(&channels) = allowed.iter().rev().find(|&&k| k <= c) else {
            return Err(bad(format!("has {c} channels, needs {}", allowed[0])));
        };
        fn samples<T: numpy::Element>(v: ArrayViewD<'_, T>, width: usize, channels: usize, half: bool) -> Samples {
            let size = std::mem::size_of::<T>() as isize;
            let s = v.strides();
            Samples {
                ptr: v.as_ptr() as *const u8,
                strides: [s[0] * size, s[1] * size, s.get(2).map_or(0, |c| c * size)],
                half,
                width,
                channels,
            }
        }
        let dtype = a.dtype();
        let (samples, borrow) = if dtype.is_equiv_to(&numpy::dtype::<f32>(py)) {
            let b = a.cast::<PyArrayDyn<f32>>()?.try_readonly().map_err(|e| bad(e.to_string()))?;
            (samples(b.as_array(), width, channels, false), Borrow::F32(b))
        } else if dtype.is_equiv_to(&numpy::dtype::<half::f16>(py)) {
            let b = a.cast::<PyArrayDyn<half::f16>>()?.try_readonly().map_err(|e| bad(e.to_string()))?;
            (samples(b.as_array(), width, channels, true), Borrow::F16(b))
        } else {
            return Err(bad(format!(
                "dtype {dtype} is not float32 or float16 — convert it with .astype(numpy.float32)"
            )));
        };
        Ok(Image { name: name.to_string(), height, width, samples, _borrow: borrow })
    }
}

/// Why a streamed denoise of host images failed.
enum Failed {
    Io(IoError),
    Denoise(DenoiseError),
}

impl From<DenoiseError> for Failed {
    fn from(e: DenoiseError) -> Self {
        Failed::Denoise(e)
    }
}

impl From<IoError> for Failed {
    fn from(e: IoError) -> Self {
        Failed::Io(e)
    }
}

/// A loaded model (or `auto`'s two), reused across frames; safe to share between Python
/// threads, which then denoise concurrently.
///
/// model: "auto" (picks per frame: with colour variances or without), a shipped model's
///     name ("balanced", "fast", "high", "spatial", …) or a .safetensors file.
/// threads: worker threads (default: all cores).
/// max_memory: working-memory budget in MB (default 512), as `kpcn denoise --max-memory`.
#[pyclass(frozen, module = "kpcn")]
struct Denoiser {
    denoisers: Denoisers,
    model: String,
}

fn options(threads: Option<usize>, max_memory: Option<usize>) -> Options {
    Options {
        threads,
        max_memory_mb: max_memory.map_or(Options::default().max_memory_mb, |m| m.max(16)),
        tile_size: None,
    }
}

#[pymethods]
impl Denoiser {
    #[new]
    #[pyo3(signature = (model = "auto", *, threads = None, max_memory = None))]
    fn new(py: Python<'_>, model: &str, threads: Option<usize>, max_memory: Option<usize>) -> PyResult<Self> {
        let denoisers = Denoisers::named(model, options(threads, max_memory)).map_err(|e| denoise_err(py, e))?;
        let (first, _) = denoisers.pick(true);
        if first.model().is_untrained() {
            return Err(raise(
                py,
                "InputError",
                format!(
                    "model `{model}` is an untrained preset ({}) and gives useless images — use a shipped model or a trained .safetensors file",
                    first.model().description
                ),
            ));
        }
        Ok(Denoiser { denoisers, model: model.to_string() })
    }

    /// The model name given.
    #[getter]
    fn model(&self) -> &str {
        &self.model
    }

    fn __repr__(&self) -> String {
        format!("kpcn.Denoiser({:?})", self.model)
    }

    /// Denoises one frame held in numpy arrays; returns the colour, (H, W, 3) float32.
    ///
    /// Each image is a float32 or float16 array of shape (H, W, C) (or (H, W) for one
    /// channel), contiguous or strided; extra channels (alpha) are ignored. The network
    /// needs diffuse, albedo, normal and depth, and color or specular (the other one is
    /// derived: color = diffuse + specular). `variances` maps input names ("color",
    /// "diffuse", "specular", "albedo", "normal", "depth") to the variance of their pixel
    /// mean, 1 or 3 channels; absent ones are estimated from the image. `progress(fraction)`
    /// is called on this thread; returning False cancels. Raises kpcn.InputError for bad
    /// arrays.
    #[pyo3(signature = (color, *, albedo = None, normal = None, depth = None, diffuse = None, specular = None, variances = None, progress = None))]
    #[allow(clippy::too_many_arguments)]
    fn denoise<'py>(
        &self,
        py: Python<'py>,
        color: Option<&Bound<'py, PyAny>>,
        albedo: Option<&Bound<'py, PyAny>>,
        normal: Option<&Bound<'py, PyAny>>,
        depth: Option<&Bound<'py, PyAny>>,
        diffuse: Option<&Bound<'py, PyAny>>,
        specular: Option<&Bound<'py, PyAny>>,
        variances: Option<&Bound<'py, PyDict>>,
        progress: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let mut given: Vec<(String, &Bound<'py, PyAny>)> = [
            ("color", color),
            ("diffuse", diffuse),
            ("specular", specular),
            ("albedo", albedo),
            ("normal", normal),
            ("depth", depth),
        ]
        .into_iter()
        .filter_map(|(n, a)| a.filter(|a| !a.is_none()).map(|a| (n.to_string(), a)))
        .collect();
        let variances: Vec<(String, Bound<'py, PyAny>)> = match variances {
            Some(d) => d
                .iter()
                .map(|(k, v)| Ok((format!("{}Variance", k.extract::<String>()?), v)))
                .collect::<PyResult<_>>()?,
            None => Vec::new(),
        };
        given.extend(variances.iter().map(|(n, a)| (n.clone(), a)));
        let images: Vec<Image<'py>> =
            given.iter().map(|(name, array)| Image::new(name, array)).collect::<PyResult<_>>()?;
        let first = images.first().ok_or_else(|| raise(py, "InputError", "no images given".into()))?;
        let (w, h) = (first.width, first.height);
        if let Some(i) = images.iter().find(|i| (i.width, i.height) != (w, h)) {
            return Err(raise(
                py,
                "InputError",
                format!(
                    "{}: is {}x{} but the frame is {w}x{h} — pass every image of a frame at one size",
                    i.name, i.width, i.height
                ),
            ));
        }
        let (denoiser, _) = self.denoisers.pick(given.iter().any(|(n, _)| n == "colorVariance"));
        // Streamed in bands as files are: the arrays are read a band at a time, never
        // copied whole. Checked before any work, so that a frame too large is an error.
        let bands = Bands::new(denoiser, w, h, None);
        let copied: usize = images.iter().map(|i| i.samples.channels).sum();
        bands.reserve(denoiser, copied, w * h * 3 * 4).map_err(|e| denoise_err(py, e))?;
        let samples: Vec<(&str, Samples)> = images.iter().map(|i| (i.name.as_str(), i.samples)).collect();
        let mut rgb = vec![0f32; w * h * 3];
        let done = run_detached(py, progress, |step| {
            let mut read = |rows: std::ops::Range<usize>| -> Result<KpcnInputs, Failed> {
                let mut named = NamedImages::new(w, rows.len());
                for (name, s) in &samples {
                    named.insert(name, s.rows(rows.clone()))?;
                }
                Ok(named.inputs()?)
            };
            let mut write = |rows: std::ops::Range<usize>, d: Denoised| -> Result<(), Failed> {
                for (i, px) in rgb[rows.start * w * 3..rows.end * w * 3].chunks_exact_mut(3).enumerate() {
                    for (v, plane) in px.iter_mut().zip(&d.color) {
                        *v = plane[i];
                    }
                }
                Ok(())
            };
            denoiser.denoise_streamed(&bands, &mut read, &mut write, step)
        })?;
        drop(images);
        match done {
            Ok(()) => {}
            Err(Failed::Io(e)) => return Err(io_err(py, e)),
            Err(Failed::Denoise(e)) => return Err(denoise_err(py, e)),
        }
        let array = numpy::ndarray::Array3::from_shape_vec((h, w, 3), rgb).expect("h*w*3 values");
        Ok(array.into_pyarray(py))
    }

    /// Denoises the layered EXR `input` into `output` as `kpcn denoise INPUT -o OUTPUT`
    /// does: a copy of every input channel plus the layer `layer` (default "denoised", or
    /// "<ViewLayer>.Denoised" for Blender files), written atomically. `aovs` adds
    /// LAYER_diffuse and LAYER_specular; `separate` writes only the new layers; `in_place`
    /// allows output == input; `view_layer` is a Blender view layer's name or "all";
    /// `layout` is "native", "cycles" or "renderman" (default: detected); `compression` an
    /// EXR compression (default: the input's when lossless, else zip); `no_clobber` refuses
    /// an existing output. The CLI's warnings are raised as UserWarning. Returns one dict per
    /// view layer: layer, view_layer, model, layout, width, height, seconds (per stage).
    #[pyo3(signature = (input, output, *, aovs = false, layer = None, view_layer = None, separate = false, in_place = false, layout = None, compression = None, no_clobber = false, progress = None))]
    #[allow(clippy::too_many_arguments)]
    fn denoise_file<'py>(
        &self,
        py: Python<'py>,
        input: PathBuf,
        output: PathBuf,
        aovs: bool,
        layer: Option<String>,
        view_layer: Option<String>,
        separate: bool,
        in_place: bool,
        layout: Option<&str>,
        compression: Option<String>,
        no_clobber: bool,
        progress: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyList>> {
        let layout = match layout {
            None => None,
            Some(l) => Some(l.parse::<Layout>().map_err(|why| raise(py, "InputError", format!("layout: {why}")))?),
        };
        let request = FileRequest {
            layout,
            view_layers: ViewLayers::parse(view_layer.as_deref()),
            layer,
            aovs,
            separate,
            in_place,
            write: WriteOptions { compression, no_clobber, ..WriteOptions::default() },
        };
        request.check().map_err(|why| raise(py, "InputError", why))?;
        let notes = std::sync::Mutex::new(Vec::new());
        let outcomes = run_detached(py, progress, |step| {
            request.run(&self.denoisers, &input, &output, step, &mut |n| notes.lock().expect("not poisoned").push(n))
        })?;
        // Warnings are raised on the calling thread, where Python's filters apply.
        for n in notes.into_inner().expect("not poisoned") {
            if n.is_warning() {
                let message = std::ffi::CString::new(n.to_string()).unwrap_or_default();
                PyErr::warn(py, &py.get_type::<PyUserWarning>(), &message, 1)?;
            }
        }
        let outcomes = outcomes.map_err(|e| file_err(py, e))?;
        let list = PyList::empty(py);
        for o in outcomes {
            list.append(outcome(py, &o)?)?;
        }
        Ok(list)
    }
}

/// One view layer's result as a dict.
fn outcome<'py>(py: Python<'py>, o: &Outcome) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("view_layer", &o.view_layer)?;
    d.set_item("layer", &o.layer)?;
    d.set_item("model", &o.model)?;
    d.set_item("layout", o.layout.name())?;
    d.set_item("width", o.size.0)?;
    d.set_item("height", o.size.1)?;
    let s = &o.report.stages;
    let stages = PyDict::new(py);
    for (k, v) in [("read", s.read), ("features", s.features), ("network", s.network), ("write", s.write)] {
        stages.set_item(k, v.as_secs_f64())?;
    }
    d.set_item("seconds", stages)?;
    Ok(d)
}

/// The native module; `kpcn/__init__.py` re-exports it.
#[pymodule]
fn _kpcn(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Denoiser>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
