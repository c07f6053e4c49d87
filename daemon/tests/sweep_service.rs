//! The `sweep` service end to end: a simulated capture replayed at the sensor's pace with a
//! tilted, offset mounting while a subscriber in this process reads every sweep. Each sweep's
//! points are `glintd decode`'s for the same sweep after the documented transform (the
//! header's twist and mounting), in the same order, with the same ring, reflectivity and time
//! offset; the front end's features are labelled.

use std::collections::HashMap;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use glint_core::se3::exp;
use glint_ipc::{Domain, PointLabel, SweepHeader, SweepPoint, SweepSubscriber};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector6};

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn scratch() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-sweep-service-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// One decoded return: time, ring, position, reflectivity.
type Decoded = (u64, u16, [f64; 3], u8);

/// `glintd decode`'s CSV, by sweep.
fn decoded(path: &PathBuf) -> HashMap<u64, Vec<Decoded>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut sweeps: HashMap<u64, Vec<Decoded>> = HashMap::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let num = |i: usize| f[i].parse::<f64>().unwrap();
        sweeps.entry(f[0].parse().unwrap()).or_default().push((
            f[1].parse().unwrap(),
            f[2].parse().unwrap(),
            [num(5), num(6), num(7)],
            f[8].parse().unwrap(),
        ));
    }
    sweeps
}

#[test]
fn published_sweeps_are_the_decoded_ones_moved_to_base_link() {
    let dir = scratch();
    let run = dir.join("run");
    assert!(glintd()
        .args(["sim", "warehouse", "--seed", "9", "--seconds", "4", "--out"])
        .arg(&run)
        .status()
        .unwrap()
        .success());
    let capture = run.join("scan.pcap");
    let csv = dir.join("points.csv");
    assert!(glintd()
        .arg("decode")
        .arg(&capture)
        .arg("--out")
        .arg(&csv)
        .stdout(Stdio::null())
        .status()
        .unwrap()
        .success());
    let config = dir.join("glintd.toml");
    std::fs::write(
        &config,
        "[mounting]\ntranslation = [0.3, -0.1, 1.2]\nrotation_rpy = [0.01, -0.03, 0.4]\n",
    )
    .unwrap();

    let domain = format!("sweep-e2e-{}", std::process::id());
    let mut replay = glintd()
        .arg("replay")
        .arg(&capture)
        .args([
            "--pace",
            "realtime",
            "--no-loop",
            "--domain",
            &domain,
            "--config",
        ])
        .arg(&config)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // The operator's view of the same service.
    let echo = glintd()
        .args(["echo", "--stream", "sweep", "--domain", &domain])
        .args(["--count", "5", "--wait", "20", "--timeout", "30"])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let domain = Domain::new(&domain).unwrap();
    let started = Instant::now();
    let subscriber = loop {
        match SweepSubscriber::open(&domain) {
            Ok(s) => break s,
            Err(_) if started.elapsed() < Duration::from_secs(20) => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => panic!("{e}"),
        }
    };
    let mut received: Vec<(SweepHeader, Vec<SweepPoint>)> = Vec::new();
    loop {
        match subscriber.try_next(|h, p| (*h, p.to_vec())).unwrap() {
            Some(sweep) => received.push(sweep),
            None if replay.try_wait().unwrap().is_some() => break,
            None => std::thread::sleep(Duration::from_millis(5)),
        }
    }
    while let Some(sweep) = subscriber.try_next(|h, p| (*h, p.to_vec())).unwrap() {
        received.push(sweep);
    }
    assert!(replay.wait().unwrap().success());
    let echoed = echo.wait_with_output().unwrap();
    assert!(echoed.status.success());
    let echoed = String::from_utf8_lossy(&echoed.stdout).into_owned();
    assert_eq!(echoed.lines().count(), 5, "{echoed}");
    assert!(echoed
        .lines()
        .all(|l| l.starts_with("sweep ") && l.contains(" points=")));

    let sweeps = decoded(&csv);
    let by_reference: HashMap<u64, &Vec<Decoded>> = sweeps
        .values()
        .map(|points| (points.iter().map(|p| p.0).max().unwrap(), points))
        .collect();
    let mut compared = 0;
    for (header, points) in &received {
        assert_eq!(header.point_count as usize, points.len());
        let Some(decoded) = by_reference.get(&header.sensor_time_ns) else {
            panic!(
                "sweep {} at {} matches no decoded sweep",
                header.sequence, header.sensor_time_ns
            );
        };
        assert_eq!(points.len(), decoded.len(), "sweep {}", header.sequence);
        let [x, y, z, w] = header.sensor_orientation;
        let mounting = Isometry3::from_parts(
            Translation3::from(header.sensor_position),
            UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
        );
        let expected_mounting = Isometry3::from_parts(
            Translation3::new(0.3, -0.1, 1.2),
            UnitQuaternion::from_euler_angles(0.01, -0.03, 0.4),
        );
        assert!(
            (mounting.to_matrix() - expected_mounting.to_matrix())
                .abs()
                .max()
                < 1e-9
        );
        let twist = Vector6::from(header.sensor_twist);
        let mut worst: f64 = 0.0;
        for (p, &(time_ns, ring, xyz, reflectivity)) in points.iter().zip(decoded.iter()) {
            assert_eq!((p.ring, p.reflectivity), (ring, reflectivity));
            assert_eq!(
                i64::from(p.time_offset_ns),
                time_ns as i64 - header.sensor_time_ns as i64
            );
            let dt = f64::from(p.time_offset_ns) * 1e-9;
            let expected = mounting * (exp(&(twist * dt)) * Point3::from(xyz));
            let got = Point3::from(p.position.map(f64::from));
            worst = worst.max((got - expected).norm());
        }
        // decode writes 0.1 mm; the deskew's exponential is shared per 0.1 ms of firing time.
        assert!(
            worst < 1e-3,
            "sweep {}: a point {worst} m off",
            header.sequence
        );
        let labelled = |label| points.iter().filter(|p| p.label.contains(label)).count();
        if header.sequence > 2 {
            assert!(labelled(PointLabel::EDGE) > 10 && labelled(PointLabel::PLANE) > 10);
            assert!(points.iter().any(|p| p.intensity.is_finite()));
        }
        compared += 1;
    }
    assert!(compared >= 20, "{compared} sweeps received");
    // The robot moves: the twist is not zero, so the deskew was exercised.
    assert!(received
        .iter()
        .any(|(h, _)| h.sensor_twist[3..].iter().any(|v| v.abs() > 0.1)));
    std::fs::remove_dir_all(&dir).unwrap();
}
