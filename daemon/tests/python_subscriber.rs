//! The Python subscriber example (`examples/python/glint_subscriber.py`, PyPI `iceoryx2==0.10.0`)
//! against a live `glintd replay`: it must receive consecutive poses with the values the daemon
//! publishes. `.ci/run` installs the package; elsewhere the test skips with a message when it is
//! missing (under `CI=true` that is a failure).

use std::path::PathBuf;
use std::process::{Command, Stdio};

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

#[test]
fn python_subscriber_receives_consecutive_poses() {
    if !glint_testkit::python_module("iceoryx2", "pip install iceoryx2==0.10.0") {
        return;
    }
    let out = std::env::temp_dir().join(format!("glint-python-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let sim = glintd()
        .args([
            "sim",
            "warehouse",
            "--seconds",
            "20",
            "--seed",
            "12",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(sim.status.success());
    let domain = format!("test-python-{}", std::process::id());
    let mut replay = glintd()
        .args([
            "replay",
            out.join("scan.pcap").to_str().unwrap(),
            "--domain",
            &domain,
        ])
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    // Wait until poses flow, so the subscriber (which opens, never creates) finds the service.
    let ready = glintd()
        .args([
            "echo",
            "--domain",
            &domain,
            "--count",
            "1",
            "--timeout",
            "30",
            "--wait",
            "30",
        ])
        .output()
        .unwrap();
    assert!(
        ready.status.success(),
        "{}",
        String::from_utf8_lossy(&ready.stderr)
    );
    let script =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/python/glint_subscriber.py");
    let python = Command::new("python3")
        .arg(&script)
        .args(["--domain", &domain, "--count", "20", "--timeout", "30"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&python.stdout);
    assert!(
        python.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&python.stderr)
    );
    let lines: Vec<Vec<&str>> = text
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(lines.len(), 20, "{text}");
    let sequences: Vec<u64> = lines.iter().map(|l| l[0].parse().unwrap()).collect();
    for w in sequences.windows(2) {
        assert_eq!(w[1], w[0] + 1, "{sequences:?}");
    }
    for l in &lines {
        // sequence, time, x y z, qx qy qz qw, flags: finite numbers and a unit quaternion.
        let q: Vec<f64> = l[5..9].iter().map(|v| v.parse().unwrap()).collect();
        assert!(
            (q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-4,
            "{l:?}"
        );
        assert!(l[2..5]
            .iter()
            .all(|v| v.parse::<f64>().unwrap().is_finite()));
    }
    assert!(replay.wait().unwrap().success());
    std::fs::remove_dir_all(out).unwrap();
}
