//! A `sweep` consumer: prints, for each sweep glintd publishes on a domain, its sequence, stamp,
//! point count and how many points are edges, planes and intensity points, and the nearest
//! return's distance from `base_link`. Polls every 10 ms (the service has no event service).
//!
//! ```sh
//! cargo run -p glint-ipc --example count_points -- --domain default --sweeps 20
//! ```

use std::process::ExitCode;
use std::time::{Duration, Instant};

use glint_ipc::{Domain, PointLabel, SweepSubscriber};

const USAGE: &str = "usage: count_points --domain NAME [--sweeps N (default: until Ctrl-C)] \
     [--timeout S (default 10: give up after this long without a sweep)]";

fn main() -> ExitCode {
    let mut domain = None;
    let mut sweeps = u64::MAX;
    let mut timeout = Duration::from_secs(10);
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let value = args.next();
        let parsed = match (flag.as_str(), value.as_deref()) {
            ("--domain", Some(v)) => Domain::new(v).map(|d| domain = Some(d)).is_ok(),
            ("--sweeps", Some(v)) => v.parse().map(|n| sweeps = n).is_ok(),
            ("--timeout", Some(v)) => v
                .parse::<f64>()
                .ok()
                .filter(|s| s.is_finite() && *s > 0.0)
                .map(|s| timeout = Duration::from_secs_f64(s))
                .is_some(),
            _ => false,
        };
        if !parsed {
            eprintln!("{USAGE}");
            return ExitCode::from(2);
        }
    }
    let Some(domain) = domain else {
        eprintln!("{USAGE}");
        return ExitCode::from(2);
    };
    let subscriber = match SweepSubscriber::open(&domain) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("count_points: {e}");
            return ExitCode::FAILURE;
        }
    };
    let mut seen = 0;
    let mut last = Instant::now();
    while seen < sweeps {
        let line = subscriber.try_next(|header, points| {
            let count = |label| points.iter().filter(|p| p.label.contains(label)).count();
            let nearest = points
                .iter()
                .map(|p| p.position.iter().map(|v| v * v).sum::<f32>().sqrt())
                .fold(f32::INFINITY, f32::min);
            format!(
                "sweep {} t {} ns: {} points, {} edges, {} planes, {} intensity; nearest {:.2} m",
                header.sequence,
                header.timestamp_ns,
                header.point_count,
                count(PointLabel::EDGE),
                count(PointLabel::PLANE),
                count(PointLabel::INTENSITY),
                nearest
            )
        });
        match line {
            Ok(Some(line)) => {
                println!("{line}");
                seen += 1;
                last = Instant::now();
            }
            Ok(None) if last.elapsed() > timeout => {
                eprintln!("count_points: no sweep for {timeout:?}");
                return ExitCode::FAILURE;
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => {
                eprintln!("count_points: {e}");
                return ExitCode::FAILURE;
            }
        }
    }
    ExitCode::SUCCESS
}
