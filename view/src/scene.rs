//! What the viewer logs, and where: Glint's poses, sweeps and status turned into rerun
//! entities on the `sensor_time` timeline (the poses' own stamps, so a recording scrubs like the
//! run). The world is the `map` frame, z up.
//!
//! - `world/robot`: `base_link`'s `map` pose; `world/robot/sweep` the current sweep in
//!   `base_link`, coloured by calibrated reflectivity, and `world/robot/features` its edge, plane
//!   and intensity points by class;
//! - `world/trajectory/{map,odom}`: the paths in the two frames;
//! - `world/map`: the map on a voxel grid, refreshed every [`REFRESH_NS`] of sensor time: the
//!   daemon's keyframes placed at their latest poses when it publishes `map_update` (so a loop
//!   closure straightens it), else the sweeps' returns gathered at tracked `map` poses around the
//!   robot; `topdown/` the same seen from above;
//! - `world/keyframes`: the keyframes' positions, `world/keyframes/odometry` the chain joining
//!   them and `world/keyframes/loops` the loop closures, as lines;
//! - `tracking/state`: a line whenever the `map` pose's state changes; `metrics/*`: time series.

use std::collections::{BTreeMap, HashMap, VecDeque};

use anyhow::Result;
use glint_ipc::{
    KeyframePose, MapContent, MapEdge, MapPoint, MapUpdate, PointLabel, Pose, PoseStream, Status,
    StatusFlags, SweepHeader, SweepPoint,
};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};
use rerun::RecordingStream;

use crate::colour;

/// The timeline every entity is logged on: the sensor's instant of the pose or sweep.
pub const TIMELINE: &str = "sensor_time";
/// How often the gathered map and the top-down view are logged again, ns of sensor time.
pub const REFRESH_NS: u64 = 2_000_000_000;
/// Edge of a cell of the gathered map, m.
const VOXEL_M: f32 = 0.3;
/// Cells of the gathered map at most; beyond it, those farthest from the robot go.
const MAX_VOXELS: usize = 120_000;
/// Trajectory points kept per frame; beyond it, every other one of the older half goes.
const MAX_TRACK: usize = 20_000;
/// Poses remembered to place a sweep that arrives after its pose.
const RECENT_POSES: usize = 64;

/// What was logged.
#[derive(Debug, Default, Clone, Copy)]
pub struct Counts {
    pub sweeps: u64,
    pub odom: u64,
    pub map: u64,
    pub status: u64,
    pub map_updates: u64,
}

/// One reflectivity cell of the gathered map: the running mean of its returns.
#[derive(Debug, Clone, Copy)]
struct Cell {
    sum: [f32; 3],
    eta_sum: f32,
    eta_count: u32,
    count: u32,
}

/// The daemon's map as keyframes (`map_update`): each keyframe's cloud in its sensor frame and
/// its latest pose.
#[derive(Debug, Default)]
struct KeyframeMap {
    map_id: u64,
    poses: BTreeMap<u32, KeyframePose>,
    clouds: HashMap<u32, Vec<MapPoint>>,
    /// Clouds whose last part has not arrived.
    partial: HashMap<u32, Vec<MapPoint>>,
    edges: Vec<MapEdge>,
    /// Changed since it was last logged.
    changed: bool,
}

impl KeyframeMap {
    fn take(&mut self, update: MapUpdate) {
        let h = update.header;
        if h.map_id != self.map_id {
            // Another map (the daemon restarted): what was held belongs to the old one.
            *self = Self {
                map_id: h.map_id,
                ..Self::default()
            };
        }
        match update.content {
            MapContent::Cloud(points) => {
                let held = self.partial.entry(h.keyframe).or_default();
                if h.part == 0 {
                    held.clear();
                }
                held.extend(points);
                if h.part + 1 >= h.parts {
                    let whole = self.partial.remove(&h.keyframe).unwrap_or_default();
                    self.clouds.insert(h.keyframe, whole);
                }
            }
            MapContent::KeyframePoses(poses) => {
                for p in poses {
                    self.poses.insert(p.keyframe, p);
                }
            }
            MapContent::Edges(edges) => self.edges = edges,
            MapContent::Unreadable => return,
        }
        self.changed = true;
    }

    fn position(&self, keyframe: u32) -> Option<[f32; 3]> {
        self.poses
            .get(&keyframe)
            .map(|p| p.position.map(|v| v as f32))
    }

    /// Every cloud at its keyframe's pose, on the voxel grid.
    fn cells(&self) -> HashMap<[i32; 3], Cell> {
        let mut cells = HashMap::new();
        for (k, cloud) in &self.clouds {
            let Some(p) = self.poses.get(k) else { continue };
            let pose = isometry(p.position, p.orientation);
            for c in cloud {
                let local = Point3::from(c.position.map(f64::from));
                add_to_cell(&mut cells, &(pose * local), c.intensity);
            }
        }
        cells
    }
}

/// A position and an `[x, y, z, w]` quaternion (as every Glint payload has them) as a pose.
fn isometry(position: [f64; 3], [x, y, z, w]: [f64; 4]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(position[0], position[1], position[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
    )
}

/// Adds a return at `w` (map frame) with calibrated reflectivity `eta` to its cell.
fn add_to_cell(cells: &mut HashMap<[i32; 3], Cell>, w: &Point3<f64>, eta: f32) {
    let w = [w.x as f32, w.y as f32, w.z as f32];
    let key = w.map(|v| (v / VOXEL_M).floor() as i32);
    let cell = cells.entry(key).or_insert(Cell {
        sum: [0.0; 3],
        eta_sum: 0.0,
        eta_count: 0,
        count: 0,
    });
    for (sum, v) in cell.sum.iter_mut().zip(w) {
        *sum += v;
    }
    cell.count += 1;
    if eta.is_finite() {
        cell.eta_sum += eta;
        cell.eta_count += 1;
    }
}

pub struct Scene {
    rec: RecordingStream,
    keyframes: KeyframeMap,
    counts: Counts,
    map_poses: VecDeque<(u64, Isometry3<f64>)>,
    map_track: Vec<[f32; 3]>,
    odom_track: Vec<[f32; 3]>,
    cells: HashMap<[i32; 3], Cell>,
    /// The keyframe map's cells, rebuilt when it changed; empty until it has clouds.
    keyframe_cells: HashMap<[i32; 3], Cell>,
    last_state: Option<&'static str>,
    robot: Option<[f32; 3]>,
    /// Sensor time of the newest pose or sweep, ns: where status lines are logged.
    now_ns: u64,
    next_refresh_ns: u64,
}

impl Scene {
    /// Logs the static parts (axes, classes, series styles) and starts empty.
    pub fn new(rec: RecordingStream) -> Result<Self> {
        rec.log_static("world", &rerun::ViewCoordinates::RIGHT_HAND_Z_UP())?;
        rec.log_static(
            "world",
            &rerun::AnnotationContext::new(colour::CLASSES.map(|(id, label, rgb)| {
                (id, label, rerun::Rgba32::from_rgb(rgb[0], rgb[1], rgb[2]))
            })),
        )?;
        rec.log_static("world/robot", &rerun::TransformAxes3D::new(0.6))?;
        for (path, name) in SERIES {
            rec.log_static(path, &rerun::SeriesLines::new().with_names([name]))?;
        }
        Ok(Self {
            rec,
            counts: Counts::default(),
            map_poses: VecDeque::new(),
            map_track: Vec::new(),
            odom_track: Vec::new(),
            cells: HashMap::new(),
            keyframes: KeyframeMap::default(),
            keyframe_cells: HashMap::new(),
            last_state: None,
            robot: None,
            now_ns: 0,
            next_refresh_ns: 0,
        })
    }

    pub fn counts(&self) -> Counts {
        self.counts
    }

    fn at(&mut self, timestamp_ns: u64) {
        self.now_ns = self.now_ns.max(timestamp_ns);
        self.rec
            .set_timestamp_nanos_since_epoch(TIMELINE, clamp_i64(timestamp_ns));
    }

    pub fn on_pose(&mut self, stream: PoseStream, pose: &Pose) {
        if pose.first_non_finite_field().is_some() {
            return;
        }
        self.at(pose.timestamp_ns);
        let position = pose.position.map(|v| v as f32);
        let result = match stream {
            PoseStream::Map => self.on_map_pose(pose, position),
            PoseStream::Odom => {
                self.counts.odom += 1;
                push_track(&mut self.odom_track, position);
                Ok(())
            }
            PoseStream::Predicted => Ok(()),
        };
        if let Err(e) = result {
            eprintln!("glint-view: cannot log a pose: {e}");
        }
    }

    fn on_map_pose(&mut self, pose: &Pose, position: [f32; 3]) -> Result<()> {
        self.counts.map += 1;
        let flags = pose.status;
        let state = state_name(flags);
        if self.last_state != Some(state) {
            self.last_state = Some(state);
            let level = match state {
                "TRACKING" => rerun::TextLogLevel::INFO,
                "LOST" => rerun::TextLogLevel::ERROR,
                _ => rerun::TextLogLevel::WARN,
            };
            self.rec.log(
                "tracking/state",
                &rerun::TextLog::new(format!("{state} ({flags})")).with_level(level),
            )?;
        }
        if flags.contains(StatusFlags::LOOP_CLOSED) {
            self.rec.log(
                "tracking/state",
                &rerun::TextLog::new("the map pose jumped (loop closed or relocalised)")
                    .with_level(rerun::TextLogLevel::INFO),
            )?;
        }
        let tracked = is_tracked(flags);
        self.rec.log(
            "metrics/tracking",
            &rerun::Scalars::single(if tracked { 1.0 } else { 0.0 }),
        )?;
        self.rec.log(
            "metrics/degenerate",
            &rerun::Scalars::single(if flags.contains(StatusFlags::DEGENERATE) {
                1.0
            } else {
                0.0
            }),
        )?;
        let sigma = (0..3)
            .map(|i| pose.covariance[i * 7])
            .fold(0.0f64, f64::max)
            .sqrt();
        self.rec
            .log("metrics/position_sigma_m", &rerun::Scalars::single(sigma))?;
        self.rec.log(
            "metrics/quality",
            &rerun::Scalars::single(f64::from(pose.quality)),
        )?;

        let q = pose.orientation;
        self.rec.log(
            "world/robot",
            &rerun::Transform3D::from_translation_rotation(
                position,
                rerun::Quaternion::from_xyzw(q.map(|v| v as f32)),
            ),
        )?;
        self.robot = Some(position);
        push_track(&mut self.map_track, position);
        // Only a tracked pose places its sweep in the gathered map: one still relocalising or
        // lost is not known to be in the map's frame.
        if tracked {
            self.map_poses
                .push_back((pose.timestamp_ns, isometry(pose.position, pose.orientation)));
            if self.map_poses.len() > RECENT_POSES {
                self.map_poses.pop_front();
            }
        }
        Ok(())
    }

    pub fn on_status(&mut self, status: &Status) {
        // A status describes the daemon now: log it at the newest sensor instant seen.
        if self.now_ns == 0 {
            return;
        }
        self.at(self.now_ns);
        self.counts.status += 1;
        let series = [
            (
                "metrics/latency_median_ms",
                f64::from(status.latency_median_ms),
            ),
            ("metrics/latency_p99_ms", f64::from(status.latency_p99_ms)),
            ("metrics/sweeps_dropped", status.sweeps_dropped as f64),
        ];
        for (path, value) in series {
            if let Err(e) = self.rec.log(path, &rerun::Scalars::single(value)) {
                eprintln!("glint-view: cannot log the status: {e}");
                return;
            }
        }
    }

    pub fn on_sweep(&mut self, header: &SweepHeader, points: &[SweepPoint]) {
        self.at(header.timestamp_ns);
        self.counts.sweeps += 1;
        if let Err(e) = self.log_sweep(points) {
            eprintln!("glint-view: cannot log a sweep: {e}");
        }
        if let Some(pose) = self.map_pose_at(header.timestamp_ns) {
            self.gather(&pose, points);
        }
    }

    fn log_sweep(&mut self, points: &[SweepPoint]) -> Result<()> {
        let finite = |p: &&SweepPoint| p.position.iter().all(|v| v.is_finite());
        self.rec.log(
            "world/robot/sweep",
            &rerun::Points3D::new(points.iter().filter(finite).map(|p| p.position))
                .with_colors(points.iter().filter(finite).map(|p| {
                    let [r, g, b] = colour::reflectivity(p.intensity);
                    rerun::Color::from_rgb(r, g, b)
                }))
                .with_radii([rerun::Radius::new_ui_points(1.5)]),
        )?;
        let features: Vec<(&SweepPoint, u16)> = points
            .iter()
            .filter(finite)
            .filter_map(|p| class_of(p.label).map(|c| (p, c)))
            .collect();
        self.rec.log(
            "world/robot/features",
            &rerun::Points3D::new(features.iter().map(|(p, _)| p.position))
                .with_class_ids(features.iter().map(|(_, c)| *c))
                .with_radii([rerun::Radius::new_ui_points(3.0)]),
        )?;
        // In thousands, so one plot holds it beside latencies of a few milliseconds.
        self.rec.log(
            "metrics/points",
            &rerun::Scalars::single(points.len() as f64 / 1000.0),
        )?;
        Ok(())
    }

    /// The tracked `map` pose of `base_link` at `timestamp_ns`, if it has arrived.
    fn map_pose_at(&self, timestamp_ns: u64) -> Option<Isometry3<f64>> {
        self.map_poses
            .iter()
            .rev()
            .find(|(t, _)| *t == timestamp_ns)
            .map(|(_, pose)| *pose)
    }

    /// Adds a sweep's returns, placed at `pose`, to the gathered map.
    fn gather(&mut self, pose: &Isometry3<f64>, points: &[SweepPoint]) {
        for p in points {
            if !p.position.iter().all(|v| v.is_finite()) {
                continue;
            }
            let local = Point3::new(
                f64::from(p.position[0]),
                f64::from(p.position[1]),
                f64::from(p.position[2]),
            );
            add_to_cell(&mut self.cells, &(pose * local), p.intensity);
        }
        if self.cells.len() > MAX_VOXELS {
            self.evict_far_cells();
        }
    }

    /// Drops the cells farthest from the robot until a tenth of the budget is free.
    fn evict_far_cells(&mut self) {
        let Some(robot) = self.robot else {
            return;
        };
        let centre = robot.map(|v| (v / VOXEL_M).floor() as i64);
        let mut distances: Vec<(i64, [i32; 3])> = self
            .cells
            .keys()
            .map(|k| {
                let d: i64 = (0..3).map(|i| (i64::from(k[i]) - centre[i]).pow(2)).sum();
                (d, *k)
            })
            .collect();
        let keep = MAX_VOXELS - MAX_VOXELS / 10;
        distances.select_nth_unstable(keep);
        for (_, key) in &distances[keep..] {
            self.cells.remove(key);
        }
    }

    /// Logs the gathered map, the trajectories and the top-down view again when
    /// [`REFRESH_NS`] of sensor time passed since the last time.
    pub fn refresh_if_due(&mut self) {
        if self.now_ns < self.next_refresh_ns || self.now_ns == 0 {
            return;
        }
        self.next_refresh_ns = self.now_ns + REFRESH_NS;
        if let Err(e) = self.refresh() {
            eprintln!("glint-view: cannot log the map: {e}");
        }
    }

    /// The last refresh, so a recording ends with the whole map and path.
    pub fn finish(&mut self) {
        if self.now_ns == 0 {
            return;
        }
        self.at(self.now_ns);
        if let Err(e) = self.refresh() {
            eprintln!("glint-view: cannot log the map: {e}");
        }
    }

    /// Takes a `map_update` message; it shows at the next refresh.
    pub fn on_map_update(&mut self, update: MapUpdate) {
        self.counts.map_updates += 1;
        self.keyframes.take(update);
    }

    /// The keyframes, the odometry chain between them and the loops.
    fn log_keyframes(&self) -> Result<()> {
        let k = &self.keyframes;
        let positions: Vec<[f32; 3]> = k
            .poses
            .values()
            .map(|p| p.position.map(|v| v as f32))
            .collect();
        self.rec.log(
            "world/keyframes",
            &rerun::Points3D::new(positions.iter().copied())
                .with_radii([rerun::Radius::new_ui_points(3.0)])
                .with_colors([rerun::Color::from_rgb(250, 200, 40)]),
        )?;
        self.rec.log(
            "world/keyframes/odometry",
            &rerun::LineStrips3D::new([positions])
                .with_colors([rerun::Color::from_rgb(200, 200, 200)]),
        )?;
        let loops: Vec<Vec<[f32; 3]>> = k
            .edges
            .iter()
            .filter_map(|e| Some(vec![k.position(e.from)?, k.position(e.to)?]))
            .collect();
        self.rec.log(
            "world/keyframes/loops",
            &rerun::LineStrips3D::new(loops)
                .with_colors([rerun::Color::from_rgb(240, 60, 200)])
                .with_radii([rerun::Radius::new_ui_points(2.0)]),
        )?;
        Ok(())
    }

    fn refresh(&mut self) -> Result<()> {
        self.at(self.now_ns);
        if self.keyframes.changed {
            self.keyframes.changed = false;
            self.keyframe_cells = self.keyframes.cells();
            self.log_keyframes()?;
        }
        // The daemon's own map when it publishes one: placed at optimised poses, it is
        // straightened by every loop closure, where the gathered one keeps both sides of a drift.
        let cells = if self.keyframe_cells.is_empty() {
            &self.cells
        } else {
            &self.keyframe_cells
        };
        let (centres, colors): (Vec<[f32; 3]>, Vec<rerun::Color>) = cells
            .values()
            .map(|c| {
                let n = c.count as f32;
                let eta = if c.eta_count > 0 {
                    c.eta_sum / c.eta_count as f32
                } else {
                    f32::NAN
                };
                let [r, g, b] = colour::reflectivity(eta);
                (c.sum.map(|s| s / n), rerun::Color::from_rgb(r, g, b))
            })
            .unzip();
        self.rec.log(
            "world/map",
            &rerun::Points3D::new(centres.iter().copied())
                .with_colors(colors.iter().copied())
                .with_radii([rerun::Radius::new_scene_units(VOXEL_M * 0.4)]),
        )?;
        for (path, track) in [
            ("world/trajectory/map", &self.map_track),
            ("world/trajectory/odom", &self.odom_track),
        ] {
            if track.len() >= 2 {
                self.rec
                    .log(path, &rerun::LineStrips3D::new([track.clone()]))?;
            }
        }
        // Top-down: image axes point down, so y is mirrored to keep the map's left on the left.
        let flat = |p: &[f32; 3]| [p[0], -p[1]];
        self.rec.log(
            "topdown/map",
            &rerun::Points2D::new(centres.iter().map(flat))
                .with_colors(colors)
                .with_radii([rerun::Radius::new_scene_units(VOXEL_M * 0.5)]),
        )?;
        if self.map_track.len() >= 2 {
            self.rec.log(
                "topdown/trajectory",
                &rerun::LineStrips2D::new([self.map_track.iter().map(flat).collect::<Vec<_>>()]),
            )?;
        }
        if let Some(robot) = self.robot {
            self.rec.log(
                "topdown/robot",
                &rerun::Points2D::new([flat(&robot)])
                    .with_radii([rerun::Radius::new_ui_points(6.0)])
                    .with_colors([rerun::Color::from_rgb(230, 60, 50)]),
            )?;
        }
        Ok(())
    }
}

/// The time series and their legends.
const SERIES: [(&str, &str); 8] = [
    ("metrics/latency_median_ms", "latency, median (ms)"),
    ("metrics/latency_p99_ms", "latency, p99 (ms)"),
    ("metrics/sweeps_dropped", "sweeps dropped"),
    ("metrics/tracking", "tracking (1) or not (0)"),
    ("metrics/degenerate", "degenerate (1) or not (0)"),
    ("metrics/position_sigma_m", "largest position σ (m)"),
    ("metrics/quality", "match quality"),
    ("metrics/points", "points per sweep (thousands)"),
];

/// The class of a labelled point (an edge wins over a plane, a plane over intensity).
fn class_of(label: PointLabel) -> Option<u16> {
    [PointLabel::EDGE, PointLabel::PLANE, PointLabel::INTENSITY]
        .iter()
        .zip(colour::CLASSES)
        .find(|(bit, _)| label.contains(**bit))
        .map(|(_, (id, _, _))| id)
}

/// Whether a `map` pose is tracked in the map: neither lost nor still relocalising.
fn is_tracked(flags: StatusFlags) -> bool {
    flags.contains(StatusFlags::TRACKING)
        && !flags.intersects(StatusFlags::LOST.with(StatusFlags::RELOCALISING))
}

/// The state a `map` pose's flags describe, most severe first.
fn state_name(flags: StatusFlags) -> &'static str {
    if flags.contains(StatusFlags::LOST) {
        "LOST"
    } else if flags.contains(StatusFlags::RELOCALISING) {
        "RELOCALISING"
    } else if flags.contains(StatusFlags::INITIALISING) {
        "INITIALISING"
    } else if flags.contains(StatusFlags::TRACKING) {
        "TRACKING"
    } else {
        "NOT TRACKING"
    }
}

/// Appends to a trajectory, thinning its older half when it is full.
fn push_track(track: &mut Vec<[f32; 3]>, p: [f32; 3]) {
    track.push(p);
    if track.len() > MAX_TRACK {
        let half = track.len() / 2;
        let thinned: Vec<[f32; 3]> = track[..half]
            .iter()
            .step_by(2)
            .chain(track[half..].iter())
            .copied()
            .collect();
        *track = thinned;
    }
}

fn clamp_i64(ns: u64) -> i64 {
    i64::try_from(ns).unwrap_or(i64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_is_classed_by_its_strongest_label() {
        assert_eq!(class_of(PointLabel::NONE), None);
        assert_eq!(class_of(PointLabel::EDGE), Some(1));
        assert_eq!(class_of(PointLabel::PLANE), Some(2));
        assert_eq!(class_of(PointLabel::INTENSITY), Some(3));
        assert_eq!(
            class_of(PointLabel::PLANE.with(PointLabel::INTENSITY)),
            Some(2)
        );
    }

    #[test]
    fn the_state_names_the_most_severe_flag() {
        let t = StatusFlags::TRACKING;
        assert_eq!(state_name(t), "TRACKING");
        assert_eq!(state_name(t.with(StatusFlags::DEGENERATE)), "TRACKING");
        assert_eq!(state_name(StatusFlags::RELOCALISING), "RELOCALISING");
        assert_eq!(state_name(t.with(StatusFlags::LOST)), "LOST");
        assert_eq!(state_name(StatusFlags::NONE), "NOT TRACKING");
        assert!(is_tracked(t.with(StatusFlags::DEGENERATE)));
        assert!(!is_tracked(t.with(StatusFlags::LOST)));
        assert!(!is_tracked(t.with(StatusFlags::RELOCALISING)));
        assert!(!is_tracked(StatusFlags::INITIALISING));
    }

    #[test]
    fn a_full_track_keeps_its_ends_and_thins_its_past() {
        let mut track = Vec::new();
        for i in 0..=MAX_TRACK {
            push_track(&mut track, [i as f32, 0.0, 0.0]);
        }
        assert!(track.len() < MAX_TRACK * 3 / 4 + 2, "{}", track.len());
        assert_eq!(track[0], [0.0, 0.0, 0.0]);
        assert_eq!(*track.last().unwrap(), [MAX_TRACK as f32, 0.0, 0.0]);
        assert!(track.windows(2).all(|w| w[0][0] < w[1][0]));
    }
}
