//! The stages' liveness: each beats its heartbeat while it works or idles, so the systemd
//! watchdog is fed only while every running stage shows progress, and a stuck one gets the
//! daemon restarted. The channel helpers here keep a stage beating while it waits on a
//! neighbour, so a slow stage is not taken for a stuck one.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, SendTimeoutError, Sender};

/// How long an idle stage waits before beating its heartbeat again.
pub(super) const IDLE_BEAT: Duration = Duration::from_millis(200);

/// A pipeline stage with a heartbeat.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Stage {
    Receive,
    FrontEnd,
    Odometry,
    /// The back end or, localising, the localiser in its place.
    BackEnd,
}

impl Stage {
    const COUNT: usize = 4;
    const ALL: [Stage; Self::COUNT] = [
        Stage::Receive,
        Stage::FrontEnd,
        Stage::Odometry,
        Stage::BackEnd,
    ];
}

/// Liveness of the stages: the time (ms since the run started) each last showed progress.
pub(super) struct Heartbeats {
    start: Instant,
    /// Indexed by `Stage`.
    beats: [AtomicU64; Stage::COUNT],
    /// Which stages run (the back end is optional), indexed by `Stage`.
    active: [bool; Stage::COUNT],
}

impl Heartbeats {
    /// A stage silent for longer than this is stuck.
    const STALE: Duration = Duration::from_secs(3);

    /// Every stage counted alive at `start`; the back end watched only when it runs.
    pub(super) fn new(start: Instant, back_end_runs: bool) -> Self {
        Self {
            start,
            beats: Default::default(),
            active: Stage::ALL.map(|stage| stage != Stage::BackEnd || back_end_runs),
        }
    }

    pub(super) fn beat(&self, stage: Stage) {
        self.beats[stage as usize]
            .store(self.start.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    pub(super) fn all_alive(&self) -> bool {
        let now = self.start.elapsed().as_millis() as u64;
        self.beats.iter().zip(self.active).all(|(b, active)| {
            !active
                || now.saturating_sub(b.load(Ordering::Relaxed)) < Self::STALE.as_millis() as u64
        })
    }
}

/// Receives, beating `stage`'s heartbeat while idle; None once the sender is gone.
pub(super) fn recv_beating<T>(
    input: &Receiver<T>,
    heartbeats: &Heartbeats,
    stage: Stage,
) -> Option<T> {
    loop {
        heartbeats.beat(stage);
        match input.recv_timeout(IDLE_BEAT) {
            Ok(message) => return Some(message),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => return None,
        }
    }
}

/// Sends, beating `stage`'s heartbeat while the next stage is busy.
pub(super) fn send_beating<T>(
    out: &Sender<T>,
    mut message: T,
    heartbeats: &Heartbeats,
    stage: Stage,
) -> Result<(), ()> {
    loop {
        match out.send_timeout(message, IDLE_BEAT) {
            Ok(()) => return Ok(()),
            Err(SendTimeoutError::Timeout(m)) => {
                heartbeats.beat(stage);
                message = m;
            }
            Err(SendTimeoutError::Disconnected(_)) => return Err(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stage_that_does_not_run_is_never_stale() {
        let long_ago = Instant::now() - 2 * Heartbeats::STALE;
        let heartbeats = Heartbeats::new(long_ago, false);
        for stage in [Stage::Receive, Stage::FrontEnd, Stage::Odometry] {
            assert!(!heartbeats.all_alive());
            heartbeats.beat(stage);
        }
        assert!(heartbeats.all_alive());

        let heartbeats = Heartbeats::new(long_ago, true);
        for stage in [Stage::Receive, Stage::FrontEnd, Stage::Odometry] {
            heartbeats.beat(stage);
        }
        assert!(!heartbeats.all_alive());
        heartbeats.beat(Stage::BackEnd);
        assert!(heartbeats.all_alive());
    }
}
