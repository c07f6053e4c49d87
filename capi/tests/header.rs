//! `include/glint.h` checked against the Rust side, not trusted: the system C compiler builds a
//! program that prints what the header defines (sizes, field offsets and sizes, result codes,
//! status flags, point labels, sweep constants, type names), and the numbers must equal
//! `size_of` / `offset_of!` on glint-ipc's structs, the codes in `error.rs`, glint-ipc's
//! `StatusFlags`, `PointLabel` and settings, and the type names the Rust structs register. The header must also compile cleanly, warnings as errors, as C99, C11 and C++11.

use core::mem::{align_of, offset_of, size_of, size_of_val};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use glint::error::CODES;
use glint_ipc::settings::SWEEP_MAX_POINTS;
use glint_ipc::{PointLabel, Pose, Status, StatusFlags, SweepHeader, SweepPoint};

fn include_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("include")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-capi-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// Compiles `source` (C or C++ by `compiler`) with `flags` and warnings as errors; returns the
/// executable.
fn compile(compiler: &str, flags: &[&str], source: &str, dir: &Path, name: &str) -> PathBuf {
    let ext = if compiler == "g++" { "cpp" } else { "c" };
    let src = dir.join(format!("{name}.{ext}"));
    std::fs::write(&src, source).expect("write source");
    let exe = dir.join(name);
    let out = Command::new(compiler)
        .args(flags)
        .args(["-Wall", "-Wextra", "-Werror", "-pedantic", "-I"])
        .arg(include_dir())
        .arg(&src)
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {compiler}: {e}"));
    assert!(
        out.status.success(),
        "{compiler} {flags:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    exe
}

/// A C program printing `key value` lines: `pose.size`, `pose.align`, `pose.<field>.offset`,
/// `pose.<field>.size`, the same for `status`, `sweep_point` and `sweep_header`, `code.<NAME>`,
/// `flag.<NAME>`, `label.<NAME>`, `const.<NAME>`, and `name.<struct>` with a type name.
fn probe_source() -> String {
    let mut s = String::from(
        "#include <glint.h>\n#include <stdio.h>\n\
         #define ALIGN(T) _Alignof(T)\n\
         #define F(tag, T, f) printf(#tag \".\" #f \".offset %zu\\n\" #tag \".\" #f \".size %zu\\n\", \
         offsetof(T, f), sizeof(((T *)0)->f))\n\
         int main(void) {\n\
         printf(\"pose.size %zu\\npose.align %zu\\n\", sizeof(glint_pose_v1), ALIGN(glint_pose_v1));\n\
         printf(\"status.size %zu\\nstatus.align %zu\\n\", sizeof(glint_status_v1), ALIGN(glint_status_v1));\n\
         printf(\"sweep_point.size %zu\\nsweep_point.align %zu\\n\", sizeof(glint_sweep_point_v1), ALIGN(glint_sweep_point_v1));\n\
         printf(\"sweep_header.size %zu\\nsweep_header.align %zu\\n\", sizeof(glint_sweep_header_v1), ALIGN(glint_sweep_header_v1));\n\
         printf(\"const.GLINT_SWEEP_MAX_POINTS %ld\\n\", (long)GLINT_SWEEP_MAX_POINTS);\n\
         printf(\"const.GLINT_SWEEP_POLL_INTERVAL_MS %ld\\n\", (long)GLINT_SWEEP_POLL_INTERVAL_MS);\n\
         printf(\"name.pose %s\\n\", GLINT_POSE_TYPE_NAME);\n\
         printf(\"name.status %s\\n\", GLINT_STATUS_TYPE_NAME);\n\
         printf(\"name.sweep_point %s\\n\", GLINT_SWEEP_POINT_TYPE_NAME);\n\
         printf(\"name.sweep_header %s\\n\", GLINT_SWEEP_HEADER_TYPE_NAME);\n",
    );
    for f in POSE_FIELDS {
        s.push_str(&format!("F(pose, glint_pose_v1, {f});\n"));
    }
    for f in STATUS_FIELDS {
        s.push_str(&format!("F(status, glint_status_v1, {f});\n"));
    }
    for f in SWEEP_POINT_FIELDS {
        s.push_str(&format!("F(sweep_point, glint_sweep_point_v1, {f});\n"));
    }
    for f in SWEEP_HEADER_FIELDS {
        s.push_str(&format!("F(sweep_header, glint_sweep_header_v1, {f});\n"));
    }
    for (_, name) in CODES {
        let name = name.to_str().expect("ASCII");
        s.push_str(&format!("printf(\"code.{name} %d\\n\", {name});\n"));
    }
    for (_, name) in FLAGS {
        s.push_str(&format!(
            "printf(\"flag.{name} %u\\n\", (unsigned)GLINT_STATUS_{name});\n"
        ));
    }
    for (_, name) in LABELS {
        s.push_str(&format!(
            "printf(\"label.{name} %u\\n\", (unsigned)GLINT_POINT_{name});\n"
        ));
    }
    s.push_str("return 0;\n}\n");
    s
}

/// Every point label bit, by its name in `glint.h` (after `GLINT_POINT_`).
const LABELS: [(PointLabel, &str); 3] = [
    (PointLabel::EDGE, "EDGE"),
    (PointLabel::PLANE, "PLANE"),
    (PointLabel::INTENSITY, "INTENSITY"),
];

const SWEEP_POINT_FIELDS: [&str; 6] = [
    "position",
    "intensity",
    "time_offset_ns",
    "ring",
    "reflectivity",
    "label",
];

const SWEEP_HEADER_FIELDS: [&str; 8] = [
    "timestamp_ns",
    "sensor_time_ns",
    "sequence",
    "point_count",
    "flags",
    "sensor_twist",
    "sensor_position",
    "sensor_orientation",
];

/// Every status flag, by its name in `glint.h` (after `GLINT_STATUS_`).
const FLAGS: [(StatusFlags, &str); 9] = [
    (StatusFlags::INITIALISING, "INITIALISING"),
    (StatusFlags::TRACKING, "TRACKING"),
    (StatusFlags::DEGENERATE, "DEGENERATE"),
    (StatusFlags::LOST, "LOST"),
    (StatusFlags::LOOP_CLOSED, "LOOP_CLOSED"),
    (StatusFlags::PREDICTED, "PREDICTED"),
    (StatusFlags::SENSOR_SILENT, "SENSOR_SILENT"),
    (StatusFlags::RELOCALISING, "RELOCALISING"),
    (StatusFlags::FOREIGN_SENSOR, "FOREIGN_SENSOR"),
];

const POSE_FIELDS: [&str; 11] = [
    "sequence",
    "timestamp_ns",
    "position",
    "orientation",
    "linear_velocity",
    "angular_velocity",
    "covariance",
    "quality",
    "frame",
    "status",
    "_pad0",
];

const STATUS_FIELDS: [&str; 13] = [
    "sequence",
    "timestamp_ns",
    "sweeps_processed",
    "sweeps_dropped",
    "packets_received",
    "packets_dropped",
    "packets_malformed",
    "sweep_rate_hz",
    "packet_rate_hz",
    "latency_median_ms",
    "latency_p99_ms",
    "flags",
    "_pad0",
];

/// What the Rust structs say, in the probe's `key value` form. `_pad0` is private in glint-ipc,
/// so its place is derived: the 4 bytes after the last public field, ending the struct.
fn rust_layout() -> BTreeMap<String, i64> {
    let mut m = BTreeMap::new();
    let mut put = |k: String, v: usize| {
        m.insert(k, i64::try_from(v).expect("small"));
    };
    let p = Pose::new(0, 0, glint_ipc::Frame::ODOM);
    macro_rules! field {
        ($tag:literal, $ty:ty, $value:expr, $f:ident) => {
            put(
                format!("{}.{}.offset", $tag, stringify!($f)),
                offset_of!($ty, $f),
            );
            put(
                format!("{}.{}.size", $tag, stringify!($f)),
                size_of_val(&$value.$f),
            );
        };
    }
    put("pose.size".into(), size_of::<Pose>());
    put("pose.align".into(), align_of::<Pose>());
    field!("pose", Pose, p, sequence);
    field!("pose", Pose, p, timestamp_ns);
    field!("pose", Pose, p, position);
    field!("pose", Pose, p, orientation);
    field!("pose", Pose, p, linear_velocity);
    field!("pose", Pose, p, angular_velocity);
    field!("pose", Pose, p, covariance);
    field!("pose", Pose, p, quality);
    field!("pose", Pose, p, frame);
    field!("pose", Pose, p, status);
    put(
        "pose._pad0.offset".into(),
        offset_of!(Pose, status) + size_of_val(&p.status),
    );
    put(
        "pose._pad0.size".into(),
        size_of::<Pose>() - offset_of!(Pose, status) - size_of_val(&p.status),
    );

    let s = Status::new(0, 0);
    put("status.size".into(), size_of::<Status>());
    put("status.align".into(), align_of::<Status>());
    field!("status", Status, s, sequence);
    field!("status", Status, s, timestamp_ns);
    field!("status", Status, s, sweeps_processed);
    field!("status", Status, s, sweeps_dropped);
    field!("status", Status, s, packets_received);
    field!("status", Status, s, packets_dropped);
    field!("status", Status, s, packets_malformed);
    field!("status", Status, s, sweep_rate_hz);
    field!("status", Status, s, packet_rate_hz);
    field!("status", Status, s, latency_median_ms);
    field!("status", Status, s, latency_p99_ms);
    field!("status", Status, s, flags);
    put(
        "status._pad0.offset".into(),
        offset_of!(Status, flags) + size_of_val(&s.flags),
    );
    put(
        "status._pad0.size".into(),
        size_of::<Status>() - offset_of!(Status, flags) - size_of_val(&s.flags),
    );
    let sp = SweepPoint::default();
    put("sweep_point.size".into(), size_of::<SweepPoint>());
    put("sweep_point.align".into(), align_of::<SweepPoint>());
    field!("sweep_point", SweepPoint, sp, position);
    field!("sweep_point", SweepPoint, sp, intensity);
    field!("sweep_point", SweepPoint, sp, time_offset_ns);
    field!("sweep_point", SweepPoint, sp, ring);
    field!("sweep_point", SweepPoint, sp, reflectivity);
    field!("sweep_point", SweepPoint, sp, label);

    let sh = SweepHeader::default();
    put("sweep_header.size".into(), size_of::<SweepHeader>());
    put("sweep_header.align".into(), align_of::<SweepHeader>());
    field!("sweep_header", SweepHeader, sh, timestamp_ns);
    field!("sweep_header", SweepHeader, sh, sensor_time_ns);
    field!("sweep_header", SweepHeader, sh, sequence);
    field!("sweep_header", SweepHeader, sh, point_count);
    field!("sweep_header", SweepHeader, sh, flags);
    field!("sweep_header", SweepHeader, sh, sensor_twist);
    field!("sweep_header", SweepHeader, sh, sensor_position);
    field!("sweep_header", SweepHeader, sh, sensor_orientation);

    put("const.GLINT_SWEEP_MAX_POINTS".into(), SWEEP_MAX_POINTS);
    put(
        "const.GLINT_SWEEP_POLL_INTERVAL_MS".into(),
        usize::try_from(glint::sweep::POLL_INTERVAL.as_millis()).expect("small"),
    );
    for (code, name) in CODES {
        m.insert(
            format!("code.{}", name.to_str().expect("ASCII")),
            i64::from(code),
        );
    }
    for (flag, name) in FLAGS {
        m.insert(format!("flag.{name}"), i64::from(flag.bits()));
    }
    for (label, name) in LABELS {
        m.insert(format!("label.{name}"), i64::from(label.0));
    }
    m
}

/// The iceoryx2 type names the Rust structs register, in the probe's `name.<struct>` form.
fn rust_type_names() -> BTreeMap<String, String> {
    [
        ("pose", Pose::TYPE_NAME),
        ("status", Status::TYPE_NAME),
        ("sweep_point", SweepPoint::TYPE_NAME),
        ("sweep_header", SweepHeader::TYPE_NAME),
    ]
    .into_iter()
    .map(|(k, v)| (format!("name.{k}"), v.to_owned()))
    .collect()
}

#[test]
fn header_layout_and_codes_equal_the_rust_side() {
    let dir = scratch("header");
    let exe = compile("gcc", &["-std=c11"], &probe_source(), &dir, "probe");
    let out = Command::new(&exe).output().expect("run the probe");
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).expect("ASCII");
    let (names, numbers): (Vec<_>, Vec<_>) = text
        .lines()
        .map(|l| l.split_once(' ').expect("key value"))
        .partition(|(k, _)| k.starts_with("name."));
    let c: BTreeMap<String, i64> = numbers
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v.parse().expect("a number")))
        .collect();
    let rust = rust_layout();
    // Same keys (no field missing on either side) and the same number for each.
    assert_eq!(c, rust);
    assert_eq!(c["pose.size"], 424);
    assert_eq!(c["status.size"], 80);
    assert_eq!(c["sweep_point.size"], 24);
    assert_eq!(c["sweep_header.size"], 136);
    let names: BTreeMap<String, String> = names
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v.to_owned()))
        .collect();
    assert_eq!(names, rust_type_names());
    // Every bit this version defines is mirrored.
    let all = FLAGS.iter().fold(StatusFlags::NONE, |a, (f, _)| a.with(*f));
    assert_eq!(all, StatusFlags::KNOWN);
    let labels = LABELS.iter().fold(PointLabel::NONE, |a, (l, _)| a.with(*l));
    assert_eq!(labels, PointLabel(0b111), "bits 3-7 are reserved");
    std::fs::remove_dir_all(dir).expect("clean up");
}

#[test]
fn header_compiles_as_c99_c11_and_cpp11_without_warnings() {
    let dir = scratch("dialects");
    let use_all = "#include <glint.h>\nint main(void) { glint_pose_v1 p; glint_status_v1 s; \
                   glint_sweep_header_v1 h; glint_sweep_point_v1 pts[2]; \
                   (void)p; (void)s; (void)h; (void)pts; \
                   return (int)sizeof(glint_pose_v1) - 424; }\n";
    for (compiler, std) in [
        ("gcc", "-std=c99"),
        ("gcc", "-std=c11"),
        ("g++", "-std=c++11"),
    ] {
        let exe = compile(compiler, &[std], use_all, &dir, &std[5..]);
        assert!(Command::new(exe).status().expect("run").success());
    }
    std::fs::remove_dir_all(dir).expect("clean up");
}

#[test]
fn a_wrong_layout_fails_to_compile() {
    // The static assertions must bite in every dialect: a header edited to shift a field is a
    // compile error, not a silent misread.
    let dir = scratch("broken");
    let header = std::fs::read_to_string(include_dir().join("glint.h")).expect("read header");
    let src = dir.join("t.c");
    std::fs::write(&src, "#include \"glint.h\"\nint main(void) { return 0; }\n").expect("write");
    // A pose field, a sweep point field and a sweep header field.
    for (good, bad) in [
        ("float quality;", "double quality;"),
        ("uint16_t ring;", "uint32_t ring;"),
        ("uint32_t point_count;", "uint64_t point_count;"),
    ] {
        let broken = header.replacen(good, bad, 1);
        assert_ne!(header, broken);
        std::fs::write(dir.join("glint.h"), broken).expect("write");
        for (compiler, std) in [
            ("gcc", "-std=c99"),
            ("gcc", "-std=c11"),
            ("g++", "-std=c++11"),
        ] {
            let out = Command::new(compiler)
                .args([
                    std,
                    "-x",
                    if compiler == "g++" { "c++" } else { "c" },
                    "-fsyntax-only",
                ])
                .arg(&src)
                .output()
                .expect("run the compiler");
            assert!(
                !out.status.success(),
                "{compiler} {std} accepted a wrong layout ({bad})"
            );
        }
    }
    std::fs::remove_dir_all(dir).expect("clean up");
}
