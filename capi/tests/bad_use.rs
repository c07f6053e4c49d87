//! The C functions called as C calls them (through the rlib), against an in-process glint-ipc
//! publisher standing in for glintd: wrong names, null pointers, no daemon, a daemon that
//! starts late and one that restarts mid-stream. Every case must give a code and a message,
//! never a crash, and the handle must connect or reconnect by itself when the daemon appears.

use core::ffi::{c_int, CStr};
use std::ffi::CString;
use std::ptr::null_mut;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};

use glint::error::{
    CODES, GLINT_ERR_INVALID_ARGUMENT, GLINT_ERR_NOT_RUNNING, GLINT_NO_DATA, GLINT_OK,
    GLINT_TIMEOUT,
};
use glint::{
    glint_code_name, glint_pose_subscriber_close, glint_pose_subscriber_last_error,
    glint_pose_subscriber_open, glint_pose_subscriber_take, glint_pose_subscriber_take_latest,
    glint_pose_subscriber_wait, glint_status_subscriber_close, glint_status_subscriber_last_error,
    glint_status_subscriber_open, glint_status_subscriber_take_latest,
    glint_status_subscriber_wait, PoseHandle, StatusHandle,
};
use glint_ipc::{Domain, Frame, Pose, PosePublisher, Status, StatusFlags};

/// A domain no other test or process uses.
fn unique(tag: &str) -> String {
    format!("capi-{tag}-{}", std::process::id())
}

fn pose(sequence: u64) -> Pose {
    let mut p = Pose::new(sequence, 1_700_000_000_000_000_000 + sequence, Frame::ODOM);
    p.position = [sequence as f64 + 0.125, -2.5, 1e-9];
    p.orientation = [0.0, 0.0, 0.6, 0.8];
    p.linear_velocity = [1.0, 2.0, 3.0];
    p.angular_velocity = [0.1, 0.2, 0.3];
    for (i, c) in p.covariance.iter_mut().enumerate() {
        *c = i as f64 * 0.001;
    }
    p.quality = 0.75;
    p.status = StatusFlags::TRACKING;
    p
}

/// A pose handle as a C program holds one, closed on drop.
struct Sub(*mut PoseHandle);

impl Sub {
    fn open(domain: &str, stream: &str) -> (c_int, Self) {
        let (d, s) = (CString::new(domain).unwrap(), CString::new(stream).unwrap());
        let mut h = null_mut();
        // SAFETY: NUL-terminated strings alive for the call; `h` is writable.
        let rc = unsafe { glint_pose_subscriber_open(d.as_ptr(), s.as_ptr(), &mut h) };
        assert!(!h.is_null(), "a handle even on failure");
        (rc, Self(h))
    }

    fn call(&self, f: unsafe extern "C" fn(*mut PoseHandle, *mut Pose) -> c_int) -> (c_int, Pose) {
        let mut p = Pose::new(u64::MAX, 0, Frame(99));
        // SAFETY: a live handle used by this thread only; `p` is room for one pose.
        let rc = unsafe { f(self.0, &mut p) };
        (rc, p)
    }

    fn take(&self) -> (c_int, Pose) {
        self.call(glint_pose_subscriber_take)
    }

    fn wait(&self, ms: u32) -> (c_int, Pose) {
        let mut p = Pose::new(u64::MAX, 0, Frame(99));
        // SAFETY: as in `call`.
        let rc = unsafe { glint_pose_subscriber_wait(self.0, ms, &mut p) };
        (rc, p)
    }

    fn message(&self) -> String {
        // SAFETY: a live handle; the string is copied before the next call.
        unsafe { CStr::from_ptr(glint_pose_subscriber_last_error(self.0)) }
            .to_string_lossy()
            .into_owned()
    }
}

impl Drop for Sub {
    fn drop(&mut self) {
        // SAFETY: opened by `Sub::open`, closed once, never used again.
        assert_eq!(unsafe { glint_pose_subscriber_close(self.0) }, GLINT_OK);
    }
}

/// Publishes `pose(sequence)` every 10 ms until dropped, so a waiting handle sees something
/// whenever it connects.
struct Ticker {
    stop: Arc<AtomicBool>,
    thread: Option<thread::JoinHandle<()>>,
}

impl Ticker {
    fn start(publisher: PosePublisher, sequence: u64) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = thread::spawn(move || {
            while !flag.load(Ordering::Relaxed) {
                publisher.publish_odom(&pose(sequence)).expect("publish");
                thread::sleep(Duration::from_millis(10));
            }
        });
        Self {
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Ticker {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().expect("ticker thread");
        }
    }
}

#[test]
fn a_wrong_stream_name_is_an_invalid_argument_with_a_message() {
    let (rc, sub) = Sub::open(&unique("badstream"), "odometry");
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);
    assert!(
        sub.message().contains("unknown pose stream \"odometry\""),
        "{}",
        sub.message()
    );
    // The handle can never connect, and says why on every call.
    assert_eq!(sub.take().0, GLINT_ERR_INVALID_ARGUMENT);
    assert_eq!(sub.wait(10).0, GLINT_ERR_INVALID_ARGUMENT);
    assert!(
        sub.message().contains("invalid arguments"),
        "{}",
        sub.message()
    );
}

#[test]
fn an_invalid_domain_is_refused_with_the_rule_it_breaks() {
    let (rc, sub) = Sub::open("agv/7", "odom");
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);
    let m = sub.message();
    assert!(
        m.contains("invalid domain \"agv/7\"") && m.contains("'/'"),
        "{m}"
    );
}

#[test]
fn null_pointers_are_invalid_arguments_not_crashes() {
    let stream = CString::new("odom").unwrap();
    let mut h = null_mut();
    // SAFETY: null domain is part of the tested contract; `h` is writable.
    let rc = unsafe { glint_pose_subscriber_open(std::ptr::null(), stream.as_ptr(), &mut h) };
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);
    let sub = Sub(h);
    assert_eq!(sub.message(), "domain is a null pointer");

    // SAFETY: a null `out` is refused before anything is written.
    let rc = unsafe { glint_pose_subscriber_open(stream.as_ptr(), stream.as_ptr(), null_mut()) };
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);

    let (_, live) = Sub::open(&unique("nullout"), "odom");
    // SAFETY: a live handle; the null `out` is refused before anything is written.
    let rc = unsafe { glint_pose_subscriber_take(live.0, null_mut()) };
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);
    assert_eq!(live.message(), "out is a null pointer");

    let mut p = pose(0);
    // SAFETY: null handles are refused; `p` is valid.
    unsafe {
        assert_eq!(
            glint_pose_subscriber_take(null_mut(), &mut p),
            GLINT_ERR_INVALID_ARGUMENT
        );
        assert_eq!(
            glint_pose_subscriber_wait(null_mut(), 5, &mut p),
            GLINT_ERR_INVALID_ARGUMENT
        );
        assert_eq!(glint_pose_subscriber_close(null_mut()), GLINT_OK);
        let m = CStr::from_ptr(glint_pose_subscriber_last_error(std::ptr::null()));
        assert_eq!(m.to_str().unwrap(), "the handle is a null pointer");
    }
    assert_eq!(p, pose(0), "nothing written on failure");
}

#[test]
fn no_daemon_is_not_running_then_the_handle_connects_when_it_starts() {
    let domain = unique("late");
    let (rc, sub) = Sub::open(&domain, "odom");
    assert_eq!(rc, GLINT_ERR_NOT_RUNNING);
    let m = sub.message();
    assert!(
        m.contains(&format!("glint/{domain}/odom")) && m.contains("does not exist"),
        "{m}"
    );
    let (rc, p) = sub.take();
    assert_eq!(rc, GLINT_ERR_NOT_RUNNING);
    assert_eq!(p.sequence, u64::MAX, "untouched");
    let started = Instant::now();
    assert_eq!(sub.wait(100).0, GLINT_ERR_NOT_RUNNING);
    assert!(
        started.elapsed() >= Duration::from_millis(100),
        "waited the timeout"
    );

    let publisher = PosePublisher::create(&Domain::new(&domain).unwrap()).expect("publisher");
    let _ticker = Ticker::start(publisher, 7);
    let (rc, p) = sub.wait(5_000);
    assert_eq!(rc, GLINT_OK, "{}", sub.message());
    assert_eq!(p, pose(7), "every byte as published");
    assert_eq!(sub.message(), "");
}

#[test]
fn a_daemon_restarted_mid_stream_shows_as_a_timeout_then_poses_resume() {
    let domain = Domain::new(&unique("restart")).unwrap();
    let publisher = PosePublisher::create(&domain).expect("publisher");
    let (rc, sub) = Sub::open(domain.as_str(), "odom");
    assert_eq!(rc, GLINT_OK, "{}", sub.message());
    for s in 1..=3 {
        publisher.publish_odom(&pose(s)).expect("publish");
    }
    for s in 1..=3 {
        assert_eq!(sub.take(), (GLINT_OK, pose(s)));
    }
    assert_eq!(sub.take().0, GLINT_NO_DATA);
    drop(publisher);

    assert_eq!(sub.wait(100).0, GLINT_TIMEOUT);
    let m = sub.message();
    assert!(
        m.contains("sequence 3") && m.contains("still running"),
        "{m}"
    );

    // The daemon comes back (its counter restarts) while the consumer sleeps in `wait`: the
    // notification of the new daemon must wake it.
    let domain2 = domain.clone();
    let restarted = thread::spawn(move || {
        thread::sleep(Duration::from_millis(200));
        let publisher = PosePublisher::create(&domain2).expect("restarted publisher");
        publisher.publish_odom(&pose(0)).expect("publish");
        publisher
    });
    let started = Instant::now();
    let (rc, p) = sub.wait(10_000);
    assert_eq!(rc, GLINT_OK, "{}", sub.message());
    assert_eq!(p, pose(0));
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "woken, not timed out"
    );
    let publisher = restarted.join().expect("restart thread");
    publisher.publish_odom(&pose(1)).expect("publish");
    assert_eq!(sub.wait(5_000), (GLINT_OK, pose(1)));
}

#[test]
fn take_latest_skips_to_the_newest_pose() {
    let domain = Domain::new(&unique("latest")).unwrap();
    let publisher = PosePublisher::create(&domain).expect("publisher");
    let (rc, sub) = Sub::open(domain.as_str(), "map");
    assert_eq!(rc, GLINT_OK, "{}", sub.message());
    for s in 10..15 {
        publisher.publish_map(&pose(s)).expect("publish");
    }
    assert_eq!(
        sub.call(glint_pose_subscriber_take_latest),
        (GLINT_OK, pose(14))
    );
    assert_eq!(sub.take().0, GLINT_NO_DATA);
    assert!(
        sub.message().contains("no unread pose"),
        "{}",
        sub.message()
    );
}

#[test]
fn status_is_read_and_a_missing_daemon_reported() {
    let domain = Domain::new(&unique("status")).unwrap();
    let d = CString::new(domain.as_str()).unwrap();
    let mut h: *mut StatusHandle = null_mut();
    // SAFETY: NUL-terminated string; `h` is writable.
    let rc = unsafe { glint_status_subscriber_open(d.as_ptr(), &mut h) };
    assert_eq!(rc, GLINT_ERR_NOT_RUNNING);
    // SAFETY: `h` is the live handle just opened, used by this thread only.
    let message = || unsafe { CStr::from_ptr(glint_status_subscriber_last_error(h)) };
    assert!(message().to_str().unwrap().contains("/status"));

    let publisher = PosePublisher::create(&domain).expect("publisher");
    let mut published = Status::new(4, 99);
    published.sweeps_processed = 1234;
    published.latency_p99_ms = 3.5;
    published.flags = StatusFlags::TRACKING;
    let mut got = Status::new(0, 0);
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut rc = GLINT_ERR_NOT_RUNNING;
    while rc != GLINT_OK && Instant::now() < deadline {
        publisher.publish_status(&published).expect("publish");
        // SAFETY: live handle; `got` is room for one status.
        rc = unsafe { glint_status_subscriber_wait(h, 50, &mut got) };
    }
    assert_eq!(rc, GLINT_OK, "{:?}", message());
    assert_eq!(got, published);
    // SAFETY: as above.
    let rc = unsafe { glint_status_subscriber_take_latest(h, &mut got) };
    assert!(rc == GLINT_OK || rc == GLINT_NO_DATA);
    // SAFETY: closed once, not used afterwards.
    assert_eq!(unsafe { glint_status_subscriber_close(h) }, GLINT_OK);
}

#[test]
fn every_code_has_its_c_name() {
    for (code, name) in CODES {
        // SAFETY: static strings.
        assert_eq!(unsafe { CStr::from_ptr(glint_code_name(code)) }, name);
    }
    // SAFETY: static string.
    assert_eq!(
        unsafe { CStr::from_ptr(glint_code_name(-1000)) },
        c"GLINT_UNKNOWN_CODE"
    );
}
