//! libglint: Glint's C interface. C and C++ controllers subscribe to `glintd`'s poses, status
//! and sweeps, and send it initial-pose hints, over iceoryx2 (exactly 0.10.0, through
//! glint-ipc) with the functions declared in `include/glint.h`.
//!
//! This file is the FFI boundary and the only place with `unsafe`: it turns C pointers into
//! references, catches every panic before it can unwind into C, and turns results into codes and
//! per-handle messages. The logic lives in safe Rust: [`handle`] (connection, reconnection,
//! messages), [`sweep`] (copying sweeps into a caller's buffer) and [`error`] (codes). The
//! payload structs are glint-ipc's own `#[repr(C)]` [`Pose`], [`Status`], [`SweepHeader`] and
//! [`SweepPoint`], so the bytes copied to C are the bytes on the wire.
//!
//! No global state: everything a call needs is in the handle the caller passes, so handles are
//! independent and a handle may move between threads (one thread at a time).

pub mod error;
pub mod handle;
pub mod sweep;

use core::ffi::{c_char, c_int, CStr};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::Duration;

use glint_ipc::{
    send_initial_pose, Domain, InitialPose, Pose, PoseStream, PoseSubscriber, Status,
    StatusSubscriber, SweepHeader, SweepPoint, SweepSubscriber,
};

use crate::error::{
    code_name, CapiError, GLINT_ERR_INTERNAL, GLINT_ERR_INVALID_ARGUMENT, GLINT_NO_DATA, GLINT_OK,
    GLINT_TIMEOUT,
};
use crate::handle::{FixedSource, Handle, Received, Source};
use crate::sweep::SweepBuffer;

/// `glint_pose_subscriber` in C: an opaque handle on one pose stream.
pub type PoseHandle = Handle<PoseSubscriber>;
/// `glint_status_subscriber` in C: an opaque handle on the status stream.
pub type StatusHandle = Handle<StatusSubscriber>;
/// `glint_sweep_subscriber` in C: an opaque handle on a domain's sweeps.
pub type SweepHandle = Handle<SweepSubscriber>;

/// What C sees when a null handle is asked for its message.
const NULL_HANDLE_MESSAGE: &CStr = c"the handle is a null pointer";

/// Runs `f` so that a panic becomes [`GLINT_ERR_INTERNAL`] instead of unwinding into C
/// (undefined behaviour); `Err` holds the panic's text.
fn guarded<R>(f: impl FnOnce() -> R) -> Result<R, String> {
    catch_unwind(AssertUnwindSafe(f)).map_err(|payload| {
        payload
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "panic without a message".to_owned())
    })
}

/// Reads a C string argument.
///
/// # Safety
/// `ptr` is null or points to a NUL-terminated string that stays valid during the call.
unsafe fn c_str<'a>(ptr: *const c_char, what: &'static str) -> Result<&'a str, CapiError> {
    if ptr.is_null() {
        return Err(CapiError::NullArgument { what });
    }
    // SAFETY: non-null checked above; NUL termination and validity are the caller's contract
    // (documented on every function of glint.h taking a string).
    let s = unsafe { CStr::from_ptr(ptr) };
    s.to_str().map_err(|_| CapiError::NotUtf8 { what })
}

fn domain_arg(domain: Result<&str, CapiError>) -> Result<Domain, CapiError> {
    let domain = domain?;
    Domain::new(domain).map_err(|source| CapiError::Domain {
        domain: domain.to_owned(),
        source,
    })
}

fn pose_stream_arg(stream: Result<&str, CapiError>) -> Result<PoseStream, CapiError> {
    match stream? {
        "odom" => Ok(PoseStream::Odom),
        "map" => Ok(PoseStream::Map),
        "predicted" => Ok(PoseStream::Predicted),
        other => Err(CapiError::UnknownStream(other.to_owned())),
    }
}

/// Opens a handle and hands it out even when opening failed, so that the caller can read why
/// (as `sqlite3_open` does); only a null `out` gets no handle.
///
/// # Safety
/// `out` is null or points to writable storage for one pointer.
unsafe fn open_into<S: Source>(
    out: *mut *mut Handle<S>,
    open: impl FnOnce() -> (Handle<S>, Result<(), CapiError>),
) -> c_int {
    if out.is_null() {
        return GLINT_ERR_INVALID_ARGUMENT;
    }
    match guarded(open) {
        Ok((handle, result)) => {
            // SAFETY: `out` is non-null (checked above) and writable (caller's contract).
            unsafe { out.write(Box::into_raw(Box::new(handle))) };
            result.map_or_else(|e| e.code(), |()| GLINT_OK)
        }
        Err(_) => {
            // SAFETY: as above.
            unsafe { out.write(core::ptr::null_mut()) };
            GLINT_ERR_INTERNAL
        }
    }
}

/// Runs one receiving call on a handle: a null handle is refused, a panic caught, and the
/// outcome becomes the code and the handle's message.
///
/// # Safety
/// `handle` is null or a live handle from the matching `open` not used by another thread during
/// the call.
unsafe fn on_handle<S: Source>(
    handle: *mut Handle<S>,
    call: impl FnOnce(&mut Handle<S>) -> Result<Received<()>, CapiError>,
) -> c_int {
    // SAFETY: null or live and unshared during the call, by the caller's contract above
    // (glint.h: "a handle is used by one thread at a time, and not after close").
    let Some(handle) = (unsafe { handle.as_mut() }) else {
        return GLINT_ERR_INVALID_ARGUMENT;
    };
    let result = guarded(|| match call(handle)? {
        Received::Message(()) => Ok(GLINT_OK),
        Received::NoData => Ok(GLINT_NO_DATA),
        Received::Timeout => Ok(GLINT_TIMEOUT),
    })
    .unwrap_or_else(|panic| Err(CapiError::Panic(panic)));
    let code = result.as_ref().map_or_else(CapiError::code, |c| *c);
    // Recording a message allocates; should even that panic, the code still gets through.
    let _ = guarded(|| handle.record(result.as_ref().copied()));
    code
}

/// Runs one receiving call on a handle and copies a message into `out`.
///
/// # Safety
/// `handle` is null or a live handle from the matching `open` not used by another thread during
/// the call; `out` is null or points to writable memory for one `S::Item` (any alignment).
unsafe fn receive<S: FixedSource>(
    handle: *mut Handle<S>,
    out: *mut S::Item,
    call: impl FnOnce(&mut Handle<S>) -> Result<Received<S::Item>, CapiError>,
) -> c_int {
    let copy = |handle: &mut Handle<S>| {
        if out.is_null() {
            return Err(CapiError::NullArgument { what: "out" });
        }
        Ok(match call(handle)? {
            Received::Message(item) => {
                // SAFETY: non-null checked above; the caller provides room for one item, and
                // `write_unaligned` asks nothing of its alignment.
                unsafe { out.write_unaligned(item) };
                Received::Message(())
            }
            Received::NoData => Received::NoData,
            Received::Timeout => Received::Timeout,
        })
    };
    // SAFETY: the handle contract is this function's own, passed on unchanged.
    unsafe { on_handle(handle, copy) }
}

/// The caller's sweep buffers: `header` non-null, `points` non-null unless `capacity` is 0
/// (checked in [`receive_sweep`], the only place that makes one).
struct CallerSweep {
    header: *mut SweepHeader,
    points: *mut SweepPoint,
    capacity: usize,
}

impl SweepBuffer for CallerSweep {
    fn capacity(&self) -> usize {
        self.capacity
    }

    fn fill(&mut self, header: &SweepHeader, points: &[SweepPoint]) {
        // The safe side never passes more; were it ever to, a panic (caught) beats an overflow.
        assert!(
            points.len() <= self.capacity,
            "{} points for a buffer of {}",
            points.len(),
            self.capacity
        );
        // SAFETY: `header` is non-null (see the struct) and room for one header (the caller's
        // contract); `write_unaligned` asks nothing of its alignment.
        unsafe { self.header.write_unaligned(*header) };
        if points.is_empty() {
            return;
        }
        // SAFETY: `points` is non-null when `capacity` > 0 (see the struct), and writable for
        // `capacity` points (the caller's contract), at least `points.len()` (asserted above).
        // The source is the sample in shared memory, which the caller cannot have been handed,
        // so the two do not overlap; copying bytes asks nothing of the destination's alignment.
        unsafe {
            core::ptr::copy_nonoverlapping(
                points.as_ptr().cast::<u8>(),
                self.points.cast::<u8>(),
                core::mem::size_of_val(points),
            );
        }
    }
}

/// Runs one receiving call on a sweep handle, copying the sweep into the caller's buffers.
///
/// # Safety
/// `handle` is null or a live sweep handle not used by another thread during the call; `header`
/// is null or writable for one `glint_sweep_header_v1`; `points` is null or writable for `capacity`
/// `glint_sweep_point_v1`s (any alignment, for both).
unsafe fn receive_sweep(
    handle: *mut SweepHandle,
    header: *mut SweepHeader,
    points: *mut SweepPoint,
    capacity: usize,
    call: impl FnOnce(&mut SweepHandle, &mut CallerSweep) -> Result<Received<()>, CapiError>,
) -> c_int {
    let copy = |handle: &mut SweepHandle| {
        if header.is_null() {
            return Err(CapiError::NullArgument { what: "header" });
        }
        // NULL with capacity 0 is allowed: a caller that only wants the headers.
        if points.is_null() && capacity > 0 {
            return Err(CapiError::NullArgument { what: "points" });
        }
        let mut out = CallerSweep {
            header,
            points,
            capacity,
        };
        call(handle, &mut out)
    };
    // SAFETY: the handle contract is this function's own, passed on unchanged; the buffers'
    // are checked in `copy` and kept by `CallerSweep`.
    unsafe { on_handle(handle, copy) }
}

/// The handle's last message.
///
/// # Safety
/// `handle` is null or a live handle not being used by another thread.
unsafe fn message_of<S: Source>(handle: *const Handle<S>) -> *const c_char {
    // SAFETY: null or live, by the caller's contract above.
    match unsafe { handle.as_ref() } {
        Some(handle) => handle.message().as_ptr(),
        None => NULL_HANDLE_MESSAGE.as_ptr(),
    }
}

/// Frees a handle.
///
/// # Safety
/// `handle` is null or a live handle from the matching `open`, not used after this call.
unsafe fn close<S: Source>(handle: *mut Handle<S>) -> c_int {
    if handle.is_null() {
        return GLINT_OK;
    }
    // SAFETY: the pointer came from `Box::into_raw` in `open_into` and, by the caller's
    // contract, is closed only once.
    let handle = unsafe { Box::from_raw(handle) };
    // Dropping releases iceoryx2 ports; a panic there must not cross into C.
    guarded(|| drop(handle)).map_or(GLINT_ERR_INTERNAL, |()| GLINT_OK)
}

fn millis(timeout_ms: u32) -> Duration {
    Duration::from_millis(u64::from(timeout_ms))
}

/// See `glint_pose_subscriber_open` in glint.h.
///
/// # Safety
/// `domain` and `stream` are null or NUL-terminated strings; `out` is null or writable.
#[no_mangle]
pub unsafe extern "C" fn glint_pose_subscriber_open(
    domain: *const c_char,
    stream: *const c_char,
    out: *mut *mut PoseHandle,
) -> c_int {
    // SAFETY: the string and `out` contracts are this function's own, passed on unchanged.
    unsafe {
        open_into(out, || {
            let stream_name = c_str(stream, "stream").unwrap_or("?");
            Handle::open(
                domain_arg(c_str(domain, "domain")),
                pose_stream_arg(c_str(stream, "stream")),
                stream_name,
            )
        })
    }
}

/// See `glint_pose_subscriber_take` in glint.h.
///
/// # Safety
/// `sub` is null or a live, unshared handle; `out` is null or room for one `glint_pose_v1`.
#[no_mangle]
pub unsafe extern "C" fn glint_pose_subscriber_take(sub: *mut PoseHandle, out: *mut Pose) -> c_int {
    // SAFETY: this function's contract is `receive`'s.
    unsafe { receive(sub, out, Handle::take) }
}

/// See `glint_pose_subscriber_take_latest` in glint.h.
///
/// # Safety
/// As [`glint_pose_subscriber_take`].
#[no_mangle]
pub unsafe extern "C" fn glint_pose_subscriber_take_latest(
    sub: *mut PoseHandle,
    out: *mut Pose,
) -> c_int {
    // SAFETY: this function's contract is `receive`'s.
    unsafe { receive(sub, out, Handle::take_latest) }
}

/// See `glint_pose_subscriber_wait` in glint.h.
///
/// # Safety
/// As [`glint_pose_subscriber_take`].
#[no_mangle]
pub unsafe extern "C" fn glint_pose_subscriber_wait(
    sub: *mut PoseHandle,
    timeout_ms: u32,
    out: *mut Pose,
) -> c_int {
    // SAFETY: this function's contract is `receive`'s.
    unsafe { receive(sub, out, |h| h.wait(millis(timeout_ms))) }
}

/// See `glint_pose_subscriber_last_error` in glint.h.
///
/// # Safety
/// `sub` is null or a live handle not used by another thread meanwhile.
#[no_mangle]
pub unsafe extern "C" fn glint_pose_subscriber_last_error(sub: *const PoseHandle) -> *const c_char {
    // SAFETY: this function's contract is `message_of`'s.
    unsafe { message_of(sub) }
}

/// See `glint_pose_subscriber_close` in glint.h.
///
/// # Safety
/// `sub` is null or a live handle, not used after this call.
#[no_mangle]
pub unsafe extern "C" fn glint_pose_subscriber_close(sub: *mut PoseHandle) -> c_int {
    // SAFETY: this function's contract is `close`'s.
    unsafe { close(sub) }
}

/// See `glint_status_subscriber_open` in glint.h.
///
/// # Safety
/// `domain` is null or a NUL-terminated string; `out` is null or writable.
#[no_mangle]
pub unsafe extern "C" fn glint_status_subscriber_open(
    domain: *const c_char,
    out: *mut *mut StatusHandle,
) -> c_int {
    // SAFETY: the string and `out` contracts are this function's own, passed on unchanged.
    unsafe {
        open_into(out, || {
            Handle::open(domain_arg(c_str(domain, "domain")), Ok(()), "status")
        })
    }
}

/// See `glint_status_subscriber_take_latest` in glint.h.
///
/// # Safety
/// `sub` is null or a live, unshared handle; `out` is null or room for one `glint_status_v1`.
#[no_mangle]
pub unsafe extern "C" fn glint_status_subscriber_take_latest(
    sub: *mut StatusHandle,
    out: *mut Status,
) -> c_int {
    // SAFETY: this function's contract is `receive`'s.
    unsafe { receive(sub, out, Handle::take_latest) }
}

/// See `glint_status_subscriber_wait` in glint.h.
///
/// # Safety
/// As [`glint_status_subscriber_take_latest`].
#[no_mangle]
pub unsafe extern "C" fn glint_status_subscriber_wait(
    sub: *mut StatusHandle,
    timeout_ms: u32,
    out: *mut Status,
) -> c_int {
    // SAFETY: this function's contract is `receive`'s.
    unsafe { receive(sub, out, |h| h.wait(millis(timeout_ms))) }
}

/// See `glint_status_subscriber_last_error` in glint.h.
///
/// # Safety
/// `sub` is null or a live handle not used by another thread meanwhile.
#[no_mangle]
pub unsafe extern "C" fn glint_status_subscriber_last_error(
    sub: *const StatusHandle,
) -> *const c_char {
    // SAFETY: this function's contract is `message_of`'s.
    unsafe { message_of(sub) }
}

/// See `glint_status_subscriber_close` in glint.h.
///
/// # Safety
/// `sub` is null or a live handle, not used after this call.
#[no_mangle]
pub unsafe extern "C" fn glint_status_subscriber_close(sub: *mut StatusHandle) -> c_int {
    // SAFETY: this function's contract is `close`'s.
    unsafe { close(sub) }
}

/// See `glint_sweep_subscriber_open` in glint.h.
///
/// # Safety
/// `domain` is null or a NUL-terminated string; `out` is null or writable.
#[no_mangle]
pub unsafe extern "C" fn glint_sweep_subscriber_open(
    domain: *const c_char,
    out: *mut *mut SweepHandle,
) -> c_int {
    // SAFETY: the string and `out` contracts are this function's own, passed on unchanged.
    unsafe {
        open_into(out, || {
            Handle::open(domain_arg(c_str(domain, "domain")), Ok(()), "sweep")
        })
    }
}

/// See `glint_sweep_subscriber_take` in glint.h.
///
/// # Safety
/// `sub` is null or a live, unshared handle; `header` is null or room for one
/// `glint_sweep_header_v1`; `points` is null or room for `capacity` `glint_sweep_point_v1`s.
#[no_mangle]
pub unsafe extern "C" fn glint_sweep_subscriber_take(
    sub: *mut SweepHandle,
    header: *mut SweepHeader,
    points: *mut SweepPoint,
    capacity: usize,
) -> c_int {
    // SAFETY: this function's contract is `receive_sweep`'s.
    unsafe { receive_sweep(sub, header, points, capacity, |h, out| h.take_into(out)) }
}

/// See `glint_sweep_subscriber_wait` in glint.h.
///
/// # Safety
/// As [`glint_sweep_subscriber_take`].
#[no_mangle]
pub unsafe extern "C" fn glint_sweep_subscriber_wait(
    sub: *mut SweepHandle,
    timeout_ms: u32,
    header: *mut SweepHeader,
    points: *mut SweepPoint,
    capacity: usize,
) -> c_int {
    // SAFETY: this function's contract is `receive_sweep`'s.
    unsafe {
        receive_sweep(sub, header, points, capacity, |h, out| {
            h.wait_into(millis(timeout_ms), out)
        })
    }
}

/// See `glint_sweep_subscriber_last_error` in glint.h.
///
/// # Safety
/// `sub` is null or a live handle not used by another thread meanwhile.
#[no_mangle]
pub unsafe extern "C" fn glint_sweep_subscriber_last_error(
    sub: *const SweepHandle,
) -> *const c_char {
    // SAFETY: this function's contract is `message_of`'s.
    unsafe { message_of(sub) }
}

/// See `glint_sweep_subscriber_close` in glint.h.
///
/// # Safety
/// `sub` is null or a live handle, not used after this call.
#[no_mangle]
pub unsafe extern "C" fn glint_sweep_subscriber_close(sub: *mut SweepHandle) -> c_int {
    // SAFETY: this function's contract is `close`'s.
    unsafe { close(sub) }
}

/// See `glint_code_name` in glint.h. Needs no handle and cannot fail: the names are static.
#[no_mangle]
pub extern "C" fn glint_code_name(code: c_int) -> *const c_char {
    code_name(code).as_ptr()
}

/// See `glint_send_initial_pose` in glint.h: one hint, sent as a one-shot tool does (open, send,
/// keep the port 0.5 s so glintd takes it, close). No handle, so the message goes to the
/// caller's buffer.
///
/// # Safety
/// `domain` is null or a NUL-terminated string; `error` is null or writable for `error_size`
/// bytes.
#[no_mangle]
pub unsafe extern "C" fn glint_send_initial_pose(
    domain: *const c_char,
    x: f64,
    y: f64,
    yaw: f64,
    position_sigma: f64,
    error: *mut c_char,
    error_size: usize,
) -> c_int {
    let result = guarded(|| {
        // SAFETY: the string contract is this function's own, passed on unchanged.
        let domain = domain_arg(unsafe { c_str(domain, "domain") })?;
        let now_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
        let hint = InitialPose::on_floor(now_ns, x, y, yaw, position_sigma);
        send_initial_pose(&domain, &hint)?;
        Ok(())
    })
    .unwrap_or_else(|panic| Err(CapiError::Panic(panic)));
    let (code, message) = match result {
        Ok(()) => (GLINT_OK, String::new()),
        Err(e) => (e.code(), e.message()),
    };
    if !error.is_null() && error_size > 0 {
        // Truncated to the buffer and always NUL-terminated, as snprintf does.
        let len = message.len().min(error_size - 1);
        // SAFETY: `error` is non-null and writable for `error_size` bytes (caller's contract);
        // `len + 1 <= error_size` bytes are written, and the source is a live Rust string.
        unsafe {
            core::ptr::copy_nonoverlapping(message.as_ptr().cast::<c_char>(), error, len);
            error.add(len).write(0);
        }
    }
    code
}
