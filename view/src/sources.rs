//! The daemon's services this viewer reads, opened when the daemon publishes them and opened
//! again when a port fails (the daemon restarted): the viewer may start first and outlive it.

use std::time::{Duration, Instant};

use glint_ipc::{
    Domain, MapUpdateSubscriber, PoseStream, PoseSubscriber, StatusSubscriber, SweepSubscriber,
};

use crate::scene::Scene;

/// How often a service that is not there yet is looked for again: a sweep at 10 Hz.
const RETRY: Duration = Duration::from_millis(100);
/// At most this many messages of one stream per poll, so one busy stream cannot starve others.
const BATCH: usize = 64;

/// One service, open or waiting to be.
struct Port<T> {
    port: Option<T>,
    next_try: Instant,
}

impl<T> Port<T> {
    fn new() -> Self {
        Self {
            port: None,
            next_try: Instant::now(),
        }
    }

    /// The open port, opening it with `open` if it is due.
    fn get(&mut self, open: impl FnOnce() -> Option<T>) -> Option<&T> {
        if self.port.is_none() && Instant::now() >= self.next_try {
            self.port = open();
            self.next_try = Instant::now() + RETRY;
        }
        self.port.as_ref()
    }

    /// Reads up to `limit` messages with `next` and hands each to `on`, opening the port first
    /// if it is due; a failed read closes the port, to be opened again later. Returns how many
    /// messages were read.
    fn drain<M, E>(
        &mut self,
        open: impl FnOnce() -> Option<T>,
        limit: usize,
        mut next: impl FnMut(&T) -> Result<Option<M>, E>,
        mut on: impl FnMut(M),
    ) -> usize {
        let Some(port) = self.get(open) else {
            return 0;
        };
        let mut read = 0;
        while read < limit {
            match next(port) {
                Ok(Some(message)) => {
                    on(message);
                    read += 1;
                }
                Ok(None) => break,
                Err(_) => {
                    self.port = None;
                    self.next_try = Instant::now() + RETRY;
                    break;
                }
            }
        }
        read
    }
}

/// The ports of one domain.
pub struct Sources {
    domain: Domain,
    odom: Port<PoseSubscriber>,
    map: Port<PoseSubscriber>,
    status: Port<StatusSubscriber>,
    sweep: Port<SweepSubscriber>,
    map_update: Port<MapUpdateSubscriber>,
}

impl Sources {
    pub fn new(domain: Domain) -> Self {
        Self {
            domain,
            odom: Port::new(),
            map: Port::new(),
            status: Port::new(),
            sweep: Port::new(),
            map_update: Port::new(),
        }
    }

    /// Hands everything that arrived since the last poll to `scene`; returns how many messages.
    pub fn poll(&mut self, scene: &mut Scene) -> usize {
        let domain = &self.domain;
        let mut received = 0;
        for (port, stream) in [
            (&mut self.odom, PoseStream::Odom),
            (&mut self.map, PoseStream::Map),
        ] {
            received += port.drain(
                || PoseSubscriber::open(domain, stream).ok(),
                BATCH,
                PoseSubscriber::try_next,
                |pose| scene.on_pose(stream, &pose),
            );
        }
        received += self.status.drain(
            || StatusSubscriber::open(domain).ok(),
            BATCH,
            StatusSubscriber::try_next,
            |status| scene.on_status(&status),
        );
        // Sweeps after poses, so the pose of a sweep's instant has usually arrived; all of them
        // (the service buffers two per subscriber).
        received += self.sweep.drain(
            || SweepSubscriber::open(domain).ok(),
            usize::MAX,
            |sub| sub.try_next(|header, points| scene.on_sweep(header, points)),
            |()| {},
        );
        // All of them: a new subscriber is sent the whole map, paced for a reader that polls
        // every 100 ms.
        received += self.map_update.drain(
            || MapUpdateSubscriber::open(domain).ok(),
            usize::MAX,
            MapUpdateSubscriber::try_next,
            |update| scene.on_map_update(update),
        );
        received
    }
}
