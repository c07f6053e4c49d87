//! What the end-to-end tests in `tests/` share: the simulator's packets through our driver into
//! the scans the front end takes, and the simulator's ground truth as TUM-style poses.

use glint_core::scan::Scan;
use glint_core::trajectory::StampedPose;
use glint_driver::{SensorStream, StreamConfig};
use glint_sim::simulation::PacketKind;
use glint_sim::Simulation;
use glintd::pipeline::scan_of;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

/// Feeds every packet of `sim` through a fresh driver stream and calls `on_scan` with each
/// sweep, converted as the daemon converts it, in order.
pub fn for_each_scan(sim: &mut Simulation, mut on_scan: impl FnMut(&Scan<'_>)) {
    let mut stream = SensorStream::new(StreamConfig::default());
    let mut points = Vec::new();
    let mut sweeps = Vec::new();
    while let Some(packet) = sim.next_packet() {
        let result = match packet.kind {
            PacketKind::Data => stream.push_data(packet.payload, packet.time_ns),
            PacketKind::Position => stream.push_position(packet.payload),
        };
        result.expect("simulated packets are valid");
        sweeps.extend(std::iter::from_fn(|| stream.take_sweep()));
        for sweep in sweeps.drain(..) {
            if let Some(scan) = scan_of(&sweep, &mut points) {
                on_scan(&scan);
            }
        }
    }
}

/// The simulator's sensor pose at `time_ns`.
pub fn sensor_pose(sim: &Simulation, time_ns: u64) -> Isometry3<f64> {
    let p = sim.sensor_pose_at(time_ns);
    let rotation = UnitQuaternion::from_rotation_matrix(&p.rotation);
    let translation = Translation3::new(p.translation.x, p.translation.y, p.translation.z);
    Isometry3::from_parts(translation, rotation)
}

/// Dense ground truth over the span of `estimates`: every 10 ms, and the last instant.
pub fn dense_groundtruth(sim: &Simulation, estimates: &[StampedPose]) -> Vec<StampedPose> {
    let first = estimates.first().map_or(0, |e| e.time_ns);
    let last = estimates.last().map_or(0, |e| e.time_ns);
    (first..=last)
        .step_by(10_000_000)
        .chain(std::iter::once(last))
        .map(|t| StampedPose {
            time_ns: t,
            pose: sensor_pose(sim, t),
        })
        .collect()
}
