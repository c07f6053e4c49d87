//! A stand-in for `glintd` on the bus: publishes a robot driving a 2 m circle on `odom`, `map`
//! and `predicted`, and a status message every tenth pose, in a given domain. For trying the
//! Python and Rust subscribers without a sensor.
//!
//! ```sh
//! cargo run -p glint-ipc --example publish_demo -- --domain demo --count 100 --rate 10
//! ```

use std::process::ExitCode;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use glint_ipc::{Domain, Frame, Pose, PosePublisher, Status, StatusFlags};

struct Args {
    domain: Domain,
    count: u64,
    rate_hz: f64,
    /// Seconds to wait before the first pose, so consumers started alongside can open first.
    delay_s: f64,
    /// Seconds to stay up after the last pose, handing the history to late subscribers.
    linger_s: f64,
}

const USAGE: &str = "usage: publish_demo --domain NAME [--count N (default 50)] \
     [--rate HZ (default 10)] [--delay S (default 0)] [--linger S (default 0)]";

fn parse_args() -> Result<Args, String> {
    let mut domain = None;
    let mut count = 50;
    let mut rate_hz: f64 = 10.0;
    let mut delay_s: f64 = 0.0;
    let mut linger_s: f64 = 0.0;
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let mut value = || args.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--domain" => domain = Some(Domain::new(&value()?).map_err(|e| e.to_string())?),
            "--count" => count = value()?.parse().map_err(|e| format!("--count: {e}"))?,
            "--rate" => rate_hz = value()?.parse().map_err(|e| format!("--rate: {e}"))?,
            "--delay" => delay_s = value()?.parse().map_err(|e| format!("--delay: {e}"))?,
            "--linger" => linger_s = value()?.parse().map_err(|e| format!("--linger: {e}"))?,
            "-h" | "--help" => return Err(USAGE.to_owned()),
            other => return Err(format!("unknown argument {other}\n{USAGE}")),
        }
    }
    let seconds = |s: f64| s >= 0.0 && s.is_finite();
    if !(rate_hz > 0.0 && rate_hz.is_finite() && seconds(delay_s) && seconds(linger_s)) {
        return Err("--rate must be positive, --delay and --linger non-negative".to_owned());
    }
    Ok(Args {
        domain: domain.ok_or(USAGE)?,
        count,
        rate_hz,
        delay_s,
        linger_s,
    })
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// The pose after `t` seconds on a circle of radius 2 m at 0.5 rad/s, facing along the path.
fn circle_pose(sequence: u64, timestamp_ns: u64, t: f64, frame: Frame) -> Pose {
    const RADIUS: f64 = 2.0;
    const OMEGA: f64 = 0.5;
    let angle = OMEGA * t;
    let yaw = angle + std::f64::consts::FRAC_PI_2;
    let mut pose = Pose::new(sequence, timestamp_ns, frame);
    pose.position = [RADIUS * angle.cos(), RADIUS * angle.sin(), 0.0];
    pose.orientation = [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()];
    pose.linear_velocity = [RADIUS * OMEGA, 0.0, 0.0];
    pose.angular_velocity = [0.0, 0.0, OMEGA];
    for (i, variance) in [1e-4, 1e-4, 4e-4, 1e-5, 1e-5, 4e-5].into_iter().enumerate() {
        pose.covariance[i * 6 + i] = variance;
    }
    pose.quality = 0.9;
    pose.status = StatusFlags::TRACKING;
    pose
}

fn run(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    let publisher = PosePublisher::create(&args.domain)?;
    let cleanup = publisher.dead_node_cleanup();
    eprintln!(
        "publishing {} poses at {} Hz on glint/{}/{{odom,map,predicted,status}} (cleaned {} dead nodes)",
        args.count, args.rate_hz, args.domain, cleanup.cleaned
    );
    std::thread::sleep(Duration::from_secs_f64(args.delay_s));

    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    for sequence in 1..=args.count {
        let t = (sequence - 1) as f64 * period.as_secs_f64();
        let stamp = now_ns();
        publisher.publish_odom(&circle_pose(sequence, stamp, t, Frame::ODOM))?;
        publisher.publish_map(&circle_pose(sequence, stamp, t, Frame::MAP))?;
        let mut predicted = circle_pose(sequence, stamp + 50_000_000, t + 0.05, Frame::ODOM);
        predicted.status |= StatusFlags::PREDICTED;
        publisher.publish_predicted(&predicted)?;
        if sequence % 10 == 1 {
            let mut status = Status::new(sequence / 10 + 1, stamp);
            status.sweeps_processed = sequence;
            status.sweep_rate_hz = args.rate_hz as f32;
            status.flags = StatusFlags::TRACKING;
            publisher.publish_status(&status)?;
        }
        std::thread::sleep(period);
    }

    // What the daemon's status tick does while no pose flows: connect late subscribers and hand
    // them the last pose of each stream.
    let tick = Duration::from_millis(100);
    let mut lingered = Duration::ZERO;
    while lingered.as_secs_f64() < args.linger_s {
        publisher.update_connections()?;
        std::thread::sleep(tick);
        lingered += tick;
    }
    Ok(())
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(args) => args,
        Err(message) => {
            eprintln!("{message}");
            return ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("publish_demo: {error}");
            let mut source = error.source();
            while let Some(cause) = source {
                eprintln!("  caused by: {cause}");
                source = cause.source();
            }
            ExitCode::FAILURE
        }
    }
}
