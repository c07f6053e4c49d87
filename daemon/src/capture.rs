//! Replaying a capture through the driver for the inspection commands: the sensor options they
//! share, and one loop from file to sweeps with everything counted.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use glint_driver::calibration::load_calibration;
use glint_driver::pcap::{CaptureError, CaptureStats};
use glint_driver::{
    Model, PacketKind, PcapSource, Ports, SensorStream, StreamConfig, StreamError, Sweep,
    SweepConfig,
};

/// Options that say how to read the sensor's packets.
#[derive(Args, Debug, Clone)]
pub struct SensorArgs {
    /// Sensor model (vlp16, puck-hires, hdl32e). Overrides detection; by default the packets'
    /// timing decides, checked against the product-id byte.
    #[arg(long)]
    pub model: Option<Model>,
    /// Laser calibration file in the ROS VLP16db.yaml layout.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// UDP port of data packets.
    #[arg(long, default_value_t = 2368)]
    pub data_port: u16,
    /// UDP port of position packets.
    #[arg(long, default_value_t = 8308)]
    pub position_port: u16,
    /// Azimuth where sweeps are cut, degrees clockwise from the sensor's +x axis.
    #[arg(long, default_value_t = 0.0)]
    pub cut_azimuth: f64,
}

impl SensorArgs {
    /// The stream configuration these options describe.
    pub fn stream_config(&self) -> Result<StreamConfig> {
        let calibration = match &self.calibration {
            Some(path) => Some(load_calibration(path)?),
            None => None,
        };
        anyhow::ensure!(
            self.cut_azimuth.is_finite() && (0.0..360.0).contains(&self.cut_azimuth),
            "--cut-azimuth must be in [0, 360) degrees, got {}",
            self.cut_azimuth
        );
        Ok(StreamConfig {
            model: self.model,
            calibration,
            sweep: SweepConfig {
                cut_azimuth: self.cut_azimuth.to_radians(),
                ..SweepConfig::default()
            },
        })
    }

    /// The ports to read.
    pub fn ports(&self) -> Ports {
        Ports {
            data: self.data_port,
            position: self.position_port,
        }
    }
}

/// What a replay saw.
#[derive(Debug)]
pub struct CaptureReport {
    /// The stream, for its detection and counters.
    pub stream: SensorStream,
    /// Datagrams to the data port, the position port and other ports.
    pub port_counts: (u64, u64, u64),
    /// Records the capture reader skipped.
    pub capture: CaptureStats,
    /// The error that ended the capture early, if any (everything before it was decoded).
    pub damage: Option<CaptureError>,
}

/// Replays `path` through a fresh stream, calling `on_sweep` for every sweep in order.
pub fn replay(
    path: &Path,
    sensor: &SensorArgs,
    mut on_sweep: impl FnMut(&Sweep) -> Result<()>,
) -> Result<CaptureReport> {
    replay_stream(
        path,
        sensor.ports(),
        sensor.stream_config()?,
        |_, _| true,
        |sweep, stream| {
            on_sweep(&sweep)?;
            if let Some(r) = stream.recycler() {
                r.recycle(sweep);
            }
            Ok(())
        },
    )
}

/// Replays `path` through a fresh stream configured by `config`. `on_packet` sees each sensor
/// packet's record time and the stream before the packet is decoded (for pacing and counters)
/// and returns false to stop early; `on_sweep` takes each sweep as it is closed.
pub fn replay_stream(
    path: &Path,
    ports: Ports,
    config: StreamConfig,
    mut on_packet: impl FnMut(u64, &SensorStream) -> bool,
    mut on_sweep: impl FnMut(Sweep, &SensorStream) -> Result<()>,
) -> Result<CaptureReport> {
    let mut source = PcapSource::open(path, ports)
        .with_context(|| format!("cannot replay {}", path.display()))?;
    let mut stream = SensorStream::new(config);
    let mut dropped_logged = 0u32;
    let mut handle = |stream: &mut SensorStream, result: Result<(), StreamError>| -> Result<()> {
        match result {
            Ok(()) => {}
            Err(e) if e.is_recoverable() => {
                if dropped_logged < 10 {
                    tracing::warn!("{e}");
                    dropped_logged += 1;
                }
            }
            Err(e) => return Err(e).context(format!("cannot decode {}", path.display())),
        }
        while let Some(sweep) = stream.take_sweep() {
            on_sweep(sweep, stream)?;
        }
        Ok(())
    };
    let damage = loop {
        match source.next() {
            Ok(Some(p)) => {
                if !on_packet(p.receive_ns, &stream) {
                    break None;
                }
                let result = match p.kind {
                    PacketKind::Data => stream.push_data(p.payload, p.receive_ns),
                    PacketKind::Position => stream.push_position(p.payload),
                };
                handle(&mut stream, result)?;
            }
            Ok(None) => break None,
            Err(e) => break Some(e),
        }
    };
    let result = stream.finish();
    handle(&mut stream, result)?;
    Ok(CaptureReport {
        port_counts: source.port_counts(),
        capture: source.capture_stats(),
        stream,
        damage,
    })
}
