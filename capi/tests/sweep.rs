//! Sweeps through libglint, against a `SweepPublisher` created here (standing in for glintd).
//! The C example (`examples/glint_sweeps.c`), built by the system gcc against the libglint.so of
//! this build and started before the publisher exists, must print every published sweep's
//! sequence, stamp and label counts. The functions are also called directly (through the rlib):
//! header and points arrive byte for byte, a buffer too small consumes the sweep and says the
//! size needed, null pointers are refused, and a handle opened before the publisher exists, or
//! kept across its restart, connects by itself.

use core::ffi::{c_int, CStr};
use std::ffi::CString;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::ptr::{null, null_mut};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread;
use std::time::{Duration, Instant};

use glint::error::{
    GLINT_ERR_INVALID_ARGUMENT, GLINT_ERR_NOT_RUNNING, GLINT_NO_DATA, GLINT_OK, GLINT_TIMEOUT,
};
use glint::{
    glint_sweep_subscriber_close, glint_sweep_subscriber_last_error, glint_sweep_subscriber_open,
    glint_sweep_subscriber_take, glint_sweep_subscriber_wait, SweepHandle,
};
use glint_ipc::settings::SWEEP_MAX_POINTS;
use glint_ipc::{Domain, PointLabel, StatusFlags, SweepHeader, SweepPoint, SweepPublisher};

fn capi_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A domain no other test or process uses.
fn unique(tag: &str) -> String {
    format!("capi-sweep-{tag}-{}", std::process::id())
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-capi-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The `libglint.so` cargo built for this test (this package's cdylib, in the test's own `deps`
/// directory), as `tests/initial_pose.rs` finds it.
fn library_dir() -> PathBuf {
    let deps = std::env::current_exe()
        .unwrap()
        .parent()
        .expect("the test runs from target/<profile>/deps")
        .to_path_buf();
    let found = std::fs::read_dir(&deps)
        .unwrap()
        .filter_map(Result::ok)
        .any(|e| e.file_name() == "libglint.so");
    assert!(found, "no libglint.so in {}", deps.display());
    deps
}

/// Builds the C example as the README tells a controller project to.
fn example(dir: &Path) -> PathBuf {
    let lib_dir = library_dir();
    let lib_dir = lib_dir.to_str().unwrap();
    let exe = dir.join("glint_sweeps");
    let out = Command::new("gcc")
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-I"])
        .arg(capi_dir().join("include"))
        .arg(capi_dir().join("examples/glint_sweeps.c"))
        .args([
            "-L",
            lib_dir,
            "-lglint",
            &format!("-Wl,-rpath,{lib_dir}"),
            "-o",
        ])
        .arg(&exe)
        .output()
        .expect("run gcc");
    assert!(
        out.status.success(),
        "gcc:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    exe
}

/// Point `i` of sweep `sweep`: every field distinct from its neighbours', and labels that walk
/// through all eight combinations of the three bits at a pace that differs per sweep.
fn point(sweep: u64, i: usize) -> SweepPoint {
    let f = i as f32;
    SweepPoint {
        position: [f * 0.5 + sweep as f32, -f * 0.25, 1.0 / (f + 1.0)],
        intensity: if i % 11 == 5 {
            // A NaN with a payload: copied as bytes, not as a float.
            f32::from_bits(0x7fc0_0000 | i as u32)
        } else {
            f * 1e-3
        },
        time_offset_ns: -(i as i32) * 1_000 - sweep as i32,
        ring: (i % 32) as u16,
        reflectivity: (i * 7 % 256) as u8,
        label: PointLabel(((i / (sweep as usize + 1)) % 8) as u8),
    }
}

fn header(sweep: u64) -> SweepHeader {
    SweepHeader {
        timestamp_ns: 1_700_000_000_000_000_000 + sweep * 100_000_000,
        sensor_time_ns: 5_000_000_000 + sweep,
        flags: StatusFlags::TRACKING.with(StatusFlags::DEGENERATE),
        sensor_twist: [0.1, -0.2, 0.3 + sweep as f64, 1.5, -2.5, f64::MIN_POSITIVE],
        sensor_position: [0.25, -0.125, 1.75],
        sensor_orientation: [0.0, 0.0, 0.6, 0.8],
        ..SweepHeader::default()
    }
}

/// The header as published: the publisher fills in `sequence` and `point_count`.
fn published(sweep: u64, sequence: u64, count: usize) -> SweepHeader {
    SweepHeader {
        sequence,
        point_count: count as u32,
        ..header(sweep)
    }
}

/// A struct's bytes. Both sweep structs are `#[repr(C)]` without padding (the header test
/// checks the sizes), so every byte is a field's.
fn bytes<T: Copy>(values: &[T]) -> &[u8] {
    // SAFETY: `values` is a live slice of padding-free plain data; the bytes live as long.
    unsafe { std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), size_of_val(values)) }
}

const SENTINEL_POINT: SweepPoint = SweepPoint {
    position: [-9.0; 3],
    intensity: -9.0,
    time_offset_ns: 999,
    ring: 0xeeee,
    reflectivity: 0xee,
    label: PointLabel(0xee),
};

fn sentinel_header() -> SweepHeader {
    SweepHeader {
        sequence: u64::MAX,
        point_count: u32::MAX,
        ..SweepHeader::default()
    }
}

/// A sweep handle as a C program holds one, closed on drop.
struct Sub(*mut SweepHandle);

/// What a receiving call returned and left in the buffers.
struct Got {
    rc: c_int,
    header: SweepHeader,
    points: Vec<SweepPoint>,
}

impl Sub {
    fn open(domain: &str) -> (c_int, Self) {
        let d = CString::new(domain).unwrap();
        let mut h = null_mut();
        // SAFETY: a NUL-terminated string alive for the call; `h` is writable.
        let rc = unsafe { glint_sweep_subscriber_open(d.as_ptr(), &mut h) };
        assert!(!h.is_null(), "a handle even on failure");
        (rc, Self(h))
    }

    /// A take into a buffer of `capacity` sentinel points.
    fn take(&self, capacity: usize) -> Got {
        let mut header = sentinel_header();
        let mut points = vec![SENTINEL_POINT; capacity];
        // SAFETY: a live handle used by this thread only; room for one header and `capacity`
        // points.
        let rc = unsafe {
            glint_sweep_subscriber_take(self.0, &mut header, points.as_mut_ptr(), capacity)
        };
        Got { rc, header, points }
    }

    /// As `take`, waiting up to `ms`.
    fn wait(&self, ms: u32, capacity: usize) -> Got {
        let mut header = sentinel_header();
        let mut points = vec![SENTINEL_POINT; capacity];
        // SAFETY: as in `take`.
        let rc = unsafe {
            glint_sweep_subscriber_wait(self.0, ms, &mut header, points.as_mut_ptr(), capacity)
        };
        Got { rc, header, points }
    }

    fn message(&self) -> String {
        // SAFETY: a live handle; the string is copied before the next call.
        unsafe { CStr::from_ptr(glint_sweep_subscriber_last_error(self.0)) }
            .to_string_lossy()
            .into_owned()
    }
}

impl Drop for Sub {
    fn drop(&mut self) {
        // SAFETY: opened by `Sub::open`, closed once, never used again.
        assert_eq!(unsafe { glint_sweep_subscriber_close(self.0) }, GLINT_OK);
    }
}

/// Asserts that `got` holds sweep `sweep` (published as `sequence`, `count` points) byte for
/// byte, and the rest of the buffer its sentinels.
fn assert_sweep(got: &Got, sweep: u64, sequence: u64, count: usize) {
    assert_eq!(
        bytes(&[got.header]),
        bytes(&[published(sweep, sequence, count)]),
        "header {:?}",
        got.header
    );
    let expected: Vec<SweepPoint> = (0..count).map(|i| point(sweep, i)).collect();
    assert!(
        bytes(&got.points[..count]) == bytes(&expected),
        "points of sweep {sweep} differ"
    );
    assert!(
        bytes(&got.points[count..]) == bytes(&vec![SENTINEL_POINT; got.points.len() - count]),
        "written past the sweep"
    );
}

/// The example, killed if the test fails before it exits.
struct Running(Child);

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn c_example_counts_the_labels_of_every_published_sweep() {
    let dir = scratch("sweeps");
    let exe = example(&dir);
    let domain = Domain::new(&unique("example")).unwrap();
    let counts = [1_000, 0, 3, 28_928, SWEEP_MAX_POINTS, 77];

    // Started first, as a controller may be: it waits for the daemon.
    let mut child = Running(
        Command::new(&exe)
            .args([domain.as_str(), &counts.len().to_string()])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let (tx, lines) = mpsc::channel();
    let stdout = child.0.stdout.take().unwrap();
    thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let _ = tx.send(line.expect("UTF-8"));
        }
    });
    let mut stderr = child.0.stderr.take().unwrap();
    let errors = thread::spawn(move || {
        let mut text = String::new();
        let _ = stderr.read_to_string(&mut text);
        text
    });
    thread::sleep(Duration::from_millis(300));

    let mut publisher = SweepPublisher::create(&domain).expect("publisher");
    for (sweep, &count) in (0u64..).zip(&counts) {
        publisher
            .publish(header(sweep), count, |i| point(sweep, i))
            .expect("publish");
        // One sweep at a time, so none is overwritten in the example's queue of two. The first
        // may predate the example's connection: it then arrives as the service's history, which
        // the publisher hands over when it updates its connections.
        let deadline = Instant::now() + Duration::from_secs(20);
        let line = loop {
            match lines.recv_timeout(Duration::from_millis(20)) {
                Ok(line) => break line,
                Err(_) if Instant::now() < deadline => {
                    publisher.update_connections().expect("connections");
                }
                Err(e) => panic!("no line for sweep {sweep} ({e})"),
            }
        };
        let labelled = |bit: PointLabel| {
            (0..count)
                .filter(|&i| point(sweep, i).label.contains(bit))
                .count()
        };
        let expected = format!(
            "sequence={sweep} timestamp_ns={} points={count} edges={} planes={} intensity={}",
            header(sweep).timestamp_ns,
            labelled(PointLabel::EDGE),
            labelled(PointLabel::PLANE),
            labelled(PointLabel::INTENSITY),
        );
        assert_eq!(line, expected);
    }

    let deadline = Instant::now() + Duration::from_secs(10);
    let status = loop {
        if let Some(status) = child.0.try_wait().unwrap() {
            break status;
        }
        assert!(Instant::now() < deadline, "the example did not exit");
        thread::sleep(Duration::from_millis(20));
    };
    let errors = errors.join().unwrap();
    assert!(status.success(), "{status}: {errors}");
    // It started before the publisher: it said so, then connected by itself.
    assert!(errors.contains("GLINT_ERR_NOT_RUNNING: "), "{errors}");
    assert!(lines.try_recv().is_err(), "a line too many");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn header_and_points_arrive_byte_for_byte_and_nothing_beyond() {
    let domain = Domain::new(&unique("bytes")).unwrap();
    let mut publisher = SweepPublisher::create(&domain).expect("publisher");
    let (rc, sub) = Sub::open(domain.as_str());
    assert_eq!(rc, GLINT_OK, "{}", sub.message());
    assert_eq!(sub.message(), "");

    let got = sub.take(16);
    assert_eq!(got.rc, GLINT_NO_DATA);
    assert_eq!(
        bytes(&[got.header]),
        bytes(&[sentinel_header()]),
        "untouched"
    );
    assert!(
        sub.message()
            .contains(&format!("no unread sweep on glint/{domain}/sweep")),
        "{}",
        sub.message()
    );

    for (sweep, count, capacity) in [(0, 1_000, 1_500), (1, 64, 64), (2, 0, 8)] {
        publisher
            .publish(header(sweep), count, |i| point(sweep, i))
            .expect("publish");
        let got = sub.take(capacity);
        assert_eq!(got.rc, GLINT_OK, "{}", sub.message());
        assert_sweep(&got, sweep, sweep, count);
        assert_eq!(sub.message(), "");
    }

    // The largest sweep, into the buffer the header recommends.
    publisher
        .publish(header(3), SWEEP_MAX_POINTS, |i| point(3, i))
        .expect("publish");
    let got = sub.wait(5_000, SWEEP_MAX_POINTS);
    assert_eq!(got.rc, GLINT_OK, "{}", sub.message());
    assert_sweep(&got, 3, 3, SWEEP_MAX_POINTS);
    assert_eq!(sub.take(0).rc, GLINT_NO_DATA);
}

#[test]
fn a_buffer_too_small_gets_the_header_and_loses_the_sweep() {
    let domain = Domain::new(&unique("small")).unwrap();
    let mut publisher = SweepPublisher::create(&domain).expect("publisher");
    let (rc, sub) = Sub::open(domain.as_str());
    assert_eq!(rc, GLINT_OK, "{}", sub.message());

    publisher
        .publish(header(0), 10, |i| point(0, i))
        .expect("publish");
    let got = sub.take(4);
    assert_eq!(got.rc, GLINT_ERR_INVALID_ARGUMENT);
    // The header says what size was needed; no point was written.
    assert_eq!(bytes(&[got.header]), bytes(&[published(0, 0, 10)]));
    assert_eq!(bytes(&got.points), bytes(&[SENTINEL_POINT; 4]));
    let m = sub.message();
    assert!(
        m.contains("sweep 0 has 10 points but the buffer holds 4") && m.contains("at least 10"),
        "{m}"
    );
    // Consumed: the next call does not see it again, and the handle stays connected.
    assert_eq!(sub.take(100).rc, GLINT_NO_DATA);

    publisher
        .publish(header(1), 3, |i| point(1, i))
        .expect("publish");
    let got = sub.take(3);
    assert_eq!(got.rc, GLINT_OK, "an exact fit: {}", sub.message());
    assert_sweep(&got, 1, 1, 3);

    // Headers alone: NULL points with capacity 0.
    let headers_only = |sub: &Sub| {
        let mut header = sentinel_header();
        // SAFETY: a live handle; a NULL point buffer with capacity 0 is part of the contract.
        let rc = unsafe { glint_sweep_subscriber_take(sub.0, &mut header, null_mut(), 0) };
        (rc, header)
    };
    publisher
        .publish(header(2), 0, |i| point(2, i))
        .expect("publish");
    assert_eq!(headers_only(&sub), (GLINT_OK, published(2, 2, 0)));
    publisher
        .publish(header(3), 5, |i| point(3, i))
        .expect("publish");
    assert_eq!(
        headers_only(&sub),
        (GLINT_ERR_INVALID_ARGUMENT, published(3, 3, 5))
    );

    // The wait returns the error as well, at once.
    publisher
        .publish(header(4), 2, |i| point(4, i))
        .expect("publish");
    let started = Instant::now();
    let got = sub.wait(5_000, 1);
    assert_eq!(got.rc, GLINT_ERR_INVALID_ARGUMENT);
    assert_eq!(got.header, published(4, 4, 2));
    assert!(started.elapsed() < Duration::from_secs(2));
}

#[test]
fn null_pointers_are_invalid_arguments_not_crashes() {
    let mut h = null_mut();
    // SAFETY: a null domain is part of the tested contract; `h` is writable.
    let rc = unsafe { glint_sweep_subscriber_open(null(), &mut h) };
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);
    let sub = Sub(h);
    assert_eq!(sub.message(), "domain is a null pointer");
    assert_eq!(sub.take(4).rc, GLINT_ERR_INVALID_ARGUMENT);
    assert!(
        sub.message().contains("invalid arguments"),
        "{}",
        sub.message()
    );

    let d = CString::new(unique("nulls")).unwrap();
    // SAFETY: a null `out` is refused before anything is written.
    let rc = unsafe { glint_sweep_subscriber_open(d.as_ptr(), null_mut()) };
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);

    let (rc, bad) = Sub::open("agv/7");
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);
    assert!(bad.message().contains("invalid domain \"agv/7\""));

    // Live handle and publisher, so that only the pointers can be at fault.
    let domain = Domain::new(&unique("nullbuf")).unwrap();
    let mut publisher = SweepPublisher::create(&domain).expect("publisher");
    let (rc, live) = Sub::open(domain.as_str());
    assert_eq!(rc, GLINT_OK, "{}", live.message());
    publisher
        .publish(header(0), 3, |i| point(0, i))
        .expect("publish");
    let mut header = sentinel_header();
    let mut points = [SENTINEL_POINT; 3];
    // SAFETY: null pointers are refused before anything is read or written; the others are
    // valid for the sizes given.
    unsafe {
        assert_eq!(
            glint_sweep_subscriber_take(live.0, null_mut(), points.as_mut_ptr(), 3),
            GLINT_ERR_INVALID_ARGUMENT
        );
        assert_eq!(live.message(), "header is a null pointer");
        assert_eq!(
            glint_sweep_subscriber_wait(live.0, 10, &mut header, null_mut(), 3),
            GLINT_ERR_INVALID_ARGUMENT
        );
        assert_eq!(live.message(), "points is a null pointer");
        assert_eq!(
            glint_sweep_subscriber_take(null_mut(), &mut header, points.as_mut_ptr(), 3),
            GLINT_ERR_INVALID_ARGUMENT
        );
        assert_eq!(
            glint_sweep_subscriber_wait(null_mut(), 10, &mut header, points.as_mut_ptr(), 3),
            GLINT_ERR_INVALID_ARGUMENT
        );
        assert_eq!(glint_sweep_subscriber_close(null_mut()), GLINT_OK);
        let m = CStr::from_ptr(glint_sweep_subscriber_last_error(null()));
        assert_eq!(m.to_str().unwrap(), "the handle is a null pointer");
    }
    assert_eq!(bytes(&[header]), bytes(&[sentinel_header()]), "untouched");
    assert_eq!(bytes(&points), bytes(&[SENTINEL_POINT; 3]), "untouched");
    // Nothing was consumed by the refused calls.
    let got = live.take(3);
    assert_eq!(got.rc, GLINT_OK, "{}", live.message());
    assert_sweep(&got, 0, 0, 3);
}

/// Publishes sweep `sweep` (`count` points) every 10 ms until dropped, so a waiting handle sees
/// one whenever it connects; the publisher comes back on drop.
struct Ticker {
    stop: Arc<AtomicBool>,
    thread: Option<thread::JoinHandle<SweepPublisher>>,
}

impl Ticker {
    fn start(mut publisher: SweepPublisher, sweep: u64, count: usize) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = thread::spawn(move || {
            while !flag.load(Ordering::Relaxed) {
                publisher
                    .publish(header(sweep), count, |i| point(sweep, i))
                    .expect("publish");
                thread::sleep(Duration::from_millis(10));
            }
            publisher
        });
        Self {
            stop,
            thread: Some(thread),
        }
    }

    fn stop(mut self) -> SweepPublisher {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().unwrap().join().expect("ticker thread")
    }
}

impl Drop for Ticker {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[test]
fn no_daemon_is_not_running_then_the_handle_connects_when_it_starts() {
    let domain = unique("late");
    let (rc, sub) = Sub::open(&domain);
    assert_eq!(rc, GLINT_ERR_NOT_RUNNING);
    let m = sub.message();
    assert!(
        m.contains(&format!("glint/{domain}/sweep")) && m.contains("does not exist"),
        "{m}"
    );
    let got = sub.take(8);
    assert_eq!(got.rc, GLINT_ERR_NOT_RUNNING);
    assert_eq!(got.header.sequence, u64::MAX, "untouched");
    let started = Instant::now();
    assert_eq!(sub.wait(100, 8).rc, GLINT_ERR_NOT_RUNNING);
    assert!(
        started.elapsed() >= Duration::from_millis(100),
        "waited the timeout"
    );

    let publisher = SweepPublisher::create(&Domain::new(&domain).unwrap()).expect("publisher");
    let ticker = Ticker::start(publisher, 7, 50);
    let got = sub.wait(5_000, 64);
    assert_eq!(got.rc, GLINT_OK, "{}", sub.message());
    let sequence = got.header.sequence;
    assert_sweep(&got, 7, sequence, 50);
    assert_eq!(sub.message(), "");
    drop(ticker.stop());
}

#[test]
fn a_wait_times_out_then_wakes_for_a_sweep_and_survives_a_restart() {
    let domain = Domain::new(&unique("restart")).unwrap();
    let mut publisher = SweepPublisher::create(&domain).expect("publisher");
    let (rc, sub) = Sub::open(domain.as_str());
    assert_eq!(rc, GLINT_OK, "{}", sub.message());

    let started = Instant::now();
    let got = sub.wait(100, 8);
    assert_eq!(got.rc, GLINT_TIMEOUT);
    assert!(started.elapsed() >= Duration::from_millis(100));
    assert_eq!(got.header.sequence, u64::MAX, "untouched");
    assert!(
        sub.message().contains("none received yet"),
        "{}",
        sub.message()
    );

    // Published while the consumer waits: the poll must find it well before the timeout.
    let late = thread::spawn(move || {
        thread::sleep(Duration::from_millis(200));
        publisher
            .publish(header(0), 5, |i| point(0, i))
            .expect("publish");
        publisher
    });
    let started = Instant::now();
    let got = sub.wait(10_000, 8);
    assert_eq!(got.rc, GLINT_OK, "{}", sub.message());
    assert_sweep(&got, 0, 0, 5);
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "found, not timed out"
    );
    let mut publisher = late.join().unwrap();
    publisher
        .publish(header(1), 5, |i| point(1, i))
        .expect("publish");
    assert_eq!(sub.wait(5_000, 8).rc, GLINT_OK);

    // The daemon goes away: silence, and the message says when the last sweep came.
    drop(publisher);
    assert_eq!(sub.wait(100, 8).rc, GLINT_TIMEOUT);
    let m = sub.message();
    assert!(
        m.contains("sequence 1") && m.contains("still running"),
        "{m}"
    );

    // It comes back (its counter restarts): the same handle reads on.
    let mut publisher = SweepPublisher::create(&domain).expect("restarted publisher");
    publisher
        .publish(header(9), 20, |i| point(9, i))
        .expect("publish");
    let got = sub.wait(5_000, 32);
    assert_eq!(got.rc, GLINT_OK, "{}", sub.message());
    assert_sweep(&got, 9, 0, 20);
}
