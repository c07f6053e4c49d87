//! Every parameter of the back end, grouped by the step of `method.md` it belongs to, with
//! defaults for a VLP-16 on a warehouse AGV. The paper gives no values for any of them
//! (`method.md`, errata); where the authors' code has one, the comment says how ours differs.

use crate::config::SolverConfig;

use super::pose_graph::PoseGraphConfig;

/// Step 6: when a sweep becomes a keyframe, and what it keeps.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeConfig {
    /// Travelled this far since the last keyframe, m (LIO-SAM's 1 m).
    pub min_distance: f64,
    /// Or turned this much, rad (15°).
    pub min_rotation: f64,
    /// Or this much time has passed, ns (a robot standing still still gets a keyframe now and
    /// then, so the graph has no long gaps in time).
    pub max_interval_ns: u64,
    /// Edge, plane and descriptor points are thinned to one per voxel of this size, m.
    pub voxel: f32,
    /// Edge points kept, at most.
    pub max_edges: usize,
    /// Plane points kept, at most.
    pub max_planes: usize,
    /// Calibrated points kept (for the descriptor and the verification's intensity map).
    pub max_cloud: usize,
    /// A keyframe within this of an earlier one that still holds its points (at the graph's
    /// poses, and not from the stretch of path just behind it) releases its own once the back
    /// end has processed it, m; 0 keeps every keyframe's. A robot that drives the same aisles for
    /// months would otherwise add ~80 kB per metre driven; a released keyframe keeps its node,
    /// edges and descriptor (~5 kB), so the trajectory is still corrected through it, but it is
    /// no loop candidate: the earlier keyframe stands for the place. The keyframe spacing: on a
    /// second pass along a path, nearly every new keyframe has an old one this close.
    pub redundant_within: f64,
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        Self {
            min_distance: 1.0,
            min_rotation: 15f64.to_radians(),
            max_interval_ns: 5_000_000_000,
            voxel: 0.3,
            max_edges: 1000,
            max_planes: 1500,
            max_cloud: 3000,
            redundant_within: 1.0,
        }
    }
}

/// Step 7: the Intensity Scan Context and the candidate search.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScanContextConfig {
    /// Sectors (columns) around the sensor: 6° each.
    pub sectors: usize,
    /// Rings (rows) out to `max_radius`.
    pub rings: usize,
    /// Outer radius, m. Indoors walls are rarely farther; the authors' 90 m (KITTI) would
    /// leave most rings empty in a warehouse.
    pub max_radius: f32,
    /// Inner radius, m: the robot itself and the noisiest returns.
    pub min_radius: f32,
    /// Points below this height in the sensor frame are left out, m (none by default: floor
    /// markings are what an aisle has that its neighbour does not).
    pub min_height: f32,
    /// Points above this height are left out, m (ceilings repeat).
    pub max_height: f32,
    /// Keyframes less than this far back along the path are not candidates, m: they are the
    /// same stretch of odometry, not a loop.
    pub exclude_recent_distance: f64,
    /// Candidates must lie within this of the current keyframe's estimated position, m…
    pub search_radius: f64,
    /// …plus this fraction of the path travelled since them (odometry drifts with distance;
    /// the authors' code gates at 3 % of it).
    pub search_drift_fraction: f64,
    /// Stored keyframes ranked by ring key; the best this many get the full shift search.
    pub ring_key_candidates: usize,
    /// Similarity a candidate needs to be verified.
    pub similarity_threshold: f64,
    /// Candidates verified per keyframe at most, best similarity first.
    pub max_verifications: usize,
    /// Keyframes without a search after an accepted loop (the authors' code waits 20 frames):
    /// the next keyframes see the same place, and one loop per visit is enough to correct it.
    pub cooldown_after_accept: usize,
    /// Likewise after a rejected verification (the authors' code: 2).
    pub cooldown_after_reject: usize,
}

impl Default for ScanContextConfig {
    fn default() -> Self {
        Self {
            sectors: 60,
            rings: 20,
            max_radius: 40.0,
            min_radius: 1.0,
            min_height: f32::NEG_INFINITY,
            max_height: 2.5,
            exclude_recent_distance: 15.0,
            search_radius: 5.0,
            search_drift_fraction: 0.03,
            ring_key_candidates: 10,
            similarity_threshold: 0.6,
            max_verifications: 2,
            cooldown_after_accept: 10,
            cooldown_after_reject: 2,
        }
    }
}

/// Step 8: geometric verification of a candidate.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VerificationConfig {
    /// Keyframes on each side of the candidate placed into its submap.
    pub submap_neighbours: usize,
    /// The coarse alignment from the ISC yaw guess: wide neighbour search, many rounds.
    pub coarse: SolverConfig,
    /// The fine alignment that scores the result: tight neighbour search.
    pub fine: SolverConfig,
    /// Fraction of the query's off-floor edge and plane points that must lie within
    /// `inlier_distance` of a submap point after the fine alignment. The floor is left out of
    /// this score because it fits anywhere: in a sweep it is the largest plane.
    pub min_inlier_ratio: f64,
    /// See `min_inlier_ratio`, m (keyframe points are thinned to 0.3 m voxels).
    pub inlier_distance: f32,
    /// Points lower than this in the sensor frame are floor for the score, m (the sensor sits
    /// 0.5–1 m up on an AGV).
    pub floor_height: f32,
    /// Largest rotation between the aligned loop and the graph's own relative pose, rad.
    /// Odometry's heading drifts by a few degrees per lap at most; a symmetric place matched
    /// the wrong way round (a corridor seen from its other end) disagrees by ~180°.
    pub max_rotation_disagreement: f64,
    /// Fewest such correspondences.
    pub min_correspondences: usize,
    /// Largest mean robust cost per residual of the fine alignment (Huber at 0.1 m: 0.5·r² for
    /// small residuals, so 0.0012 is an RMS of about 5 cm).
    pub max_cost: f64,
}

impl Default for VerificationConfig {
    fn default() -> Self {
        // Every residual weighs alike here (no angular weighting): the loop's score and its
        // `max_cost` were measured that way, and a keyframe's thinned cloud has few far returns.
        let coarse = SolverConfig {
            outer_iterations: 12,
            inner_iterations: 3,
            max_neighbour_distance: 2.0,
            plane_tolerance: 0.1,
            min_correspondences: 0,
            angular_noise: 0.0,
            ..SolverConfig::default()
        };
        // A loop has no motion prior: only geometry can settle each direction of its
        // translation, since descriptors and reflectivity patterns repeat (posters along a
        // corridor). So the fine alignment must be constrained in every direction with a margin
        // the odometry does not need: 0.05 information per plane correspondence in the weakest
        // direction (15 % of an even 1/3), not 0.01. Measured on the simulated scenes: true
        // loops in the warehouse and the yard 0.23–0.27; corridor look-alikes up to 0.016.
        let fine = SolverConfig {
            outer_iterations: 3,
            inner_iterations: 3,
            max_neighbour_distance: 1.0,
            min_correspondences: 0,
            angular_noise: 0.0,
            degeneracy_threshold: 0.05,
            ..SolverConfig::default()
        };
        Self {
            submap_neighbours: 4,
            coarse,
            fine,
            min_inlier_ratio: 0.6,
            inlier_distance: 0.3,
            floor_height: -0.3,
            max_rotation_disagreement: 0.35,
            min_correspondences: 200,
            max_cost: 0.0012,
        }
    }
}

/// Step 9: the edges' uncertainty and the optimiser.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GraphConfig {
    /// 1σ translation error of an odometry edge, m, plus `odometry_sigma_per_metre` per metre
    /// of the edge.
    pub odometry_sigma_translation: f64,
    /// See above (the simulated odometry drifts 0.3–0.5 %; 1 % leaves room).
    pub odometry_sigma_per_metre: f64,
    /// 1σ rotation error of an odometry edge, rad.
    pub odometry_sigma_rotation: f64,
    /// 1σ translation error of a verified loop, m.
    pub loop_sigma_translation: f64,
    /// 1σ rotation error of a verified loop, rad.
    pub loop_sigma_rotation: f64,
    /// The optimiser (its Cauchy kernel applies to loops).
    pub optimizer: PoseGraphConfig,
    /// While running, an optimisation moves only the newest this-many keyframes and holds the
    /// older ones where they are, so it costs the same after hours of driving as after
    /// minutes (a robot repeating its route adds a keyframe every metre or so; with whole-graph
    /// optimisations a soak's CPU time per sweep grew from 10.6 to 18.4 ms over 12,000
    /// keyframes). A loop closed over more keyframes than this corrects only their newest part.
    /// The last optimisation of a run moves them all. 0: always the whole graph.
    pub optimize_window: usize,
}

impl Default for GraphConfig {
    fn default() -> Self {
        Self {
            odometry_sigma_translation: 0.005,
            odometry_sigma_per_metre: 0.01,
            odometry_sigma_rotation: 0.002,
            loop_sigma_translation: 0.05,
            loop_sigma_rotation: 0.01,
            optimizer: PoseGraphConfig::default(),
            optimize_window: 1000,
        }
    }
}

/// Step 9: every keyframe that sees the floor is tied to the one floor plane of the run (see
/// [`super::floor`]). For sites with one flat floor, as a warehouse's; switch it off where
/// the robot drives ramps between levels or across a slope.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FloorConfig {
    /// Tie keyframes to the floor.
    pub enabled: bool,
    /// Returns within this horizontal distance of the sensor are fitted, m: close enough that
    /// a tilt error of a few mrad moves them by less than the range noise.
    pub radius: f64,
    /// Fewest returns in the fit (a keyframe keeps one per 0.3 m voxel).
    pub min_points: usize,
    /// Smallest spread of the fitted returns across their main direction, m (square root of
    /// the second covariance eigenvalue): returns along one line leave the tilt about it free.
    pub min_spread: f64,
    /// Largest RMS distance of the returns from the fitted floor, m.
    pub max_rms: f64,
    /// The floor is looked for within this of where the graph expects it, and the fit may lie
    /// this far from it, m; a fit must also hold half the returns from this far above it down.
    pub search_band: f64,
    /// The fit's normal may be this far from the one the graph expects (or, for the run's first
    /// floor, from the sensor's z axis), rad (3°): a ramp is not the floor.
    pub max_tilt: f64,
    /// The first floor of a run is the most populated layer at least this far below the
    /// sensor, m.
    pub min_clearance: f64,
    /// 1σ error of a keyframe's measured height above the floor, m: the VLP-16's ±3 cm range
    /// accuracy, averaged over the fit but not its calibration's bias.
    pub sigma_height: f64,
    /// 1σ error of a keyframe's measured tilt, rad: 3 mrad lifts the floor 10 m away by 3 cm.
    pub sigma_tilt: f64,
    /// The graph is optimised after this many floor edges (and after every accepted loop), so
    /// the map pose follows the floor in small steps.
    pub optimize_every: usize,
}

impl Default for FloorConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            radius: 12.0,
            min_points: 50,
            min_spread: 0.5,
            max_rms: 0.03,
            search_band: 0.3,
            max_tilt: 3f64.to_radians(),
            min_clearance: 0.3,
            sigma_height: 0.02,
            sigma_tilt: 0.003,
            optimize_every: 10,
        }
    }
}

/// The whole back end.
#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BackEndConfig {
    /// Step 6.
    pub keyframes: KeyframeConfig,
    /// Step 7.
    pub scan_context: ScanContextConfig,
    /// Step 8.
    pub verification: VerificationConfig,
    /// Step 9.
    pub graph: GraphConfig,
    /// Step 9: the floor as a landmark.
    pub floor: FloorConfig,
}
