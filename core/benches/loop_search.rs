//! The back end's per-keyframe costs that grow or repeat: the Intensity Scan Context of a
//! keyframe's cloud, and the candidate search over 10,000 stored keyframes (ring-key
//! pre-filter over all of them, shift search on the best few), every one eligible — the worst
//! case, with no position gate.
//!
//!     cargo bench -p glint-core --bench loop_search

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use glint_core::backend::config::ScanContextConfig;
use glint_core::backend::loop_closure::search;
use glint_core::backend::scan_context::ScanContext;
use nalgebra::Vector3;

/// A deterministic pseudo-random place: walls at varied ranges, patches of varied reflectivity.
fn place(seed: u64, points: usize) -> Vec<(Vector3<f32>, f32)> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    let walls: Vec<f32> = (0..12).map(|_| 3.0 + 30.0 * next()).collect();
    let paint: Vec<f32> = (0..24).map(|_| 100.0 * next()).collect();
    (0..points)
        .map(|i| {
            let a = i as f32 * std::f32::consts::TAU / points as f32;
            let sector = (a / std::f32::consts::TAU * 12.0) as usize % 12;
            let r = walls[sector] * (0.8 + 0.2 * next());
            let eta = paint[(sector * 2 + (next() > 0.5) as usize) % 24];
            (
                Vector3::new(r * a.cos(), r * a.sin(), 2.0 * next() - 0.7),
                eta,
            )
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let config = ScanContextConfig::default();
    let cloud = place(1, 3000);
    c.bench_function("scan context of a 3000-point keyframe", |b| {
        b.iter(|| ScanContext::new(black_box(cloud.iter().copied()), &config))
    });
    let stored: Vec<ScanContext> = (0..10_000)
        .map(|k| ScanContext::new(place(k + 2, 600), &config))
        .collect();
    let query = ScanContext::new(place(5_000, 600), &config);
    c.bench_function("candidate search over 10000 keyframes", |b| {
        b.iter(|| search(black_box(&query), &stored, |_| true, &config))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
