//! Steps 1–2 of the method for one sweep: intensity calibration (the range image, normals and
//! incidence angles) and the selection of edge, plane and intensity points. Independent of the
//! motion, so it runs on a thread of its own ahead of the odometry. The calibration and the
//! returns' roughness, and the picks of all sectors but the last, can also be worked out as the
//! sweep streams in, so that once the last return is in only the sweep's end and its last
//! sector remain.

use crate::calibration::RangeImage;
use crate::config::OdometryConfig;
use crate::features::{FeatureSelector, SweepFeatures};
use crate::scan::{Scan, ScanPoint};

/// Steps 1–2 for one sweep, reusing its buffers from sweep to sweep.
#[derive(Debug, Default)]
pub struct FrontEnd {
    config: OdometryConfig,
    image: RangeImage,
    selector: FeatureSelector,
    /// The last return streamed into the open sweep, if any.
    streamed: Option<ScanPoint>,
    /// The open sweep's edges and planes handed out by [`Self::early_features`].
    handed_early: (usize, usize),
}

impl FrontEnd {
    /// A front end with the calibration and feature sections of `config`.
    pub fn new(config: &OdometryConfig) -> Self {
        Self {
            config: config.clone(),
            ..Self::default()
        }
    }

    /// Opens a sweep of a sensor with `rings` rings to stream returns into, dropping whatever
    /// was streamed before.
    pub fn begin(&mut self, rings: usize) {
        self.image.begin(rings);
        self.selector.begin(self.image.rings());
        self.streamed = None;
        self.handed_early = (0, 0);
    }

    /// Streams the open sweep's next returns in, in firing order, calibrating those whose
    /// neighbourhood is in and measuring the roughness of those whose neighbours are calibrated.
    pub fn stream(&mut self, points: &[ScanPoint]) {
        if let Some(&last) = points.last() {
            self.image.extend(points, &self.config.calibration);
            self.selector.extend(&self.image, &self.config.features);
            self.streamed = Some(last);
        }
    }

    /// Returns of the open sweep streamed in so far.
    pub fn streamed(&self) -> usize {
        self.streamed.map_or(0, |_| self.image.len())
    }

    /// Calibrates `scan` and selects its features into `out`. When the returns streamed in
    /// since [`Self::begin`] are the start of `scan` only the rest is calibrated now, otherwise
    /// the whole of it; the result is the same either way.
    pub fn process(&mut self, scan: &Scan<'_>, out: &mut SweepFeatures) {
        let calibration = &self.config.calibration;
        let streamed = self.streamed();
        let continues = streamed > 0
            && self.image.rings() == scan.rings.max(1)
            && scan.points.get(streamed - 1) == self.streamed.as_ref();
        if continues {
            self.image.extend(&scan.points[streamed..], calibration);
            self.image.finish(calibration);
            self.selector
                .finish(scan, &self.image, &self.config.features, out);
        } else {
            self.image.build(scan, calibration);
            self.selector
                .select(scan, &self.image, &self.config.features, out);
        }
        self.streamed = None;
    }

    /// The edges and planes of `features`, which [`Self::process`] selected from `points`, with
    /// the sweep's first return as the reference time, as [`Self::early_features`] hands them
    /// out, into `out`: for the odometry to associate those it was not handed early.
    pub fn features_from_start(
        &self,
        points: &[ScanPoint],
        features: &SweepFeatures,
        out: &mut SweepFeatures,
    ) {
        let scan = Scan {
            points,
            rings: self.image.rings(),
            reference_ns: points.first().map_or(0, |p| p.time_ns),
        };
        crate::features::features_of(&scan, &self.image, features, out);
    }

    /// Feature sectors of the open sweep already picked (see [`FeatureSelector`]): the
    /// sectors left for its close are the others.
    pub fn sectors_picked(&self) -> usize {
        self.selector.picked_early()
    }

    /// The edges and planes of the open sweep picked since the last call (since
    /// [`Self::begin`] the first time), as features of `streamed` (the returns streamed in
    /// since [`Self::begin`]) with the first of them as the reference time, into `out`: what
    /// the odometry can associate before the sweep closes (see
    /// [`crate::odometry::Odometry::associate_early`]).
    pub fn early_features(&mut self, streamed: &[ScanPoint], out: &mut SweepFeatures) {
        let scan = Scan {
            points: streamed,
            rings: self.image.rings(),
            reference_ns: streamed.first().map_or(0, |p| p.time_ns),
        };
        self.handed_early = self.selector.early_features(
            &scan,
            &self.image,
            &self.config.features,
            self.handed_early,
            out,
        );
    }

    /// How many rings of the sweep last processed had been streamed in and had to be
    /// recalibrated at its close (see [`RangeImage`]).
    pub fn recalibrated(&self) -> usize {
        self.image.recalibrated()
    }

    /// Return `i` of the scan last processed: its calibrated reflectivity η, NaN where it has
    /// none (see [`RangeImage::calibrated`]).
    pub fn calibrated(&self, i: usize) -> f32 {
        self.image.calibrated(i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::Feature;

    /// A VLP-16 sweep of `columns` columns (1800 a turn, more to wrap onto its start) inside a
    /// 10 m × 6 m box 2.5 m tall with a pillar, no ceiling (the upper rings see sky over the
    /// near walls), range noise of ±1 cm, reflectivity varying along the walls with a few
    /// retro-reflective patches.
    fn box_sweep(columns: u64) -> Vec<ScanPoint> {
        let mut points = Vec::new();
        for c in 0..columns {
            let az = -(c as f32) * 0.2f32.to_radians();
            for ring in 0..16u8 {
                let el = (-15.0 + 2.0 * f32::from(ring)).to_radians();
                let d = [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()];
                let mut range = f32::INFINITY;
                for (axis, bound) in [(0, 6.0f32), (0, -4.0), (1, 3.0), (1, -3.0), (2, -0.8)] {
                    let t = bound / d[axis];
                    if t > 0.0 && t < range {
                        range = t;
                    }
                }
                // The pillar: a 0.4 m square at (2, 1.5).
                for (axis, bound) in [(0, 1.8f32), (1, 1.3)] {
                    let t = bound / d[axis];
                    let p = [d[0] * t, d[1] * t];
                    if t > 0.0
                        && t < range
                        && (1.8..=2.2).contains(&p[0])
                        && (1.3..=1.7).contains(&p[1])
                    {
                        range = t;
                    }
                }
                if d[2] * range > 1.7 {
                    continue;
                }
                let k = c * 16 + u64::from(ring);
                let noise = ((k.wrapping_mul(2_654_435_761) % 2001) as f32 / 1000.0 - 1.0) * 0.01;
                let range = range + noise;
                let along = (az.to_degrees() * 3.0).sin();
                let reflectivity = if (c + 50) % 97 < 4 {
                    180
                } else {
                    (40.0 + 25.0 * along) as u8
                };
                points.push(ScanPoint {
                    position: [d[0] * range, d[1] * range, d[2] * range],
                    time_ns: 1_000_000_000 + c * 55_296,
                    reflectivity,
                    ring,
                });
            }
        }
        points
    }

    fn bits(features: &[Feature]) -> Vec<[u32; 9]> {
        features
            .iter()
            .map(|f| {
                [
                    f.position[0].to_bits(),
                    f.position[1].to_bits(),
                    f.position[2].to_bits(),
                    f.dt.to_bits(),
                    f.eta.to_bits(),
                    f.normal[0].to_bits(),
                    f.normal[1].to_bits(),
                    f.normal[2].to_bits(),
                    f.point,
                ]
            })
            .collect()
    }

    /// What a front end made of its last sweep, bit for bit: each return's η and normal, each
    /// ring's roughness, the features.
    fn outcome(front_end: &FrontEnd, features: &SweepFeatures, n: usize) -> Vec<Vec<[u32; 9]>> {
        let calibrated = (0..n)
            .map(|i| {
                let mut row = [0; 9];
                row[0] = front_end.calibrated(i).to_bits();
                for (slot, v) in row[1..4].iter_mut().zip(front_end.image.normal[i]) {
                    *slot = v.to_bits();
                }
                row
            })
            .collect();
        let roughness = front_end
            .selector
            .roughness()
            .map(|(g, i, w)| {
                let mut row = [0; 9];
                row[..3].copy_from_slice(&[g.to_bits(), i.to_bits(), w]);
                row
            })
            .collect();
        vec![
            calibrated,
            roughness,
            bits(&features.edges),
            bits(&features.planes),
            bits(&features.intensity),
            bits(&features.calibrated),
        ]
    }

    fn scan(points: &[ScanPoint]) -> Scan<'_> {
        Scan {
            points,
            rings: 16,
            reference_ns: points.last().unwrap().time_ns,
        }
    }

    #[test]
    fn streamed_in_it_calibrates_and_selects_exactly_as_whole() {
        let config = OdometryConfig::default();
        for columns in [1800, 1803] {
            let points = box_sweep(columns);
            let scan = scan(&points);
            // Each after a sweep like it, which leaves its plan of sectors.
            let before = later(&points, -1);
            let before = Scan {
                points: &before,
                ..scan
            };
            let mut whole = FrontEnd::new(&config);
            let mut features = SweepFeatures::default();
            whole.process(&before, &mut features);
            whole.process(&scan, &mut features);
            let expected = outcome(&whole, &features, points.len());
            assert!(
                features.edges.len() > 8 && features.planes.len() > 100,
                "{} edges, {} planes, {} intensity",
                features.edges.len(),
                features.planes.len(),
                features.intensity.len()
            );

            // A packet's worth at a time, the last packet's with the closed sweep.
            let mut streamed = FrontEnd::new(&config);
            streamed.process(&before, &mut features);
            streamed.begin(16);
            let last_packet = points.len() - 384;
            for chunk in points[..last_packet].chunks(384) {
                streamed.stream(chunk);
            }
            assert_eq!(streamed.streamed(), last_packet);
            // All sectors but the last are picked before the close, unless a ring is to be
            // recalibrated.
            assert!(
                streamed.sectors_picked() == config.features.sectors - 1 || columns > 1800,
                "{} sectors picked",
                streamed.sectors_picked()
            );
            // Most of it is calibrated before the sweep closes.
            let pending = streamed.image.pending();
            assert!(
                pending < 16 * 30,
                "{pending} of {last_packet} returns not calibrated"
            );
            let mut streamed_features = SweepFeatures::default();
            streamed.process(&scan, &mut streamed_features);
            assert_eq!(
                outcome(&streamed, &streamed_features, points.len()),
                expected
            );
            // A sweep wrapping onto its start changes cells that normals there read: the rings
            // that read them are recalibrated; one turn exactly needs none.
            let rings = streamed.recalibrated();
            assert_eq!(
                rings > 0,
                columns > 1800,
                "{rings} rings, {columns} columns"
            );
        }
    }

    /// `points` `sweeps` sweeps of 100 ms later.
    fn later(points: &[ScanPoint], sweeps: i64) -> Vec<ScanPoint> {
        let mut points = points.to_vec();
        for p in &mut points {
            p.time_ns = p.time_ns.wrapping_add_signed(sweeps * 100_000_000);
        }
        points
    }

    /// What a new front end makes of `points` as one sweep.
    fn processed_whole(config: &OdometryConfig, points: &[ScanPoint]) -> Vec<Vec<[u32; 9]>> {
        let mut whole = FrontEnd::new(config);
        let mut features = SweepFeatures::default();
        whole.process(&scan(points), &mut features);
        outcome(&whole, &features, points.len())
    }

    #[test]
    fn a_sweep_unlike_the_last_is_picked_again_by_its_own_sectors() {
        let config = OdometryConfig::default();
        let points = box_sweep(1800);
        let expected = processed_whole(&config, &points);
        let mut features = SweepFeatures::default();

        // The sweep before saw nothing of the upper rings over half its turn.
        let half_seen: Vec<ScanPoint> = later(&points, -1)
            .into_iter()
            .enumerate()
            .filter(|(i, p)| p.ring < 8 || i % (16 * 1800) < 16 * 900)
            .map(|(_, p)| p)
            .collect();
        let mut front_end = FrontEnd::new(&config);
        front_end.process(&scan(&half_seen), &mut features);
        front_end.begin(16);
        for chunk in points[..points.len() - 384].chunks(384) {
            front_end.stream(chunk);
        }
        assert!(front_end.sectors_picked() > 0);
        front_end.process(&scan(&points), &mut features);
        assert_eq!(outcome(&front_end, &features, points.len()), expected);
    }

    #[test]
    fn returns_streamed_from_another_sweep_are_dropped() {
        let config = OdometryConfig::default();
        let points = box_sweep(1800);
        let expected = processed_whole(&config, &points);

        let other = later(&points, 1);
        let mut front_end = FrontEnd::new(&config);
        front_end.begin(16);
        front_end.stream(&other[..5000]);
        let mut features = SweepFeatures::default();
        front_end.process(&scan(&points), &mut features);
        assert_eq!(outcome(&front_end, &features, points.len()), expected);
        assert_eq!(front_end.recalibrated(), 0);

        // Streamed for another sensor's ring count.
        front_end.begin(32);
        front_end.stream(&points[..5000]);
        front_end.process(&scan(&points), &mut features);
        assert_eq!(outcome(&front_end, &features, points.len()), expected);
    }
}
