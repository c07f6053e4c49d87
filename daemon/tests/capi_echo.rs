//! The C interface end to end: the C and C++ examples (`capi/examples/glint_echo.{c,cpp}`),
//! built by the system gcc and g++ against the libglint this build produced (shared for C,
//! static for C++), receive every pose `glintd replay` publishes, in order, with the very values
//! a Rust subscriber (glint-ipc) receives; and they keep receiving when the daemon is killed
//! with SIGKILL and started again.
//!
//! Why glint-capi is a dev-dependency of glintd: it makes cargo build the library (all its
//! crate types, into this test's `deps` directory) before this test runs, on a clean clone and
//! under `cargo test --workspace --locked`, without a nested cargo.
//!
//! "Every pose" needs the consumers connected before the first pose. They only open services
//! (never create them), so the test first stands in for the daemon with a glint-ipc publisher
//! of the same settings, waits until both programs print its probe pose, and lets go; the
//! subscribers keep the services alive and glintd re-opens them, the documented restart path.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};

use glint_ipc::{Domain, Frame, Pose, PosePublisher, PoseStream, PoseSubscriber, StatusFlags};

const PROBE: u64 = u64::MAX;

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn capi_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../capi")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-capi-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The `libglint.<ext>` cargo built for this test (the dev-dependency) in the test's own `deps`
/// directory, so always the one of this profile and this source, copied to `dir`. Cargo gives
/// cdylib and staticlib outputs no hash suffix today; a `libglint-<hash>.<ext>` is accepted too
/// (the newest wins) should that change.
fn library(dir: &Path, ext: &str) -> PathBuf {
    let deps = std::env::current_exe()
        .unwrap()
        .parent()
        .expect("the test runs from target/<profile>/deps")
        .to_path_buf();
    let newest = std::fs::read_dir(&deps)
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name == format!("libglint.{ext}")
                || (name.starts_with("libglint-") && name.ends_with(&format!(".{ext}")))
        })
        .max_by_key(|p| p.metadata().and_then(|m| m.modified()).ok())
        .unwrap_or_else(|| panic!("no libglint.{ext} in {}", deps.display()));
    let to = dir.join(format!("libglint.{ext}"));
    std::fs::copy(&newest, &to).unwrap();
    to
}

fn build(compiler: &str, args: &[&str], out: &Path) {
    let o = Command::new(compiler)
        .args(args)
        .arg("-o")
        .arg(out)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {compiler}: {e}"));
    assert!(
        o.status.success(),
        "{compiler} {args:?}:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Builds the C example against libglint.so and the C++ example against libglint.a, as the
/// README tells a controller project to.
fn examples(dir: &Path) -> (PathBuf, PathBuf) {
    let so = library(dir, "so");
    let a = library(dir, "a");
    let include = capi_dir().join("include");
    let include = include.to_str().unwrap();
    let lib_dir = so.parent().unwrap().to_str().unwrap();
    let c_exe = dir.join("glint_echo");
    let c_src = capi_dir().join("examples/glint_echo.c");
    build(
        "gcc",
        &[
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-I",
            include,
            c_src.to_str().unwrap(),
            "-L",
            lib_dir,
            "-lglint",
            &format!("-Wl,-rpath,{lib_dir}"),
        ],
        &c_exe,
    );
    let cpp_exe = dir.join("glint_echo_cpp");
    let cpp_src = capi_dir().join("examples/glint_echo.cpp");
    let mut args = vec![
        "-std=c++11",
        "-Wall",
        "-Wextra",
        "-Werror",
        "-I",
        include,
        cpp_src.to_str().unwrap(),
        a.to_str().unwrap(),
    ];
    // What a Rust static library needs from the system on Linux (also in capi/glint.pc.in).
    args.extend(["-lpthread", "-ldl", "-lm", "-lrt", "-lgcc_s"]);
    build("g++", &args, &cpp_exe);
    (c_exe, cpp_exe)
}

/// A consumer program whose stdout lines arrive on a channel.
struct Consumer {
    child: Child,
    lines: Receiver<String>,
    got: Vec<Line>,
    connected: bool,
}

/// One printed pose: sequence, timestamp, position and orientation as bit patterns, status.
#[derive(Debug, PartialEq)]
struct Line {
    sequence: u64,
    timestamp_ns: u64,
    values: [u64; 7],
    status: u32,
}

impl Line {
    fn parse(text: &str) -> Self {
        let f: Vec<&str> = text.split_whitespace().collect();
        assert_eq!(f.len(), 10, "{text}");
        let mut values = [0u64; 7];
        for (v, s) in values.iter_mut().zip(&f[2..9]) {
            // 17 significant digits convert back to the same double.
            *v = s.parse::<f64>().unwrap().to_bits();
        }
        Self {
            sequence: f[0].parse().unwrap(),
            timestamp_ns: f[1].parse().unwrap(),
            values,
            status: u32::from_str_radix(f[9].trim_start_matches("0x"), 16).unwrap(),
        }
    }

    fn of(p: &Pose) -> Self {
        let [x, y, z] = p.position;
        let [qx, qy, qz, qw] = p.orientation;
        Self {
            sequence: p.sequence,
            timestamp_ns: p.timestamp_ns,
            values: [x, y, z, qx, qy, qz, qw].map(f64::to_bits),
            status: p.status.bits(),
        }
    }
}

impl Consumer {
    fn spawn(exe: &Path, domain: &str) -> Self {
        let mut child = Command::new(exe)
            .arg(domain)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let stdout = child.stdout.take().unwrap();
        let (tx, lines) = mpsc::channel();
        thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Self {
            child,
            lines,
            got: Vec::new(),
            connected: false,
        }
    }

    /// Collects lines until `enough` holds of them or `within` passes.
    fn collect_until(&mut self, within: Duration, enough: impl Fn(&[Line]) -> bool) {
        let deadline = Instant::now() + within;
        while !enough(&self.got) {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) => {
                    let line = Line::parse(&l);
                    // Once connected, further probes (sent while others connect) are noise.
                    if !(self.connected && line.sequence == PROBE) {
                        self.got.push(line);
                    }
                }
                Err(_) => break,
            }
        }
    }

    fn stop(mut self) -> Vec<Line> {
        let _ = self.child.kill();
        let _ = self.child.wait();
        self.got
    }
}

/// A Rust subscriber collecting every pose on a thread until stopped.
struct RustConsumer {
    stop: Arc<AtomicBool>,
    thread: thread::JoinHandle<Vec<Pose>>,
}

impl RustConsumer {
    fn start(domain: &Domain) -> Self {
        let sub = PoseSubscriber::open(domain, PoseStream::Odom).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = thread::spawn(move || {
            let mut got = Vec::new();
            loop {
                match sub.wait_next(Duration::from_millis(200)).unwrap() {
                    Some(p) if p.sequence != PROBE => got.push(p),
                    Some(_) => {}
                    None if flag.load(Ordering::Relaxed) => return got,
                    None => {}
                }
            }
        });
        Self { stop, thread }
    }

    fn finish(self) -> Vec<Pose> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().unwrap()
    }
}

/// Stands in for the daemon until every consumer printed the probe pose, so all are connected;
/// returns the stand-in, to be dropped before glintd starts.
fn connect(domain: &Domain, consumers: &mut [&mut Consumer]) -> PosePublisher {
    let stand_in = PosePublisher::create(domain).unwrap();
    let probe = Pose::new(PROBE, 0, Frame::ODOM);
    let deadline = Instant::now() + Duration::from_secs(30);
    for c in consumers.iter_mut() {
        while !c.got.iter().any(|l| l.sequence == PROBE) {
            assert!(Instant::now() < deadline, "a consumer never connected");
            stand_in.publish_odom(&probe).unwrap();
            c.collect_until(Duration::from_millis(50), |got| {
                got.iter().any(|l| l.sequence == PROBE)
            });
        }
        c.got.clear();
        c.connected = true;
    }
    stand_in
}

fn simulate(dir: &Path, seconds: &str, seed: &str) -> PathBuf {
    let sim = glintd()
        .args([
            "sim",
            "warehouse",
            "--seconds",
            seconds,
            "--seed",
            seed,
            "--out",
        ])
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );
    dir.join("scan.pcap")
}

/// Starts `glintd replay`, its log in `<trajectory>.log` (a file, so that an unread pipe can
/// never stall it).
fn replay(capture: &Path, domain: &Domain, trajectory: &Path) -> Child {
    let log = std::fs::File::create(trajectory.with_extension("log")).unwrap();
    glintd()
        .arg("replay")
        .arg(capture)
        .args(["--domain", domain.as_str(), "--trajectory"])
        .arg(trajectory)
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .unwrap()
}

/// Runs a replay to its end; the number of sweeps (trajectory lines) it published.
fn replay_to_end(capture: &Path, domain: &Domain, trajectory: &Path) -> usize {
    let status = replay(capture, domain, trajectory).wait().unwrap();
    let log = std::fs::read_to_string(trajectory.with_extension("log")).unwrap_or_default();
    assert!(status.success(), "glintd replay failed:\n{log}");
    std::fs::read_to_string(trajectory).unwrap().lines().count()
}

#[test]
fn c_and_cpp_examples_receive_every_pose_the_rust_subscriber_receives() {
    let dir = scratch("echo");
    let (c_exe, cpp_exe) = examples(&dir);
    let capture = simulate(&dir, "4", "21");
    let domain = Domain::new(&format!("test-capi-{}", std::process::id())).unwrap();

    let mut c = Consumer::spawn(&c_exe, domain.as_str());
    let mut cpp = Consumer::spawn(&cpp_exe, domain.as_str());
    let stand_in = connect(&domain, &mut [&mut c, &mut cpp]);
    let rust = RustConsumer::start(&domain);
    drop(stand_in);

    let sweeps = replay_to_end(&capture, &domain, &dir.join("trajectory.tum"));
    assert!(sweeps >= 20, "a 4 s capture has ~40 sweeps, got {sweeps}");

    let poses = rust.finish();
    // Tracked poses carry the alignment's covariance: symmetric, and on the warehouse's
    // well-constrained geometry a few millimetres (the old nominal 2 cm, or the 2 m of an
    // unmeasured pose, would fail).
    let tracked: Vec<&Pose> = poses
        .iter()
        .filter(|p| p.status.contains(StatusFlags::TRACKING))
        .collect();
    assert!(
        tracked.len() + 2 >= poses.len(),
        "{} tracked",
        tracked.len()
    );
    for p in tracked {
        let c = p.covariance;
        for i in 0..6 {
            for j in 0..6 {
                assert_eq!(c[i * 6 + j], c[j * 6 + i], "{c:?}");
            }
        }
        for i in 0..3 {
            let sigma = c[i * 7].sqrt();
            assert!(
                (0.004..0.015).contains(&sigma),
                "position 1σ {sigma}: {c:?}"
            );
        }
    }
    let expected: Vec<Line> = poses.iter().map(Line::of).collect();
    assert_eq!(
        expected.len(),
        sweeps,
        "the Rust subscriber got one pose per sweep"
    );
    for (i, l) in expected.iter().enumerate() {
        assert_eq!(l.sequence, i as u64, "from the first pose, no gap");
    }
    for (name, consumer) in [("C", c), ("C++", cpp)] {
        let mut consumer = consumer;
        consumer.collect_until(Duration::from_secs(20), |got| got.len() >= expected.len());
        let got = consumer.stop();
        assert_eq!(got, expected, "{name} example");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn c_example_keeps_receiving_across_a_sigkilled_daemon() {
    let dir = scratch("kill");
    let (c_exe, _) = examples(&dir);
    let capture = simulate(&dir, "6", "22");
    let domain = Domain::new(&format!("test-capi-kill-{}", std::process::id())).unwrap();
    let mut c = Consumer::spawn(&c_exe, domain.as_str());
    drop(connect(&domain, &mut [&mut c]));

    // The first daemon dies mid-stream, without a chance to clean up.
    let mut first = replay(&capture, &domain, &dir.join("first.tum"));
    c.collect_until(Duration::from_secs(60), |got| got.len() >= 5);
    first.kill().unwrap();
    first.wait().unwrap();
    let before = c.got.len();
    assert!(before >= 5, "poses before the kill: {before}");

    // A new daemon on the same domain: it cleans the dead one's resources and the example,
    // never reopened, receives its stream from sequence 0 to the end.
    let sweeps = replay_to_end(&capture, &domain, &dir.join("second.tum"));
    c.collect_until(Duration::from_secs(20), |got| {
        got.last().is_some_and(|l| l.sequence + 1 == sweeps as u64)
    });
    let got = c.stop();
    let after: Vec<u64> = got[before..].iter().map(|l| l.sequence).collect();
    let restart = after
        .iter()
        .position(|s| *s == 0)
        .unwrap_or_else(|| panic!("the restarted daemon's first pose: {after:?}"));
    assert_eq!(
        after[restart..].to_vec(),
        (0..sweeps as u64).collect::<Vec<_>>(),
        "every pose of the restarted daemon, in order"
    );
    std::fs::remove_dir_all(dir).unwrap();
}
