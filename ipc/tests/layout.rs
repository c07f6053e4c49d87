//! The byte layout of the wire payloads, pinned: size, alignment and every field's offset and size
//! of `Pose`, `Status`, `InitialPose`, `SweepHeader` and `SweepPoint`, checked against one table per struct — the same tables as in
//! `ipc/README.md`, whose rows this test also finds in the README. A failure here means the
//! contract with C and Python consumers changed: bump the type name (`glint::PoseV2`) and the
//! README together, never the layout alone.

use core::mem::{align_of, offset_of, size_of, size_of_val};

use glint_ipc::{Frame, InitialPose, Pose, Status, SweepHeader, SweepPoint};

/// One README row: byte offset, size in bytes, type as the README spells it, field name.
type Row = (usize, usize, &'static str, &'static str);

const POSE_SIZE: usize = 424;
const POSE_ALIGN: usize = 8;
const POSE_LAYOUT: &[Row] = &[
    (0, 8, "u64", "sequence"),
    (8, 8, "u64", "timestamp_ns"),
    (16, 24, "f64[3]", "position"),
    (40, 32, "f64[4]", "orientation"),
    (72, 24, "f64[3]", "linear_velocity"),
    (96, 24, "f64[3]", "angular_velocity"),
    (120, 288, "f64[36]", "covariance"),
    (408, 4, "f32", "quality"),
    (412, 4, "u32", "frame"),
    (416, 4, "u32", "status"),
    (420, 4, "u32", "_pad0"),
];

const STATUS_SIZE: usize = 80;
const STATUS_ALIGN: usize = 8;
const STATUS_LAYOUT: &[Row] = &[
    (0, 8, "u64", "sequence"),
    (8, 8, "u64", "timestamp_ns"),
    (16, 8, "u64", "sweeps_processed"),
    (24, 8, "u64", "sweeps_dropped"),
    (32, 8, "u64", "packets_received"),
    (40, 8, "u64", "packets_dropped"),
    (48, 8, "u64", "packets_malformed"),
    (56, 4, "f32", "sweep_rate_hz"),
    (60, 4, "f32", "packet_rate_hz"),
    (64, 4, "f32", "latency_median_ms"),
    (68, 4, "f32", "latency_p99_ms"),
    (72, 4, "u32", "flags"),
    (76, 4, "u32", "_pad0"),
];

const INITIAL_POSE_SIZE: usize = 80;
const INITIAL_POSE_ALIGN: usize = 8;
const INITIAL_POSE_LAYOUT: &[Row] = &[
    (0, 8, "u64", "timestamp_ns"),
    (8, 24, "f64[3]", "position"),
    (32, 32, "f64[4]", "orientation"),
    (64, 8, "f64", "position_sigma"),
    (72, 4, "u32", "frame"),
    (76, 4, "u32", "_pad0"),
];

const SWEEP_HEADER_SIZE: usize = 136;
const SWEEP_HEADER_ALIGN: usize = 8;
const SWEEP_HEADER_LAYOUT: &[Row] = &[
    (0, 8, "u64", "timestamp_ns"),
    (8, 8, "u64", "sensor_time_ns"),
    (16, 8, "u64", "sequence"),
    (24, 4, "u32", "point_count"),
    (28, 4, "u32", "flags"),
    (32, 48, "f64[6]", "sensor_twist"),
    (80, 24, "f64[3]", "sensor_position"),
    (104, 32, "f64[4]", "sensor_orientation"),
];

const SWEEP_POINT_SIZE: usize = 24;
const SWEEP_POINT_ALIGN: usize = 4;
const SWEEP_POINT_LAYOUT: &[Row] = &[
    (0, 12, "f32[3]", "position"),
    (12, 4, "f32", "intensity"),
    (16, 4, "i32", "time_offset_ns"),
    (20, 2, "u16", "ring"),
    (22, 1, "u8", "reflectivity"),
    (23, 1, "u8", "label"),
];

/// `(name, offset, size)` of a public field, measured.
macro_rules! measured {
    ($value:expr, $ty:ty, $field:ident) => {
        (
            stringify!($field),
            offset_of!($ty, $field),
            size_of_val(&$value.$field),
        )
    };
}

fn assert_matches(table: &[Row], measured: &[(&str, usize, usize)], size: usize) {
    // Every public field sits where the table says.
    for (name, offset, len) in measured {
        let row = table
            .iter()
            .find(|row| row.3 == *name)
            .unwrap_or_else(|| panic!("field {name} missing from the table"));
        assert_eq!((row.0, row.1), (*offset, *len), "field {name}");
    }
    // The table tiles the struct without gaps, so the padding fields (private, not measurable
    // from here) are exactly where it says and no implicit padding exists.
    let mut next = 0;
    for (offset, len, _, name) in table {
        assert_eq!(*offset, next, "gap or overlap before {name}");
        next = offset + len;
    }
    assert_eq!(next, size, "the table does not cover the whole struct");
}

#[test]
fn pose_layout_matches_the_contract() {
    assert_eq!(size_of::<Pose>(), POSE_SIZE);
    assert_eq!(align_of::<Pose>(), POSE_ALIGN);
    let p = Pose::new(0, 0, Frame::ODOM);
    let measured = [
        measured!(p, Pose, sequence),
        measured!(p, Pose, timestamp_ns),
        measured!(p, Pose, position),
        measured!(p, Pose, orientation),
        measured!(p, Pose, linear_velocity),
        measured!(p, Pose, angular_velocity),
        measured!(p, Pose, covariance),
        measured!(p, Pose, quality),
        measured!(p, Pose, frame),
        measured!(p, Pose, status),
    ];
    assert_eq!(measured.len() + 1, POSE_LAYOUT.len(), "one padding field");
    assert_matches(POSE_LAYOUT, &measured, POSE_SIZE);
}

#[test]
fn status_layout_matches_the_contract() {
    assert_eq!(size_of::<Status>(), STATUS_SIZE);
    assert_eq!(align_of::<Status>(), STATUS_ALIGN);
    let s = Status::new(0, 0);
    let measured = [
        measured!(s, Status, sequence),
        measured!(s, Status, timestamp_ns),
        measured!(s, Status, sweeps_processed),
        measured!(s, Status, sweeps_dropped),
        measured!(s, Status, packets_received),
        measured!(s, Status, packets_dropped),
        measured!(s, Status, packets_malformed),
        measured!(s, Status, sweep_rate_hz),
        measured!(s, Status, packet_rate_hz),
        measured!(s, Status, latency_median_ms),
        measured!(s, Status, latency_p99_ms),
        measured!(s, Status, flags),
    ];
    assert_eq!(measured.len() + 1, STATUS_LAYOUT.len(), "one padding field");
    assert_matches(STATUS_LAYOUT, &measured, STATUS_SIZE);
}

#[test]
fn initial_pose_layout_matches_the_contract() {
    assert_eq!(size_of::<InitialPose>(), INITIAL_POSE_SIZE);
    assert_eq!(align_of::<InitialPose>(), INITIAL_POSE_ALIGN);
    let h = InitialPose::new(0, [0.0; 3], [0.0, 0.0, 0.0, 1.0], 0.0);
    let measured = [
        measured!(h, InitialPose, timestamp_ns),
        measured!(h, InitialPose, position),
        measured!(h, InitialPose, orientation),
        measured!(h, InitialPose, position_sigma),
        measured!(h, InitialPose, frame),
    ];
    assert_eq!(
        measured.len() + 1,
        INITIAL_POSE_LAYOUT.len(),
        "one padding field"
    );
    assert_matches(INITIAL_POSE_LAYOUT, &measured, INITIAL_POSE_SIZE);
}

#[test]
fn sweep_layouts_match_the_contract() {
    assert_eq!(size_of::<SweepHeader>(), SWEEP_HEADER_SIZE);
    assert_eq!(align_of::<SweepHeader>(), SWEEP_HEADER_ALIGN);
    let h = SweepHeader::default();
    let measured = [
        measured!(h, SweepHeader, timestamp_ns),
        measured!(h, SweepHeader, sensor_time_ns),
        measured!(h, SweepHeader, sequence),
        measured!(h, SweepHeader, point_count),
        measured!(h, SweepHeader, flags),
        measured!(h, SweepHeader, sensor_twist),
        measured!(h, SweepHeader, sensor_position),
        measured!(h, SweepHeader, sensor_orientation),
    ];
    assert_eq!(measured.len(), SWEEP_HEADER_LAYOUT.len(), "no padding");
    assert_matches(SWEEP_HEADER_LAYOUT, &measured, SWEEP_HEADER_SIZE);

    assert_eq!(size_of::<SweepPoint>(), SWEEP_POINT_SIZE);
    assert_eq!(align_of::<SweepPoint>(), SWEEP_POINT_ALIGN);
    let p = SweepPoint::default();
    let measured = [
        measured!(p, SweepPoint, position),
        measured!(p, SweepPoint, intensity),
        measured!(p, SweepPoint, time_offset_ns),
        measured!(p, SweepPoint, ring),
        measured!(p, SweepPoint, reflectivity),
        measured!(p, SweepPoint, label),
    ];
    assert_eq!(measured.len(), SWEEP_POINT_LAYOUT.len(), "no padding");
    assert_matches(SWEEP_POINT_LAYOUT, &measured, SWEEP_POINT_SIZE);
}

#[test]
fn readme_tables_state_the_same_layout() {
    let readme = include_str!("../README.md");
    for (offset, len, ty, name) in POSE_LAYOUT
        .iter()
        .chain(STATUS_LAYOUT)
        .chain(INITIAL_POSE_LAYOUT)
        .chain(SWEEP_HEADER_LAYOUT)
        .chain(SWEEP_POINT_LAYOUT)
    {
        let row = format!("| {offset} | {len} | {ty} | `{name}` |");
        assert!(readme.contains(&row), "README lacks the row {row}");
    }
    for needle in [
        format!(
            "`{}`, {POSE_SIZE} bytes, alignment {POSE_ALIGN}",
            Pose::TYPE_NAME
        ),
        format!(
            "`{}`, {STATUS_SIZE} bytes, alignment {STATUS_ALIGN}",
            Status::TYPE_NAME
        ),
        format!(
            "`{}`, {INITIAL_POSE_SIZE} bytes, alignment {INITIAL_POSE_ALIGN}",
            InitialPose::TYPE_NAME
        ),
        format!(
            "`{}`, {SWEEP_HEADER_SIZE} bytes, alignment {SWEEP_HEADER_ALIGN}",
            SweepHeader::TYPE_NAME
        ),
        format!(
            "`{}`, {SWEEP_POINT_SIZE} bytes, alignment {SWEEP_POINT_ALIGN}",
            SweepPoint::TYPE_NAME
        ),
    ] {
        assert!(readme.contains(&needle), "README lacks {needle:?}");
    }
}

#[test]
fn type_names_are_the_documented_ones() {
    assert_eq!(Pose::TYPE_NAME, "glint::PoseV1");
    assert_eq!(Status::TYPE_NAME, "glint::StatusV1");
    assert_eq!(InitialPose::TYPE_NAME, "glint::InitialPoseV1");
    assert_eq!(SweepHeader::TYPE_NAME, "glint::SweepHeaderV1");
    assert_eq!(SweepPoint::TYPE_NAME, "glint::SweepPointV1");
}
