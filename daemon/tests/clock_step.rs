//! The host clock stepped under a live daemon (chrony or PTP correcting a wrong boot clock), by
//! ±2 s and ±1 h: the pipeline runs in this process on UDP from a simulated sensor, with a
//! receive clock the test shifts mid-run (no root needed). Stamps follow the new clock at once,
//! the motion does not see the step, the step is counted with its size, and the streamed
//! trajectory starts a new file when stamps go back, so every file's stamps increase.

use std::net::{IpAddr, Ipv4Addr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use glint_driver::udp::{ReceiveClock, UdpConfig};
use glint_driver::{Ports, StreamConfig};
use glintd::pipeline::{self, Input, Options, SiteMapOptions, Summary};
use nalgebra::Isometry3;

/// The tests stream at real-time pace: one at a time, so they do not starve each other.
static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-clock-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `n` UDP ports free right now.
fn free_ports<const N: usize>() -> [u16; N] {
    let sockets: Vec<UdpSocket> = (0..N)
        .map(|_| UdpSocket::bind("127.0.0.1:0").unwrap())
        .collect();
    std::array::from_fn(|i| sockets[i].local_addr().unwrap().port())
}

/// A live run of 6 s of simulated warehouse, the receive clock stepped by `step_ns` 3 s in:
/// the summary and the trajectory files written (the current one last).
fn run_with_step(name: &str, step_ns: i64) -> (Summary, Vec<Vec<u64>>) {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = scratch(name);
    // The simulator's position packets carry a GPS fix, which would anchor the stamps instead
    // of the host clock: they go to a port the daemon does not read, as from a sensor with no
    // GPS receiver.
    let [data, position, elsewhere] = free_ports::<3>();
    let ports = Ports { data, position };
    let shift = Arc::new(AtomicI64::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let trajectory = dir.join("trajectory.tum");
    let (clock, stopped, written) = (
        ReceiveClock::shifted(shift.clone()),
        stop.clone(),
        trajectory.clone(),
    );
    // Options hold the caller's callbacks, which stay on the thread that runs the pipeline.
    let daemon = std::thread::spawn(move || {
        pipeline::run(Options {
            input: Input::Live {
                udp: UdpConfig {
                    bind: IpAddr::V4(Ipv4Addr::LOCALHOST),
                    ports,
                    clock,
                    ..UdpConfig::default()
                },
                source: None,
                silence: Duration::from_secs(2),
            },
            stream: StreamConfig::default(),
            odometry: Default::default(),
            queue: 4,
            odometry_thread: Default::default(),
            base_from_sensor: Isometry3::identity(),
            publish: None,
            trajectory: Some(written),
            trajectory_max_bytes: None,
            kitti: None,
            map: None,
            keep_estimates: true,
            backend: None,
            site_map: SiteMapOptions::default(),
            odom_trajectory: None,
            known_poses: None,
            stop: stopped,
            on_ready: Some(Box::new(move || {
                let _ = ready_tx.send(());
            })),
            on_alive: None,
            on_sweep: None,
        })
    });
    ready_rx
        .recv_timeout(Duration::from_secs(10))
        .expect("the pipeline starts");
    let mut sim = Command::new(env!("CARGO_BIN_EXE_glintd"))
        .args([
            "sim",
            "warehouse",
            "--seconds",
            "6",
            "--seed",
            "5",
            "--udp",
            "127.0.0.1",
            "--data-port",
            &ports.data.to_string(),
            "--position-port",
            &elsewhere.to_string(),
        ])
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(3));
    shift.store(step_ns, Ordering::Relaxed);
    assert!(sim.wait().unwrap().success());
    std::thread::sleep(Duration::from_millis(500));
    stop.store(true, Ordering::Relaxed);
    let summary = daemon.join().unwrap().expect("the run ends cleanly");
    let stamps = |p: &Path| -> Vec<u64> {
        std::fs::read_to_string(p)
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| {
                let s: f64 = l.split(' ').next().unwrap().parse().unwrap();
                (s * 1e9).round() as u64
            })
            .collect()
    };
    let mut files = Vec::new();
    let rotated = dir.join("trajectory.tum.1");
    if rotated.exists() {
        files.push(stamps(&rotated));
    }
    files.push(stamps(&trajectory));
    std::fs::remove_dir_all(&dir).unwrap();
    (summary, files)
}

fn check(name: &str, step_s: f64) {
    let step_ns = (step_s * 1e9) as i64;
    let (summary, files) = run_with_step(name, step_ns);
    let (steps, last) = summary.clock_steps;
    assert_eq!(steps, 1, "{name}: one step seen");
    let error_s = (last - step_ns) as f64 * 1e-9;
    assert!(error_s.abs() < 0.05, "{name}: step measured {last} ns");

    // One jump in the published stamps, of the step's size, from one sweep to the next: the
    // time base followed the new clock at once.
    let stamps: Vec<i64> = summary.estimates.iter().map(|e| e.time_ns as i64).collect();
    assert!(stamps.len() >= 40, "{name}: {} poses", stamps.len());
    let jumps: Vec<i64> = stamps
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| (*d - 100_000_000).abs() > 500_000_000)
        .collect();
    assert_eq!(jumps.len(), 1, "{name}: {jumps:?}");
    let jump_error_s = (jumps[0] - step_ns - 100_000_000) as f64 * 1e-9;
    assert!(jump_error_s.abs() < 0.06, "{name}: jump {} ns", jumps[0]);

    // The motion never saw it: every sweep tracked, the path continuous (at most 1.5 m/s).
    assert_eq!(summary.statuses.lost, 0, "{name}: {:?}", summary.statuses);
    for w in summary.estimates.windows(2) {
        let moved = (w[1].pose.translation.vector - w[0].pose.translation.vector).norm();
        assert!(moved < 0.3, "{name}: {moved} m in one sweep");
    }

    // The streamed trajectory: a second file exactly when stamps went back, each increasing.
    assert_eq!(files.len(), if step_ns < 0 { 2 } else { 1 }, "{name}");
    for file in &files {
        assert!(file.windows(2).all(|w| w[0] < w[1]), "{name}: {file:?}");
    }
    let written: usize = files.iter().map(Vec::len).sum();
    assert_eq!(written, stamps.len(), "{name}");
}

#[test]
fn a_two_second_step_of_the_host_clock() {
    check("forward-2s", 2.0);
    check("back-2s", -2.0);
}

#[test]
fn an_hour_s_step_of_the_host_clock() {
    check("forward-1h", 3600.0);
    check("back-1h", -3600.0);
}
