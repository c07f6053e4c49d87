//! A bounding-volume hierarchy over axis-aligned boxes: a binned surface-area-heuristic binary
//! build, collapsed into a 4-wide tree whose nodes hold their four children's boxes side by side
//! (one node visit tests four boxes in a loop the compiler can vectorise, and the tree is half as
//! deep), traversed front to back with a fixed stack, so casting a ray never allocates.
//!
//! Bounds are f32, rounded outwards by a millimetre so that f32 rounding can only add
//! candidates, never lose a hit. The exact tests against primitives are the caller's, in f64.

/// An axis-aligned box in f64.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: [f64; 3],
    /// Upper corner.
    pub max: [f64; 3],
}

impl Aabb {
    /// The box containing nothing (the identity of [`Aabb::union`]).
    pub const EMPTY: Aabb = Aabb {
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
    };

    /// The smallest box containing both.
    pub fn union(&self, other: &Aabb) -> Aabb {
        let mut out = *self;
        for i in 0..3 {
            out.min[i] = out.min[i].min(other.min[i]);
            out.max[i] = out.max[i].max(other.max[i]);
        }
        out
    }

    /// The box grown to contain `p`.
    pub fn with_point(&self, p: [f64; 3]) -> Aabb {
        self.union(&Aabb { min: p, max: p })
    }

    /// The centre.
    pub fn centroid(&self) -> [f64; 3] {
        [
            0.5 * (self.min[0] + self.max[0]),
            0.5 * (self.min[1] + self.max[1]),
            0.5 * (self.min[2] + self.max[2]),
        ]
    }

    /// Half the surface area (what the heuristic compares), 0 for an empty box.
    pub fn half_area(&self) -> f64 {
        let d = [
            self.max[0] - self.min[0],
            self.max[1] - self.min[1],
            self.max[2] - self.min[2],
        ];
        if d.iter().any(|&x| x < 0.0) {
            return 0.0;
        }
        d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
    }

    /// Whether the box contains nothing.
    pub fn is_empty(&self) -> bool {
        (0..3).any(|i| self.min[i] > self.max[i])
    }
}

/// A node of the binary build.
#[derive(Debug, Clone, Copy)]
struct Node {
    min: [f32; 3],
    /// Leaf: first item. Interior: index of the second child (the first follows the node).
    index: u32,
    max: [f32; 3],
    /// Leaf: item count (> 0). Interior: 0.
    count: u32,
}

/// Items per leaf at most.
const LEAF_MAX: usize = 2;
const BINS: usize = 16;
/// Pending entries held on the stack (up to three per level of a 4-wide tree, so a tree 10
/// levels deep); deeper trees spill to the heap. Small, because it is initialised per ray.
const STACK: usize = 32;
/// Outward rounding of node bounds, m.
const MARGIN: f64 = 1e-3;

/// A node of the 4-wide tree: its children's boxes as six rows of four lanes (min x, y, z,
/// max x, y, z), and per lane a child node index or, with [`LEAF`] set, a leaf index. Unused
/// lanes have empty boxes.
#[derive(Debug, Clone, Copy)]
#[repr(C)]
struct Node4 {
    bounds: [[f32; 4]; 6],
    child: [u32; 4],
}

/// Marks a lane's child as a leaf.
const LEAF: u32 = 1 << 31;

/// The hierarchy. Leaves refer to positions in [`Bvh::items`], which lists the input boxes in
/// leaf order, so callers can store their per-item data in that order for locality.
#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node4>,
    /// Per leaf: first item and count.
    leaves: Vec<(u32, u32)>,
    items: Vec<u32>,
}

struct Build<'a> {
    boxes: &'a [Aabb],
    centroids: Vec<[f64; 3]>,
    nodes: Vec<Node>,
}

impl Bvh {
    /// Builds the hierarchy over `boxes` (empty input gives a tree no ray hits).
    pub fn build(boxes: &[Aabb]) -> Bvh {
        let mut items: Vec<u32> = (0..boxes.len() as u32).collect();
        let mut bvh = Bvh {
            nodes: Vec::new(),
            leaves: Vec::new(),
            items: Vec::new(),
        };
        if boxes.is_empty() {
            return bvh;
        }
        let mut b = Build {
            boxes,
            centroids: boxes.iter().map(Aabb::centroid).collect(),
            nodes: Vec::with_capacity(2 * boxes.len() / LEAF_MAX + 1),
        };
        b.node(&mut items, 0);
        bvh.collapse(&b.nodes, 0);
        bvh.items = items;
        bvh
    }

    /// Turns the binary subtree at `at` into 4-wide nodes; returns the index of the node made.
    fn collapse(&mut self, binary: &[Node], at: usize) -> u32 {
        // Gather up to four children by opening the largest interior child first.
        let mut kids: Vec<usize> = if binary[at].count > 0 {
            vec![at]
        } else {
            vec![at + 1, binary[at].index as usize]
        };
        while kids.len() < 4 {
            let open = kids
                .iter()
                .enumerate()
                .filter(|(_, &k)| binary[k].count == 0)
                .max_by(|a, b| area(&binary[*a.1]).total_cmp(&area(&binary[*b.1])))
                .map(|(i, _)| i);
            let Some(i) = open else { break };
            let k = kids.swap_remove(i);
            kids.push(k + 1);
            kids.push(binary[k].index as usize);
        }
        let index = self.nodes.len();
        self.nodes.push(Node4 {
            bounds: [
                [f32::INFINITY; 4],
                [f32::INFINITY; 4],
                [f32::INFINITY; 4],
                [f32::NEG_INFINITY; 4],
                [f32::NEG_INFINITY; 4],
                [f32::NEG_INFINITY; 4],
            ],
            child: [0; 4],
        });
        for (lane, &k) in kids.iter().enumerate() {
            let n = binary[k];
            let child = if n.count > 0 {
                self.leaves.push((n.index, n.count));
                LEAF | (self.leaves.len() as u32 - 1)
            } else {
                self.collapse(binary, k)
            };
            let node = &mut self.nodes[index];
            for axis in 0..3 {
                node.bounds[axis][lane] = n.min[axis];
                node.bounds[axis + 3][lane] = n.max[axis];
            }
            node.child[lane] = child;
        }
        index as u32
    }

    /// Input box indices in leaf order: position `k` of the order is what the traversal hands
    /// to its visitor.
    pub fn items(&self) -> &[u32] {
        &self.items
    }

    /// Nodes in the tree (for reports).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Visits, front to back, every leaf item whose box the ray `origin + t·dir` meets for `t`
    /// in `[t_min, t_max]`. `visit(k, t_max)` tests item `items()[k]` and returns the distance
    /// of a hit nearer than `t_max`, which then shrinks the search.
    #[inline]
    pub fn traverse(
        &self,
        origin: [f64; 3],
        dir: [f64; 3],
        t_min: f64,
        mut t_max: f64,
        mut visit: impl FnMut(usize, f64) -> Option<f64>,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let o = [origin[0] as f32, origin[1] as f32, origin[2] as f32];
        let inv = dir.map(|d| {
            // A zero component would give 0 × ∞ = NaN on a slab boundary; a tiny one is exact
            // enough and keeps every product finite.
            let d = if d.abs() < 1e-12 {
                1e-12f64.copysign(d)
            } else {
                d
            };
            (1.0 / d) as f32
        });
        // Per axis, which bound row the ray meets first.
        let near: [usize; 3] = [0, 1, 2].map(|a| if inv[a] >= 0.0 { a } else { a + 3 });
        let far: [usize; 3] = near.map(|r| if r < 3 { r + 3 } else { r - 3 });
        let t_lo = t_min as f32;
        let mut t_hi = t_max as f32;
        // Pending subtrees and leaves with the distance at which the ray enters them: one
        // popped after the search has found something nearer is dropped without a test.
        let mut stack = [(0u32, 0f32); STACK];
        let mut sp = 1usize;
        // Only a tree deeper than STACK / 3 levels would ever use this.
        let mut overflow: Vec<(u32, f32)> = Vec::new();
        loop {
            let (next, entry) = if let Some(n) = overflow.pop() {
                n
            } else if sp > 0 {
                sp -= 1;
                stack[sp]
            } else {
                return;
            };
            if entry > t_hi {
                continue;
            }
            if next & LEAF != 0 {
                let (first, count) = self.leaves[(next & !LEAF) as usize];
                for k in first as usize..(first + count) as usize {
                    if let Some(t) = visit(k, t_max) {
                        t_max = t;
                        t_hi = t as f32;
                    }
                }
                continue;
            }
            let b = &self.nodes[next as usize].bounds;
            // Four slab tests side by side, one axis at a time, so that each step is one
            // 4-lane vector operation.
            let mut enter = [t_lo; 4];
            let mut leave = [t_hi; 4];
            for axis in 0..3 {
                let (lo_row, hi_row) = (&b[near[axis]], &b[far[axis]]);
                let (oa, ia) = (o[axis], inv[axis]);
                for lane in 0..4 {
                    enter[lane] = max(enter[lane], (lo_row[lane] - oa) * ia);
                    leave[lane] = min(leave[lane], (hi_row[lane] - oa) * ia);
                }
            }
            let node = &self.nodes[next as usize];
            let meets = [0, 1, 2, 3].map(|lane| enter[lane] <= leave[lane]);
            // Push the children met, farthest first, so the nearest is popped next.
            let mut order = [(0f32, 0u32); 4];
            let mut n = 0;
            for lane in 0..4 {
                if meets[lane] {
                    let mut i = n;
                    while i > 0 && order[i - 1].0 < enter[lane] {
                        order[i] = order[i - 1];
                        i -= 1;
                    }
                    order[i] = (enter[lane], node.child[lane]);
                    n += 1;
                }
            }
            for &(e, child) in &order[..n] {
                if sp < STACK {
                    stack[sp] = (child, e);
                    sp += 1;
                } else {
                    overflow.push((child, e));
                }
            }
        }
    }
}

#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

#[inline(always)]
fn min(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

fn area(n: &Node) -> f64 {
    let d = [0, 1, 2].map(|i| f64::from(n.max[i] - n.min[i]));
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}

impl Build<'_> {
    fn bounds(&self, items: &[u32]) -> (Aabb, Aabb) {
        let mut b = Aabb::EMPTY;
        let mut c = Aabb::EMPTY;
        for &i in items {
            b = b.union(&self.boxes[i as usize]);
            c = c.with_point(self.centroids[i as usize]);
        }
        (b, c)
    }

    /// Builds the subtree over `items` (which start at `offset` in the final order) and
    /// returns its node index.
    fn node(&mut self, items: &mut [u32], offset: usize) -> usize {
        let (bounds, cbounds) = self.bounds(items);
        let at = self.nodes.len();
        self.nodes.push(Node {
            min: bounds.min.map(|x| round_down(x - MARGIN)),
            max: bounds.max.map(|x| round_up(x + MARGIN)),
            index: offset as u32,
            count: items.len() as u32,
        });
        if items.len() <= LEAF_MAX {
            return at;
        }
        match self.split(items, &bounds, &cbounds) {
            Split::Leaf => at,
            Split::At { mid } => self.interior(at, items, offset, mid),
            // Coincident centroids: halve by count (the order among them does not matter).
            Split::Degenerate => self.interior(at, items, offset, items.len() / 2),
        }
    }

    fn interior(&mut self, at: usize, items: &mut [u32], offset: usize, mid: usize) -> usize {
        let (left, right) = items.split_at_mut(mid);
        self.node(left, offset);
        let second = self.node(right, offset + mid);
        let n = &mut self.nodes[at];
        n.index = second as u32;
        n.count = 0;
        at
    }

    /// The binned-SAH split over the three axes, partitioning `items` when it splits.
    fn split(&self, items: &mut [u32], bounds: &Aabb, cbounds: &Aabb) -> Split {
        let n = items.len();
        let mut best: Option<(f64, usize, usize)> = None;
        for axis in 0..3 {
            let lo = cbounds.min[axis];
            let extent = cbounds.max[axis] - lo;
            if extent <= 1e-9 {
                continue;
            }
            let scale = BINS as f64 / extent;
            let mut bins = [(Aabb::EMPTY, 0usize); BINS];
            for &i in items.iter() {
                let b = bin_of(self.centroids[i as usize][axis], lo, scale);
                bins[b].0 = bins[b].0.union(&self.boxes[i as usize]);
                bins[b].1 += 1;
            }
            let mut right_area = [0.0; BINS];
            let mut acc = (Aabb::EMPTY, 0usize);
            for b in (1..BINS).rev() {
                acc = (acc.0.union(&bins[b].0), acc.1 + bins[b].1);
                right_area[b] = acc.0.half_area() * acc.1 as f64;
            }
            let mut left = (Aabb::EMPTY, 0usize);
            for b in 0..BINS - 1 {
                left = (left.0.union(&bins[b].0), left.1 + bins[b].1);
                if left.1 == 0 || left.1 == n {
                    continue;
                }
                let cost = left.0.half_area() * left.1 as f64 + right_area[b + 1];
                if best.is_none_or(|(c, _, _)| cost < c) {
                    best = Some((cost, axis, b));
                }
            }
        }
        let Some((cost, axis, split_bin)) = best else {
            return Split::Degenerate;
        };
        // A leaf costs one test per item; a split costs the children's tests weighted by the
        // chance of entering them. Small nodes that gain nothing from splitting stay leaves.
        if n <= 2 * LEAF_MAX && cost >= bounds.half_area() * n as f64 {
            return Split::Leaf;
        }
        let lo = cbounds.min[axis];
        let scale = BINS as f64 / (cbounds.max[axis] - lo);
        let mut i = 0;
        let mut j = n;
        while i < j {
            if bin_of(self.centroids[items[i] as usize][axis], lo, scale) <= split_bin {
                i += 1;
            } else {
                j -= 1;
                items.swap(i, j);
            }
        }
        Split::At {
            mid: i.clamp(1, n - 1),
        }
    }
}

enum Split {
    Leaf,
    At { mid: usize },
    Degenerate,
}

fn bin_of(c: f64, lo: f64, scale: f64) -> usize {
    (((c - lo) * scale) as usize).min(BINS - 1)
}

fn round_down(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) > x {
        f.next_down()
    } else {
        f
    }
}

fn round_up(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) < x {
        f.next_up()
    } else {
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn unit_box(c: [f64; 3], h: f64) -> Aabb {
        Aabb {
            min: [c[0] - h, c[1] - h, c[2] - h],
            max: [c[0] + h, c[1] + h, c[2] + h],
        }
    }

    /// Nearest box hit by brute force and through the tree must agree on random rays.
    #[test]
    fn traversal_finds_the_same_nearest_box_as_brute_force() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let boxes: Vec<Aabb> = (0..2000)
            .map(|_| {
                let c = [
                    rng.random_range(-50.0..50.0),
                    rng.random_range(-50.0..50.0),
                    rng.random_range(0.0..10.0),
                ];
                unit_box(c, rng.random_range(0.05..1.5))
            })
            .collect();
        let bvh = Bvh::build(&boxes);
        assert_eq!(bvh.items().len(), boxes.len());
        let mut sorted = bvh.items().to_vec();
        sorted.sort_unstable();
        assert!(
            sorted.iter().enumerate().all(|(i, &x)| i as u32 == x),
            "items are a permutation"
        );
        let entry = |b: &Aabb, o: [f64; 3], d: [f64; 3]| -> Option<f64> {
            let (mut lo, mut hi) = (0.0f64, 1e9f64);
            for i in 0..3 {
                let inv = 1.0 / d[i];
                let (a, c) = ((b.min[i] - o[i]) * inv, (b.max[i] - o[i]) * inv);
                lo = lo.max(a.min(c));
                hi = hi.min(a.max(c));
            }
            (lo <= hi).then_some(lo)
        };
        let mut visited_total = 0usize;
        for _ in 0..500 {
            let o = [
                rng.random_range(-60.0..60.0),
                rng.random_range(-60.0..60.0),
                rng.random_range(0.0..10.0),
            ];
            let mut d: [f64; 3] = [
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.2..0.2),
            ];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d.iter_mut().for_each(|x| *x /= n);
            let brute = boxes
                .iter()
                .filter_map(|b| entry(b, o, d))
                .fold(f64::INFINITY, f64::min);
            let mut best = f64::INFINITY;
            let mut visited = 0;
            bvh.traverse(o, d, 0.0, 1e9, |k, t_max| {
                visited += 1;
                let t = entry(&boxes[bvh.items()[k] as usize], o, d)?;
                (t < t_max).then(|| {
                    best = best.min(t);
                    t
                })
            });
            visited_total += visited;
            assert_eq!(best, brute);
        }
        // The tree must actually prune: far fewer tests than boxes per ray.
        assert!(
            visited_total / 500 < 200,
            "{} tests per ray",
            visited_total / 500
        );
    }

    #[test]
    fn degenerate_inputs() {
        let empty = Bvh::build(&[]);
        empty.traverse([0.0; 3], [1.0, 0.0, 0.0], 0.0, 10.0, |_, _| {
            panic!("no items")
        });
        // Many identical boxes: split by count, all still reachable.
        let same = vec![unit_box([5.0, 0.0, 0.0], 1.0); 100];
        let bvh = Bvh::build(&same);
        let mut seen = 0;
        bvh.traverse([0.0; 3], [1.0, 0.0, 0.0], 0.0, 10.0, |_, _| {
            seen += 1;
            None
        });
        assert_eq!(seen, 100);
        // An axis-parallel ray starting exactly on a slab boundary still meets the box.
        let flat = vec![Aabb {
            min: [0.0, 0.0, 0.0],
            max: [10.0, 10.0, 0.0],
        }];
        let bvh = Bvh::build(&flat);
        let mut hit = false;
        bvh.traverse([5.0, 5.0, 0.0], [1.0, 0.0, 0.0], 0.0, 10.0, |_, _| {
            hit = true;
            None
        });
        assert!(hit);
    }
}
