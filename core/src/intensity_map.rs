//! Step 3 of the method: the intensity map. A sparse voxel grid (hash map keyed by integer
//! cell) holding the running mean of calibrated reflectivity, `M ← M + (η − M)/n` with `n`
//! capped so the map can follow changes. Lookups interpolate trilinearly between the eight cell
//! centres around a point — with the weights the paper misprinted corrected — over observed
//! cells only (weights renormalised), and return the analytic gradient for the solver.

use nalgebra::Vector3;
use rustc_hash::FxHashMap;

use crate::config::IntensityMapConfig;

#[derive(Debug, Clone, Copy)]
struct Cell {
    mean: f32,
    count: u16,
}

/// Reflectivity per voxel. See the module docs.
#[derive(Debug, Clone)]
pub struct IntensityMap {
    voxel: f32,
    max_count: u16,
    min_weight: f32,
    cells: FxHashMap<[i32; 3], Cell>,
}

/// The eight cells around the last lookup (their means, `None` where unobserved), for
/// [`IntensityMap::sample_near`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Corners {
    base: Option<[i32; 3]>,
    means: [Option<f32>; 8],
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
            cells: FxHashMap::default(),
        }
    }

    /// Cells stored.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    fn key(&self, p: &Vector3<f32>) -> [i32; 3] {
        [
            (p.x / self.voxel).floor() as i32,
            (p.y / self.voxel).floor() as i32,
            (p.z / self.voxel).floor() as i32,
        ]
    }

    /// Adds one observation at world point `p`.
    pub fn insert(&mut self, p: &Vector3<f32>, eta: f32) {
        if !eta.is_finite() || !p.iter().all(|v| v.is_finite()) {
            return;
        }
        let max = self.max_count;
        let cell = self.cells.entry(self.key(p)).or_insert(Cell {
            mean: eta,
            count: 0,
        });
        cell.count = (cell.count + 1).min(max);
        cell.mean += (eta - cell.mean) / f32::from(cell.count);
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
        let s = f64::from(self.voxel);
        // Cell centres sit at (i + ½)·s: the lower corner of the bracketing cube is i0.
        let u = p / s - Vector3::repeat(0.5);
        let i0 = u.map(f64::floor);
        let t = u - i0;
        let base = [i0.x as i32, i0.y as i32, i0.z as i32];
        if corners.base != Some(base) {
            corners.base = Some(base);
            for (corner, mean) in corners.means.iter_mut().enumerate() {
                let (a, b, c) = (
                    corner as i32 & 1,
                    (corner as i32 >> 1) & 1,
                    corner as i32 >> 2,
                );
                *mean = self
                    .cells
                    .get(&[base[0] + a, base[1] + b, base[2] + c])
                    .map(|cell| cell.mean);
            }
        }
        let mut weight = 0.0;
        let mut value = 0.0;
        let mut d_weight = Vector3::zeros();
        let mut d_value = Vector3::zeros();
        for (corner, mean) in corners.means.iter().enumerate() {
            let Some(mean) = mean else {
                continue;
            };
            let (a, b, c) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            // w₀(t) = 1 − t, w₁(t) = t per axis (the paper printed t for both).
            let w = |bit: usize, t: f64| if bit == 1 { t } else { 1.0 - t };
            let dw = |bit: usize| if bit == 1 { 1.0 / s } else { -1.0 / s };
            let (wx, wy, wz) = (w(a, t.x), w(b, t.y), w(c, t.z));
            let wk = wx * wy * wz;
            let grad = Vector3::new(dw(a) * wy * wz, wx * dw(b) * wz, wx * wy * dw(c));
            let m = f64::from(*mean);
            weight += wk;
            value += wk * m;
            d_weight += grad;
            d_value += grad * m;
        }
        if weight < f64::from(self.min_weight) {
            return None;
        }
        let mean = value / weight;
        // Quotient rule on Σwₖmₖ / Σwₖ.
        Some(IntensitySample {
            value: mean,
            gradient: (d_value - d_weight * mean) / weight,
        })
    }

    /// Drops cells farther than `radius` from `center` (horizontally and vertically), so memory
    /// stays flat on an endless run.
    pub fn retain_near(&mut self, center: &Vector3<f32>, radius: f32) {
        let c = self.key(center);
        let r = (radius / self.voxel).ceil() as i32;
        self.cells.retain(|k, _| {
            (k[0] - c[0]).abs() <= r && (k[1] - c[1]).abs() <= r && (k[2] - c[2]).abs() <= r
        });
    }
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
}
