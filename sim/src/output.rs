//! A run's files: `scan.pcap` (Ethernet/IPv4/UDP as the sensor sends it), `groundtruth.tum`
//! (the sensor's pose at every sweep's last firing), `groundtruth_dense.tum` (100 Hz),
//! `scene.json` (what was simulated, with its conventions) and, for a run with a kidnap,
//! `kidnaps.txt` (the ground-truth instants that bracket each jump).

use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::net::Ipv4Addr;
use std::path::{Path, PathBuf};

use glint_driver::nmea::civil_from_days;
use glint_driver::pcap::{CaptureWriter, UdpEndpoints};
use serde_json::{json, Value};

use crate::error::SimError;
use crate::sensor::{
    vertical_offset_m, BLOCK_NS, DETECTION_THRESHOLD, ELEVATION_DEG, LASERS, LASER_INTERVAL_NS,
    MAX_RANGE_M, MIN_RANGE_M, PRODUCT_ID, SEQUENCE_NS,
};
use crate::simulation::{
    PacketKind, PacketRef, Simulation, DATA_PORT, POSITION_PERIOD_NS, POSITION_PORT,
    SEND_LATENCY_NS,
};
use crate::trajectory::Pose;
use crate::SimSummary;

/// The sensor's factory address.
pub const SENSOR_ADDRESS: Ipv4Addr = Ipv4Addr::new(192, 168, 1, 201);

/// File names inside the output directory.
pub const PCAP_FILE: &str = "scan.pcap";
/// See [`PCAP_FILE`].
pub const GROUNDTRUTH_FILE: &str = "groundtruth.tum";
/// See [`PCAP_FILE`].
pub const DENSE_GROUNDTRUTH_FILE: &str = "groundtruth_dense.tum";
/// See [`PCAP_FILE`].
pub const SCENE_FILE: &str = "scene.json";
/// See [`PCAP_FILE`]. Written only when the run has a kidnap.
pub const KIDNAPS_FILE: &str = "kidnaps.txt";

/// Endpoints of a packet as the sensor sends it: from 192.168.1.201 to broadcast, source port
/// equal to destination port.
pub fn endpoints(kind: PacketKind) -> UdpEndpoints {
    endpoints_from(SENSOR_ADDRESS, kind)
}

/// [`endpoints`] of a sensor at `source`.
pub fn endpoints_from(source: Ipv4Addr, kind: PacketKind) -> UdpEndpoints {
    let port = kind.default_port();
    UdpEndpoints {
        source: (source, port),
        destination: (Ipv4Addr::BROADCAST, port),
    }
}

/// Writes a run into a directory.
pub struct OutputWriter {
    dir: PathBuf,
    pcap: CaptureWriter<BufWriter<File>>,
    source: Ipv4Addr,
}

impl std::fmt::Debug for OutputWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OutputWriter")
            .field("dir", &self.dir)
            .finish()
    }
}

fn io_error<'a>(
    action: &'static str,
    path: &'a Path,
) -> impl FnOnce(std::io::Error) -> SimError + 'a {
    move |source| SimError::Io {
        action,
        path: path.to_path_buf(),
        source,
    }
}

impl OutputWriter {
    /// Creates the directory (and parents) and opens the capture, of a sensor at its factory
    /// address.
    pub fn create(dir: &Path) -> Result<OutputWriter, SimError> {
        Self::create_from(dir, SENSOR_ADDRESS)
    }

    /// [`Self::create`] for a sensor at `source` (the IPv4 source of every packet).
    pub fn create_from(dir: &Path, source: Ipv4Addr) -> Result<OutputWriter, SimError> {
        fs::create_dir_all(dir).map_err(io_error("create directory", dir))?;
        let path = dir.join(PCAP_FILE);
        let pcap = CaptureWriter::create(&path).map_err(io_error("create", &path))?;
        Ok(OutputWriter {
            dir: dir.to_path_buf(),
            pcap,
            source,
        })
    }

    /// Appends a packet to the capture, stamped with its send time.
    pub fn packet(&mut self, packet: &PacketRef<'_>) -> Result<(), SimError> {
        let path = self.dir.join(PCAP_FILE);
        self.pcap
            .write_udp(
                packet.time_ns,
                endpoints_from(self.source, packet.kind),
                packet.payload,
            )
            .map_err(io_error("write", &path))
    }

    /// Flushes the capture and writes the ground truth and the scene description.
    pub fn finish(self, sim: &Simulation, summary: &SimSummary) -> Result<(), SimError> {
        let pcap_path = self.dir.join(PCAP_FILE);
        self.pcap.finish().map_err(io_error("write", &pcap_path))?;
        // A run stopped early has ground truth only for what it simulated.
        let end = sim.last_generated_firing_ns().unwrap_or(0);
        let upto =
            |times: Vec<u64>| -> Vec<u64> { times.into_iter().filter(|&t| t <= end).collect() };
        write_tum(
            &self.dir.join(GROUNDTRUTH_FILE),
            &upto(sim.sweep_end_times()),
            |t| sim.sensor_pose_at(t),
        )?;
        write_tum(
            &self.dir.join(DENSE_GROUNDTRUTH_FILE),
            &upto(sim.dense_times()),
            |t| sim.sensor_pose_at(t),
        )?;
        let kidnaps_path = self.dir.join(KIDNAPS_FILE);
        let kidnaps: Vec<String> = sim
            .kidnaps()
            .iter()
            .filter(|k| k.after_ns <= end)
            .map(|k| kidnap_line(k.before_ns, k.after_ns))
            .collect();
        if sim.config().kidnap_s.is_some() {
            let text: String = kidnaps.iter().map(|l| format!("{l}\n")).collect();
            fs::write(&kidnaps_path, text).map_err(io_error("write", &kidnaps_path))?;
        } else if kidnaps_path.exists() {
            // A kidnaps.txt from an earlier run into this directory would describe jumps this
            // run does not have.
            fs::remove_file(&kidnaps_path).map_err(io_error("remove", &kidnaps_path))?;
        }
        let path = self.dir.join(SCENE_FILE);
        let mut scene = scene_json(sim, summary);
        scene["network"]["source"] = json!(self.source.to_string());
        let text = serde_json::to_string_pretty(&scene).map_err(|e| SimError::Io {
            action: "serialise",
            path: path.clone(),
            source: e.into(),
        })?;
        fs::write(&path, text).map_err(io_error("write", &path))
    }
}

/// One TUM line: `t x y z qx qy qz qw`, t in seconds with 9 decimals (exact from the ns).
pub fn tum_line(time_ns: u64, pose: &Pose) -> String {
    let q = pose.quaternion_xyzw();
    let p = pose.translation;
    format!(
        "{}.{:09} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
        time_ns / 1_000_000_000,
        time_ns % 1_000_000_000,
        p.x,
        p.y,
        p.z,
        q[0],
        q[1],
        q[2],
        q[3]
    )
}

fn write_tum(path: &Path, times: &[u64], pose: impl Fn(u64) -> Pose) -> Result<(), SimError> {
    let file = File::create(path).map_err(io_error("create", path))?;
    let mut out = BufWriter::new(file);
    for &t in times {
        writeln!(out, "{}", tum_line(t, &pose(t))).map_err(io_error("write", path))?;
    }
    out.flush().map_err(io_error("write", path))
}

/// One line of `kidnaps.txt`: the last ground-truth time before the jump and the first after
/// it, in seconds with 9 decimals.
pub fn kidnap_line(before_ns: u64, after_ns: u64) -> String {
    let s = |t: u64| format!("{}.{:09}", t / 1_000_000_000, t % 1_000_000_000);
    format!("{} {}", s(before_ns), s(after_ns))
}

/// An instant as RFC 3339 UTC with ns.
pub fn format_utc(time_ns: u64) -> String {
    let secs = time_ns / 1_000_000_000;
    let (y, m, d) = civil_from_days((secs / 86_400) as i64);
    let tod = secs % 86_400;
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{:09}Z",
        tod / 3600,
        (tod / 60) % 60,
        tod % 60,
        time_ns % 1_000_000_000
    )
}

/// What was simulated, with the conventions needed to use the outputs.
pub fn scene_json(sim: &Simulation, summary: &SimSummary) -> Value {
    let mut value = base_scene_json(sim, summary);
    if sim.config().is_variant() {
        value["variant"] = variant_json(sim);
    }
    value
}

/// How the run departs from its scenario's own route, unit and contents.
fn variant_json(sim: &Simulation) -> Value {
    let c = sim.config();
    let kidnaps: Vec<Value> = sim
        .kidnaps()
        .iter()
        .map(|k| {
            json!({
                "before_ns": k.before_ns,
                "after_ns": k.after_ns,
                "from_xy": k.from,
                "to_xy": k.to,
                "distance_m": (k.to[0] - k.from[0]).hypot(k.to[1] - k.from[1]),
            })
        })
        .collect();
    json!({
        "path_seed": c.path_seed,
        "reverse": c.reverse,
        "start_fraction": c.start_fraction,
        "unit_seed": c.unit_seed,
        "change": c.change,
        "change_seed": c.change_seed,
        "movers": c.movers,
        "kidnap_s": c.kidnap_s,
        "kidnaps": kidnaps,
        "changed_objects": sim.changes(),
        "conventions": {
            "frame": "every run of one scenario and seed shares the scene frame, whatever its route, direction, start, unit or changes",
            "kidnaps": "the robot is teleported right after a sweep end; before_ns and after_ns are consecutive sweep ends (lines of groundtruth.tum), groundtruth_dense.tum has no line strictly between them, and kidnaps.txt lists them in seconds, one jump per line: never interpolate across a jump",
            "changed_objects": "movable objects of the unchanged scene (centre of their box) removed (shift null) or moved horizontally by shift; primitive ids in scene.primitives are those of the changed scene",
        },
    })
}

fn base_scene_json(sim: &Simulation, summary: &SimSummary) -> Value {
    let c = sim.config();
    let sensor = sim.sensor();
    let scene = sim.scene();
    let traj = sim.trajectory();
    let primitives: Vec<Value> = scene
        .primitives()
        .iter()
        .enumerate()
        .map(|(id, p)| json!({ "id": id, "tag": scene.tags()[usize::from(p.tag)], "material": p.material.0, "shape": p.shape }))
        .collect();
    let movers: Vec<Value> = scene
        .movers()
        .iter()
        .enumerate()
        .map(|(k, m)| {
            json!({
                "id": scene.primitives().len() + k,
                "tag": scene.tags()[usize::from(m.tag)],
                "material": m.material.0,
                "shape": m.shape,
                "travel": m.travel,
                "speed": m.speed,
                "phase_s": m.phase,
                "motion": "slides back and forth between shape and shape + travel at constant speed; position at t s after the start: offset = travel × triangle((t + phase) / (2 |travel| / speed))",
            })
        })
        .collect();
    json!({
        "format": "glint-sim scene 1",
        "conventions": {
            "units": "SI (m, rad, s) unless a name says otherwise (_deg, _ns); absolute times are ns since the Unix epoch (UTC)",
            "scene_frame": "right-handed, z up, z = 0 the floor or ground; poses and primitives are in this frame",
            "sensor_frame": "REP-103: x forward, y left, z up. Azimuth α is measured clockwise seen from above, 0 = +x. Laser l with elevation ω fires along (cos ω cos α, −cos ω sin α, sin ω) from (0, 0, 41.91 mm × tan(−ω)); the reported distance is along that ray from that origin",
            "timing": "firing sequence n starts at start_time_ns + n × 55296 ns; laser l of a sequence fires l × 2304 ns later; a data packet's timestamp field is the µs past the UTC hour of its first firing, truncated; the block azimuth is the rotor angle at the block's first firing in 0.01°, rounded, mod 36000; the pcap record time is when the packet leaves the sensor",
            "groundtruth.tum": "t x y z qx qy qz qw: the sensor's pose in the scene frame at every sweep's last firing (laser 15 of the last sequence starting before the rotor crosses azimuth 0; the driver, which sees rounded azimuths, may cut one 55 µs sequence earlier or later)",
            "groundtruth_dense.tum": "the same every 10 ms from the first firing",
            "tum": "t in seconds with 9 decimals; quaternion Hamilton qx qy qz qw (qw >= 0), rotating sensor-frame vectors into the scene frame; position of the sensor origin",
            "evaluation": "interpolate the ground truth at the estimate's own timestamps: an estimate must be stamped with the instant it describes",
            "reflectivity": "diffuse: round(100 ρ cos α gain_l c + N(0, σ_r)) clamped to 0..100 (c = coverage of partial surfaces); retro-reflective: round(value (0.85 + 0.15 cos α) + N(0, 2σ_r)) clamped to 101..255",
            "detection": format!("a diffuse echo is reported if ρ cos α c (100 m / R)² >= {DETECTION_THRESHOLD}; retro echoes always; only {MIN_RANGE_M} m <= R <= {MAX_RANGE_M} m; no return = distance 0"),
            "returns": "strongest = largest expected reflectivity; last = farthest; dual: even block the last, odd block the strongest (the second strongest when the strongest is the last); identical blocks when there is one echo",
        },
        "run": {
            "scenario": c.scenario.name(),
            "seed": c.seed,
            "seconds": c.seconds,
            "start_time_ns": sim.start_ns(),
            "start_time_utc": format_utc(sim.start_ns()),
            "last_firing_ns": sim.last_firing_ns(),
            "rpm": c.rpm,
            "return_mode": c.return_mode.name(),
            "noise": c.noise,
            "range_noise_m": sensor.range_sigma(),
            "reflectivity_noise": sensor.reflectivity_sigma(),
            "laser_gain_bias": c.laser_gain_bias,
            "packet_loss": c.packet_loss,
        },
        "sensor": {
            "model": "VLP-16",
            "product_id": PRODUCT_ID,
            "return_mode_byte": c.return_mode.byte(),
            "elevation_deg": ELEVATION_DEG,
            "vertical_offset_m": (0..LASERS).map(vertical_offset_m).collect::<Vec<_>>(),
            "laser_gain": sensor.laser_gains(),
            "laser_interval_ns": LASER_INTERVAL_NS,
            "sequence_ns": SEQUENCE_NS,
            "block_ns": BLOCK_NS,
            "start_azimuth_rad": sensor.start_azimuth(),
            "mount_on_base": traj.mount(),
            "vibration": traj.vibration(),
        },
        "network": {
            "source": SENSOR_ADDRESS.to_string(),
            "destination": Ipv4Addr::BROADCAST.to_string(),
            "data_port": DATA_PORT,
            "position_port": POSITION_PORT,
            "position_period_ns": POSITION_PERIOD_NS,
            "send_latency_ns": SEND_LATENCY_NS,
            "position_packets": "PPS locked; $GPRMC of the last whole second; timestamp field = µs past the hour when sent",
        },
        "trajectory": {
            "kind": if traj.waypoints().is_empty() { "fixed" } else { "closed loop: periodic cubic spline through the waypoints, resampled by arc length; speed profile bounded by the limits; repeats lap after lap" },
            "waypoints": traj.waypoints(),
            "limits": traj.limits(),
            "figures": traj.figures(),
        },
        "scene": {
            "description": sim.description(),
            "tags": scene.tags(),
            "materials": scene.materials(),
            "primitives": primitives,
            "movers": movers,
        },
        "outputs": {
            "sweeps": summary.sweeps,
            "data_packets": summary.data_packets,
            "position_packets": summary.position_packets,
            "dropped_packets": summary.dropped_packets,
            "rays": summary.rays,
            "returns": summary.returns,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tum_lines_and_utc_are_exact() {
        let pose = Pose::from_xyz_ypr([1.0, -2.5, 0.75], 0.0, 0.0, 0.0);
        assert_eq!(
            tum_line(1_700_000_000_000_000_123, &pose),
            "1700000000.000000123 1.000000 -2.500000 0.750000 0.000000000 0.000000000 0.000000000 1.000000000"
        );
        assert_eq!(
            format_utc(1_700_000_000_500_000_000),
            "2023-11-14T22:13:20.500000000Z"
        );
    }
}
