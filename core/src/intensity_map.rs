//! Step 3 of the method: the intensity map. A sparse voxel grid holding the running mean of
//! calibrated reflectivity, `M ← M + (η − M)/n` with `n` capped so the map can follow changes,
//! each sweep counting once per cell ([`IntensityMap::insert_sweep`]).
//! Lookups interpolate trilinearly between the eight cell centres around a point — with the
//! weights the paper misprinted corrected — over observed cells only (weights renormalised),
//! and return the analytic gradient for the solver.
//!
//! Cells are stored in blocks of 4 × 4 × 4 behind one hash lookup a block: a lookup's eight
//! cells and a sweep's successive returns mostly fall in one block, so a cell costs an array
//! read instead of a hash probe into a table too large for the cache (a 0.2 m grid over an
//! 80 m radius).

use nalgebra::Vector3;
use rustc_hash::FxHashMap;

use crate::config::IntensityMapConfig;

/// Cells per block edge.
const BLOCK: i32 = 4;
const BLOCK_CELLS: usize = (BLOCK * BLOCK * BLOCK) as usize;

/// A block's cells: running means and their counts (0 = never observed).
#[derive(Debug, Clone)]
struct Block {
    mean: [f32; BLOCK_CELLS],
    count: [u16; BLOCK_CELLS],
}

impl Block {
    const EMPTY: Self = Self {
        mean: [0.0; BLOCK_CELLS],
        count: [0; BLOCK_CELLS],
    };
}

/// The block holding cell `cell`, and the cell's index inside it.
fn split(cell: [i32; 3]) -> ([i32; 3], usize) {
    let block = cell.map(|v| v.div_euclid(BLOCK));
    let [x, y, z] = cell.map(|v| v.rem_euclid(BLOCK) as usize);
    (block, x + BLOCK as usize * (y + BLOCK as usize * z))
}

/// Reflectivity per voxel. See the module docs.
#[derive(Debug, Clone)]
pub struct IntensityMap {
    voxel: f32,
    max_count: u16,
    min_weight: f32,
    /// Block key → index into `blocks`.
    index: FxHashMap<[i32; 3], u32>,
    /// Per block: its key and its cells.
    blocks: Vec<([i32; 3], Block)>,
    /// Observed cells.
    cells: usize,
    /// Scratch for [`Self::insert_sweep`].
    sweep: SweepSums,
}

/// A sweep's returns summed per cell, block by block, before they enter the map.
#[derive(Debug, Clone, Default)]
struct SweepSums {
    /// Per block of the map: its entry in `sums`, or [`UNTOUCHED`].
    entry: Vec<u32>,
    /// Per block the sweep touched: the block, and per cell the sum of η and the count.
    sums: Vec<(u32, [(f32, u32); BLOCK_CELLS])>,
}

const UNTOUCHED: u32 = u32::MAX;

/// The eight cells around the last lookup, for [`IntensityMap::sample_near`]: corner
/// `a + 2b + 4c` is the cell `a`, `b`, `c` steps up along x, y, z from the lower one.
#[derive(Debug, Clone, Copy, Default)]
pub struct Corners {
    base: Option<[i32; 3]>,
    /// The cells' means, 0 where unobserved.
    means: [f64; 8],
    /// 1 where observed, 0 where not.
    observed: [f64; 8],
}

/// The trilinear interpolation of the corner values `f` (indexed as in [`Corners`]) at the
/// fractions `t` within the cube, and its gradient with respect to `t`. The lower and upper
/// corners along an axis weigh 1 − t and t (the paper printed t for both).
fn trilinear(f: &[f64; 8], t: &Vector3<f64>) -> (f64, Vector3<f64>) {
    let lerp = |lo: f64, hi: f64, t: f64| lo + t * (hi - lo);
    // Along x, for each (y, z) edge of the cube: the value and its x-derivative.
    let along_x = |yz: usize| {
        let (lo, hi) = (f[2 * yz], f[2 * yz + 1]);
        (lerp(lo, hi, t.x), hi - lo)
    };
    // Called one by one: through `array::map` the compiler left a call per lookup.
    let ((x00, dx00), (x10, dx10)) = (along_x(0), along_x(1));
    let ((x01, dx01), (x11, dx11)) = (along_x(2), along_x(3));
    let (y0, y1) = (lerp(x00, x10, t.y), lerp(x01, x11, t.y));
    let (dx0, dx1) = (lerp(dx00, dx10, t.y), lerp(dx01, dx11, t.y));
    let (dy0, dy1) = (x10 - x00, x11 - x01);
    (
        lerp(y0, y1, t.z),
        Vector3::new(lerp(dx0, dx1, t.z), lerp(dy0, dy1, t.z), y1 - y0),
    )
}

/// An interpolated lookup: the value and its gradient with respect to the point (per metre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntensitySample {
    /// Interpolated mean reflectivity.
    pub value: f64,
    /// ∂value/∂point.
    pub gradient: Vector3<f64>,
}

impl IntensityMap {
    /// An empty map.
    pub fn new(config: &IntensityMapConfig) -> Self {
        Self {
            voxel: config.voxel,
            max_count: config.max_count.max(1),
            min_weight: config.min_weight,
            index: FxHashMap::default(),
            blocks: Vec::new(),
            cells: 0,
            sweep: SweepSums::default(),
        }
    }

    /// Cells stored.
    pub fn len(&self) -> usize {
        self.cells
    }

    /// Whether nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.cells == 0
    }

    /// Voxel edge, m.
    pub fn voxel(&self) -> f32 {
        self.voxel
    }

    /// The configuration the map was made with (`max_count` at least 1).
    pub fn config(&self) -> IntensityMapConfig {
        IntensityMapConfig {
            voxel: self.voxel,
            max_count: self.max_count,
            min_weight: self.min_weight,
        }
    }

    /// The observed cells as (cell key, mean, count), the key of a cell being its lower
    /// corner divided by the voxel edge. The order is the storage's, so a map rebuilt from
    /// these in this order with [`Self::insert_cell`] lists them in the same order again.
    pub fn cells(&self) -> impl Iterator<Item = ([i32; 3], f32, u16)> + '_ {
        self.blocks.iter().flat_map(|(key, block)| {
            (0..BLOCK_CELLS).filter_map(move |at| {
                let count = block.count[at];
                let b = BLOCK as usize;
                let offset = [at % b, (at / b) % b, at / (b * b)];
                let cell = std::array::from_fn(|a| key[a] * BLOCK + offset[a] as i32);
                (count > 0).then_some((cell, block.mean[at], count))
            })
        })
    }

    /// Sets cell `key` to a mean seen `count` times (capped at the map's `max_count`),
    /// replacing what it held: the inverse of [`Self::cells`]. A count of 0 or a non-finite
    /// mean leaves the map as it is, since no observation makes one.
    pub fn insert_cell(&mut self, key: [i32; 3], mean: f32, count: u16) {
        if count == 0 || !mean.is_finite() {
            return;
        }
        let (block_key, at) = split(key);
        let b = self.block(block_key);
        let block = &mut self.blocks[b].1;
        if block.count[at] == 0 {
            self.cells += 1;
        }
        block.count[at] = count.min(self.max_count);
        block.mean[at] = mean;
    }

    fn key(&self, p: &Vector3<f32>) -> [i32; 3] {
        [
            (p.x * (1.0 / self.voxel)).floor() as i32,
            (p.y * (1.0 / self.voxel)).floor() as i32,
            (p.z * (1.0 / self.voxel)).floor() as i32,
        ]
    }

    /// Adds one observation at world point `p`.
    pub fn insert(&mut self, p: &Vector3<f32>, eta: f32) {
        if !eta.is_finite() || !p.iter().all(|v| v.is_finite()) {
            return;
        }
        let (key, at) = split(self.key(p));
        let block = self.block(key);
        self.observe(block, at, eta);
    }

    /// The index of the block with key `key`, created empty if absent.
    fn block(&mut self, key: [i32; 3]) -> usize {
        match self.index.get(&key) {
            Some(&b) => b as usize,
            None => {
                self.index.insert(key, self.blocks.len() as u32);
                self.blocks.push((key, Block::EMPTY));
                self.blocks.len() - 1
            }
        }
    }

    /// Adds one observation `eta` to cell `at` of block `block`.
    fn observe(&mut self, block: usize, at: usize, eta: f32) {
        let block = &mut self.blocks[block].1;
        let count = &mut block.count[at];
        if *count == 0 {
            self.cells += 1;
            block.mean[at] = eta;
        }
        *count = (*count + 1).min(self.max_count);
        block.mean[at] += (eta - block.mean[at]) / f32::from(*count);
    }

    /// Adds a sweep's returns (world points with their reflectivity). A sweep's returns in one
    /// cell count as one observation, their mean: near the robot a sweep puts dozens of returns
    /// in a 0.2 m cell, which would fill the capped count alone and make the map there the last
    /// sweep — the next one would then be matched to its predecessor rather than to a map.
    pub fn insert_sweep(&mut self, returns: impl IntoIterator<Item = (Vector3<f32>, f32)>) {
        let mut sweep = std::mem::take(&mut self.sweep);
        sweep.sums.clear();
        // Successive returns mostly fall in one block: its entry is kept from one to the next.
        let mut last: Option<([i32; 3], usize)> = None;
        for (p, eta) in returns {
            if !eta.is_finite() || !p.iter().all(|v| v.is_finite()) {
                continue;
            }
            let (key, at) = split(self.key(&p));
            let entry = match last {
                Some((k, entry)) if k == key => entry,
                _ => {
                    let block = self.block(key);
                    sweep.entry.resize(self.blocks.len(), UNTOUCHED);
                    let entry = match sweep.entry[block] {
                        UNTOUCHED => {
                            sweep.entry[block] = sweep.sums.len() as u32;
                            sweep.sums.push((block as u32, [(0.0, 0); BLOCK_CELLS]));
                            sweep.sums.len() - 1
                        }
                        entry => entry as usize,
                    };
                    last = Some((key, entry));
                    entry
                }
            };
            let (sum, n) = &mut sweep.sums[entry].1[at];
            *sum += eta;
            *n += 1;
        }
        for (block, cells) in &sweep.sums {
            sweep.entry[*block as usize] = UNTOUCHED;
            for (at, &(sum, n)) in cells.iter().enumerate() {
                if n > 0 {
                    self.observe(*block as usize, at, sum / n as f32);
                }
            }
        }
        self.sweep = sweep;
    }

    /// The mean of cell `cell`, if observed; `last` caches the most recent block looked up.
    fn cell_mean(&self, cell: [i32; 3], last: &mut Option<([i32; 3], Option<u32>)>) -> Option<f32> {
        let (key, at) = split(cell);
        let block = match *last {
            Some((k, b)) if k == key => b,
            _ => {
                let b = self.index.get(&key).copied();
                *last = Some((key, b));
                b
            }
        }?;
        let block = &self.blocks[block as usize].1;
        (block.count[at] > 0).then_some(block.mean[at])
    }

    /// The interpolated reflectivity at `p` and its gradient, if enough of the eight
    /// surrounding cells have been observed.
    pub fn sample(&self, p: &Vector3<f64>) -> Option<IntensitySample> {
        self.sample_near(p, &mut Corners::default())
    }

    /// [`Self::sample`], reading the eight cells from `corners` when they are the ones around
    /// `p` (and filling it otherwise). A solver sampling the same points at poses a few
    /// millimetres apart finds them there and skips the hashing; the map must not change while
    /// a `Corners` is in use.
    pub fn sample_near(&self, p: &Vector3<f64>, corners: &mut Corners) -> Option<IntensitySample> {
        self.sample_with(p, corners, f64::from(self.min_weight))
    }

    /// [`Self::sample_near`] wherever any of the eight cells is observed, whatever their weight:
    /// the interpolation is continuous there, so a point that had a sample keeps one, close to
    /// it, when moved by a little.
    pub fn sample_observed(
        &self,
        p: &Vector3<f64>,
        corners: &mut Corners,
    ) -> Option<IntensitySample> {
        self.sample_with(p, corners, f64::MIN_POSITIVE)
    }

    fn sample_with(
        &self,
        p: &Vector3<f64>,
        corners: &mut Corners,
        min_weight: f64,
    ) -> Option<IntensitySample> {
        let s = f64::from(self.voxel);
        // Cell centres sit at (i + ½)·s: the lower corner of the bracketing cube is i0.
        let u = p * (1.0 / s) - Vector3::repeat(0.5);
        let i0 = u.map(f64::floor);
        let t = u - i0;
        let base = [i0.x as i32, i0.y as i32, i0.z as i32];
        if corners.base != Some(base) {
            corners.base = Some(base);
            let mut last = None;
            for corner in 0..8 {
                let (a, b, c) = (corner & 1, (corner >> 1) & 1, corner >> 2);
                let mean = self.cell_mean([base[0] + a, base[1] + b, base[2] + c], &mut last);
                let at = corner as usize;
                corners.means[at] = mean.map_or(0.0, f64::from);
                corners.observed[at] = if mean.is_some() { 1.0 } else { 0.0 };
            }
        }
        // The interpolation weights Σwₖ over the observed corners and the weighted sum Σwₖmₖ,
        // each a trilinear interpolation (unobserved corners entering as 0), then normalised.
        let (weight, d_weight) = trilinear(&corners.observed, &t);
        if weight < min_weight {
            return None;
        }
        let (value, d_value) = trilinear(&corners.means, &t);
        let mean = value / weight;
        // Quotient rule on Σwₖmₖ / Σwₖ; ∂t/∂p = 1/s.
        Some(IntensitySample {
            value: mean,
            gradient: (d_value - d_weight * mean) * (1.0 / (weight * s)),
        })
    }

    /// Drops blocks farther than `radius` from `center` (horizontally and vertically), so
    /// memory stays flat on an endless run. The kept blocks keep their order.
    pub fn retain_near(&mut self, center: &Vector3<f32>, radius: f32) {
        let (c, _) = split(self.key(center));
        let r = (radius / (self.voxel * BLOCK as f32)).ceil() as i32;
        let near = |k: &[i32; 3]| (0..3).all(|a| (k[a] - c[a]).abs() <= r);
        let (before, mut dropped) = (self.blocks.len(), 0);
        self.blocks.retain(|(k, block)| {
            let keep = near(k);
            if !keep {
                dropped += block.count.iter().filter(|&&n| n > 0).count();
            }
            keep
        });
        self.cells -= dropped;
        if self.blocks.len() != before {
            self.index.clear();
            for (i, (k, _)) in self.blocks.iter().enumerate() {
                self.index.insert(*k, i as u32);
            }
        }
    }
}

/// A map of 1 m cells with `min_weight` 0.5 and one observed cell, centred at (0.5, 0.5, 0.5),
/// holding `eta`: a point's weight falls from 1 at the centre to 0 a cell away.
#[cfg(test)]
pub(crate) fn one_cell_map(eta: f32) -> IntensityMap {
    let mut m = IntensityMap::new(&IntensityMapConfig {
        voxel: 1.0,
        max_count: 20,
        min_weight: 0.5,
    });
    m.insert(&Vector3::new(0.5, 0.5, 0.5), eta);
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map_with(f: impl Fn(f32) -> f32) -> IntensityMap {
        let mut m = IntensityMap::new(&IntensityMapConfig {
            voxel: 0.5,
            max_count: 20,
            min_weight: 0.5,
        });
        for i in -20..20 {
            for j in -4..4 {
                for k in -4..4 {
                    let p = Vector3::new(
                        i as f32 * 0.5 + 0.25,
                        j as f32 * 0.5 + 0.25,
                        k as f32 * 0.5 + 0.25,
                    );
                    m.insert(&p, f(p.x));
                }
            }
        }
        m
    }

    #[test]
    fn trilinear_reproduces_a_linear_field_and_its_gradient() {
        let m = map_with(|x| 50.0 + 4.0 * x);
        for x in [-3.1, -0.4, 0.0, 0.37, 2.9] {
            let s = m.sample(&Vector3::new(x, 0.1, -0.2)).unwrap();
            assert!(
                (s.value - (50.0 + 4.0 * x)).abs() < 1e-4,
                "{x}: {}",
                s.value
            );
            assert!(
                (s.gradient - Vector3::new(4.0, 0.0, 0.0)).norm() < 1e-4,
                "{}",
                s.gradient
            );
        }
    }

    #[test]
    fn weights_sum_to_one_between_two_cells() {
        // Between centres 0.25 (value 10) and 0.75 (value 30), a quarter of the way: 15.
        let m = map_with(|x| if x < 0.5 { 10.0 } else { 30.0 });
        let s = m.sample(&Vector3::new(0.375, 0.25, 0.25)).unwrap();
        assert!((s.value - 15.0).abs() < 1e-5, "{}", s.value);
    }

    #[test]
    fn empty_cells_do_not_pull_toward_zero() {
        let mut m = IntensityMap::new(&IntensityMapConfig {
            voxel: 1.0,
            max_count: 20,
            min_weight: 0.25,
        });
        m.insert(&Vector3::new(0.5, 0.5, 0.5), 80.0);
        m.insert(&Vector3::new(1.5, 0.5, 0.5), 80.0);
        m.insert(&Vector3::new(0.5, 1.5, 0.5), 80.0);
        m.insert(&Vector3::new(1.5, 1.5, 0.5), 80.0);
        // Half the corners (z above) are unobserved: the value stays 80, not 40.
        let s = m.sample(&Vector3::new(1.0, 1.0, 1.0)).unwrap();
        assert!((s.value - 80.0).abs() < 1e-9);
        assert!(m.sample(&Vector3::new(10.0, 10.0, 10.0)).is_none());
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let m = map_with(|x| 40.0 + 20.0 * (x * 1.3).sin());
        let p = Vector3::new(1.13, 0.41, -0.27);
        let s = m.sample(&p).unwrap();
        for axis in 0..3 {
            let mut d = Vector3::zeros();
            d[axis] = 1e-5;
            let fd = (m.sample(&(p + d)).unwrap().value - m.sample(&(p - d)).unwrap().value) / 2e-5;
            assert!(
                (fd - s.gradient[axis]).abs() < 1e-3,
                "axis {axis}: {fd} vs {}",
                s.gradient[axis]
            );
        }
    }

    #[test]
    fn a_map_rebuilt_from_its_cells_samples_the_same() {
        let mut m = map_with(|x| 40.0 + 20.0 * (x * 1.3).sin());
        // Cells on both sides of zero and in several blocks, with different counts.
        for _ in 0..3 {
            m.insert(&Vector3::new(-7.3, 2.2, -0.1), 90.0);
        }
        let cells: Vec<_> = m.cells().collect();
        assert_eq!(cells.len(), m.len());
        assert!(cells.iter().any(|c| c.2 == 3) && cells.iter().any(|c| c.2 == 1));
        let mut rebuilt = IntensityMap::new(&m.config());
        for &(key, mean, count) in &cells {
            rebuilt.insert_cell(key, mean, count);
        }
        assert_eq!(rebuilt.len(), m.len());
        assert_eq!(rebuilt.cells().collect::<Vec<_>>(), cells);
        assert_eq!(rebuilt.voxel(), 0.5);
        for i in 0..200 {
            let f = f64::from(i);
            let p = Vector3::new(
                -11.0 + f * 0.11,
                (f * 0.37).sin() * 2.0,
                (f * 0.23).cos() * 2.0,
            );
            assert_eq!(m.sample(&p), rebuilt.sample(&p), "{p}");
        }
        // A cell's key is the voxel it holds.
        let only = one_cell_map(40.0).cells().collect::<Vec<_>>();
        assert_eq!(only, vec![([0, 0, 0], 40.0, 1)]);
        let mut negative = IntensityMap::new(&m.config());
        negative.insert(&Vector3::new(-0.1, -2.6, 1.9), 7.0);
        assert_eq!(negative.cells().next().unwrap().0, [-1, -6, 3]);
        // Nothing is made of no observation; a count past the cap is capped.
        negative.insert_cell([5, 5, 5], 1.0, 0);
        negative.insert_cell([5, 5, 6], f32::NAN, 3);
        negative.insert_cell([-1, -6, 3], 9.0, u16::MAX);
        assert_eq!(
            negative.cells().collect::<Vec<_>>(),
            vec![([-1, -6, 3], 9.0, 20)]
        );
    }

    #[test]
    fn running_mean_is_capped() {
        let mut m = IntensityMap::new(&IntensityMapConfig {
            voxel: 1.0,
            max_count: 4,
            min_weight: 0.1,
        });
        let p = Vector3::new(0.5, 0.5, 0.5);
        for _ in 0..100 {
            m.insert(&p, 10.0);
        }
        for _ in 0..20 {
            m.insert(&p, 90.0);
        }
        // With the count capped at 4 the mean follows the change.
        assert!((m.sample(&p.cast()).unwrap().value - 90.0).abs() < 1.0);
    }

    #[test]
    fn a_thinly_covered_point_has_an_observed_sample_only() {
        let m = one_cell_map(40.0);
        // 0.8 of the way to the next (unobserved) cell centre: weight 0.2.
        let p = Vector3::new(1.3, 0.5, 0.5);
        assert!(m.sample_near(&p, &mut Corners::default()).is_none());
        let observed = m.sample_observed(&p, &mut Corners::default()).unwrap();
        assert!((observed.value - 40.0).abs() < 1e-9);
        // Where no cell around is observed there is nothing to interpolate.
        let far = Vector3::new(5.0, 0.5, 0.5);
        assert!(m.sample_observed(&far, &mut Corners::default()).is_none());
    }

    #[test]
    fn a_sweep_counts_once_per_cell() {
        let mut m = IntensityMap::new(&IntensityMapConfig {
            voxel: 1.0,
            max_count: 20,
            min_weight: 0.1,
        });
        let p = Vector3::new(0.5, 0.5, 0.5);
        let sweep = |eta: f32| (0..50).map(move |i| (p + Vector3::repeat(i as f32 * 1e-3), eta));
        m.insert_sweep(sweep(10.0));
        m.insert_sweep(sweep(90.0));
        // Two observations of equal weight, not 50 of the last sweep: the mean is halfway.
        assert!((m.sample(&p.cast()).unwrap().value - 50.0).abs() < 1e-4);
        assert_eq!(m.len(), 1);
        // NaN returns are skipped, not averaged in.
        m.insert_sweep([(p, f32::NAN), (p, 50.0)]);
        assert!((m.sample(&p.cast()).unwrap().value - 50.0).abs() < 1e-4);
        // A sweep going back and forth between cells of different blocks still gives each
        // cell one observation, the mean of its returns.
        let q = Vector3::new(10.5, 0.5, 0.5);
        m.insert_sweep([(q, 10.0), (p, 80.0), (q, 30.0), (p, 100.0), (q, 50.0)]);
        assert_eq!(m.len(), 2);
        assert!((m.sample(&q.cast()).unwrap().value - 30.0).abs() < 1e-4);
        // Three observations of p: 10, 90, 50 (count 3, mean 50), then 90.
        let expected = 50.0 + (90.0 - 50.0) / 4.0;
        assert!((m.sample(&p.cast()).unwrap().value - expected).abs() < 1e-4);
    }
}
