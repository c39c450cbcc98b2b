//! Training augmentation: the square's eight symmetries and the six orders of the colour
//! channels, and a patch's network input as the augmented frame would give it.

use crate::features::{Branch, Features, INPUT_CHANNELS, sanitize};

/// One of the square's eight symmetries (mirrors and transposition), for training
/// augmentation: a mirrored or transposed render is as plausible as the render itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Orientation {
    /// Mirrored left to right.
    pub flip_x: bool,
    /// Mirrored top to bottom.
    pub flip_y: bool,
    /// Rows and columns exchanged (before the mirrors).
    pub transpose: bool,
}

impl Orientation {
    /// Symmetry `i` of the eight (bits: mirror x, mirror y, transpose); 0 is the identity.
    pub fn from_index(i: u64) -> Orientation {
        Orientation { flip_x: i & 1 != 0, flip_y: i & 2 != 0, transpose: i & 4 != 0 }
    }

    /// CHW planes of `side`² squares, oriented.
    pub fn apply(self, planes: &[f32], side: usize) -> Vec<f32> {
        let n = side * side;
        let mut out = Vec::with_capacity(planes.len());
        for plane in planes.chunks_exact(n) {
            for v in 0..side {
                for u in 0..side {
                    let (mut x, mut y) = if self.transpose { (v, u) } else { (u, v) };
                    if self.flip_x {
                        x = side - 1 - x;
                    }
                    if self.flip_y {
                        y = side - 1 - y;
                    }
                    out.push(plane[y * side + x]);
                }
            }
        }
        out
    }
}

/// The colour channels reordered (training augmentation: a render with its red and blue
/// exchanged is as plausible as the render): channel `c` of the result is channel
/// `self.0[c]` of the original, in colour, albedo and references alike.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelOrder(pub [usize; 3]);

impl Default for ChannelOrder {
    /// R, G, B as they are.
    fn default() -> Self {
        ChannelOrder([0, 1, 2])
    }
}

impl ChannelOrder {
    /// Order `i` of the six (0 is the identity).
    pub fn from_index(i: u64) -> ChannelOrder {
        const ALL: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
        ChannelOrder(ALL[(i % 6) as usize])
    }

    /// Three planes (R, G, B) in this order.
    pub fn pick<T>(self, planes: &[T; 3]) -> [&T; 3] {
        self.0.map(|c| &planes[c])
    }
}

impl Features {
    /// The input of branch `b` over the `side`² square at (`x0`, `y0`) as the network
    /// would see it in a mirrored or transposed frame whose colour channels are reordered
    /// (training augmentation): the planes are oriented first and the gradients taken
    /// afterwards, along the oriented axes; colour and albedo reordered alike. The identity
    /// is [`Features::branch_input`] exactly. (Normals keep their components; the network
    /// sees only their gradients.)
    pub fn branch_input_oriented(
        &self,
        b: Branch,
        (x0, y0): (isize, isize),
        side: usize,
        o: Orientation,
        order: ChannelOrder,
    ) -> Vec<f32> {
        if o == Orientation::default() && order == ChannelOrder::default() {
            return self.branch_input(b, x0, y0, side, side);
        }
        // One pixel of margin on every side, for the backward differences of the border.
        let m = side + 2;
        let all = self.guides(b);
        // c̃ (0..3) and albedo (6..9) reordered alike.
        let guides: [&[f32]; 10] = std::array::from_fn(|k| match k {
            0..3 => all[order.0[k]],
            6..9 => all[6 + order.0[k - 6]],
            _ => all[k],
        });
        let g = o.apply(&self.region(&guides, x0 - 1, y0 - 1, m, m), m);
        let at = |k: usize, x: usize, y: usize| g[(k * m + y) * m + x];
        let mut out = Vec::with_capacity(INPUT_CHANNELS * side * side);
        let square = |out: &mut Vec<f32>, f: &dyn Fn(usize, usize) -> f32| {
            (0..side).for_each(|y| (0..side).for_each(|x| out.push(f(x + 1, y + 1))));
        };
        for k in 0..3 {
            square(&mut out, &|x, y| at(k, x, y));
        }
        for k in 0..10 {
            square(&mut out, &|x, y| sanitize(at(k, x, y) - at(k, x - 1, y)));
        }
        for k in 0..10 {
            square(&mut out, &|x, y| sanitize(at(k, x, y) - at(k, x, y - 1)));
        }
        out.extend(o.apply(&self.region(&self.variances(b), x0, y0, side, side), side));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::tests::inputs;
    use crate::io::layout::KpcnInputs;

    /// `k` with every plane mirrored left to right.
    fn mirrored(k: &KpcnInputs) -> KpcnInputs {
        let (w, h) = (k.width, k.height);
        let m = |p: &Vec<f32>| (0..w * h).map(|i| p[(i / w) * w + (w - 1 - i % w)]).collect::<Vec<f32>>();
        let m3 = |p: &[Vec<f32>; 3]| [m(&p[0]), m(&p[1]), m(&p[2])];
        KpcnInputs {
            width: w,
            height: h,
            color: m3(&k.color),
            diffuse: m3(&k.diffuse),
            specular: m3(&k.specular),
            albedo: m3(&k.albedo),
            normal: m3(&k.normal),
            depth: m(&k.depth),
            visibility: None,
            color_variance: m(&k.color_variance),
            diffuse_variance: m(&k.diffuse_variance),
            specular_variance: m(&k.specular_variance),
            albedo_variance: m(&k.albedo_variance),
            normal_variance: m(&k.normal_variance),
            depth_variance: m(&k.depth_variance),
        }
    }

    #[test]
    fn oriented_input_is_the_input_of_the_mirrored_frame() {
        let k = inputs(20, 16, |i| ((i * 7919) % 97) as f32 / 50.0);
        let (f, fm) = (Features::new(&k), Features::new(&mirrored(&k)));
        let (x0, y0, side) = (4, 5, 8);
        for b in [Branch::Diffuse, Branch::Specular] {
            let o = Orientation { flip_x: true, ..Default::default() };
            let got = f.branch_input_oriented(b, (x0, y0), side, o, ChannelOrder::default());
            let want = fm.branch_input(b, 20 - x0 - side as isize, y0, side, side);
            assert_eq!(got, want, "{b:?}");
            let id = f.branch_input_oriented(b, (x0, y0), side, Orientation::default(), ChannelOrder::default());
            assert_eq!(id, f.branch_input(b, x0, y0, side, side));
        }
        // Transposing twice, or mirroring twice, is the identity; the eight are distinct.
        let sq: Vec<f32> = (0..9).map(|v| v as f32).collect();
        let all: Vec<Vec<f32>> = (0..8).map(|i| Orientation::from_index(i).apply(&sq, 3)).collect();
        for (i, a) in all.iter().enumerate() {
            assert!(all[..i].iter().all(|b| b != a), "symmetry {i} repeats");
        }
        let t = Orientation { transpose: true, ..Default::default() };
        assert_eq!(t.apply(&t.apply(&sq, 3), 3), sq);
        assert_eq!(all[4], [0.0, 3.0, 6.0, 1.0, 4.0, 7.0, 2.0, 5.0, 8.0]);
    }

    #[test]
    fn channel_ordered_input_is_the_input_of_the_reordered_frame() {
        let mut k = inputs(20, 16, |i| ((i * 7919) % 97) as f32 / 50.0);
        k.albedo = std::array::from_fn(|c| k.albedo[c].iter().map(|a| a * (0.3 + 0.3 * c as f32)).collect());
        let f = Features::new(&k);
        let (x0, y0, side) = (4, 5, 8);
        for i in 1..6 {
            let order = ChannelOrder::from_index(i);
            let mut r = k.clone();
            for planes in [&mut r.color, &mut r.diffuse, &mut r.specular, &mut r.albedo] {
                *planes = order.pick(planes).map(Vec::clone);
            }
            let fr = Features::new(&r);
            for b in [Branch::Diffuse, Branch::Specular] {
                let o = Orientation::from_index(i);
                let got = f.branch_input_oriented(b, (x0, y0), side, o, order);
                let want = fr.branch_input_oriented(b, (x0, y0), side, o, ChannelOrder::default());
                // Equal but for the variances' RGB means, summed in another order.
                for (j, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!((g - w).abs() <= 1e-6 * w.abs().max(1e-3), "{b:?} order {order:?} value {j}: {g} {w}");
                }
                assert_ne!(got, f.branch_input_oriented(b, (x0, y0), side, o, ChannelOrder::default()));
            }
        }
        let all: Vec<[usize; 3]> = (0..6).map(|i| ChannelOrder::from_index(i).0).collect();
        assert!(all.iter().enumerate().all(|(i, a)| !all[..i].contains(a)), "six distinct orders: {all:?}");
    }
}
