//! [`Handle`]: what a C caller holds — one subscription (pose stream, status or sweeps) that
//! connects, reconnects and remembers the message of its last call. Entirely safe Rust; `lib.rs`
//! only turns pointers into references around it.
//!
//! Connection plan. A handle exists even when the daemon does not: opening fails with
//! `GLINT_ERR_NOT_RUNNING` and leaves a disconnected handle that tries again on each later call
//! (at most every [`RECONNECT_INTERVAL`]), so a controller may start before the daemon. Once
//! connected, the iceoryx2 ports outlive a daemon restart by themselves (the services live while
//! anyone holds them, and the restarted daemon re-opens them; see `ipc/README.md`), so a restart
//! shows as a pause and a drop in `sequence`, not as an error. A failure of the ports themselves
//! drops the connection, and the next call builds a new one.

use core::ffi::c_int;
use std::ffi::CString;
use std::time::{Duration, Instant};

use glint_ipc::{
    Domain, Pose, PoseStream, PoseSubscriber, ReceiveError, Status, StatusSubscriber,
    SubscribeError, WaitError,
};

use crate::error::{CapiError, GLINT_NO_DATA, GLINT_OK};

/// How often a disconnected handle tries to open the services. While disconnected there is no
/// event service to sleep on, so a wait polls at this pace; once connected it sleeps on events.
pub const RECONNECT_INTERVAL: Duration = Duration::from_millis(20);

/// One kind of subscription: what it opens. Implemented by the glint-ipc subscribers so that one
/// [`Handle`] (connection, reconnection, messages) serves every C handle type; how messages reach
/// the caller is the business of [`FixedSource`] or, for sweeps, of [`crate::sweep`].
pub trait Source: Sized {
    /// Which stream of the domain to open.
    type Stream: Copy;
    /// What the messages are called in messages to the user (`pose`, `status`, `sweep`).
    const NOUN: &'static str;

    /// Opens the services.
    fn open(domain: &Domain, stream: Self::Stream) -> Result<Self, SubscribeError>;
}

/// A source whose messages are one fixed-size struct, copied whole into the caller's struct
/// (poses, status). A sweep's size varies, so it is copied into a caller's buffer instead.
pub trait FixedSource: Source {
    /// The payload copied into the caller's struct.
    type Item: Copy;

    /// The oldest unread message, without blocking.
    fn try_next(&self) -> Result<Option<Self::Item>, ReceiveError>;
    /// The newest message, discarding older unread ones, without blocking.
    fn try_latest(&self) -> Result<Option<Self::Item>, ReceiveError>;
    /// The oldest unread message, sleeping on the event service up to `timeout`.
    fn wait_next(&self, timeout: Duration) -> Result<Option<Self::Item>, WaitError>;
    /// The publisher's sequence number of a message.
    fn sequence(item: &Self::Item) -> u64;
}

impl Source for PoseSubscriber {
    type Stream = PoseStream;
    const NOUN: &'static str = "pose";

    fn open(domain: &Domain, stream: PoseStream) -> Result<Self, SubscribeError> {
        PoseSubscriber::open(domain, stream)
    }
}

impl FixedSource for PoseSubscriber {
    type Item = Pose;

    fn try_next(&self) -> Result<Option<Pose>, ReceiveError> {
        PoseSubscriber::try_next(self)
    }
    fn try_latest(&self) -> Result<Option<Pose>, ReceiveError> {
        PoseSubscriber::try_latest(self)
    }
    fn wait_next(&self, timeout: Duration) -> Result<Option<Pose>, WaitError> {
        PoseSubscriber::wait_next(self, timeout)
    }
    fn sequence(item: &Pose) -> u64 {
        item.sequence
    }
}

impl Source for StatusSubscriber {
    type Stream = ();
    const NOUN: &'static str = "status";

    fn open(domain: &Domain, (): ()) -> Result<Self, SubscribeError> {
        StatusSubscriber::open(domain)
    }
}

impl FixedSource for StatusSubscriber {
    type Item = Status;

    fn try_next(&self) -> Result<Option<Status>, ReceiveError> {
        StatusSubscriber::try_next(self)
    }
    fn try_latest(&self) -> Result<Option<Status>, ReceiveError> {
        StatusSubscriber::try_latest(self)
    }
    fn wait_next(&self, timeout: Duration) -> Result<Option<Status>, WaitError> {
        StatusSubscriber::wait_next(self, timeout)
    }
    fn sequence(item: &Status) -> u64 {
        item.sequence
    }
}

/// What a receiving call produced, before it becomes a code.
#[derive(Debug)]
pub enum Received<T> {
    /// A message for the caller's struct.
    Message(T),
    /// Nothing unread (non-blocking calls).
    NoData,
    /// Nothing arrived within the timeout.
    Timeout,
}

/// Which services a handle subscribes to.
#[derive(Debug, Clone)]
struct Target<S: Source> {
    domain: Domain,
    stream: S::Stream,
    /// `glint/<domain>/<stream>`, for messages.
    service: String,
}

/// One C handle: the target, the connection if any, and the message of the last call.
pub struct Handle<S: Source> {
    /// `Err` when opened with invalid arguments: every call then fails with this message.
    target: Result<Target<S>, String>,
    port: Option<S>,
    next_attempt: Instant,
    /// Code and message of the last failed connection attempt, repeated until the next one.
    pending: Option<(c_int, String)>,
    /// Sequence and arrival of the last message handed out, for the timeout message.
    last: Option<(u64, Instant)>,
    message: CString,
}

impl<S: Source> Handle<S> {
    /// A handle for `stream` of `domain`, connected if the daemon is there. The error (if any)
    /// is also the handle's message; the handle stays usable and retries unless the arguments
    /// were invalid.
    pub fn open(
        domain: Result<Domain, CapiError>,
        stream: Result<S::Stream, CapiError>,
        stream_name: &str,
    ) -> (Self, Result<(), CapiError>) {
        let target = domain.and_then(|domain| {
            Ok(Target {
                service: format!("glint/{domain}/{stream_name}"),
                stream: stream?,
                domain,
            })
        });
        let (target, result) = match target {
            Ok(t) => (Ok(t), Ok(())),
            Err(e) => (Err(e.message()), Err(e)),
        };
        let mut handle = Self {
            target,
            port: None,
            next_attempt: Instant::now(),
            pending: None,
            last: None,
            message: CString::default(),
        };
        let result = result.and_then(|()| handle.connect().map(|_| ()));
        handle.record(result.as_ref().map(|()| GLINT_OK));
        (handle, result)
    }

    /// The message of the last call: empty after `GLINT_OK`.
    pub fn message(&self) -> &CString {
        &self.message
    }

    /// Remembers how the last call ended: its message for C, and a dropped connection after a
    /// port failure so the next call reconnects.
    pub fn record(&mut self, result: Result<c_int, &CapiError>) {
        if matches!(result, Ok(GLINT_OK)) && self.message.is_empty() {
            // The steady state of a controller's loop: nothing to change, nothing to allocate.
            return;
        }
        let text = match result {
            Ok(GLINT_OK) => String::new(),
            Ok(GLINT_NO_DATA) => format!("no unread {} on {}", S::NOUN, self.service()),
            Ok(_) => self.timeout_message(),
            Err(e) => {
                if e.drops_connection() {
                    self.port = None;
                }
                e.message()
            }
        };
        // Interior NULs cannot occur in our messages; should one ever, truncate rather than lose
        // the whole message.
        let bytes: Vec<u8> = text
            .into_bytes()
            .into_iter()
            .take_while(|b| *b != 0)
            .collect();
        self.message = CString::new(bytes).unwrap_or_default();
    }

    /// While disconnected within a wait: sleeps until the next connection attempt is due, or
    /// hands `e` back once `deadline` has passed or when retrying cannot help.
    pub(crate) fn await_reconnect(&self, e: CapiError, deadline: Instant) -> Result<(), CapiError> {
        let now = Instant::now();
        if !self.is_retryable(&e) || now >= deadline {
            return Err(e);
        }
        std::thread::sleep(self.next_attempt.min(deadline) - now);
        Ok(())
    }

    fn is_retryable(&self, e: &CapiError) -> bool {
        self.target.is_ok() && matches!(e, CapiError::Subscribe(_) | CapiError::Disconnected { .. })
    }

    /// Notes a message handed to the caller, for the timeout message.
    pub(crate) fn delivered(&mut self, sequence: u64) {
        self.last = Some((sequence, Instant::now()));
    }

    /// The connection, made now if there is none and the last attempt is old enough; a retry
    /// that comes too soon repeats the last attempt's reason instead of creating another node.
    pub(crate) fn connect(&mut self) -> Result<&S, CapiError> {
        let target = self
            .target
            .as_ref()
            .map_err(|m| CapiError::Unusable(m.clone()))?;
        let port = match self.port.take() {
            Some(port) => port,
            None => {
                let now = Instant::now();
                if let (true, Some((code, reason))) = (now < self.next_attempt, &self.pending) {
                    return Err(CapiError::Disconnected {
                        code: *code,
                        reason: reason.clone(),
                    });
                }
                self.next_attempt = now + RECONNECT_INTERVAL;
                match S::open(&target.domain, target.stream) {
                    Ok(port) => {
                        self.pending = None;
                        port
                    }
                    Err(e) => {
                        let e = CapiError::from(e);
                        self.pending = Some((e.code(), e.message()));
                        return Err(e);
                    }
                }
            }
        };
        Ok(self.port.insert(port))
    }

    fn service(&self) -> &str {
        match &self.target {
            Ok(t) => &t.service,
            Err(_) => "(no service)",
        }
    }

    fn timeout_message(&self) -> String {
        let mut text = format!("no {} on {} before the timeout", S::NOUN, self.service());
        match (&self.port, self.last) {
            (None, _) => text.push_str(" (not connected)"),
            (Some(_), Some((sequence, at))) => text.push_str(&format!(
                "; the last (sequence {sequence}) arrived {:.3} s ago: is glintd still running?",
                at.elapsed().as_secs_f64()
            )),
            (Some(_), None) => text.push_str("; none received yet"),
        }
        text
    }
}

impl<S: FixedSource> Handle<S> {
    /// The oldest unread message, without blocking.
    pub fn take(&mut self) -> Result<Received<S::Item>, CapiError> {
        let item = self.connect()?.try_next()?;
        Ok(self.hand_out(item, Received::NoData))
    }

    /// The newest message, discarding older unread ones, without blocking.
    pub fn take_latest(&mut self) -> Result<Received<S::Item>, CapiError> {
        let item = self.connect()?.try_latest()?;
        Ok(self.hand_out(item, Received::NoData))
    }

    /// The oldest unread message, sleeping until one arrives or `timeout` passes. Connected, it
    /// sleeps on the event service the daemon notifies; disconnected, it retries the connection
    /// every [`RECONNECT_INTERVAL`] and then waits on events for the rest of the time.
    pub fn wait(&mut self, timeout: Duration) -> Result<Received<S::Item>, CapiError> {
        let deadline = Instant::now() + timeout;
        loop {
            // Connect first and borrow the port afterwards, so that the retry branch may use
            // `self` again.
            let connected = self.connect().map(|_| ());
            match connected {
                Ok(()) => {
                    let remaining = deadline.saturating_duration_since(Instant::now());
                    let item = self.connect()?.wait_next(remaining)?;
                    return Ok(self.hand_out(item, Received::Timeout));
                }
                Err(e) => self.await_reconnect(e, deadline)?,
            }
        }
    }

    fn hand_out(&mut self, item: Option<S::Item>, none: Received<S::Item>) -> Received<S::Item> {
        match item {
            Some(item) => {
                self.delivered(S::sequence(&item));
                Received::Message(item)
            }
            None => none,
        }
    }
}
