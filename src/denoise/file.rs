//! Denoising a layered EXR file to a new one in bands of rows, so memory stays bounded
//! whatever the frame size: a 4K frame is never held whole.
//!
//! Each band is read with [`Denoiser::halo`] context rows above and below, preprocessed
//! with the whole frame's statistics (one pass over the depth, and for auto-exposed models
//! the colour, first), and its inner rows are denoised and written beside a copy of the
//! input channels, on an encoder thread: copied from the band's own decode where the
//! budget holds them until its result is out, else decoded again by the encoder. The
//! result equals denoising the whole frame at once (tested bit for bit).

use super::stream::FrameStream;
use super::{Bands, Component, DenoiseError, Denoised, Denoiser, Progress};
use crate::features::{self, FrameStats};
use crate::io::layout::{Layout, Mapping, Quantity};
use crate::io::{Attribute, FrameBuffers, FrameReader, FrameWriter, IoError, SampleFormat, WriteOptions};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};

/// What to write.
#[derive(Debug, Clone)]
pub struct FileOptions {
    /// Name of the denoised layer (`NAME.R/G/B`).
    pub layer: String,
    /// Also write `NAME_diffuse` and `NAME_specular`, which add up to `NAME`.
    pub aovs: bool,
    /// Write only the new layers (and the metadata), not a copy of the input channels.
    pub separate: bool,
    /// Allow the output to be the input itself (links followed): the new layers are added
    /// to the render atomically. Without it such an output is refused
    /// ([`check_output`]); it cannot be combined with `separate`.
    pub in_place: bool,
    /// Compression and overwrite policy.
    pub write: WriteOptions,
    /// Rows per band (testing; normally derived from the denoiser's memory budget).
    pub band_rows: Option<usize>,
}

impl Default for FileOptions {
    fn default() -> Self {
        FileOptions {
            layer: "denoised".into(),
            aovs: false,
            separate: false,
            in_place: false,
            write: WriteOptions::default(),
            band_rows: None,
        }
    }
}

/// Errors of [`FileJob`].
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// Reading, mapping or writing failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// The output, the options or the layer name would lose data of the render; nothing
    /// was written.
    #[error("{}: {why}", path.display())]
    Refused {
        /// The output (or the input, for a layer name that collides with its passes).
        path: PathBuf,
        /// Why, and what to do.
        why: String,
    },
    /// The denoiser failed or was cancelled.
    #[error("{}: {cause}", path.display())]
    Denoise {
        /// The input file.
        path: PathBuf,
        /// Why (in the message, not a separate source: a report of the chain would say
        /// it twice).
        cause: DenoiseError,
    },
}

/// Refuses, before any work, an `output` that would lose the render `input` or cannot be
/// written: the input itself (the same file, links followed) unless `opts.in_place`, and
/// not even then with `opts.separate`; a folder, a missing folder, a file or folder you
/// cannot write. Every entrance checks this (`FileJob::run` does; the CLI also lists every
/// frame's problem before the first frame runs).
pub fn check_output(input: &Path, output: &Path, opts: &FileOptions) -> Result<(), FileError> {
    let refuse = |why: String| Err(FileError::Refused { path: output.into(), why });
    let same = crate::io::atomic::same_file(input, output);
    if same && opts.separate {
        return refuse(format!(
            "is the input {} itself, and a separate output holds only the new layers — the render would be erased; choose another output",
            input.display()
        ));
    }
    if same && !opts.in_place {
        return refuse(format!(
            "is the input {} itself — the render would be replaced; ask for in-place writing (`--in-place`, the C ABI's `in_place`) to add the denoised layer to it, or choose another output",
            input.display()
        ));
    }
    crate::io::atomic::check_writable(output).or_else(refuse)
}

/// Refuses a layer name that is empty or malformed, or whose channels (`NAME.R/G/B`, and
/// with `aovs` `NAME_diffuse.*`, `NAME_specular.*`) would replace a pass of the render: one
/// the network reads, or any channel of a file kpcn did not write (`kpcn:model` absent).
/// A file kpcn wrote may have its own earlier result replaced.
fn check_layer(reader: &FrameReader, mapping: &Mapping, opts: &FileOptions) -> Result<(), FileError> {
    let path = reader.header().display_path();
    let refuse = |why: String| Err(FileError::Refused { path: path.clone(), why });
    let name = &opts.layer;
    if name.is_empty() || name.trim() != name || name.starts_with('.') || name.ends_with('.') {
        return refuse(format!(
            "the layer name `{name}` is empty or malformed (channels would be named `{name}.R`) — give a name such as `denoised`"
        ));
    }
    let read = mapping.channels();
    let written_by_kpcn = reader.header().attribute("kpcn:model").is_some();
    for n in new_layer_names(name, opts.aovs) {
        let pass = reader.channel_names().find(|c| *c == n && (read.iter().any(|r| r == c) || !written_by_kpcn));
        if let Some(existing) = pass {
            return refuse(format!(
                "the layer `{name}` would overwrite the render's channel `{existing}` — choose another layer name (`--layer`, the C ABI's `layer`)"
            ));
        }
    }
    Ok(())
}

/// What [`FileJob::run`] saw on the way: the inputs' repaired samples, per input (name,
/// physical range, counts), over the whole frame.
#[derive(Debug, Clone, Default)]
pub struct FileReport {
    /// Inputs with repaired samples.
    pub repairs: Vec<(&'static str, &'static str, features::Repairs)>,
    /// What the beauty held beyond diffuse + specular, carried to the output undenoised,
    /// counted over the whole frame (no planes).
    pub remainder: crate::io::layout::Remainder,
    /// Where the time went.
    pub stages: Stages,
    /// Whether the input's pixels were decoded by OpenEXRCore
    /// ([`crate::io::read_lossless_exr_with_openexr_core`]).
    pub openexr_core: bool,
}

/// Wall time of a file's stages, summed over its bands.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stages {
    /// Reading and decoding the input's channels (whole-frame statistics included).
    pub read: std::time::Duration,
    /// Mapping the channels to the network's inputs and preprocessing them.
    pub features: std::time::Duration,
    /// The network and its kernels.
    pub network: std::time::Duration,
    /// Encoding and writing the output.
    pub write: std::time::Duration,
}

/// Runs `f`, adding its wall time to `into`.
fn timed<T>(into: &mut std::time::Duration, f: impl FnOnce() -> T) -> T {
    let t = std::time::Instant::now();
    let out = f();
    *into += t.elapsed();
    out
}

/// One input file, opened and mapped, ready to denoise.
pub struct FileJob {
    reader: FrameReader,
    mapping: Mapping,
}

/// An output channel: its name in its part, format and source.
type OutChannel = (String, SampleFormat, Src);

/// Where an output channel comes from.
enum Src {
    Input(String),
    New(usize),
}

impl FileJob {
    /// Opens `input` and maps its channels (`layout`, or detected). Fails now, before any
    /// output exists, when a required input is missing.
    pub fn open(input: &Path, layout: Option<Layout>) -> Result<FileJob, FileError> {
        Self::open_view_layer(input, layout, None)
    }

    /// [`FileJob::open`] reading Blender view layer `view_layer` (Cycles layout) rather
    /// than the first one by name; an error lists the file's view layers when it lacks it.
    pub fn open_view_layer(
        input: &Path,
        layout: Option<Layout>,
        view_layer: Option<&str>,
    ) -> Result<FileJob, FileError> {
        let reader = FrameReader::open(input)?;
        // View layers are Blender's: asking for one means the Cycles layout.
        let layout = if view_layer.is_some() { layout.or(Some(Layout::Cycles)) } else { layout };
        let mapping = Mapping::for_view_layer(reader.channel_names(), layout, view_layer);
        if let Some(l) = view_layer.filter(|l| !mapping.view_layers.iter().any(|v| v == l)) {
            return Err(IoError::NoSuchViewLayer {
                path: input.into(),
                name: l.into(),
                available: mapping.view_layers.clone(),
            }
            .into());
        }
        mapping.check(input)?;
        Ok(FileJob { reader, mapping })
    }

    /// How the file's channels map to the network's inputs.
    pub fn mapping(&self) -> &Mapping {
        &self.mapping
    }

    /// Width and height.
    pub fn size(&self) -> (usize, usize) {
        (self.reader.header().width(), self.reader.header().height())
    }

    /// The bands this frame is streamed in.
    pub fn bands(&self, denoiser: &Denoiser, opts: &FileOptions) -> Bands {
        let (w, h) = self.size();
        Bands::new(denoiser, w, h, opts.band_rows)
    }

    /// Denoises into `output` (atomically: nothing appears there on failure or cancel).
    /// `progress` counts tiles over the whole frame; returning `false` cancels.
    pub fn run(
        mut self,
        denoiser: &Denoiser,
        output: &Path,
        opts: &FileOptions,
        progress: &dyn Fn(Progress) -> bool,
    ) -> Result<FileReport, FileError> {
        let (w, h) = self.size();
        let path = self.reader.header().display_path();
        check_output(&path, output, opts)?;
        check_layer(&self.reader, &self.mapping, opts)?;
        if w == 0 || h == 0 {
            return Err(FileError::Denoise { path, cause: DenoiseError::Empty });
        }
        let bands = self.bands(denoiser, opts);
        let band = bands.rows();
        // Every handle is opened before the output, whose creation sizes OpenEXR's pool.
        self.reader.set_decoders(denoiser.threads())?;
        // The largest band's working memory (context rows included) and, beside it, a
        // band's copied channels and result held by the encoder (with several bands, one
        // more on its way there), checked before the output exists.
        let channels = self.reader.channel_names().count();
        // A streamed frame's bands keep the channels they copy from their one decode until
        // their result comes out, where that fits the budget (else the encoder decodes them
        // again: a third more decoding).
        let kept = bands.held_copies_bytes(denoiser, channels);
        let in_flight = (channels + 9) * if bands.len() > 1 { 2 } else { 1 };
        bands
            .reserve(denoiser, in_flight, kept.unwrap_or(0))
            .map_err(|cause| FileError::Denoise { path: path.clone(), cause })?;
        let needed = self.mapping.channels();
        let needed: Vec<&str> = needed.iter().map(String::as_str).collect();

        // The depth scale and the exposure are whole-frame statistics: one pass over the
        // depth (and colour) channels first.
        let mut stages = Stages::default();
        let whole = if bands.len() == 1 {
            None
        } else {
            Some(timed(&mut stages.read, || self.frame_stats(band, channels, denoiser.auto_exposed()))?)
        };

        // Output parts: the input's, each with its channels and name (a same-named channel
        // is replaced in place); the new layers join the part that holds the beauty. With
        // `separate`, one part of only the new layers.
        let new_names = new_layer_names(&opts.layer, opts.aovs);
        let color = self.mapping.entry_for(Quantity::Color).mean_channels();
        let input_parts = self.reader.parts();
        let beauty =
            input_parts.iter().position(|p| p.channels.iter().any(|c| color.first() == Some(&c.0))).unwrap_or(0);
        let mut parts: Vec<(String, Vec<OutChannel>)> = Vec::new();
        for (i, part) in input_parts.iter().enumerate() {
            if opts.separate && i != beauty {
                continue;
            }
            let mut channels: Vec<OutChannel> = Vec::new();
            if !opts.separate {
                for (name, in_part, format) in &part.channels {
                    match (i == beauty).then(|| new_names.iter().position(|n| n == in_part)).flatten() {
                        Some(k) => channels.push((in_part.clone(), SampleFormat::Float, Src::New(k))),
                        None => channels.push((in_part.clone(), *format, Src::Input(name.clone()))),
                    }
                }
            }
            if i == beauty {
                for (k, n) in new_names.iter().enumerate() {
                    if !channels.iter().any(|(name, ..)| name == n) {
                        channels.push((n.clone(), SampleFormat::Float, Src::New(k)));
                    }
                }
            }
            let name = if opts.separate { String::new() } else { part.name.clone() };
            parts.push((name, channels));
        }
        let beauty_out = if opts.separate { 0 } else { beauty };
        let mut header = self.reader.header().clone();
        header.set_attribute(Attribute::string("kpcn:model", &denoiser.model().description));
        header.set_attribute(Attribute::string("kpcn:layout", self.mapping.layout.name()));
        let spec: Vec<(&str, Vec<(&str, SampleFormat)>)> = parts
            .iter()
            .map(|(name, ch)| (name.as_str(), ch.iter().map(|(n, f, _)| (n.as_str(), *f)).collect()))
            .collect();
        let total = bands.total_tiles(denoiser);
        let mut done = 0;
        let mut totals: Vec<(&'static str, &'static str, features::Repairs)> = Vec::new();
        let mut report = FileReport::default();
        // The encoder decodes the copied channels no band keeps (other parts', and a
        // streamed frame's beyond the budget) with handles of its own, so that this runs
        // beside the network, not between its bands (opened before the output, as the
        // producer's are).
        let kept_by_bands = bands.len() == 1 || kept.is_some();
        let decodes =
            parts.iter().enumerate().any(|(p, (_, ch))| !copied(ch).is_empty() && (p != beauty_out || !kept_by_bands));
        let mut copier = if decodes {
            let mut r = FrameReader::open(&path)?;
            r.set_decoders(denoiser.threads())?;
            Some(r)
        } else {
            None
        };
        let mut writer = FrameWriter::create(output, &header, &spec, &opts.write)?;
        // The encoder decodes in pieces of what it writes at a time (below): handles beyond
        // the chunks of a piece would hold a chunk's buffers (30 MB at 4K) for nothing.
        if let Some(c) = copier.as_mut() {
            c.set_decoders(c.chunks_in(writer.most_rows_per_write()).min(denoiser.threads()))?;
        }
        // The output is encoded on a thread of its own (OpenEXR compresses a 4K file's rows
        // a chunk at a time), while the next bands are read and denoised; a band is handed
        // over only when the previous one is written, so at most two are in flight.
        let (tx, rx) = std::sync::mpsc::sync_channel::<Written>(0);
        let aovs = opts.aovs;
        let parts = &parts;
        let (produced, written) = std::thread::scope(|scope| {
            let encoder = scope.spawn(move || -> Result<(FrameWriter, [std::time::Duration; 2]), FileError> {
                let (mut part, mut spent) = (0, [std::time::Duration::ZERO; 2]);
                for m in rx {
                    match m {
                        Written::NextPart => {
                            let started = std::time::Instant::now();
                            writer.next_part()?;
                            part += 1;
                            spent[1] += started.elapsed();
                        }
                        Written::Rows { rows, copies, denoised } => {
                            let channels = &parts[part].1;
                            let names = copied(channels);
                            let new = denoised.as_ref().map(|d| new_planes(d, aovs)).unwrap_or_default();
                            // In pieces of what the writer takes per call, so that the copier
                            // decodes no more rows at a time than are encoded (a 4K band's 41
                            // channels: 10 MB a piece against 40 MB a band).
                            let piece = writer.rows_per_write();
                            let w = writer.width();
                            for r0 in (0..rows.len()).step_by(piece) {
                                let r1 = (r0 + piece).min(rows.len());
                                // Decoded here when no band kept them (the copier is opened then).
                                let decoded;
                                let (copies, at) = match (&copies, copier.as_mut()) {
                                    (Some(fb), _) => (fb, r0),
                                    (None, Some(copier)) if !names.is_empty() => {
                                        let (a, b) = (rows.start + r0, rows.start + r1);
                                        decoded = timed(&mut spent[0], || copier.read_band(Some(&names), a, b))?;
                                        (&decoded, 0)
                                    }
                                    (None, _) => {
                                        decoded = FrameBuffers::new(0, 0);
                                        (&decoded, 0)
                                    }
                                };
                                let started = std::time::Instant::now();
                                let planes = channels
                                    .iter()
                                    .map(|(_, _, src)| match src {
                                        Src::New(k) => Ok(&new[*k][r0 * w..r1 * w]),
                                        Src::Input(n) => copies
                                            .channel(n)
                                            .map(|c| &c[at * w..(at + r1 - r0) * w])
                                            .ok_or_else(|| IoError::NoSuchChannel {
                                                path: copies.display_path(),
                                                channel: n.clone(),
                                            }),
                                    })
                                    .collect::<Result<Vec<&[f32]>, IoError>>()?;
                                writer.write_band(&planes, r1 - r0)?;
                                spent[1] += started.elapsed();
                            }
                        }
                    }
                }
                Ok((writer, spent))
            });
            let sink = Sink(tx);
            let produced = (|| -> Result<(), FileError> {
                // Parts are written one after another (as EXR requires), each streamed in bands;
                // only the beauty's part runs the network.
                for (p, (_, channels)) in parts.iter().enumerate() {
                    if p > 0 {
                        sink.send(Written::NextPart)?;
                    }
                    let copies = copied(channels);
                    // A multi-scale model's network runs down the frame's bands as one stream;
                    // a band's result comes out once the rows below it that it needs went in.
                    let mut network = if p == beauty_out { FrameStream::new(denoiser, w, h) } else { None };
                    let mut held_bands: VecDeque<Option<FrameBuffers>> = VecDeque::new();
                    // The rows a band's read shares with the next one's (its context rows),
                    // kept so that they are decoded once.
                    let mut shared: Option<FrameBuffers> = None;
                    let all: Vec<&std::ops::Range<usize>> = bands.iter().collect();
                    for (i, &band) in all.iter().enumerate() {
                        let (a, b) = (band.start, band.end);
                        if p != beauty_out {
                            sink.send(Written::Rows { rows: a..b, copies: None, denoised: None })?;
                            continue;
                        }
                        let context = bands.with_context(band);
                        let (c0, c1) = (context.start, context.end);
                        // A band decodes its rows once for the network's inputs and the copied
                        // channels, whose inner rows it keeps until its result is written: a
                        // band without context rows (the whole frame, as a 1280×720 frame is at
                        // the default budget), or a streamed frame's where they fit the budget
                        // (`kept`). Otherwise it holds only the network's inputs, until they are
                        // mapped, and the encoder decodes the copied channels again.
                        let once = !copies.is_empty() && (context == *band || kept.is_some());
                        let names = if once { union(&needed, &copies) } else { needed.clone() };
                        let mut fb = timed(&mut stages.read, || match shared.take() {
                            Some(rows) => self.reader.read_band_after(rows, c1),
                            None => self.reader.read_band(Some(&names), c0, c1),
                        })?;
                        let next = all.get(i + 1).map(|b| bands.with_context(b).start);
                        if let Some(next) = next.filter(|n| (c0..c1).contains(n) && c1 - n <= MAX_SHARED_ROWS) {
                            shared = Some(fb.copy_rows(next - c0..c1 - c0));
                        }
                        let started = std::time::Instant::now();
                        let inputs = self.mapping.extract(&fb)?;
                        let held = if once {
                            for n in needed.iter().filter(|n| !copies.contains(n)) {
                                fb.remove(n);
                            }
                            fb.keep_rows(a - c0..b - c0);
                            Some(fb)
                        } else {
                            drop(fb);
                            None
                        };
                        for (name, range, r) in features::repairs(&inputs, a - c0..b - c0) {
                            match totals.iter_mut().find(|t| t.0 == name) {
                                Some(t) => {
                                    t.2.nonfinite += r.nonfinite;
                                    t.2.out_of_range += r.out_of_range;
                                }
                                None => totals.push((name, range, r)),
                            }
                        }
                        let remainder = inputs.remainder(a - c0..b - c0);
                        report.remainder.absorb_counts(&remainder);
                        let f = denoiser.features(std::borrow::Cow::Owned(inputs), whole);
                        stages.features += started.elapsed();
                        if let Some(network) = network.as_mut() {
                            timed(&mut stages.network, || network.push(&f, c0, band.clone(), remainder));
                            drop(f);
                            held_bands.push_back(held);
                            while let Some((rows, d)) = network.ready() {
                                done += 1;
                                if !progress(Progress { done, total }) {
                                    return Err(FileError::Denoise { path, cause: DenoiseError::Cancelled });
                                }
                                sink.send(Written::Rows {
                                    rows,
                                    copies: held_bands.pop_front().flatten(),
                                    denoised: Some(Box::new(d)),
                                })?;
                            }
                            continue;
                        }
                        let step = |p: Progress| progress(Progress { done: done + p.done, total });
                        let mut d = timed(&mut stages.network, || denoiser.denoise_band(&f, a - c0..b - c0, &step))
                            .map_err(|cause| FileError::Denoise { path: path.clone(), cause })?;
                        d.carry(&remainder);
                        drop(f);
                        done += bands.tiles_in(denoiser, band);
                        sink.send(Written::Rows { rows: band.clone(), copies: held, denoised: Some(Box::new(d)) })?;
                    }
                }
                Ok(())
            })();
            drop(sink);
            (produced, encoder.join())
        });
        // The encoder's own error first: the producer only saw it stop.
        let (writer, [read, write]) = match written {
            Ok(w) => w?,
            Err(panic) => std::panic::resume_unwind(panic),
        };
        produced?;
        stages.read += read;
        stages.write += write;
        timed(&mut stages.write, || writer.commit())?;
        totals.retain(|t| t.2 != features::Repairs::default());
        report.repairs = totals;
        report.stages = stages;
        report.openexr_core = self.reader.reads_with_openexr_core();
        Ok(report)
    }

    /// The largest finite depth of the whole frame and, when `exposure`, its exposure (of
    /// the colour exactly as the network's inputs hold it), reading only the depth's and the
    /// colour's channels four bands at a time (fewer where that would hold more bytes than
    /// a band's read of all `channels`), so that each read gives every decoder many chunks:
    /// 1.9 s for a 4K file against 3.7 in one-band reads, whose peak memory is not raised
    /// (larger reads raised it by about 20 MiB).
    fn frame_stats(&mut self, band: usize, channels: usize, exposure: bool) -> Result<FrameStats, FileError> {
        let path = self.reader.header().display_path();
        self.mapping.check(&path)?;
        let depth = self.mapping.entry_for(Quantity::Depth).clone();
        let colour = self.mapping.entry_for(Quantity::Color).clone();
        let mut names = depth.mean_channels();
        if exposure {
            names.extend(colour.mean_channels().into_iter().filter(|c| !names.contains(c)).collect::<Vec<_>>());
        }
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        let (w, h) = self.size();
        let mut meter = features::FrameStatsMeter::new(w, exposure);
        let rows = band * (channels / names.len().max(1)).clamp(1, 4);
        // The next rows decode while these are measured (at most one more read waits).
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let (reader, names) = (&mut self.reader, &names);
        std::thread::scope(|scope| {
            scope.spawn(move || {
                for a in (0..h).step_by(rows) {
                    let fb = reader.read_band(Some(names), a, a + rows);
                    let failed = fb.is_err();
                    // A closed queue: the measuring side stopped on an error of its own.
                    if tx.send(fb).is_err() || failed {
                        break;
                    }
                }
            });
            for fb in rx {
                let fb = fb?;
                // The inputs' own formulas (`Mapping::extract`), on only these channels.
                let Some(d) = depth.eval_mean(&fb).and_then(|mut v| v.pop()) else { continue };
                let c = if meter.wants_colour() { colour.eval_mean(&fb) } else { None };
                meter.add(&d, c.as_ref().map(|c| [0, 1, 2].map(|i| c[i].as_slice())));
            }
            Ok(meter.finish())
        })
    }
}

/// The most context rows a band's read shares with the next that are kept for it rather
/// than decoded again (a streamed network's are 4; a tiled network's can be hundreds,
/// which the budget does not count twice).
const MAX_SHARED_ROWS: usize = 16;

/// What the encoder thread of [`FileJob::run`] writes, in order.
enum Written {
    /// Rows of the current part: its channels copied from `copies` (decoded by the encoder
    /// when `None`), the new ones from `denoised` (the beauty's part).
    Rows { rows: std::ops::Range<usize>, copies: Option<FrameBuffers>, denoised: Option<Box<Denoised>> },
    /// The next part starts.
    NextPart,
}

/// The producer's end of the encoder thread's queue.
struct Sink(std::sync::mpsc::SyncSender<Written>);

impl Sink {
    /// Hands `m` over once the encoder has taken the previous one; an error when the
    /// encoder stopped (its own error is the one reported).
    fn send(&self, m: Written) -> Result<(), FileError> {
        self.0.send(m).map_err(|_| FileError::Refused { path: PathBuf::new(), why: "the encoder stopped".into() })
    }
}

/// The input channels an output part copies.
fn copied(channels: &[OutChannel]) -> Vec<&str> {
    channels
        .iter()
        .filter_map(|(_, _, src)| match src {
            Src::Input(n) => Some(n.as_str()),
            Src::New(_) => None,
        })
        .collect()
}

/// The channels of `a` and those of `b` not in `a`.
fn union<'a>(a: &[&'a str], b: &[&'a str]) -> Vec<&'a str> {
    a.iter().chain(b.iter().filter(|n| !a.contains(n))).copied().collect()
}

/// The layers written: suffix of the layer name and which result it holds. `NAME`, then
/// with `aovs` `NAME_diffuse` and `NAME_specular`.
fn new_layers(aovs: bool) -> &'static [(&'static str, Component)] {
    const ALL: [(&str, Component); 3] =
        [("", Component::Color), ("_diffuse", Component::Diffuse), ("_specular", Component::Specular)];
    if aovs { &ALL } else { &ALL[..1] }
}

/// Channel names of [`new_layers`], R/G/B per layer.
fn new_layer_names(layer: &str, aovs: bool) -> Vec<String> {
    new_layers(aovs).iter().flat_map(|(suffix, _)| ["R", "G", "B"].map(|c| format!("{layer}{suffix}.{c}"))).collect()
}

/// The planes of [`new_layer_names`], in that order.
fn new_planes(d: &Denoised, aovs: bool) -> Vec<&[f32]> {
    new_layers(aovs).iter().flat_map(|(_, c)| d.component(*c).iter().map(Vec::as_slice)).collect()
}
