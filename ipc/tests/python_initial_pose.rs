//! The Python hint sender (`examples/python/glint_initial_pose.py`, PyPI `iceoryx2==0.10.0`)
//! against an `InitialPoseSubscriber` created here, standing in for glintd: the hint must arrive
//! with the values given, bit for bit as the Rust constructor computes them, and without a
//! daemon the script must say so. `.ci/run` installs the package; elsewhere the test skips with
//! a message when python3 or iceoryx2 is missing (under `CI=true` that is a failure).

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::thread;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use glint_ipc::{settings, Domain, Frame, InitialPose, InitialPoseSubscriber};

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/python/glint_initial_pose.py")
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64
}

#[test]
fn python_sender_delivers_a_hint_or_says_no_daemon_runs() {
    if !glint_testkit::python_module("iceoryx2", "pip install iceoryx2==0.10.0") {
        return;
    }
    let domain = Domain::new(&format!("test-python-ip-{}", std::process::id())).unwrap();

    // No daemon yet: exit 2 and the reason.
    let out = Command::new("python3")
        .arg(script())
        .args(["--domain", domain.as_str(), "1", "2", "0"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("does not exist: is glintd running"), "{err}");

    let daemon = InitialPoseSubscriber::create(&domain).unwrap();
    let before = now_ns();
    let child = Command::new("python3")
        .arg(script())
        .args([
            "--domain",
            domain.as_str(),
            "-4.5",
            "7.25",
            "-2.5",
            "--sigma",
            "1.5",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Poll as glintd does, while the script lingers.
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut got = None;
    while got.is_none() && Instant::now() < deadline {
        got = daemon.try_next().unwrap();
        thread::sleep(settings::INITIAL_POSE_MAX_POLL_INTERVAL / 5);
    }
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.starts_with("sent x=-4.5 y=7.25 yaw=-2.5 sigma=1.5"),
        "{stdout}"
    );

    let hint = got.expect("the hint arrived");
    // Python's math.sin/cos are the C library's, as Rust's are: the same bits.
    let expected = InitialPose::on_floor(hint.timestamp_ns, -4.5, 7.25, -2.5, 1.5);
    assert_eq!(hint, expected);
    assert_eq!(hint.frame, Frame::MAP);
    assert!((before..=now_ns()).contains(&hint.timestamp_ns));
    assert_eq!(daemon.rejected(), 0, "{:?}", daemon.last_rejection());

    // An invalid hint never leaves the script.
    let out = Command::new("python3")
        .arg(script())
        .args(["--domain", domain.as_str(), "1", "2", "0", "--sigma", "-1"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(daemon.try_next().unwrap(), None);
}
