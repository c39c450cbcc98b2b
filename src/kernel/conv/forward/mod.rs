//! The forward pass: a register-blocked direct convolution over zero-padded bands of rows.

use super::super::planes::{Planes, repeat_pairs};
use super::super::simd::{Isa, mask16};
use super::{ConvLayer, MR, winograd};
use rayon::prelude::*;
use std::ops::Range;

/// `c` planes of `w × h` read zero-padded by `r` pixels each side.
#[derive(Clone, Copy)]
struct Padded {
    c: usize,
    w: usize,
    h: usize,
    r: usize,
}

/// Rows `y0 − r .. y1 + r` of the planes `input`, zero outside the plane, each row
/// zero-padded by `r` each side, written into `buf` (resized, with `2r` zeros after): the
/// padded input of output rows `ys = y0..y1`.
fn pad_rows(buf: &mut Vec<f32>, input: &[f32], p: Padded, ys: Range<usize>) {
    let (w, h) = (p.w, p.h);
    pad_rows_with(buf, p, ys, |ch, y, dst| dst.copy_from_slice(&input[(ch * h + y) * w..][..w]));
}

/// [`pad_rows`] of planes that `row(channel, y, dst)` writes, `w` values at a time.
fn pad_rows_with(buf: &mut Vec<f32>, p: Padded, ys: Range<usize>, row_of: impl Fn(usize, usize, &mut [f32])) {
    let (Padded { c, w, h, r }, y0) = (p, ys.start);
    let (pw, rows) = (w + 2 * r, ys.len() + 2 * r);
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
// SAFETY: each row behind the pointer is written by one task only (see above).
unsafe impl Send for RowsPtr {}
// SAFETY: as for `Send`.
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
    conv_rows(layer, relu, (w, h), 0..h, |ch, y, dst| {
        if ch < cc {
            let src = &coarse.data[(ch * coarse.h + y / 2) * coarse.w..][..coarse.w];
            repeat_pairs(dst, src);
        } else {
            dst.copy_from_slice(&skip.data[((ch - cc) * h + y) * w..][..w]);
        }
    })
}

thread_local! {
    /// Each thread's padded rows and partial sums, kept from call to call: a stream's
    /// convolutions are many and small, and fresh buffers were zeroed anew for each.
    static BUFFERS: std::cell::RefCell<(Vec<f32>, Vec<f32>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// `f` of this thread's [`BUFFERS`]; fresh ones where they are in use (never, unless
/// `f` itself convolves).
fn with_buffers<T>(f: impl FnOnce(&mut Vec<f32>, &mut Vec<f32>) -> T) -> T {
    BUFFERS.with(|b| match b.try_borrow_mut() {
        Ok(mut b) => {
            let (buf, scratch) = &mut *b;
            f(buf, scratch)
        }
        Err(_) => f(&mut Vec::new(), &mut Vec::new()),
    })
}

/// Rows `out` of [`conv`] of `layer.cin` planes of `w × h` that are never built:
/// `row_of(channel, y, dst)` writes row `y` of a plane (`w` values) where a task reads
/// it, so a caller holding the rows in pieces (a stream's chunks) or as parts of other
/// planes (a decoder's upsampled input) hands them over without gathering them first,
/// and rows outside `out` (context, or zeros past the plane) cost no multiply-adds. Each
/// value is [`conv`]'s of the whole planes, bit for bit.
pub fn conv_rows(
    layer: &ConvLayer,
    relu: bool,
    (w, h): (usize, usize),
    out: Range<usize>,
    row_of: impl Fn(usize, usize, &mut [f32]) + Sync,
) -> Planes {
    assert!(out.start <= out.end && out.end <= h, "rows {out:?} of a plane {h} tall");
    let rows = out.len();
    if layer.cout * w * rows == 0 {
        return Planes::from_vec(layer.cout, w, rows, Vec::new());
    }
    let r = (layer.k - 1) / 2;
    let mut data = crate::kernel::buffers::with_capacity(layer.cout * w * rows);
    let (isa, pw, band) = (Isa::detect(), w + 2 * r, band_rows(w));
    let ptr = RowsPtr(data.as_mut_ptr());
    (0..rows.div_ceil(band)).into_par_iter().for_each(|t| {
        let (y0, y1) = (out.start + t * band, (out.start + t * band + band).min(out.end));
        with_buffers(|buf, scratch| {
            pad_rows_with(buf, Padded { c: layer.cin, w, h, r }, y0..y1, &row_of);
            let job = Job { src: buf, layer, w, h: rows, oy: out.start, pw, ph: y1 - y0 + 2 * r, y0, relu, isa };
            // SAFETY: rows y0..y1 of every output plane are written by this task only,
            // inside the buffer's capacity (`out`'s rows, from `oy`); `data` outlives the
            // loop.
            unsafe { job.rows(y0..y1, ptr.get(), scratch) }
        })
    });
    // SAFETY: every row of every channel was written above.
    unsafe { data.set_len(layer.cout * w * rows) };
    Planes::from_vec(layer.cout, w, rows, data)
}

/// [`conv`] of `items` consecutive images of `cin` planes of `w × h` each: their outputs,
/// one after the other.
pub fn conv_batch(input: &[f32], items: usize, w: usize, h: usize, layer: &ConvLayer, relu: bool) -> Vec<f32> {
    let (n_in, n_out) = (layer.cin * w * h, layer.cout * w * h);
    assert_eq!(input.len(), items * n_in, "{items} images of {}×{h}×{w}", layer.cin);
    let mut out = crate::kernel::buffers::with_capacity(items * n_out);
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
            Job { src: item, layer, w, h, oy: 0, pw, ph: h, y0: 0, relu, isa }
        } else {
            pad_rows(buf, item, Padded { c: layer.cin, w, h, r }, y0..y1);
            Job { src: buf, layer, w, h, oy: 0, pw, ph: y1 - y0 + 2 * r, y0, relu, isa }
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
    /// Rows of each output plane that `out` holds, from row `oy` of the plane.
    h: usize,
    oy: usize,
    pw: usize,
    ph: usize,
    /// The output row `src`'s first rows belong to.
    y0: usize,
    relu: bool,
    isa: Isa,
}

impl Job<'_> {
    /// Output rows `ys` of every channel (`scratch`: a reusable buffer).
    ///
    /// # Safety
    /// `out` points at `cout × h × w` floats, `ys` lie in `oy..oy + h` and inside `src`,
    /// and no other thread writes these rows.
    unsafe fn rows(&self, ys: Range<usize>, out: *mut f32, scratch: &mut Vec<f32>) {
        if winograd::applies(self.layer, self.w) {
            let task = winograd::Rows {
                src: &self.src[(ys.start - self.y0) * self.pw..],
                plane: self.pw * self.ph,
                w: self.w,
                rows: ys.len(),
                out: out.wrapping_add((ys.start - self.oy) * self.w),
                out_plane: self.w * self.h,
                relu: self.relu,
            };
            // SAFETY: the caller's contract: the rows' outputs are this task's, and `src`
            // holds their padded input rows.
            return unsafe { winograd::rows(self.layer, &task, self.isa, scratch) };
        }
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
    /// As [`Job::rows`].
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
                unsafe { *out.add((co * self.h + y - self.oy) * self.w + x) = v };
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
        let flat = pw == w || 16 * w.div_ceil(16) > pw + pw / 16;
        let first = (ys.start - self.y0) * pw;
        let (segments, dst, out_plane): (Vec<Segment>, *mut f32, usize) = if !flat {
            let segments = ys
                .clone()
                .flat_map(|y| {
                    (0..w).step_by(16).map(move |x| Segment {
                        src: (y - self.y0) * pw + x,
                        dst: (y - self.oy) * w + x,
                        mask: mask16(w - x),
                    })
                })
                .collect();
            (segments, out, w * h)
        } else {
            let n = rows * pw;
            // With r = 0 the flat rows are the output's own; else they go to `scratch`.
            let (dst, base) = if pw == w {
                (out, (ys.start - self.oy) * w)
            } else {
                scratch.resize(l.cout.next_multiple_of(MR) * n, 0.0);
                (scratch.as_mut_ptr(), 0)
            };
            let segments =
                (0..n).step_by(16).map(|q| Segment { src: first + q, dst: base + q, mask: mask16(n - q) }).collect();
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
                            out.add((c * h + y - self.oy) * w),
                            w,
                        )
                    };
                }
            }
        }
    }

    /// Row `y` in groups of up to [`NV_AVX2`] segments of 8 pixels, each group by blocks
    /// of up to [`M_AVX2`] output channels (half a weight panel): 8 accumulators, and per
    /// tap 2 loads and 4 broadcasts for 8 multiply-adds. Larger blocks (4 × 3, 6 × 2) need
    /// all 16 registers, and the compiler's spills made them slower on Zen.
    ///
    /// # Safety
    /// As [`Job::rows`], and AVX2 and FMA are available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn row_avx2(&self, y: usize, out: *mut f32) {
        use std::arch::x86_64::*;
        let l = self.layer;
        let kk = l.cin * l.k * l.k;
        for x in (0..self.w).step_by(8 * NV_AVX2) {
            let n = (self.w - x).min(8 * NV_AVX2);
            let (nv, tail) = (n.div_ceil(8), n % 8);
            // The lanes of the group's last segment inside the plane.
            let last = if tail == 0 { 8 } else { tail } as i32;
            let mask = _mm256_cmpgt_epi32(_mm256_set1_epi32(last), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
            for c0 in (0..l.cout).step_by(M_AVX2) {
                let (b, j0) = (c0 / MR, c0 % MR);
                let m = (l.cout - c0).min(M_AVX2);
                let a = Block {
                    src: self.src[((y - self.y0) * self.pw + x)..].as_ptr(),
                    panel: l.packed[b * kk * MR + j0..].as_ptr(),
                    bias: l.bias[c0..].as_ptr(),
                    dst: out.wrapping_add((c0 * self.h + y - self.oy) * self.w + x),
                    out_plane: self.w * self.h,
                    channels: l.cin,
                    first: true,
                    last: true,
                };
                // SAFETY: unmasked reads stay inside the padded planes; writes stay in
                // row y of channels c0.. + m, masked to the columns < w.
                unsafe {
                    macro_rules! by_segments {
                        ($masked:literal) => {
                            with_const!(nv, NV => with_const!(m, M => block_avx2::<M, NV, $masked>(self, &a, mask), [4 3 2] else 1), [2] else 1)
                        };
                    }
                    if tail == 0 { by_segments!(false) } else { by_segments!(true) }
                };
            }
        }
    }
}

/// Output channels per AVX2 micro-kernel block: half a weight panel, so no block
/// straddles two panels.
#[cfg(target_arch = "x86_64")]
const M_AVX2: usize = MR / 2;
#[cfg(target_arch = "x86_64")]
const _: () = assert!(MR.is_multiple_of(M_AVX2));

/// Segments of 8 pixels per AVX2 micro-kernel block.
#[cfg(target_arch = "x86_64")]
const NV_AVX2: usize = 2;

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
    // SAFETY: the caller's contract: the instructions exist and every access is in bounds.
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

/// `M` output channels × `NV` segments of 8 consecutive pixels; the last segment only in
/// the lanes of `mask` (the columns < w) when `MASKED`.
///
/// # Safety
/// AVX2 and FMA are available; `a`'s pointers are valid for the unmasked lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_avx2<const M: usize, const NV: usize, const MASKED: bool>(
    job: &Job,
    a: &Block,
    mask: std::arch::x86_64::__m256i,
) {
    use std::arch::x86_64::*;
    let (k, cin, pw, plane) = (job.layer.k, a.channels, job.pw, job.pw * job.ph);
    // SAFETY: the caller's contract: the instructions exist and every access is in bounds.
    unsafe {
        let mut acc = [[_mm256_setzero_ps(); NV]; M];
        for (j, row) in acc.iter_mut().enumerate() {
            *row = [_mm256_set1_ps(*a.bias.add(j)); NV];
        }
        let mut wp = a.panel;
        for ci in 0..cin {
            for ky in 0..k {
                let row = a.src.add(ci * plane + ky * pw);
                for kx in 0..k {
                    let mut v = [_mm256_setzero_ps(); NV];
                    for (i, vi) in v.iter_mut().enumerate() {
                        let p = row.add(kx + 8 * i);
                        *vi = if MASKED && i == NV - 1 { _mm256_maskload_ps(p, mask) } else { _mm256_loadu_ps(p) };
                    }
                    for (j, accj) in acc.iter_mut().enumerate() {
                        let wv = _mm256_set1_ps(*wp.add(j));
                        for i in 0..NV {
                            accj[i] = _mm256_fmadd_ps(v[i], wv, accj[i]);
                        }
                    }
                    wp = wp.add(MR);
                }
            }
        }
        for (j, accj) in acc.iter().enumerate() {
            let dst = a.dst.add(j * a.out_plane);
            for (i, &s) in accj.iter().enumerate() {
                let o = if job.relu { _mm256_max_ps(s, _mm256_setzero_ps()) } else { s };
                if MASKED && i == NV - 1 {
                    _mm256_maskstore_ps(dst.add(8 * i), mask, o);
                } else {
                    _mm256_storeu_ps(dst.add(8 * i), o);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
