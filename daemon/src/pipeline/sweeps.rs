//! The `sweep` service's part of the pipeline: the front end labels each sweep's returns (which
//! it chose as edges, planes, intensity points) and keeps their calibrated reflectivity; once
//! the sweep's pose is published, the publishing thread hands the returns and the estimated
//! motion to a thread of its own, which deskews them into `base_link` and writes them into
//! shared memory. A pose never waits for this: when that thread is still busy with the previous
//! sweep, the new one is dropped and counted.

use crossbeam_channel::{Receiver, Sender, TrySendError};
use glint_core::features::SweepFeatures;
use glint_core::front_end::FrontEnd;
use glint_core::odometry::SweepDeskew;
use glint_core::scan::Scan;
use glint_ipc::{Domain, PointLabel, StatusFlags, SweepHeader, SweepPoint, SweepPublisher};
use nalgebra::{Isometry3, Point3, Vector6};

/// One return as the front end leaves it: sensor frame at its firing.
#[derive(Debug, Clone, Copy)]
pub(super) struct Return {
    position: [f32; 3],
    /// Firing time minus the sweep's reference time, ns.
    time_offset_ns: i32,
    intensity: f32,
    ring: u16,
    reflectivity: u8,
    label: PointLabel,
}

/// A sweep's returns in firing order, labelled.
#[derive(Debug, Default)]
pub(super) struct LabelledSweep {
    returns: Vec<Return>,
}

impl LabelledSweep {
    /// The returns of `scan`, just processed by `front_end` into `features`.
    pub(super) fn of(scan: &Scan<'_>, front_end: &FrontEnd, features: &SweepFeatures) -> Self {
        let mut returns: Vec<Return> = scan
            .points
            .iter()
            .enumerate()
            .map(|(i, p)| Return {
                position: p.position,
                time_offset_ns: (p.time_ns as i64 - scan.reference_ns as i64)
                    .clamp(i64::from(i32::MIN), i64::from(i32::MAX))
                    as i32,
                intensity: front_end.calibrated(i),
                ring: u16::from(p.ring),
                reflectivity: p.reflectivity,
                label: PointLabel::NONE,
            })
            .collect();
        for (chosen, label) in [
            (&features.edges, PointLabel::EDGE),
            (&features.planes, PointLabel::PLANE),
            (&features.intensity, PointLabel::INTENSITY),
        ] {
            for f in chosen {
                if let Some(r) = returns.get_mut(f.point as usize) {
                    r.label = r.label.with(label);
                }
            }
        }
        Self { returns }
    }
}

/// A sweep whose pose is published, on its way to the `sweep` service.
pub(super) struct PublishedSweep {
    pub(super) sweep: LabelledSweep,
    /// The odometry's body twist over the sweep, sensor frame.
    pub(super) twist: Vector6<f64>,
    /// The pose's stamp and sensor time, ns.
    pub(super) timestamp_ns: u64,
    pub(super) sensor_time_ns: u64,
    /// The `odom` pose's flags.
    pub(super) flags: StatusFlags,
}

/// The publishing thread's handle: offers sweeps without ever waiting.
pub(super) struct SweepOutlet {
    tx: Sender<PublishedSweep>,
    /// Sweeps dropped because the sweep thread was still busy.
    pub(super) dropped: u64,
}

impl SweepOutlet {
    pub(super) fn new(tx: Sender<PublishedSweep>) -> Self {
        Self { tx, dropped: 0 }
    }

    /// Hands `sweep` over, or drops it if the sweep thread is busy or gone.
    pub(super) fn offer(&mut self, sweep: PublishedSweep) {
        match self.tx.try_send(sweep) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                self.dropped += 1;
                // Expected in a replay at full pace; the run's summary has the count.
                if self.dropped == 1 {
                    tracing::info!(
                        "sweep service busy: a sweep was not published (poses unaffected)"
                    );
                }
            }
            Err(TrySendError::Disconnected(_)) => self.dropped += 1,
        }
    }
}

/// The sweep thread: creates the service, then deskews and publishes each sweep until the
/// publishing thread is gone. If the service cannot be created, says so once and drains.
pub(super) fn run_sweep_publisher(
    domain: &Domain,
    base_from_sensor: Isometry3<f64>,
    input: &Receiver<PublishedSweep>,
) {
    let mut publisher = match SweepPublisher::create(domain) {
        Ok(p) => Some(p),
        Err(e) => {
            tracing::error!("the sweep service is off: {:#}", anyhow::Error::from(e));
            None
        }
    };
    let deskew = SweepDeskew::default();
    let mut failures = 0u64;
    for published in input {
        let Some(publisher) = publisher.as_mut() else {
            continue;
        };
        let q = base_from_sensor.rotation.coords;
        let header = SweepHeader {
            timestamp_ns: published.timestamp_ns,
            sensor_time_ns: published.sensor_time_ns,
            flags: published.flags,
            sensor_twist: published.twist.into(),
            sensor_position: base_from_sensor.translation.vector.into(),
            sensor_orientation: [q.x, q.y, q.z, q.w],
            ..SweepHeader::default()
        };
        let returns = &published.sweep.returns;
        let result = publisher.publish(header, returns.len(), |i| {
            base_point(&deskew, &base_from_sensor, &published.twist, &returns[i])
        });
        if let Err(e) = result {
            failures += 1;
            if failures.is_power_of_two() {
                tracing::warn!(failures, "{:#}", anyhow::Error::from(e));
            }
        }
    }
}

/// `r` in `base_link` at the sweep's reference time: deskewed for the twist, then mounted.
fn base_point(
    deskew: &SweepDeskew,
    base_from_sensor: &Isometry3<f64>,
    twist: &Vector6<f64>,
    r: &Return,
) -> SweepPoint {
    let at_reference = deskew.point(twist, r.position, r.time_offset_ns as f32 * 1e-9);
    let p = base_from_sensor * Point3::from(at_reference);
    SweepPoint {
        position: [p.x as f32, p.y as f32, p.z as f32],
        intensity: r.intensity,
        time_offset_ns: r.time_offset_ns,
        ring: r.ring,
        reflectivity: r.reflectivity,
        label: r.label,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glint_core::config::OdometryConfig;
    use glint_core::scan::ScanPoint;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A square room seen from its middle, one ring per 2° of elevation.
    fn room() -> Vec<ScanPoint> {
        let mut points = Vec::new();
        for ring in 0..16u8 {
            let elevation = (f32::from(ring) - 7.5) * 2f32.to_radians();
            for column in 0..1800 {
                let azimuth = column as f32 * 0.2f32.to_radians();
                let (s, c) = azimuth.sin_cos();
                let reach = 5.0 / c.abs().max(s.abs());
                points.push(ScanPoint {
                    position: [reach * c, -reach * s, reach * elevation.tan()],
                    time_ns: 1_000_000_000 + column as u64 * 55_296,
                    reflectivity: if column % 300 < 20 { 90 } else { 20 },
                    ring,
                });
            }
        }
        points
    }

    #[test]
    fn labels_follow_the_features_and_points_the_mounting() {
        let points = room();
        let scan = Scan {
            points: &points,
            rings: 16,
            reference_ns: points.iter().map(|p| p.time_ns).max().unwrap(),
        };
        let mut front_end = FrontEnd::new(&OdometryConfig::default());
        let mut features = SweepFeatures::default();
        front_end.process(&scan, &mut features);
        let sweep = LabelledSweep::of(&scan, &front_end, &features);
        assert_eq!(sweep.returns.len(), points.len());
        let count = |label| {
            sweep
                .returns
                .iter()
                .filter(|r| r.label.contains(label))
                .count()
        };
        assert_eq!(count(PointLabel::EDGE), features.edges.len());
        assert_eq!(count(PointLabel::PLANE), features.planes.len());
        assert_eq!(count(PointLabel::INTENSITY), features.intensity.len());
        assert!(
            features.planes.len() > 10,
            "{} planes",
            features.planes.len()
        );
        for f in features.edges.iter().chain(&features.planes) {
            assert_eq!(sweep.returns[f.point as usize].position, f.position);
        }
        assert!(sweep.returns.iter().any(|r| r.intensity.is_finite()));
        assert!(sweep.returns.iter().all(|r| r.time_offset_ns <= 0));

        // Not moving: a point is where the mounting puts it.
        let mounting = Isometry3::from_parts(
            Translation3::new(0.2, 0.0, 1.1),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5),
        );
        let deskew = SweepDeskew::default();
        let r = &sweep.returns[1234];
        let p = base_point(&deskew, &mounting, &Vector6::zeros(), r);
        let expected = mounting * Point3::from(r.position.map(f64::from));
        for k in 0..3 {
            assert!((f64::from(p.position[k]) - expected[k]).abs() < 1e-5);
        }
        assert_eq!(
            (p.ring, p.reflectivity, p.label),
            (r.ring, r.reflectivity, r.label)
        );
        // Turning: a return fired before the reference moves with the turn undone.
        let turning = Vector6::new(0.0, 0.0, 1.0, 0.0, 0.0, 0.0);
        let early = sweep
            .returns
            .iter()
            .find(|r| r.time_offset_ns < -50_000_000)
            .unwrap();
        let moved = base_point(&deskew, &Isometry3::identity(), &turning, early);
        let angle = (early.time_offset_ns as f64 * 1e-9) * 1.0;
        let expected = UnitQuaternion::from_euler_angles(0.0, 0.0, angle)
            * Point3::from(early.position.map(f64::from));
        for k in 0..3 {
            assert!((f64::from(moved.position[k]) - expected[k]).abs() < 2e-3);
        }
    }
}
