//! Steps 7–8 of the method around the descriptor: the candidate search over stored keyframes
//! (ring-key pre-filter, then the full shift search on the few best) and the geometric
//! verification of a candidate by scan-to-map alignment — the odometry's own residuals and
//! solver (`crate::solver::align`) against a submap of the candidate and its neighbours, started
//! from the ISC yaw guess. A loop is accepted only when the aligned query has enough inliers at
//! a low residual and geometry constrains every direction: a wrong loop bends the whole map,
//! a missed one costs nothing but a later chance.

use nalgebra::{Isometry3, Point3, Vector3};

use super::config::{ScanContextConfig, VerificationConfig};
use super::keyframe::Keyframe;
use super::scan_context::ScanContext;
use crate::config::{IntensityMapConfig, LocalMapConfig};
use crate::intensity_map::IntensityMap;
use crate::local_map::LocalMap;
use crate::solver::{align, AlignmentInput, IntensityPoint, MapView};

/// A stored keyframe that looks like the query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Its index among the keyframes.
    pub index: usize,
    /// ISC similarity at the best shift.
    pub similarity: f64,
    /// The yaw taking the query's frame to the candidate's, from the shift (rad).
    pub yaw: f64,
}

/// The candidates among `descriptors` for which `eligible(index)` holds, with similarity at or
/// above the threshold, best first (ties by index). Cost: one ring-key distance per eligible
/// keyframe, then the shift search on the `ring_key_candidates` nearest ring keys only.
pub fn search(
    query: &ScanContext,
    descriptors: &[ScanContext],
    eligible: impl Fn(usize) -> bool,
    config: &ScanContextConfig,
) -> Vec<Candidate> {
    let k = config.ring_key_candidates.max(1);
    // The k nearest ring keys, kept sorted by (distance, index).
    let mut nearest: Vec<(f32, usize)> = Vec::with_capacity(k + 1);
    for (i, d) in descriptors.iter().enumerate() {
        if !eligible(i) {
            continue;
        }
        let distance = query.ring_key_distance(d);
        if nearest.len() == k && distance >= nearest[k - 1].0 {
            continue;
        }
        let at = nearest.partition_point(|&(e, j)| (e, j) < (distance, i));
        nearest.insert(at, (distance, i));
        nearest.truncate(k);
    }
    let mut found: Vec<Candidate> = nearest
        .into_iter()
        .filter_map(|(_, index)| {
            let m = query.compare(&descriptors[index]);
            (m.similarity >= config.similarity_threshold).then_some(Candidate {
                index,
                similarity: m.similarity,
                yaw: m.yaw,
            })
        })
        .collect();
    found.sort_by(|a, b| {
        b.similarity
            .total_cmp(&a.similarity)
            .then(a.index.cmp(&b.index))
    });
    found
}

/// What the verification of one candidate found.
#[derive(Debug, Clone, PartialEq)]
pub struct Verification {
    /// Whether the loop is accepted.
    pub accepted: bool,
    /// Query sensor → candidate sensor, as aligned.
    pub relative: Isometry3<f64>,
    /// Fraction of the query's off-floor edge and plane points near a submap point after the
    /// fine alignment.
    pub inlier_ratio: f64,
    /// Edge and plane correspondences of the fine alignment.
    pub correspondences: usize,
    /// Mean robust cost per residual of the fine alignment.
    pub cost: f64,
    /// Whether geometry left a direction unconstrained.
    pub degenerate: bool,
}

/// A keyframe placed in the candidate's frame, for the submap.
#[derive(Debug, Clone, Copy)]
pub struct Placed<'a> {
    /// Keyframe sensor → candidate sensor.
    pub pose: Isometry3<f64>,
    /// The keyframe.
    pub keyframe: &'a Keyframe,
}

/// Aligns `query` to the submap made of `submap` (the candidate at the identity and its
/// neighbours), from each of `guesses` (query → candidate), and judges the best result.
pub fn verify(
    query: &Keyframe,
    submap: &[Placed<'_>],
    guesses: &[Isometry3<f64>],
    config: &VerificationConfig,
) -> Verification {
    let mut edges = LocalMap::new(&LocalMapConfig {
        min_spacing: 0.1,
        ..LocalMapConfig::default()
    });
    let mut planes = LocalMap::new(&LocalMapConfig::default());
    let mut all = LocalMap::new(&LocalMapConfig {
        min_spacing: 0.05,
        ..LocalMapConfig::default()
    });
    let mut intensity = IntensityMap::new(&IntensityMapConfig::default());
    for placed in submap {
        let pose = placed.pose.cast::<f32>();
        let place = |p: &[f32; 3]| (pose * Point3::from(Vector3::from(*p))).coords;
        for p in &placed.keyframe.edges {
            edges.insert(place(p));
            all.insert(place(p));
        }
        for p in &placed.keyframe.planes {
            planes.insert(place(p));
            all.insert(place(p));
        }
        for c in &placed.keyframe.cloud {
            intensity.insert(&place(&c.position), c.eta);
        }
    }
    let to64 = |p: &[f32; 3]| Vector3::from(*p).cast::<f64>();
    let input = AlignmentInput {
        edges: query.edges.iter().map(to64).collect(),
        planes: query.planes.iter().map(to64).collect(),
        intensity: query
            .cloud
            .iter()
            .map(|c| IntensityPoint {
                point: to64(&c.position),
                eta: f64::from(c.eta),
                normal: Vector3::zeros(),
            })
            .collect(),
    };
    let maps = MapView {
        edges: &edges,
        planes: &planes,
        intensity: &intensity,
    };
    let scored: Vec<Vector3<f64>> = input
        .edges
        .iter()
        .chain(&input.planes)
        .filter(|p| p.z as f32 >= config.floor_height)
        .copied()
        .collect();
    let mut nearest = Vec::with_capacity(1);
    let mut inlier_ratio = |pose: &Isometry3<f64>| {
        let inliers = scored
            .iter()
            .filter(|p| {
                all.nearest(
                    &(pose * Point3::from(**p)).coords.cast(),
                    1,
                    config.inlier_distance,
                    &mut nearest,
                );
                !nearest.is_empty()
            })
            .count();
        inliers as f64 / scored.len().max(1) as f64
    };
    let mut best: Option<Verification> = None;
    for guess in guesses {
        let coarse = align(guess, &input, maps, &config.coarse);
        let fine = align(&coarse.pose, &input, maps, &config.fine);
        let correspondences = fine.edges + fine.planes;
        let result = Verification {
            accepted: false,
            relative: fine.pose,
            inlier_ratio: inlier_ratio(&fine.pose),
            correspondences,
            cost: fine.cost,
            degenerate: fine.degenerate,
        };
        // Better: more inliers; equal, the lower cost. Deterministic for equal input.
        let better = best
            .as_ref()
            .is_none_or(|b| (result.inlier_ratio, -result.cost) > (b.inlier_ratio, -b.cost));
        if better {
            best = Some(result);
        }
    }
    let mut v = best.unwrap_or(Verification {
        accepted: false,
        relative: Isometry3::identity(),
        inlier_ratio: 0.0,
        correspondences: 0,
        cost: f64::INFINITY,
        degenerate: true,
    });
    v.accepted = v.inlier_ratio >= config.min_inlier_ratio
        && v.correspondences >= config.min_correspondences
        && v.cost <= config.max_cost
        && !v.degenerate;
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::config::KeyframeConfig;
    use crate::backend::keyframe::Keyframe;
    use crate::se3::{exp, log};
    use crate::test_scenes::{keyframe_at, room};
    use nalgebra::Vector6;

    #[test]
    fn verification_recovers_the_relative_pose_and_accepts() {
        let candidate = keyframe_at(&Isometry3::identity());
        let truth = exp(&Vector6::new(0.0, 0.0, 0.6, 0.7, -0.4, 0.0));
        let query = keyframe_at(&truth);
        // The ISC yaw guess is off by a sector (6°), the translation unknown.
        let guess = Isometry3::rotation(Vector3::z() * (0.6 + 6f64.to_radians()));
        let submap = [Placed {
            pose: Isometry3::identity(),
            keyframe: &candidate,
        }];
        let v = verify(&query, &submap, &[guess], &VerificationConfig::default());
        let error = log(&(v.relative.inverse() * truth));
        assert!(error.norm() < 0.02, "{error} {v:?}");
        assert!(v.accepted, "{v:?}");
    }

    #[test]
    fn a_different_place_is_rejected() {
        let candidate = keyframe_at(&Isometry3::identity());
        // The same walls seen 90° turned and mirrored: the room does not fit itself so.
        let (planes, edges) = room();
        let mirror = |p: &Vector3<f64>| Vector3::new(p.y * 1.3, -p.x * 0.7, p.z);
        let input = AlignmentInput {
            edges: edges.iter().map(mirror).collect(),
            planes: planes.iter().map(mirror).collect(),
            intensity: Vec::new(),
        };
        let query = Keyframe::new(
            0,
            Isometry3::identity(),
            &input,
            std::iter::empty(),
            &KeyframeConfig::default(),
        );
        let submap = [Placed {
            pose: Isometry3::identity(),
            keyframe: &candidate,
        }];
        let v = verify(
            &query,
            &submap,
            &[Isometry3::identity()],
            &VerificationConfig::default(),
        );
        assert!(!v.accepted, "{v:?}");
    }

    #[test]
    fn search_returns_the_similar_descriptors_best_first() {
        let config = ScanContextConfig::default();
        let place = |seed: f32| {
            (0..2000).map(move |i| {
                let a = i as f32 * 0.00314;
                let r = 5.0 + 3.0 * (a * seed).sin().abs();
                (
                    Vector3::new(r * a.cos(), r * a.sin(), 0.5),
                    30.0 + 50.0 * (a * 3.0 * seed).cos().abs(),
                )
            })
        };
        let descriptors: Vec<ScanContext> = (0..50)
            .map(|k| ScanContext::new(place(1.0 + k as f32 * 0.37), &config))
            .collect();
        let query = ScanContext::new(place(1.0 + 17.0 * 0.37), &config);
        let found = search(&query, &descriptors, |_| true, &config);
        assert_eq!(found.first().map(|c| c.index), Some(17), "{found:?}");
        assert!(found.windows(2).all(|w| w[0].similarity >= w[1].similarity));
        let none = search(&query, &descriptors, |i| i != 17, &config);
        assert!(none.iter().all(|c| c.index != 17));
    }
}
