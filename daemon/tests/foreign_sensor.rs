//! Two sensors on one network: a capture of two simulated VLP-16s (different scenes, different
//! source addresses) interleaved by time. Only one sensor's packets are decoded: the one named
//! by `--source`, or the first to send valid data; the other's are refused, counted and flagged.

use std::collections::BTreeMap;
use std::net::Ipv4Addr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use glint_driver::pcap::{CaptureReader, CaptureWriter, UdpEndpoints};

const OURS: &str = "192.168.1.201";
const OTHER: &str = "192.168.1.202";

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-foreign-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A 5 s warehouse run of `seed` from `source`, its first firing at `start`.
fn simulate(dir: &Path, seed: &str, source: &str, start: &str) -> PathBuf {
    let o = glintd()
        .args(["sim", "warehouse", "--seconds", "5", "--seed", seed])
        .args(["--start-time", start, "--source-address", source, "--out"])
        .arg(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    dir.join("scan.pcap")
}

/// Every datagram of the captures in one, ordered by record time (the first capture's first on
/// a tie), as one network tap would have recorded both sensors.
fn merge(captures: &[&Path], out: &Path) {
    let mut records = Vec::new();
    for (i, path) in captures.iter().enumerate() {
        let mut reader = CaptureReader::open(path).unwrap();
        while let Some(d) = reader.next().unwrap() {
            let endpoints = UdpEndpoints {
                source: (d.source, d.source_port),
                destination: (Ipv4Addr::BROADCAST, d.destination_port),
            };
            records.push((d.time_ns, i, endpoints, d.payload.to_vec()));
        }
    }
    records.sort_by_key(|r| (r.0, r.1));
    let mut writer = CaptureWriter::create(out).unwrap();
    for (time_ns, _, endpoints, payload) in &records {
        writer.write_udp(*time_ns, *endpoints, payload).unwrap();
    }
    writer.finish().unwrap();
}

/// Datagrams per (source, destination port).
fn counts(path: &Path) -> BTreeMap<(String, u16), u64> {
    let mut counts = BTreeMap::new();
    let mut reader = CaptureReader::open(path).unwrap();
    while let Some(d) = reader.next().unwrap() {
        *counts
            .entry((d.source.to_string(), d.destination_port))
            .or_default() += 1;
    }
    counts
}

fn stdout_of(o: &std::process::Output) -> String {
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    text
}

/// Replays `capture` (with `args`) and returns the trajectory file's bytes and the report.
fn replay(dir: &Path, name: &str, capture: &Path, args: &[&str]) -> (Vec<u8>, String) {
    let trajectory = dir.join(name);
    let o = glintd()
        .arg("replay")
        .arg(capture)
        .args(["--no-publish", "--no-loop", "--trajectory"])
        .arg(&trajectory)
        .args(args)
        .output()
        .unwrap();
    let text = stdout_of(&o);
    (std::fs::read(&trajectory).unwrap(), text)
}

#[test]
fn only_our_sensors_packets_make_the_trajectory() {
    let dir = scratch("replay");
    let ours = simulate(&dir.join("ours"), "6", OURS, "1700000000.0");
    // The other sensor starts 37 ms later: ours sends the first valid data.
    let other = simulate(&dir.join("other"), "8", OTHER, "1700000000.037");
    let merged = dir.join("merged.pcap");
    merge(&[&ours, &other], &merged);
    let (theirs, mine) = (counts(&other), counts(&ours));
    let (other_data, other_position) =
        (theirs[&(OTHER.into(), 2368)], theirs[&(OTHER.into(), 8308)]);
    let (our_data, our_position) = (mine[&(OURS.into(), 2368)], mine[&(OURS.into(), 8308)]);

    // `info` names both sources with their packets and says which one it describes.
    let info = stdout_of(&glintd().arg("info").arg(&merged).output().unwrap());
    assert!(
        info.contains(&format!("source: {OURS} (the first to send valid data)")),
        "{info}"
    );
    assert!(
        info.contains(&format!(
            "from {OURS}: {our_data} data, {our_position} position packets (read)"
        )),
        "{info}"
    );
    assert!(
        info.contains(&format!(
            "from {OTHER}: {other_data} data, {other_position} position packets (refused)"
        )),
        "{info}"
    );
    // The sweeps are ours alone: 10 Hz over 5 s, not the two sensors' azimuths interleaved.
    let sweeps: u64 = info
        .lines()
        .find_map(|l| l.strip_prefix("sweeps: "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no sweep count: {info}"));
    assert!((49..=52).contains(&sweeps), "{info}");

    // The trajectory of our sensor alone, byte for byte, whether ours is named or locked onto.
    let (alone, alone_report) = replay(&dir, "alone.tum", &ours, &[]);
    assert!(alone.len() > 1000);
    assert!(
        !alone_report.contains("other sensors"),
        "one sensor, nothing refused: {alone_report}"
    );
    let (named, _) = replay(&dir, "named.tum", &merged, &["--source", OURS]);
    assert!(
        named == alone,
        "--source {OURS} differs from our sensor alone"
    );
    let (locked, report) = replay(&dir, "locked.tum", &merged, &[]);
    assert!(locked == alone, "locking on differs from our sensor alone");
    assert!(
        report.contains(&format!(
            "other sensors: {other_data} data and {other_position} position packets refused"
        )),
        "{report}"
    );
    assert!(
        report.contains(&format!("source: {OURS} (the first to send valid data)")),
        "{report}"
    );

    // Naming the other sensor reads it instead, as if it were alone.
    let (theirs_alone, _) = replay(&dir, "other-alone.tum", &other, &[]);
    let (theirs_named, _) = replay(&dir, "other-named.tum", &merged, &["--source", OTHER]);
    assert!(theirs_named == theirs_alone);
    assert!(theirs_named != alone);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn refused_packets_flag_the_published_poses() {
    let dir = scratch("flag");
    let ours = simulate(&dir.join("ours"), "6", OURS, "1700000000.0");
    let other = simulate(&dir.join("other"), "8", OTHER, "1700000000.037");
    let merged = dir.join("merged.pcap");
    merge(&[&ours, &other], &merged);
    let domain = format!("test-foreign-{}", std::process::id());
    let echo = |count: &str| {
        glintd()
            .args(["echo", "--domain", &domain, "--count", count])
            .args(["--timeout", "60", "--wait", "30"])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let run = |capture: &Path| {
        let o = glintd()
            .arg("replay")
            .arg(capture)
            .args(["--no-loop", "--domain", &domain])
            .stdout(Stdio::null())
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let subscriber = echo("20");
    run(&merged);
    let lines = stdout_of(&subscriber.wait_with_output().unwrap());
    assert_eq!(lines.lines().count(), 20);
    assert!(
        lines.lines().all(|l| l.contains("FOREIGN_SENSOR")),
        "{lines}"
    );
    // One sensor alone: never flagged.
    let subscriber = echo("20");
    run(&ours);
    let lines = stdout_of(&subscriber.wait_with_output().unwrap());
    assert!(!lines.contains("FOREIGN_SENSOR"), "{lines}");
    std::fs::remove_dir_all(&dir).unwrap();
}
