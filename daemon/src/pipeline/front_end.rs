//! The front-end stage: each closed sweep converted to the odometry's input, calibrated and
//! reduced to features, the stream's partial first sweep left out when a whole one follows.

use std::time::Instant;

use crossbeam_channel::{Receiver, Sender};
use glint_core::config::OdometryConfig;
use glint_core::features::SweepFeatures;
use glint_core::front_end::FrontEnd;
use glint_core::scan::{Scan, ScanPoint};
use glint_driver::Sweep;

use super::health::{recv_beating, send_beating, Heartbeats, Stage};
use super::receive::Arrival;
use super::sweeps::LabelledSweep;

/// A sweep's features on their way to the odometry.
pub(super) struct Featured {
    pub(super) features: SweepFeatures,
    /// What turns the sweep's sensor times into stamps (`Sweep::stamp_offset_ns`).
    pub(super) stamp_offset_ns: i64,
    pub(super) received: Instant,
    /// Time spent in the front end, ms.
    pub(super) front_end_ms: f64,
    /// Every return, labelled, when the `sweep` service is on.
    pub(super) returns: Option<LabelledSweep>,
}

/// Converts a driver sweep to the odometry's input, its points written into `out`; `None` for
/// an empty sweep. The reference time is the sweep's last return; the ring count is whatever
/// the sweep holds (16 for the VLP-16 family, 32 for the HDL-32E).
pub fn scan_of<'a>(sweep: &Sweep, out: &'a mut Vec<ScanPoint>) -> Option<Scan<'a>> {
    let reference_ns = sweep.points.last()?.time_ns;
    out.clear();
    out.extend(sweep.points.iter().map(|p| ScanPoint {
        position: [p.x, p.y, p.z],
        time_ns: p.time_ns,
        reflectivity: p.reflectivity,
        ring: p.ring,
    }));
    let rings = out
        .iter()
        .map(|p| usize::from(p.ring) + 1)
        .max()
        .unwrap_or(16);
    Some(Scan {
        points: out,
        rings,
        reference_ns,
    })
}

/// The front end's thread: features of each sweep, until the receive stage is gone.
pub(super) fn run_front_end(
    config: &OdometryConfig,
    label_returns: bool,
    input: &Receiver<Arrival>,
    output: &Sender<Featured>,
    heartbeats: &Heartbeats,
) {
    let mut front_end = FrontEnd::new(config);
    let mut points = Vec::new();
    let mut start = LeadingSweep::default();
    let mut process = |arrival: Arrival| -> Result<(), ()> {
        let begin = Instant::now();
        let scan = scan_of(&arrival.sweep, &mut points);
        let stamp_offset_ns = arrival.sweep.stamp_offset_ns;
        if let Some(r) = &arrival.recycler {
            r.recycle(arrival.sweep);
        }
        let Some(scan) = scan else {
            return Ok(());
        };
        let mut features = SweepFeatures::default();
        front_end.process(&scan, &mut features);
        let front_end_ms = begin.elapsed().as_secs_f64() * 1e3;
        let returns = label_returns.then(|| LabelledSweep::of(&scan, &front_end, &features));
        let message = Featured {
            features,
            stamp_offset_ns,
            received: arrival.received,
            front_end_ms,
            returns,
        };
        send_beating(output, message, heartbeats, Stage::FrontEnd)
    };
    while let Some(arrival) = recv_beating(input, heartbeats, Stage::FrontEnd) {
        for a in start.admit(arrival).into_iter().flatten() {
            if process(a).is_err() {
                return;
            }
        }
    }
    if let Some(a) = start.finish() {
        // A stream of nothing but partial sweeps (a capture shorter than two rotations).
        let _ = process(a);
    }
}

/// Keeps a stream's partial first sweep out of the odometry when a whole one follows. The
/// sensor is mid-rotation when a capture or the daemon starts, so the first sweep may hold a
/// few degrees of the scene; the odometry would build its first map from that sliver, and with
/// the robot already moving (a restart while driving) the next sweeps would match too little of
/// it to see the motion (a simulated yard, seed 41: 85 plane matches, the first 0.35 m lost).
#[derive(Default)]
struct LeadingSweep {
    held: Option<Arrival>,
    decided: bool,
}

impl LeadingSweep {
    /// The sweeps to process now, in order.
    fn admit(&mut self, arrival: Arrival) -> [Option<Arrival>; 2] {
        if self.decided {
            return [Some(arrival), None];
        }
        match (self.held.take(), arrival.sweep.partial) {
            (None, true) => {
                self.held = Some(arrival);
                [None, None]
            }
            (Some(first), false) => {
                self.decided = true;
                tracing::info!(
                    returns = first.sweep.points.len(),
                    "the stream's first sweep covers part of a rotation: the odometry starts from the next"
                );
                if let Some(r) = &first.recycler {
                    r.recycle(first.sweep);
                }
                [Some(arrival), None]
            }
            (held, _) => {
                self.decided = true;
                [held, Some(arrival)]
            }
        }
    }

    /// A sweep still held at the end of the stream.
    fn finish(&mut self) -> Option<Arrival> {
        self.held.take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_partial_first_sweep_is_left_out_when_a_whole_one_follows() {
        let arrival = |index: u64, partial: bool| Arrival {
            sweep: Sweep {
                index,
                partial,
                ..Sweep::default()
            },
            recycler: None,
            received: Instant::now(),
        };
        let indices = |v: [Option<Arrival>; 2]| {
            v.iter()
                .flatten()
                .map(|a| a.sweep.index)
                .collect::<Vec<_>>()
        };

        // A capture started mid-rotation: its sliver is dropped, the rest pass, partial or not.
        let mut start = LeadingSweep::default();
        assert!(indices(start.admit(arrival(0, true))).is_empty());
        assert_eq!(indices(start.admit(arrival(1, false))), [1]);
        assert_eq!(indices(start.admit(arrival(2, false))), [2]);
        assert_eq!(indices(start.admit(arrival(3, true))), [3]);
        assert!(start.finish().is_none());

        // Started at the cut: nothing held.
        let mut start = LeadingSweep::default();
        assert_eq!(indices(start.admit(arrival(0, false))), [0]);
        assert!(start.finish().is_none());

        // Nothing but partial sweeps (a capture of about one rotation): all of them.
        let mut start = LeadingSweep::default();
        assert!(indices(start.admit(arrival(0, true))).is_empty());
        assert_eq!(indices(start.admit(arrival(1, true))), [0, 1]);
        let mut start = LeadingSweep::default();
        assert!(indices(start.admit(arrival(0, true))).is_empty());
        assert_eq!(start.finish().map(|a| a.sweep.index), Some(0));
    }
}
