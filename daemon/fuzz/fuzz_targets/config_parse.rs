//! Fuzzes the daemon's configuration parser: any text gives a configuration or an error,
//! never a panic. Bytes that are not UTF-8 are converted lossily, as a file read for the
//! parser would be refused before it; what is accepted must be usable as the daemon uses it.
#![no_main]

use glintd::config::{initial_pose, DaemonConfig};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let Ok(config) = DaemonConfig::parse(&text) else {
        return;
    };
    let base_from_sensor = config.mounting.base_from_sensor();
    if let Some(pose) = config.site_map.initial_pose {
        initial_pose(&pose, &base_from_sensor).expect("a validated initial pose is usable");
    }
    let _ = config.udp_config();
    // With a calibration file it would read the disk; without, it must succeed.
    if config.sensor.calibration.is_none() {
        config
            .stream_config()
            .expect("a validated configuration gives a stream configuration");
    }
});
