//! Association: each point's map correspondence (a line or plane fitted through its nearest
//! map neighbours, with the residual's weight), kept between alignments of the same points.

use rustc_hash::FxHashMap;

use super::*;

/// A geometric correspondence fixed for one round: residual `e = P·(T·p − c)`, where `P` is the
/// projection onto the line's normal space (edges) or onto the plane normal (planes).
#[derive(Debug, Clone, Copy)]
pub(super) struct Model {
    pub(super) point: Vector3<f64>,
    pub(super) center: Vector3<f64>,
    pub(super) shape: Shape,
    /// The residual's scale: the square root of its weight (its noise at a frontal surface over
    /// its noise here, squared; see [`residual_weight`]), taken once at association rather than
    /// in every Levenberg–Marquardt trial.
    pub(super) scale: f64,
}

/// What a neighbourhood was fitted as.
#[derive(Debug, Clone, Copy)]
pub(super) enum Shape {
    /// A line with this unit direction: `P = I − d·dᵀ`.
    Line(Vector3<f64>),
    /// A plane with this unit normal: `P = n·nᵀ`, a scalar residual `n·(T·p − c)`.
    Plane(Vector3<f64>),
}

/// What an alignment found for each point — its map correspondence and where it was made, its
/// eight intensity cells (and whether its intensity residual is in the round's set, see
/// `IntensitySet`) — kept for another alignment of the same points against the same maps
/// (the same sweep deskewed again, its points moved by millimetres): each point keeps what is
/// still valid for it, by the rule of [`SolverConfig::reassociation_distance`].
#[derive(Debug, Default, Clone)]
pub struct Correspondences {
    pub(super) edges: Links,
    pub(super) planes: Links,
    pub(super) intensity: Vec<IntensityLink>,
}

/// An intensity point's eight map cells, and whether it has a residual in the current round.
#[derive(Debug, Default, Clone, Copy)]
pub(super) struct IntensityLink {
    pub(super) corners: Corners,
    pub(super) active: bool,
}

/// Which intensity points a [`build`] gives a residual.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum IntensitySet {
    /// Those the map covers at this pose (a round's first system): the set is recorded.
    Select,
    /// The recorded set (a trial within the round), so that its cost and the system's are sums
    /// over the same residuals. A point entering or leaving the map's cover as the pose moves
    /// by a millimetre would make the cost jump by its whole residual; Levenberg–Marquardt then
    /// rejected step after step for a rise no damping could remove.
    Keep,
}

impl Correspondences {
    /// Forgets everything (a new sweep, or the maps changed).
    pub fn clear(&mut self) {
        for links in [&mut self.edges, &mut self.planes] {
            links.at.clear();
            links.models.clear();
        }
        self.intensity.clear();
    }
}

/// Each point's correspondence and where (world frame) it was made. A point that has moved less
/// than [`SolverConfig::reassociation_distance`] since keeps it: its nearest neighbours, 0.1 m
/// or more apart in the map, would be the same, and the search is most of the solver's time.
#[derive(Debug, Default, Clone)]
pub(super) struct Links {
    pub(super) at: Vec<Vector3<f64>>,
    pub(super) models: Vec<Option<Model>>,
}

impl Links {
    /// For each point that moved enough (all of them the first time), fits a model to its nearest
    /// map neighbours at `pose`: `fit` turns the neighbourhood (centroid, covariance, the
    /// neighbours) into the residual's projection, or rejects it.
    pub(super) fn update(
        &mut self,
        pose: &Isometry3<f64>,
        points: &[Vector3<f64>],
        map: &LocalMap,
        config: &SolverConfig,
        neighbours: &mut Vec<Vector3<f32>>,
        fit: impl Fn(&Vector3<f64>, &Matrix3<f64>, &[Vector3<f32>]) -> Option<Shape>,
    ) -> usize {
        let fresh = self.at.len() != points.len();
        if fresh {
            self.at.clear();
            self.at.resize(points.len(), Vector3::zeros());
            self.models.clear();
            self.models.resize(points.len(), None);
        }
        let limit_sq = config.reassociation_distance.powi(2);
        let mut updated = 0;
        for (i, p) in points.iter().enumerate() {
            let q = (pose * Point3::from(*p)).coords;
            if !fresh && (q - self.at[i]).norm_squared() <= limit_sq {
                continue;
            }
            self.at[i] = q;
            self.models[i] = associate(pose, p, &q, map, config, neighbours, &fit);
            updated += 1;
        }
        updated
    }

    /// Appends the current models to `models`; returns how many there are.
    pub(super) fn collect(&self, models: &mut Vec<Model>) -> usize {
        let before = models.len();
        models.extend(self.models.iter().flatten());
        models.len() - before
    }
}

/// Fits a model for the point `p` (sensor frame), seen at `q` (world), to its nearest map
/// neighbours.
pub(super) fn associate(
    pose: &Isometry3<f64>,
    p: &Vector3<f64>,
    q: &Vector3<f64>,
    map: &LocalMap,
    config: &SolverConfig,
    neighbours: &mut Vec<Vector3<f32>>,
    fit: &impl Fn(&Vector3<f64>, &Matrix3<f64>, &[Vector3<f32>]) -> Option<Shape>,
) -> Option<Model> {
    map.nearest(
        &q.cast(),
        config.neighbours,
        config.max_neighbour_distance,
        neighbours,
    );
    if neighbours.len() < config.neighbours {
        return None;
    }
    let (center, covariance) = covariance(neighbours);
    fit(&center, &covariance, neighbours).map(|shape| Model {
        point: *p,
        center,
        shape,
        scale: residual_weight(pose, p, &shape, config).sqrt(),
    })
}

/// A geometric residual's weight from how much an angular error of the ray moves the point off
/// its model. An angular error δ (the sweep's vibration and residual motion, the beam's width)
/// displaces a return at range r by r·δ across its ray, and a plane sees the part along its
/// normal, r·δ·sin α at incidence α: |p × n|·δ (a line, the part leaving it: |p × d|·δ). Range
/// noise σ adds along the ray (taken whole, the map's own fit included), so the residual's
/// variance is σ² + (|p × n|·δ)², and the weight σ² over that: 1 on a wall seen head-on, small
/// for ground seen far away at a grazing angle, which a tilt of the sensor lifts by metres.
pub(super) fn residual_weight(
    pose: &Isometry3<f64>,
    p: &Vector3<f64>,
    shape: &Shape,
    config: &SolverConfig,
) -> f64 {
    let direction = match shape {
        Shape::Plane(n) => n,
        Shape::Line(d) => d,
    };
    let local = pose.rotation.inverse_transform_vector(direction);
    angular_weight(p.cross(&local).norm_squared(), config)
}

/// The weight σ² / (σ² + lever²·δ²) of a residual whose point (sensor frame) moves `lever` m per
/// radian of ray error: |p × n| for a plane with normal n, |p × d| for a line along d (the
/// part of an angular error that leaves the line). See [`residual_weight`].
pub fn angular_weight(lever_sq: f64, config: &SolverConfig) -> f64 {
    let noise = config.plane_noise * config.plane_noise;
    noise / (noise + lever_sq * config.angular_noise * config.angular_noise)
}

/// Correspondences made before a sweep's close for the edges and planes picked early, by the
/// point's index in its scan: at the close, [`Self::seed`] hands them to the sweep's first
/// alignment, which keeps each one its point still meets there (within
/// [`SolverConfig::reassociation_distance`] of where it was made, the rule every later round
/// applies) and searches the others. Made against the maps as they are: whatever changes the
/// maps must [`Self::clear`] them.
#[derive(Debug, Default, Clone)]
pub struct EarlyCorrespondences {
    /// The sweep they were made for: its first return's time, ns.
    sweep: u64,
    edges: FxHashMap<u32, Early>,
    planes: FxHashMap<u32, Early>,
}

/// One early correspondence: where (world frame) and what.
#[derive(Debug, Clone, Copy)]
struct Early {
    at: Vector3<f64>,
    model: Option<Model>,
}

impl EarlyCorrespondences {
    /// Forgets them all.
    pub fn clear(&mut self) {
        self.edges.clear();
        self.planes.clear();
    }

    /// How many there are.
    pub fn len(&self) -> usize {
        self.edges.len() + self.planes.len()
    }

    /// None made.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Associates, at `pose`, the edges and planes of sweep `sweep` (its first return's time)
    /// not associated yet: each given as its return's index in the scan and what `deskew` turns
    /// into the point in the sensor frame at the reference time `pose` is for (only those not
    /// associated yet are deskewed). Those of another sweep are dropped first.
    pub fn associate<T>(
        &mut self,
        sweep: u64,
        pose: &Isometry3<f64>,
        (edges, planes): (
            impl Iterator<Item = (u32, T)>,
            impl Iterator<Item = (u32, T)>,
        ),
        deskew: impl Fn(T) -> Vector3<f64>,
        maps: MapView<'_>,
        config: &SolverConfig,
    ) {
        if sweep != self.sweep {
            self.clear();
            self.sweep = sweep;
        }
        let mut neighbours = Vec::with_capacity(8);
        let line = |_: &_, covariance: &_, _: &_| line_model(config, covariance);
        let plane =
            |center: &_, covariance: &_, near: &_| plane_model(config, center, covariance, near);
        for (id, f) in edges {
            self.edges.entry(id).or_insert_with(|| {
                let p = deskew(f);
                let q = (pose * Point3::from(p)).coords;
                let model = associate(pose, &p, &q, maps.edges, config, &mut neighbours, &line);
                Early { at: q, model }
            });
        }
        for (id, f) in planes {
            self.planes.entry(id).or_insert_with(|| {
                let p = deskew(f);
                let q = (pose * Point3::from(p)).coords;
                let model = associate(pose, &p, &q, maps.planes, config, &mut neighbours, &plane);
                Early { at: q, model }
            });
        }
    }

    /// Starts `kept` for a sweep's first alignment from `pose`: the points `input` holds, whose
    /// returns' indices in the scan are `ids` (edges, planes), take the early correspondence
    /// made for their return, if any, with the residual's point and scale as they are now (the
    /// early one was deskewed to the sweep's first return).
    pub fn seed(
        &self,
        kept: &mut Correspondences,
        (edges, planes): (&[u32], &[u32]),
        input: &AlignmentInput,
        pose: &Isometry3<f64>,
        config: &SolverConfig,
    ) {
        kept.clear();
        let sets = [
            (&mut kept.edges, edges, &input.edges, &self.edges),
            (&mut kept.planes, planes, &input.planes, &self.planes),
        ];
        for (links, ids, points, early) in sets {
            for (id, p) in ids.iter().zip(points) {
                let found = early.get(id);
                links
                    .at
                    .push(found.map_or(Vector3::repeat(f64::INFINITY), |e| e.at));
                links
                    .models
                    .push(found.and_then(|e| e.model).map(|m| Model {
                        point: *p,
                        scale: residual_weight(pose, p, &m.shape, config).sqrt(),
                        ..m
                    }));
            }
        }
    }
}
