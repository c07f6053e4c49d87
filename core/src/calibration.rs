//! Step 1 of the method: intensity calibration. The VLP-16 compensates range but not the
//! incidence angle, so each diffuse return's reflectivity is divided by cos α, with α taken from
//! the local surface normal. The normal comes from range-image neighbours (the points on the same
//! ring either side, and on the rings above and below at the same azimuth): no search.
//! Retro-reflectors (> 100) keep their raw value and their class; weak returns are dropped.

use std::cell::Cell;

use nalgebra::Vector3;

use crate::config::CalibrationConfig;
use crate::scan::{Scan, ScanPoint};

/// The baseline a normal is built on, m, and the most ring steps taken to reach it along a ring.
/// With 1.5 cm range noise, adjacent returns on a wall 2 m away (7 mm apart) give a normal that
/// is noise; on the simulated corridor, widening to 0.2 m took the drift with intensity from 55 %
/// to 2–5 %.
const MIN_BASELINE: f32 = 0.2;
/// The ring steps tried along a ring, out to 20: sparser farther out, so a near wall (which
/// needs all 20 to approach the baseline) costs 9 distance tests instead of 20, and where the
/// baseline is reached sooner the chosen step is at most half again the first one past it.
const RING_STEPS: [usize; 9] = [1, 2, 3, 4, 6, 8, 11, 15, 20];
/// The ring steps tried across rings.
const ACROSS_STEPS: [usize; 2] = [1, 2];

/// One step of a baseline walk from `p`: a candidate `q` within the surface gate `gate_sq`
/// (squared distance from `p`) becomes the farthest reached; the walk goes on while that is
/// nearer than [`MIN_BASELINE`]. A walk steps out through its candidates, nearest first, until
/// this says stop or they run out, and keeps the last one reached. The walks run four times for
/// every normal estimated: they are written out and inlined, since through closures or an
/// iterator adapter the compiler left a call per step.
#[inline(always)]
fn reach(best: &mut Option<Vector3<f32>>, q: Vector3<f32>, p: &Vector3<f32>, gate_sq: f32) -> bool {
    let distance_sq = (q - p).norm_squared();
    if distance_sq >= gate_sq {
        return false;
    }
    *best = Some(q);
    distance_sq < MIN_BASELINE * MIN_BASELINE
}

/// The baseline walk along a ring from the `k`-th of its `positions` (see [`reach`]).
#[inline(always)]
fn walk_along(
    positions: &[Vector3<f32>],
    k: usize,
    forward: bool,
    gate_sq: f32,
) -> Option<Vector3<f32>> {
    let p = positions[k];
    let mut best = None;
    for d in RING_STEPS {
        match step(k, d, forward).and_then(|index| positions.get(index)) {
            Some(&q) if reach(&mut best, q, &p, gate_sq) => {}
            _ => break,
        }
    }
    best
}

/// `d` places up (or down) from `k`, if not below 0.
#[inline(always)]
fn step(k: usize, d: usize, up: bool) -> Option<usize> {
    if up {
        Some(k + d)
    } else {
        k.checked_sub(d)
    }
}

/// The tangent through `p` from its neighbours on either side: central when both exist,
/// one-sided otherwise.
fn span(
    before: Option<Vector3<f32>>,
    after: Option<Vector3<f32>>,
    p: &Vector3<f32>,
) -> Option<Vector3<f32>> {
    match (before, after) {
        (Some(a), Some(b)) => Some(b - a),
        (Some(a), None) => Some(p - a),
        (None, Some(b)) => Some(b - p),
        (None, None) => None,
    }
}

/// atan2(y, x) within 2e-5 rad (a millidegree, against the image's 0.2° columns) in a few dozen
/// instructions: libm's `atan2f` took ~130 a call, an eighth of the calibration's. Without
/// branches (selects only), so a loop of them vectorises; 0 at the origin.
#[inline(always)]
fn atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    // atan of the ratio in [0, 1], by a minimax polynomial in its square.
    let (low, high) = (ax.min(ay), ax.max(ay));
    let t = if high > 0.0 { low / high } else { 0.0 };
    let t2 = t * t;
    let poly = -0.011_721_2_f32;
    let poly = poly * t2 + 0.052_653_32;
    let poly = poly * t2 - 0.116_432_87;
    let poly = poly * t2 + 0.193_543_46;
    let poly = poly * t2 - 0.332_623_47;
    let poly = poly * t2 + 0.999_977_26;
    let mut a = poly * t;
    if ay > ax {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

/// Columns of the range image: 0.2°, the VLP-16's horizontal step at 600 rpm.
pub const COLUMNS: usize = 1800;
const COLUMNS_PER_RAD: f32 = COLUMNS as f32 / std::f32::consts::TAU;
const COLUMNS_PER_DEGREE: usize = COLUMNS / 360;
const EMPTY: u32 = u32::MAX;
/// The farthest a normal looks along its ring, in returns: a return is calibrated as it
/// streams in once this many more of its ring have arrived.
const RING_REACH: usize = RING_STEPS[RING_STEPS.len() - 1];

/// The offsets (reader ring minus cell ring) of the rings whose normals read a cell, as the
/// walks across the rings take them ([`ACROSS_STEPS`] either way).
const READER_OFFSETS: [isize; 4] = [-2, -1, 1, 2];

/// The bit marking a cell of ring `cell_ring` as read by a normal on ring `reader`.
#[inline(always)]
fn reader_bit(cell_ring: usize, reader: usize) -> u8 {
    match reader as isize - cell_ring as isize {
        -2 => 1,
        -1 => 2,
        1 => 4,
        _ => 8,
    }
}

/// A sweep arranged by ring and azimuth column, with each return's calibrated reflectivity.
/// Buffers are reused from sweep to sweep.
///
/// Filled either whole ([`Self::build`]) or as the sweep streams in ([`Self::begin`], then
/// [`Self::extend`] with each batch of returns, then [`Self::finish`]): a return is calibrated
/// as soon as its ring has [`RING_REACH`] more returns, so at the sweep's end little remains.
/// Both give the same image, bit for bit. A ring's returns are calibrated in order (they reuse
/// each other's normals); across the rings a normal reads cells of the rings around it, which
/// are marked with the reader's ring, and a later return landing in a marked cell (the sweep's
/// end wrapping onto its start, a return where there was none) has the rings that read it
/// recalibrated at the finish.
#[derive(Debug, Default, Clone)]
pub struct RangeImage {
    rings: usize,
    /// Per ring, indices into the scan's points in firing (= azimuth) order.
    pub ring_points: Vec<Vec<u32>>,
    /// Per ring, the positions of `ring_points` (contiguous: the walks along a ring read them).
    pub ring_positions: Vec<Vec<Vector3<f32>>>,
    /// Per ring × column, the index of the return there (the last one if several).
    cells: Vec<u32>,
    /// Per ring × column: the rings whose normals read this cell, as bits for the ring offsets
    /// −2, −1, +1, +2 (see [`reader_bit`]). Interior mutability because the normal's walks
    /// borrow the image whole.
    read: Vec<Cell<u8>>,
    /// Per point: its place in its ring's `ring_points` (`EMPTY` if in none).
    ring_index: Vec<u32>,
    /// Per point: its ring and raw reflectivity.
    ring: Vec<u8>,
    /// See `ring`.
    raw: Vec<u8>,
    /// Per point: its column, its range, and whether it passed the weak-return filter.
    pub column: Vec<u16>,
    /// See `column`.
    pub range: Vec<f32>,
    /// See `column`.
    pub valid: Vec<bool>,
    /// Per point: calibrated reflectivity η, or NaN where no normal could be estimated.
    pub eta: Vec<f32>,
    /// Per point: reflectivity above 100 (a retro-reflector).
    pub retro: Vec<bool>,
    /// Per point: the unit surface normal the calibration used (zero where none), sensor frame.
    pub normal: Vec<[f32; 3]>,
    /// Per point: azimuth, rad, clockwise from +x as the sensor counts it.
    azimuth: Vec<f32>,
    steps: Vec<f32>,
    /// Per ring, the last return whose normal was estimated, and that normal.
    last_normal: Vec<Option<(Vector3<f32>, Vector3<f32>)>>,
    /// Per ring, how many of its returns are calibrated (the first ones, in ring order).
    done: Vec<usize>,
    /// Per ring: a return landed in a cell one of its normals had read.
    stale: Vec<bool>,
    /// Rings recalibrated at the finish.
    recalibrated: usize,
    /// The sweep's azimuth step, see [`Self::azimuth_step`].
    step: Option<f32>,
    /// The degrees of azimuth holding a return, as bits: see [`Self::coverage`].
    degrees_seen: Vec<u64>,
}

impl RangeImage {
    /// Fills the image from a sweep and calibrates every return.
    pub fn build(&mut self, scan: &Scan<'_>, config: &CalibrationConfig) {
        self.begin(scan.rings);
        self.extend(scan.points, config);
        self.finish(config);
    }

    /// Starts a sweep of a sensor with `rings` rings; returns on other rings are left out.
    pub fn begin(&mut self, rings: usize) {
        self.rings = rings.max(1);
        self.ring_points.resize_with(self.rings, Vec::new);
        self.ring_positions.resize_with(self.rings, Vec::new);
        for r in &mut self.ring_points {
            r.clear();
        }
        for r in &mut self.ring_positions {
            r.clear();
        }
        self.cells.clear();
        self.cells.resize(self.rings * COLUMNS, EMPTY);
        self.read.clear();
        self.read.resize(self.rings * COLUMNS, Cell::new(0));
        self.range.clear();
        self.eta.clear();
        self.column.clear();
        self.valid.clear();
        self.ring_index.clear();
        self.ring.clear();
        self.raw.clear();
        self.retro.clear();
        self.azimuth.clear();
        self.normal.clear();
        self.last_normal.clear();
        self.last_normal.resize(self.rings, None);
        self.done.clear();
        self.done.resize(self.rings, 0);
        self.stale.clear();
        self.stale.resize(self.rings, false);
        self.recalibrated = 0;
        self.step = None;
        self.degrees_seen.clear();
        self.degrees_seen.resize(360usize.div_ceil(64), 0);
    }

    /// The rings of the sweep begun.
    pub fn rings(&self) -> usize {
        self.rings
    }

    /// Returns taken in since [`Self::begin`].
    pub fn len(&self) -> usize {
        self.range.len()
    }

    /// No return taken in since [`Self::begin`].
    pub fn is_empty(&self) -> bool {
        self.range.is_empty()
    }

    /// Takes in the sweep's next returns, in firing order, and calibrates those whose
    /// neighbourhood has arrived.
    pub fn extend(&mut self, points: &[ScanPoint], config: &CalibrationConfig) {
        let first = self.range.len();
        let n = first + points.len();
        self.range.resize(n, 0.0);
        self.eta.resize(n, 0.0);
        self.column.resize(n, 0);
        self.valid.resize(n, false);
        self.ring_index.resize(n, EMPTY);
        self.ring.resize(n, 0);
        self.raw.resize(n, 0);
        self.retro.resize(n, false);
        self.azimuth.resize(n, 0.0);
        self.normal.resize(n, [0.0; 3]);

        // Ranges and azimuths first, in a loop of arithmetic alone that the compiler vectorises.
        let polar = self.range[first..]
            .iter_mut()
            .zip(&mut self.azimuth[first..]);
        for ((range, azimuth), p) in polar.zip(points) {
            let [x, y, z] = p.position;
            *range = (x * x + y * y + z * z).sqrt();
            // Clockwise from +x, as the sensor counts azimuth.
            let a = atan2(-y, x);
            *azimuth = if a < 0.0 {
                a + std::f32::consts::TAU
            } else {
                a
            };
        }
        for (i, p) in (first..).zip(points) {
            let (range, azimuth) = (self.range[i], self.azimuth[i]);
            let ring = usize::from(p.ring);
            if !range.is_finite() || range <= 0.0 || ring >= self.rings {
                // Out of the image: as if never measured.
                (self.range[i], self.azimuth[i]) = (0.0, 0.0);
                continue;
            }
            // Through i32: converting a float to usize takes a longer instruction sequence.
            let column = ((azimuth * COLUMNS_PER_RAD) as i32).clamp(0, COLUMNS as i32 - 1) as usize;
            self.column[i] = column as u16;
            let degree = column / COLUMNS_PER_DEGREE;
            self.degrees_seen[degree / 64] |= 1 << (degree % 64);
            self.ring[i] = p.ring;
            self.raw[i] = p.reflectivity;
            self.retro[i] = p.reflectivity > 100;
            self.valid[i] = p.reflectivity >= config.min_reflectivity;
            self.ring_index[i] = self.ring_points[ring].len() as u32;
            self.ring_points[ring].push(i as u32);
            self.ring_positions[ring].push(Vector3::from(p.position));
            let cell = ring * COLUMNS + column;
            let readers = self.read[cell].get();
            if readers != 0 {
                for (bit, offset) in READER_OFFSETS.iter().enumerate() {
                    if readers & (1 << bit) != 0 {
                        self.stale[ring.wrapping_add_signed(*offset)] = true;
                    }
                }
            }
            self.cells[cell] = i as u32;
        }
        self.calibrate(config, false);
    }

    /// Calibrates the returns left once the sweep is complete.
    pub fn finish(&mut self, config: &CalibrationConfig) {
        for ring in 0..self.rings {
            if self.stale[ring] {
                self.recalibrated += 1;
                self.done[ring] = 0;
                self.last_normal[ring] = None;
            }
        }
        self.calibrate(config, true);
        self.step = self.measure_azimuth_step();
    }

    /// How many rings of the sweep last finished had to be recalibrated (see the type's notes).
    pub fn recalibrated(&self) -> usize {
        self.recalibrated
    }

    /// How many of ring `ring`'s returns are calibrated: its first ones, in ring order. Their
    /// η is final unless the ring is [`Self::redone`].
    pub fn calibrated_in_ring(&self, ring: usize) -> usize {
        self.done.get(ring).copied().unwrap_or(0)
    }

    /// Whether ring `ring`'s streamed calibration is (or, before the finish, will be) done again
    /// at the finish.
    pub fn redone(&self, ring: usize) -> bool {
        self.stale.get(ring).copied().unwrap_or(false)
    }

    /// Returns taken in and not yet calibrated.
    pub fn pending(&self) -> usize {
        (0..self.rings)
            .map(|r| self.ring_points[r].len() - self.done[r])
            .sum()
    }

    /// Calibrates each ring's returns from its first one not yet done: every one left when the
    /// sweep is `complete`, otherwise those with [`RING_REACH`] more of the ring after them.
    fn calibrate(&mut self, config: &CalibrationConfig, complete: bool) {
        if complete && self.done.iter().all(|&d| d == 0) {
            // In firing order, not ring by ring: the returns above and below at the same
            // azimuth were fired with the one calibrated and sit beside it in memory, so the
            // sweep is read through once instead of once per ring.
            for i in 0..self.range.len() {
                let k = self.ring_index[i];
                if k != EMPTY {
                    self.estimate_normal(i, usize::from(self.ring[i]), k as usize, config);
                }
            }
            for i in 0..self.range.len() {
                let k = self.ring_index[i];
                if k != EMPTY {
                    self.calibrate_return(i, usize::from(self.ring[i]), k as usize, config);
                }
            }
            self.done.clear();
            self.done.extend(self.ring_points.iter().map(Vec::len));
            return;
        }
        for ring in 0..self.rings {
            let n = self.ring_points[ring].len();
            let end = if complete {
                n
            } else {
                n.saturating_sub(RING_REACH)
            };
            for k in self.done[ring]..end {
                let i = self.ring_points[ring][k] as usize;
                self.estimate_normal(i, ring, k, config);
            }
            for k in self.done[ring]..end {
                let i = self.ring_points[ring][k] as usize;
                self.calibrate_return(i, ring, k, config);
            }
            self.done[ring] = self.done[ring].max(end);
        }
    }

    /// The surface normal of return `i`, the `k`-th of ring `ring`, the ring's earlier ones
    /// done (a retro-reflector needs none). Apart from [`Self::calibrate_return`], so that the
    /// latter's divisions, which no later return waits on, overlap from one return to the next.
    #[inline(always)]
    fn estimate_normal(&mut self, i: usize, ring: usize, k: usize, config: &CalibrationConfig) {
        if self.retro[i] {
            return;
        }
        let reuse_sq = config.normal_spacing * config.normal_spacing;
        let position = self.ring_positions[ring][k];
        let normal = match self.last_normal[ring] {
            Some((anchor, unit)) if (position - anchor).norm_squared() < reuse_sq => Some(unit),
            _ => {
                let unit = self.surface_normal(ring, k, i, config);
                self.last_normal[ring] = unit.map(|u| (position, u));
                unit
            }
        };
        self.normal[i] = normal.map_or([0.0; 3], |unit| [unit.x, unit.y, unit.z]);
    }

    /// Calibrates return `i`, the `k`-th of ring `ring`, whose normal is estimated.
    #[inline(always)]
    fn calibrate_return(&mut self, i: usize, ring: usize, k: usize, config: &CalibrationConfig) {
        let raw = f32::from(self.raw[i]);
        if self.retro[i] {
            self.eta[i] = raw;
            return;
        }
        let position = self.ring_positions[ring][k];
        // A unit normal is never zero: zero is none.
        let normal = Some(Vector3::from(self.normal[i])).filter(|unit| *unit != Vector3::zeros());
        let cos = normal.map(|unit| (position.dot(&unit) / self.range[i]).abs());
        self.eta[i] = match cos {
            Some(c) if c >= config.min_reliable_cos => {
                (raw / c.max(config.min_cos_incidence)).min(config.max_calibrated)
            }
            _ => f32::NAN,
        };
    }

    /// Return `i`'s calibrated reflectivity η, NaN where it has none: a weak return (below
    /// `min_reflectivity`), no surface normal, or no valid position.
    pub fn calibrated(&self, i: usize) -> f32 {
        if self.valid.get(i) == Some(&true) && self.ring_index[i] != EMPTY {
            self.eta[i]
        } else {
            f32::NAN
        }
    }

    /// The share of a turn's 360 degrees of azimuth holding at least one of the returns taken
    /// in: 1 for a whole sweep, less for one the stream cut short (the sensor fell silent, the
    /// capture ended) or a mounting that blocks part of the view. Whole degrees, not columns:
    /// a degree holds returns at any rotation rate (the step is 0.1–0.4°), where a sensor at
    /// 1200 rpm fills only every other 0.2° column.
    pub fn coverage(&self) -> f32 {
        let seen: u32 = self.degrees_seen.iter().map(|w| w.count_ones()).sum();
        seen as f32 / 360.0
    }

    /// The typical azimuth step between successive returns of a ring, rad (the median over
    /// every eighth pair of the sweep's; 0.2° for a VLP-16 at 600 rpm). `None` for a sweep too
    /// sparse to tell.
    pub fn azimuth_step(&self) -> Option<f32> {
        self.step
    }

    fn measure_azimuth_step(&mut self) -> Option<f32> {
        self.steps.clear();
        for members in &self.ring_points {
            // Thousands of samples still, for an eighth of the ranking's cost.
            for w in members.windows(2).step_by(8) {
                let d = (self.azimuth[w[1] as usize] - self.azimuth[w[0] as usize]).abs();
                let d = d.min(std::f32::consts::TAU - d);
                if d > 0.0 {
                    self.steps.push(d);
                }
            }
        }
        if self.steps.len() < 10 {
            return None;
        }
        let mid = self.steps.len() / 2;
        Some(*self.steps.select_nth_unstable_by(mid, f32::total_cmp).1)
    }

    /// The return at ring `ring`, column `column` (or the next column either side), if any;
    /// the cells looked at are marked as read by `reader` (a bit of [`reader_bit`]).
    fn at(&self, ring: usize, column: usize, reader: u8) -> Option<usize> {
        let row = ring * COLUMNS;
        let next = if column + 1 == COLUMNS { 0 } else { column + 1 };
        let previous = if column == 0 { COLUMNS - 1 } else { column - 1 };
        [column, next, previous]
            .into_iter()
            .map(|c| {
                let read = &self.read[row + c];
                read.set(read.get() | reader);
                self.cells[row + c]
            })
            .find(|&v| v != EMPTY)
            .map(|v| v as usize)
    }

    /// The position of return `j`, which is in the image.
    fn position(&self, j: usize) -> Vector3<f32> {
        self.ring_positions[usize::from(self.ring[j])][self.ring_index[j] as usize]
    }

    /// The baseline walk across the rings from `p`, the return at ring `ring`, column
    /// `column` (see [`reach`]).
    #[inline(always)]
    fn walk_across(
        &self,
        (ring, column): (usize, usize),
        upward: bool,
        p: &Vector3<f32>,
        gate_sq: f32,
    ) -> Option<Vector3<f32>> {
        let mut best = None;
        for d in ACROSS_STEPS {
            let Some(j) = step(ring, d, upward)
                .filter(|&r| r < self.rings)
                .and_then(|r| self.at(r, column, reader_bit(r, ring)))
            else {
                break;
            };
            if !reach(&mut best, self.position(j), p, gate_sq) {
                break;
            }
        }
        best
    }

    /// The unit normal of the surface through the neighbours of point `i` (the `k`-th of ring
    /// `ring`), if they lie on one surface.
    fn surface_normal(
        &self,
        ring: usize,
        k: usize,
        i: usize,
        config: &CalibrationConfig,
    ) -> Option<Vector3<f32>> {
        let positions = &self.ring_positions[ring];
        let p = positions[k];
        let range = self.range[i];
        // Along the ring: the farthest point either side within the surface gate, stepping out
        // until the baseline reaches MIN_BASELINE (a wall 2 m away puts neighbours 7 mm apart,
        // below the range noise, so adjacent points give noise for a normal).
        let near_sq = (config.neighbour_gap * range * 4.0 + MIN_BASELINE).powi(2);
        let along_ring = |forward: bool| walk_along(positions, k, forward, near_sq);
        let along = span(along_ring(false), along_ring(true), &p)?;
        // Across the rings, at the same azimuth: one ring away, or two when one is closer than
        // the baseline. Floors seen at a low angle put adjacent rings far apart, so the gate is
        // wide; the surface test is the normal's consistency.
        let column = usize::from(self.column[i]);
        let across_sq = (0.5 * range + 0.2).powi(2);
        let across_ring = |upward: bool| self.walk_across((ring, column), upward, &p, across_sq);
        let across = span(across_ring(false), across_ring(true), &p)?;
        let normal = along.cross(&across);
        let norm = normal.norm();
        if norm < 1e-9 {
            return None;
        }
        Some(normal / norm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::ScanPoint;

    /// Calibrates a four-ring scan with the default configuration.
    fn calibrate(pts: &[ScanPoint]) -> RangeImage {
        let mut image = RangeImage::default();
        image.build(
            &Scan {
                points: pts,
                rings: 4,
                reference_ns: 0,
            },
            &CalibrationConfig::default(),
        );
        image
    }

    /// The calibrated values that could be computed.
    fn finite_etas(image: &RangeImage) -> Vec<f32> {
        image
            .eta
            .iter()
            .copied()
            .filter(|e| e.is_finite())
            .collect()
    }

    /// Rings of a VLP-16 hitting a flat floor 1 m below, with reflectivity 100·ρ·cos α.
    fn floor_scan(rho: f32, elevations: &[f32]) -> Vec<ScanPoint> {
        let mut pts = Vec::new();
        for c in 0..1800 {
            let az = c as f32 * 0.2f32.to_radians();
            for (ring, el) in elevations.iter().enumerate() {
                let el = el.to_radians();
                let dir = Vector3::new(el.cos() * az.cos(), -el.cos() * az.sin(), el.sin());
                let range = -1.0 / dir.z;
                let cos_alpha = -dir.z;
                pts.push(ScanPoint {
                    position: (dir * range).into(),
                    time_ns: c as u64,
                    reflectivity: (100.0 * rho * cos_alpha).round() as u8,
                    ring: ring as u8,
                });
            }
        }
        pts
    }

    #[test]
    fn coverage_is_the_share_of_the_turn_seen_at_any_rotation_rate() {
        // One ring's returns on a circle 5 m away, `step` degrees apart over `span` degrees.
        let turn = |step: f32, span: f32| {
            let n = (span / step).round() as usize;
            let pts: Vec<ScanPoint> = (0..n)
                .map(|i| {
                    let az = (i as f32 * step).to_radians();
                    ScanPoint {
                        position: [5.0 * az.cos(), -5.0 * az.sin(), 0.0],
                        time_ns: i as u64,
                        reflectivity: 40,
                        ring: 0,
                    }
                })
                .collect();
            calibrate(&pts).coverage()
        };
        // 600, 1200 and 300 rpm.
        for step in [0.2, 0.4, 0.1] {
            assert!(
                turn(step, 360.0) > 0.99,
                "step {step}: {}",
                turn(step, 360.0)
            );
            assert!((turn(step, 90.0) - 0.25).abs() < 0.01, "step {step}");
            assert!(
                (turn(step, 13.0) - 13.0 / 360.0).abs() < 0.01,
                "step {step}"
            );
        }
        assert_eq!(calibrate(&[]).coverage(), 0.0);
    }

    #[test]
    fn the_fast_atan2_matches_libm() {
        for i in 0..10_000 {
            let angle = (i as f32 / 5_000.0 - 1.0) * std::f32::consts::PI;
            for r in [0.5f32, 3.0, 100.0] {
                let (y, x) = (r * angle.sin(), r * angle.cos());
                assert!((atan2(y, x) - y.atan2(x)).abs() < 2e-5, "{y} {x}");
            }
        }
        assert_eq!(atan2(0.0, 0.0), 0.0);
        assert!((atan2(0.0, -1.0) - std::f32::consts::PI).abs() < 1e-6);
    }

    #[test]
    fn calibration_removes_the_incidence_angle() {
        // Rings steep enough that the floor's incidence stays under the 72.5° trust limit.
        let pts = floor_scan(0.6, &[-25.0, -22.0, -20.0, -18.0]);
        let image = calibrate(&pts);
        let etas = finite_etas(&image);
        assert!(etas.len() > pts.len() * 9 / 10);
        // Raw values range from 100·0.6·sin 18° ≈ 19 to 100·0.6·sin 25° ≈ 25; calibrated ≈ 60,
        // up to the rounding of the raw value (±0.5 / cos α).
        for e in etas {
            assert!((e - 60.0).abs() < 2.0, "{e}");
        }
    }

    /// Four rings sweeping a wall 2 m away (y = 2) with 1.5 cm range noise, reflectivity
    /// 100·ρ·cos α with ρ = 0.5: neighbours along a ring are 7 mm apart.
    fn noisy_near_wall() -> Vec<ScanPoint> {
        let mut pts = Vec::new();
        let mut seed = 11u64;
        let mut noise = || {
            // Sum of uniforms ≈ Gaussian, σ = 1.5 cm.
            (0..12)
                .map(|_| {
                    seed = seed
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1_442_695_040_888_963_407);
                    (seed >> 11) as f32 / (1u64 << 53) as f32
                })
                .sum::<f32>()
                * 0.015
                - 6.0 * 0.015
        };
        let rho = 0.5;
        for c in 0..900 {
            // Azimuths −30°…−150° (clockwise), facing the wall y = 2 on the left.
            let az = -(30.0 + c as f32 * 0.2 * 0.6667).to_radians();
            for (ring, el) in [-3.0f32, -1.0, 1.0, 3.0].iter().enumerate() {
                let el = el.to_radians();
                let dir = Vector3::new(el.cos() * az.cos(), -el.cos() * az.sin(), el.sin());
                let range = 2.0 / dir.y;
                let cos_alpha = dir.y;
                let measured = range + noise();
                pts.push(ScanPoint {
                    position: (dir * measured).into(),
                    time_ns: c as u64,
                    reflectivity: (100.0 * rho * cos_alpha).round() as u8,
                    ring: ring as u8,
                });
            }
        }
        pts
    }

    /// The mean and standard deviation of the calibrated values that could be computed.
    fn eta_statistics(image: &RangeImage) -> (f32, f32, usize) {
        let etas = finite_etas(image);
        let mean = etas.iter().sum::<f32>() / etas.len() as f32;
        let sd = (etas.iter().map(|e| (e - mean).powi(2)).sum::<f32>() / etas.len() as f32).sqrt();
        (mean, sd, etas.len())
    }

    /// A noisy near wall: a normal from adjacent points is noise. The widened baseline keeps
    /// η consistent.
    #[test]
    fn a_noisy_near_wall_calibrates_consistently() {
        let pts = noisy_near_wall();
        let (mean, sd, count) = eta_statistics(&calibrate(&pts));
        assert!(count > pts.len() / 2, "{count} of {}", pts.len());
        assert!(
            (mean - 50.0).abs() < 3.0 && sd < 5.0,
            "mean {mean}, sd {sd}"
        );
    }

    /// Returns within `normal_spacing` of the last estimated normal on their ring take it: on
    /// the near wall a fraction of the normals are estimated, and η is as consistent as when
    /// every return estimates its own.
    #[test]
    fn nearby_returns_share_an_estimated_normal() {
        let pts = noisy_near_wall();
        let scan = Scan {
            points: &pts,
            rings: 4,
            reference_ns: 0,
        };
        let with_spacing = |normal_spacing| {
            let mut image = RangeImage::default();
            let config = CalibrationConfig {
                normal_spacing,
                ..CalibrationConfig::default()
            };
            image.build(&scan, &config);
            image
        };
        // Per ring, how often the normal changes from one return to the next.
        let changes = |image: &RangeImage| {
            image
                .ring_points
                .iter()
                .flat_map(|ring| ring.windows(2))
                .filter(|w| image.normal[w[0] as usize] != image.normal[w[1] as usize])
                .count()
        };
        let (shared, own) = (with_spacing(0.1), with_spacing(0.0));
        // 0.1 m holds ~14 returns on this wall.
        assert!(
            changes(&shared) * 5 < changes(&own),
            "{} against {}",
            changes(&shared),
            changes(&own)
        );
        let (mean_shared, sd_shared, count_shared) = eta_statistics(&shared);
        let (mean_own, sd_own, count_own) = eta_statistics(&own);
        assert!(
            (mean_shared - mean_own).abs() < 1.0,
            "{mean_shared} {mean_own}"
        );
        assert!(sd_shared < sd_own + 1.0, "{sd_shared} {sd_own}");
        assert!(
            count_shared * 10 > count_own * 9,
            "{count_shared} {count_own}"
        );
    }

    #[test]
    fn grazing_returns_are_not_trusted() {
        // At −15° to −10° the floor is seen at 75°–80° incidence: beyond the trust limit.
        let pts = floor_scan(0.6, &[-15.0, -13.0, -11.0, -10.0]);
        let image = calibrate(&pts);
        assert!(image.eta.iter().all(|e| e.is_nan()));
        assert!(image.valid.iter().all(|&v| v), "still valid for geometry");
    }

    #[test]
    fn retro_reflectors_keep_their_value_and_weak_returns_are_invalid() {
        let mut pts = floor_scan(0.5, &[-25.0, -22.0, -20.0, -18.0]);
        pts[100].reflectivity = 200;
        pts[101].reflectivity = 0;
        let image = calibrate(&pts);
        assert!(image.retro[100] && image.eta[100] == 200.0);
        assert!(!image.valid[101]);
    }
}
