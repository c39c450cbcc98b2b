//! A frame streamed in bands of rows, so that memory stays bounded whatever its size: each
//! band is read with [`Denoiser::halo`] context rows above and below and preprocessed with
//! the whole frame's statistics, and only its inner rows are denoised. The result equals
//! denoising the whole frame at once, bit for bit. Files ([`super::FileJob`]) and host
//! buffers (the C ABI, the Python module) are streamed alike.

use super::stream::FrameStream;
use super::{DenoiseError, Denoised, Denoiser, Progress, reserve_working_memory};
use crate::features;
use crate::io::layout::KpcnInputs;
use std::borrow::Cow;
use std::ops::Range;

/// Working floats per pixel of a band: every channel of a layered EXR (≈40), the
/// network inputs (21) and the features (25), with room to spare, so that a band takes
/// about half the memory budget and the tiles in flight the rest. (Twice this left a
/// 1280×720 frame two bands at the default budget, and one runs 1.4× faster for 100 MB
/// more peak RSS: BENCHMARKS.md.)
const BAND_FLOATS_PER_PIXEL: usize = 120;

/// Rows per band of a streamed frame that takes several.
const STREAMED_BAND_ROWS: usize = 64;

/// The bands of a `width`×`height` frame for one denoiser.
#[derive(Debug, Clone)]
pub struct Bands {
    bands: Vec<Range<usize>>,
    halo: usize,
    /// Rows the first and the last band are read with at least, for the rows a streamed
    /// frame mirrors beyond its edges.
    mirrored: usize,
    width: usize,
    height: usize,
}

impl Bands {
    /// Bands of `band_rows` rows (testing), or as many as half of `denoiser`'s memory
    /// budget holds; never thinner than twice the context rows, and starting on the
    /// network's pooling grid.
    pub fn new(denoiser: &Denoiser, width: usize, height: usize, band_rows: Option<usize>) -> Bands {
        let budget = denoiser.options.max_memory_mb << 20;
        let by_budget = budget / (width.max(1) * 4 * BAND_FLOATS_PER_PIXEL);
        // A band thinner than its context rows would spend most of its work on them (the
        // ladder's 194 rows each side at 4K: 5× the frame's work in 96-row bands): then a
        // band is twice the context, over budget rather than several times slower.
        let halo = denoiser.halo(width);
        let by_budget = by_budget.max(2 * halo).max(16);
        // A streamed frame of several bands decodes its rows for the statistics first
        // whatever the bands' size, so its bands are short: they hold the features and the
        // rows being written, beside the streams.
        let by_budget =
            if denoiser.streams(width) && by_budget < height { by_budget.min(STREAMED_BAND_ROWS) } else { by_budget };
        // A streamed band's diffuse output reads its neighbours' rows only.
        let spread = super::Bounds::diffuse_context(&denoiser.model().arch);
        let rows =
            band_rows.unwrap_or(by_budget).max(spread).max(1).next_multiple_of(denoiser.model().arch.alignment());
        let rows = rows.min(height.max(1));
        let bands = (0..height).step_by(rows).map(|a| a..(a + rows).min(height)).collect();
        let mirrored = if denoiser.streams(width) { FrameStream::mirrored_rows(denoiser, height) + 1 } else { 0 };
        Bands { bands, halo, mirrored, width, height }
    }

    /// Rows per band (the last may be shorter).
    pub fn rows(&self) -> usize {
        self.bands.first().map_or(0, |b| b.len())
    }

    /// The bands, top to bottom.
    pub fn iter(&self) -> impl Iterator<Item = &Range<usize>> {
        self.bands.iter()
    }

    /// How many.
    pub fn len(&self) -> usize {
        self.bands.len()
    }

    /// Whether the frame has no rows.
    pub fn is_empty(&self) -> bool {
        self.bands.is_empty()
    }

    /// `band` with its context rows (clipped to the frame; for a streamed frame's first
    /// and last bands, also the rows mirrored beyond its edges).
    pub fn with_context(&self, band: &Range<usize>) -> Range<usize> {
        let mut start = band.start.saturating_sub(self.halo);
        let mut end = (band.end + self.halo).min(self.height);
        if band.start == 0 {
            end = end.max(self.mirrored.min(self.height));
        }
        if band.end == self.height {
            start = start.min(self.height.saturating_sub(self.mirrored));
        }
        start..end
    }

    /// `band`'s rows within [`Bands::with_context`].
    pub fn inner(&self, band: &Range<usize>) -> Range<usize> {
        let c0 = self.with_context(band).start;
        band.start - c0..band.end - c0
    }

    /// Tiles of `band` (a streamed frame counts a band as one).
    pub fn tiles_in(&self, denoiser: &Denoiser, band: &Range<usize>) -> usize {
        if denoiser.streams(self.width) {
            return 1;
        }
        let rows = self.with_context(band).len();
        denoiser.band_tiles(self.width, denoiser.diffuse_rows(self.inner(band), rows), rows).len()
    }

    /// Tiles of the frame.
    pub fn total_tiles(&self, denoiser: &Denoiser) -> usize {
        self.iter().map(|b| self.tiles_in(denoiser, b)).sum()
    }

    /// Bytes that `channels` decoded planes take when a streamed frame keeps them from a
    /// band's decode until its result comes out: the rows the stream holds back, the band
    /// being read and the band on its way to the encoder. `None` when they do not fit the
    /// memory budget beside the largest band's working memory, or the frame is not
    /// streamed in several bands (one band is decoded once anyway).
    pub fn held_copies_bytes(&self, denoiser: &Denoiser, channels: usize) -> Option<usize> {
        if self.len() < 2 || !denoiser.streams(self.width) {
            return None;
        }
        let (_, working) = self.largest_band(denoiser)?;
        let held_rows = (denoiser.stream_region(self.width).1 + 2 * self.rows()).min(self.height);
        let held = channels * 4 * self.width * held_rows;
        (working + held <= denoiser.options.max_memory_mb << 20).then_some(held)
    }

    /// The largest band's rows with context, and the bytes of its network inputs and
    /// working memory.
    fn largest_band(&self, denoiser: &Denoiser) -> Option<(usize, usize)> {
        let band = self.iter().max_by_key(|b| self.with_context(b).len())?;
        let rows = self.with_context(band).len();
        let bytes = KpcnInputs::bytes(self.width, rows).saturating_add(denoiser.working_bytes(
            self.width,
            self.inner(band),
            rows,
        ));
        Some((rows, bytes))
    }

    /// Checks, before any work, that the largest band can be had: its network inputs and
    /// working memory, `floats_per_pixel` more of the caller's own over its rows with
    /// context, and `fixed` bytes.
    pub fn reserve(&self, denoiser: &Denoiser, floats_per_pixel: usize, fixed: usize) -> Result<(), DenoiseError> {
        let Some((rows, working)) = self.largest_band(denoiser) else { return Ok(()) };
        let bytes = working
            .saturating_add(floats_per_pixel.saturating_mul(self.width).saturating_mul(rows).saturating_mul(4))
            .saturating_add(fixed);
        reserve_working_memory(bytes)
    }
}

impl Denoiser {
    /// Denoises a frame read band by band: `read(rows)` gives the network's inputs for
    /// those rows (each band's rows with context, and with several bands each band once
    /// more for the whole frame's statistics); each band's result goes to
    /// `write(rows, denoised)`. `progress` counts tiles over the frame; `false` cancels.
    pub fn denoise_streamed<E: From<DenoiseError>>(
        &self,
        bands: &Bands,
        read: &mut dyn FnMut(Range<usize>) -> Result<KpcnInputs, E>,
        write: &mut dyn FnMut(Range<usize>, Denoised) -> Result<(), E>,
        progress: &dyn Fn(Progress) -> bool,
    ) -> Result<(), E> {
        if bands.is_empty() || bands.width == 0 {
            return Err(DenoiseError::Empty.into());
        }
        let whole = if bands.len() == 1 {
            None
        } else {
            let mut meter = features::FrameStatsMeter::new(bands.width, self.auto_exposed());
            for band in bands.iter() {
                let inputs = read(band.clone())?;
                meter.add(&inputs.depth, Some(inputs.color.each_ref().map(Vec::as_slice)));
            }
            Some(meter.finish())
        };
        let (total, mut done) = (bands.total_tiles(self), 0);
        if let Some(mut network) = FrameStream::new(self, bands.width, bands.height) {
            for band in bands.iter() {
                let context = bands.with_context(band);
                let inputs = read(context.clone())?;
                let remainder = inputs.remainder(bands.inner(band));
                let f = self.features(Cow::Owned(inputs), whole);
                network.push(&f, context.start, band.clone(), remainder);
                drop(f);
                while let Some((rows, d)) = network.ready() {
                    done += 1;
                    if !progress(Progress { done, total }) {
                        return Err(DenoiseError::Cancelled.into());
                    }
                    write(rows, d)?;
                }
            }
            return Ok(());
        }
        for band in bands.iter() {
            let inner = bands.inner(band);
            let inputs = read(bands.with_context(band))?;
            let remainder = inputs.remainder(inner.clone());
            let f = self.features(Cow::Owned(inputs), whole);
            let step = |p: Progress| progress(Progress { done: done + p.done, total });
            let mut d = self.denoise_band(&f, inner, &step)?;
            drop(f);
            d.carry(&remainder);
            done += bands.tiles_in(self, band);
            write(band.clone(), d)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::denoise::Options;
    use crate::io::{FrameBuffers, NamedImages};
    use crate::model::Model;

    /// Rows `rows` of the example frame's passes as named host images (`variances`: with
    /// the file's variances, else estimated), made the network's inputs.
    fn host_rows(fb: &FrameBuffers, rows: Range<usize>, variances: bool) -> KpcnInputs {
        let w = fb.width();
        let mut images = NamedImages::new(w, rows.len());
        let rgb = |p: &str| ["R", "G", "B"].map(|c| if p.is_empty() { c.to_string() } else { format!("{p}.{c}") });
        let mut named: Vec<(&str, Vec<String>)> = vec![
            ("color", rgb("").to_vec()),
            ("diffuse", rgb("diffuse").to_vec()),
            ("albedo", rgb("albedo").to_vec()),
            ("normal", rgb("normal").to_vec()),
            ("depth", vec!["depth.Z".into()]),
        ];
        if variances {
            for v in ["color", "diffuse", "specular", "albedo", "normal", "depth"] {
                named.push((Box::leak(format!("{v}Variance").into_boxed_str()), vec![format!("{v}Variance.Z")]));
            }
        }
        for (name, channels) in named {
            let planes =
                channels.iter().map(|c| fb.channel(c).unwrap()[rows.start * w..rows.end * w].to_vec()).collect();
            images.insert(name, planes).unwrap();
        }
        images.inputs().unwrap()
    }

    /// `component` of `fb` denoised by `d` in bands of 16 rows (several), streamed.
    fn streamed(
        d: &Denoiser,
        fb: &FrameBuffers,
        variances: bool,
        component: fn(Denoised) -> [Vec<f32>; 3],
    ) -> [Vec<f32>; 3] {
        let (w, h) = (fb.width(), fb.height());
        let bands = Bands::new(d, w, h, Some(16));
        assert!(bands.len() > 1, "several bands");
        let mut got: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0f32; w * h]);
        let mut read = |rows: Range<usize>| Ok::<_, DenoiseError>(host_rows(fb, rows, variances));
        let mut write = |rows: Range<usize>, r: Denoised| {
            for (g, p) in got.iter_mut().zip(component(r)) {
                g[rows.start * w..rows.end * w].copy_from_slice(&p);
            }
            Ok(())
        };
        d.denoise_streamed(&bands, &mut read, &mut write, &|_| true).unwrap();
        got
    }

    #[test]
    fn streamed_bands_equal_the_whole_frame_bit_for_bit() {
        let fb = FrameBuffers::read(std::path::Path::new("examples/data/spheres-crop-00016spp.exr")).unwrap();
        let h = fb.height();
        for (model, variances) in [("spatial", false), ("balanced", true), ("compact", false)] {
            let d = Denoiser::new(Model::resolve(model).unwrap(), Options::default()).unwrap();
            let whole = d.denoise(&host_rows(&fb, 0..h, variances), &|_| true).unwrap();
            let got = streamed(&d, &fb, variances, |r| r.color);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            for (c, (g, w)) in got.iter().zip(&whole.color).enumerate() {
                assert!(bits(g) == bits(w), "{model}: channel {c} differs");
            }
        }
    }

    /// `balanced` under a ceiling of one standard error, its take spread over 15×15, its
    /// detail not restored.
    fn spreading() -> Model {
        use crate::features::Branch;
        use crate::model::{model_file_with_bound, model_file_with_detail, model_file_with_spread};
        let bytes = Model::resolve("balanced").unwrap().to_bytes().unwrap();
        let bytes = model_file_with_detail(&bytes, None, "mem").unwrap();
        let bytes = model_file_with_bound(&bytes, Branch::Diffuse, Some(1), "mem").unwrap();
        Model::from_bytes(&model_file_with_spread(&bytes, Some(7), "mem").unwrap(), "mem").unwrap()
    }

    #[test]
    fn a_spread_gives_banded_frames_the_whole_frames_light_bit_for_bit() {
        // Streamed bands (the next band's first rows send light up), and bands in tiles
        // with context rows (a budget too small to stream the network).
        let fb = FrameBuffers::read(std::path::Path::new("examples/data/spheres-crop-00016spp.exr")).unwrap();
        let h = fb.height();
        let inputs = host_rows(&fb, 0..h, true);
        let with = |f: fn(&mut Model)| {
            let mut m = spreading();
            f(&mut m);
            Denoiser::new(m, Options::default()).unwrap().denoise(&inputs, &|_| true).unwrap()
        };
        let dropped = with(|m| m.arch.diffuse_spread = None);
        let unbounded = with(|m| (m.arch.diffuse_spread, m.arch.diffuse_bound) = (None, None));
        let total = |d: &Denoised| d.diffuse.iter().flatten().map(|&v| v as f64).sum::<f64>();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for options in [Options::default(), Options { max_memory_mb: 1, tile_size: Some(64), ..Options::default() }] {
            let d = Denoiser::new(spreading(), options).unwrap();
            let whole = d.denoise(&inputs, &|_| true).unwrap();
            let moved: f32 = (0..3)
                .map(|c| whole.diffuse[c].iter().zip(&dropped.diffuse[c]).map(|(a, b)| (a - b).abs()).sum::<f32>())
                .sum();
            assert!(moved > 0.0, "the ceiling takes light here and the spread moves it");
            let (kept, all) = (total(&whole), total(&unbounded));
            assert!((kept - all).abs() <= 1e-5 * all && total(&dropped) < all, "{kept} kept of {all}");
            let got = streamed(&d, &fb, true, |r| r.diffuse);
            for (c, (g, w)) in got.iter().zip(&whole.diffuse).enumerate() {
                assert!(bits(g) == bits(w), "{} MB: channel {c} differs", d.options.max_memory_mb);
            }
        }
    }

    #[test]
    fn restored_detail_gives_banded_frames_the_whole_frames_output_bit_for_bit() {
        // Streamed bands (the next band's first rows are read), and bands in tiles with
        // context rows (a budget too small to stream the network); with a spread beside it.
        use crate::model::model_file_with_detail;
        // `spatial` on the frame without its variances (estimated, as for Blender's files).
        let fb = FrameBuffers::read(std::path::Path::new("examples/data/spheres-crop-00016spp.exr")).unwrap();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let models = [
            (Model::resolve("balanced").unwrap(), true),
            (spreading(), true),
            (Model::resolve("spatial").unwrap(), false),
        ];
        for (base, variances) in models {
            let inputs = host_rows(&fb, 0..fb.height(), variances);
            let base = base.to_bytes().unwrap();
            let (bytes, plain) = (
                model_file_with_detail(&base, Some(7), "mem").unwrap(),
                model_file_with_detail(&base, None, "mem").unwrap(),
            );
            let plain = Model::from_bytes(&plain, "mem").unwrap();
            let plain = Denoiser::new(plain, Options::default()).unwrap().denoise(&inputs, &|_| true).unwrap();
            for options in [Options::default(), Options { max_memory_mb: 1, tile_size: Some(64), ..Options::default() }]
            {
                let d = Denoiser::new(Model::from_bytes(&bytes, "mem").unwrap(), options).unwrap();
                let whole = d.denoise(&inputs, &|_| true).unwrap();
                assert!(whole.diffuse[1].iter().zip(&plain.diffuse[1]).any(|(a, b)| a != b), "detail restored here");
                let got = streamed(&d, &fb, variances, |r| r.diffuse);
                for (c, (g, w)) in got.iter().zip(&whole.diffuse).enumerate() {
                    assert!(bits(g) == bits(w), "{variances} {} MB: channel {c} differs", d.options.max_memory_mb);
                }
            }
        }
    }

    #[test]
    fn a_streamed_frame_keeps_its_copied_channels_only_within_the_budget() {
        let d = |mb| {
            Denoiser::new(Model::resolve("balanced").unwrap(), Options { max_memory_mb: mb, ..Options::default() })
        };
        let d512 = d(512).unwrap();
        // One band decodes once anyway.
        assert_eq!(Bands::new(&d512, 1280, 720, None).held_copies_bytes(&d512, 41), None);
        // A 1080p file's 41 channels fit the default budget beside its streams; a 4K
        // file's do not, and with twice the budget they do.
        let hd = Bands::new(&d512, 1920, 1080, None);
        let kept = hd.held_copies_bytes(&d512, 41).expect("1080p keeps them");
        let held_rows = d512.stream_region(hd.width).1 + 2 * hd.rows();
        assert_eq!(kept, 41 * 4 * 1920 * held_rows);
        assert_eq!(Bands::new(&d512, 3840, 2160, None).held_copies_bytes(&d512, 41), None);
        let d1024 = d(1024).unwrap();
        assert!(Bands::new(&d1024, 3840, 2160, None).held_copies_bytes(&d1024, 41).is_some());
    }
}
