//! `glint-view` end to end: 10 s of a simulated warehouse replayed at the sensor's pace on a
//! domain of its own while `glint-view --save` records it. The recording is then read back with
//! the `rerun-sdk` Python package (`check_recording.py`), which must find a `world/robot`
//! transform for every sweep the replay published (but the first, which may come before the
//! viewer attached), point clouds, the keyframes of `map_update` and the chain joining them, and
//! the sensor's timeline spanning the replay's poses; and it is shown in rerun's web viewer in
//! headless Chromium (`browser.py`), which must draw it, not an empty viewer.
//!
//! Needs `glintd` built beside `glint-view` (`cargo test --workspace` builds both),
//! `rerun-sdk==0.36.3` for Python 3 (`examples/python/requirements.txt`) and, for the browser,
//! Debian's `chromium` and `chromium-driver` (`.ci/run` installs all of them).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

fn glint_view() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glint-view"))
}

/// `glintd`, from the same target directory and profile.
fn glintd() -> Command {
    let path = Path::new(env!("CARGO_BIN_EXE_glint-view")).with_file_name("glintd");
    assert!(
        path.exists(),
        "{} is missing: build it first (`cargo build -p glintd`, or `cargo test --workspace`)",
        path.display()
    );
    Command::new(path)
}

/// A directory of the test target's own, emptied first (the recording is ~40 MB: it stays in
/// `target/`, not in the system's temporary directory).
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("glint-view-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn rerun_sdk() -> bool {
    glint_testkit::python_module("rerun", "pip install -r examples/python/requirements.txt")
}

fn chromium() -> bool {
    let install = "apt-get install chromium chromium-driver";
    glint_testkit::program("chromium", install) && glint_testkit::program("chromedriver", install)
}

/// Stamps (ns) of a TUM trajectory's lines.
fn stamps(tum: &Path) -> Vec<u64> {
    std::fs::read_to_string(tum)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let t: &str = l.split_whitespace().next().unwrap();
            let (s, frac) = t.split_once('.').unwrap_or((t, "0"));
            let frac = format!("{frac:0<9}");
            s.parse::<u64>().unwrap() * 1_000_000_000 + frac[..9].parse::<u64>().unwrap()
        })
        .collect()
}

/// The replay's recording and the stamps of the sweeps it published.
struct Recorded {
    rrd: PathBuf,
    sweeps: Vec<u64>,
}

/// Records the replay once for every test of this file (the first to ask waits for it).
fn recorded() -> &'static Recorded {
    static RECORDED: OnceLock<Recorded> = OnceLock::new();
    RECORDED.get_or_init(record)
}

fn record() -> Recorded {
    let dir = scratch("save");
    let run = dir.join("run");
    assert!(glintd()
        .args([
            "sim",
            "warehouse",
            "--seed",
            "12",
            "--seconds",
            "10",
            "--out"
        ])
        .arg(&run)
        .stdout(Stdio::null())
        .status()
        .unwrap()
        .success());
    let domain = format!("view-e2e-{}", std::process::id());
    let rrd = dir.join("view.rrd");
    // The viewer first, as an operator would have it open before the robot starts.
    let mut view = glint_view()
        .args([
            "--domain",
            &domain,
            "--idle-exit",
            "3",
            "--seconds",
            "120",
            "--save",
        ])
        .arg(&rrd)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let trajectory = dir.join("odom.tum");
    let replay = glintd()
        .arg("replay")
        .arg(run.join("scan.pcap"))
        .args(["--pace", "realtime", "--domain", &domain])
        .arg("--odom-trajectory")
        .arg(&trajectory)
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(replay.success());
    let started = Instant::now();
    let status = loop {
        if let Some(status) = view.try_wait().unwrap() {
            break status;
        }
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "glint-view did not stop after the replay"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let output = view.wait_with_output().unwrap();
    assert!(
        status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let sweeps = stamps(&trajectory);
    assert!(sweeps.len() >= 90, "{} sweeps replayed", sweeps.len());
    Recorded { rrd, sweeps }
}

/// What one of this directory's Python scripts printed, one `name value` per line.
struct Report(String);

impl Report {
    fn run(name: &str, args: &[&Path]) -> Report {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests")
            .join(name);
        let out = Command::new("python3")
            .arg(&path)
            .args(args)
            .output()
            .unwrap();
        let report = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{name}: {report}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        Report(report)
    }

    fn get<T: std::str::FromStr>(&self, key: &str) -> T {
        let text = self
            .0
            .lines()
            .find_map(|l| l.strip_prefix(&format!("{key} ")))
            .unwrap_or_else(|| panic!("no {key} in {}", self.0));
        text.trim()
            .parse()
            .unwrap_or_else(|_| panic!("{key}: {text:?} is not a number"))
    }
}

#[test]
fn a_replay_viewed_and_saved_reads_back_with_a_transform_per_sweep() {
    if !rerun_sdk() {
        return;
    }
    let Recorded { rrd, sweeps } = recorded();
    let report = Report::run("check_recording.py", &[rrd]);
    let transforms: usize = report.get("transforms");
    assert!(
        transforms + 1 >= sweeps.len() && transforms <= sweeps.len(),
        "{transforms} transforms for {} sweeps",
        sweeps.len()
    );
    assert!(report.get::<usize>("sweep_clouds") + 1 >= sweeps.len());
    assert!(report.get::<usize>("map_clouds") >= 1);
    // The daemon's keyframes (map_update) and the chain joining them.
    assert!(report.get::<usize>("keyframes") >= 1);
    assert!(report.get::<usize>("odometry_lines") >= 1);
    // The sensor's timeline carries the poses' own stamps.
    let (first, last): (u64, u64) = (report.get("time_min_ns"), report.get("time_max_ns"));
    assert!(
        first <= sweeps[1] && first >= sweeps[0],
        "{first} vs {:?}",
        &sweeps[..2]
    );
    assert_eq!(last, *sweeps.last().unwrap());
}

#[test]
fn the_recording_shows_in_a_browser_not_an_empty_viewer() {
    if !rerun_sdk() || !chromium() {
        return;
    }
    let Recorded { rrd, .. } = recorded();
    let shots = scratch("browser");
    let report = Report::run("browser.py", &[rrd, &shots]);
    let differing: f64 = report.get("differing");
    let drawn: f64 = report.get("ramp_pixels_recording");
    let empty: f64 = report.get("ramp_pixels_empty");
    // The empty viewer is a welcome page; the recording fills the layout with the map, the sweep
    // and the plots. Screenshots stay in target/tmp/glint-view-browser for a look.
    assert!(differing > 0.2, "only {differing} of the pixels differ");
    assert!(
        drawn >= 1000.0 && drawn >= 10.0 * empty.max(1.0),
        "{drawn} point-coloured pixels with the recording, {empty} without"
    );
}
