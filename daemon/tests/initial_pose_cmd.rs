//! `glintd initial-pose` against an `InitialPoseSubscriber` created here, standing in for the
//! daemon: the hint arrives with x, y, yaw and sigma as given (negative numbers too), and
//! without a daemon, or with a NaN, the command fails saying why.

use std::process::{Command, Stdio};
use std::thread;
use std::time::{Duration, Instant};

use glint_ipc::{settings, Domain, Frame, InitialPose, InitialPoseSubscriber};

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

#[test]
fn initial_pose_command_sends_one_hint_or_says_why_not() {
    let domain = Domain::new(&format!("test-initial-pose-{}", std::process::id())).unwrap();
    let args = |extra: &[&str]| {
        let mut a = vec!["initial-pose", "--domain", domain.as_str()];
        a.extend_from_slice(extra);
        a.into_iter().map(str::to_owned).collect::<Vec<_>>()
    };

    let out = glintd().args(args(&["1", "2", "0"])).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("is glintd running with this domain?"), "{err}");

    let daemon = InitialPoseSubscriber::create(&domain).unwrap();
    let child = glintd()
        .args(args(&["-3.5", "12.25", "-1.5", "--sigma", "2"]))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Poll as the daemon does, while the command lingers.
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut got = None;
    while got.is_none() && Instant::now() < deadline {
        got = daemon.try_next().unwrap();
        thread::sleep(settings::INITIAL_POSE_MAX_POLL_INTERVAL / 5);
    }
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("to 1 subscriber(s)"), "{stdout}");
    let hint = got.expect("the hint arrived");
    assert_eq!(
        hint,
        InitialPose::on_floor(hint.timestamp_ns, -3.5, 12.25, -1.5, 2.0)
    );
    assert_eq!(hint.frame, Frame::MAP);
    assert!(hint.timestamp_ns > 1_700_000_000_000_000_000, "stamped now");

    let out = glintd().args(args(&["NaN", "2", "0"])).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("position is not finite"), "{err}");
    assert_eq!(daemon.try_next().unwrap(), None);
}
