//! A simulated VLP-16 as a payload source: the packets `glintd sim` would write to a capture,
//! generated one at a time and handed straight to the pipeline, so a run of any length (a
//! soak of hours of sensor time) needs neither a capture file nor the memory for one.

use std::net::Ipv4Addr;

use anyhow::{Context, Result};
use glint_driver::pcap::{CaptureError, CaptureStats};
use glint_driver::{PacketKind, SensorPayload};
use glint_sim::{SimConfig, Simulation};

use crate::capture::PayloadSource;

/// A simulation's packets, sent from the sensor's factory address.
pub struct SimulatedSensor {
    simulation: Simulation,
    address: Ipv4Addr,
    data: u64,
    position: u64,
}

impl SimulatedSensor {
    /// Builds the scene and the motion of `config`; packets are generated as they are read.
    pub fn new(config: &SimConfig) -> Result<SimulatedSensor> {
        let simulation = Simulation::new(config).context("cannot start the simulated sensor")?;
        Ok(SimulatedSensor {
            simulation,
            address: glint_sim::output::SENSOR_ADDRESS,
            data: 0,
            position: 0,
        })
    }
}

impl PayloadSource for SimulatedSensor {
    fn next_payload(&mut self) -> Result<Option<SensorPayload<'_>>, CaptureError> {
        let Some(packet) = self.simulation.next_packet() else {
            return Ok(None);
        };
        let kind = match packet.kind {
            glint_sim::PacketKind::Data => {
                self.data += 1;
                PacketKind::Data
            }
            glint_sim::PacketKind::Position => {
                self.position += 1;
                PacketKind::Position
            }
        };
        Ok(Some(SensorPayload {
            kind,
            source: self.address,
            payload: packet.payload,
            receive_ns: packet.time_ns,
        }))
    }

    fn port_counts(&self) -> (u64, u64, u64) {
        (self.data, self.position, 0)
    }

    fn capture_stats(&self) -> CaptureStats {
        CaptureStats::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::replay_payloads;
    use glint_driver::StreamConfig;
    use glint_sim::Scenario;

    /// The in-process sensor gives the same sweeps as its capture file replayed.
    #[test]
    fn sweeps_match_the_written_capture() {
        let config = SimConfig {
            scenario: Scenario::Corridor,
            seed: 11,
            seconds: 1.2,
            ..SimConfig::default()
        };
        let dir = std::env::temp_dir().join(format!("glint-simulated-{}", std::process::id()));
        glint_sim::simulate_to_dir(&config, &dir).unwrap();
        let mut from_file = Vec::new();
        crate::capture::replay_stream(
            &dir.join("scan.pcap"),
            glint_driver::Ports::default(),
            StreamConfig::default(),
            None,
            |_, _, _| true,
            |sweep, _| {
                from_file.push((sweep.end_ns, sweep.points.len()));
                Ok(())
            },
        )
        .unwrap();
        let mut in_process = Vec::new();
        let report = replay_payloads(
            &mut SimulatedSensor::new(&config).unwrap(),
            "simulation",
            StreamConfig::default(),
            None,
            |_, _, _| true,
            |sweep, _| {
                in_process.push((sweep.end_ns, sweep.points.len()));
                Ok(())
            },
        )
        .unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(from_file.len() >= 10, "{} sweeps", from_file.len());
        assert_eq!(in_process, from_file);
        assert!(report.port_counts.0 > 0 && report.port_counts.1 > 0);
    }
}
