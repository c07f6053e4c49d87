//! `glint_send_initial_pose`: the C example (`examples/glint_initial_pose.c`), built by the
//! system gcc against the libglint.so of this build, sends a hint that an
//! `InitialPoseSubscriber` created here (standing in for glintd) receives with the very values
//! given; without a daemon, or with a NaN, it fails with the documented code and message. The
//! function is also called directly (through the rlib) for its error buffer.

use core::ffi::{c_char, CStr};
use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::thread;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use glint::error::{GLINT_ERR_INVALID_ARGUMENT, GLINT_ERR_NOT_RUNNING};
use glint::glint_send_initial_pose;
use glint_ipc::{settings, Domain, Frame, InitialPose, InitialPoseSubscriber};

fn capi_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn unique(tag: &str) -> String {
    format!("capi-ip-{tag}-{}", std::process::id())
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-capi-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The `libglint.so` cargo built for this test (this package's cdylib, in the test's own `deps`
/// directory), as `daemon/tests/capi_echo.rs` finds it.
fn library_dir() -> PathBuf {
    let deps = std::env::current_exe()
        .unwrap()
        .parent()
        .expect("the test runs from target/<profile>/deps")
        .to_path_buf();
    let found = std::fs::read_dir(&deps)
        .unwrap()
        .filter_map(Result::ok)
        .any(|e| e.file_name() == "libglint.so");
    assert!(found, "no libglint.so in {}", deps.display());
    deps
}

/// Builds the C example as the README tells a controller project to.
fn example(dir: &Path) -> PathBuf {
    let lib_dir = library_dir();
    let lib_dir = lib_dir.to_str().unwrap();
    let exe = dir.join("glint_initial_pose");
    let out = Command::new("gcc")
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-I"])
        .arg(capi_dir().join("include"))
        .arg(capi_dir().join("examples/glint_initial_pose.c"))
        .args([
            "-L",
            lib_dir,
            "-lglint",
            &format!("-Wl,-rpath,{lib_dir}"),
            "-o",
        ])
        .arg(&exe)
        .output()
        .expect("run gcc");
    assert!(
        out.status.success(),
        "gcc:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    exe
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn c_example_sends_a_hint_the_daemon_side_receives() {
    let dir = scratch("initial-pose");
    let exe = example(&dir);
    let domain = Domain::new(&unique("roundtrip")).unwrap();
    let daemon = InitialPoseSubscriber::create(&domain).unwrap();

    let before = now_ns();
    let child = Command::new(&exe)
        .args([domain.as_str(), "12.5", "-3.25", "1.25", "0.5"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Poll as glintd does, while the example lingers.
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut got = None;
    while got.is_none() && Instant::now() < deadline {
        got = daemon.try_next().unwrap();
        thread::sleep(settings::INITIAL_POSE_MAX_POLL_INTERVAL / 5);
    }
    let out: Output = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).starts_with("sent x=12.5 y=-3.25 yaw=1.25 sigma=0.5"));

    let hint = got.expect("the hint arrived");
    let expected = InitialPose::on_floor(hint.timestamp_ns, 12.5, -3.25, 1.25, 0.5);
    assert_eq!(hint, expected, "the same bits as Rust computes");
    assert_eq!(hint.frame, Frame::MAP);
    assert!((before..=now_ns()).contains(&hint.timestamp_ns));
    assert_eq!(daemon.rejected(), 0);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn c_example_says_why_it_cannot_send() {
    let dir = scratch("initial-pose-errors");
    let exe = example(&dir);

    let absent = unique("absent");
    let out = Command::new(&exe)
        .args([&absent, "1", "2", "0"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(
        // iceoryx2 may warn first (no config file), so look for the line, not the start.
        err.contains("GLINT_ERR_NOT_RUNNING: ")
            && err.contains(&format!("glint/{absent}/initial_pose")),
        "{err}"
    );

    // strtod reads "nan": the library, not the example, refuses it.
    let domain = Domain::new(&unique("nan")).unwrap();
    let daemon = InitialPoseSubscriber::create(&domain).unwrap();
    let out = Command::new(&exe)
        .args([domain.as_str(), "nan", "2", "0"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("GLINT_ERR_INVALID_ARGUMENT: ") && err.contains("not finite"),
        "{err}"
    );
    assert_eq!(daemon.try_next().unwrap(), None);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_error_buffer_is_truncated_terminated_and_optional() {
    let domain = CString::new(unique("buffer")).unwrap();
    let mut small = [b'x' as c_char; 8];
    // SAFETY: a NUL-terminated domain; `small` is writable for its length.
    let rc = unsafe {
        glint_send_initial_pose(
            domain.as_ptr(),
            1.0,
            2.0,
            0.0,
            0.0,
            small.as_mut_ptr(),
            small.len(),
        )
    };
    assert_eq!(rc, GLINT_ERR_NOT_RUNNING);
    // SAFETY: the library NUL-terminated it within its 8 bytes.
    let message = unsafe { CStr::from_ptr(small.as_ptr()) };
    assert_eq!(message.to_bytes(), b"service");

    // SAFETY: a null error buffer is allowed; so is a null domain (refused, not dereferenced).
    let rc = unsafe {
        glint_send_initial_pose(
            core::ptr::null(),
            1.0,
            2.0,
            0.0,
            -1.0,
            core::ptr::null_mut(),
            0,
        )
    };
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);
    let mut buffer = [0 as c_char; 256];
    // SAFETY: as above, with a 256-byte buffer.
    let rc = unsafe {
        glint_send_initial_pose(
            domain.as_ptr(),
            1.0,
            2.0,
            0.0,
            -1.0,
            buffer.as_mut_ptr(),
            buffer.len(),
        )
    };
    assert_eq!(rc, GLINT_ERR_INVALID_ARGUMENT);
    // SAFETY: NUL-terminated by the library.
    let message = unsafe { CStr::from_ptr(buffer.as_ptr()) }.to_string_lossy();
    assert!(message.contains("position_sigma is -1"), "{message}");
}
