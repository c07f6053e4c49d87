//! Glint's virtual VLP-16: scenes whose geometry and reflectivity we control, a robot moving
//! through them, and exactly what the real sensor would put on the wire, with ground truth.
//!
//! - [`config`]: what to simulate ([`SimConfig`], [`Scenario`]) and its validation.
//! - [`scene`], [`geometry`], [`material`] and [`bvh`]: primitives, their reflectivity
//!   patterns and decals, movers, ray casting.
//! - [`trajectory`]: smooth AGV motion in continuous time, sensor mount and vibration.
//! - [`sensor`]: the VLP-16's own tables (from the manual, not from the decoder), echoes,
//!   reflectivity and return selection.
//! - [`simulation`]: packets in send order, per-return truth, ground-truth instants.
//! - [`scenarios`]: the warehouse, the corridor and the yard, their routes and descriptions.
//! - [`changes`]: the same scene on another day, with some goods moved or gone.
//! - [`output`] and [`stream`]: files (pcap, TUM, scene.json) and live UDP.
//!
//! The library never imports the decoder's tables (`glint_driver::model`, `glint_driver::decode`):
//! it uses only the driver's byte-layout setters, pcap writer and NMEA formatter, so that the
//! decoder and the simulator check each other.

pub mod bvh;
pub mod changes;
pub mod config;
pub mod error;
pub mod geometry;
pub mod material;
mod num;
pub mod output;
pub mod scenarios;
pub mod scene;
pub mod sensor;
pub mod simulation;
mod spline;
pub mod stream;
pub mod trajectory;

use std::fmt::Write as _;
use std::net::Ipv4Addr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

pub use config::{
    parse_start_time, ConfigError, Scenario, SimConfig, StartTimeError, UnknownScenario,
};
pub use error::SimError;
pub use glint_driver::wire::ReturnMode;
pub use output::OutputWriter;
pub use simulation::{Packet, PacketKind, PacketRef, SimStats, Simulation, TruthKind, TruthReturn};
pub use stream::{UdpStreamer, UdpTarget};

/// Where a run's packets go.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunOptions<'a> {
    /// Write `scan.pcap`, the ground truth and `scene.json` here.
    pub out_dir: Option<&'a Path>,
    /// Stream the packets live at real-time pace.
    pub udp: Option<&'a UdpTarget>,
    /// Stop early when this becomes true (checked between packets).
    pub stop: Option<&'a AtomicBool>,
    /// The sensor's IPv4 address in the capture (None: the factory 192.168.1.201).
    pub source_address: Option<Ipv4Addr>,
}

/// What a run did and how fast.
#[derive(Debug, Clone, PartialEq)]
pub struct SimSummary {
    /// The scenario.
    pub scenario: Scenario,
    /// The seed.
    pub seed: u64,
    /// Sensor time simulated, s.
    pub simulated_seconds: f64,
    /// Time of the first firing, ns since the Unix epoch.
    pub start_ns: u64,
    /// Sweeps (lines of `groundtruth.tum`).
    pub sweeps: usize,
    /// Data packets produced.
    pub data_packets: u64,
    /// Position packets produced.
    pub position_packets: u64,
    /// Data packets lost on purpose.
    pub dropped_packets: u64,
    /// Laser firings simulated.
    pub rays: u64,
    /// Returns reported.
    pub returns: u64,
    /// Time building the scene and trajectory, s.
    pub setup_seconds: f64,
    /// Time generating packets (ray casting, encoding), s.
    pub compute_seconds: f64,
    /// Time of the whole run including writing and pacing, s.
    pub wall_seconds: f64,
    /// Firings per second of compute time.
    pub rays_per_second: f64,
    /// Sensor seconds per second of compute time.
    pub real_time_factor: f64,
    /// The loop's lap time, s.
    pub lap_seconds: Option<f64>,
    /// The run was stopped before its end.
    pub stopped: bool,
}

impl SimSummary {
    /// A short human-readable report.
    pub fn report(&self) -> String {
        let mut s = String::new();
        let _ = write!(
            s,
            "{} seed {}: {:.1} s simulated, {} sweeps, {} data + {} position packets",
            self.scenario,
            self.seed,
            self.simulated_seconds,
            self.sweeps,
            self.data_packets,
            self.position_packets
        );
        if self.dropped_packets > 0 {
            let _ = write!(s, " ({} data packets dropped)", self.dropped_packets);
        }
        let _ = write!(
            s,
            "\n{} rays, {} returns; {:.2} M rays/s, {:.1}× real time (compute {:.2} s, setup {:.2} s, wall {:.2} s)",
            self.rays,
            self.returns,
            self.rays_per_second / 1e6,
            self.real_time_factor,
            self.compute_seconds,
            self.setup_seconds,
            self.wall_seconds
        );
        if let Some(lap) = self.lap_seconds {
            let _ = write!(
                s,
                "\nlap {lap:.1} s ({:.2} laps)",
                self.simulated_seconds / lap
            );
        }
        if self.stopped {
            s.push_str("\nstopped early");
        }
        s
    }
}

/// Simulates `config` into `dir`: `scan.pcap`, `groundtruth.tum`, `groundtruth_dense.tum`,
/// `scene.json`.
pub fn simulate_to_dir(config: &SimConfig, dir: &Path) -> Result<SimSummary, SimError> {
    run(
        config,
        &RunOptions {
            out_dir: Some(dir),
            ..RunOptions::default()
        },
    )
}

/// Simulates `config` into files, a live UDP stream, or both.
pub fn run(config: &SimConfig, options: &RunOptions<'_>) -> Result<SimSummary, SimError> {
    if options.out_dir.is_none() && options.udp.is_none() {
        return Err(SimError::NoOutput);
    }
    let wall = Instant::now();
    config.validate()?;
    let source = options.source_address.unwrap_or(output::SENSOR_ADDRESS);
    let mut writer = options
        .out_dir
        .map(|dir| OutputWriter::create_from(dir, source))
        .transpose()?;
    let mut streamer = options.udp.map(UdpStreamer::connect).transpose()?;
    let mut sim = Simulation::new(config)?;
    let setup = wall.elapsed();
    let mut compute = Duration::ZERO;
    let mut stopped = false;
    loop {
        if options.stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            stopped = true;
            break;
        }
        let t = Instant::now();
        let Some(packet) = sim.next_packet() else {
            break;
        };
        compute += t.elapsed();
        if let Some(w) = writer.as_mut() {
            w.packet(&packet)?;
        }
        if let Some(s) = streamer.as_mut() {
            s.send(&packet)?;
        }
    }
    let stats = sim.stats();
    let generated = sim.generated_packets();
    let simulated_seconds = generated as f64 * sim.packet_span_ns() as f64 * 1e-9;
    let compute_seconds = compute.as_secs_f64().max(1e-9);
    let summary = SimSummary {
        scenario: config.scenario,
        seed: config.seed,
        simulated_seconds,
        start_ns: sim.start_ns(),
        sweeps: {
            let end = sim.last_generated_firing_ns().unwrap_or(0);
            sim.sweep_end_times().iter().filter(|&&t| t <= end).count()
        },
        data_packets: stats.data_packets,
        position_packets: stats.position_packets,
        dropped_packets: stats.dropped_packets,
        rays: stats.rays,
        returns: stats.returns,
        setup_seconds: setup.as_secs_f64(),
        compute_seconds,
        wall_seconds: wall.elapsed().as_secs_f64(),
        rays_per_second: stats.rays as f64 / compute_seconds,
        real_time_factor: simulated_seconds / compute_seconds,
        lap_seconds: sim.trajectory().figures().map(|f| f.lap_seconds),
        stopped,
    };
    if let Some(w) = writer {
        w.finish(&sim, &summary)?;
    }
    Ok(SimSummary {
        wall_seconds: wall.elapsed().as_secs_f64(),
        ..summary
    })
}
