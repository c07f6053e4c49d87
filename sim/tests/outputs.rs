//! What `simulate_to_dir` writes, and that it is reproducible: same seed, same bytes (pcap,
//! ground truth, scene.json); a different seed, a different layout. Clear errors for bad
//! requests, never a panic.

mod common;

use std::fs;
use std::path::PathBuf;

use glint_sim::{
    scenarios, simulate_to_dir, ConfigError, RunOptions, Scenario, SimConfig, SimError, Simulation,
};

/// A fresh directory under the system's temp dir, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir =
            std::env::temp_dir().join(format!("glint-sim-test-{}-{name}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

const FILES: [&str; 4] = [
    "scan.pcap",
    "groundtruth.tum",
    "groundtruth_dense.tum",
    "scene.json",
];

#[test]
fn same_seed_gives_the_same_bytes_in_every_file() {
    for scenario in Scenario::ALL {
        let config = SimConfig {
            scenario,
            seed: 11,
            seconds: 0.4,
            ..SimConfig::default()
        };
        let (a, b) = (
            TempDir::new(&format!("same-a-{scenario}")),
            TempDir::new(&format!("same-b-{scenario}")),
        );
        let sa = simulate_to_dir(&config, &a.0).unwrap();
        let sb = simulate_to_dir(&config, &b.0).unwrap();
        assert_eq!(
            (sa.data_packets, sa.rays, sa.returns),
            (sb.data_packets, sb.rays, sb.returns)
        );
        for f in FILES {
            let (x, y) = (
                fs::read(a.0.join(f)).unwrap(),
                fs::read(b.0.join(f)).unwrap(),
            );
            assert!(
                !x.is_empty() && x == y,
                "{scenario}: {f} differs between two runs of the same seed"
            );
        }
        // The in-memory API produces exactly the file's packets.
        let (pcap, _) = common::capture(&mut Simulation::new(&config).unwrap());
        assert_eq!(pcap, fs::read(a.0.join("scan.pcap")).unwrap());
    }
}

#[test]
fn a_different_seed_gives_a_different_layout_of_the_same_kind() {
    for scenario in Scenario::ALL {
        let one = scenarios::build(scenario, 1).unwrap();
        let two = scenarios::build(scenario, 2).unwrap();
        assert_ne!(one.description, two.description, "{scenario}");
        assert_ne!(
            one.scene.primitives(),
            two.scene.primitives(),
            "{scenario}: primitives"
        );
        // Same kind of place: the same kinds of objects.
        let kinds = |b: &scenarios::Built| {
            let mut t: Vec<String> = b.scene.tag_counts().into_iter().map(|(t, _)| t).collect();
            t.sort();
            t
        };
        assert_eq!(kinds(&one), kinds(&two), "{scenario}");
    }
}

#[test]
fn ground_truth_and_scene_files_follow_the_conventions() {
    let dir = TempDir::new("conventions");
    let config = SimConfig {
        scenario: Scenario::Warehouse,
        seed: 4,
        seconds: 1.2,
        start_time_ns: Some(1_700_000_000_123_456_789),
        ..SimConfig::default()
    };
    let summary = simulate_to_dir(&config, &dir.0).unwrap();
    let parse = |name: &str| -> Vec<(u64, [f64; 7])> {
        fs::read_to_string(dir.0.join(name))
            .unwrap()
            .lines()
            .map(|l| {
                let f: Vec<&str> = l.split(' ').collect();
                assert_eq!(f.len(), 8, "{l}");
                let (s, ns) = f[0].split_once('.').unwrap();
                assert_eq!(ns.len(), 9, "9 decimals: {l}");
                let t = s.parse::<u64>().unwrap() * 1_000_000_000 + ns.parse::<u64>().unwrap();
                let v: Vec<f64> = f[1..].iter().map(|x| x.parse().unwrap()).collect();
                (t, v.try_into().unwrap())
            })
            .collect()
    };
    let sweeps = parse("groundtruth.tum");
    let dense = parse("groundtruth_dense.tum");
    assert_eq!(sweeps.len(), summary.sweeps);
    // 600 rpm for 1.2 s: 12 crossings of azimuth 0 (±1), plus the cut-off last sweep.
    assert!((12..=14).contains(&sweeps.len()), "{}", sweeps.len());
    for w in sweeps.windows(2) {
        let dt = w[1].0 - w[0].0;
        assert!(
            w[1].0 > w[0].0 && (dt as f64 - 1e8).abs() < 1e8 * 0.02
                || w[1] == *sweeps.last().unwrap(),
            "sweep spacing {dt}"
        );
    }
    assert_eq!(dense[0].0, 1_700_000_000_123_456_789);
    assert!(dense.windows(2).all(|w| w[1].0 - w[0].0 == 10_000_000));
    for (_, v) in sweeps.iter().chain(&dense) {
        let q = (v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]).sqrt();
        assert!(
            (q - 1.0).abs() < 1e-8 && v[6] >= 0.0,
            "unit quaternion, qw ≥ 0"
        );
        assert!((0.5..=1.0).contains(&v[2]), "sensor height {}", v[2]);
    }
    let json: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(dir.0.join("scene.json")).unwrap()).unwrap();
    assert_eq!(json["run"]["scenario"], "warehouse");
    assert_eq!(json["run"]["start_time_ns"], 1_700_000_000_123_456_789u64);
    assert_eq!(json["sensor"]["elevation_deg"][0], -15.0);
    assert_eq!(json["sensor"]["product_id"], 0x22);
    assert!(json["conventions"]["tum"]
        .as_str()
        .unwrap()
        .contains("qx qy qz qw"));
    let built = scenarios::build(Scenario::Warehouse, 4).unwrap();
    assert_eq!(
        json["scene"]["primitives"].as_array().unwrap().len(),
        built.scene.primitives().len()
    );
    assert_eq!(json["outputs"]["data_packets"], summary.data_packets);
}

#[test]
fn packet_loss_drops_data_packets_and_the_driver_counts_them() {
    let config = SimConfig {
        scenario: Scenario::Corridor,
        seconds: 0.5,
        packet_loss: 0.1,
        ..SimConfig::default()
    };
    let mut sim = Simulation::new(&config).unwrap();
    let (pcap, truth) = common::capture(&mut sim);
    let stats = sim.stats();
    let total = sim.data_packets_total();
    assert_eq!(stats.data_packets + stats.dropped_packets, total);
    assert!(
        (15..=60).contains(&stats.dropped_packets),
        "{} of {total} dropped",
        stats.dropped_packets
    );
    let decoded = common::decode(pcap);
    assert_eq!(
        decoded.points.len(),
        truth.len(),
        "no truth for lost packets"
    );
    assert_eq!(decoded.data_packets as u64, stats.data_packets);
}

#[test]
fn bad_requests_are_clear_errors() {
    let dir = TempDir::new("bad");
    for seconds in [0.0, -5.0, f64::NAN] {
        let config = SimConfig {
            seconds,
            ..SimConfig::default()
        };
        assert!(matches!(
            simulate_to_dir(&config, &dir.0),
            Err(SimError::Config(ConfigError::Seconds(_)))
        ));
    }
    assert!("parking-lot".parse::<Scenario>().is_err());
    // An output "directory" that is a file, and one that cannot be created.
    fs::create_dir_all(&dir.0).unwrap();
    let file = dir.0.join("a-file");
    fs::write(&file, b"x").unwrap();
    let config = SimConfig {
        seconds: 0.1,
        ..SimConfig::default()
    };
    let err = simulate_to_dir(&config, &file.join("out")).unwrap_err();
    assert!(matches!(err, SimError::Io { .. }), "{err}");
    assert!(
        err.to_string().contains("a-file"),
        "the message names the path: {err}"
    );
    assert!(matches!(
        simulate_to_dir(
            &config,
            std::path::Path::new("/proc/glint-sim-cannot-exist")
        ),
        Err(SimError::Io { .. })
    ));
    assert!(matches!(
        glint_sim::run(&config, &RunOptions::default()),
        Err(SimError::NoOutput)
    ));
}

#[test]
fn layouts_are_printable() {
    for scenario in Scenario::ALL {
        let text = scenarios::describe(scenario, 7).unwrap();
        assert!(text.starts_with(&format!("{scenario} (seed 7)")), "{text}");
        assert!(
            text.contains("loop:") && text.contains("primitives:") && text.contains("sensor:"),
            "{text}"
        );
    }
    let corridor = scenarios::describe(Scenario::Corridor, 7).unwrap();
    assert!(corridor.contains("unique cues") && corridor.contains("doors every"));
}
