//! Sweeps for C: a [`Handle`] on the `sweep` service that copies each sweep into the caller's
//! header and point buffer. Safe Rust; the buffers are raw pointers only behind
//! [`SweepBuffer`], which `lib.rs` implements.
//!
//! A sweep has as many points as the sensor returned, so it cannot be one fixed struct like a
//! pose: the caller passes a buffer and its capacity. A sweep larger than the buffer is consumed
//! anyway, with its header written and its points not: holding it back instead would stall a
//! caller whose buffer never grows on that sweep forever, and the header tells the caller what
//! size to allocate. The service has no event service, so a wait polls ([`POLL_INTERVAL`]).

use std::time::{Duration, Instant};

use glint_ipc::{Domain, SubscribeError, SweepHeader, SweepPoint, SweepSubscriber};

use crate::error::CapiError;
use crate::handle::{Handle, Received, Source};

/// How often a waiting sweep handle looks for a new sweep: at most 5 ms added to a sweep that
/// comes every 50–100 ms, for 200 non-blocking checks a second while waiting. Mirrored as
/// `GLINT_SWEEP_POLL_INTERVAL_MS` in glint.h.
pub const POLL_INTERVAL: Duration = Duration::from_millis(5);

impl Source for SweepSubscriber {
    type Stream = ();
    const NOUN: &'static str = "sweep";

    fn open(domain: &Domain, (): ()) -> Result<Self, SubscribeError> {
        SweepSubscriber::open(domain)
    }
}

/// Where a sweep is copied: the caller's header and room for [`capacity`](Self::capacity)
/// points.
pub trait SweepBuffer {
    /// How many points fit.
    fn capacity(&self) -> usize;
    /// Writes `header` and copies `points` (never more than [`capacity`](Self::capacity)) to
    /// the start of the point buffer, leaving the rest as it was.
    fn fill(&mut self, header: &SweepHeader, points: &[SweepPoint]);
}

impl Handle<SweepSubscriber> {
    /// Copies the oldest unread sweep into `out`, without blocking. A sweep larger than `out`
    /// is consumed: its header is written, its points are not, and the result is
    /// [`CapiError::BufferTooSmall`].
    pub fn take_into(&mut self, out: &mut impl SweepBuffer) -> Result<Received<()>, CapiError> {
        let capacity = out.capacity();
        let taken = self.connect()?.try_next(|header, points| {
            // A C caller bounds its loop over the points with `point_count`: make it the number
            // of points there are, whatever a foreign publisher wrote.
            let header = SweepHeader {
                point_count: u32::try_from(points.len()).unwrap_or(u32::MAX),
                ..*header
            };
            let fits = points.len() <= capacity;
            out.fill(&header, if fits { points } else { &[] });
            (header.sequence, points.len())
        })?;
        let Some((sequence, needed)) = taken else {
            return Ok(Received::NoData);
        };
        self.delivered(sequence);
        if needed > capacity {
            return Err(CapiError::BufferTooSmall {
                sequence,
                needed,
                capacity,
            });
        }
        Ok(Received::Message(()))
    }

    /// Copies the oldest unread sweep into `out`, looking every [`POLL_INTERVAL`] until one
    /// arrives or `timeout` passes; disconnected, it retries the connection every
    /// [`RECONNECT_INTERVAL`](crate::handle::RECONNECT_INTERVAL) within the timeout.
    pub fn wait_into(
        &mut self,
        timeout: Duration,
        out: &mut impl SweepBuffer,
    ) -> Result<Received<()>, CapiError> {
        let deadline = Instant::now() + timeout;
        loop {
            match self.take_into(out) {
                Ok(Received::NoData) => {
                    let now = Instant::now();
                    if now >= deadline {
                        return Ok(Received::Timeout);
                    }
                    std::thread::sleep(POLL_INTERVAL.min(deadline - now));
                }
                Err(e) => self.await_reconnect(e, deadline)?,
                done => return done,
            }
        }
    }
}
