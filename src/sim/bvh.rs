//! A bounding volume hierarchy built with the binned surface area heuristic.

use super::geometry::{Aabb, Ray, Shape, SurfaceHit};
use glam::Vec3;

const BINS: usize = 12;
const LEAF_SIZE: usize = 4;

#[derive(Debug, Clone, Copy)]
struct Node {
    bounds: Aabb,
    /// Leaf: first primitive; inner: index of the second child (the first follows the node).
    offset: u32,
    /// Primitives in a leaf; 0 for inner nodes.
    count: u32,
    axis: u8,
}

/// A BVH over shapes; intersection returns the index of the shape hit.
pub struct Bvh {
    nodes: Vec<Node>,
    /// Shape indices in leaf order.
    order: Vec<u32>,
}

impl Bvh {
    /// Builds the hierarchy.
    pub fn build(shapes: &[Shape]) -> Bvh {
        let bounds: Vec<Aabb> = shapes.iter().map(Shape::bounds).collect();
        let centroids: Vec<Vec3> = bounds.iter().map(Aabb::centroid).collect();
        let mut order: Vec<u32> = (0..shapes.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * shapes.len().max(1));
        if !shapes.is_empty() {
            build_node(&bounds, &centroids, &mut order, 0, shapes.len(), &mut nodes);
        }
        Bvh { nodes, order }
    }

    /// Nearest hit: (shape index, hit).
    pub fn intersect(&self, shapes: &[Shape], ray: &Ray) -> Option<(usize, SurfaceHit)> {
        let mut ray = *ray;
        let mut best = None;
        self.traverse(&ray.clone(), |i, t_max| {
            ray.t_max = t_max;
            if let Some(h) = shapes[i].intersect(&ray) {
                best = Some((i, h));
                return Some(h.t);
            }
            None
        });
        best
    }

    /// Whether anything blocks the ray before its `t_max`.
    pub fn occluded(&self, shapes: &[Shape], ray: &Ray) -> bool {
        let mut hit = false;
        self.traverse(ray, |i, _| {
            if shapes[i].intersect(ray).is_some() {
                hit = true;
                return Some(0.0);
            }
            None
        });
        hit
    }

    /// Visits candidate shapes front to back; `visit` returns a new `t_max` on a hit (0 stops).
    fn traverse(&self, ray: &Ray, mut visit: impl FnMut(usize, f32) -> Option<f32>) {
        if self.nodes.is_empty() {
            return;
        }
        let inv = ray.dir.recip();
        let neg = [inv.x < 0.0, inv.y < 0.0, inv.z < 0.0];
        let mut t_max = ray.t_max;
        let mut stack = [0u32; 64];
        let mut sp = 0;
        let mut at = 0usize;
        loop {
            let node = &self.nodes[at];
            if node.bounds.hit(ray.origin, inv, t_max) {
                if node.count > 0 {
                    for &i in &self.order[node.offset as usize..(node.offset + node.count) as usize] {
                        if let Some(t) = visit(i as usize, t_max) {
                            if t <= 0.0 {
                                return;
                            }
                            t_max = t;
                        }
                    }
                } else {
                    // Near child first.
                    let (first, second) = if neg[node.axis as usize] {
                        (node.offset as usize, at + 1)
                    } else {
                        (at + 1, node.offset as usize)
                    };
                    stack[sp] = second as u32;
                    sp += 1;
                    at = first;
                    continue;
                }
            }
            if sp == 0 {
                return;
            }
            sp -= 1;
            at = stack[sp] as usize;
        }
    }
}

fn build_node(
    bounds: &[Aabb],
    centroids: &[Vec3],
    order: &mut [u32],
    start: usize,
    end: usize,
    nodes: &mut Vec<Node>,
) -> usize {
    let at = nodes.len();
    let node_bounds = order[start..end].iter().fold(Aabb::EMPTY, |b, &i| b.union(bounds[i as usize]));
    nodes.push(Node { bounds: node_bounds, offset: start as u32, count: (end - start) as u32, axis: 0 });
    let n = end - start;
    if n <= LEAF_SIZE {
        return at;
    }
    let cb = order[start..end].iter().fold(Aabb::EMPTY, |b, &i| {
        let c = centroids[i as usize];
        b.union(Aabb { min: c, max: c })
    });
    let extent = cb.max - cb.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    if extent[axis] <= 0.0 {
        return at;
    }
    // Binned SAH.
    let bin_of =
        |i: u32| (((centroids[i as usize][axis] - cb.min[axis]) / extent[axis] * BINS as f32) as usize).min(BINS - 1);
    let mut bin_bounds = [Aabb::EMPTY; BINS];
    let mut bin_count = [0usize; BINS];
    for &i in &order[start..end] {
        let b = bin_of(i);
        bin_bounds[b] = bin_bounds[b].union(bounds[i as usize]);
        bin_count[b] += 1;
    }
    let mut best = (f32::INFINITY, 0);
    for split in 1..BINS {
        let (mut lb, mut lc, mut rb, mut rc) = (Aabb::EMPTY, 0, Aabb::EMPTY, 0);
        for b in 0..split {
            lb = lb.union(bin_bounds[b]);
            lc += bin_count[b];
        }
        for b in split..BINS {
            rb = rb.union(bin_bounds[b]);
            rc += bin_count[b];
        }
        if lc == 0 || rc == 0 {
            continue;
        }
        let cost = lb.area() * lc as f32 + rb.area() * rc as f32;
        if cost < best.0 {
            best = (cost, split);
        }
    }
    let leaf_cost = node_bounds.area() * n as f32;
    if best.0 >= leaf_cost && n <= 16 {
        return at;
    }
    let mid = if best.1 == 0 {
        // All centroids in one bin: split in the middle.
        order[start..end].sort_by(|&a, &b| centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis]));
        start + n / 2
    } else {
        let (mut i, mut j) = (start, end);
        while i < j {
            if bin_of(order[i]) < best.1 {
                i += 1;
            } else {
                j -= 1;
                order.swap(i, j);
            }
        }
        i
    };
    build_node(bounds, centroids, order, start, mid, nodes);
    let second = build_node(bounds, centroids, order, mid, end, nodes);
    nodes[at] = Node { bounds: node_bounds, offset: second as u32, count: 0, axis: axis as u8 };
    at
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::rng::Rng;

    #[test]
    fn bvh_finds_the_same_hits_as_brute_force() {
        let mut rng = Rng::for_sample(1, 2, 3);
        let mut v = || Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 10.0 - 5.0;
        let mut shapes = Vec::new();
        for i in 0..300 {
            let c = v();
            if i % 3 == 0 {
                shapes.push(Shape::Sphere { center: c, radius: 0.3 });
            } else {
                let n = Vec3::Z;
                shapes.push(Shape::Triangle { p: [c, c + v() * 0.2, c + v() * 0.2], n: [n; 3] });
            }
        }
        let bvh = Bvh::build(&shapes);
        for _ in 0..500 {
            let ray = Ray::new(v(), v().normalize_or(Vec3::X));
            let brute = shapes
                .iter()
                .enumerate()
                .filter_map(|(i, s)| s.intersect(&ray).map(|h| (i, h.t)))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            let fast = bvh.intersect(&shapes, &ray).map(|(i, h)| (i, h.t));
            assert_eq!(brute.map(|b| b.0), fast.map(|f| f.0));
            assert_eq!(brute.is_some(), bvh.occluded(&shapes, &ray));
        }
    }
}
