//! 2-D convolution on CHW planes with zero padding ("same" size): the forward pass used
//! by inference and training, and the weight gradient used by training.
//!
//! The forward pass is a register-blocked direct convolution. Weights are packed once per
//! layer ([`ConvLayer`]) into panels of [`MR`] output channels, `[cin·k·k][MR]`, so the
//! micro-kernel broadcasts them from one contiguous stream; input rows are read straight
//! from zero-padded bands of rows (no im2col copy). With AVX-512 a block is 8 output
//! channels × 3 segments of 16 pixels (24 accumulators, masked at the edges; narrow
//! planes run their segments across row ends, see `Job::rows_avx512`); with AVX2,
//! 8 × 8; otherwise scalar. Every output value starts at its bias and adds
//! `input·weight` with one fused multiply-add per term, in the order (input channel,
//! row, column), wherever it lies in the plane and whichever path runs, so tiles and
//! bands equal the whole frame bit for bit.
//!
//! The weight gradient vectorises over pixels (`Taps`), or over output channels for
//! 3×3 layers wider than 16 (`by_channel`); the input gradient is the forward pass with
//! transposed weights ([`ConvLayer::transposed`]).

use super::planes::Planes;
use super::simd::Isa;
use rayon::prelude::*;
use std::borrow::Cow;
use std::ops::Range;

/// Output channels per packed weight panel (one micro-kernel block).
pub const MR: usize = 8;

/// A convolution's weights packed for the micro-kernels, with its bias.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvLayer {
    cout: usize,
    cin: usize,
    k: usize,
    /// `ceil(cout / MR)` panels of `[cin·k·k][MR]`, the last one zero-filled.
    packed: Vec<f32>,
    /// `ceil(cout / MR)·MR` biases, zero-filled.
    bias: Vec<f32>,
}

impl ConvLayer {
    /// Packs `weight` `[cout][cin][k][k]` (odd `k`) and `bias` `[cout]`.
    pub fn new(weight: &[f32], bias: &[f32], cin: usize, k: usize) -> ConvLayer {
        let cout = bias.len();
        let kk = cin * k * k;
        assert!(k % 2 == 1, "convolutions have odd sizes, not {k}");
        assert_eq!(weight.len(), cout * kk, "weights are [{cout}][{cin}][{k}][{k}]");
        let blocks = cout.div_ceil(MR);
        let mut packed = vec![0f32; blocks * kk * MR];
        for co in 0..cout {
            let (b, j) = (co / MR, co % MR);
            for (t, &v) in weight[co * kk..(co + 1) * kk].iter().enumerate() {
                packed[(b * kk + t) * MR + j] = v;
            }
        }
        let mut padded_bias = bias.to_vec();
        padded_bias.resize(blocks * MR, 0.0);
        ConvLayer { cout, cin, k, packed, bias: padded_bias }
    }

    /// The layer whose output is this one's input gradient: transposed channels, flipped
    /// taps, no bias (for "same" zero padding the input gradient is this convolution of
    /// the output gradient).
    pub fn transposed(weight: &[f32], cout: usize, cin: usize, k: usize) -> ConvLayer {
        let k2 = k * k;
        let mut t = vec![0f32; weight.len()];
        for co in 0..cout {
            for ci in 0..cin {
                for n in 0..k2 {
                    t[(ci * cout + co) * k2 + (k2 - 1 - n)] = weight[(co * cin + ci) * k2 + n];
                }
            }
        }
        ConvLayer::new(&t, &vec![0.0; cin], cout, k)
    }

    /// Output channels.
    pub fn cout(&self) -> usize {
        self.cout
    }

    /// Input channels.
    pub fn cin(&self) -> usize {
        self.cin
    }

    /// Multiply-adds ×2 per pixel.
    pub fn flops_per_pixel(&self) -> usize {
        2 * self.cout * self.cin * self.k * self.k
    }
}

/// `c` planes of `w × h` (`input`) zero-padded by `r` each side, written into `buf`
/// (resized). Channels are copied in parallel, and only the border is zeroed.
fn pad_into(buf: &mut Vec<f32>, input: &[f32], c: usize, w: usize, h: usize, r: usize) {
    let (pw, ph) = (w + 2 * r, h + 2 * r);
    // Every value is written below (border rows and columns, then the interior), so a
    // reused buffer of the right length needs no clearing.
    buf.resize(c * pw * ph, 0.0);
    buf.par_chunks_mut(pw * ph).zip(input.par_chunks(w * h)).for_each(|(dst, src)| {
        dst[..r * pw].fill(0.0);
        dst[(h + r) * pw..].fill(0.0);
        for y in 0..h {
            let row = &mut dst[(y + r) * pw..][..pw];
            row[..r].fill(0.0);
            row[r..r + w].copy_from_slice(&src[y * w..][..w]);
            row[r + w..].fill(0.0);
        }
    });
}

/// Rows `y0 − r .. y1 + r` of `c` planes of `w × h` (`input`), zero outside the plane,
/// each row zero-padded by `r` each side, written into `buf` (resized, with `2r` zeros
/// after): the padded input of output rows `y0..y1`.
#[allow(clippy::too_many_arguments)]
fn pad_rows(buf: &mut Vec<f32>, input: &[f32], c: usize, w: usize, h: usize, r: usize, y0: usize, y1: usize) {
    pad_rows_with(buf, c, w, h, r, y0, y1, |ch, y, dst| dst.copy_from_slice(&input[(ch * h + y) * w..][..w]));
}

/// [`pad_rows`] of planes that `row(channel, y, dst)` writes, `w` values at a time.
#[allow(clippy::too_many_arguments)]
fn pad_rows_with(
    buf: &mut Vec<f32>,
    c: usize,
    w: usize,
    h: usize,
    r: usize,
    y0: usize,
    y1: usize,
    row_of: impl Fn(usize, usize, &mut [f32]),
) {
    let (pw, rows) = (w + 2 * r, y1 - y0 + 2 * r);
    // Every value is written below, so a reused buffer of the right length needs no
    // clearing. The last plane is followed by 2r zeros, read (times dropped columns) by
    // flat segments.
    buf.resize(c * rows * pw + 2 * r, 0.0);
    buf[c * rows * pw..].fill(0.0);
    for (ch, dst) in buf[..c * rows * pw].chunks_mut(rows * pw).enumerate() {
        for (j, row) in dst.chunks_mut(pw).enumerate() {
            match (y0 + j).checked_sub(r).filter(|&y| y < h) {
                Some(y) => {
                    row[..r].fill(0.0);
                    row_of(ch, y, &mut row[r..r + w]);
                    row[r + w..].fill(0.0);
                }
                None => row.fill(0.0),
            }
        }
    }
}

/// Output rows per parallel task of a convolution: the task pads just its own input rows
/// ([`pad_rows`]), so no padded copy of a whole (possibly huge) input is ever held.
/// At least 8 rows and ~2048 pixels, so a narrow plane's task is not all edges.
fn band_rows(w: usize) -> usize {
    (2048 / w.max(1)).max(8)
}

/// A raw pointer that rows written by different threads share; each row is written by
/// exactly one task.
#[derive(Clone, Copy)]
struct RowsPtr(*mut f32);
unsafe impl Send for RowsPtr {}
unsafe impl Sync for RowsPtr {}

impl RowsPtr {
    /// The pointer (a method, so closures capture the `Sync` wrapper, not the field).
    fn get(self) -> *mut f32 {
        self.0
    }
}

/// `layer` applied to `input` with zero padding, so the output has the input's size;
/// ReLU when `relu`.
pub fn conv(input: &Planes, layer: &ConvLayer, relu: bool) -> Planes {
    assert_eq!(input.c, layer.cin, "a {}-channel layer given {} channels", layer.cin, input.c);
    Planes::from_vec(layer.cout, input.w, input.h, conv_batch(&input.data, 1, input.w, input.h, layer, relu))
}

/// [`conv`] of `up_nearest(coarse).concat(skip)` (a U-Net decoder's input) without
/// building it: each task upsamples and stacks just the rows it reads. The same sums as
/// [`conv`] of the built planes, bit for bit.
pub fn conv_up_concat(coarse: &Planes, skip: &Planes, layer: &ConvLayer, relu: bool) -> Planes {
    let (w, h, cc) = (skip.w, skip.h, coarse.c);
    assert_eq!((coarse.w * 2, coarse.h * 2), (w, h), "a half-size coarse input");
    assert_eq!(cc + skip.c, layer.cin, "a {}-channel layer given {} channels", layer.cin, cc + skip.c);
    if layer.cout * w * h == 0 {
        return Planes::from_vec(layer.cout, w, h, Vec::new());
    }
    let r = (layer.k - 1) / 2;
    let mut out = super::buffers::with_capacity(layer.cout * w * h);
    let (isa, pw, band) = (Isa::detect(), w + 2 * r, band_rows(w));
    let ptr = RowsPtr(out.as_mut_ptr());
    let row_of = |ch: usize, y: usize, dst: &mut [f32]| {
        if ch < cc {
            let src = &coarse.data[(ch * coarse.h + y / 2) * coarse.w..][..coarse.w];
            for (pair, &v) in dst.chunks_mut(2).zip(src) {
                pair.fill(v);
            }
        } else {
            dst.copy_from_slice(&skip.data[((ch - cc) * h + y) * w..][..w]);
        }
    };
    (0..h.div_ceil(band)).into_par_iter().for_each_init(<(Vec<f32>, Vec<f32>)>::default, |(buf, scratch), t| {
        let (y0, y1) = (t * band, (t * band + band).min(h));
        pad_rows_with(buf, layer.cin, w, h, r, y0, y1, row_of);
        let job = Job { src: buf, layer, w, h, pw, ph: y1 - y0 + 2 * r, y0, relu, isa };
        // SAFETY: rows y0..y1 of every output plane are written by this task only, inside
        // the buffer's capacity; `out` outlives the loop.
        unsafe { job.rows(y0..y1, ptr.get(), scratch) }
    });
    // SAFETY: every row of every channel was written above.
    unsafe { out.set_len(layer.cout * w * h) };
    Planes::from_vec(layer.cout, w, h, out)
}

/// [`conv`] of `items` consecutive images of `cin` planes of `w × h` each: their outputs,
/// one after the other.
pub fn conv_batch(input: &[f32], items: usize, w: usize, h: usize, layer: &ConvLayer, relu: bool) -> Vec<f32> {
    let (n_in, n_out) = (layer.cin * w * h, layer.cout * w * h);
    assert_eq!(input.len(), items * n_in, "{items} images of {}×{h}×{w}", layer.cin);
    let mut out = super::buffers::with_capacity(items * n_out);
    if items * n_out == 0 {
        return out;
    }
    let r = (layer.k - 1) / 2;
    let (isa, pw, band) = (Isa::detect(), w + 2 * r, band_rows(w));
    let bands = h.div_ceil(band);
    let ptr = RowsPtr(out.as_mut_ptr());
    // One task per band of rows of one image, so a batch of small images (training
    // patches at the coarse scales) still gives every thread work.
    (0..items * bands).into_par_iter().for_each_init(<(Vec<f32>, Vec<f32>)>::default, |(buf, scratch), t| {
        let (i, y0) = (t / bands, t % bands * band);
        let y1 = (y0 + band).min(h);
        let item = &input[i * n_in..][..n_in];
        let job = if r == 0 {
            // A 1×1 convolution reads its input in place.
            Job { src: item, layer, w, h, pw, ph: h, y0: 0, relu, isa }
        } else {
            pad_rows(buf, item, layer.cin, w, h, r, y0, y1);
            Job { src: buf, layer, w, h, pw, ph: y1 - y0 + 2 * r, y0, relu, isa }
        };
        // SAFETY: rows y0..y1 of every output plane of item `i` are written by this task
        // only, inside the buffer's capacity; `out` outlives the loop.
        unsafe { job.rows(y0..y1, ptr.get().wrapping_add(i * n_out), scratch) }
    });
    // SAFETY: every row of every channel of every item was written above (each path
    // writes columns 0..w of its rows).
    unsafe { out.set_len(items * n_out) };
    out
}

struct Job<'a> {
    /// Zero-padded input planes, `pw × ph` each, from output row `y0`'s first input row.
    src: &'a [f32],
    layer: &'a ConvLayer,
    w: usize,
    h: usize,
    pw: usize,
    ph: usize,
    /// The output row `src`'s first rows belong to.
    y0: usize,
    relu: bool,
    isa: Isa,
}

/// Evaluates `$body` with the constant `$M` equal to `$m`, one of the listed values (the
/// last one when no other matches), so micro-kernels get their block sizes at compile time.
macro_rules! with_const {
    ($m:expr, $M:ident => $body:expr, [$($n:literal)*] else $last:literal) => {
        match $m {
            $($n => {
                const $M: usize = $n;
                $body
            })*
            _ => {
                const $M: usize = $last;
                $body
            }
        }
    };
}

impl Job<'_> {
    /// Output rows `ys` of every channel (`scratch`: a reusable buffer).
    ///
    /// # Safety
    /// `out` points at `cout × h × w` floats, `ys` lie below `h` and inside `src`, and no
    /// other thread writes these rows.
    unsafe fn rows(&self, ys: Range<usize>, out: *mut f32, scratch: &mut Vec<f32>) {
        #[cfg(target_arch = "x86_64")]
        if self.isa == Isa::Avx512 {
            // SAFETY: the CPU has the instructions (detected); the caller's contract.
            return unsafe { self.rows_avx512(ys, out, scratch) };
        }
        let _ = scratch;
        for y in ys {
            #[cfg(target_arch = "x86_64")]
            if self.isa == Isa::Avx2 {
                // SAFETY: as above.
                unsafe { self.row_avx2(y, out) };
                continue;
            }
            // SAFETY: the caller's contract.
            unsafe { self.row_scalar(y, out, 0) }
        }
    }

    /// Columns `from..w` of row `y`, one value at a time, in the canonical order.
    ///
    /// # Safety
    /// As [`Job::row`].
    unsafe fn row_scalar(&self, y: usize, out: *mut f32, from: usize) {
        let l = self.layer;
        let (k, kk, plane) = (l.k, l.cin * l.k * l.k, self.pw * self.ph);
        for co in 0..l.cout {
            let panel = &l.packed[(co / MR) * kk * MR + co % MR..];
            for x in from..self.w {
                let mut acc = l.bias[co];
                let mut t = 0;
                for ci in 0..l.cin {
                    for ky in 0..k {
                        let row = &self.src[ci * plane + (y - self.y0 + ky) * self.pw + x..];
                        for &v in &row[..k] {
                            acc = v.mul_add(panel[t * MR], acc);
                            t += 1;
                        }
                    }
                }
                let v = if self.relu { acc.max(0.0) } else { acc };
                // SAFETY: inside the buffer (caller's contract).
                unsafe { *out.add((co * self.h + y) * self.w + x) = v };
            }
        }
    }

    /// Rows `ys` in segments of up to 16 pixels, taken `NV` at a time in row-major order
    /// whatever the width: a 12-pixel-wide plane fills 12 of 16 lanes, not 12 of 48.
    /// Narrow planes go flat: segments run on across row ends in the padded rows, whose
    /// `2r` extra columns are computed and dropped (24 columns fill 24 of every 26 lanes
    /// instead of 24 of 32); with `r > 0` the sums then wait in `scratch`, in rows of
    /// `pw`. Each output value is the same sum either way.
    ///
    /// # Safety
    /// As [`Job::rows`], and AVX-512F is available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn rows_avx512(&self, ys: Range<usize>, out: *mut f32, scratch: &mut Vec<f32>) {
        const NV: usize = 3;
        let l = self.layer;
        let (w, h, pw) = (self.w, self.h, self.pw);
        let (k2, kk, plane) = (l.k * l.k, l.cin * l.k * l.k, pw * self.ph);
        let rows = ys.len();
        let mask = |left: usize| if left >= 16 { u16::MAX } else { (1u16 << left) - 1 };
        let flat = pw == w || 16 * w.div_ceil(16) > pw + pw / 16;
        let first = (ys.start - self.y0) * pw;
        let (segments, dst, out_plane): (Vec<Segment>, *mut f32, usize) = if !flat {
            let segments = ys
                .clone()
                .flat_map(|y| {
                    (0..w).step_by(16).map(move |x| Segment {
                        src: (y - self.y0) * pw + x,
                        dst: y * w + x,
                        mask: mask(w - x),
                    })
                })
                .collect();
            (segments, out, w * h)
        } else {
            let n = rows * pw;
            // With r = 0 the flat rows are the output's own; else they go to `scratch`.
            let (dst, base) = if pw == w {
                (out, ys.start * w)
            } else {
                scratch.resize(l.cout.next_multiple_of(MR) * n, 0.0);
                (scratch.as_mut_ptr(), 0)
            };
            let segments =
                (0..n).step_by(16).map(|q| Segment { src: first + q, dst: base + q, mask: mask(n - q) }).collect();
            (segments, dst, if pw == w { w * h } else { n })
        };
        // Input channels go through in chunks of about 144 terms, so one chunk's input rows
        // and weights stay in L1 across the output-channel blocks. The partial sums wait
        // in the output, so every value is still summed in the one canonical order.
        let chunk = 144usize.div_ceil(k2);
        for group in segments.chunks(NV) {
            // A short last group repeats its first segment with every lane masked off.
            let group: [Segment; NV] =
                std::array::from_fn(|i| group.get(i).copied().unwrap_or(Segment { mask: 0, ..group[0] }));
            for c0 in (0..l.cin).step_by(chunk) {
                let c1 = (c0 + chunk).min(l.cin);
                for b in 0..l.cout.div_ceil(MR) {
                    let m = (l.cout - b * MR).min(MR);
                    let a = Block {
                        src: self.src[c0 * plane..].as_ptr(),
                        panel: l.packed[(b * kk + c0 * k2) * MR..].as_ptr(),
                        bias: l.bias[b * MR..].as_ptr(),
                        dst: dst.wrapping_add(b * MR * out_plane),
                        out_plane,
                        channels: c1 - c0,
                        first: c0 == 0,
                        last: c1 == l.cin,
                    };
                    // SAFETY: masked reads stay inside the padded planes (flat segments
                    // read up to 2r floats past a plane: the next plane's zero rows, or
                    // the zeros after the last); writes (and the reads of partial sums)
                    // stay in the group's rows of channels b·MR.. + m, masked.
                    unsafe { with_const!(m, M => block_avx512::<M, NV>(self, &a, &group), [8 7 6 5 4 3 2] else 1) };
                }
            }
        }
        if flat && pw != w {
            for c in 0..l.cout {
                for (j, y) in ys.clone().enumerate() {
                    // SAFETY: row y of channel c lies in `out` (caller's contract); the
                    // scratch row was written above.
                    unsafe {
                        std::ptr::copy_nonoverlapping(
                            scratch.as_ptr().add(c * out_plane + j * pw),
                            out.add((c * h + y) * w),
                            w,
                        )
                    };
                }
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn row_avx2(&self, y: usize, out: *mut f32) {
        use std::arch::x86_64::*;
        const NR: usize = 8;
        let l = self.layer;
        let kk = l.cin * l.k * l.k;
        for x in (0..self.w).step_by(NR) {
            let left = (self.w - x).min(NR) as i32;
            let mask = _mm256_cmpgt_epi32(_mm256_set1_epi32(left), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
            for b in 0..l.cout.div_ceil(MR) {
                let m = (l.cout - b * MR).min(MR);
                let a = Block {
                    src: self.src[((y - self.y0) * self.pw + x)..].as_ptr(),
                    panel: l.packed[b * kk * MR..].as_ptr(),
                    bias: l.bias[b * MR..].as_ptr(),
                    dst: out.wrapping_add((b * MR * self.h + y) * self.w + x),
                    out_plane: self.w * self.h,
                    channels: l.cin,
                    first: true,
                    last: true,
                };
                // SAFETY: unmasked reads stay inside the padded planes; writes stay in
                // row y of channels b·MR.. + m, masked to the columns < w.
                unsafe {
                    if left == NR as i32 {
                        with_const!(m, M => block_avx2::<M, false>(self, &a, mask), [8 7 6 5 4 3 2] else 1)
                    } else {
                        with_const!(m, M => block_avx2::<M, true>(self, &a, mask), [8 7 6 5 4 3 2] else 1)
                    }
                };
            }
        }
    }
}

/// One micro-kernel block's pointers.
struct Block {
    /// Padded input at channel 0 (AVX-512: row 0, column 0 of the job's rows; AVX2: the
    /// block's first padded row and column).
    src: *const f32,
    /// The block's weight panel `[cin·k·k][MR]`.
    panel: *const f32,
    /// The block's `MR` biases.
    bias: *const f32,
    /// Output at the block's first channel (AVX-512: row 0, column 0; AVX2: the block's
    /// row and column).
    dst: *mut f32,
    /// Floats between output channels.
    out_plane: usize,
    /// Input channels this call sums (from `src`'s first).
    channels: usize,
    /// The sums start at the bias (else at the partial sums in `dst`).
    first: bool,
    /// The sums are complete: apply the ReLU.
    last: bool,
}

/// Up to 16 consecutive output pixels of one row, as offsets from [`Block::src`] and
/// [`Block::dst`].
#[derive(Clone, Copy)]
struct Segment {
    /// Offset of the segment's first padded input (tap 0, 0) in a padded plane.
    src: usize,
    /// Offset of its first output in an output plane.
    dst: usize,
    /// Lanes inside the plane.
    mask: u16,
}

/// `M` output channels × `NV` segments of 16 pixels (each under its mask).
///
/// # Safety
/// AVX-512F is available; `a`'s pointers are valid for the masked reads and writes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn block_avx512<const M: usize, const NV: usize>(job: &Job, a: &Block, seg: &[Segment; NV]) {
    use std::arch::x86_64::*;
    let (k, pw, plane) = (job.layer.k, job.pw, job.pw * job.ph);
    unsafe {
        let mut acc = [[_mm512_setzero_ps(); NV]; M];
        for (j, row) in acc.iter_mut().enumerate() {
            if a.first {
                *row = [_mm512_set1_ps(*a.bias.add(j)); NV];
            } else {
                let dst = a.dst.add(j * a.out_plane);
                for (i, v) in row.iter_mut().enumerate() {
                    *v = _mm512_maskz_loadu_ps(seg[i].mask, dst.add(seg[i].dst));
                }
            }
        }
        let mut wp = a.panel;
        for ci in 0..a.channels {
            for ky in 0..k {
                let row = a.src.add(ci * plane + ky * pw);
                for kx in 0..k {
                    let mut v = [_mm512_setzero_ps(); NV];
                    for (i, vi) in v.iter_mut().enumerate() {
                        *vi = _mm512_maskz_loadu_ps(seg[i].mask, row.add(seg[i].src + kx));
                    }
                    for (j, accj) in acc.iter_mut().enumerate() {
                        let wv = _mm512_set1_ps(*wp.add(j));
                        for i in 0..NV {
                            accj[i] = _mm512_fmadd_ps(v[i], wv, accj[i]);
                        }
                    }
                    wp = wp.add(MR);
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (j, accj) in acc.iter().enumerate() {
            let dst = a.dst.add(j * a.out_plane);
            for i in 0..NV {
                let o = if job.relu && a.last { _mm512_max_ps(accj[i], zero) } else { accj[i] };
                _mm512_mask_storeu_ps(dst.add(seg[i].dst), seg[i].mask, o);
            }
        }
    }
}

/// `M` output channels × 8 pixels; only the lanes of `mask` (the columns < w) when
/// `MASKED`.
///
/// # Safety
/// AVX2 and FMA are available; `a`'s pointers are valid for the unmasked lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_avx2<const M: usize, const MASKED: bool>(job: &Job, a: &Block, mask: std::arch::x86_64::__m256i) {
    use std::arch::x86_64::*;
    let (k, cin, pw, plane) = (job.layer.k, a.channels, job.pw, job.pw * job.ph);
    unsafe {
        let mut acc = [_mm256_setzero_ps(); M];
        for (j, v) in acc.iter_mut().enumerate() {
            *v = _mm256_set1_ps(*a.bias.add(j));
        }
        let mut wp = a.panel;
        for ci in 0..cin {
            for ky in 0..k {
                let row = a.src.add(ci * plane + ky * pw);
                for kx in 0..k {
                    let v = if MASKED { _mm256_maskload_ps(row.add(kx), mask) } else { _mm256_loadu_ps(row.add(kx)) };
                    for (j, s) in acc.iter_mut().enumerate() {
                        *s = _mm256_fmadd_ps(v, _mm256_set1_ps(*wp.add(j)), *s);
                    }
                    wp = wp.add(MR);
                }
            }
        }
        for (j, &s) in acc.iter().enumerate() {
            let o = if job.relu { _mm256_max_ps(s, _mm256_setzero_ps()) } else { s };
            if MASKED {
                _mm256_maskstore_ps(a.dst.add(j * a.out_plane), mask, o);
            } else {
                _mm256_storeu_ps(a.dst.add(j * a.out_plane), o);
            }
        }
    }
}

/// The weight gradient of a "same" convolution, `[cout][cin][k][k]`: for each tap, the
/// sum over items and pixels of `grad[co]·input[ci]` shifted by the tap. `input` and
/// `grad` hold `items` consecutive images of `cin` and `cout` planes of `w × h`.
#[allow(clippy::too_many_arguments)]
pub fn weight_gradient(
    input: &[f32],
    grad: &[f32],
    items: usize,
    w: usize,
    h: usize,
    cin: usize,
    cout: usize,
    k: usize,
) -> Vec<f32> {
    weight_gradient_on(Isa::detect(), input, grad, items, w, h, cin, cout, k)
}

/// [`weight_gradient`] on the given instruction set.
#[allow(clippy::too_many_arguments)]
fn weight_gradient_on(
    isa: Isa,
    input: &[f32],
    grad: &[f32],
    items: usize,
    w: usize,
    h: usize,
    cin: usize,
    cout: usize,
    k: usize,
) -> Vec<f32> {
    let (r, k2, plane) = (k.saturating_sub(1) / 2, k * k, w * h);
    assert_eq!(input.len(), items * cin * plane, "input of {items} images of {cin}×{h}×{w}");
    assert_eq!(grad.len(), items * cout * plane, "gradient of {items} images of {cout}×{h}×{w}");
    // Every plane is laid out in rows of `pw` floats: the input zero-padded, the gradient
    // with `2r` zero columns. Gradient pixel `p = y·pw + x` then meets padded input
    // `p + ky·pw + kx` for tap (ky, kx), so rows form one flat run and vectors cross row
    // ends: a 24-pixel-wide patch fills 24 of every 26 lanes, not 24 of 32. The zero
    // columns add nothing. A 1×1 convolution uses both planes in place.
    let (pw, ph) = (w + 2 * r, h + 2 * r);
    let (splane, gplane) = (pw * ph, pw * h);
    let src: Cow<[f32]> = if r == 0 {
        Cow::Borrowed(input)
    } else {
        let mut pad = Vec::new();
        pad_into(&mut pad, input, items * cin, w, h, r);
        // The last plane's last taps read `2r` floats past it (times zero gradient).
        pad.resize(pad.len() + 2 * r, 0.0);
        Cow::Owned(pad)
    };
    #[cfg(target_arch = "x86_64")]
    if k == 3 && cout > 16 && isa != Isa::Scalar {
        return by_channel::weight_gradient(isa, &src, grad, by_channel::Dims { items, w, h, cin, cout });
    }
    let g: Cow<[f32]> = if r == 0 {
        Cow::Borrowed(grad)
    } else {
        let mut g = vec![0f32; items * cout * gplane];
        g.par_chunks_mut(pw).zip(grad.par_chunks(w)).for_each(|(d, s)| d[..w].copy_from_slice(s));
        Cow::Owned(g)
    };
    // Register blocks: 3 output channels × 1 input channel × 9 taps for 3×3, 4 × 6 for
    // 1×1 (27 and 24 accumulators: more FMAs per load, which bounds these loops), each
    // summed as 16 lanes kept in memory between runs of pixels, so a run's planes stay in
    // cache while every block uses them. One task per output-channel block
    // owns its values and sums items, runs and lanes in a fixed order, so results do not
    // depend on threads.
    let (mb, nb) = if k == 1 { (4, 6) } else { (3, 1) };
    let (co_blocks, ci_blocks) = (cout.div_ceil(mb), cin.div_ceil(nb));
    let block = mb * nb * k2;
    let per_block = ci_blocks * block;
    let run = (32768 / cin.max(1)).next_multiple_of(16).clamp(16, gplane.max(16));
    // One task per group of output-channel blocks and half of the images: a run of
    // pixels of every input channel is read from memory once per group (the runs of a
    // large 1×1 layer would otherwise stream from memory once per block), and the halves
    // keep both threads busy when there are few groups. Group sizes (from the thread
    // count and ~256 KiB of lanes) change no value's order of summation; each value sums
    // its half's images, runs and lanes in one fixed order, then the halves in order.
    let group = co_blocks.div_ceil(2 * rayon::current_num_threads()).clamp(1, (65536 / (per_block * 16)).max(1));
    let groups = co_blocks.div_ceil(group);
    let halves = items.clamp(1, 2);
    let partial: Vec<Vec<f32>> = (0..groups * halves)
        .into_par_iter()
        .map(|t| {
            let (gr, half) = (t / halves, t % halves);
            let cbs = gr * group..((gr + 1) * group).min(co_blocks);
            let images = half * items / halves..(half + 1) * items / halves;
            let mut lanes = vec![0f32; cbs.len() * per_block * 16];
            for (i, p0) in images.flat_map(|i| (0..gplane).step_by(run).map(move |p0| (i, p0))) {
                let pixels = p0..(p0 + run).min(gplane);
                for (cb, lanes) in cbs.clone().zip(lanes.chunks_mut(per_block * 16)) {
                    let co = cb * mb;
                    let m = (cout - co).min(mb);
                    for (cj, acc) in lanes.chunks_mut(block * 16).enumerate() {
                        let ci = cj * nb;
                        let n = (cin - ci).min(nb);
                        let t = Taps {
                            src: &src[(i * cin + ci) * splane..],
                            grad: &g[(i * cout + co) * gplane..][..m * gplane],
                            splane,
                            gplane,
                            pw,
                        };
                        // The block shapes the vector kernels are built for; others go scalar.
                        #[allow(unused_macros)] // unused off x86-64
                        macro_rules! blocks {
                            ($sum:ident) => {
                                match (m, n, k) {
                                    (1..=3, 1, 3) => {
                                        with_const!(m, M => t.$sum::<M, 1, 3>(pixels.clone(), nb, acc), [3 2] else 1)
                                    }
                                    (1..=4, 1..=6, 1) => with_const!(m, M => with_const!(n, N =>
                                        t.$sum::<M, N, 1>(pixels.clone(), nb, acc), [6 5 4 3 2] else 1), [4 3 2] else 1),
                                    _ => t.sum_scalar(m, n, k, nb, pixels.clone(), acc),
                                }
                            };
                        }
                        #[cfg(target_arch = "x86_64")]
                        match isa {
                            // SAFETY: AVX-512F is available (detected).
                            Isa::Avx512 => unsafe { blocks!(sum_avx512) },
                            // SAFETY: AVX2 and FMA are available (detected).
                            Isa::Avx2 => unsafe { blocks!(sum_avx2) },
                            Isa::Scalar => t.sum_scalar(m, n, k, nb, pixels.clone(), acc),
                        }
                        #[cfg(not(target_arch = "x86_64"))]
                        t.sum_scalar(m, n, k, nb, pixels.clone(), acc);
                    }
                }
            }
            lanes
        })
        .collect();
    let blocks: Vec<f32> = partial
        .chunks(halves)
        .flat_map(|halves| {
            let mut lanes = halves[0].clone();
            for other in &halves[1..] {
                lanes.iter_mut().zip(other).for_each(|(a, b)| *a += b);
            }
            lanes
                .chunks_exact(16)
                .map(|lane| {
                    // A pairwise tree, which vectorises (a running sum is a 16-add
                    // latency chain per value, a fifth of the whole on narrow layers).
                    let mut v: [f32; 16] = lane.try_into().expect("16 lanes");
                    for half in [8, 4, 2, 1] {
                        for i in 0..half {
                            v[i] += v[i + half];
                        }
                    }
                    v[0]
                })
                .collect::<Vec<f32>>()
        })
        .collect();
    // Blocks are [co block][ci block][mb][nb][k²]; the result is [cout][cin][k²].
    let mut out = vec![0f32; cout * cin * k2];
    for co in 0..cout {
        for ci in 0..cin {
            let block = (co / mb) * ci_blocks + ci / nb;
            let from = ((block * mb + co % mb) * nb + ci % nb) * k2;
            out[(co * cin + ci) * k2..][..k2].copy_from_slice(&blocks[from..from + k2]);
        }
    }
    out
}

/// One weight-gradient task's planes, laid out as in [`weight_gradient_on`]: input
/// channels from `src`'s start, `splane` floats apart, and `m` output channels'
/// gradients, `gplane` floats apart.
struct Taps<'a> {
    src: &'a [f32],
    grad: &'a [f32],
    splane: usize,
    gplane: usize,
    pw: usize,
}

/// Defines a vector [`Taps`] kernel: the sums of [`Taps::sum_scalar`] for `M` gradients,
/// `N ≤ nb` input channels and `K × K` taps, `$lanes` pixels at a time into the first
/// `$lanes` of 16 lanes. One body for every instruction set; what differs is passed in:
/// the vector type's zero, the mask of the `left` pixels still to go, a masked load, a
/// fused multiply-add, and the accumulators' load and store.
macro_rules! taps_kernel {
    (
        $(#[$attr:meta])* $name:ident, $lanes:literal, $zero:expr,
        mask |$left:ident| $mask:expr,
        load |$ptr:ident, $m:ident| $load:expr,
        $fma:path,
        get |$q:ident| $get:expr,
        put |$d:ident, $v:ident| $put:expr $(,)?
    ) => {
        $(#[$attr])*
        #[allow(clippy::needless_range_loop)] // indices name the accumulator block's axes
        unsafe fn $name<const M: usize, const N: usize, const K: usize>(
            &self,
            pixels: Range<usize>,
            nb: usize,
            out: &mut [f32],
        ) {
            use std::arch::x86_64::*;
            assert!(self.fits(M, N, K, &pixels, nb, out.len()), "a weight-gradient block outside its planes");
            let at = |j: usize, c: usize, ky: usize, kx: usize| (((j * nb + c) * K + ky) * K + kx) * 16;
            let (pw, sp, gp) = (self.pw, self.splane, self.gplane);
            // SAFETY: masked lanes are not read; the rest stay inside the slices (checked).
            unsafe {
                let mut acc = [[[[$zero; K]; K]; N]; M];
                for j in 0..M {
                    for c in 0..N {
                        for ky in 0..K {
                            for kx in 0..K {
                                let $q = out.as_ptr().add(at(j, c, ky, kx));
                                acc[j][c][ky][kx] = $get;
                            }
                        }
                    }
                }
                for p in pixels.clone().step_by($lanes) {
                    let $left = pixels.end - p;
                    let $m = $mask;
                    let mut g = [$zero; M];
                    for (j, gv) in g.iter_mut().enumerate() {
                        let $ptr = self.grad.as_ptr().add(j * gp + p);
                        *gv = $load;
                    }
                    for c in 0..N {
                        for ky in 0..K {
                            let row = self.src.as_ptr().add(c * sp + ky * pw + p);
                            for kx in 0..K {
                                let $ptr = row.add(kx);
                                let v = $load;
                                for j in 0..M {
                                    acc[j][c][ky][kx] = $fma(g[j], v, acc[j][c][ky][kx]);
                                }
                            }
                        }
                    }
                }
                for j in 0..M {
                    for c in 0..N {
                        for ky in 0..K {
                            for kx in 0..K {
                                let ($d, $v) = (out.as_mut_ptr().add(at(j, c, ky, kx)), acc[j][c][ky][kx]);
                                $put;
                            }
                        }
                    }
                }
            }
        }
    };
}

impl Taps<'_> {
    /// Whether a block of `m` gradients × `n` input channels × `k²` taps over `pixels`
    /// stays inside the planes and an accumulator slice of `out` floats (lanes laid out
    /// for `nb`).
    fn fits(&self, m: usize, n: usize, k: usize, pixels: &Range<usize>, nb: usize, out: usize) -> bool {
        pixels.end <= self.gplane
            && self.grad.len() >= m * self.gplane
            && self.src.len() >= (n.max(1) - 1) * self.splane + pixels.end + (k - 1) * (self.pw + 1)
            && n <= nb
            && out >= m * nb * k * k * 16
    }

    /// Adds `Σ grad[j][p]·src[c][p + ky·pw + kx]` over `pixels` at each of the `k²` taps
    /// to lane 0 of `acc[((j·nb + c)·k² + tap)·16..]`.
    #[allow(clippy::too_many_arguments)]
    fn sum_scalar(&self, m: usize, n: usize, k: usize, nb: usize, pixels: Range<usize>, acc: &mut [f32]) {
        for j in 0..m {
            let g = &self.grad[j * self.gplane..][pixels.clone()];
            for c in 0..n {
                for ky in 0..k {
                    for kx in 0..k {
                        let src = &self.src[c * self.splane + ky * self.pw + kx..][pixels.clone()];
                        let s = g.iter().zip(src).map(|(a, b)| a * b).sum::<f32>();
                        acc[(((j * nb + c) * k + ky) * k + kx) * 16] += s;
                    }
                }
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    taps_kernel! {
        /// [`Taps::sum_scalar`] with AVX-512, 16 pixels at a time.
        ///
        /// # Safety
        /// AVX-512F is available.
        #[target_feature(enable = "avx512f")]
        sum_avx512, 16, _mm512_setzero_ps(),
        mask |left| if left >= 16 { u16::MAX } else { (1u16 << left) - 1 },
        load |ptr, mask| _mm512_maskz_loadu_ps(mask, ptr),
        _mm512_fmadd_ps,
        get |q| _mm512_loadu_ps(q),
        put |d, v| _mm512_storeu_ps(d, v),
    }

    #[cfg(target_arch = "x86_64")]
    taps_kernel! {
        /// [`Taps::sum_scalar`] with AVX2, 8 pixels at a time.
        ///
        /// # Safety
        /// AVX2 and FMA are available.
        #[target_feature(enable = "avx2,fma")]
        sum_avx2, 8, _mm256_setzero_ps(),
        mask |left| _mm256_cmpgt_epi32(_mm256_set1_epi32(left.min(8) as i32), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7)),
        load |ptr, mask| _mm256_maskload_ps(ptr, mask),
        _mm256_fmadd_ps,
        get |q| _mm256_loadu_ps(q),
        put |d, v| _mm256_storeu_ps(d, v),
    }
}

/// The weight gradient of 3×3 layers with more than 16 output channels, with the output
/// channels in the vector lanes: the gradient is transposed to channels-last once, and
/// each pixel then costs one aligned load per 16 output channels and one broadcast per
/// tap, against 27 fused multiply-adds (the pixel-vector kernels of [`Taps`] load every
/// tap's shifted row, mostly across cache lines). No lane is wasted at row ends, and each
/// value is one lane summed over images and pixels in order.
#[cfg(target_arch = "x86_64")]
mod by_channel {
    use super::super::simd::Isa;
    use rayon::prelude::*;

    /// A batch's sizes: `items` images of `w × h`, `cin` input and `cout` output channels.
    pub(super) struct Dims {
        pub items: usize,
        pub w: usize,
        pub h: usize,
        pub cin: usize,
        pub cout: usize,
    }

    /// `src`: `items·cin` zero-padded planes (`(w + 2) × (h + 2)`); `grad`: `items·cout`
    /// planes of `w × h`. Returns `[cout][cin][3][3]`.
    pub(super) fn weight_gradient(isa: Isa, src: &[f32], grad: &[f32], dims: Dims) -> Vec<f32> {
        let Dims { items, w, h, cin, cout } = dims;
        let lanes = if isa == Isa::Avx512 { 16 } else { 8 };
        let (plane, pw, splane, cp) = (w * h, w + 2, (w + 2) * (h + 2), cout.next_multiple_of(lanes));
        // The channels-last gradient `[item][pixel][cp]`, 64-byte aligned so that no load
        // crosses a cache line.
        let mut store = vec![0f32; items * plane * cp + 16];
        let skip = store.as_ptr().align_offset(64).min(16);
        let gt = &mut store[skip..skip + items * plane * cp];
        gt.par_chunks_mut(plane * cp).enumerate().for_each(|(i, dst)| {
            for co in 0..cout {
                for (p, &v) in grad[(i * cout + co) * plane..][..plane].iter().enumerate() {
                    dst[p * cp + co] = v;
                }
            }
        });
        let gt = &*gt;
        // Blocks of up to 3 vectors of output channels (27 accumulators).
        let vecs = cp / lanes;
        let mv = if vecs % 3 == 0 || vecs > 4 { 3 } else { vecs.min(2) };
        let blocks: Vec<(usize, usize)> = (0..vecs).step_by(mv).map(|v| (v, (vecs - v).min(mv))).collect();
        // Tasks: a block × a group of input channels; rows go in runs of ~256 pixels, so
        // a run's gradient stays in L1 while each channel of the group uses it.
        let group = 4;
        let run = (256 / w.max(1)).max(1);
        let ci_groups = cin.div_ceil(group);
        let sums: Vec<Vec<f32>> = (0..blocks.len() * ci_groups)
            .into_par_iter()
            .map(|t| {
                let ((v0, m), c0) = (blocks[t / ci_groups], t % ci_groups * group);
                let channels = c0..(c0 + group).min(cin);
                let mut acc = vec![0f32; channels.len() * 3 * 9 * lanes];
                for i in 0..items {
                    for y0 in (0..h).step_by(run) {
                        let rows = y0..(y0 + run).min(h);
                        for (ci, acc) in channels.clone().zip(acc.chunks_mut(3 * 9 * lanes)) {
                            let job = Job {
                                gt: gt[i * plane * cp + v0 * lanes..].as_ptr(),
                                cp,
                                src: &src[(i * cin + ci) * splane..][..splane],
                                w,
                                pw,
                                rows: rows.clone(),
                            };
                            // SAFETY: the instructions are available (detected); `job`'s
                            // pointers cover `m` vectors of every pixel of the rows.
                            unsafe {
                                match isa {
                                    Isa::Avx512 => with_const!(m, M => job.sum_avx512::<M>(acc), [3 2] else 1),
                                    _ => with_const!(m, M => job.sum_avx2::<M>(acc), [3 2] else 1),
                                }
                            }
                        }
                    }
                }
                acc
            })
            .collect();
        let mut out = vec![0f32; cout * cin * 9];
        for (t, acc) in sums.iter().enumerate() {
            let ((v0, m), c0) = (blocks[t / ci_groups], t % ci_groups * group);
            for (n, acc) in acc.chunks(3 * 9 * lanes).enumerate() {
                let ci = c0 + n;
                for v in 0..m {
                    for tap in 0..9 {
                        for l in 0..lanes {
                            let co = (v0 + v) * lanes + l;
                            if co < cout && ci < cin {
                                out[(co * cin + ci) * 9 + tap] = acc[(v * 9 + tap) * lanes + l];
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// One call's operands: the channels-last gradient at pixel 0 of the block's first
    /// vector, one input channel's padded plane, and the rows to sum.
    struct Job<'a> {
        gt: *const f32,
        cp: usize,
        src: &'a [f32],
        w: usize,
        pw: usize,
        rows: std::ops::Range<usize>,
    }

    /// Defines a kernel adding, for `M` vectors of output channels and the 9 taps,
    /// `Σ gt[p][co]·src[p + tap]` over the job's rows to `acc[(v·9 + tap)·lanes + l]`.
    macro_rules! by_channel_kernel {
        ($(#[$attr:meta])* $name:ident, $lanes:literal, $load:ident, $store:ident, $set1:ident, $fma:ident) => {
            $(#[$attr])*
            #[allow(clippy::needless_range_loop)] // indices name the accumulator block's axes
            unsafe fn $name<const M: usize>(&self, acc: &mut [f32]) {
                use std::arch::x86_64::*;
                let (w, pw, cp) = (self.w, self.pw, self.cp);
                assert!(acc.len() >= M * 9 * $lanes && (self.rows.end + 1) * pw + w + 1 < self.src.len());
                // SAFETY: the gradient holds M vectors at every pixel of the rows (caller);
                // the largest source index is (rows.end + 1)·pw + w + 1 (checked).
                unsafe {
                    let mut a = [[$set1(0.0); 9]; M];
                    for v in 0..M {
                        for t in 0..9 {
                            a[v][t] = $load(acc.as_ptr().add((v * 9 + t) * $lanes));
                        }
                    }
                    let src = self.src.as_ptr();
                    for y in self.rows.clone() {
                        let g_row = self.gt.add(y * w * cp);
                        let s_row = src.add(y * pw);
                        for x in 0..w {
                            let mut g = [$set1(0.0); M];
                            for v in 0..M {
                                g[v] = $load(g_row.add(x * cp + v * $lanes));
                            }
                            for ky in 0..3 {
                                for kx in 0..3 {
                                    let s = $set1(*s_row.add(ky * pw + x + kx));
                                    for v in 0..M {
                                        a[v][ky * 3 + kx] = $fma(g[v], s, a[v][ky * 3 + kx]);
                                    }
                                }
                            }
                        }
                    }
                    for v in 0..M {
                        for t in 0..9 {
                            $store(acc.as_mut_ptr().add((v * 9 + t) * $lanes), a[v][t]);
                        }
                    }
                }
            }
        };
    }

    impl Job<'_> {
        by_channel_kernel! {
            /// 16 output channels per vector.
            ///
            /// # Safety
            /// AVX-512F is available.
            #[target_feature(enable = "avx512f")]
            sum_avx512, 16, _mm512_loadu_ps, _mm512_storeu_ps, _mm512_set1_ps, _mm512_fmadd_ps
        }

        by_channel_kernel! {
            /// 8 output channels per vector.
            ///
            /// # Safety
            /// AVX2 and FMA are available.
            #[target_feature(enable = "avx2,fma")]
            sum_avx2, 8, _mm256_loadu_ps, _mm256_storeu_ps, _mm256_set1_ps, _mm256_fmadd_ps
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use candle_core::{Device, Tensor};

    fn candle_conv(x: &[f32], wt: &[f32], b: &[f32], cin: usize, k: usize, w: usize, h: usize) -> Vec<f32> {
        let cout = b.len();
        let xt = Tensor::from_vec(x.to_vec(), (1, cin, h, w), &Device::Cpu).unwrap();
        let wtt = Tensor::from_vec(wt.to_vec(), (cout, cin, k, k), &Device::Cpu).unwrap();
        let bt = Tensor::from_vec(b.to_vec(), (1, cout, 1, 1), &Device::Cpu).unwrap();
        let y = xt.conv2d(&wtt, (k - 1) / 2, 1, 1, 1).unwrap().broadcast_add(&bt).unwrap();
        y.flatten_all().unwrap().to_vec1::<f32>().unwrap()
    }

    #[test]
    fn matches_candle_conv2d() {
        // Widths around the 8- and 32-pixel blocks, channels around the 8-channel panels.
        for (cin, cout, k, w, h) in [
            (3, 5, 3, 37, 6),
            (8, 4, 1, 16, 3),
            (27, 9, 3, 20, 5),
            (2, 3, 3, 5, 4),
            (16, 17, 3, 70, 3),
            (5, 8, 1, 33, 2),
        ] {
            let x = SplitMix64(1).centred(cin * w * h);
            let wt = SplitMix64(2).centred(cout * cin * k * k);
            let b = SplitMix64(3).centred(cout);
            let ours = conv(&Planes::from_vec(cin, w, h, x.clone()), &ConvLayer::new(&wt, &b, cin, k), true);
            let theirs = candle_conv(&x, &wt, &b, cin, k, w, h);
            for (i, (a, b)) in ours.data.iter().zip(&theirs).enumerate() {
                assert!((a - b.max(0.0)).abs() < 1e-5, "{cin}→{cout} k{k} {w}×{h} at {i}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn the_fused_decoder_input_gives_the_built_inputs_bits() {
        // Narrow (flat path) and wide planes, several bands, 3×3 and 1×1.
        for (cc, cs, cout, k, w, h) in [(6, 4, 5, 3, 12, 10), (16, 8, 12, 3, 64, 40), (5, 3, 7, 1, 20, 6)] {
            let coarse = Planes::from_vec(cc, w / 2, h / 2, SplitMix64(4).centred(cc * w * h / 4));
            let skip = Planes::from_vec(cs, w, h, SplitMix64(5).centred(cs * w * h));
            let cin = cc + cs;
            let layer =
                ConvLayer::new(&SplitMix64(6).centred(cout * cin * k * k), &SplitMix64(7).centred(cout), cin, k);
            let built = conv(&coarse.up_nearest().concat(&skip), &layer, true);
            let fused = conv_up_concat(&coarse, &skip, &layer, true);
            assert_eq!((fused.c, fused.w, fused.h), (cout, w, h));
            assert!(
                built.data.iter().zip(&fused.data).all(|(a, b)| a.to_bits() == b.to_bits()),
                "{cc}+{cs} k{k} {w}×{h}"
            );
        }
    }

    #[test]
    fn every_instruction_set_gives_the_same_bits() {
        // More input channels than one chunk, more rows than one band, a ragged last
        // block; widths that take the row-wise (45) and the flat (24, 12) AVX-512 paths.
        for (cin, cout, k, w, h) in [(20, 11, 3, 45, 11), (20, 11, 3, 24, 11), (7, 9, 3, 12, 5), (6, 5, 1, 12, 9)] {
            let r = (k - 1) / 2;
            let input = Planes::from_vec(cin, w, h, SplitMix64(7).centred(cin * w * h));
            let layer =
                ConvLayer::new(&SplitMix64(8).centred(cout * cin * k * k), &SplitMix64(9).centred(cout), cin, k);
            let bits = |p: &[f32]| p.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            let run = |isa: Isa| {
                let mut pad = Vec::new();
                pad_rows(&mut pad, &input.data, cin, w, h, r, 0, h);
                let mut out = Planes::zeros(cout, w, h);
                let job = Job { src: &pad, layer: &layer, w, h, pw: w + 2 * r, ph: h + 2 * r, y0: 0, relu: false, isa };
                // SAFETY: single-threaded; rows inside the buffer.
                unsafe { job.rows(0..h, out.data.as_mut_ptr(), &mut Vec::new()) };
                bits(&out.data)
            };
            let scalar = run(Isa::Scalar);
            assert_eq!(run(Isa::detect()), scalar, "{w}×{h}");
            // The banded, parallel path of `conv` too.
            assert_eq!(bits(&conv(&input, &layer, false).data), scalar, "{w}×{h}");
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                assert_eq!(run(Isa::Avx2), scalar, "{w}×{h}");
            }
        }
    }

    #[test]
    fn a_pixel_does_not_depend_on_where_the_plane_ends() {
        // The same 40×4 content seen whole and as its left 24 columns: identical bits.
        let (cin, cout) = (5, 6);
        let x = SplitMix64(4).centred(cin * 40 * 4);
        let layer = ConvLayer::new(&SplitMix64(5).centred(cout * cin * 9), &SplitMix64(6).centred(cout), cin, 3);
        let whole = conv(&Planes::from_vec(cin, 40, 4, x.clone()), &layer, false);
        let left: Vec<f32> = x.chunks(40).flat_map(|r| r[..24].to_vec()).collect();
        let part = conv(&Planes::from_vec(cin, 24, 4, left), &layer, false);
        for c in 0..cout {
            for y in 0..4 {
                // Column 23 saw zero padding in the part; the rest must agree exactly.
                for x in 0..23 {
                    assert_eq!(part.plane(c)[y * 24 + x].to_bits(), whole.plane(c)[y * 40 + x].to_bits());
                }
            }
        }
    }

    #[test]
    fn gradients_match_candle() {
        use candle_core::Var;
        // 3×3 and 1×1, channel counts around the register blocks.
        // More than 16 outputs take the channel-vector path (3 and 2 vectors with AVX-512).
        for (cin, cout, k, w, h) in
            [(5, 7, 3, 19, 6), (9, 6, 1, 21, 5), (3, 2, 3, 33, 2), (5, 37, 3, 19, 6), (6, 20, 3, 9, 7)]
        {
            let x = SplitMix64(11).centred(2 * cin * w * h);
            let wt = SplitMix64(12).centred(cout * cin * k * k);
            let g = SplitMix64(13).centred(2 * cout * w * h);
            // Candle's autograd: loss = Σ conv(x)·g.
            let xv = Var::from_vec(x.clone(), (2, cin, h, w), &Device::Cpu).unwrap();
            let wv = Var::from_vec(wt.clone(), (cout, cin, k, k), &Device::Cpu).unwrap();
            let gt = Tensor::from_vec(g.clone(), (2, cout, h, w), &Device::Cpu).unwrap();
            let y = xv.as_tensor().conv2d(wv.as_tensor(), (k - 1) / 2, 1, 1, 1).unwrap();
            let grads = (y * gt).unwrap().sum_all().unwrap().backward().unwrap();
            let dx = grads.get(xv.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let dw = grads.get(wv.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();

            let back = ConvLayer::transposed(&wt, cout, cin, k);
            let ours_dx = conv_batch(&g, 2, w, h, &back, false);
            let ours_dw = weight_gradient(&x, &g, 2, w, h, cin, cout, k);
            let mut checks = vec![("input", ours_dx, &dx), ("weight", ours_dw, &dw)];
            let scalar = weight_gradient_on(Isa::Scalar, &x, &g, 2, w, h, cin, cout, k);
            checks.push(("weight (scalar)", scalar, &dw));
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                checks.push(("weight (AVX2)", weight_gradient_on(Isa::Avx2, &x, &g, 2, w, h, cin, cout, k), &dw));
            }
            for (name, a, b) in checks {
                assert_eq!(a.len(), b.len());
                for (i, (a, b)) in a.iter().zip(b.iter()).enumerate() {
                    assert!(
                        (a - b).abs() < 1e-4 * (1.0 + b.abs()),
                        "{cin}→{cout} k{k} {name} gradient {i}: {a} vs {b}"
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod speed {
    use super::*;

    /// `cargo test --release --lib conv_throughput -- --ignored --nocapture`
    #[test]
    #[ignore = "a measurement, not a test"]
    fn conv_throughput() {
        for (cin, cout, k, w, h) in [
            (27, 16, 3, 1024, 512),
            (16, 16, 3, 1024, 512),
            (16, 32, 3, 512, 256),
            (32, 32, 3, 512, 256),
            (80, 32, 3, 512, 256),
            (48, 48, 3, 256, 128),
            (112, 48, 3, 256, 128),
            (64, 64, 3, 128, 64),
            (16, 26, 1, 1024, 512),
            (48, 26, 1, 96, 96),
            (26, 48, 1, 96, 96),
            (27, 16, 3, 96, 96),
        ] {
            let x = Planes::from_vec(cin, w, h, vec![0.5; cin * w * h]);
            let layer = ConvLayer::new(&vec![0.01f32; cout * cin * k * k], &vec![0.0f32; cout], cin, k);
            conv(&x, &layer, true);
            let t = std::time::Instant::now();
            let n = 5;
            for _ in 0..n {
                std::hint::black_box(conv(&x, &layer, true));
            }
            let s = t.elapsed().as_secs_f64() / n as f64;
            let flop = 2.0 * (cin * cout * k * k * w * h) as f64;
            println!("{cin:>3}→{cout:<3} {k}×{k} {w}×{h}: {:.1} GFLOP/s", flop / s / 1e9);
        }
    }
}

#[cfg(test)]
mod wgrad_speed {
    use super::*;

    #[test]
    #[ignore = "a measurement, not a test"]
    fn weight_gradient_throughput() {
        for (cin, cout, k, w) in [(27, 16, 3, 96), (16, 16, 3, 96), (80, 32, 3, 48), (48, 26, 1, 96)] {
            let x = vec![0.5; 6 * cin * w * w];
            let g = vec![0.5; 6 * cout * w * w];
            weight_gradient(&x, &g, 6, w, w, cin, cout, k);
            let t = std::time::Instant::now();
            for _ in 0..5 {
                std::hint::black_box(weight_gradient(&x, &g, 6, w, w, cin, cout, k));
            }
            let s = t.elapsed().as_secs_f64() / 5.0;
            let gflops = 2.0 * (cin * cout * k * k * 6 * w * w) as f64 / s / 1e9;
            println!("{cin}→{cout} k{k} 6×{w}²: {:.2} ms {gflops:.1} GFLOP/s", s * 1e3);
        }
    }
}
