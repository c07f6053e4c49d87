//! [`Forwarder`]: one stream of the fleet link (odom, map or status). Poses are state, not a log:
//! while nobody on the link listens (the link is down, the fleet server restarts) or the
//! stream's rate limit has not yet passed, the forwarder keeps only the latest payload, counts
//! the ones it replaced, and sends the latest as soon as it may. Its memory is one payload
//! whatever the outage's length, and `offer` never waits for the network: Zenoh's congestion
//! control is `Drop`, so a full send queue costs a message, never the caller's time.

use std::time::{Duration, Instant};

use zenoh::pubsub::Publisher;
use zenoh::qos::{CongestionControl, Priority};
use zenoh::{Session, Wait};

use crate::keys::PayloadType;

/// What a [`Forwarder`] did with the payloads it was offered.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct ForwardCounts {
    /// Payloads handed to Zenoh.
    pub sent: u64,
    /// Payloads replaced by a newer one before they could be sent because nobody listened.
    pub dropped_unheard: u64,
    /// Payloads replaced by a newer one within the stream's rate limit.
    pub dropped_rate: u64,
    /// Sends Zenoh refused (the session closing); the payload was dropped.
    pub failed: u64,
}

/// One stream's publisher with its latest-only slot and rate limit.
pub struct Forwarder {
    publisher: Publisher<'static>,
    attachment: &'static str,
    min_interval: Duration,
    pending: Option<Vec<u8>>,
    pending_unheard: bool,
    last_sent: Option<Instant>,
    counts: ForwardCounts,
}

impl Forwarder {
    /// Declares the publisher of `key`. `max_rate_hz` of 0 (or less, or not finite) forwards
    /// every payload; otherwise at most that many per second, always the latest.
    pub fn declare(
        session: &Session,
        key: String,
        payload: PayloadType,
        max_rate_hz: f64,
    ) -> Result<Self, zenoh::Error> {
        // Poses are sent ahead of bulk data on a shared link; status is a low-rate summary.
        let priority = match payload {
            PayloadType::Pose => Priority::InteractiveHigh,
            PayloadType::Status => Priority::Data,
        };
        let publisher = session
            .declare_publisher(key)
            .congestion_control(CongestionControl::Drop)
            .priority(priority)
            .express(true)
            .wait()?;
        let min_interval = if max_rate_hz.is_finite() && max_rate_hz > 0.0 {
            Duration::from_secs_f64(1.0 / max_rate_hz)
        } else {
            Duration::ZERO
        };
        Ok(Self {
            publisher,
            attachment: payload.attachment(),
            min_interval,
            pending: None,
            pending_unheard: false,
            last_sent: None,
            counts: ForwardCounts::default(),
        })
    }

    /// The key the stream publishes on.
    pub fn key(&self) -> &str {
        self.publisher.key_expr().as_str()
    }

    /// Makes `payload` the stream's latest and sends it if the link and the rate limit allow.
    pub fn offer(&mut self, payload: Vec<u8>, now: Instant) {
        if self.pending.is_some() {
            if self.pending_unheard {
                self.counts.dropped_unheard += 1;
            } else {
                self.counts.dropped_rate += 1;
            }
        }
        self.pending = Some(payload);
        self.flush(now);
    }

    /// Sends the kept payload if there is one and it may go now. Call it when nothing new
    /// arrives, so the latest goes out once the link returns or the rate limit passes.
    pub fn flush(&mut self, now: Instant) {
        if self.pending.is_none() {
            return;
        }
        if self
            .last_sent
            .is_some_and(|t| now.saturating_duration_since(t) < self.min_interval)
        {
            self.pending_unheard = false;
            return;
        }
        // No matching subscriber anywhere reachable: the link is down or nobody listens.
        let heard = self
            .publisher
            .matching_status()
            .wait()
            .is_ok_and(|s| s.matching());
        if !heard {
            self.pending_unheard = true;
            return;
        }
        let Some(payload) = self.pending.take() else {
            return;
        };
        match self
            .publisher
            .put(payload)
            .attachment(self.attachment)
            .wait()
        {
            Ok(()) => self.counts.sent += 1,
            Err(_) => self.counts.failed += 1,
        }
        self.last_sent = Some(now);
    }

    /// Whether a payload waits to be sent.
    pub fn has_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// What the forwarder did so far.
    pub fn counts(&self) -> ForwardCounts {
        self.counts
    }
}
