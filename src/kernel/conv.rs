//! 2-D convolution on CHW planes with zero padding ("same" size): the forward pass used
//! by inference and training, and the weight gradient used by training.
//!
//! The forward pass is a register-blocked direct convolution. Weights are packed once per
//! layer ([`ConvLayer`]) into panels of [`MR`] output channels, `[cin·k·k][MR]`, so the
//! micro-kernel broadcasts them from one contiguous stream; input rows are read straight
//! from the zero-padded planes (no im2col copy). With AVX-512 a block is 8 output
//! channels × 32 pixels (16 accumulators, masked at the right edge); with AVX2,
//! 8 × 8; otherwise scalar. Every output value starts at its bias and adds
//! `input·weight` with one fused multiply-add per term, in the order (input channel,
//! row, column), wherever it lies in the plane and whichever path runs, so tiles and
//! bands equal the whole frame bit for bit.

use super::planes::Planes;
use rayon::prelude::*;
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
/// each row zero-padded by `r` each side, written into `buf` (resized): the padded input
/// of output rows `y0..y1`.
#[allow(clippy::too_many_arguments)]
fn pad_rows(buf: &mut Vec<f32>, input: &[f32], c: usize, w: usize, h: usize, r: usize, y0: usize, y1: usize) {
    let (pw, rows) = (w + 2 * r, y1 - y0 + 2 * r);
    // Every value is written below, so a reused buffer of the right length needs no
    // clearing.
    buf.resize(c * rows * pw, 0.0);
    for (ch, dst) in buf.chunks_mut(rows * pw).enumerate() {
        for (j, row) in dst.chunks_mut(pw).enumerate() {
            match (y0 + j).checked_sub(r).filter(|&y| y < h) {
                Some(y) => {
                    row[..r].fill(0.0);
                    row[r..r + w].copy_from_slice(&input[(ch * h + y) * w..][..w]);
                    row[r + w..].fill(0.0);
                }
                None => row.fill(0.0),
            }
        }
    }
}

/// Output rows per parallel task of a convolution: the task pads just its own input rows
/// ([`pad_rows`]), so no padded copy of a whole (possibly huge) input is ever held.
const BAND: usize = 8;

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
    let (isa, pw) = (Isa::detect(), w + 2 * r);
    for i in 0..items {
        let item = &input[i * n_in..][..n_in];
        let ptr = RowsPtr(out.as_mut_ptr().wrapping_add(i * n_out));
        if r == 0 {
            // A 1×1 convolution reads its input in place.
            let job = Job { src: item, layer, w, h, pw, ph: h, y0: 0, relu, isa };
            (0..h).into_par_iter().for_each(|y| {
                // SAFETY: row `y` of every output plane of item `i` is written by this
                // task only, inside the buffer's capacity; `out` outlives the loop.
                unsafe { job.row(y, ptr.get()) }
            });
            continue;
        }
        (0..h.div_ceil(BAND)).into_par_iter().for_each_init(Vec::new, |buf, b| {
            let (y0, y1) = (b * BAND, (b * BAND + BAND).min(h));
            pad_rows(buf, item, layer.cin, w, h, r, y0, y1);
            let job = Job { src: buf, layer, w, h, pw, ph: y1 - y0 + 2 * r, y0, relu, isa };
            for y in y0..y1 {
                // SAFETY: as above, for the rows of this band.
                unsafe { job.row(y, ptr.get()) }
            }
        });
    }
    // SAFETY: every row of every channel of every item was written above (each path
    // writes columns 0..w of its rows).
    unsafe { out.set_len(items * n_out) };
    out
}

/// The instruction set the micro-kernels use, detected at run time.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Isa {
    Avx512,
    Avx2,
    Scalar,
}

impl Isa {
    fn detect() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            if super::simd::avx512() {
                return Isa::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                return Isa::Avx2;
            }
        }
        Isa::Scalar
    }
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
    /// Output row `y` of every channel.
    ///
    /// # Safety
    /// `out` points at `cout × h × w` floats, `y < h`, and no other thread writes row `y`.
    unsafe fn row(&self, y: usize, out: *mut f32) {
        #[cfg(target_arch = "x86_64")]
        match self.isa {
            // SAFETY: the CPU has the instructions (detected); the caller's contract.
            Isa::Avx512 => return unsafe { self.row_avx512(y, out) },
            Isa::Avx2 => return unsafe { self.row_avx2(y, out) },
            Isa::Scalar => {}
        }
        // SAFETY: the caller's contract.
        unsafe { self.row_scalar(y, out, 0) }
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

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn row_avx512(&self, y: usize, out: *mut f32) {
        const NV: usize = 3;
        let l = self.layer;
        let (k2, kk) = (l.k * l.k, l.cin * l.k * l.k);
        // Input channels go through in chunks of about 144 terms, so one chunk's input rows
        // and weights stay in L1 across the output-channel blocks. The partial sums wait
        // in the output, so every value is still summed in the one canonical order.
        let chunk = 144usize.div_ceil(k2);
        for x in (0..self.w).step_by(16 * NV) {
            let masks: [u16; NV] = std::array::from_fn(|i| {
                let left = (self.w - x).saturating_sub(16 * i);
                if left >= 16 { u16::MAX } else { (1u16 << left) - 1 }
            });
            for c0 in (0..l.cin).step_by(chunk) {
                let c1 = (c0 + chunk).min(l.cin);
                for b in 0..l.cout.div_ceil(MR) {
                    let m = (l.cout - b * MR).min(MR);
                    let a = Block {
                        src: self.src[(c0 * self.pw * self.ph + (y - self.y0) * self.pw + x)..].as_ptr(),
                        panel: l.packed[(b * kk + c0 * k2) * MR..].as_ptr(),
                        bias: l.bias[b * MR..].as_ptr(),
                        dst: out.wrapping_add((b * MR * self.h + y) * self.w + x),
                        out_plane: self.w * self.h,
                        channels: c1 - c0,
                        first: c0 == 0,
                        last: c1 == l.cin,
                    };
                    // SAFETY: unmasked reads stay inside the padded planes; writes (and
                    // the reads of partial sums) stay in row y of channels b·MR.. + m,
                    // masked to the columns < w.
                    unsafe { with_const!(m, M => block_avx512::<M, NV>(self, &a, masks), [8 7 6 5 4 3 2] else 1) };
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
    /// Padded input at (channel 0, the block's first padded row and column).
    src: *const f32,
    /// The block's weight panel `[cin·k·k][MR]`.
    panel: *const f32,
    /// The block's `MR` biases.
    bias: *const f32,
    /// Output at (the block's first channel, row, column).
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

/// `M` output channels × `16·NV` pixels (`NV` vectors, each under its mask).
///
/// # Safety
/// AVX-512F is available; `a`'s pointers are valid for the reads and masked writes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn block_avx512<const M: usize, const NV: usize>(job: &Job, a: &Block, masks: [u16; NV]) {
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
                    *v = _mm512_maskz_loadu_ps(masks[i], dst.add(16 * i));
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
                        *vi = _mm512_maskz_loadu_ps(masks[i], row.add(kx + 16 * i));
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
                _mm512_mask_storeu_ps(dst.add(16 * i), masks[i], o);
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
    let (pw, ph) = (w + 2 * r, h + 2 * r);
    let pads: Vec<Vec<f32>> = (0..items)
        .map(|i| {
            let mut p = Vec::new();
            pad_into(&mut p, &input[i * cin * plane..][..cin * plane], cin, w, h, r);
            p
        })
        .collect();
    // Register blocks: 2 output channels × 1 input channel × 9 taps for 3×3, 4 × 4 for
    // 1×1, each summed as 16 lanes kept in memory between bands of rows, so a band's
    // planes stay in cache while every block uses them. One task per output-channel block
    // owns its values and sums items, bands and lanes in a fixed order, so results do not
    // depend on threads.
    let (mb, nb) = if k == 1 { (4, 4) } else { (2, 1) };
    let (co_blocks, ci_blocks) = (cout.div_ceil(mb), cin.div_ceil(nb));
    let block = mb * nb * k2;
    let band = (32768 / (cin * pw).max(1)).clamp(1, h.max(1));
    let mut blocks = vec![0f32; co_blocks * ci_blocks * block];
    blocks.par_chunks_mut(ci_blocks * block).enumerate().for_each(|(cb, taps)| {
        let co = cb * mb;
        let m = (cout - co).min(mb);
        let mut lanes = vec![0f32; ci_blocks * block * 16];
        for (i, pad) in pads.iter().enumerate() {
            for y0 in (0..h).step_by(band) {
                let rows = y0..(y0 + band).min(h);
                for (cj, acc) in lanes.chunks_mut(block * 16).enumerate() {
                    let ci = cj * nb;
                    let n = (cin - ci).min(nb);
                    let t = Taps {
                        src: &pad[ci * pw * ph..(ci + n) * pw * ph],
                        grad: &grad[(i * cout + co) * plane..][..m * plane],
                        w,
                        h,
                        pw,
                        ph,
                    };
                    // The block shapes the vector kernels are built for; others go scalar.
                    #[allow(unused_macros)] // unused off x86-64
                    macro_rules! blocks {
                        ($sum:ident) => {
                            match (m, n, k) {
                                (2, 1, 3) => t.$sum::<2, 1, 3>(rows.clone(), nb, acc),
                                (1, 1, 3) => t.$sum::<1, 1, 3>(rows.clone(), nb, acc),
                                (1..=4, 1..=4, 1) => with_const!(m, M => with_const!(n, N =>
                                    t.$sum::<M, N, 1>(rows.clone(), nb, acc), [4 3 2] else 1), [4 3 2] else 1),
                                _ => t.sum_scalar(m, n, k, nb, rows.clone(), acc),
                            }
                        };
                    }
                    #[cfg(target_arch = "x86_64")]
                    match isa {
                        // SAFETY: AVX-512F is available (detected).
                        Isa::Avx512 => unsafe { blocks!(sum_avx512) },
                        // SAFETY: AVX2 and FMA are available (detected).
                        Isa::Avx2 => unsafe { blocks!(sum_avx2) },
                        Isa::Scalar => t.sum_scalar(m, n, k, nb, rows.clone(), acc),
                    }
                    #[cfg(not(target_arch = "x86_64"))]
                    t.sum_scalar(m, n, k, nb, rows.clone(), acc);
                }
            }
        }
        for (t, lane) in taps.iter_mut().zip(lanes.chunks(16)) {
            *t = lane.iter().sum();
        }
    });
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

/// One weight-gradient task's planes: `n` input channels padded (`pw × ph` each) and `m`
/// output channels' gradients (`w × h` each).
struct Taps<'a> {
    src: &'a [f32],
    grad: &'a [f32],
    w: usize,
    h: usize,
    pw: usize,
    ph: usize,
}

impl Taps<'_> {
    /// Whether a block of `m` gradients × `n` input channels × `k²` taps over `rows` stays
    /// inside the planes and an accumulator slice of `out` floats (lanes laid out for `nb`).
    fn fits(&self, m: usize, n: usize, k: usize, rows: &Range<usize>, nb: usize, out: usize) -> bool {
        let (w, h, pw) = (self.w, self.h, self.pw);
        rows.end <= h
            && self.grad.len() >= m * w * h
            && self.src.len() >= (n.max(1) - 1) * pw * self.ph + (h + k - 1) * pw
            && n <= nb
            && out >= m * nb * k * k * 16
    }

    /// Adds `Σ grad[j]·src[c]` over `rows` at each of the `k²` taps to lane 0 of
    /// `acc[((j·nb + c)·k² + tap)·16..]`.
    #[allow(clippy::too_many_arguments)]
    fn sum_scalar(&self, m: usize, n: usize, k: usize, nb: usize, rows: Range<usize>, acc: &mut [f32]) {
        let (w, h, pw) = (self.w, self.h, self.pw);
        for j in 0..m {
            let g = &self.grad[j * w * h..][..w * h];
            for c in 0..n {
                let src = &self.src[c * pw * self.ph..];
                for ky in 0..k {
                    for kx in 0..k {
                        let mut s = 0f32;
                        for y in rows.clone() {
                            let row = &src[(y + ky) * pw + kx..][..w];
                            s += g[y * w..][..w].iter().zip(row).map(|(a, b)| a * b).sum::<f32>();
                        }
                        acc[(((j * nb + c) * k + ky) * k + kx) * 16] += s;
                    }
                }
            }
        }
    }

    /// [`Taps::sum_scalar`] for `M` gradients, `N ≤ nb` input channels and `K × K` taps,
    /// 16 pixels at a time into 16 lanes.
    ///
    /// # Safety
    /// AVX-512F is available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[allow(clippy::needless_range_loop)] // indices name the accumulator block's axes
    unsafe fn sum_avx512<const M: usize, const N: usize, const K: usize>(
        &self,
        rows: Range<usize>,
        nb: usize,
        out: &mut [f32],
    ) {
        use std::arch::x86_64::*;
        let (w, h, pw, pp) = (self.w, self.h, self.pw, self.pw * self.ph);
        assert!(self.fits(M, N, K, &rows, nb, out.len()), "a weight-gradient block outside its planes");
        // SAFETY: masked lanes are not read; the rest stay inside the slices (checked).
        unsafe {
            let mut acc = [[[[_mm512_setzero_ps(); K]; K]; N]; M];
            for j in 0..M {
                for c in 0..N {
                    for ky in 0..K {
                        for kx in 0..K {
                            acc[j][c][ky][kx] =
                                _mm512_loadu_ps(out.as_ptr().add((((j * nb + c) * K + ky) * K + kx) * 16));
                        }
                    }
                }
            }
            for y in rows {
                for x in (0..w).step_by(16) {
                    let mask = if w - x >= 16 { u16::MAX } else { (1u16 << (w - x)) - 1 };
                    let mut g = [_mm512_setzero_ps(); M];
                    for (j, gv) in g.iter_mut().enumerate() {
                        *gv = _mm512_maskz_loadu_ps(mask, self.grad.as_ptr().add(j * w * h + y * w + x));
                    }
                    for c in 0..N {
                        for ky in 0..K {
                            let row = self.src.as_ptr().add(c * pp + (y + ky) * pw + x);
                            for kx in 0..K {
                                let v = _mm512_maskz_loadu_ps(mask, row.add(kx));
                                for j in 0..M {
                                    acc[j][c][ky][kx] = _mm512_fmadd_ps(g[j], v, acc[j][c][ky][kx]);
                                }
                            }
                        }
                    }
                }
            }
            for j in 0..M {
                for c in 0..N {
                    for ky in 0..K {
                        for kx in 0..K {
                            let at = out.as_mut_ptr().add((((j * nb + c) * K + ky) * K + kx) * 16);
                            _mm512_storeu_ps(at, acc[j][c][ky][kx]);
                        }
                    }
                }
            }
        }
    }
}

impl Taps<'_> {
    /// [`Taps::sum_avx512`] with AVX2: 8 pixels at a time into the first 8 of 16 lanes.
    ///
    /// # Safety
    /// AVX2 and FMA are available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::needless_range_loop)] // indices name the accumulator block's axes
    unsafe fn sum_avx2<const M: usize, const N: usize, const K: usize>(
        &self,
        rows: Range<usize>,
        nb: usize,
        out: &mut [f32],
    ) {
        use std::arch::x86_64::*;
        let (w, h, pw, pp) = (self.w, self.h, self.pw, self.pw * self.ph);
        assert!(self.fits(M, N, K, &rows, nb, out.len()), "a weight-gradient block outside its planes");
        let lane = |i: usize| ((((i / (N * K * K)) * nb + (i / (K * K)) % N) * K + (i / K) % K) * K + i % K) * 16;
        // SAFETY: masked lanes are not read; the rest stay inside the slices (checked).
        unsafe {
            let mut acc = [[[[_mm256_setzero_ps(); K]; K]; N]; M];
            for (i, a) in acc.iter_mut().flatten().flatten().flatten().enumerate() {
                *a = _mm256_loadu_ps(out.as_ptr().add(lane(i)));
            }
            for y in rows {
                for x in (0..w).step_by(8) {
                    let left = (w - x).min(8) as i32;
                    let mask = _mm256_cmpgt_epi32(_mm256_set1_epi32(left), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
                    let mut g = [_mm256_setzero_ps(); M];
                    for (j, gv) in g.iter_mut().enumerate() {
                        *gv = _mm256_maskload_ps(self.grad.as_ptr().add(j * w * h + y * w + x), mask);
                    }
                    for c in 0..N {
                        for ky in 0..K {
                            let row = self.src.as_ptr().add(c * pp + (y + ky) * pw + x);
                            for kx in 0..K {
                                let v = _mm256_maskload_ps(row.add(kx), mask);
                                for j in 0..M {
                                    acc[j][c][ky][kx] = _mm256_fmadd_ps(g[j], v, acc[j][c][ky][kx]);
                                }
                            }
                        }
                    }
                }
            }
            for (i, a) in acc.iter().flatten().flatten().flatten().enumerate() {
                _mm256_storeu_ps(out.as_mut_ptr().add(lane(i)), *a);
            }
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
    fn every_instruction_set_gives_the_same_bits() {
        // More input channels than one chunk, more rows than one band, a ragged last block.
        let (cin, cout, k, w, h) = (20, 11, 3, 45, 11);
        let input = Planes::from_vec(cin, w, h, SplitMix64(7).centred(cin * w * h));
        let layer = ConvLayer::new(&SplitMix64(8).centred(cout * cin * 9), &SplitMix64(9).centred(cout), cin, k);
        let bits = |p: &[f32]| p.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        let run = |isa: Isa| {
            let mut pad = Vec::new();
            pad_into(&mut pad, &input.data, cin, w, h, 1);
            let mut out = Planes::zeros(cout, w, h);
            let job = Job { src: &pad, layer: &layer, w, h, pw: w + 2, ph: h + 2, y0: 0, relu: false, isa };
            for y in 0..h {
                // SAFETY: single-threaded; rows inside the buffer.
                unsafe { job.row(y, out.data.as_mut_ptr()) };
            }
            bits(&out.data)
        };
        let scalar = run(Isa::Scalar);
        assert_eq!(run(Isa::detect()), scalar);
        // The banded, parallel path of `conv` too.
        assert_eq!(bits(&conv(&input, &layer, false).data), scalar);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            assert_eq!(run(Isa::Avx2), scalar);
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
        for (cin, cout, k, w, h) in [(5, 7, 3, 19, 6), (9, 6, 1, 21, 5), (3, 2, 3, 33, 2)] {
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
