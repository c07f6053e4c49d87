//! The chain as a user runs it: `glintd demo` end to end, a separate `glintd echo` process
//! receiving every pose a `glintd replay` publishes, in order, `glintd bench`, and `replay`
//! taking its parameters from a daemon configuration.

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

/// A short simulated warehouse capture in `dir`.
fn simulate(dir: &std::path::Path, seconds: &str) -> PathBuf {
    let o = glintd()
        .args([
            "sim",
            "warehouse",
            "--seed",
            "6",
            "--seconds",
            seconds,
            "--out",
        ])
        .arg(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    dir.join("scan.pcap")
}

#[test]
fn bench_times_every_stage_on_one_thread() {
    let dir = scratch("bench");
    let capture = simulate(&dir, "3");
    let o = glintd().arg("bench").arg(&capture).output().unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let sweeps: usize = text
        .split_whitespace()
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no sweep count: {text}"));
    assert!((25..=31).contains(&sweeps), "{text}");
    assert!(text.contains("with intensity"), "{text}");
    for stage in [
        "per sweep: median",
        "calibration + features: median",
        "deskew: median",
        "alignment: median",
        "map update: median",
    ] {
        assert!(text.contains(stage), "{stage} missing: {text}");
    }
    let geometry = glintd()
        .arg("bench")
        .arg(&capture)
        .arg("--no-intensity")
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&geometry.stdout).contains("geometry only"));
    let missing = glintd()
        .args(["bench", "/nonexistent/capture.pcap"])
        .output()
        .unwrap();
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("capture.pcap"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn replay_takes_its_parameters_from_a_daemon_config() {
    let dir = scratch("replay-config");
    let capture = simulate(&dir, "3");
    let replay = |config: &str| {
        let path = dir.join("glintd.toml");
        std::fs::write(&path, config).unwrap();
        glintd()
            .arg("replay")
            .arg(&capture)
            .args(["--no-publish", "--config"])
            .arg(&path)
            .output()
            .unwrap()
    };
    let defaults = replay("");
    let text = String::from_utf8_lossy(&defaults.stdout);
    assert!(defaults.status.success(), "{text}");
    assert!(
        text.contains("with intensity") && text.contains("back end:"),
        "{text}"
    );
    let ablation = replay("[pipeline]\nintensity = false\nloop_closure = false\n");
    let text = String::from_utf8_lossy(&ablation.stdout);
    assert!(ablation.status.success(), "{text}");
    assert!(
        text.contains("geometry only") && !text.contains("back end:"),
        "{text}"
    );
    let wrong = replay("[odometry.solver]\nouter_iteration = 3\n");
    assert!(!wrong.status.success());
    let message = String::from_utf8_lossy(&wrong.stderr);
    assert!(message.contains("outer_iteration"), "{message}");
    std::fs::remove_dir_all(dir).unwrap();
}
