//! 2-D convolution on CHW planes with zero padding ("same" size): the forward pass used
//! by inference and training, and the weight gradient used by training.
//!
//! The forward pass is a register-blocked direct convolution. Weights are packed once per
//! layer ([`ConvLayer`]) into panels of [`MR`] output channels, `[cin·k·k][MR]`, so the
//! micro-kernel broadcasts them from one contiguous stream; input rows are read straight
//! from zero-padded bands of rows (no im2col copy). With AVX-512 a block is 8 output
//! channels × 3 segments of 16 pixels (24 accumulators, masked at the edges; narrow
//! planes run their segments across row ends, see `Job::rows_avx512`); with AVX2, 4
//! output channels (half a panel) × 2 segments of 8 pixels; otherwise scalar. Every
//! output value starts at its bias and adds `input·weight` with one fused multiply-add
//! per term, in the order (input channel, row, column), wherever it lies in the plane and
//! whichever path runs, so tiles and bands equal the whole frame bit for bit. Layers
//! packed [`ConvLayer::with_winograd`] go by Winograd's F(2, 3) or F(4, 3) along rows
//! instead ([`Winograd`]: 6 or 4.5 multiply-adds per channel pair and pixel instead of
//! 9), with one order of operations on every path too and a value depending only on its
//! tile of 2 or 4 columns (and, with F(4, 3), on two columns each side beyond its 3×3
//! window).
//!
//! The weight gradient vectorises over pixels (`Taps`), or over output channels for
//! 3×3 layers wider than 16 (`by_channel`); the input gradient is the forward pass with
//! transposed weights ([`ConvLayer::transposed`]).

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

mod forward;
mod weight_gradient;
mod winograd;

pub use forward::{conv, conv_batch, conv_rows, conv_up_concat};
pub use weight_gradient::weight_gradient;
pub use winograd::Winograd;

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
    /// The panels of `winograd::pack` ([`ConvLayer::with_winograd`]).
    winograd: Option<winograd::Packed>,
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
        ConvLayer { cout, cin, k, packed, bias: padded_bias, winograd: None }
    }

    /// This layer with panels for `filter` packed too, where it takes it
    /// ([`Winograd::takes`]; else unchanged): planes whose width is a multiple of the
    /// filter's tile then take that path, where a value depends on its tile of columns
    /// (and with F(4, 3) on two more columns each side). Use it only where every plane the
    /// layer is given starts on a multiple of the tile in the frame's columns (the
    /// multi-scale network's scales whose regions do,
    /// [`crate::model::multiscale::winograd_scale`]), so tiles still equal the whole frame
    /// bit for bit.
    pub fn with_winograd(mut self, filter: Winograd) -> ConvLayer {
        if filter.takes(self.cin, self.k) {
            // The weights back from the direct panels, so callers need not keep them.
            let kk = self.cin * 9;
            let weight: Vec<f32> = (0..self.cout)
                .flat_map(|co| (0..kk).map(move |t| (co, t)))
                .map(|(co, t)| self.packed[((co / MR) * kk + t) * MR + co % MR])
                .collect();
            self.winograd = Some(winograd::pack(filter, &weight, self.cout, self.cin));
        }
        self
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

/// The sizes of a batch a convolution runs on: `items` images of `w × h`, `cin` input and
/// `cout` output channels, `k × k` taps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvShape {
    /// Images in the batch.
    pub items: usize,
    /// Width of every plane.
    pub w: usize,
    /// Height of every plane.
    pub h: usize,
    /// Input channels.
    pub cin: usize,
    /// Output channels.
    pub cout: usize,
    /// Kernel side.
    pub k: usize,
}
