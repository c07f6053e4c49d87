//! The front-end stage: each closed sweep converted to the odometry's input, calibrated and
//! reduced to features, the stream's partial first sweep left out when a whole one follows.

use std::time::Instant;

use crossbeam_channel::{never, select, Receiver, Sender, TryRecvError};
use glint_core::config::OdometryConfig;
use glint_core::features::SweepFeatures;
use glint_core::front_end::FrontEnd;
use glint_core::scan::{Scan, ScanPoint};
use glint_driver::{Point, Sweep};

use super::health::{send_beating, Heartbeats, Stage, IDLE_BEAT};
use super::receive::{Arrival, Returns};
use super::sweeps::LabelledSweep;

/// What the front end hands the odometry.
pub(super) enum ToOdometry {
    /// Edges and planes of a sweep for the odometry to associate, deskewed to its first return
    /// (`sweep`, its time): those picked before its close while the rest streams in, and all
    /// of them with the closed sweep (the odometry skips those it has).
    Picked { sweep: u64, features: SweepFeatures },
    /// A closed sweep's features.
    Closed(Featured),
}

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

/// A driver return as the odometry takes it.
pub(super) fn scan_point(p: &Point) -> ScanPoint {
    ScanPoint {
        position: [p.x, p.y, p.z],
        time_ns: p.time_ns,
        reflectivity: p.reflectivity,
        ring: p.ring,
    }
}

/// Converts a driver sweep to the odometry's input, its points written into `out`; `None` for
/// an empty sweep. The reference time is the sweep's last return; the ring count is whatever
/// the sweep holds (16 for the VLP-16 family, 32 for the HDL-32E).
pub fn scan_of<'a>(sweep: &Sweep, out: &'a mut Vec<ScanPoint>) -> Option<Scan<'a>> {
    out.clear();
    out.extend(sweep.points.iter().map(scan_point));
    scan_over(out)
}

/// [`scan_of`] for the sweep that streamed in as `open`: the returns it converted already are
/// taken over (`open` gets `out`'s buffer back) and only the rest converted, unless they are
/// not the start of `sweep` (a gap in the stream).
fn scan_of_streamed<'a>(
    sweep: &Sweep,
    open: &mut OpenSweep,
    out: &'a mut Vec<ScanPoint>,
) -> Option<Scan<'a>> {
    let n = open.points.len();
    let continues = open.streaming == Some((sweep.index, n))
        && n > 0
        && sweep.points.len() >= n
        && open.points[0] == scan_point(&sweep.points[0])
        && open.points[n - 1] == scan_point(&sweep.points[n - 1]);
    if !continues {
        return scan_of(sweep, out);
    }
    std::mem::swap(out, &mut open.points);
    out.extend(sweep.points[n..].iter().map(scan_point));
    scan_over(out)
}

/// `points`, a sweep's returns in firing order, as the odometry's input.
fn scan_over(points: &[ScanPoint]) -> Option<Scan<'_>> {
    let reference_ns = points.last()?.time_ns;
    let rings = points
        .iter()
        .map(|p| usize::from(p.ring) + 1)
        .max()
        .unwrap_or(16);
    Some(Scan {
        points,
        rings,
        reference_ns,
    })
}

/// The front end's thread: features of each sweep, until the receive stage is gone. The open
/// sweep's returns are calibrated as they arrive, and each sector's features handed to the
/// odometry as soon as they are picked; at the close only the rest is left.
pub(super) fn run_front_end(
    config: &OdometryConfig,
    label_returns: bool,
    input: &Receiver<Arrival>,
    returns: &Receiver<Returns>,
    output: &Sender<ToOdometry>,
    heartbeats: &Heartbeats,
) {
    let mut front_end = FrontEnd::new(config);
    let mut points = Vec::new();
    let mut start = LeadingSweep::default();
    let mut open = OpenSweep::default();
    let mut returns = returns.clone();
    let mut process = |arrival: Arrival, open: &mut OpenSweep, front_end: &mut FrontEnd| {
        let begin = Instant::now();
        let index = arrival.sweep.index;
        let scan = scan_of_streamed(&arrival.sweep, open, &mut points);
        let stamp_offset_ns = arrival.sweep.stamp_offset_ns;
        if let Some(r) = &arrival.recycler {
            r.recycle(arrival.sweep);
        }
        let Some(scan) = scan else {
            return Ok(());
        };
        if !open.closes(index) {
            front_end.begin(scan.rings);
        }
        open.rings = scan.rings;
        let mut features = SweepFeatures::default();
        front_end.process(&scan, &mut features);
        // The rest of the sweep's edges and planes for the odometry to associate as it did
        // those handed out early (it skips those): the same whatever streamed in before.
        let mut rest = SweepFeatures::default();
        front_end.features_from_start(scan.points, &features, &mut rest);
        let rest = ToOdometry::Picked {
            sweep: scan.points[0].time_ns,
            features: rest,
        };
        send_beating(output, rest, heartbeats, Stage::FrontEnd)?;
        let front_end_ms = begin.elapsed().as_secs_f64() * 1e3;
        let returns = label_returns.then(|| LabelledSweep::of(&scan, front_end, &features));
        let message = Featured {
            features,
            stamp_offset_ns,
            received: arrival.received,
            front_end_ms,
            returns,
        };
        send_beating(
            output,
            ToOdometry::Closed(message),
            heartbeats,
            Stage::FrontEnd,
        )
    };
    let mut admit = |arrival: Arrival, open: &mut OpenSweep, front_end: &mut FrontEnd| {
        for a in start.admit(arrival).into_iter().flatten() {
            process(a, open, front_end)?;
        }
        Ok::<(), ()>(())
    };
    loop {
        heartbeats.beat(Stage::FrontEnd);
        // Closed sweeps first: one queued is older than any open sweep's returns.
        let arrival = match input.try_recv() {
            Ok(a) => Ok(a),
            Err(TryRecvError::Disconnected) => break,
            Err(TryRecvError::Empty) => select! {
                recv(input) -> a => match a {
                    Ok(a) => Ok(a),
                    Err(_) => break,
                },
                recv(returns) -> r => match r {
                    Ok(r) => Err(r),
                    Err(_) => {
                        returns = never();
                        continue;
                    }
                },
                default(IDLE_BEAT) => continue,
            },
        };
        let result = match arrival {
            Ok(a) => admit(a, &mut open, &mut front_end),
            Err(r) => {
                // A newer sweep's returns: the one before it is queued already (unless the
                // receive stage dropped it), and goes first.
                if open.is_newer(r.sweep) {
                    let mut result = Ok(());
                    while let (Ok(a), Ok(())) = (input.try_recv(), result) {
                        result = admit(a, &mut open, &mut front_end);
                    }
                    result
                } else {
                    Ok(())
                }
                .and_then(|()| open.stream(&r, &mut front_end, output, heartbeats))
            }
        };
        if result.is_err() {
            return;
        }
    }
    if let Some(a) = start.finish() {
        // A stream of nothing but partial sweeps (a capture shorter than two rotations).
        let _ = process(a, &mut open, &mut front_end);
    }
}

/// Hands the odometry the features of the open sweep picked since the last offer.
#[derive(Debug, Default)]
struct Picked {
    /// Sectors of the open sweep whose features went.
    sectors: usize,
}

impl Picked {
    /// Offers what the front end picked of the returns `streamed` so far.
    fn offer(
        &mut self,
        front_end: &mut FrontEnd,
        streamed: &[ScanPoint],
        output: &Sender<ToOdometry>,
        heartbeats: &Heartbeats,
    ) -> Result<(), ()> {
        let (Some(first), picked) = (streamed.first(), front_end.sectors_picked()) else {
            return Ok(());
        };
        if picked <= self.sectors {
            return Ok(());
        }
        self.sectors = picked;
        let mut features = SweepFeatures::default();
        front_end.early_features(streamed, &mut features);
        let message = ToOdometry::Picked {
            sweep: first.time_ns,
            features,
        };
        send_beating(output, message, heartbeats, Stage::FrontEnd)
    }
}

/// The front end's view of the sweep streaming in.
#[derive(Debug)]
struct OpenSweep {
    /// The sweep streamed into the front end, and how many of its returns.
    streaming: Option<(u64, usize)>,
    /// Its returns so far.
    points: Vec<ScanPoint>,
    picked: Picked,
    /// The last sweep processed.
    done: Option<u64>,
    /// The ring count of the last sweep processed: the next one's, for streaming.
    rings: usize,
}

impl Default for OpenSweep {
    fn default() -> Self {
        Self {
            streaming: None,
            points: Vec::new(),
            picked: Picked::default(),
            done: None,
            rings: 16,
        }
    }
}

impl OpenSweep {
    /// Returns of sweep `index` are of one not yet streamed nor processed.
    fn is_newer(&self, index: u64) -> bool {
        self.streaming.is_none_or(|(s, _)| index > s) && self.done.is_none_or(|d| index > d)
    }

    /// Streams returns into the front end if they continue what it holds or start a newer
    /// sweep, and offers the odometry what it picked; drops them otherwise (an old sweep's, or
    /// after a gap).
    fn stream(
        &mut self,
        r: &Returns,
        front_end: &mut FrontEnd,
        output: &Sender<ToOdometry>,
        heartbeats: &Heartbeats,
    ) -> Result<(), ()> {
        match self.streaming {
            Some((s, n)) if s == r.sweep => {
                if n != r.offset {
                    // A gap: the sweep is calibrated whole at its close.
                    self.streaming = None;
                    front_end.begin(self.rings);
                    return Ok(());
                }
            }
            _ if r.offset == 0 && self.is_newer(r.sweep) => {
                front_end.begin(self.rings);
                self.streaming = Some((r.sweep, 0));
                self.points.clear();
                self.picked = Picked::default();
            }
            _ => return Ok(()),
        }
        front_end.stream(&r.points);
        self.points.extend_from_slice(&r.points);
        if let Some((_, n)) = &mut self.streaming {
            *n += r.points.len();
        }
        self.picked
            .offer(front_end, &self.points, output, heartbeats)
    }

    /// Sweep `index` is being processed: whether it is the one streamed in.
    fn closes(&mut self, index: u64) -> bool {
        let streamed = self.streaming.take().is_some_and(|(s, _)| s == index);
        self.done = Some(self.done.map_or(index, |d| d.max(index)));
        streamed
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

    #[test]
    fn a_streamed_sweep_is_converted_only_past_what_streamed_in() {
        let sweep = Sweep {
            index: 3,
            points: (0..64)
                .map(|i| Point {
                    time_ns: 1_000 + i as u64 * 100,
                    x: 4.0,
                    y: i as f32 * 0.02,
                    z: 0.5,
                    reflectivity: 40,
                    ring: (i % 16) as u8,
                    ..Point::default()
                })
                .collect(),
            ..Sweep::default()
        };
        let mut whole = Vec::new();
        let expected = scan_of(&sweep, &mut whole).unwrap();
        let streamed = |index: u64, n: usize| OpenSweep {
            streaming: Some((index, n)),
            points: sweep.points[..n].iter().map(scan_point).collect(),
            ..OpenSweep::default()
        };
        // The first 40 streamed in: taken over, the other 24 converted.
        let mut open = streamed(3, 40);
        let mut out = Vec::new();
        let scan = scan_of_streamed(&sweep, &mut open, &mut out).unwrap();
        assert_eq!(scan.points, expected.points);
        assert_eq!((scan.rings, scan.reference_ns), (16, 1_000 + 63 * 100));
        assert!(open.points.is_empty(), "the buffers were swapped");
        // Another sweep's returns, or ones that are not this sweep's start: converted whole.
        for mut open in [streamed(2, 40), {
            let mut o = streamed(3, 40);
            o.points[39].position[0] += 1.0;
            o
        }] {
            let mut out = Vec::new();
            let scan = scan_of_streamed(&sweep, &mut open, &mut out).unwrap();
            assert_eq!(scan.points, expected.points);
        }
    }

    #[test]
    fn only_the_start_of_a_newer_sweep_streams_in() {
        let returns = |sweep: u64, offset: usize, n: usize| Returns {
            sweep,
            offset,
            points: (0..n)
                .map(|i| ScanPoint {
                    position: [5.0, i as f32 * 0.01, 0.0],
                    time_ns: (offset + i) as u64 * 1000,
                    reflectivity: 30,
                    ring: (i % 16) as u8,
                })
                .collect(),
        };
        let mut front_end = FrontEnd::new(&OdometryConfig::default());
        let mut open = OpenSweep::default();
        let (tx, _rx) = crossbeam_channel::unbounded();
        let heartbeats = Heartbeats::new(Instant::now(), false);

        // Sweep 5 from its start, in two batches, then closed: what was streamed is used.
        open.stream(&returns(5, 0, 32), &mut front_end, &tx, &heartbeats)
            .unwrap();
        open.stream(&returns(5, 32, 48), &mut front_end, &tx, &heartbeats)
            .unwrap();
        assert_eq!(front_end.streamed(), 80);
        assert!(open.closes(5));

        // A late batch of the sweep closed, an older sweep's, or a sweep joined midway: dropped.
        for (sweep, offset) in [(5, 80), (4, 0), (6, 16)] {
            open.stream(
                &returns(sweep, offset, 16),
                &mut front_end,
                &tx,
                &heartbeats,
            )
            .unwrap();
            assert_eq!(front_end.streamed(), 80, "sweep {sweep} from {offset}");
        }

        // Sweep 6 from its start, then a batch missed: the rest of it is not streamed, and it
        // is processed whole at its close.
        open.stream(&returns(6, 0, 32), &mut front_end, &tx, &heartbeats)
            .unwrap();
        assert_eq!(front_end.streamed(), 32);
        open.stream(&returns(6, 48, 16), &mut front_end, &tx, &heartbeats)
            .unwrap();
        open.stream(&returns(6, 64, 16), &mut front_end, &tx, &heartbeats)
            .unwrap();
        assert_eq!(front_end.streamed(), 0);
        assert!(!open.closes(6));

        // Sweep 7 closes while 8 streams in: 7 was not streamed, and 8's next batches are not
        // taken (it is processed whole).
        open.stream(&returns(8, 0, 16), &mut front_end, &tx, &heartbeats)
            .unwrap();
        assert!(!open.closes(7));
        open.stream(&returns(8, 16, 16), &mut front_end, &tx, &heartbeats)
            .unwrap();
        assert!(open.streaming.is_none());
        assert!(!open.closes(8));
    }
}
