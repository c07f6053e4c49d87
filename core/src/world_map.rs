//! The whole run's map, for export: every calibrated return placed in the map frame and
//! averaged per voxel (position and reflectivity), never evicted. Grows with the area covered,
//! not with time.

use nalgebra::Vector3;
use rustc_hash::FxHashMap;

#[derive(Debug, Clone, Copy, Default)]
struct Accumulator {
    sum: [f64; 3],
    eta: f64,
    count: u32,
}

/// A voxel-downsampled point cloud with calibrated intensity.
#[derive(Debug, Clone)]
pub struct WorldMap {
    voxel: f32,
    cells: FxHashMap<[i32; 3], Accumulator>,
}

/// One map point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    /// Mean position, m, map frame.
    pub position: [f32; 3],
    /// Mean calibrated reflectivity.
    pub intensity: f32,
}

impl WorldMap {
    /// An empty map with voxels of `voxel` metres.
    pub fn new(voxel: f32) -> Self {
        Self {
            voxel: voxel.max(0.01),
            cells: FxHashMap::default(),
        }
    }

    /// Adds a point in the map frame.
    pub fn insert(&mut self, p: &Vector3<f32>, eta: f32) {
        if !p.iter().all(|v| v.is_finite()) || !eta.is_finite() {
            return;
        }
        let key = [
            (p.x / self.voxel).floor() as i32,
            (p.y / self.voxel).floor() as i32,
            (p.z / self.voxel).floor() as i32,
        ];
        let a = self.cells.entry(key).or_default();
        for (s, v) in a.sum.iter_mut().zip(p.iter()) {
            *s += f64::from(*v);
        }
        a.eta += f64::from(eta);
        a.count += 1;
    }

    /// Voxels stored.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// The points, in a stable order (sorted by voxel) so exports are reproducible.
    pub fn points(&self) -> Vec<MapPoint> {
        let mut keys: Vec<_> = self.cells.keys().copied().collect();
        keys.sort_unstable();
        keys.iter()
            .map(|k| {
                let a = &self.cells[k];
                let n = f64::from(a.count);
                MapPoint {
                    position: [
                        (a.sum[0] / n) as f32,
                        (a.sum[1] / n) as f32,
                        (a.sum[2] / n) as f32,
                    ],
                    intensity: (a.eta / n) as f32,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averages_per_voxel_in_a_stable_order() {
        let mut m = WorldMap::new(1.0);
        m.insert(&Vector3::new(0.2, 0.2, 0.2), 10.0);
        m.insert(&Vector3::new(0.4, 0.4, 0.4), 30.0);
        m.insert(&Vector3::new(-3.0, 0.0, 0.0), 50.0);
        m.insert(&Vector3::new(f32::NAN, 0.0, 0.0), 50.0);
        let p = m.points();
        assert_eq!(p.len(), 2);
        assert_eq!(p[0].position, [-3.0, 0.0, 0.0]);
        assert!((p[1].position[0] - 0.3).abs() < 1e-6 && p[1].intensity == 20.0);
    }
}
