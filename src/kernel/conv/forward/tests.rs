//! The forward pass's tests: against candle, rows and bands against the whole plane, every
//! instruction set and both Winograd filters against the scalar path, bit for bit.

use super::*;
use crate::kernel::conv::Winograd;
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
    // Widths around the 8- and 32-pixel blocks, channels around the 8-channel panels;
    // 3×3 layers take F(2, 3) on even widths from 32 channels, F(4, 3) on widths of
    // multiples of 4 from 16.
    for (cin, cout, k, w, h) in [
        (3, 5, 3, 37, 6),
        (32, 9, 3, 38, 5),
        (40, 17, 3, 100, 3),
        (8, 4, 1, 16, 3),
        (27, 9, 3, 20, 5),
        (2, 3, 3, 5, 4),
        (16, 17, 3, 70, 3),
        (16, 9, 3, 36, 5),
        (5, 8, 1, 33, 2),
    ] {
        for filter in [Winograd::F2, Winograd::F4] {
            let x = SplitMix64(1).centred(cin * w * h);
            let wt = SplitMix64(2).centred(cout * cin * k * k);
            let b = SplitMix64(3).centred(cout);
            let layer = ConvLayer::new(&wt, &b, cin, k).with_winograd(filter);
            let ours = conv(&Planes::from_vec(cin, w, h, x.clone()), &layer, true);
            let theirs = candle_conv(&x, &wt, &b, cin, k, w, h);
            for (i, (a, b)) in ours.data.iter().zip(&theirs).enumerate() {
                assert!((a - b.max(0.0)).abs() < 1e-5, "{filter:?} {cin}→{cout} k{k} {w}×{h} at {i}: {a} vs {b}");
            }
        }
    }
}

#[test]
fn rows_of_planes_handed_over_by_row_are_the_whole_convolutions_bits() {
    // Narrow (flat path) and wide planes, 3×3, 5×5 and 1×1, row ranges that start and
    // end at the plane's edges, inside it, span several bands, or are empty.
    for (cin, cout, k, w, h) in [
        (5, 9, 3, 12, 30),
        (16, 8, 3, 64, 40),
        (3, 4, 5, 20, 13),
        (7, 5, 1, 33, 9),
        (33, 10, 3, 22, 30),
        (32, 8, 3, 64, 40),
    ] {
        let input = Planes::from_vec(cin, w, h, SplitMix64(8).centred(cin * w * h));
        for filter in [Winograd::F2, Winograd::F4] {
            let layer =
                ConvLayer::new(&SplitMix64(9).centred(cout * cin * k * k), &SplitMix64(10).centred(cout), cin, k)
                    .with_winograd(filter);
            let whole = conv(&input, &layer, true);
            for out in [0..h, 0..1, 3..h, 1..h - 1, h / 2..h / 2 + 1, 2..2] {
                let rows = conv_rows(&layer, true, (w, h), out.clone(), |c, y, dst| {
                    dst.copy_from_slice(&input.data[(c * h + y) * w..][..w]);
                });
                assert_eq!((rows.c, rows.w, rows.h), (cout, w, out.len()));
                let n = out.len();
                for c in 0..cout {
                    for (j, y) in out.clone().enumerate() {
                        let (got, want) = (&rows.data[(c * n + j) * w..][..w], &whole.data[(c * h + y) * w..][..w]);
                        assert!(
                            got.iter().zip(want).all(|(a, b)| a.to_bits() == b.to_bits()),
                            "{filter:?} {cin}→{cout} k{k} {w}×{h}, rows {out:?}: channel {c}, row {y}"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn the_fused_decoder_input_gives_the_built_inputs_bits() {
    // Narrow (flat path) and wide planes, several bands, 3×3 and 1×1.
    for (cc, cs, cout, k, w, h) in
        [(6, 4, 5, 3, 12, 10), (16, 8, 12, 3, 64, 40), (5, 3, 7, 1, 20, 6), (24, 16, 12, 3, 64, 40)]
    {
        let coarse = Planes::from_vec(cc, w / 2, h / 2, SplitMix64(4).centred(cc * w * h / 4));
        let skip = Planes::from_vec(cs, w, h, SplitMix64(5).centred(cs * w * h));
        let cin = cc + cs;
        for filter in [Winograd::F2, Winograd::F4] {
            let layer =
                ConvLayer::new(&SplitMix64(6).centred(cout * cin * k * k), &SplitMix64(7).centred(cout), cin, k)
                    .with_winograd(filter);
            let built = conv(&coarse.up_nearest().concat(&skip), &layer, true);
            let fused = conv_up_concat(&coarse, &skip, &layer, true);
            assert_eq!((fused.c, fused.w, fused.h), (cout, w, h));
            assert!(
                built.data.iter().zip(&fused.data).all(|(a, b)| a.to_bits() == b.to_bits()),
                "{filter:?} {cc}+{cs} k{k} {w}×{h}"
            );
        }
    }
}

#[test]
fn every_instruction_set_gives_the_same_bits() {
    // More input channels than one chunk, more rows than one band, a ragged last
    // block; widths that take the row-wise (45, 21) and the flat (24, 12) AVX-512 paths,
    // and end AVX2's 16-pixel groups with one or two segments, masked or not; and the
    // Winograd paths (F(2, 3) from 32 channels on even widths, F(4, 3) from 16 on
    // multiples of 4), whose flat tiles end a segment of 16 or AVX2's runs of 8
    // anywhere, or fill them.
    let shapes = [
        (20, 11, 3, 45, 11),
        (20, 11, 3, 24, 11),
        (7, 9, 3, 12, 5),
        (6, 5, 1, 12, 9),
        (5, 6, 3, 21, 4),
        (32, 11, 3, 22, 7),
        (36, 9, 3, 64, 5),
        (33, 4, 3, 6, 3),
        (16, 7, 3, 12, 9),
        (24, 5, 3, 4, 3),
    ];
    for ((cin, cout, k, w, h), filter) in shapes.into_iter().flat_map(|s| [(s, Winograd::F2), (s, Winograd::F4)]) {
        let r = (k - 1) / 2;
        let input = Planes::from_vec(cin, w, h, SplitMix64(7).centred(cin * w * h));
        let layer = ConvLayer::new(&SplitMix64(8).centred(cout * cin * k * k), &SplitMix64(9).centred(cout), cin, k)
            .with_winograd(filter);
        let bits = |p: &[f32]| p.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        let run = |isa: Isa| {
            let mut pad = Vec::new();
            pad_rows(&mut pad, &input.data, Padded { c: cin, w, h, r }, 0..h);
            let mut out = Planes::zeros(cout, w, h);
            let job =
                Job { src: &pad, layer: &layer, w, h, oy: 0, pw: w + 2 * r, ph: h + 2 * r, y0: 0, relu: false, isa };
            // SAFETY: single-threaded; rows inside the buffer.
            unsafe { job.rows(0..h, out.data.as_mut_ptr(), &mut Vec::new()) };
            bits(&out.data)
        };
        let scalar = run(Isa::Scalar);
        assert_eq!(run(Isa::detect()), scalar, "{filter:?} {w}×{h}");
        // The banded, parallel path of `conv` too.
        assert_eq!(bits(&conv(&input, &layer, false).data), scalar, "{filter:?} {w}×{h}");
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            assert_eq!(run(Isa::Avx2), scalar, "{filter:?} {w}×{h}");
        }
    }
}

#[test]
fn a_pixel_does_not_depend_on_where_the_plane_ends() {
    // The same 40×4 content seen whole and as its left 24 columns: identical bits,
    // directly and by Winograd (32 channels), except where an output's window (and,
    // by Winograd, the columns beyond it that its rounding reads) sees the padding.
    for ((cin, cout), filter) in [((5, 6), Winograd::F2), ((32, 6), Winograd::F2), ((32, 6), Winograd::F4)] {
        let x = SplitMix64(4).centred(cin * 40 * 4);
        let layer = ConvLayer::new(&SplitMix64(5).centred(cout * cin * 9), &SplitMix64(6).centred(cout), cin, 3)
            .with_winograd(filter);
        let whole = conv(&Planes::from_vec(cin, 40, 4, x.clone()), &layer, false);
        let left: Vec<f32> = x.chunks(40).flat_map(|r| r[..24].to_vec()).collect();
        let part = conv(&Planes::from_vec(cin, 24, 4, left), &layer, false);
        let reads = 1 + if filter.takes(cin, 3) { filter.extra_columns() } else { 0 };
        for c in 0..cout {
            for y in 0..4 {
                for x in 0..24 - reads {
                    let (p, w) = (part.plane(c)[y * 24 + x], whole.plane(c)[y * 40 + x]);
                    assert_eq!(p.to_bits(), w.to_bits(), "{filter:?} {cin} at {x}");
                }
            }
        }
    }
}
