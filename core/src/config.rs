//! Every parameter of the odometry in one place, grouped by the step of `method.md` it belongs
//! to, with defaults that work on a VLP-16 at 10 Hz. Each stage receives only its own section.
//! The structs deserialise from the daemon's TOML (every key optional, unknown keys refused) and
//! [`OdometryConfig::validate`] refuses values no run could work with.

use serde::Deserialize;

/// Step 1: intensity calibration.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrationConfig {
    /// Floor on cos α, so grazing returns do not explode (cos 80°).
    pub min_cos_incidence: f32,
    /// Below this cos α (72.5°) the calibrated value is not trusted for the intensity map or
    /// residual: the sensor reports a few counts there (100·ρ·cos α, rounded), a small error in
    /// the normal changes η a lot, and the error depends on the viewpoint, so averaging it over
    /// viewpoints blurs the map.
    pub min_reliable_cos: f32,
    /// Returns with a raw reflectivity below this are weak (noisy range): dropped.
    pub min_reflectivity: u8,
    /// Neighbours farther apart than this fraction of the range are not on the same surface.
    pub neighbour_gap: f32,
    /// Calibrated values are clamped to this (diffuse surfaces report at most 100).
    pub max_calibrated: f32,
    /// A return this close (m) to the last one on its ring whose normal was estimated takes
    /// that normal instead of estimating its own. The estimate reaches at least 0.2 m either
    /// side, so returns 0.1 m apart share most of its support; a wall 2 m away puts 14 returns
    /// in 0.1 m, each of which would walk 20 steps either way. On the simulated scenes 0.05 and
    /// 0.1 gave the same drift (within 0.01 %). 0 estimates every normal.
    pub normal_spacing: f32,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self {
            min_cos_incidence: 0.17,
            min_reliable_cos: 0.3,
            min_reflectivity: 1,
            neighbour_gap: 0.05,
            max_calibrated: 150.0,
            normal_spacing: 0.1,
        }
    }
}

/// Step 2: salient points.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureConfig {
    /// Neighbours on each side used for roughness.
    pub neighbours: usize,
    /// Sectors per ring, each with its own caps.
    pub sectors: usize,
    /// Weight of the geometric roughness σᴳ (LOAM's normalised curvature). Its scale: a 90°
    /// corner seen at the VLP-16's 0.2° step gives ≈ 0.0074; range noise of 1.5 cm on a plane
    /// spreads it by ≈ 0.016 / r (1σ), so nearer than ~2 m noise hides a corner.
    pub geometric_weight: f32,
    /// Weight of the intensity roughness σᴵ (mean |Δη| / 100). A painted edge of 60 units gives
    /// σᴵ ≈ 0.3, so 0.03 ranks it with a geometric corner. Off by default: on the simulated
    /// warehouse, corridor and yard, edges picked by reflectivity made the drift worse
    /// (0.29 → 0.34 %, 55 → 72 %, 0.55 → 0.62 %); the intensity residual uses σᴵ regardless.
    pub intensity_weight: f32,
    /// σ above which a point may be an edge, for a 0.2° azimuth step (scaled with the sweep's
    /// own step).
    pub edge_threshold: f32,
    /// σᴳ below which a point may be planar (the map-side plane check does the rest), for a
    /// 0.2° azimuth step (scaled likewise).
    pub plane_threshold: f32,
    /// Edges kept per sector.
    pub edges_per_sector: usize,
    /// The sensor's range noise (1σ), m. Noise alone spreads σᴳ by ≈ σ·√((2k + 1)/2k) / r at
    /// range r: an edge must exceed the threshold by three times that, and a plane may be that
    /// rough.
    pub range_noise: f32,
    /// Returns nearer than this are the robot or noise.
    pub min_range: f32,
    /// Returns farther than this are too sparse to describe a surface.
    pub max_range: f32,
    /// Planar points are thinned to one per voxel of this size (m).
    pub plane_voxel: f32,
    /// Planar points kept per sweep at most, spread evenly over those the voxels kept (in ring
    /// order); 0 keeps all. Stated for the 0.2° azimuth step of a VLP-16 at 600 rpm: a slower
    /// rotor's sweep, with finer steps, lasts as much longer and keeps proportionally more (twice
    /// at 300 rpm), a faster one keeps the whole cap. A sweep outdoors keeps over 3,000 after the
    /// voxels, and each costs a neighbour search and a residual in every trial of the alignment,
    /// while the pose has six degrees of freedom: on five 60 s simulated yard runs at 600 rpm,
    /// 1,500 gave a mean drift of 0.266 % against 0.267 % at 2,000 (1,200: 0.271 %, 1,000:
    /// 0.280 %); at 300 rpm a flat 1,500 moved three yard runs from 0.328 to 0.355 %, hence the
    /// scaling. Indoor sweeps (about 1,000 in the warehouse, 600 in the corridor) stay under it.
    pub max_planes: usize,
    /// Intensity points (largest σᴵ) kept per sweep for the intensity residual. Past the
    /// strongest gradients the residuals add more noise than constraint: on five simulated
    /// warehouse runs (60 s, seeds 3, 5, 11, 17 and 23), the scene whose sweeps fill the cap, the
    /// mean drift was 0.248 % at 1,500, 0.240 % at 1,000 and 0.237 % at 700; on fifteen other
    /// 60 s runs (five per scenario) 0.274 % at 1,000 and 0.273 % at 700 (the warehouse's five
    /// 0.244 → 0.242 %), and localising in a saved warehouse map as well (fitted frame, median
    /// of 20 runs: 0.026 → 0.027 m, 0.128 → 0.130°). Yard and corridor sweeps hold about 500.
    pub max_intensity_points: usize,
    /// σᴵ below which a point carries no intensity gradient worth matching: a mean reflectivity
    /// step of 10 units to its neighbours, above what calibrated reflectivity's noise alone makes
    /// (range noise in the normal, the unit's per-laser gain, the sensor's own noise). At 0.05
    /// the cap filled with noise points that pulled the axis a corridor's geometry leaves free:
    /// 60 s corridor runs, seeds 5 / 8 / 14, drifted 1.15 / 1.72 / 4.05 %, and 1.62 / 1.34 /
    /// 1.47 % at 0.1 (0.15 starves it: 5–13 %); warehouse 3 0.331 → 0.330 %, yard 7 / 19 / 8
    /// 0.67 / 0.58 / ~1.0 → 0.71 / 0.60 / 0.91 %.
    pub intensity_roughness_threshold: f32,
    /// Returns handed to the intensity map are at least this far apart along a ring, m. The
    /// map keeps one observation per sweep per cell (the mean of the sweep's returns in it), and
    /// a wall a few metres away puts twenty returns of a ring in a 0.2 m cell: a few of them
    /// give nearly the same mean for a fraction of the deskewing and hashing. 0 keeps all.
    pub intensity_map_spacing: f32,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        Self {
            neighbours: 5,
            sectors: 6,
            geometric_weight: 1.0,
            intensity_weight: 0.0,
            edge_threshold: 0.004,
            plane_threshold: 0.003,
            edges_per_sector: 20,
            range_noise: 0.02,
            min_range: 0.8,
            max_range: 90.0,
            plane_voxel: 0.5,
            max_planes: 1500,
            max_intensity_points: 700,
            intensity_roughness_threshold: 0.1,
            intensity_map_spacing: 0.05,
        }
    }
}

/// Step 3: the intensity map.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IntensityMapConfig {
    /// Voxel edge, m.
    pub voxel: f32,
    /// Cap on the running mean's count (of sweeps: a sweep's returns in a cell are one
    /// observation), so the map can follow changes.
    pub max_count: u16,
    /// Sum of trilinear weights of observed corners needed for a lookup.
    pub min_weight: f32,
}

impl Default for IntensityMapConfig {
    fn default() -> Self {
        Self {
            voxel: 0.2,
            max_count: 20,
            min_weight: 0.5,
        }
    }
}

/// Step 4: the local edge and plane maps.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocalMapConfig {
    /// Hash cell edge, m (neighbour search looks at the 27 cells around a query).
    pub cell: f32,
    /// Points kept per cell.
    pub points_per_cell: usize,
    /// Map points closer than this to an existing one in their cell are not added, m.
    pub min_spacing: f32,
    /// Cells farther than this from the robot are dropped, m.
    pub radius: f32,
    /// Plane points whose residual weight (`solver.angular_noise`) is below this are left out of
    /// the alignment and the map: seen at a grazing angle from far away, a sweep's small tilt
    /// lifts them by decimetres, and the map would keep that error.
    pub min_plane_weight: f64,
    /// A tracked sweep grows the maps (edge, plane and intensity) only once the sensor has moved
    /// this far since the last sweep that did, m, or turned [`Self::update_angle`]. A parked
    /// robot, whose pose jitters by millimetres, then keeps its map as it was when it stopped,
    /// instead of adding every person and forklift passing by, sweep after sweep, to the map it
    /// localises in; a moving one grows them every sweep, as before. Gating harder changes the
    /// odometry: at 0.3 m (the update skipped on two sweeps of three at 1.4 m/s) the warehouse's
    /// drift grew by a sixth (0.246 → 0.276 %, seed 3), and at 0.1 m the real 20 Hz capture's
    /// 0.7 m path (`shared/data`) ended 2.5 cm from where it ends ungated (2 mm at 1 cm). 0 grows
    /// them every sweep.
    pub update_distance: f64,
    /// See [`Self::update_distance`], rad.
    pub update_angle: f64,
}

impl Default for LocalMapConfig {
    fn default() -> Self {
        Self {
            cell: 1.0,
            points_per_cell: 20,
            min_spacing: 0.2,
            radius: 80.0,
            min_plane_weight: 0.1,
            update_distance: 0.01,
            update_angle: 0.002,
        }
    }
}

/// Step 4: the scan-to-map solver.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SolverConfig {
    /// Associate, then solve: this many times per sweep.
    pub outer_iterations: usize,
    /// Levenberg–Marquardt steps per association.
    pub inner_iterations: usize,
    /// Nearest map neighbours used for a line or a plane.
    pub neighbours: usize,
    /// The farthest neighbour may be this far, m.
    pub max_neighbour_distance: f32,
    /// A line needs its largest covariance eigenvalue this many times the second.
    pub line_ratio: f64,
    /// Every plane neighbour must lie within this of the plane, m. (F-LOAM's 0.2 m lets a
    /// neighbourhood straddling a floor and a wall pass as a tilted plane, which biases height.)
    pub plane_tolerance: f64,
    /// Huber threshold of the geometric residuals, m.
    pub huber_geometric: f64,
    /// Noise of a point-to-plane residual on a surface seen head-on, m (range noise and the
    /// map's plane fit).
    pub plane_noise: f64,
    /// Angular error of a return's ray, rad: vibration within a sweep that the constant-velocity
    /// deskew cannot follow, the beam's divergence. Plane residuals are weighted by
    /// plane_noise² / (plane_noise² + (|p × n|·angular_noise)²), line residuals likewise with
    /// |p × d|, so ground far away at a grazing angle, which a small tilt lifts by decimetres,
    /// does not steer the tilt. 0 weighs every residual alike.
    pub angular_noise: f64,
    /// Translation error of a sweep's pose that no count of residuals averages away, m (1σ per
    /// axis): motion within the sweep that the constant-velocity deskew cannot follow, and the
    /// local map's own error. It enters only the pose's reported covariance
    /// ([`crate::solver::Alignment::covariance`]), as `angular_noise` does for rotation. On the
    /// simulated runs (warehouse 3, yard 7, corridor 5) the pose's error changed from one sweep
    /// to the next by 2–13 mm per axis, against 1–3 mm from the residuals alone.
    pub motion_noise: f64,
    /// Use the intensity residual.
    pub use_intensity: bool,
    /// Weight turning reflectivity units into the metres of the geometric residuals. Larger
    /// weights pulled the pose off the ground truth even with a perfect map (see the README's
    /// odometry notes): 0.003 helps the corridor without hurting elsewhere.
    pub intensity_weight: f64,
    /// Huber threshold of the weighted intensity residual.
    pub huber_intensity: f64,
    /// Directions whose information per geometric correspondence is below this (0–1/3, rotations
    /// counted about the sensor as the displacement at the returns' RMS range) are not moved:
    /// the pose there stays at the prediction. A step along them would follow the small biases
    /// of the fitted lines and planes: over a bare floor, inside a sphere of equal ranges, along
    /// a corridor without intensity.
    pub hold_information: f64,
    /// Stop when an update moves less than this (rad and m). 1 mrad and 1 mm are half the
    /// sweep's own angular noise and a fifth of its translational one (`angular_noise`,
    /// `motion_noise`); at 1e-4 a fifth of the yard's evaluations of the normal equations were
    /// steps of a millimetre rejected for a cost 1e-5 higher. Measured over nine runs (three
    /// scenarios, 60 and 160 s): 28 % fewer evaluations, drift 0.285 → 0.285 %.
    pub convergence: f64,
    /// Stop when a step changes the cost by less than this fraction of it, up or down: the fit
    /// is at the resolution of its own model (Huber corners, trilinear intensity cells), where
    /// a rejected step stays rejected however much it is damped. Without this, three trials in
    /// four were such retries (12 s warehouse), each a full evaluation of the system.
    pub cost_tolerance: f64,
    /// Between rounds, a point keeps its correspondence unless the pose moved it more than
    /// this, m. A line or plane model stays valid as the point slides along it, and map points
    /// are ≥ 0.2 m apart, so a few centimetres seldom change a neighbourhood; re-searching
    /// every point every round was most of the solver's time. Measured on 60 s runs: 5 cm
    /// instead of 1 cm took 15–20 % off the alignment with drift unchanged within the seeds'
    /// spread (warehouse 3, yard 7 and 19, corridor 5). 10 cm, half the map's spacing, took
    /// another 5 % of the yard's instructions; drift over nine runs (three scenarios, 60 and
    /// 160 s) averaged 0.284 % against 0.286 % (15 cm: 0.288 %).
    pub reassociation_distance: f64,
    /// Fewer geometric correspondences than this: the sweep is not trusted (lost).
    pub min_correspondences: usize,
    /// A sweep whose returns cover less than this share of a turn's azimuth (see
    /// [`crate::calibration::RangeImage::coverage`]) is not aligned: it is lost, the
    /// prediction reported and the maps not grown from it. Such a sweep is what a stream cut
    /// short leaves (the sensor falling silent, a capture's end), and the few degrees it holds
    /// can slide along a corridor: a 13° sliver at the end of a simulated corridor run (seed 71)
    /// aligned 0.64 m from the truth, where the prediction was 6 mm off. A quarter turn: a
    /// sensor at a vehicle's corner, its body blocking up to half the view, clears it with every
    /// whole sweep, and a partial 37 % of a turn (yard, seed 42) aligned to within a millimetre of
    /// the truth's step.
    pub min_coverage: f32,
    /// The smallest eigenvalue of the plane correspondences' translational information per
    /// correspondence (0–1/3) below which the pose is reported degenerate. Measured on the
    /// simulated runs: corridor 0.002–0.005, warehouse ≥ 0.068, yard ≥ 0.022.
    pub degeneracy_threshold: f64,
    /// The same for rotation about the sensor (the rotational information per correspondence
    /// over the mean squared range, 0–1/3): a sweep whose every return lies at one range, a
    /// sphere about the sensor, leaves rotation unconstrained and reads 0.
    pub rotational_degeneracy_threshold: f64,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            outer_iterations: 5,
            inner_iterations: 2,
            neighbours: 5,
            max_neighbour_distance: 1.5,
            line_ratio: 3.0,
            plane_tolerance: 0.05,
            huber_geometric: 0.1,
            plane_noise: 0.02,
            angular_noise: 0.002,
            motion_noise: 0.005,
            use_intensity: true,
            intensity_weight: 0.003,
            huber_intensity: 0.1,
            hold_information: 0.002,
            convergence: 1e-3,
            cost_tolerance: 1e-4,
            reassociation_distance: 0.1,
            min_correspondences: 30,
            min_coverage: 0.25,
            degeneracy_threshold: 0.01,
            rotational_degeneracy_threshold: 0.002,
        }
    }
}

/// The whole odometry.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryConfig {
    /// Step 1.
    pub calibration: CalibrationConfig,
    /// Step 2.
    pub features: FeatureConfig,
    /// Step 3.
    pub intensity_map: IntensityMapConfig,
    /// Step 4, maps.
    pub local_map: LocalMapConfig,
    /// Step 4, solver.
    pub solver: SolverConfig,
}

impl OdometryConfig {
    /// The ablation without intensity: no intensity roughness in feature selection and no
    /// intensity residual (geometry only, as LOAM).
    pub fn geometry_only() -> Self {
        Self::default().without_intensity()
    }

    /// This configuration with intensity switched off (the geometry-only ablation).
    pub fn without_intensity(mut self) -> Self {
        self.features.intensity_weight = 0.0;
        self.solver.use_intensity = false;
        self
    }
}

/// A configuration value no run could work with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key} = {value}: {reason}")]
pub struct InvalidConfig {
    /// The key, dotted from the odometry section (`solver.huber_geometric`).
    pub key: &'static str,
    /// The value given.
    pub value: String,
    /// What it must be.
    pub reason: &'static str,
}

impl OdometryConfig {
    /// Checks every value that has a hard limit (positive sizes, ordered ranges, fractions).
    pub fn validate(&self) -> Result<(), InvalidConfig> {
        fn check<T: std::fmt::Display>(
            key: &'static str,
            value: T,
            ok: bool,
            reason: &'static str,
        ) -> Result<(), InvalidConfig> {
            if ok {
                Ok(())
            } else {
                Err(InvalidConfig {
                    key,
                    value: value.to_string(),
                    reason,
                })
            }
        }
        let positive = "must be a finite number > 0";
        let non_negative = "must be a finite number >= 0";
        let (c, f, i, l, s) = (
            &self.calibration,
            &self.features,
            &self.intensity_map,
            &self.local_map,
            &self.solver,
        );
        let pos32 = |v: f32| v.is_finite() && v > 0.0;
        let pos64 = |v: f64| v.is_finite() && v > 0.0;
        let non_negative32 = |v: f32| v.is_finite() && v >= 0.0;
        let non_negative64 = |v: f64| v.is_finite() && v >= 0.0;
        let cos = |v: f32| v.is_finite() && v > 0.0 && v <= 1.0;
        check(
            "calibration.min_cos_incidence",
            c.min_cos_incidence,
            cos(c.min_cos_incidence),
            "must be in (0, 1]",
        )?;
        check(
            "calibration.min_reliable_cos",
            c.min_reliable_cos,
            cos(c.min_reliable_cos),
            "must be in (0, 1]",
        )?;
        check(
            "calibration.neighbour_gap",
            c.neighbour_gap,
            pos32(c.neighbour_gap),
            positive,
        )?;
        check(
            "calibration.max_calibrated",
            c.max_calibrated,
            pos32(c.max_calibrated),
            positive,
        )?;
        check(
            "calibration.normal_spacing",
            c.normal_spacing,
            non_negative32(c.normal_spacing),
            non_negative,
        )?;
        check(
            "features.neighbours",
            f.neighbours,
            (1..=32).contains(&f.neighbours),
            "must be in 1..=32",
        )?;
        check(
            "features.sectors",
            f.sectors,
            (1..=360).contains(&f.sectors),
            "must be in 1..=360",
        )?;
        check(
            "features.geometric_weight",
            f.geometric_weight,
            non_negative32(f.geometric_weight),
            non_negative,
        )?;
        check(
            "features.intensity_weight",
            f.intensity_weight,
            non_negative32(f.intensity_weight),
            non_negative,
        )?;
        check(
            "features.edge_threshold",
            f.edge_threshold,
            pos32(f.edge_threshold),
            positive,
        )?;
        check(
            "features.plane_threshold",
            f.plane_threshold,
            pos32(f.plane_threshold),
            positive,
        )?;
        check(
            "features.range_noise",
            f.range_noise,
            pos32(f.range_noise),
            positive,
        )?;
        check(
            "features.min_range",
            f.min_range,
            non_negative32(f.min_range),
            non_negative,
        )?;
        check(
            "features.max_range",
            f.max_range,
            f.max_range.is_finite() && f.max_range > f.min_range,
            "must be finite and > features.min_range",
        )?;
        check(
            "features.plane_voxel",
            f.plane_voxel,
            pos32(f.plane_voxel),
            positive,
        )?;
        check(
            "features.intensity_map_spacing",
            f.intensity_map_spacing,
            non_negative32(f.intensity_map_spacing),
            non_negative,
        )?;
        check("intensity_map.voxel", i.voxel, pos32(i.voxel), positive)?;
        check(
            "intensity_map.max_count",
            i.max_count,
            i.max_count > 0,
            "must be > 0",
        )?;
        check(
            "intensity_map.min_weight",
            i.min_weight,
            i.min_weight.is_finite() && (0.0..=1.0).contains(&i.min_weight),
            "must be in [0, 1]",
        )?;
        check("local_map.cell", l.cell, pos32(l.cell), positive)?;
        check(
            "local_map.points_per_cell",
            l.points_per_cell,
            l.points_per_cell > 0,
            "must be > 0",
        )?;
        check(
            "local_map.min_spacing",
            l.min_spacing,
            non_negative32(l.min_spacing),
            non_negative,
        )?;
        check(
            "local_map.radius",
            l.radius,
            // The map's hash tells cells apart modulo 2²¹ of them (`local_map::packed`).
            l.radius.is_finite() && l.radius > l.cell && l.radius < l.cell * (1 << 20) as f32,
            "must be finite, > local_map.cell and < 2^20 cells",
        )?;
        check(
            "local_map.min_plane_weight",
            l.min_plane_weight,
            l.min_plane_weight.is_finite() && (0.0..=1.0).contains(&l.min_plane_weight),
            "must be in [0, 1]",
        )?;
        check(
            "local_map.update_distance",
            l.update_distance,
            non_negative64(l.update_distance),
            non_negative,
        )?;
        check(
            "local_map.update_angle",
            l.update_angle,
            non_negative64(l.update_angle),
            non_negative,
        )?;
        check(
            "solver.outer_iterations",
            s.outer_iterations,
            s.outer_iterations > 0,
            "must be > 0",
        )?;
        check(
            "solver.inner_iterations",
            s.inner_iterations,
            s.inner_iterations > 0,
            "must be > 0",
        )?;
        check(
            "solver.neighbours",
            s.neighbours,
            (3..=32).contains(&s.neighbours),
            "must be in 3..=32",
        )?;
        check(
            "solver.min_coverage",
            s.min_coverage,
            (0.0..=1.0).contains(&s.min_coverage),
            "must be in 0..=1",
        )?;
        check(
            "solver.max_neighbour_distance",
            s.max_neighbour_distance,
            pos32(s.max_neighbour_distance),
            positive,
        )?;
        check(
            "solver.line_ratio",
            s.line_ratio,
            s.line_ratio.is_finite() && s.line_ratio >= 1.0,
            "must be a finite number >= 1",
        )?;
        check(
            "solver.plane_tolerance",
            s.plane_tolerance,
            pos64(s.plane_tolerance),
            positive,
        )?;
        check(
            "solver.huber_geometric",
            s.huber_geometric,
            pos64(s.huber_geometric),
            positive,
        )?;
        check(
            "solver.plane_noise",
            s.plane_noise,
            pos64(s.plane_noise),
            positive,
        )?;
        check(
            "solver.angular_noise",
            s.angular_noise,
            non_negative64(s.angular_noise),
            non_negative,
        )?;
        check(
            "solver.motion_noise",
            s.motion_noise,
            non_negative64(s.motion_noise),
            non_negative,
        )?;
        check(
            "solver.intensity_weight",
            s.intensity_weight,
            non_negative64(s.intensity_weight),
            non_negative,
        )?;
        check(
            "solver.huber_intensity",
            s.huber_intensity,
            pos64(s.huber_intensity),
            positive,
        )?;
        check(
            "solver.convergence",
            s.convergence,
            pos64(s.convergence),
            positive,
        )?;
        check(
            "solver.cost_tolerance",
            s.cost_tolerance,
            non_negative64(s.cost_tolerance),
            non_negative,
        )?;
        check(
            "solver.degeneracy_threshold",
            s.degeneracy_threshold,
            non_negative64(s.degeneracy_threshold),
            non_negative,
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        assert_eq!(OdometryConfig::default().validate(), Ok(()));
        assert_eq!(OdometryConfig::geometry_only().validate(), Ok(()));
    }

    #[test]
    fn an_impossible_value_names_its_key() {
        let mut c = OdometryConfig::default();
        c.local_map.radius = 0.5;
        let e = c.validate().unwrap_err();
        assert_eq!(e.key, "local_map.radius");
        c.local_map.radius = 2.0e6;
        let e = c.validate().unwrap_err();
        assert_eq!(e.key, "local_map.radius");
        c = OdometryConfig::default();
        c.solver.huber_geometric = f64::NAN;
        assert_eq!(c.validate().unwrap_err().key, "solver.huber_geometric");
        c = OdometryConfig::default();
        c.solver.cost_tolerance = -1.0;
        assert_eq!(c.validate().unwrap_err().key, "solver.cost_tolerance");
        c = OdometryConfig::default();
        c.features.intensity_map_spacing = f32::INFINITY;
        assert_eq!(
            c.validate().unwrap_err().key,
            "features.intensity_map_spacing"
        );
        c = OdometryConfig::default();
        c.calibration.normal_spacing = -0.1;
        assert_eq!(c.validate().unwrap_err().key, "calibration.normal_spacing");
    }
}
