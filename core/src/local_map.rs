//! Step 4's local maps: edge and plane points around the robot in a voxel hash (after
//! KISS-ICP's). Each cell keeps a bounded number of points spaced apart, so a cell's content
//! stays a thinned sample of the surface; cells beyond a radius are dropped, so memory stays flat
//! on an endless run. Nearest neighbours come from the 27 cells around the query, which bounds
//! the search radius by one cell.
//!
//! The cells' points live in one flat array, a block of `points_per_cell` places a cell, each
//! block its x's, then its y's, then its z's, so a search reads one contiguous block per cell
//! instead of chasing a heap allocation per cell (or three arrays far apart), and a cell's
//! distances are computed side by side (vectorised) before any is ranked; the hash only maps a
//! cell's key to its slot. A search skips every one of the 27 cells whose box is
//! farther than the current k-th neighbour: the answer is the exact k nearest, and a query in the
//! middle of a surface reads two or three cells instead of nine.

use nalgebra::Vector3;
use rustc_hash::FxHashMap;

use crate::config::LocalMapConfig;

/// The most neighbours [`LocalMap::nearest`] returns.
pub const MAX_NEIGHBOURS: usize = 8;
/// Points whose distances [`LocalMap::nearest`] computes together.
const CHUNK: usize = 16;

/// A cell's key as one word for the hash (one comparison a probe instead of three): each index
/// modulo 2²¹ cells. Two cells share a word only 2²¹ cells (2,000 km at 1 m) apart, and the map
/// holds cells within `radius` of the robot.
fn packed(key: [i32; 3]) -> u64 {
    const MASK: u64 = (1 << 21) - 1;
    let [x, y, z] = key.map(|k| k as u32 as u64 & MASK);
    (x << 42) | (y << 21) | z
}

/// Where the x's of slot `slot`'s block start in the storage, at `per_cell` places a cell (its
/// y's `per_cell` later, its z's `2 × per_cell`).
fn block_start(slot: usize, per_cell: usize) -> usize {
    slot * 3 * per_cell
}

/// The coordinates (x, y, z) of the first `used` points of slot `slot`'s block in `storage`.
fn block_coordinates(storage: &[f32], slot: usize, per_cell: usize, used: usize) -> [&[f32]; 3] {
    let start = block_start(slot, per_cell);
    [0, 1, 2].map(|axis| {
        let from = start + axis * per_cell;
        &storage[from..from + used]
    })
}

/// Points around the robot. See the module docs.
#[derive(Debug, Clone)]
pub struct LocalMap {
    cell: f32,
    per_cell: usize,
    min_spacing_sq: f32,
    /// Cell key ([`packed`]) → slot and how many of its places are used (as in `slots`, so
    /// that a search learns both from the lookup it makes anyway).
    index: FxHashMap<u64, (u32, u32)>,
    /// Per slot: its cell's key and how many of its `per_cell` points are used.
    slots: Vec<([i32; 3], u32)>,
    /// A block of `3 × per_cell` values per slot: its points' x's, then y's, then z's.
    storage: Vec<f32>,
    points: usize,
}

impl LocalMap {
    /// An empty map.
    pub fn new(config: &LocalMapConfig) -> Self {
        Self {
            cell: config.cell,
            per_cell: config.points_per_cell.max(1),
            min_spacing_sq: config.min_spacing * config.min_spacing,
            index: FxHashMap::default(),
            slots: Vec::new(),
            storage: Vec::new(),
            points: 0,
        }
    }

    /// Points stored.
    pub fn len(&self) -> usize {
        self.points
    }

    /// Whether nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.points == 0
    }

    fn key(&self, p: &Vector3<f32>) -> [i32; 3] {
        [
            (p.x * (1.0 / self.cell)).floor() as i32,
            (p.y * (1.0 / self.cell)).floor() as i32,
            (p.z * (1.0 / self.cell)).floor() as i32,
        ]
    }

    /// Where the x's of slot `slot`'s block start in `storage`.
    fn block(&self, slot: usize) -> usize {
        block_start(slot, self.per_cell)
    }

    /// The coordinates (x, y, z) of the first `used` points of slot `slot`.
    fn block_coordinates(&self, slot: usize, used: usize) -> [&[f32]; 3] {
        block_coordinates(&self.storage, slot, self.per_cell, used)
    }

    /// The points of slot `slot`.
    #[cfg(test)]
    fn slot_points(&self, slot: usize) -> impl Iterator<Item = Vector3<f32>> + '_ {
        let [x, y, z] = self.block_coordinates(slot, self.slots[slot].1 as usize);
        (0..x.len()).map(move |j| Vector3::new(x[j], y[j], z[j]))
    }

    /// Adds a world point unless its cell is full or it is too close to a point already there.
    pub fn insert(&mut self, p: Vector3<f32>) {
        if !p.iter().all(|v| v.is_finite()) {
            return;
        }
        let key = self.key(&p);
        let per_cell = self.per_cell;
        // Field by field, so that the cell is looked up once and its entry stays borrowed while
        // the block is read and written.
        let Self {
            index,
            slots,
            storage,
            min_spacing_sq,
            points,
            ..
        } = self;
        let entry = index.entry(packed(key)).or_insert_with(|| {
            let slot = slots.len();
            slots.push((key, 0));
            storage.resize(storage.len() + 3 * per_cell, 0.0);
            (slot as u32, 0)
        });
        let (slot, used) = (entry.0 as usize, entry.1 as usize);
        if used >= per_cell {
            return;
        }
        let [x, y, z] = block_coordinates(storage, slot, per_cell, used);
        if (0..used).any(|j| (Vector3::new(x[j], y[j], z[j]) - p).norm_squared() < *min_spacing_sq)
        {
            return;
        }
        let start = block_start(slot, per_cell);
        for (axis, v) in p.iter().enumerate() {
            storage[start + axis * per_cell + used] = *v;
        }
        entry.1 += 1;
        slots[slot].1 += 1;
        *points += 1;
    }

    /// The `k` (at most [`MAX_NEIGHBOURS`]) nearest points to `p` within `max_distance`,
    /// nearest first, into `out`.
    pub fn nearest(
        &self,
        p: &Vector3<f32>,
        k: usize,
        max_distance: f32,
        out: &mut Vec<Vector3<f32>>,
    ) {
        out.clear();
        let k = k.clamp(1, MAX_NEIGHBOURS);
        let max_sq = max_distance * max_distance;
        // The nearest so far, sorted: distances² (infinity past `found`, so the k-th is a bound
        // from the start) and the place of each one's x in `storage`, read only for the answer.
        let mut best_sq = [f32::INFINITY; MAX_NEIGHBOURS];
        let mut best_at = [0u32; MAX_NEIGHBOURS];
        let mut found = 0;
        let c = self.key(p);
        // The query's offset inside its cell gives each neighbouring cell's box distance per
        // axis: none for the same layer, the offset below, the remainder above. Layers go in
        // order of distance per axis (own, nearer side, farther side), so the first cells read
        // are the nearest and the bound tightens early.
        let layers = |v: f32, k: i32| {
            let below = v - k as f32 * self.cell;
            let above = self.cell - below;
            let (below, above) = (below * below, above * above);
            if below <= above {
                [(0, 0.0), (-1, below), (1, above)]
            } else {
                [(0, 0.0), (1, above), (-1, below)]
            }
        };
        let (lx, ly, lz) = (layers(p.x, c[0]), layers(p.y, c[1]), layers(p.z, c[2]));
        for &(dx, bx) in &lx {
            for &(dy, by) in &ly {
                for &(dz, bz) in &lz {
                    let box_sq = bx + by + bz;
                    if box_sq > max_sq || box_sq >= best_sq[k - 1] {
                        continue;
                    }
                    let key = packed([c[0] + dx, c[1] + dy, c[2] + dz]);
                    let Some(&(slot, used)) = self.index.get(&key) else {
                        continue;
                    };
                    let slot = slot as usize;
                    let [xs, ys, zs] = self.block_coordinates(slot, used as usize);
                    let chunks = xs.chunks(CHUNK).zip(ys.chunks(CHUNK)).zip(zs.chunks(CHUNK));
                    for (chunk, ((xs, ys), zs)) in chunks.enumerate() {
                        let first = self.block(slot) + chunk * CHUNK;
                        // Distances first, in a loop the compiler vectorises; ranking after.
                        let mut d = [0.0f32; CHUNK];
                        let d = &mut d[..xs.len()];
                        for (((d, x), y), z) in d.iter_mut().zip(xs).zip(ys).zip(zs) {
                            let (dx, dy, dz) = (x - p.x, y - p.y, z - p.z);
                            *d = dx * dx + dy * dy + dz * dz;
                        }
                        for (j, &d) in d.iter().enumerate() {
                            if d > max_sq || d >= best_sq[k - 1] {
                                continue;
                            }
                            // Insertion into the sorted prefix.
                            let mut at = found.min(k - 1);
                            while at > 0 && best_sq[at - 1] > d {
                                best_sq[at] = best_sq[at - 1];
                                best_at[at] = best_at[at - 1];
                                at -= 1;
                            }
                            best_sq[at] = d;
                            best_at[at] = (first + j) as u32;
                            found = (found + 1).min(k);
                        }
                    }
                }
            }
        }
        let (storage, per) = (&self.storage, self.per_cell);
        out.extend(best_at[..found].iter().map(|&i| {
            let i = i as usize;
            Vector3::new(storage[i], storage[i + per], storage[i + 2 * per])
        }));
    }

    /// Drops cells farther than `radius` from `center` (per axis). The kept cells keep their
    /// order, so the map's content never depends on hash order.
    pub fn retain_near(&mut self, center: &Vector3<f32>, radius: f32) {
        let c = self.key(center);
        let r = (radius / self.cell).ceil() as i32;
        let mut kept = 0;
        for slot in 0..self.slots.len() {
            let (k, used) = self.slots[slot];
            let keep =
                (k[0] - c[0]).abs() <= r && (k[1] - c[1]).abs() <= r && (k[2] - c[2]).abs() <= r;
            if !keep {
                self.index.remove(&packed(k));
                self.points -= used as usize;
                continue;
            }
            if kept != slot {
                self.slots[kept] = (k, used);
                let (from, to) = (self.block(slot)..self.block(slot + 1), self.block(kept));
                self.storage.copy_within(from, to);
                self.index.insert(packed(k), (kept as u32, used));
            }
            kept += 1;
        }
        self.slots.truncate(kept);
        let end = self.block(kept);
        self.storage.truncate(end);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> LocalMapConfig {
        LocalMapConfig {
            cell: 1.0,
            points_per_cell: 20,
            min_spacing: 0.1,
            radius: 10.0,
            ..LocalMapConfig::default()
        }
    }

    #[test]
    fn nearest_neighbours_are_exact_within_a_cell() {
        let mut m = LocalMap::new(&LocalMapConfig {
            points_per_cell: 30,
            ..config()
        });
        for i in 0..30 {
            for j in 0..30 {
                m.insert(Vector3::new(i as f32 * 0.2, j as f32 * 0.2, 0.0));
            }
        }
        let mut out = Vec::new();
        m.nearest(&Vector3::new(2.01, 2.02, 0.05), 5, 1.0, &mut out);
        assert_eq!(out.len(), 5);
        assert_eq!(out[0], Vector3::new(2.0, 2.0, 0.0));
        // The four next-nearest are the grid neighbours 0.2 m away.
        for q in &out[1..] {
            assert!(
                ((q - Vector3::new(2.0, 2.0, 0.0)).norm() - 0.2).abs() < 1e-5,
                "{q}"
            );
        }
    }

    #[test]
    fn pruned_search_equals_brute_force() {
        let mut rng = glint_testkit::SeededRng::new(11);
        let mut next = || (rng.centred() + 0.5) as f32;
        let mut m = LocalMap::new(&LocalMapConfig {
            min_spacing: 0.0,
            ..config()
        });
        let mut all = Vec::new();
        for _ in 0..3000 {
            let p = Vector3::new(next() * 6.0 - 3.0, next() * 6.0 - 3.0, next() * 2.0);
            m.insert(p);
            all.push(p);
        }
        // Keep only what the map stored (cells cap their points).
        let mut stored = Vec::new();
        for slot in 0..m.slots.len() {
            stored.extend(m.slot_points(slot));
        }
        assert_eq!(stored.len(), m.len());
        let mut out = Vec::new();
        for _ in 0..200 {
            let q = Vector3::new(next() * 6.0 - 3.0, next() * 6.0 - 3.0, next() * 2.0);
            m.nearest(&q, 5, 0.9, &mut out);
            let mut brute: Vec<f32> = stored
                .iter()
                .map(|p| (p - q).norm_squared())
                .filter(|d| *d <= 0.81)
                .collect();
            brute.sort_by(f32::total_cmp);
            brute.truncate(5);
            let got: Vec<f32> = out.iter().map(|p| (p - q).norm_squared()).collect();
            assert_eq!(got, brute, "query {q}");
        }
        // Eviction keeps the remaining cells searchable.
        m.retain_near(&Vector3::new(-3.0, -3.0, 0.0), 2.0);
        let kept: usize = (0..m.slots.len()).map(|s| m.slot_points(s).count()).sum();
        assert_eq!(kept, m.len());
        m.nearest(&Vector3::new(-2.5, -2.5, 0.5), 3, 0.9, &mut out);
        assert_eq!(out.len(), 3);
    }

    #[test]
    fn spacing_and_cell_caps_bound_memory() {
        let mut m = LocalMap::new(&config());
        for _ in 0..100 {
            m.insert(Vector3::new(0.5, 0.5, 0.5));
        }
        assert_eq!(m.len(), 1);
        for i in 0..1000 {
            m.insert(Vector3::new(
                (i % 10) as f32 * 0.099,
                (i / 10 % 10) as f32 * 0.099,
                (i / 100) as f32 * 0.099,
            ));
        }
        assert!(m.len() <= 20);
        m.insert(Vector3::new(50.0, 0.0, 0.0));
        m.retain_near(&Vector3::zeros(), 10.0);
        assert!(m.len() <= 20);
        let mut out = Vec::new();
        m.nearest(&Vector3::new(50.0, 0.0, 0.0), 5, 1.0, &mut out);
        assert!(out.is_empty());
    }
}
