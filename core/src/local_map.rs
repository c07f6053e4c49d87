//! Step 4's local maps: edge and plane points around the robot in a voxel hash (after
//! KISS-ICP's). Each cell keeps a bounded number of points spaced apart, so a cell's content
//! stays a thinned sample of the surface; cells beyond a radius are dropped, so memory stays flat
//! on an endless run. Nearest neighbours come from the 27 cells around the query, which bounds
//! the search radius by one cell.

use nalgebra::Vector3;
use rustc_hash::FxHashMap;

use crate::config::LocalMapConfig;

/// The most neighbours [`LocalMap::nearest`] returns.
pub const MAX_NEIGHBOURS: usize = 8;

/// Points around the robot. See the module docs.
#[derive(Debug, Clone)]
pub struct LocalMap {
    cell: f32,
    per_cell: usize,
    min_spacing_sq: f32,
    cells: FxHashMap<[i32; 3], Vec<Vector3<f32>>>,
    points: usize,
}

impl LocalMap {
    /// An empty map.
    pub fn new(config: &LocalMapConfig) -> Self {
        Self {
            cell: config.cell,
            per_cell: config.points_per_cell.max(1),
            min_spacing_sq: config.min_spacing * config.min_spacing,
            cells: FxHashMap::default(),
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
            (p.x / self.cell).floor() as i32,
            (p.y / self.cell).floor() as i32,
            (p.z / self.cell).floor() as i32,
        ]
    }

    /// Adds a world point unless its cell is full or it is too close to a point already there.
    pub fn insert(&mut self, p: Vector3<f32>) {
        if !p.iter().all(|v| v.is_finite()) {
            return;
        }
        let key = self.key(&p);
        let (per_cell, min_sq) = (self.per_cell, self.min_spacing_sq);
        let cell = self
            .cells
            .entry(key)
            .or_insert_with(|| Vec::with_capacity(per_cell));
        if cell.len() >= per_cell || cell.iter().any(|q| (q - p).norm_squared() < min_sq) {
            return;
        }
        cell.push(p);
        self.points += 1;
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
        // A small sorted buffer of (distance², point) on the stack.
        let mut best = [(f32::INFINITY, Vector3::zeros()); MAX_NEIGHBOURS];
        let mut found = 0;
        let c = self.key(p);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(cell) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) else {
                        continue;
                    };
                    for q in cell {
                        let d = (q - p).norm_squared();
                        if d > max_sq || (found == k && d >= best[k - 1].0) {
                            continue;
                        }
                        // Insertion into the sorted prefix.
                        let mut at = found.min(k - 1);
                        while at > 0 && best[at - 1].0 > d {
                            best[at] = best[at - 1];
                            at -= 1;
                        }
                        best[at] = (d, *q);
                        found = (found + 1).min(k);
                    }
                }
            }
        }
        out.extend(best[..found].iter().map(|(_, q)| *q));
    }

    /// Drops cells farther than `radius` from `center` (per axis).
    pub fn retain_near(&mut self, center: &Vector3<f32>, radius: f32) {
        let c = self.key(center);
        let r = (radius / self.cell).ceil() as i32;
        let mut removed = 0;
        self.cells.retain(|k, v| {
            let keep =
                (k[0] - c[0]).abs() <= r && (k[1] - c[1]).abs() <= r && (k[2] - c[2]).abs() <= r;
            if !keep {
                removed += v.len();
            }
            keep
        });
        self.points -= removed;
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
