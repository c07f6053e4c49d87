//! `glintd info` and `glintd decode` on the real captures and on bad input: the public
//! interface (headers, counts, exit codes, one-line errors).

use std::path::PathBuf;
use std::process::{Command, Output};

use glint_testkit::shared_data;

fn glintd(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
        .args(args)
        .output()
        .expect("glintd runs")
}

/// The real capture the inspections run on, when `../shared/data` is beside the workspace.
fn real_capture() -> Option<PathBuf> {
    shared_data(
        "glintd info/decode on a real VLP-16 capture",
        "vlp16_real_short.pcap",
    )
}

fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn info_reports_the_model_disagreement_and_counts() {
    let Some(capture) = real_capture() else {
        return;
    };
    let out = glintd(&["info", capture.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("model: VLP-16 (detected)"), "{text}");
    assert!(
        text.contains("0x21 (HDL-32E)") && text.contains("overruled"),
        "{text}"
    );
    assert!(
        text.contains("84 data (port 2368), 16 position (port 8308)"),
        "{text}"
    );
    assert!(text.contains("19579 returns"), "{text}");
    assert!(text.contains("return mode: strongest"), "{text}");
}

#[test]
fn decode_writes_csv_with_the_documented_header() {
    let Some(capture) = real_capture() else {
        return;
    };
    let dir = scratch_dir("csv");
    let csv = dir.join("points.csv");
    let out = glintd(&[
        "decode",
        capture.to_str().unwrap(),
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("sweep,time_ns,ring,laser,azimuth_deg,x,y,z,reflectivity,return")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 19_579);
    let mut last_time = 0u64;
    for r in &rows {
        assert_eq!(r.len(), 10);
        let t: u64 = r[1].parse().unwrap();
        assert!(t >= last_time);
        last_time = t;
        assert!(r[2].parse::<u8>().unwrap() < 16 && r[3].parse::<u8>().unwrap() < 16);
        for v in &r[4..8] {
            assert!(v.parse::<f64>().unwrap().is_finite());
        }
        assert_eq!(r[9], "strongest");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn decode_writes_ply_with_the_same_fields() {
    let Some(capture) = real_capture() else {
        return;
    };
    let dir = scratch_dir("ply");
    let ply = dir.join("points.ply");
    let out = glintd(&[
        "decode",
        capture.to_str().unwrap(),
        "--out",
        ply.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    let bytes = std::fs::read(&ply).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.is_ascii());
    let count: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(count, 19_579);
    for field in [
        "sweep",
        "time_ns",
        "ring",
        "laser",
        "azimuth_deg",
        "x",
        "y",
        "z",
        "reflectivity",
        "return",
    ] {
        assert!(
            header
                .lines()
                .any(|l| l.starts_with("property") && l.ends_with(&format!(" {field}"))),
            "{field}"
        );
    }
    // uint + double + 2 uchar + 4 float + 2 uchar = 32 bytes per vertex.
    assert_eq!(bytes.len() - end, count * 32);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn bad_input_is_a_one_line_error_and_a_failure() {
    let dir = scratch_dir("bad");
    let foreign = dir.join("foreign.pcap");
    std::fs::write(&foreign, b"this is not a capture at all, just text\n").unwrap();
    let missing = dir.join("missing.pcap");
    for path in [&foreign, &missing] {
        for cmd in [
            vec!["info", path.to_str().unwrap()],
            vec!["decode", path.to_str().unwrap(), "--out", "/dev/null"],
        ] {
            let out = glintd(&cmd);
            assert_eq!(out.status.code(), Some(1), "{cmd:?}");
            let err = String::from_utf8(out.stderr).unwrap();
            assert_eq!(err.trim_end().lines().count(), 1, "{err}");
            assert!(err.starts_with("glintd: "), "{err}");
        }
    }
    let out = glintd(&["info", "x.pcap", "--model", "vlp99"]);
    assert_eq!(out.status.code(), Some(2), "clap rejects an unknown model");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_damaged_capture_still_yields_what_came_before() {
    let Some(capture) = real_capture() else {
        return;
    };
    let dir = scratch_dir("damaged");
    let bytes = std::fs::read(&capture).unwrap();
    let damaged = dir.join("damaged.pcap");
    std::fs::write(&damaged, &bytes[..bytes.len() / 2]).unwrap();
    let csv = dir.join("points.csv");
    let out = glintd(&[
        "decode",
        damaged.to_str().unwrap(),
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("truncated") && err.contains("byte"), "{err}");
    let rows = std::fs::read_to_string(&csv).unwrap().lines().count() - 1;
    assert!(rows > 5_000 && rows < 19_579, "{rows}");
    std::fs::remove_dir_all(dir).unwrap();
}
