//! The chain as a user runs it: `glintd demo` end to end, and a separate `glintd echo` process
//! receiving every pose a `glintd replay` publishes, in order.

use std::path::PathBuf;
use std::process::{Command, Stdio};

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-pipeline-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A domain no other test or daemon uses.
fn domain(name: &str) -> String {
    format!("test-{name}-{}", std::process::id())
}

#[test]
fn demo_runs_the_whole_chain_and_reports_accuracy() {
    let out = scratch("demo");
    let o = glintd()
        .args([
            "demo",
            "--seconds",
            "8",
            "--seed",
            "4",
            "--out",
            out.to_str().unwrap(),
            "--domain",
            &domain("demo"),
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        text.contains("drift") && text.contains("ATE RMSE"),
        "{text}"
    );
    for f in [
        "scan.pcap",
        "groundtruth.tum",
        "trajectory.tum",
        "trajectory_kitti.txt",
        "map.pcd",
        "scene.json",
    ] {
        assert!(
            out.join(f).metadata().map(|m| m.len() > 0).unwrap_or(false),
            "{f} missing"
        );
    }
    let trajectory = std::fs::read_to_string(out.join("trajectory.tum")).unwrap();
    assert!(trajectory.lines().count() >= 75, "one pose per sweep");
    std::fs::remove_dir_all(out).unwrap();
}

#[test]
fn a_separate_subscriber_receives_the_published_poses_in_order() {
    let out = scratch("echo");
    let sim = glintd()
        .args([
            "sim",
            "warehouse",
            "--seconds",
            "6",
            "--seed",
            "9",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(sim.status.success());
    let d = domain("echo");
    let echo = glintd()
        .args([
            "echo",
            "--domain",
            &d,
            "--count",
            "30",
            "--timeout",
            "60",
            "--wait",
            "30",
        ])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let replay = glintd()
        .args([
            "replay",
            out.join("scan.pcap").to_str().unwrap(),
            "--domain",
            &d,
        ])
        .stdout(Stdio::null())
        .output()
        .unwrap();
    assert!(
        replay.status.success(),
        "{}",
        String::from_utf8_lossy(&replay.stderr)
    );
    let echoed = echo.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&echoed.stdout);
    assert!(echoed.status.success(), "{text}");
    let sequences: Vec<u64> = text
        .lines()
        .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(sequences.len(), 30);
    for w in sequences.windows(2) {
        assert_eq!(w[1], w[0] + 1, "no gap, no reordering: {sequences:?}");
    }
    std::fs::remove_dir_all(out).unwrap();
}
