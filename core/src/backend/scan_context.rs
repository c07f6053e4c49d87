//! Step 7 of the method: Intensity Scan Context. A keyframe's points, in polar coordinates
//! around the sensor, fall into Nₛ sectors × Nᵣ rings, each cell holding the largest calibrated
//! reflectivity seen there. Two descriptors are compared by the mean cosine similarity of their
//! sector columns at the best circular sector shift: the paper's formula compares columns at
//! equal index, which a turn of the robot breaks; the shift makes it rotation invariant and is
//! itself a yaw estimate. A ring key (each ring's mean over sectors, invariant to the shift)
//! ranks the stored keyframes cheaply, so only a few get the full shift search.

use nalgebra::Vector3;

use super::config::ScanContextConfig;

/// One keyframe's descriptor.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanContext {
    sectors: usize,
    rings: usize,
    /// Row-major by sector: `cells[sector * rings + ring]`, so a column is contiguous.
    cells: Vec<f32>,
    /// Each column's Euclidean norm (0 for an empty column).
    norms: Vec<f32>,
    ring_key: Vec<f32>,
    /// The ring key's Euclidean norm (at least 1e-6), which every ring-key comparison divides by.
    ring_key_norm: f32,
}

/// The best match between two descriptors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    /// Mean column cosine similarity, in [0, 1] for non-negative cells.
    pub similarity: f64,
    /// Sector shift: column `k` of the query matches column `k + shift` of the candidate.
    pub shift: usize,
    /// The rotation about z taking the query's frame to the candidate's (rad, in (−π, π]).
    pub yaw: f64,
}

impl ScanContext {
    /// The descriptor of points (sensor frame, m) with their calibrated reflectivity.
    pub fn new(
        points: impl IntoIterator<Item = (Vector3<f32>, f32)>,
        config: &ScanContextConfig,
    ) -> Self {
        let (sectors, rings) = (config.sectors.max(1), config.rings.max(1));
        let mut cells = vec![0.0f32; sectors * rings];
        let sector_width = std::f32::consts::TAU / sectors as f32;
        let ring_width = config.max_radius / rings as f32;
        for (p, eta) in points {
            let r = (p.x * p.x + p.y * p.y).sqrt();
            if !(r.is_finite() && eta.is_finite())
                || r >= config.max_radius
                || r < config.min_radius
            {
                continue;
            }
            if p.z < config.min_height || p.z > config.max_height {
                continue;
            }
            let azimuth = p.y.atan2(p.x) + std::f32::consts::PI;
            let s = ((azimuth / sector_width) as usize).min(sectors - 1);
            let k = ((r / ring_width) as usize).min(rings - 1);
            let cell = &mut cells[s * rings + k];
            *cell = cell.max(eta.max(0.0));
        }
        Self::from_grid(sectors, rings, cells)
    }

    /// A descriptor from its cells as [`Self::cells`] gives them (e.g. read back from a file):
    /// `None` unless there are `sectors × rings ≥ 1` of them, each finite and non-negative, as
    /// [`Self::new`] makes them. The derived sums are recomputed, so the result equals the
    /// descriptor the cells came from.
    pub fn from_cells(sectors: usize, rings: usize, cells: Vec<f32>) -> Option<Self> {
        let valid = sectors > 0
            && rings > 0
            && sectors.checked_mul(rings) == Some(cells.len())
            && cells.iter().all(|v| v.is_finite() && *v >= 0.0);
        valid.then(|| Self::from_grid(sectors, rings, cells))
    }

    /// The descriptor of a filled grid: the column norms and the ring key derived from it.
    fn from_grid(sectors: usize, rings: usize, cells: Vec<f32>) -> Self {
        let norms = cells
            .chunks_exact(rings)
            .map(|c| c.iter().map(|v| v * v).sum::<f32>().sqrt())
            .collect();
        let ring_key: Vec<f32> = (0..rings)
            .map(|k| (0..sectors).map(|s| cells[s * rings + k]).sum::<f32>() / sectors as f32)
            .collect();
        let ring_key_norm = ring_key.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-6);
        Self {
            sectors,
            rings,
            cells,
            norms,
            ring_key,
            ring_key_norm,
        }
    }

    /// Sectors (columns).
    pub fn sectors(&self) -> usize {
        self.sectors
    }

    /// Rings (rows).
    pub fn rings(&self) -> usize {
        self.rings
    }

    /// The grid, row-major by sector: cell `(sector, ring)` is `cells()[sector * rings() + ring]`.
    pub fn cells(&self) -> &[f32] {
        &self.cells
    }

    /// The shift-invariant ring key.
    pub fn ring_key(&self) -> &[f32] {
        &self.ring_key
    }

    /// Cells with a return.
    pub fn occupied(&self) -> usize {
        self.cells.iter().filter(|&&v| v > 0.0).count()
    }

    /// Squared distance between two ring keys, each scaled to unit norm so that overall
    /// brightness (sensor gain, distance to walls) matters less than the profile.
    pub fn ring_key_distance(&self, other: &ScanContext) -> f32 {
        let (na, nb) = (self.ring_key_norm, other.ring_key_norm);
        self.ring_key
            .iter()
            .zip(&other.ring_key)
            .map(|(a, b)| (a / na - b / nb).powi(2))
            .sum()
    }

    /// The best circular shift of `candidate` against `self` and its similarity: the mean,
    /// over columns occupied in both, of the columns' cosine similarity. Columns empty in
    /// either say nothing about the place (occlusion, range) and are left out, as in the
    /// original Scan Context; fewer than a quarter of the columns in common scores 0.
    pub fn compare(&self, candidate: &ScanContext) -> Match {
        let n = self.sectors;
        let mut best = Match {
            similarity: 0.0,
            shift: 0,
            yaw: 0.0,
        };
        if candidate.sectors != n || candidate.rings != self.rings {
            return best;
        }
        let rings = self.rings;
        for shift in 0..n {
            let mut sum = 0.0f64;
            let mut count = 0usize;
            for k in 0..n {
                let j = (k + shift) % n;
                let (na, nb) = (self.norms[k], candidate.norms[j]);
                if na == 0.0 || nb == 0.0 {
                    continue;
                }
                let a = &self.cells[k * rings..(k + 1) * rings];
                let b = &candidate.cells[j * rings..(j + 1) * rings];
                let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
                sum += f64::from(dot / (na * nb));
                count += 1;
            }
            if count * 4 < n {
                continue;
            }
            let similarity = sum / count as f64;
            if similarity > best.similarity {
                best = Match {
                    similarity,
                    shift,
                    yaw: 0.0,
                };
            }
        }
        let step = std::f64::consts::TAU / n as f64;
        let yaw = best.shift as f64 * step;
        best.yaw = if yaw > std::f64::consts::PI {
            yaw - std::f64::consts::TAU
        } else {
            yaw
        };
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    /// A synthetic place: walls at varied distances with patches of varied reflectivity.
    fn place() -> Vec<(Vector3<f32>, f32)> {
        let mut points = Vec::new();
        for i in 0..3600 {
            let a = i as f32 * std::f32::consts::TAU / 3600.0;
            let r =
                6.0 + 4.0 * (3.0 * a).sin().abs() + if (a * 7.0).sin() > 0.6 { 8.0 } else { 0.0 };
            let eta =
                20.0 + 60.0 * ((a * 11.0).cos() * 0.5 + 0.5) + if i % 97 < 5 { 120.0 } else { 0.0 };
            for h in [-0.5f32, 0.5, 1.5] {
                points.push((Vector3::new(r * a.cos(), r * a.sin(), h), eta));
            }
        }
        points
    }

    #[test]
    fn a_rotated_view_matches_with_its_yaw() {
        let config = ScanContextConfig::default();
        let original = ScanContext::new(place(), &config);
        // Rotate by whole sectors, so the cells are the same ones, shifted.
        for sectors in [0usize, 7, 30, 53] {
            let yaw = sectors as f32 * std::f32::consts::TAU / config.sectors as f32;
            let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw + 0.001);
            // The query is the place seen by a sensor turned by `yaw`: its points are the
            // candidate's rotated by −yaw.
            let query = ScanContext::new(
                place()
                    .into_iter()
                    .map(|(p, e)| (rotation.inverse() * p, e)),
                &config,
            );
            let m = query.compare(&original);
            // The extra 1 mrad moves ~1 % of the points into the next sector.
            assert!(m.similarity > 0.95, "{sectors}: {m:?}");
            assert_eq!(m.shift, sectors % config.sectors, "{m:?}");
            let error = (m.yaw - f64::from(yaw)).rem_euclid(std::f64::consts::TAU);
            assert!(error.min(std::f64::consts::TAU - error) < 1e-3, "{m:?}");
            assert!(query.ring_key_distance(&original) < 1e-3);
        }
    }

    #[test]
    fn a_different_place_scores_lower() {
        let config = ScanContextConfig::default();
        let a = ScanContext::new(place(), &config);
        let other: Vec<_> = place()
            .into_iter()
            .map(|(p, e)| (p * 0.6, 100.0 - e.min(100.0)))
            .collect();
        let b = ScanContext::new(other, &config);
        let same = a.compare(&a).similarity;
        let different = a.compare(&b).similarity;
        assert!((same - 1.0).abs() < 1e-6, "{same}");
        assert!(different < 0.9, "{different}");
        assert!(a.ring_key_distance(&b) > 0.01);
    }

    #[test]
    fn a_descriptor_rebuilt_from_its_cells_is_equal() {
        let config = ScanContextConfig::default();
        let a = ScanContext::new(place(), &config);
        let b = ScanContext::from_cells(a.sectors(), a.rings(), a.cells().to_vec()).unwrap();
        assert_eq!(a, b);
        assert_eq!((b.sectors(), b.rings()), (config.sectors, config.rings));
        let n = a.cells().len();
        assert!(ScanContext::from_cells(a.sectors(), a.rings(), vec![0.0; n - 1]).is_none());
        assert!(ScanContext::from_cells(0, 0, Vec::new()).is_none());
        assert!(ScanContext::from_cells(usize::MAX, 2, Vec::new()).is_none());
        let mut negative = a.cells().to_vec();
        negative[3] = -1.0;
        assert!(ScanContext::from_cells(a.sectors(), a.rings(), negative).is_none());
        let mut nan = a.cells().to_vec();
        nan[3] = f32::NAN;
        assert!(ScanContext::from_cells(a.sectors(), a.rings(), nan).is_none());
    }

    #[test]
    fn an_empty_descriptor_matches_nothing() {
        let config = ScanContextConfig::default();
        let empty = ScanContext::new(std::iter::empty(), &config);
        let a = ScanContext::new(place(), &config);
        assert_eq!(empty.occupied(), 0);
        assert_eq!(a.compare(&empty).similarity, 0.0);
        assert_eq!(empty.compare(&a).similarity, 0.0);
    }
}
