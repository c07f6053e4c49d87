//! The saved site map as a user drives it: a simulated run mapped with `glintd replay
//! --save-map`, checked with `glintd map info` and `map export`, then the same scene replayed
//! with `--localise` (and its `--localize` spelling): a relocalisation line on stdout, and a
//! trajectory of verified poses only, in the map frame the mapping run's own trajectory is in.
//! A map extended by a localisation run that drove on past it (`--localise MAP --save-map NEW`)
//! covers what the run added. Damaged and foreign map files are refused with a one-line error.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-sitemap-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn run(args: &[&str]) -> (Output, String, String) {
    let o = glintd().args(args).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    (o, stdout, stderr)
}

fn tum(path: &Path) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect()
}

/// Simulates a warehouse run into `dir/run` and maps it with `replay --save-map` into
/// `dir/site.glintmap` (its trajectory in `dir/mapping.tum`); the capture's path.
fn simulate_and_map(dir: &Path, seed: &str, seconds: &str) -> String {
    let d = |f: &str| dir.join(f).to_str().unwrap().to_owned();
    let (o, out, err) = run(&[
        "sim",
        "warehouse",
        "--seed",
        seed,
        "--seconds",
        seconds,
        "--out",
        &d("run"),
    ]);
    assert!(o.status.success(), "{out}{err}");
    let capture = d("run/scan.pcap");
    let (o, out, err) = run(&[
        "replay",
        &capture,
        "--no-publish",
        "--save-map",
        &d("site.glintmap"),
        "--trajectory",
        &d("mapping.tum"),
    ]);
    assert!(o.status.success(), "{out}{err}");
    assert!(out.contains("site map written to"), "{out}");
    capture
}

#[test]
fn a_mapped_run_is_saved_inspected_and_localised_in() {
    let dir = scratch("cycle");
    let d = |f: &str| dir.join(f).to_str().unwrap().to_owned();
    let capture = simulate_and_map(&dir, "11", "20");

    let (o, out, err) = run(&["map", "info", &d("site.glintmap")]);
    assert!(o.status.success(), "{out}{err}");
    assert!(
        out.contains("glintmap format 1") && out.contains("keyframes:"),
        "{out}"
    );
    assert!(out.contains("extent (map frame)"), "{out}");

    let (o, out, err) = run(&[
        "map",
        "export",
        &d("site.glintmap"),
        "--out",
        &d("site.ply"),
    ]);
    assert!(o.status.success(), "{out}{err}");
    let ply = std::fs::read(d("site.ply")).unwrap();
    assert!(
        ply.starts_with(b"ply\n") && ply.len() > 10_000,
        "{} bytes",
        ply.len()
    );

    // The same capture localised in its own map: found at once, every later sweep verified,
    // and each verified pose where the mapping run put the same sweep.
    for flag in ["--localise", "--localize"] {
        let (o, out, err) = run(&[
            "replay",
            &capture,
            "--no-publish",
            flag,
            &d("site.glintmap"),
            "--trajectory",
            &d("localised.tum"),
        ]);
        assert!(o.status.success(), "{out}{err}");
        let line = out
            .lines()
            .find(|l| l.contains("relocalised"))
            .unwrap_or_else(|| panic!("no relocalisation line: {out}"));
        let seconds: f64 = line
            .split("after ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{line}"));
        assert!(seconds <= 2.0, "{line}");
        let mapping = tum(&dir.join("mapping.tum"));
        let localised = tum(&dir.join("localised.tum"));
        assert!(
            localised.len() * 10 >= mapping.len() * 8,
            "{} of {}",
            localised.len(),
            mapping.len()
        );
        for pose in &localised {
            let same = mapping
                .iter()
                .find(|m| (m[0] - pose[0]).abs() < 1e-6)
                .expect("a sweep of the mapping run");
            let d = ((same[1] - pose[1]).powi(2)
                + (same[2] - pose[2]).powi(2)
                + (same[3] - pose[3]).powi(2))
            .sqrt();
            assert!(d < 0.1, "{pose:?} vs {same:?}: {d} m");
        }
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// The number after `keyframes:` in `glintd map info`'s report.
fn keyframes_in(map: &str) -> usize {
    let (o, out, err) = run(&["map", "info", map]);
    assert!(o.status.success(), "{out}{err}");
    out.lines()
        .find_map(|l| l.trim().strip_prefix("keyframes:"))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{out}"))
}

/// `N` in replay's "localisation: N of M sweeps verified" line.
fn verified_in(stdout: &str) -> usize {
    stdout
        .lines()
        .find_map(|l| l.strip_prefix("localisation: "))
        .and_then(|r| r.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{stdout}"))
}

#[test]
fn a_run_past_the_map_s_end_extends_it() {
    let dir = scratch("extend");
    let d = |f: &str| dir.join(f).to_str().unwrap().to_owned();
    // The first 10 s of the route mapped; the same route driven for 25 s.
    simulate_and_map(&dir, "11", "10");
    let (o, out, err) = run(&[
        "sim",
        "warehouse",
        "--seed",
        "11",
        "--seconds",
        "25",
        "--out",
        &d("longer"),
    ]);
    assert!(o.status.success(), "{out}{err}");
    let capture = d("longer/scan.pcap");
    let (o, out, err) = run(&[
        "replay",
        &capture,
        "--no-publish",
        "--localise",
        &d("site.glintmap"),
        "--save-map",
        &d("extended.glintmap"),
    ]);
    assert!(o.status.success(), "{out}{err}");
    assert!(out.contains("map extended:"), "{out}");
    let in_saved = verified_in(&out);
    let (saved, extended) = (
        keyframes_in(&d("site.glintmap")),
        keyframes_in(&d("extended.glintmap")),
    );
    assert!(extended >= saved + 5, "{saved} → {extended}: {out}");
    // The longer run again, in the extended map: verified past where the saved map ended.
    let (o, out, err) = run(&[
        "replay",
        &capture,
        "--no-publish",
        "--localise",
        &d("extended.glintmap"),
    ]);
    assert!(o.status.success(), "{out}{err}");
    let in_extended = verified_in(&out);
    assert!(
        in_extended > in_saved + 50,
        "{in_saved} → {in_extended}: {out}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn damaged_and_foreign_maps_are_refused_with_one_line() {
    let dir = scratch("refused");
    let d = |f: &str| dir.join(f).to_str().unwrap().to_owned();
    std::fs::write(d("foreign.glintmap"), b"# .PCD v0.7\nVERSION 0.7\n").unwrap();
    std::fs::write(d("empty.glintmap"), b"").unwrap();
    for (file, words) in [
        ("foreign.glintmap", "not a glintmap"),
        ("empty.glintmap", "truncated"),
        ("missing.glintmap", "missing.glintmap"),
    ] {
        let (o, out, err) = run(&["map", "info", &d(file)]);
        assert!(!o.status.success(), "{out}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(words), "{file}: {err}");
        let (o, _, err) = run(&["replay", "no-such.pcap", "--localise", &d(file)]);
        assert!(!o.status.success());
        assert!(err.contains(words), "{file}: {err}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_consumer_s_initial_pose_reaches_a_localising_daemon() {
    let dir = scratch("hint");
    let d = |f: &str| dir.join(f).to_str().unwrap().to_owned();
    let domain = format!("test-hint-{}", std::process::id());
    let capture = simulate_and_map(&dir, "12", "8");
    // Localising at the sensor's pace, publishing on a domain of its own: the hint service
    // exists while it runs.
    let daemon = glintd()
        .args([
            "replay",
            &capture,
            "--localise",
            &d("site.glintmap"),
            "--pace",
            "realtime",
            "--domain",
            &domain,
        ])
        .env("GLINT_LOG", "info")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut sent = None;
    for _ in 0..40 {
        std::thread::sleep(std::time::Duration::from_millis(250));
        let (o, out, _) = run(&["initial-pose", "--domain", &domain, "1.0", "-0.5", "0.2"]);
        if o.status.success() {
            sent = Some(out);
            break;
        }
    }
    let daemon = daemon.wait_with_output().unwrap();
    let log = String::from_utf8_lossy(&daemon.stderr);
    assert!(daemon.status.success(), "{log}");
    let sent = sent.expect("the daemon's hint service never appeared");
    assert!(sent.contains("1 subscriber"), "{sent}");
    assert!(log.contains("initial-pose hint received"), "{log}");
    std::fs::remove_dir_all(dir).unwrap();
}
