//! The `map_update` service end to end, against `glintd replay` of a simulated warehouse:
//!
//! - Mapping with an offset, tilted mounting: every keyframe arrives with its points, and the
//!   last poses sent are the run's final trajectory (the sensor's, optimised) moved into the
//!   frame of the `map` stream by the mounting; the keyframes' clouds, placed at those poses,
//!   overlap where the keyframes saw the same walls.
//! - Localising in the map saved from that run: a subscriber there from the start and one that
//!   connects mid-run each receive the whole saved map (every keyframe's cloud and pose, flagged
//!   as a saved map), the late one as a replay.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use glint_ipc::{
    Domain, KeyframePose, MapContent, MapEdge, MapPoint, MapUpdate, MapUpdateFlags,
    MapUpdateSubscriber,
};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn scratch() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-map-update-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn ok(command: &mut Command) {
    let out = command.output().unwrap();
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn isometry(position: [f64; 3], orientation: [f64; 4]) -> Isometry3<f64> {
    let [x, y, z, w] = orientation;
    Isometry3::from_parts(
        Translation3::new(position[0], position[1], position[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
    )
}

/// The map as a consumer holds it: the last pose and the whole cloud of each keyframe.
#[derive(Default)]
struct HeldMap {
    poses: BTreeMap<u32, KeyframePose>,
    clouds: BTreeMap<u32, Vec<MapPoint>>,
    /// Parts of clouds not yet complete.
    partial: BTreeMap<u32, Vec<MapPoint>>,
    edges: Vec<MapEdge>,
    messages: usize,
    flags_seen: Vec<MapUpdateFlags>,
    map_ids: Vec<u64>,
}

impl HeldMap {
    fn take(&mut self, m: MapUpdate) {
        self.messages += 1;
        self.flags_seen.push(m.header.flags);
        if !self.map_ids.contains(&m.header.map_id) {
            self.map_ids.push(m.header.map_id);
        }
        match m.content {
            MapContent::Cloud(points) => {
                let k = m.header.keyframe;
                let held = self.partial.entry(k).or_default();
                if m.header.part == 0 {
                    held.clear();
                }
                held.extend(points);
                if m.header.part + 1 == m.header.parts {
                    let whole = self.partial.remove(&k).unwrap();
                    self.clouds.insert(k, whole);
                }
            }
            MapContent::KeyframePoses(poses) => {
                for p in poses {
                    self.poses.insert(p.keyframe, p);
                }
            }
            MapContent::Edges(edges) => self.edges = edges,
            MapContent::Unreadable => panic!("unreadable message {:?}", m.header),
        }
    }

    fn drain(&mut self, subscriber: &MapUpdateSubscriber) {
        while let Some(m) = subscriber.try_next().unwrap() {
            self.take(m);
        }
    }
}

fn open(domain: &Domain, replay: &mut Child) -> MapUpdateSubscriber {
    let started = Instant::now();
    loop {
        match MapUpdateSubscriber::open(domain) {
            Ok(s) => return s,
            Err(e) => {
                assert!(
                    replay.try_wait().unwrap().is_none(),
                    "the replay ended before the service existed: {e}"
                );
                assert!(started.elapsed() < Duration::from_secs(30), "{e}");
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }
}

fn replay(capture: &Path, domain: &str, extra: &[&str]) -> Child {
    glintd()
        .arg("replay")
        .arg(capture)
        .args(["--pace", "2", "--domain", domain])
        .args(extra)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// TUM lines: time (s) and the pose.
fn tum(path: &Path) -> Vec<(f64, Isometry3<f64>)> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            (v[0], isometry([v[1], v[2], v[3]], [v[4], v[5], v[6], v[7]]))
        })
        .collect()
}

#[test]
fn consumers_hold_the_map_as_keyframes_mapping_and_localising() {
    let dir = scratch();
    let run = dir.join("run");
    ok(glintd()
        .args([
            "sim",
            "warehouse",
            "--seed",
            "21",
            "--seconds",
            "8",
            "--out",
        ])
        .arg(&run));
    let capture = run.join("scan.pcap");
    let config = dir.join("glintd.toml");
    std::fs::write(
        &config,
        "[mounting]\ntranslation = [0.3, -0.1, 1.2]\nrotation_rpy = [0.01, -0.03, 0.4]\n",
    )
    .unwrap();
    let mounting = isometry(
        [0.3, -0.1, 1.2],
        UnitQuaternion::from_euler_angles(0.01, -0.03, 0.4)
            .coords
            .into(),
    );

    // Mapping.
    let name = format!("map-update-slam-{}", std::process::id());
    let trajectory = dir.join("slam.tum");
    let mut mapping = replay(
        &capture,
        &name,
        &[
            "--config",
            config.to_str().unwrap(),
            "--trajectory",
            trajectory.to_str().unwrap(),
        ],
    );
    let domain = Domain::new(&name).unwrap();
    let subscriber = open(&domain, &mut mapping);
    let mut held = HeldMap::default();
    while mapping.try_wait().unwrap().is_none() {
        held.drain(&subscriber);
        std::thread::sleep(Duration::from_millis(20));
    }
    held.drain(&subscriber);
    assert!(mapping.wait().unwrap().success());

    let keyframes = held.poses.len();
    assert!(keyframes >= 5, "{keyframes} keyframes");
    assert_eq!(held.clouds.len(), keyframes, "a cloud per keyframe");
    assert!(held.partial.is_empty());
    assert_eq!(held.map_ids.len(), 1);
    assert!(held
        .flags_seen
        .iter()
        .all(|f| !f.contains(MapUpdateFlags::SAVED_MAP)));
    assert!(held.clouds.values().all(|c| c.len() >= 100));

    // The last poses are the final trajectory's, in the `map` stream's frame. Trajectory lines
    // are stamped on the poses' time base, keyframes on the sensor's clock; the first keyframe
    // is the first sweep, which fixes the offset between the two.
    let lines = tum(&trajectory);
    let offset = lines[0].0 - held.poses[&0].sensor_time_ns as f64 * 1e-9;
    let matched: Vec<_> = held
        .poses
        .values()
        .filter_map(|k| {
            let t = k.sensor_time_ns as f64 * 1e-9 + offset;
            lines
                .iter()
                .find(|(s, _)| (s - t).abs() < 2e-3)
                .map(|l| (k, l))
        })
        .collect();
    assert_eq!(
        matched.len(),
        keyframes,
        "every keyframe on a trajectory line"
    );
    for (k, (_, sensor)) in &matched {
        let expected = mounting * sensor;
        let got = isometry(k.position, k.orientation);
        let moved = (expected.translation.vector - got.translation.vector).norm();
        let turned = (expected.rotation.inverse() * got.rotation).angle();
        assert!(
            moved < 1e-4 && turned < 1e-5,
            "keyframe {}: {moved} m, {turned} rad off",
            k.keyframe
        );
    }

    // Placed at their poses, consecutive keyframes' clouds overlap. Their planes sample the
    // surfaces one per 0.5 m voxel, so two clouds of the same walls lie about a quarter of a
    // metre apart however well placed (0.16–0.26 m on this run); a keyframe placed off by more
    // than the voxel would leave its cloud farther.
    let placed = |k: u32| -> Vec<Vector3<f64>> {
        let p = &held.poses[&k];
        let pose = isometry(p.position, p.orientation);
        held.clouds[&k]
            .iter()
            .map(|c| {
                let q = Point3::new(
                    f64::from(c.position[0]),
                    f64::from(c.position[1]),
                    f64::from(c.position[2]),
                );
                (pose * q).coords
            })
            .collect()
    };
    for k in 1..keyframes as u32 {
        let (a, b) = (placed(k - 1), placed(k));
        let mut near: Vec<f64> = b
            .iter()
            .step_by(7)
            .map(|p| a.iter().map(|q| (p - q).norm()).fold(f64::MAX, f64::min))
            .collect();
        near.sort_by(f64::total_cmp);
        let median = near[near.len() / 2];
        assert!(
            median < 0.3,
            "keyframes {} and {k}: median gap {median} m",
            k - 1
        );
    }

    // Localising in the map saved from the same capture.
    let site = dir.join("site.glintmap");
    ok(glintd()
        .arg("replay")
        .arg(&capture)
        .args(["--no-publish", "--config"])
        .arg(&config)
        .arg("--save-map")
        .arg(&site));
    let name = format!("map-update-loc-{}", std::process::id());
    let mut localising = replay(
        &capture,
        &name,
        &[
            "--config",
            config.to_str().unwrap(),
            "--localise",
            site.to_str().unwrap(),
        ],
    );
    // The operator's view of the same service.
    let echo = glintd()
        .args(["echo", "--stream", "map_update", "--domain", &name])
        .args(["--count", "3", "--wait", "20", "--timeout", "30"])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let domain = Domain::new(&name).unwrap();
    let early = open(&domain, &mut localising);
    let mut first = HeldMap::default();
    let mut second = HeldMap::default();
    let mut late = None;
    let started = Instant::now();
    while localising.try_wait().unwrap().is_none() {
        first.drain(&early);
        if late.is_none() && started.elapsed() > Duration::from_secs(2) {
            late = Some(MapUpdateSubscriber::open(&domain).unwrap());
        }
        if let Some(s) = &late {
            second.drain(s);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    first.drain(&early);
    assert!(localising.wait().unwrap().success());
    let late = late.expect("the replay ran for more than 2 s");
    let echoed = echo.wait_with_output().unwrap();
    assert!(echoed.status.success());
    let echoed = String::from_utf8_lossy(&echoed.stdout).into_owned();
    assert_eq!(echoed.lines().count(), 3, "{echoed}");
    assert!(
        echoed
            .lines()
            .all(|l| l.starts_with("map_update ") && l.contains(" keyframes=")),
        "{echoed}"
    );
    second.drain(&late);

    for (who, got) in [("early", &first), ("late", &second)] {
        assert!(got.messages > 0, "{who} got nothing");
        assert!(
            got.flags_seen
                .iter()
                .all(|f| f.contains(MapUpdateFlags::SAVED_MAP)),
            "{who}"
        );
        assert_eq!(got.map_ids.len(), 1, "{who}");
        assert!(got.partial.is_empty(), "{who}");
        let k = got.poses.len();
        assert!(k >= 5, "{who}: {k}");
        assert_eq!(got.clouds.len(), k, "{who}: a cloud per keyframe");
        assert_eq!(
            got.poses.keys().copied().collect::<Vec<_>>(),
            (0..k as u32).collect::<Vec<_>>(),
            "{who}"
        );
    }
    assert!(second
        .flags_seen
        .iter()
        .all(|f| f.contains(MapUpdateFlags::REPLAY)));
    assert_eq!(first.poses, second.poses, "the same saved map");
    assert_eq!(first.clouds, second.clouds);
    std::fs::remove_dir_all(dir).unwrap();
}
