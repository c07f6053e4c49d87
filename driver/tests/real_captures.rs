//! The driver against real VLP-16 captures in `../shared/data`: model detection despite a wrong
//! product-id byte, packet and return counts, geometry against the manual's laser table, time
//! order, and damaged files.

use std::path::Path;

use glint_driver::model::{ByteVerdict, ModelSource};
use glint_driver::pcap::CaptureError;
use glint_driver::{Model, PacketKind, PcapSource, Ports, SensorStream, StreamConfig, Sweep};
use glint_testkit::shared_data;

/// What does not run without `../shared/data`.
const REAL_CAPTURES: &str = "real VLP-16 captures";

/// The manual's VLP-16 table (63-9243), written here independently of the decoder's copy:
/// laser index → elevation in degrees. Vertical offsets follow 41.91 mm × tan(−ω).
const MANUAL_ELEVATION_DEG: [f64; 16] = [
    -15., 1., -13., 3., -11., 5., -9., 7., -7., 9., -5., 11., -3., 13., -1., 15.,
];

struct Replayed {
    sweeps: Vec<Sweep>,
    stream: SensorStream,
    ports: (u64, u64, u64),
}

fn replay(path: &Path, config: StreamConfig) -> Replayed {
    let mut source = PcapSource::open(path, Ports::default()).unwrap();
    let mut stream = SensorStream::new(config);
    let mut sweeps = Vec::new();
    while let Some(p) = source.next().unwrap() {
        match p.kind {
            PacketKind::Data => stream.push_data(p.payload, p.receive_ns).unwrap(),
            PacketKind::Position => stream.push_position(p.payload).unwrap(),
        }
        sweeps.extend(std::iter::from_fn(|| stream.take_sweep()));
    }
    stream.finish().unwrap();
    sweeps.extend(std::iter::from_fn(|| stream.take_sweep()));
    Replayed {
        ports: source.port_counts(),
        sweeps,
        stream,
    }
}

#[test]
fn real_short_capture_is_a_vlp16_despite_its_hdl32e_byte() {
    let Some(path) = shared_data(REAL_CAPTURES, "vlp16_real_short.pcap") else {
        return;
    };
    let r = replay(&path, StreamConfig::default());
    let d = r.stream.detection().unwrap();
    assert_eq!(d.model, Model::Vlp16);
    assert_eq!(d.source, ModelSource::Timing);
    assert_eq!(d.product_id, 0x21);
    assert_eq!(d.byte, ByteVerdict::Contradicted(Model::Hdl32e));
    assert!(d.describe().contains("overruled"), "{}", d.describe());
    let us = d.measured_block_us.unwrap();
    assert!((us - 110.592).abs() < 0.2, "{us}");
    assert_eq!(r.ports, (84, 16, 0));
    let returns: usize = r.sweeps.iter().map(|s| s.points.len()).sum();
    assert_eq!(returns, 19_579);
}

#[test]
fn a_configured_model_wins() {
    let Some(path) = shared_data(REAL_CAPTURES, "vlp16_real_short.pcap") else {
        return;
    };
    let config = StreamConfig {
        model: Some(Model::PuckHiRes),
        ..StreamConfig::default()
    };
    let r = replay(&path, config);
    let d = r.stream.detection().unwrap();
    assert_eq!(
        (d.model, d.source),
        (Model::PuckHiRes, ModelSource::Configured)
    );
}

#[test]
fn every_point_lies_on_its_lasers_cone() {
    let Some(path) = shared_data(REAL_CAPTURES, "vlp16_real_short.pcap") else {
        return;
    };
    let r = replay(&path, StreamConfig::default());
    let mut checked = 0;
    for p in r.sweeps.iter().flat_map(|s| &s.points) {
        assert!(p.x.is_finite() && p.y.is_finite() && p.z.is_finite() && p.azimuth.is_finite());
        let omega = MANUAL_ELEVATION_DEG[p.laser as usize].to_radians();
        let offset = 0.04191 * (-omega).tan();
        let horizontal = f64::from(p.x).hypot(f64::from(p.y));
        let elevation = (f64::from(p.z) - offset).atan2(horizontal);
        // Tolerance: the manual rounds offsets to 0.1 mm (≤ 0.05 mm off the formula) and the
        // coordinates are f32 (7 significant digits); at the nearest return (~0.5 m) that bounds
        // the angle error by ~1e-4 rad. Measurement noise does not enter: range noise moves a
        // point along its beam, not off it.
        let tolerance = 1e-4 + 0.06e-3 / f64::from(p.range);
        assert!(
            (elevation - omega).abs() < tolerance,
            "laser {} at {} m: {elevation} vs {omega}",
            p.laser,
            p.range
        );
        // The ring is the elevation order.
        let rank = MANUAL_ELEVATION_DEG
            .iter()
            .filter(|&&e| e < MANUAL_ELEVATION_DEG[p.laser as usize])
            .count();
        assert_eq!(p.ring as usize, rank);
        checked += 1;
    }
    assert_eq!(checked, 19_579);
}

#[test]
fn azimuths_and_times_increase_within_each_sweep() {
    let Some(path) = shared_data(REAL_CAPTURES, "vlp16_20hz_50_rotations.pcap") else {
        return;
    };
    let r = replay(&path, StreamConfig::default());
    assert_eq!(r.sweeps.iter().filter(|s| !s.partial).count(), 50);
    assert_eq!(
        r.sweeps.iter().map(|s| s.points.len()).sum::<usize>(),
        700_400
    );
    for s in &r.sweeps {
        let mut last_azimuth = -1.0f32;
        let mut last_time = 0;
        let mut last_laser_time = [0u64; 16];
        for p in &s.points {
            // Firing order: time never goes back; azimuth (cut at 0) never goes back by more than
            // the per-laser interpolation noise.
            assert!(p.time_ns >= last_time);
            assert!(
                p.azimuth >= last_azimuth - 1e-4,
                "sweep {}: {} after {}",
                s.index,
                p.azimuth,
                last_azimuth
            );
            assert!(p.time_ns > last_laser_time[p.laser as usize]);
            last_laser_time[p.laser as usize] = p.time_ns;
            last_time = p.time_ns;
            last_azimuth = last_azimuth.max(p.azimuth);
        }
        if !s.partial {
            assert_eq!(s.packets_missing, 0);
            assert!((s.rpm().unwrap() - 1200.0).abs() < 10.0);
        }
    }
}

#[test]
fn a_truncated_copy_yields_the_packets_before_the_damage() {
    let Some(path) = shared_data(REAL_CAPTURES, "vlp16_real_short.pcap") else {
        return;
    };
    let bytes = std::fs::read(&path).unwrap();
    let cut = bytes.len() * 2 / 3;
    let dir = std::env::temp_dir().join(format!("glint-trunc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let truncated = dir.join("truncated.pcap");
    std::fs::write(&truncated, &bytes[..cut]).unwrap();
    let mut source = PcapSource::open(&truncated, Ports::default()).unwrap();
    let mut n = 0;
    let err = loop {
        match source.next() {
            Ok(Some(_)) => n += 1,
            Ok(None) => panic!("the damage went unnoticed"),
            Err(e) => break e,
        }
    };
    let CaptureError::Truncated { offset } = err else {
        panic!("{err}")
    };
    assert!(
        offset < cut as u64 && offset > cut as u64 - 1300,
        "offset {offset}, cut {cut}"
    );
    assert!(err.to_string().contains(&offset.to_string()));
    assert!(n > 50);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn proper_byte_capture_decodes_as_vlp16() {
    let Some(path) = shared_data(REAL_CAPTURES, "vlp16_example.pcap") else {
        return;
    };
    let r = replay(&path, StreamConfig::default());
    let d = r.stream.detection().unwrap();
    assert_eq!((d.model, d.byte), (Model::Vlp16, ByteVerdict::Agrees));
    assert_eq!(
        r.sweeps.iter().map(|s| s.points.len()).sum::<usize>(),
        31_630
    );
}
