//! Step 2 of the method: salient points. Along each ring, a return's roughness is
//! σ = wᴳσᴳ + wᴵσᴵ, with σᴳ LOAM's range-invariant curvature `|Σⱼ(pⱼ − pᵢ)| / (2k·|pᵢ|)` and σᴵ
//! the mean |ηⱼ − ηᵢ| / 100 of the calibrated reflectivity. Each ring is split into sectors; in
//! each, the roughest returns become edges (neighbours suppressed), the geometrically smooth ones
//! planes (thinned by a voxel grid, then to a cap per sweep), and the ones with the largest σᴵ
//! intensity points. LOAM's rejection rules drop returns at occlusion boundaries and on surfaces
//! seen edge-on.

use std::collections::hash_map::Entry;
use std::ops::Range;

use nalgebra::Vector3;
use rustc_hash::FxHashMap;

use crate::calibration::RangeImage;
use crate::config::FeatureConfig;
use crate::scan::Scan;

/// A selected return: its position in the sensor frame at its firing, its time relative to the
/// sweep's reference time (s, ≤ 0) and its calibrated reflectivity (NaN if unknown).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Feature {
    /// Position at firing, sensor frame, m.
    pub position: [f32; 3],
    /// Firing time minus the reference time, s.
    pub dt: f32,
    /// Calibrated reflectivity η.
    pub eta: f32,
    /// Unit surface normal at the return (sensor frame), zero if unknown.
    pub normal: [f32; 3],
    /// The return's index in the scan's points.
    pub point: u32,
}

/// The features of one sweep: what the front end hands the odometry.
#[derive(Debug, Clone)]
pub struct SweepFeatures {
    /// The instant the sweep's pose describes, ns since the epoch.
    pub reference_ns: u64,
    /// Returns in the sweep, before selection.
    pub returns: usize,
    /// The share of a turn's azimuth the sweep's returns cover (see
    /// [`RangeImage::coverage`]); 1 where not measured.
    pub coverage: f32,
    /// Edges (geometric corners and intensity boundaries).
    pub edges: Vec<Feature>,
    /// Planar returns, one per voxel.
    pub planes: Vec<Feature>,
    /// Returns with the largest intensity roughness, for the intensity residual.
    pub intensity: Vec<Feature>,
    /// Valid calibrated returns, `intensity_map_spacing` apart along a ring: the intensity
    /// map's input.
    pub calibrated: Vec<Feature>,
}

impl Default for SweepFeatures {
    fn default() -> Self {
        Self {
            reference_ns: 0,
            returns: 0,
            coverage: 1.0,
            edges: Vec::new(),
            planes: Vec::new(),
            intensity: Vec::new(),
            calibrated: Vec::new(),
        }
    }
}

impl SweepFeatures {
    /// Empties them for the features of `scan`, whose returns `image` holds.
    fn restart(&mut self, scan: &Scan<'_>, image: &RangeImage) {
        self.reference_ns = scan.reference_ns;
        self.returns = scan.points.len();
        self.coverage = image.coverage();
        self.edges.clear();
        self.planes.clear();
        self.intensity.clear();
        self.calibrated.clear();
    }
}

/// Selects features; owns the buffers it reuses from sweep to sweep.
///
/// A return's roughness and LOAM's flags read only its ring's neighbours, so they can be
/// measured as the sweep streams in ([`Self::begin`], [`Self::extend`] after each batch the
/// range image calibrates, then [`Self::finish`]). The picks are made sector by sector, all
/// rings' sector before the next sector's; a sector is picked as soon as every ring has
/// measured it, by the [`SectorPlan`] the last sweep left, so that at the close only the last
/// sector's picks remain. [`Self::select`] does it all at once; both give the same features,
/// bit for bit, from the same plan.
#[derive(Debug, Default, Clone)]
pub struct FeatureSelector {
    /// Per ring: its places' values and roughness, measured so far.
    rings: Vec<RingRoughness>,
    /// The sectors' bounds and the thresholds of the open sweep's picks.
    plan: Option<SectorPlan>,
    /// Sectors of the open sweep picked so far.
    picked: usize,
    /// The open sweep's picks so far.
    picks: Picks,
    /// Per return of the sweep: handed to the intensity map.
    kept: Vec<bool>,
    /// Plane picks of the last sweep, before the cap: the open sweep's planes are thinned as
    /// if it had as many (see [`PlaneThinning`]).
    last_planes: usize,
}

/// How the open sweep's rings are cut into sectors, and the azimuth step its thresholds follow:
/// the last sweep's, whose rings were measured whole. A sector's picks need its bounds before
/// the ring ends; a sweep whose rings come out longer or shorter than planned by more than
/// [`PLAN_TOLERANCE`] of a sector, or whose step differs, is picked again at its close by its
/// own (see [`FeatureSelector::finish`]).
#[derive(Debug, Clone)]
struct SectorPlan {
    /// Per ring: its roughness entries.
    measured: Vec<usize>,
    /// The azimuth step, rad (`None` when too sparse to tell).
    step: Option<f32>,
}

/// How far (as a share of a sector) a ring's measured length may miss its plan and the sweep
/// keep the picks made by it: less than a sector, so that no bound moves past the next one's
/// planned place. A ring's entries are its returns, not its firings: a ring that sees sky over
/// part of the yard counts tens of returns more or fewer from sweep to sweep (half a sector in
/// the median on an open yard), and its bounds, cut by count, sit no nearer any azimuth than
/// that anyway.
const PLAN_TOLERANCE: f32 = 1.0;

impl SectorPlan {
    /// The roughness entries of sector `sector` of ring `r`, which has `measured` of them so
    /// far: equal shares of the planned entries, the last running to the ring's end.
    fn sector(&self, r: usize, sector: usize, sectors: usize, measured: usize) -> Range<usize> {
        let planned = self.measured[r];
        let per = planned.div_ceil(sectors).max(1);
        let hi = if sector + 1 == sectors {
            measured
        } else {
            ((sector + 1) * per).min(planned).min(measured)
        };
        (sector * per).min(hi)..hi
    }

    /// Whether a sweep whose rings and step came out as `own` was cut as planned.
    fn holds(&self, own: &SectorPlan, sectors: usize) -> bool {
        let steps_agree = match (self.step, own.step) {
            (Some(a), Some(b)) => (a - b).abs() <= 0.01 * a,
            (a, b) => a.is_none() && b.is_none(),
        };
        steps_agree
            && self.measured.len() == own.measured.len()
            && self
                .measured
                .iter()
                .zip(&own.measured)
                .all(|(&planned, &measured)| {
                    let slack = PLAN_TOLERANCE * planned.div_ceil(sectors) as f32;
                    (measured as f32 - planned as f32).abs() <= slack
                })
    }
}

/// One ring's values side by side, read from the sweep's per-point arrays once: a ring is every
/// sixteenth return, so each of the passes over it would otherwise load every cache line of
/// those arrays again. Filled place by place as the ring's returns are calibrated.
#[derive(Debug, Default, Clone)]
struct RingRoughness {
    /// Per place: the return's range, m.
    range: Vec<f32>,
    /// Per place: valid and within the feature range limits.
    usable: Vec<bool>,
    /// Per place: [η or 0, 1 if η is known else 0].
    eta: Vec<[f32; 2]>,
    /// Per place: LOAM's rules reject it (occlusion boundaries, surfaces seen edge-on). A depth
    /// jump flags places ahead of the last one loaded, so this may be the longer.
    unreliable: Vec<bool>,
    /// (σᴳ, σᴵ, place) of each usable place measured, in ring order.
    roughness: Vec<(f32, f32, u32)>,
    /// Per entry of `roughness`: the noise floor of σᴳ at its range ([`noise_floor`]; it falls
    /// as 1/r).
    noise: Vec<f32>,
    /// Σ positions over the window of the place last measured.
    window: Vector3<f64>,
    /// The next place to measure.
    next: usize,
    /// The position of the last return handed to the intensity map.
    last_kept: [f32; 3],
    /// Per place: next to a chosen edge.
    suppressed: Vec<bool>,
}

/// One sweep as the selection rules read it.
struct SweepView<'a> {
    scan: &'a Scan<'a>,
    image: &'a RangeImage,
    config: &'a FeatureConfig,
}

impl SweepView<'_> {
    /// Return `i` as a feature.
    fn feature(&self, i: usize) -> Feature {
        feature(self.scan, self.image, i)
    }
}

/// The edges and planes of `features`, returns of `scan` (which `image` has calibrated), as
/// features of `scan`, whose reference time may be another, into `out`.
pub(crate) fn features_of(
    scan: &Scan<'_>,
    image: &RangeImage,
    features: &SweepFeatures,
    out: &mut SweepFeatures,
) {
    out.restart(scan, image);
    let of = |f: &Feature| feature(scan, image, f.point as usize);
    out.edges.extend(features.edges.iter().map(of));
    out.planes.extend(features.planes.iter().map(of));
}

/// Return `i` of `scan`, which `image` has calibrated, as a feature.
fn feature(scan: &Scan<'_>, image: &RangeImage, i: usize) -> Feature {
    let p = &scan.points[i];
    let dt = (p.time_ns as f64 - scan.reference_ns as f64) * 1e-9;
    Feature {
        position: p.position,
        dt: dt as f32,
        eta: image.eta[i],
        normal: image.normal[i],
        point: i as u32,
    }
}

/// The sweep's thresholds: σᴳ of a corner grows with the azimuth step between returns (0.2° at
/// 600 rpm, 0.4° at 1200 rpm), so they follow the sweep's own step; the ranking is unchanged.
/// So does the cap on planar points: a slower rotor's finer steps make a sweep that lasts as
/// much longer, which keeps proportionally more (see [`FeatureConfig::max_planes`]).
struct Thresholds {
    edge: f32,
    plane: f32,
    /// 1 / the plane voxel's size, 1/m.
    per_voxel: f32,
    /// The sweep's cap on planar points: `max_planes` at the reference step and coarser.
    max_planes: usize,
}

impl Thresholds {
    /// The thresholds for a sweep of azimuth step `step` (rad; the reference step if unknown).
    fn new(config: &FeatureConfig, step: Option<f32>) -> Self {
        let step_ratio = step.map_or(1.0, |step| step / REFERENCE_STEP_RAD);
        Self {
            edge: config.edge_threshold * step_ratio.clamp(0.5, 4.0),
            plane: config.plane_threshold * step_ratio.clamp(0.5, 4.0),
            per_voxel: 1.0 / config.plane_voxel,
            max_planes: (config.max_planes as f32 / step_ratio.clamp(0.25, 1.0)).round() as usize,
        }
    }
}

impl RingRoughness {
    fn clear(&mut self) {
        self.range.clear();
        self.usable.clear();
        self.eta.clear();
        self.unreliable.clear();
        self.roughness.clear();
        self.noise.clear();
        self.window = Vector3::zeros();
        self.next = 0;
        self.last_kept = [f32::INFINITY; 3];
        self.suppressed.clear();
    }

    /// Loads ring `r`'s places up to `ready` (those calibrated), marks in `kept` those handed
    /// to the intensity map, flags them by LOAM's rules as far as their neighbours are in, and
    /// measures the roughness of each place whose `k` neighbours either side are in.
    fn advance(
        &mut self,
        image: &RangeImage,
        (r, ready): (usize, usize),
        config: &FeatureConfig,
        k: usize,
        kept: &mut [bool],
    ) {
        let spacing_sq = config.intensity_map_spacing * config.intensity_map_spacing;
        let members = &image.ring_points[r];
        let positions = &image.ring_positions[r];
        let loaded = self.range.len();
        for (w, &m) in members.iter().enumerate().take(ready).skip(loaded) {
            let m = m as usize;
            let (range, eta) = (image.range[m], image.eta[m]);
            let usable = image.valid[m] && range >= config.min_range && range <= config.max_range;
            self.range.push(range);
            self.usable.push(usable);
            // The intensity map's input: valid calibrated returns, `intensity_map_spacing`
            // apart along the ring.
            if usable && eta.is_finite() {
                let p = positions[w];
                let last = self.last_kept;
                let [dx, dy, dz] = [p.x - last[0], p.y - last[1], p.z - last[2]];
                if dx * dx + dy * dy + dz * dz >= spacing_sq {
                    self.last_kept = [p.x, p.y, p.z];
                    kept[m] = true;
                }
            }
            self.eta.push(if eta.is_finite() {
                [eta, 1.0]
            } else {
                [0.0, 0.0]
            });
            if self.unreliable.len() <= w {
                self.unreliable.resize(w + 1, false);
            }
            self.flag_unreliable(positions, w, k);
        }
        self.measure_roughness(positions, k, noise_floor(config, k, 1.0));
    }

    /// LOAM's rejection rules as place `w` arrives: a depth jump from the place before makes
    /// the `k` places on the far side unreliable (they may be occluded next sweep); the place
    /// before, much nearer or farther than both its neighbours, lies on a surface seen edge-on.
    fn flag_unreliable(&mut self, positions: &[Vector3<f32>], w: usize, k: usize) {
        if w == 0 {
            return;
        }
        let (ra, rb) = (self.range[w - 1], self.range[w]);
        // Squared, as the span below: a square root per return was the ring pass's largest cost.
        let gap_sq = (positions[w - 1] - positions[w]).norm_squared();
        if gap_sq > (0.1 * ra.min(rb) + 0.1).powi(2) {
            if ra > rb {
                for flag in &mut self.unreliable[w.saturating_sub(k)..w] {
                    *flag = true;
                }
            } else {
                if self.unreliable.len() < w + k {
                    self.unreliable.resize(w + k, false);
                }
                for flag in &mut self.unreliable[w..w + k] {
                    *flag = true;
                }
            }
        }
        if w >= 2 {
            let (before, at, after) = (self.range[w - 2], self.range[w - 1], rb);
            if (before - at).abs() > 0.02 * at && (after - at).abs() > 0.02 * at {
                self.unreliable[w - 1] = true;
            }
        }
    }

    /// Each usable place's (σᴳ, σᴵ, place) over a contiguous window of `k` neighbours, for the
    /// places whose window is loaded, and its noise floor (`noise_at_1m` at 1 m).
    fn measure_roughness(&mut self, positions: &[Vector3<f32>], k: usize, noise_at_1m: f32) {
        let first = self.roughness.len();
        // Σ positions over the window [w − k, w + k], slid along the ring: in f64, so the
        // additions and removals along a ring of 1800 returns leave no drift at f32's scale.
        let wide = |v: &Vector3<f32>| v.cast::<f64>();
        self.next = self.next.max(k);
        while self.next + k < self.range.len() {
            let w = self.next;
            self.next += 1;
            if w == k {
                self.window = positions[..2 * k].iter().map(wide).sum();
            }
            self.window += wide(&positions[w + k]);
            if w > k {
                self.window -= wide(&positions[w - k - 1]);
            }
            if !self.usable[w] {
                continue;
            }
            let range = self.range[w];
            let p = positions[w];
            // The window must be contiguous: no gap wider than a few steps.
            let span_sq = (positions[w - k] - positions[w + k]).norm_squared();
            if span_sq > ((2 * k) as f32 * 0.02 * range + 0.5).powi(2) {
                continue;
            }
            // Σⱼ(pⱼ − pᵢ) over the 2k neighbours.
            let sum = (self.window - wide(&p) * (2 * k + 1) as f64).cast::<f32>();
            let [ei, known] = self.eta[w];
            let mut eta_diff = 0f32;
            let mut eta_count = 0f32;
            if known > 0.0 {
                // Branch-free over the whole window: an unknown η adds 0 to both sums; the
                // return itself adds |ei − ei| = 0 and one to the count, taken back after.
                for &[ej, known] in &self.eta[w - k..w + k + 1] {
                    eta_diff += known * (ej - ei).abs();
                    eta_count += known;
                }
                eta_count -= 1.0;
            }
            let intensity = if eta_count > 0.0 {
                eta_diff / (eta_count * 100.0)
            } else {
                0.0
            };
            // |Σ|² for now: σᴳ below.
            self.roughness
                .push((sum.norm_squared(), intensity, w as u32));
        }
        // The square roots and divisions in a pass of their own: inside the loop above, each
        // waited on the one before; here they overlap.
        let scale = (2 * k) as f32;
        for entry in &mut self.roughness[first..] {
            let range = self.range[entry.2 as usize];
            entry.0 = entry.0.sqrt() / (scale * range);
            self.noise.push(noise_at_1m / range.max(0.1));
        }
    }
}

impl FeatureSelector {
    /// Opens a sweep of `rings` rings, dropping whatever was measured before. Its sectors follow
    /// the last sweep's plan if that had as many rings.
    pub fn begin(&mut self, rings: usize) {
        self.rings.resize_with(rings, RingRoughness::default);
        for ring in &mut self.rings {
            ring.clear();
        }
        self.kept.clear();
        if self
            .plan
            .as_ref()
            .is_some_and(|plan| plan.measured.len() != rings)
        {
            self.plan = None;
        }
        self.picks.restart();
        self.picked = 0;
    }

    /// Measures the roughness of the returns `image` has calibrated since the last call, and
    /// picks the sectors every ring has now measured (all but the last). A ring the image will
    /// calibrate again is left to [`Self::finish`].
    pub fn extend(&mut self, image: &RangeImage, config: &FeatureConfig) {
        let k = config.neighbours.max(1);
        self.kept.resize(image.len(), false);
        for (r, ring) in self.rings.iter_mut().enumerate().take(image.rings()) {
            if !image.redone(r) {
                let ready = image.calibrated_in_ring(r);
                ring.advance(image, (r, ready), config, k, &mut self.kept);
            }
        }
        let Some(plan) = self.plan.take() else {
            return;
        };
        let sectors = config.sectors.max(1);
        let limits = Thresholds::new(config, plan.step);
        while self.picked + 1 < sectors {
            let sector = self.picked;
            let measured = self.rings.iter().enumerate().all(|(r, ring)| {
                !image.redone(r)
                    && ring.roughness.len() >= plan.sector(r, sector, sectors, usize::MAX).end
            });
            if !measured {
                break;
            }
            self.pick_sector(image, config, (&plan, &limits), sector);
            self.picked += 1;
        }
        self.plan = Some(plan);
    }

    /// Selects the features of `scan`, whose returns `image` has calibrated, into `out`.
    pub fn select(
        &mut self,
        scan: &Scan<'_>,
        image: &RangeImage,
        config: &FeatureConfig,
        out: &mut SweepFeatures,
    ) {
        self.begin(image.rings());
        self.finish(scan, image, config, out);
    }

    /// [`Self::select`], continuing from what [`Self::extend`] measured and picked of `image`
    /// since [`Self::begin`]: ring by ring the rest of the roughness, the sectors left to pick
    /// (all of them again if a ring was recalibrated or the plan did not hold), then the
    /// intensity points and the intensity map's input. Leaves the plan for the next sweep.
    pub fn finish(
        &mut self,
        scan: &Scan<'_>,
        image: &RangeImage,
        config: &FeatureConfig,
        out: &mut SweepFeatures,
    ) {
        out.restart(scan, image);
        let k = config.neighbours.max(1);
        if self.rings.len() != image.rings() {
            self.begin(image.rings());
        }
        self.kept.resize(image.len(), false);
        let mut restart = false;
        for (r, (ring, members)) in self.rings.iter_mut().zip(&image.ring_points).enumerate() {
            if image.redone(r) || ring.range.len() > members.len() {
                ring.clear();
                for &m in members {
                    self.kept[m as usize] = false;
                }
                restart = true;
            }
            ring.advance(image, (r, members.len()), config, k, &mut self.kept);
        }
        let sectors = config.sectors.max(1);
        let step = image.azimuth_step();
        let own = SectorPlan {
            measured: self.rings.iter().map(|ring| ring.roughness.len()).collect(),
            step,
        };
        let plan = match self.plan.take() {
            Some(plan) if plan.holds(&own, sectors) => plan,
            _ => {
                restart = true;
                own.clone()
            }
        };
        if restart {
            self.picks.restart();
            for ring in &mut self.rings {
                ring.suppressed.clear();
            }
            self.picked = 0;
        }
        let limits = Thresholds::new(config, plan.step);
        for sector in self.picked..sectors {
            self.pick_sector(image, config, (&plan, &limits), sector);
        }
        self.picked = sectors;
        self.plan = Some(own);

        let sweep = SweepView {
            scan,
            image,
            config,
        };
        out.edges
            .extend(self.picks.edges.iter().map(|&i| sweep.feature(i as usize)));
        out.planes
            .extend(self.picks.planes.iter().map(|&i| sweep.feature(i as usize)));
        self.picks.keep_strongest_intensity(&sweep, out);
        let picked = out.planes.len();
        PlaneThinning::settled(limits.max_planes, self.last_planes, picked).apply(&mut out.planes);
        self.last_planes = picked;
        // In firing order, as the intensity map takes them.
        if scan.rings > 0 {
            for (i, _) in self.kept.iter().enumerate().filter(|(_, &kept)| kept) {
                out.calibrated.push(sweep.feature(i));
            }
        }
    }

    /// Sectors of the open sweep picked before its close.
    pub fn picked_early(&self) -> usize {
        self.picked
    }

    /// The edges and planes of the open sweep picked so far, from the `from`th edge and plane on
    /// (a plane's pick may still change to a rougher return of its voxel), as features of
    /// `scan`, whose returns `image` holds, into `out`; returns how many edges and planes were
    /// picked.
    pub fn early_features(
        &self,
        scan: &Scan<'_>,
        image: &RangeImage,
        config: &FeatureConfig,
        from: (usize, usize),
        out: &mut SweepFeatures,
    ) -> (usize, usize) {
        out.restart(scan, image);
        let picked =
            |picks: &[u32], from: usize, keeps: &dyn Fn(usize) -> bool, into: &mut Vec<Feature>| {
                into.extend(
                    picks
                        .iter()
                        .enumerate()
                        .skip(from)
                        .filter(|&(j, &i)| (i as usize) < scan.points.len() && keeps(j))
                        .map(|(_, &i)| feature(scan, image, i as usize)),
                );
            };
        picked(&self.picks.edges, from.0, &|_| true, &mut out.edges);
        // Those the planned thinning drops are left out: most sweeps keep it (see
        // `PlaneThinning::settled`).
        let limits = Thresholds::new(config, self.plan.as_ref().and_then(|plan| plan.step));
        let thinning = PlaneThinning::planned(limits.max_planes, self.last_planes);
        picked(
            &self.picks.planes,
            from.1,
            &|j| thinning.keeps(j),
            &mut out.planes,
        );
        (self.picks.edges.len(), self.picks.planes.len())
    }

    /// Every ring's (σᴳ, σᴵ, place) of the sweep last selected, ring after ring.
    #[cfg(test)]
    pub(crate) fn roughness(&self) -> impl Iterator<Item = (f32, f32, u32)> + '_ {
        self.rings
            .iter()
            .flat_map(|ring| ring.roughness.iter().copied())
    }

    /// Sector `sector` of every ring, in ring order: its edges, then its planes and intensity
    /// candidates.
    fn pick_sector(
        &mut self,
        image: &RangeImage,
        config: &FeatureConfig,
        (plan, limits): (&SectorPlan, &Thresholds),
        sector: usize,
    ) {
        let k = config.neighbours.max(1);
        let sectors = config.sectors.max(1);
        for (r, ring) in self.rings.iter_mut().enumerate() {
            let range = plan.sector(r, sector, sectors, ring.roughness.len());
            if range.is_empty() {
                continue;
            }
            let members = &image.ring_points[r];
            ring.suppressed.resize(ring.range.len(), false);
            self.picks
                .edges_in(config, limits, (ring, members), range.clone(), k);
            self.picks.planes_and_intensity_candidates_in(
                config,
                limits,
                (ring, members, &image.ring_positions[r]),
                range,
            );
        }
    }
}

/// The picks of the open sweep, as returns of its scan, and the buffers they are made with.
#[derive(Debug, Default, Clone)]
struct Picks {
    edges: Vec<u32>,
    planes: Vec<u32>,
    /// Plane voxel → its entry in `planes`.
    voxels: FxHashMap<(i32, i32, i32), usize>,
    /// The voxel of the last plane candidate and its entry: successive returns of a ring mostly
    /// share one, which is then not hashed again.
    last_voxel: Option<((i32, i32, i32), usize)>,
    /// Per plane: its return's σᴳ.
    plane_roughness: Vec<f32>,
    /// Intensity candidates: (σᴵ, return).
    candidates: Vec<(f32, u32)>,
    /// A sector's edge candidates (reliable, combined σ clear of the threshold by three times
    /// the noise), roughest first.
    edge_candidates: Vec<(f32, u32)>,
}

impl Picks {
    fn restart(&mut self) {
        self.edges.clear();
        self.planes.clear();
        self.voxels.clear();
        self.last_voxel = None;
        self.plane_roughness.clear();
        self.candidates.clear();
    }

    /// A sector's edges: only reliable returns whose combined σ clears the threshold by three
    /// times the noise can be one, so only those are ranked (ties by ring order, so the choice
    /// is deterministic); the roughest `edges_per_sector` are taken, each suppressing its `k`
    /// neighbours either side so that edges spread along the ring.
    fn edges_in(
        &mut self,
        config: &FeatureConfig,
        limits: &Thresholds,
        (ring, members): (&mut RingRoughness, &[u32]),
        sector: Range<usize>,
        k: usize,
    ) {
        let combined = |g: f32, i: f32| config.geometric_weight * g + config.intensity_weight * i;
        let unreliable = &ring.unreliable;
        self.edge_candidates.clear();
        self.edge_candidates.extend(
            ring.roughness[sector.clone()]
                .iter()
                .zip(&ring.noise[sector])
                .map(|(&(g, i, w), &noise)| (combined(g, i), w, noise))
                .filter(|&(sigma, w, noise)| {
                    sigma > limits.edge + 3.0 * noise && !unreliable[w as usize]
                })
                .map(|(sigma, w, _)| (sigma, w)),
        );
        self.edge_candidates
            .sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let len = ring.suppressed.len();
        let mut edges = 0;
        for &(_, w) in &self.edge_candidates {
            if edges >= config.edges_per_sector {
                break;
            }
            let w = w as usize;
            if ring.suppressed[w] {
                continue;
            }
            self.edges.push(members[w]);
            edges += 1;
            for flag in &mut ring.suppressed[w.saturating_sub(k)..(w + k + 1).min(len)] {
                *flag = true;
            }
        }
    }

    /// A sector's planes and intensity candidates. Planes: reliable returns, not next to an
    /// edge, with σᴳ under the threshold plus the noise, one per voxel of `plane_voxel`: the
    /// least flat return that still passes (the first of the returns ranked roughest first;
    /// keeping the flattest instead drifted more, see `docs/decisions.md`). Intensity
    /// candidates: reliable returns with a known η and σᴵ over its threshold.
    fn planes_and_intensity_candidates_in(
        &mut self,
        config: &FeatureConfig,
        limits: &Thresholds,
        (ring, members, positions): (&RingRoughness, &[u32], &[Vector3<f32>]),
        sector: Range<usize>,
    ) {
        let entries = ring.roughness[sector.clone()]
            .iter()
            .zip(&ring.noise[sector]);
        for (&(g, rough_i, w), &noise) in entries {
            let (w, i) = (w as usize, members[w as usize]);
            if ring.unreliable[w] {
                continue;
            }
            if g < limits.plane + noise && !ring.suppressed[w] {
                let p = positions[w];
                let key = (
                    (p.x * limits.per_voxel).floor() as i32,
                    (p.y * limits.per_voxel).floor() as i32,
                    (p.z * limits.per_voxel).floor() as i32,
                );
                let at = match self.last_voxel {
                    Some((voxel, at)) if voxel == key => Some(at),
                    _ => match self.voxels.entry(key) {
                        Entry::Vacant(v) => {
                            v.insert(self.planes.len());
                            self.last_voxel = Some((key, self.planes.len()));
                            self.planes.push(i);
                            self.plane_roughness.push(g);
                            None
                        }
                        Entry::Occupied(o) => {
                            self.last_voxel = Some((key, *o.get()));
                            Some(*o.get())
                        }
                    },
                };
                if let Some(at) = at {
                    if g > self.plane_roughness[at] {
                        self.plane_roughness[at] = g;
                        self.planes[at] = i;
                    }
                }
            }
            if rough_i > config.intensity_roughness_threshold && ring.eta[w][1] > 0.0 {
                self.candidates.push((rough_i, i));
            }
        }
    }

    /// The intensity points: the candidates with the strongest intensity gradients, at most
    /// `max_intensity_points`.
    fn keep_strongest_intensity(&mut self, sweep: &SweepView<'_>, out: &mut SweepFeatures) {
        let cap = sweep.config.max_intensity_points.min(self.candidates.len());
        if cap < self.candidates.len() {
            self.candidates
                .select_nth_unstable_by(cap, |a, b| b.0.total_cmp(&a.0));
        }
        for &(_, i) in &self.candidates[..cap] {
            out.intensity.push(sweep.feature(i as usize));
        }
    }
}

/// Which of a sweep's plane picks, in their order, are kept under the cap `max_planes`: `cap`
/// spread evenly over `of` (of every `of / cap` in a row, the last; all of them when `of` is
/// within the cap or the cap is 0).
///
/// A pick's place in the order is known once it is picked, `of` only at the close. The
/// thinning a sweep's planes are handed out with before the close is planned for as many as
/// the last sweep picked; the close keeps it unless the sweep's own count would then keep more
/// than [`THINNING_TOLERANCE`] of the cap more or fewer than the exact thinning, and thins
/// exactly otherwise (the first sweep, a sweep entering a very different scene). Either way a
/// sweep's planes follow from it and the one before, not from how it streamed in.
#[derive(Debug, Clone, Copy, PartialEq)]
struct PlaneThinning {
    cap: usize,
    of: usize,
}

/// How far the planes kept by the planned thinning may stray from the cap (as a share of it)
/// before the close thins exactly.
const THINNING_TOLERANCE: f64 = 0.1;

impl PlaneThinning {
    /// Planned for a sweep after one that picked `last` planes.
    fn planned(cap: usize, last: usize) -> Self {
        Self { cap, of: last }
    }

    /// What the close keeps of `picked` planes, planned for `last`.
    fn settled(cap: usize, last: usize, picked: usize) -> Self {
        let exact = Self { cap, of: picked };
        let planned = Self::planned(cap, last);
        let off = planned.kept(picked).abs_diff(exact.kept(picked));
        if (off as f64) <= THINNING_TOLERANCE * cap as f64 {
            planned
        } else {
            exact
        }
    }

    fn thins(&self) -> bool {
        self.cap > 0 && self.of > self.cap
    }

    /// Whether the `j`th pick (from 0) is kept.
    fn keeps(&self, j: usize) -> bool {
        !self.thins() || j * self.cap / self.of != (j + 1) * self.cap / self.of
    }

    /// How many of `n` picks are kept.
    fn kept(&self, n: usize) -> usize {
        if self.thins() {
            n * self.cap / self.of
        } else {
            n
        }
    }

    fn apply(&self, features: &mut Vec<Feature>) {
        let mut j = 0;
        features.retain(|_| {
            j += 1;
            self.keeps(j - 1)
        });
    }
}

/// The spread (1σ) of the σᴳ that range noise alone produces at range `r` with `k` neighbours
/// each side. In `Σⱼ(pⱼ − pᵢ)` the return's own noise counts 2k times and each neighbour's once,
/// so the sum's noise is σ·√(2k + 4k²) (the rays in a window are nearly parallel, so the noise
/// adds along one direction): σᴳ's is σ·√((2k + 1)/2k) / r, about σ / r whatever k.
fn noise_floor(config: &FeatureConfig, k: usize, r: f32) -> f32 {
    let two_k = (2 * k) as f32;
    config.range_noise * ((two_k + 1.0) / two_k).sqrt() / r.max(0.1)
}

/// The azimuth step the configured thresholds are stated for: 0.2°, a VLP-16 at 600 rpm.
const REFERENCE_STEP_RAD: f32 = 0.2 * std::f32::consts::PI / 180.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::ScanPoint;

    /// Two rings sweeping two walls meeting at a corner (x = 5 and y = 5), with a painted stripe
    /// on the first wall, returns `step` degrees apart (0.2° at 600 rpm).
    fn corner_scan_at(step: f32) -> Vec<ScanPoint> {
        let mut pts = Vec::new();
        let columns = (90.0 / step).round() as usize;
        let column_ns = (55_296.0 * step / 0.2).round() as u64;
        for ring in 0..2u8 {
            let el = (f32::from(ring) * 2.0 - 1.0).to_radians();
            for c in 0..columns {
                // Azimuth from 0° (+x) to −90° (+y) clockwise, i.e. counter-clockwise here.
                let az = -(c as f32) * step.to_radians();
                let dir = [el.cos() * az.cos(), -el.cos() * az.sin(), el.sin()];
                let t_x = 5.0 / dir[0];
                let t_y = 5.0 / dir[1];
                let t = if dir[1] <= 0.0 || t_x < t_y { t_x } else { t_y };
                let p = [dir[0] * t, dir[1] * t, dir[2] * t];
                let on_stripe = p[1] > 1.0 && p[1] < 1.3 && t == t_x;
                pts.push(ScanPoint {
                    position: p,
                    time_ns: c as u64 * column_ns,
                    reflectivity: if on_stripe { 90 } else { 20 },
                    ring,
                });
            }
        }
        pts
    }

    /// The corner scan through calibration and selection with `config`.
    fn corner_features(config: FeatureConfig) -> SweepFeatures {
        corner_features_at(config, 0.2)
    }

    /// [`corner_features`] of the corner seen `step` degrees apart.
    fn corner_features_at(config: FeatureConfig, step: f32) -> SweepFeatures {
        let pts = corner_scan_at(step);
        let scan = Scan {
            points: &pts,
            rings: 2,
            reference_ns: pts.last().map_or(0, |p| p.time_ns),
        };
        let mut f = SweepFeatures::default();
        let odometry = crate::config::OdometryConfig {
            features: config,
            ..Default::default()
        };
        crate::front_end::FrontEnd::new(&odometry).process(&scan, &mut f);
        f
    }

    #[test]
    fn corner_is_an_edge_and_walls_are_planes() {
        // The scan is noise-free: at 5 m a 2 cm noise floor would hide the corner.
        let f = corner_features(FeatureConfig {
            intensity_weight: 0.0,
            range_noise: 0.001,
            ..FeatureConfig::default()
        });
        assert!(!f.planes.is_empty());
        assert!(
            f.edges
                .iter()
                .any(|e| (e.position[0] - 5.0).abs() < 0.1 && (e.position[1] - 5.0).abs() < 0.2),
            "{:?}",
            f.edges
        );
        for e in &f.edges {
            let at_corner = (e.position[0] - 5.0).abs() < 0.1 && (e.position[1] - 5.0).abs() < 0.5;
            assert!(at_corner, "geometry-only edge away from the corner: {e:?}");
        }
        assert!(f.edges.iter().all(|e| e.dt <= 0.0));
    }

    #[test]
    fn planned_plane_thinning_holds_while_the_count_stays_near_the_last() {
        let cap = 2000;
        // As many as planned: the exact thinning.
        let exact = PlaneThinning::settled(cap, 3000, 3000);
        assert_eq!(exact, PlaneThinning { cap, of: 3000 });
        assert_eq!((0..3000).filter(|&j| exact.keeps(j)).count(), cap);
        // A few more or fewer than the last sweep: the plan holds, about the cap is kept.
        for picked in [2800, 3200] {
            let thinning = PlaneThinning::settled(cap, 3000, picked);
            assert_eq!(thinning, PlaneThinning::planned(cap, 3000));
            let kept = (0..picked).filter(|&j| thinning.keeps(j)).count();
            assert_eq!(kept, thinning.kept(picked));
            assert!(kept.abs_diff(cap) <= cap / 10, "{kept}");
        }
        // Far from the plan (the first sweep, a new scene): exact.
        assert_eq!(
            PlaneThinning::settled(cap, 0, 3000),
            PlaneThinning { cap, of: 3000 }
        );
        assert_eq!(
            PlaneThinning::settled(cap, 3000, 6000),
            PlaneThinning { cap, of: 6000 }
        );
        assert_eq!(
            PlaneThinning::settled(cap, 6000, 2500),
            PlaneThinning { cap, of: 2500 }
        );
        // Under the cap, or no cap: all kept.
        assert_eq!(PlaneThinning::settled(cap, 1500, 1600).kept(1600), 1600);
        assert_eq!(PlaneThinning::settled(0, 3000, 3100).kept(3100), 3100);
    }

    #[test]
    fn planes_over_the_cap_are_thinned_evenly() {
        let all = corner_features(FeatureConfig {
            max_planes: 0,
            ..FeatureConfig::default()
        });
        let n = all.planes.len();
        assert!(n >= 40, "{n} planes");
        let capped = corner_features(FeatureConfig {
            max_planes: n / 4,
            ..FeatureConfig::default()
        });
        assert_eq!(capped.planes.len(), n / 4);
        // The kept ones are the voxels' own, in their order, one of about every four.
        let at = |f: &Feature| all.planes.iter().position(|a| a.position == f.position);
        let indices: Vec<usize> = capped.planes.iter().map(|f| at(f).unwrap()).collect();
        for pair in indices.windows(2) {
            assert!((3..=5).contains(&(pair[1] - pair[0])), "{indices:?}");
        }
        assert_eq!(indices.last(), Some(&(n - 1)));
        // Under the cap nothing changes; the rest of the selection never does.
        let roomy = corner_features(FeatureConfig {
            max_planes: n,
            ..FeatureConfig::default()
        });
        assert_eq!(roomy.planes, all.planes);
        assert_eq!(capped.edges, all.edges);
        assert_eq!(capped.intensity, all.intensity);
    }

    #[test]
    fn a_slower_rotors_finer_steps_keep_proportionally_more_planes() {
        let with_cap = |step: f32, max_planes: usize| {
            let config = FeatureConfig {
                max_planes,
                ..FeatureConfig::default()
            };
            corner_features_at(config, step).planes.len()
        };
        // 300 rpm: steps of 0.1°, a sweep twice as long, twice the cap.
        let n = with_cap(0.1, 0);
        assert!(n >= 40, "{n} planes");
        let kept = with_cap(0.1, n / 4);
        assert!(kept.abs_diff(2 * (n / 4)) <= 1, "{kept} of {n}");
        // 1200 rpm: steps of 0.4°; the cap stays whole.
        let n = with_cap(0.4, 0);
        assert!(n >= 20, "{n} planes");
        assert_eq!(with_cap(0.4, n / 4), n / 4);
    }

    #[test]
    fn the_intensity_map_input_is_thinned_along_each_ring() {
        let all = corner_features(FeatureConfig {
            intensity_map_spacing: 0.0,
            ..FeatureConfig::default()
        });
        let thinned = corner_features(FeatureConfig::default());
        // At 5–7 m the returns are 1.7–2.5 cm apart: one in two or three is kept, and no two
        // kept on a ring are closer than the spacing.
        assert!(thinned.calibrated.len() * 2 <= all.calibrated.len());
        assert!(thinned.calibrated.len() * 4 >= all.calibrated.len());
        let spacing = FeatureConfig::default().intensity_map_spacing;
        for pair in thinned.calibrated.windows(2) {
            let d: f32 = (0..3)
                .map(|a| (pair[1].position[a] - pair[0].position[a]).powi(2))
                .sum::<f32>()
                .sqrt();
            let same_ring = (pair[1].position[2] > 0.0) == (pair[0].position[2] > 0.0);
            assert!(!same_ring || d >= spacing, "{d} m apart");
        }
        // The reflectivity of what is kept is unchanged.
        assert!(thinned.calibrated.iter().all(|t| all
            .calibrated
            .iter()
            .any(|a| a.position == t.position && a.eta == t.eta)));
    }

    #[test]
    fn intensity_roughness_finds_the_stripe() {
        let f = corner_features(FeatureConfig {
            intensity_weight: 0.03,
            range_noise: 0.001,
            ..FeatureConfig::default()
        });
        let near_stripe = |p: [f32; 3]| {
            (p[0] - 5.0).abs() < 0.05 && ((p[1] - 1.0).abs() < 0.2 || (p[1] - 1.3).abs() < 0.2)
        };
        assert!(f.intensity.iter().any(|e| near_stripe(e.position)));
        assert!(
            f.edges.iter().any(|e| near_stripe(e.position)),
            "with wᴵ > 0 the stripe's boundaries are edges"
        );
    }
}
