//! Simulation speed per scenario: firings (rays) per second and sensor seconds per second of
//! one core (× real time), in strongest-return mode at 600 rpm with noise on. Scene and
//! trajectory construction are outside the timed part.
//!
//! Besides criterion's figures (throughput in rays/s, wall clock), each scenario prints one
//! line measured over 4 s of sensor time, in wall-clock time and — where Linux reports it — in
//! the thread's own CPU time, which other processes on a shared machine do not inflate:
//! `warehouse: 3.51 M rays/s, 12.1× real time (CPU: 3.60 M rays/s, 12.4×) …`.

use std::hint::black_box;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use glint_sim::{Scenario, SimConfig, Simulation};

/// Sensor time per criterion iteration, s.
const ITERATION_SECONDS: f64 = 0.5;
/// Sensor time of the printed summary, s.
const SUMMARY_SECONDS: f64 = 4.0;

fn run(config: &SimConfig) -> u64 {
    let mut sim = Simulation::new(config).expect("valid configuration");
    while let Some(p) = sim.next_packet() {
        black_box(p.payload);
    }
    sim.stats().rays
}

/// CPU time this thread has run, s (Linux scheduler statistics), if available.
fn thread_cpu_seconds() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = text.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

fn simulate(c: &mut Criterion) {
    let mut group = c.benchmark_group("simulate");
    group.sample_size(10);
    for scenario in Scenario::ALL {
        let config = SimConfig {
            scenario,
            seed: 1,
            seconds: SUMMARY_SECONDS,
            ..SimConfig::default()
        };
        let cpu_start = thread_cpu_seconds();
        let start = Instant::now();
        let rays = run(&config);
        let elapsed = start.elapsed().as_secs_f64();
        let cpu = match (cpu_start, thread_cpu_seconds()) {
            (Some(a), Some(b)) if b > a => {
                format!(
                    " (CPU: {:.2} M rays/s, {:.1}×)",
                    rays as f64 / (b - a) / 1e6,
                    SUMMARY_SECONDS / (b - a)
                )
            }
            _ => String::new(),
        };
        println!(
            "{scenario}: {:.2} M rays/s, {:.1}× real time{cpu} — {rays} rays for {SUMMARY_SECONDS} s of sensor time in {elapsed:.2} s, one core",
            rays as f64 / elapsed / 1e6,
            SUMMARY_SECONDS / elapsed
        );
        let config = SimConfig {
            seconds: ITERATION_SECONDS,
            ..config
        };
        let rays = run(&config);
        group.throughput(Throughput::Elements(rays));
        group.bench_function(scenario.name(), |b| {
            b.iter_batched(
                || Simulation::new(&config).expect("valid configuration"),
                |mut sim| {
                    while let Some(p) = sim.next_packet() {
                        black_box(p.payload);
                    }
                    sim.stats().rays
                },
                BatchSize::LargeInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, simulate);
criterion_main!(benches);
