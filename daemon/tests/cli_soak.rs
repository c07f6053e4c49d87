//! `glintd soak` as `scripts/soak.sh` drives it, kept short: a simulated sensor in process
//! through the whole pipeline, a CSV with one row per sampling interval whose counts add up,
//! in SLAM mode and localising in a map of the same scene.

use std::path::PathBuf;
use std::process::Command;

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn scratch() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-soak-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs a soak; its stdout and the CSV's rows as columns by name.
fn soak(args: &[&str], csv: &PathBuf) -> (String, Vec<std::collections::HashMap<String, f64>>) {
    let out = glintd()
        .args(["soak", "--no-publish", "--csv"])
        .arg(csv)
        .args(args)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(',').map(|v| v.parse::<f64>().unwrap()))
                .collect()
        })
        .collect();
    (stdout, rows)
}

/// The summary counts the sweeps asked for (one more when the run's first, partial sweep is
/// published as well).
fn assert_swept(stdout: &str, sweeps: u64) {
    let done: u64 = stdout
        .split("soak done: ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no summary:\n{stdout}"));
    assert!(
        (sweeps..=sweeps + 1).contains(&done),
        "{done} sweeps:\n{stdout}"
    );
}

#[test]
fn a_short_soak_samples_every_interval_in_both_modes() {
    let dir = scratch();
    let csv = dir.join("slam.csv");
    let (stdout, rows) = soak(
        &[
            "--scenario",
            "warehouse",
            "--seed",
            "6",
            "--sweeps",
            "250",
            "--every",
            "0.5",
        ],
        &csv,
    );
    assert_swept(&stdout, 250);
    assert!(stdout.contains("back end: "), "{stdout}");
    assert!(rows.len() >= 2, "{} samples:\n{stdout}", rows.len());
    for pair in rows.windows(2) {
        assert!(pair[1]["sweeps"] > pair[0]["sweeps"]);
        assert!(pair[1]["sensor_s"] > pair[0]["sensor_s"]);
        assert!(pair[1]["distance_m"] >= pair[0]["distance_m"]);
    }
    let last = rows.last().unwrap();
    // The robot drives at about 1.2 m/s; sensor time is the sweeps at 10 Hz.
    assert!(
        (last["sensor_s"] - 0.1 * (last["sweeps"] - 1.0)).abs() < 0.15,
        "{last:?}"
    );
    let speed = last["distance_m"] / last["sensor_s"];
    assert!((0.5..2.5).contains(&speed), "{speed} m/s");
    for r in &rows {
        assert!(r["rss_mib"] > 1.0 && r["cpu_ms_per_sweep"] > 0.0, "{r:?}");
        assert_eq!(r["lost"], 0.0, "{r:?}");
    }

    // Localising in a map of the same scene: poses verified in it.
    let site = dir.join("site");
    let status = glintd()
        .args([
            "sim",
            "warehouse",
            "--seed",
            "6",
            "--seconds",
            "20",
            "--out",
        ])
        .arg(&site)
        .output()
        .unwrap();
    assert!(status.status.success());
    let map = dir.join("site.glintmap");
    let status = glintd()
        .arg("replay")
        .arg(site.join("scan.pcap"))
        .args(["--no-publish", "--save-map"])
        .arg(&map)
        .output()
        .unwrap();
    assert!(status.status.success());
    let (stdout, rows) = soak(
        &[
            "--seed",
            "6",
            "--sweeps",
            "150",
            "--every",
            "0.5",
            "--localise",
            map.to_str().unwrap(),
        ],
        &dir.join("localisation.csv"),
    );
    assert_swept(&stdout, 150);
    let verified: f64 = rows.iter().map(|r| r["verified"]).sum();
    assert!(verified > 50.0, "{verified} verified:\n{stdout}");
    std::fs::remove_dir_all(&dir).unwrap();
}
