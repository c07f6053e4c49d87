//! What Glint's tests and benches share, as a dev-dependency only: finding the real captures and
//! public benchmarks in `../shared/data` beside the workspace, the Python modules and programs
//! some tests drive, and one seeded random generator, so every test draws the same numbers on
//! every machine without a dependency.

use std::collections::HashSet;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;

/// The folder of real data, relative to the workspace root, as messages name it.
const SHARED_DATA: &str = "../shared/data";

/// The path of `name` in `../shared/data` beside the workspace, or `None` when it is absent.
///
/// `group` names what cannot run without it ("real VLP-16 captures"): the first absence in a
/// group prints one line to stderr, so a run says once what it skipped rather than once per
/// test. Under `CI=true` an absence panics instead: CI must run everything.
pub fn shared_data(group: &str, name: &str) -> Option<PathBuf> {
    find(&workspace_root().join(SHARED_DATA), group, name, under_ci())
}

/// The workspace root: this crate sits one level below it, so the path holds from any crate's
/// tests, whatever their working directory.
fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the testkit lies inside the workspace")
        .to_path_buf()
}

fn find(dir: &Path, group: &str, name: &str, ci: bool) -> Option<PathBuf> {
    let path = dir.join(name);
    if path.exists() {
        return Some(path);
    }
    if ci {
        panic!(
            "{}: {SHARED_DATA}/{name} is absent ({}); CI must run with shared/ beside the repository",
            group,
            path.display()
        );
    }
    if first_skip(group) {
        // Straight to stderr: the test harness captures `eprintln!`, and a skip must show.
        let _ = writeln!(
            std::io::stderr(),
            "skipped: {group}: {SHARED_DATA}/{name} is absent"
        );
    }
    None
}

/// Whether `python3` imports `module`.
pub fn python_imports(module: &str) -> bool {
    let mut probe = Command::new("python3");
    probe.args(["-c", &format!("import {module}")]);
    succeeds(probe)
}

/// Whether a test that needs the Python module `module` can run: when `python3` cannot import
/// it, one line on stderr says the test is skipped and how to `install` it, and under `CI=true`
/// it panics instead (`.ci/run` installs every module the tests use).
pub fn python_module(module: &str, install: &str) -> bool {
    required(
        python_imports(module),
        &format!("python3 module {module}"),
        install,
        under_ci(),
    )
}

/// Whether a test that needs `program` can run (`program --version` succeeds); when it cannot,
/// as for [`python_module`].
pub fn program(program: &str, install: &str) -> bool {
    let mut probe = Command::new(program);
    probe.arg("--version");
    required(succeeds(probe), program, install, under_ci())
}

fn succeeds(mut probe: Command) -> bool {
    probe
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn under_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true")
}

fn required(present: bool, what: &str, install: &str, ci: bool) -> bool {
    if !present {
        assert!(!ci, "{what} is missing ({install}); CI must run every test");
        let _ = writeln!(std::io::stderr(), "skipped: {what} is missing ({install})");
    }
    present
}

/// Whether `group` skips for the first time in this process.
fn first_skip(group: &str) -> bool {
    static SKIPPED: Mutex<Option<HashSet<String>>> = Mutex::new(None);
    let mut skipped = SKIPPED.lock().unwrap_or_else(|e| e.into_inner());
    skipped
        .get_or_insert_with(HashSet::new)
        .insert(group.to_owned())
}

/// A 64-bit linear congruential generator with Knuth's MMIX constants: tests' and benches'
/// inputs, fixed by the seed. Its low bits cycle quickly, so every draw below uses the high ones.
#[derive(Clone, Debug)]
pub struct SeededRng(u64);

impl SeededRng {
    const MULTIPLIER: u64 = 6364136223846793005;
    const INCREMENT: u64 = 1442695040888963407;

    /// The sequence fixed by `seed`; any seed, zero included, is good.
    pub const fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next state, all 64 bits (take the high ones for a smaller number).
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(Self::MULTIPLIER)
            .wrapping_add(Self::INCREMENT);
        self.0
    }

    /// Uniform in [0, 1), from the top 53 bits.
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [−0.5, 0.5).
    pub fn centred(&mut self) -> f64 {
        self.unit() - 0.5
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform in 0..n, for n below 2³².
    pub fn below(&mut self, n: usize) -> usize {
        assert!(n > 0 && n as u64 <= u32::MAX as u64, "below({n})");
        (((self.next_u64() >> 32) * n as u64) >> 32) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sequence_is_knuths_mmix_lcg() {
        // Test data drawn before this crate existed depends on these exact numbers.
        let mut rng = SeededRng::new(0);
        assert_eq!(rng.next_u64(), 1442695040888963407);
        assert_eq!(rng.next_u64(), 1876011003808476466);
        let mut one = SeededRng::new(1);
        assert_eq!(one.next_u64(), 7806831264735756412);
    }

    #[test]
    fn draws_stay_in_their_ranges_and_cover_them() {
        let mut rng = SeededRng::new(11);
        let (mut low, mut high) = (f64::INFINITY, f64::NEG_INFINITY);
        let mut counts = [0usize; 7];
        for _ in 0..10_000 {
            let c = rng.centred();
            assert!((-0.5..0.5).contains(&c), "{c}");
            low = low.min(c);
            high = high.max(c);
            let u = rng.uniform(-3.0, 4.0);
            assert!((-3.0..4.0).contains(&u), "{u}");
            counts[rng.below(7)] += 1;
        }
        assert!(low < -0.499 && high > 0.499, "{low} {high}");
        // 10,000 draws over 7 bins: about 1,429 each, a binomial σ of 35.
        assert!(
            counts.iter().all(|&n| (1250..1600).contains(&n)),
            "{counts:?}"
        );
    }

    #[test]
    fn an_absent_file_is_skipped_with_one_line_per_group() {
        let dir = workspace_root().join(SHARED_DATA);
        let group = "the testkit's own absent file";
        assert_eq!(find(&dir, group, "no-such-file.pcap", false), None);
        assert!(!first_skip(group), "the group was announced once already");
        assert_eq!(find(&dir, group, "no-such-file-either.pcap", false), None);
        assert!(first_skip("another group"));
    }

    #[test]
    #[should_panic(expected = "CI must run with shared/")]
    fn an_absent_file_fails_under_ci() {
        find(
            Path::new("/nonexistent"),
            "under CI",
            "no-such-file.pcap",
            true,
        );
    }

    #[test]
    fn a_present_file_is_found() {
        let here = Path::new(env!("CARGO_MANIFEST_DIR"));
        assert_eq!(
            find(here, "testkit", "Cargo.toml", true),
            Some(here.join("Cargo.toml"))
        );
    }

    #[test]
    fn a_missing_tool_skips_outside_ci_and_fails_under_it() {
        assert!(required(true, "python3 module present", "-", true));
        assert!(!required(false, "python3 module absent", "-", false));
        let under_ci = std::panic::catch_unwind(|| required(false, "chromium", "apt-get", true));
        assert!(under_ci.is_err());
        assert!(!python_imports("glint_no_such_module"));
    }
}
