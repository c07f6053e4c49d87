//! The daemon as it runs on the robot: `glintd run` receiving a simulated sensor over UDP on
//! localhost at real-time pace, consumers in separate processes, signals, and the faults a fleet
//! meets (garbage on the port, lost packets, a silent sensor, consumers and daemons killed,
//! another sensor on the network).

use std::io::{BufRead, BufReader};
use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use glint_core::metrics::{associate, ate_rmse};
use glint_core::trajectory::{parse_tum, StampedPose};
use glint_driver::pcap::CaptureReader;
use glint_testkit::SeededRng;

/// These tests run at real-time pace: one at a time, so they do not starve each other of CPU.
static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn real_time() -> std::sync::MutexGuard<'static, ()> {
    REAL_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-live-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A domain no other test or daemon uses.
fn domain(name: &str) -> String {
    format!("live-{name}-{}", std::process::id())
}

/// Two UDP ports free right now.
fn free_ports() -> (u16, u16) {
    let a = UdpSocket::bind("127.0.0.1:0").unwrap();
    let b = UdpSocket::bind("127.0.0.1:0").unwrap();
    (
        a.local_addr().unwrap().port(),
        b.local_addr().unwrap().port(),
    )
}

fn simulate(dir: &Path, scenario: &str, seed: u64, seconds: f64) {
    let o = glintd()
        .args([
            "sim",
            scenario,
            "--seconds",
            &seconds.to_string(),
            "--seed",
            &seed.to_string(),
            "--out",
            dir.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

fn write_config(dir: &Path, ports: (u16, u16), domain: &str) -> PathBuf {
    let path = dir.join("glintd.toml");
    std::fs::write(
        &path,
        format!(
            "[sensor]\naddress = \"127.0.0.1\"\ndata_port = {}\nposition_port = {}\n\
             silence_timeout_s = 0.5\n[ipc]\ndomain = \"{domain}\"\n\
             [output]\ntrajectory = \"{}\"\nmap = \"{}\"\n",
            ports.0,
            ports.1,
            dir.join("trajectory.tum").display(),
            dir.join("map.pcd").display()
        ),
    )
    .unwrap();
    path
}

/// Starts `glintd run` and waits until it says it is ready (its log on stderr).
fn start_daemon(config: &Path) -> (Child, std::sync::mpsc::Receiver<String>) {
    let mut child = glintd()
        .args(["run", "--config", config.to_str().unwrap()])
        .env("GLINT_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let line = rx
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .expect("glintd run did not become ready");
        if line.contains("ready") {
            break;
        }
    }
    (child, rx)
}

fn spawn_echo(domain: &str, stream: &str, seconds: f64) -> Child {
    glintd()
        .args([
            "echo",
            "--domain",
            domain,
            "--stream",
            stream,
            "--timeout",
            &seconds.to_string(),
            "--wait",
            "20",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn echoed_lines(child: Child) -> Vec<String> {
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(str::to_owned)
        .collect()
}

fn sequences(lines: &[String]) -> Vec<u64> {
    lines
        .iter()
        .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
        .collect()
}

/// Sends SIGTERM and returns the exit status and how long the daemon took to exit.
fn terminate(child: &mut Child) -> (std::process::ExitStatus, Duration) {
    let pid = child.id().to_string();
    let start = Instant::now();
    assert!(Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .unwrap()
        .success());
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return (status, start.elapsed());
        }
        if start.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            panic!("glintd did not exit on SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn read_tum(path: &Path) -> Vec<StampedPose> {
    parse_tum(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn run_receives_a_simulated_sensor_over_udp_and_a_subscriber_gets_every_pose() {
    let _serial = real_time();
    let dir = scratch("udp");
    let ports = free_ports();
    let d = domain("udp");
    let config = write_config(&dir, ports, &d);
    let (mut daemon, _log) = start_daemon(&config);
    let echo = spawn_echo(&d, "odom", 25.0);
    let predicted = spawn_echo(&d, "predicted", 20.0);
    // The simulator streams at real-time pace, and writes the same run's ground truth.
    let sim = glintd()
        .args([
            "sim",
            "warehouse",
            "--seconds",
            "12",
            "--seed",
            "31",
            "--udp",
            "127.0.0.1",
            "--data-port",
            &ports.0.to_string(),
            "--position-port",
            &ports.1.to_string(),
            "--out",
            dir.join("sim").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );
    std::thread::sleep(Duration::from_millis(500));
    let (status, took) = terminate(&mut daemon);
    assert!(status.success(), "glintd run exited with {status}");
    // The service's stop deadline: the pipeline drains and the outputs are written in time.
    assert!(took < Duration::from_secs(2), "shutdown took {took:?}");

    let trajectory = read_tum(&dir.join("trajectory.tum"));
    // Live, a loaded machine may drop whole sweeps (counted); most must get through.
    assert!(
        trajectory.len() >= 60,
        "{} poses from 12 s",
        trajectory.len()
    );
    assert!(dir.join("map.pcd").metadata().unwrap().len() > 1000);
    let lines = echoed_lines(echo);
    let seq = sequences(&lines);
    assert_eq!(seq.len(), trajectory.len(), "the subscriber got every pose");
    assert!(
        seq.windows(2).all(|w| w[1] == w[0] + 1),
        "in order, no gaps"
    );
    // The echoed timestamps are the trajectory's.
    for (line, pose) in lines.iter().zip(&trajectory) {
        let t: f64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
        assert!((t - pose.time_ns as f64 * 1e-9).abs() < 1e-6);
    }
    // Predictions come between sweeps, flagged, never more than one sweep period (0.1 s) past
    // the latest sweep. (How many depends on the latency: none once a pose takes a whole
    // period, so only their presence and bounds are checked.)
    let predicted = echoed_lines(predicted);
    assert!(!predicted.is_empty(), "no predicted poses");
    let sweep_times: Vec<f64> = trajectory.iter().map(|p| p.time_ns as f64 * 1e-9).collect();
    for line in &predicted {
        assert!(line.contains("PREDICTED"), "{line}");
        let t: f64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
        let latest = sweep_times
            .iter()
            .rev()
            .find(|&&s| s <= t + 1e-9)
            .expect("a prediction before any sweep");
        assert!(
            t - latest <= 0.1 + 1e-3,
            "{line}: {:.4} s past the sweep",
            t - latest
        );
    }

    // Accuracy within the odometry's bounds (the first sweep defines the frame; ATE aligns).
    let groundtruth = read_tum(&dir.join("sim/groundtruth.tum"));
    let pairs = associate(&trajectory, &groundtruth);
    let ate = ate_rmse(&pairs).unwrap();
    assert!(ate.rmse < 0.10, "{ate}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The fault injector's draws: the top 31 bits of the seeded generator.
fn draw(rng: &mut SeededRng) -> u64 {
    rng.next_u64() >> 33
}

#[test]
fn garbage_loss_and_silence_are_counted_and_survived() {
    let _serial = real_time();
    let dir = scratch("faults");
    simulate(&dir, "warehouse", 32, 16.0);
    let ports = free_ports();
    let d = domain("faults");
    let config = write_config(&dir, ports, &d);
    let (mut daemon, log) = start_daemon(&config);
    let status = spawn_echo(&d, "status", 26.0);
    let echo = spawn_echo(&d, "odom", 26.0);

    // Replay the capture onto the ports at real-time pace, losing 10 % of the data packets,
    // with garbage between them and five seconds of silence (the sensor's clock runs on, as
    // it would if a cable were out).
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut reader = CaptureReader::open(&dir.join("scan.pcap")).unwrap();
    let mut rng = SeededRng::new(7);
    let (mut first, start) = (None, Instant::now());
    let (mut sent, mut lost, mut garbage) = (0u64, 0u64, 0u64);
    while let Some(record) = reader.next().unwrap() {
        let t = record.time_ns;
        let t0 = *first.get_or_insert(t);
        let since = Duration::from_nanos(t - t0);
        if since >= Duration::from_secs(5) && since < Duration::from_secs(10) {
            continue;
        }
        if let Some(wait) = since.checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
        let port = if record.destination_port == 2368 {
            ports.0
        } else {
            ports.1
        };
        if port == ports.0 && draw(&mut rng).is_multiple_of(10) {
            lost += 1;
            continue;
        }
        socket.send_to(record.payload, ("127.0.0.1", port)).unwrap();
        sent += 1;
        if draw(&mut rng).is_multiple_of(50) {
            let len = [3usize, 100, 554, 1206, 1500][draw(&mut rng) as usize % 5];
            let bytes: Vec<u8> = (0..len).map(|_| draw(&mut rng) as u8).collect();
            socket.send_to(&bytes, ("127.0.0.1", ports.0)).unwrap();
            garbage += 1;
        }
    }
    assert!(lost > 100 && garbage > 10 && sent > 1000);
    std::thread::sleep(Duration::from_millis(500));
    let (exit, _) = terminate(&mut daemon);
    assert!(exit.success(), "glintd run exited with {exit}");
    let log: Vec<String> = log.try_iter().collect();
    assert!(
        log.iter().any(|l| l.contains("no data from the sensor")),
        "silence logged:\n{}",
        log.join("\n")
    );
    assert!(log.iter().any(|l| l.contains("resumed")));
    for line in log.iter().filter(|l| l.contains("gap")) {
        eprintln!("{line}");
    }

    let statuses = echoed_lines(status);
    assert!(
        statuses.iter().any(|l| l.contains("SENSOR_SILENT")),
        "{statuses:?}"
    );
    // Silent during the gap, then not (tracking resumed), then silent again once the sender
    // stopped for good.
    let first_silent = statuses
        .iter()
        .position(|l| l.contains("SENSOR_SILENT"))
        .unwrap();
    assert!(
        statuses[first_silent..]
            .iter()
            .any(|l| !l.contains("SENSOR_SILENT")),
        "{statuses:?}"
    );

    let lines = echoed_lines(echo);
    let seq = sequences(&lines);
    assert!(seq.windows(2).all(|w| w[1] == w[0] + 1));
    let trajectory = read_tum(&dir.join("trajectory.tum"));
    assert_eq!(seq.len(), trajectory.len());
    assert!(trajectory
        .iter()
        .all(|p| p.pose.translation.vector.iter().all(|v| v.is_finite())));
    // Before the silence and after it, every pose not flagged lost is near the truth.
    let groundtruth = read_tum(&dir.join("groundtruth.tum"));
    let pairs = associate(&trajectory, &groundtruth);
    assert!(pairs.len() + 5 >= trajectory.len());
    let lost_flags = lines.iter().filter(|l| l.contains("LOST")).count();
    let silence_starts = groundtruth[0].time_ns + 5_000_000_000;
    let early: Vec<StampedPose> = trajectory
        .iter()
        .filter(|p| p.time_ns < silence_starts)
        .copied()
        .collect();
    let before = associate(&early, &groundtruth);
    let ate = ate_rmse(&before).unwrap();
    assert!(ate.rmse < 0.10, "before the silence: {ate}");
    // After it, a pose is either flagged lost or right: never a wrong pose presented as good.
    let trusted: Vec<StampedPose> = trajectory
        .iter()
        .zip(&lines)
        .filter(|(_, l)| !l.contains("LOST"))
        .map(|(p, _)| *p)
        .collect();
    let ate = ate_rmse(&associate(&trusted, &groundtruth)).unwrap();
    assert!(
        ate.rmse < 0.10,
        "{lost_flags} poses flagged lost; the others: {ate}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn consumers_and_daemons_killed_mid_stream_do_not_stop_publishing() {
    let _serial = real_time();
    let dir = scratch("kill");
    simulate(&dir, "warehouse", 33, 8.0);
    let capture = dir.join("scan.pcap");
    let d = domain("kill");
    let replay = |pace: &str| {
        glintd()
            .args([
                "replay",
                capture.to_str().unwrap(),
                "--domain",
                &d,
                "--pace",
                pace,
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    // A daemon killed without a chance to clean up ...
    let mut first = replay("realtime");
    let mut consumer = spawn_echo(&d, "odom", 30.0);
    std::thread::sleep(Duration::from_secs(3));
    first.kill().unwrap(); // SIGKILL
    first.wait().unwrap();
    // ... and a consumer killed the same way.
    consumer.kill().unwrap();
    consumer.wait().unwrap();
    // The next daemon on the same domain starts (stale resources cleaned) and publishes every
    // pose to a new consumer, while a stalled consumer that never reads is ignored.
    let stalled = glintd()
        .args(["echo", "--domain", &d, "--wait", "20", "--timeout", "30"])
        .stdout(Stdio::piped()) // never read: its pipe fills and it blocks
        .spawn()
        .unwrap();
    let echo = spawn_echo(&d, "odom", 25.0);
    let second = replay("2").wait_with_output().unwrap();
    assert!(
        second.status.success(),
        "{}",
        String::from_utf8_lossy(&second.stderr)
    );
    let seq = sequences(&echoed_lines(echo));
    assert!(seq.len() >= 70, "{} poses", seq.len());
    assert!(seq.windows(2).all(|w| w[1] == w[0] + 1));
    let mut stalled = stalled;
    let _ = stalled.kill();
    let _ = stalled.wait();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_replay_is_byte_identical_at_any_pace() {
    let dir = scratch("determinism");
    simulate(&dir, "warehouse", 34, 6.0);
    let capture = dir.join("scan.pcap");
    let run = |name: &str, pace: &str| {
        let out = dir.join(name);
        let o = glintd()
            .args([
                "replay",
                capture.to_str().unwrap(),
                "--no-publish",
                "--pace",
                pace,
                "--trajectory",
                out.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(out).unwrap()
    };
    let a = run("a.tum", "max");
    let b = run("b.tum", "max");
    let c = run("c.tum", "3");
    assert!(a.len() > 1000);
    assert!(a == b, "two replays at max pace differ");
    assert!(
        a == c,
        "a replay at 3× real time differs from one at max pace"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_bad_configuration_is_refused_naming_the_key() {
    let dir = scratch("config");
    let path = dir.join("bad.toml");
    for (text, named) in [
        ("[sensor]\ndata_prot = 2368\n", "data_prot"),
        (
            "[odometry.solver]\nhuber_geometric = -1.0\n",
            "odometry.solver.huber_geometric",
        ),
    ] {
        std::fs::write(&path, text).unwrap();
        let o = glintd()
            .args(["run", "--config", path.to_str().unwrap(), "--check"])
            .output()
            .unwrap();
        assert!(!o.status.success());
        assert!(String::from_utf8_lossy(&o.stderr).contains(named), "{text}");
    }
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/../systemd/glintd.toml");
    let o = glintd()
        .args(["run", "--config", example, "--check"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn record_captures_what_the_sensor_sends() {
    let _serial = real_time();
    let dir = scratch("record");
    let ports = free_ports();
    let out = dir.join("recorded.pcap");
    let mut recorder = glintd()
        .args([
            "record",
            "--out",
            out.to_str().unwrap(),
            "--seconds",
            "6",
            "--data-port",
            &ports.0.to_string(),
            "--position-port",
            &ports.1.to_string(),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The recorder says when it listens; the simulator starts after that, so the recording
    // holds the whole stream. Its output stays open to the end: its last line must not meet a
    // closed pipe.
    let mut said = BufReader::new(recorder.stdout.take().unwrap());
    let mut line = String::new();
    said.read_line(&mut line).unwrap();
    assert!(line.starts_with("recording ports"), "{line}");
    let sim = glintd()
        .args([
            "sim",
            "warehouse",
            "--seconds",
            "3",
            "--seed",
            "35",
            "--udp",
            "127.0.0.1",
            "--data-port",
            &ports.0.to_string(),
            "--position-port",
            &ports.1.to_string(),
        ])
        .output()
        .unwrap();
    let simulated = String::from_utf8_lossy(&sim.stdout);
    assert!(sim.status.success(), "{simulated}");
    let o = recorder.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    drop(said);
    // What was recorded replays: the same packets and sweeps as the simulator produced. The
    // recording spans the whole stream, so no sweep is cut at its edges; the first and last
    // sweeps the simulator counts are partial ones already (the stream starts and stops
    // mid-turn), and the replay counts them as sweeps too.
    let info = glintd()
        .args([
            "info",
            out.to_str().unwrap(),
            "--data-port",
            &ports.0.to_string(),
            "--position-port",
            &ports.1.to_string(),
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(
        info.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&info.stderr)
    );
    assert!(text.contains("model: VLP-16"), "{text}");
    assert!(text.contains("0 packets missing"), "{text}");
    assert!(
        text.contains("source: 127.0.0.1 (the first to send valid data)"),
        "the sender's address is recorded: {text}"
    );
    assert_eq!(
        number_after(&text, "packets: "),
        number_after(&simulated, "sweeps, "),
        "data packets: {simulated}\n{text}"
    );
    let sweeps = number_after(&simulated, "simulated, ");
    assert!(sweeps >= 25, "3 s at 10 Hz: {simulated}");
    assert_eq!(
        number_after(&text, "sweeps: "),
        sweeps,
        "sweeps: {simulated}\n{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn two_sensors_on_loopback_only_the_configured_one_is_tracked() {
    let _serial = real_time();
    let dir = scratch("two-sensors");
    let ports = free_ports();
    let d = domain("two-sensors");
    let config = write_config(&dir, ports, &d);
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(
        &config,
        text.replace("[sensor]\n", "[sensor]\nsource = \"127.0.0.2\"\n"),
    )
    .unwrap();
    let (mut daemon, log) = start_daemon(&config);
    let status = spawn_echo(&d, "status", 14.0);
    let sensor = |bind: &str, seed: &str| {
        glintd()
            .args(["sim", "warehouse", "--seconds", "5", "--seed", seed])
            .args(["--udp", "127.0.0.1", "--udp-bind", bind])
            .args(["--data-port", &ports.0.to_string()])
            .args(["--position-port", &ports.1.to_string()])
            .arg("--out")
            .arg(dir.join(bind))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    // The other sensor starts first: naming ours is what keeps it out.
    let other = sensor("127.0.0.3", "36");
    std::thread::sleep(Duration::from_millis(300));
    let ours = sensor("127.0.0.2", "35");
    for s in [other, ours] {
        let o = s.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    std::thread::sleep(Duration::from_millis(500));
    let (exit, _) = terminate(&mut daemon);
    assert!(exit.success(), "glintd run exited with {exit}");
    let log: Vec<String> = log.try_iter().collect();
    assert!(
        log.iter()
            .any(|l| l.contains("packets from 127.0.0.3 refused")),
        "{}",
        log.join("\n")
    );
    let statuses = echoed_lines(status);
    assert!(
        statuses.iter().any(|l| l.contains("FOREIGN_SENSOR")),
        "{statuses:?}"
    );
    let trajectory = read_tum(&dir.join("trajectory.tum"));
    assert!(
        trajectory.len() >= 35,
        "{} poses from 5 s",
        trajectory.len()
    );
    let groundtruth = read_tum(&dir.join("127.0.0.2/groundtruth.tum"));
    let ate = ate_rmse(&associate(&trajectory, &groundtruth)).unwrap();
    assert!(ate.rmse < 0.10, "{ate}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The whole number that follows the first `label` in a command's report.
fn number_after(text: &str, label: &str) -> u64 {
    let at = text
        .find(label)
        .unwrap_or_else(|| panic!("no {label:?} in {text}"));
    let digits: String = text[at + label.len()..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits
        .parse()
        .unwrap_or_else(|_| panic!("no number after {label:?} in {text}"))
}

#[test]
fn a_full_disk_stops_the_file_not_the_poses() {
    if !Path::new("/dev/full").exists() {
        eprintln!("skipped: no /dev/full on this machine");
        return;
    }
    let dir = scratch("full");
    simulate(&dir, "warehouse", 36, 4.0);
    let d = domain("full");
    let echo = spawn_echo(&d, "odom", 20.0);
    let o = glintd()
        .args([
            "replay",
            dir.join("scan.pcap").to_str().unwrap(),
            "--domain",
            &d,
            "--trajectory",
            "/dev/full",
            "--pace",
            "2",
        ])
        .output()
        .unwrap();
    // The run reports the lost file and fails, but only after every pose went out.
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("could not be written"), "{stderr}");
    let seq = sequences(&echoed_lines(echo));
    assert!(seq.len() >= 35, "{} poses", seq.len());
    assert!(seq.windows(2).all(|w| w[1] == w[0] + 1));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Streams `seconds` of the simulated warehouse `seed` to `ports` at real-time pace, its ground
/// truth written into `out`.
fn stream_warehouse(ports: (u16, u16), seed: &str, seconds: &str, out: &Path) {
    let o = glintd()
        .args(["sim", "warehouse", "--seconds", seconds, "--seed", seed])
        .args(["--udp", "127.0.0.1"])
        .args(["--data-port", &ports.0.to_string()])
        .args(["--position-port", &ports.1.to_string()])
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The keyframe count `glintd map info` reports.
fn map_keyframes(map: &Path) -> u64 {
    let o = glintd().args(["map", "info"]).arg(map).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    number_after(&String::from_utf8_lossy(&o.stdout), "keyframes: ")
}

#[test]
fn a_site_mapped_live_is_localised_in_and_extended_live() {
    let _serial = real_time();
    let dir = scratch("site-map");
    let site = dir.join("site.glintmap");
    let extended = dir.join("extended.glintmap");

    // Mapping: the map is written at shutdown.
    let ports = free_ports();
    let d = domain("site-mapping");
    let config = write_config(&dir, ports, &d);
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(
        &config,
        format!(
            "{text}[site_map]\nmode = \"mapping\"\npath = \"{}\"\nautosave_s = 0\n",
            site.display()
        ),
    )
    .unwrap();
    let (mut daemon, _log) = start_daemon(&config);
    stream_warehouse(ports, "33", "12", &dir.join("mapping"));
    std::thread::sleep(Duration::from_millis(500));
    let (exit, _) = terminate(&mut daemon);
    assert!(exit.success(), "glintd run exited with {exit}");
    let mapped = map_keyframes(&site);
    assert!(mapped >= 5, "{mapped} keyframes");

    // Localising along the same route and on past the mapped part: verified `map` poses, and
    // at shutdown the map extended by the new part.
    let ports = free_ports();
    let d = domain("site-localising");
    let local = dir.join("localising");
    std::fs::create_dir_all(&local).unwrap();
    let config = write_config(&local, ports, &d);
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(
        &config,
        format!(
            "{text}[site_map]\nmode = \"localisation\"\npath = \"{}\"\nextend_to = \"{}\"\n",
            site.display(),
            extended.display()
        ),
    )
    .unwrap();
    let (mut daemon, _log) = start_daemon(&config);
    let map_poses = spawn_echo(&d, "map", 30.0);
    stream_warehouse(ports, "33", "24", &local.join("sim"));
    std::thread::sleep(Duration::from_millis(500));
    let (exit, _) = terminate(&mut daemon);
    assert!(exit.success(), "glintd run exited with {exit}");
    let lines = echoed_lines(map_poses);
    let tracked = lines.iter().filter(|l| l.contains("TRACKING")).count();
    assert!(
        tracked >= 100,
        "{tracked} of {} map poses tracked",
        lines.len()
    );
    assert!(
        lines
            .iter()
            .all(|l| !(l.contains("TRACKING") && l.contains("RELOCALISING"))),
        "a map pose both tracked and relocalising"
    );
    let grown = map_keyframes(&extended);
    assert!(grown > mapped, "{mapped} keyframes extended to {grown}");
    // The saved map itself is only read.
    assert_eq!(map_keyframes(&site), mapped);
    std::fs::remove_dir_all(&dir).unwrap();
}
