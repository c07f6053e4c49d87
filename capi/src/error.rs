//! The result codes of the C interface and [`CapiError`], the one error type behind them.
//!
//! C sees an `int` per call and a message per handle; Rust keeps the cause as a typed error until
//! the last moment, so the message carries the whole chain (`cannot open service …: iceoryx2's
//! reason`) and the code is derived from the variant in one place ([`CapiError::code`]). The
//! numeric values are part of the ABI and mirrored in `include/glint.h`; `tests/header.rs`
//! compiles the header and compares them.

use core::ffi::{c_int, CStr};
use std::error::Error as _;

use glint_ipc::iceoryx2::port::listener::ListenerWaitError;
use glint_ipc::iceoryx2::service::builder::event::EventOpenError;
use glint_ipc::iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;
use glint_ipc::{
    DomainError, InitialPoseOpenError, InitialPoseSendError, ReceiveError, SendInitialPoseError,
    SubscribeError, WaitError,
};
use thiserror::Error;

/// Success: the caller's struct holds a new message.
pub const GLINT_OK: c_int = 0;
/// Not an error: no unread message (non-blocking take); the caller's struct is untouched.
pub const GLINT_NO_DATA: c_int = 1;
/// Not an error: the wait ended without a message; the caller's struct is untouched.
pub const GLINT_TIMEOUT: c_int = 2;
/// A null pointer, an invalid domain, an unknown stream name, or a sweep buffer too small for the
/// sweep; retrying the same call cannot help.
pub const GLINT_ERR_INVALID_ARGUMENT: c_int = -1;
/// The service does not exist: the daemon is not running, runs with another domain or another
/// iceoryx2 root. The handle retries on its next call.
pub const GLINT_ERR_NOT_RUNNING: c_int = -2;
/// The service exists but is not Glint's contract as this library knows it (another payload
/// version, or settings from a publisher that is not glintd). The handle retries.
pub const GLINT_ERR_INCOMPATIBLE: c_int = -3;
/// Any other iceoryx2 failure (permissions, shared memory, ports); the handle drops its
/// connection and retries on its next call.
pub const GLINT_ERR_IPC: c_int = -4;
/// A signal interrupted the wait; call again.
pub const GLINT_ERR_INTERRUPTED: c_int = -5;
/// A bug inside the library was caught at the boundary instead of unwinding into C.
pub const GLINT_ERR_INTERNAL: c_int = -6;

/// Every code with its name, in header order; [`code_name`] and the header test walk it.
pub const CODES: [(c_int, &CStr); 9] = [
    (GLINT_OK, c"GLINT_OK"),
    (GLINT_NO_DATA, c"GLINT_NO_DATA"),
    (GLINT_TIMEOUT, c"GLINT_TIMEOUT"),
    (GLINT_ERR_INVALID_ARGUMENT, c"GLINT_ERR_INVALID_ARGUMENT"),
    (GLINT_ERR_NOT_RUNNING, c"GLINT_ERR_NOT_RUNNING"),
    (GLINT_ERR_INCOMPATIBLE, c"GLINT_ERR_INCOMPATIBLE"),
    (GLINT_ERR_IPC, c"GLINT_ERR_IPC"),
    (GLINT_ERR_INTERRUPTED, c"GLINT_ERR_INTERRUPTED"),
    (GLINT_ERR_INTERNAL, c"GLINT_ERR_INTERNAL"),
];

/// The name of `code` (`GLINT_ERR_NOT_RUNNING`), or `GLINT_UNKNOWN_CODE`; C strings because C
/// receives them as they are.
pub fn code_name(code: c_int) -> &'static CStr {
    CODES
        .iter()
        .find(|(c, _)| *c == code)
        .map_or(c"GLINT_UNKNOWN_CODE", |(_, name)| name)
}

/// Why a call of the C interface failed.
#[derive(Debug, Error)]
pub enum CapiError {
    /// A pointer argument that must not be null was null.
    #[error("{what} is a null pointer")]
    NullArgument {
        /// The parameter's name as in `glint.h`.
        what: &'static str,
    },
    /// A string argument is not UTF-8 (domains and stream names are ASCII).
    #[error("{what} is not valid UTF-8")]
    NotUtf8 {
        /// The parameter's name as in `glint.h`.
        what: &'static str,
    },
    /// The domain is not 1–64 characters from `[A-Za-z0-9_-]`.
    #[error("invalid domain {domain:?}")]
    Domain {
        /// The domain as given.
        domain: String,
        /// Which rule it breaks.
        #[source]
        source: DomainError,
    },
    /// The stream name is not one of the pose streams.
    #[error("unknown pose stream {0:?}: expected \"odom\", \"map\" or \"predicted\"")]
    UnknownStream(String),
    /// The caller's point buffer is smaller than the sweep. The sweep is consumed all the same
    /// (see [`crate::sweep`]), so the message says what size would have done.
    #[error(
        "sweep {sequence} has {needed} points but the buffer holds {capacity}: skipped, only its \
         header was written; pass room for at least {needed} points (GLINT_SWEEP_MAX_POINTS fits \
         any sweep)"
    )]
    BufferTooSmall {
        /// The skipped sweep's `sequence`.
        sequence: u64,
        /// Its points.
        needed: usize,
        /// The `capacity` passed.
        capacity: usize,
    },
    /// The handle was opened with invalid arguments and can never connect.
    #[error("this handle was opened with invalid arguments ({0}); close it")]
    Unusable(String),
    /// Still not connected: the last attempt (under a
    /// [`RECONNECT_INTERVAL`](crate::handle::RECONNECT_INTERVAL) ago) failed like this.
    #[error("{reason} (retrying)")]
    Disconnected {
        /// The code of the last attempt.
        code: c_int,
        /// Its message.
        reason: String,
    },
    /// Opening the services failed.
    #[error(transparent)]
    Subscribe(#[from] SubscribeError),
    /// Taking a message failed.
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    /// Waiting for a message failed.
    #[error(transparent)]
    Wait(#[from] WaitError),
    /// Sending an initial-pose hint failed (an invalid hint, no daemon, or iceoryx2).
    #[error(transparent)]
    SendInitialPose(#[from] SendInitialPoseError),
    /// A panic inside the library, caught at the C boundary.
    #[error("internal error (a bug in libglint): {0}")]
    Panic(String),
}

impl CapiError {
    /// The result code C sees for this error.
    pub fn code(&self) -> c_int {
        match self {
            Self::NullArgument { .. }
            | Self::NotUtf8 { .. }
            | Self::Domain { .. }
            | Self::UnknownStream(_)
            | Self::BufferTooSmall { .. }
            | Self::Unusable(_) => GLINT_ERR_INVALID_ARGUMENT,
            Self::Disconnected { code, .. } => *code,
            Self::Subscribe(e) => subscribe_code(e),
            Self::Receive(_) => GLINT_ERR_IPC,
            Self::Wait(WaitError::Wait {
                source: ListenerWaitError::InterruptSignal,
                ..
            }) => GLINT_ERR_INTERRUPTED,
            Self::Wait(_) => GLINT_ERR_IPC,
            Self::SendInitialPose(e) => send_initial_pose_code(e),
            Self::Panic(_) => GLINT_ERR_INTERNAL,
        }
    }

    /// Whether the handle's connection should be dropped and made anew on the next call: after
    /// a failure of the ports themselves, not after an interrupted wait.
    pub fn drops_connection(&self) -> bool {
        matches!(self.code(), GLINT_ERR_IPC)
    }

    /// The message with every cause, `outer: inner: innermost`, because C callers get no
    /// `source()` to walk.
    pub fn message(&self) -> String {
        let mut text = self.to_string();
        let mut source = self.source();
        while let Some(cause) = source {
            text.push_str(": ");
            text.push_str(&cause.to_string());
            source = cause.source();
        }
        text
    }
}

/// Splits open failures into "the daemon is not there", "it is there but speaks another
/// contract" and everything else, because a controller reacts differently to each (wait, alert
/// an operator, log).
fn subscribe_code(e: &SubscribeError) -> c_int {
    use EventOpenError as E;
    use PublishSubscribeOpenError as P;
    match e {
        SubscribeError::NotRunning { .. } => GLINT_ERR_NOT_RUNNING,
        SubscribeError::Service {
            source:
                P::IncompatibleTypes
                | P::IncompatibleMessagingPattern
                | P::IncompatibleAttributes
                | P::IncompatibleOverflowBehavior,
            ..
        }
        | SubscribeError::EventService {
            source:
                E::IncompatibleMessagingPattern
                | E::IncompatibleAttributes
                | E::IncompatibleDeadline
                | E::IncompatibleNotifierCreatedEvent
                | E::IncompatibleNotifierDroppedEvent
                | E::IncompatibleNotifierDeadEvent,
            ..
        } => GLINT_ERR_INCOMPATIBLE,
        _ => GLINT_ERR_IPC,
    }
}

/// The same split for a hint: refused as invalid, no daemon, another contract, anything else.
fn send_initial_pose_code(e: &SendInitialPoseError) -> c_int {
    use EventOpenError as E;
    use InitialPoseOpenError as O;
    use PublishSubscribeOpenError as P;
    match e {
        SendInitialPoseError::Send(InitialPoseSendError::Invalid(_)) => GLINT_ERR_INVALID_ARGUMENT,
        SendInitialPoseError::Open(O::NotRunning { .. }) => GLINT_ERR_NOT_RUNNING,
        SendInitialPoseError::Open(
            O::Service {
                source:
                    P::IncompatibleTypes
                    | P::IncompatibleMessagingPattern
                    | P::IncompatibleAttributes
                    | P::IncompatibleOverflowBehavior,
                ..
            }
            | O::EventService {
                source:
                    E::IncompatibleMessagingPattern
                    | E::IncompatibleAttributes
                    | E::IncompatibleDeadline
                    | E::IncompatibleNotifierCreatedEvent
                    | E::IncompatibleNotifierDroppedEvent
                    | E::IncompatibleNotifierDeadEvent,
                ..
            },
        ) => GLINT_ERR_INCOMPATIBLE,
        _ => GLINT_ERR_IPC,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_has_a_distinct_name_and_value() {
        for (i, (code, name)) in CODES.iter().enumerate() {
            assert_eq!(code_name(*code), *name);
            assert!(CODES[i + 1..].iter().all(|(c, n)| c != code && n != name));
        }
        assert_eq!(code_name(42), c"GLINT_UNKNOWN_CODE");
    }

    #[test]
    fn message_carries_the_cause_chain() {
        let e = CapiError::Domain {
            domain: "a/b".into(),
            source: DomainError::InvalidCharacter { ch: '/', index: 1 },
        };
        assert_eq!(e.code(), GLINT_ERR_INVALID_ARGUMENT);
        let m = e.message();
        assert!(
            m.starts_with("invalid domain \"a/b\": ") && m.contains("'/' at byte 1"),
            "{m}"
        );
    }

    #[test]
    fn a_missing_service_is_not_running_and_keeps_the_connection_plan() {
        let e = CapiError::Subscribe(SubscribeError::NotRunning {
            service: "glint/x/odom".into(),
        });
        assert_eq!(e.code(), GLINT_ERR_NOT_RUNNING);
        assert!(!e.drops_connection());
        assert!(e.message().contains("glint/x/odom"));
    }
}
