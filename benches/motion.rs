//! Benchmarks of the `motion` stage: adaptive block matching on 40x40 and 80x80 targets and
//! the direct ellipse fit on 200 points.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use pftrack::frames::GrayF32;
use pftrack::geometry::Ellipse;
use pftrack::motion::{AbmParams, block_match, fit_ellipse};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// A smooth random texture (value noise on a 3-px lattice) shifted by `(dx, dy)`.
fn texture(w: u32, h: u32, dx: f64, dy: f64) -> GrayF32 {
    let n = 160usize;
    let mut rng = StdRng::seed_from_u64(11);
    let v: Vec<f32> = (0..n * n).map(|_| rng.random_range(0.0..1.0)).collect();
    let mut g = GrayF32::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let (gx, gy) = ((x as f64 - dx) / 3.0 + 5.0, (y as f64 - dy) / 3.0 + 5.0);
            let (x0, y0) = (gx.floor(), gy.floor());
            let (fx, fy) = ((gx - x0) as f32, (gy - y0) as f32);
            let at = |i: f64, j: f64| v[(j as usize % n) * n + (i as usize % n)];
            let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1.0, y0) * fx;
            let bot = at(x0, y0 + 1.0) * (1.0 - fx) + at(x0 + 1.0, y0 + 1.0) * fx;
            g.data[(y * w + x) as usize] = top * (1.0 - fy) + bot * fy;
        }
    }
    g
}

fn bench_abm(c: &mut Criterion) {
    let (w, h) = (320, 240);
    let prev = texture(w, h, 0.0, 0.0);
    let cur = texture(w, h, 3.0, -2.0);
    let small = Ellipse::new(160.0, 120.0, 20.0, 20.0);
    let large = Ellipse::new(160.0, 120.0, 40.0, 40.0);
    c.bench_function("block_match 40x40 target, block 8, ±10", |b| {
        let p = AbmParams::default();
        b.iter(|| block_match(black_box(&prev), black_box(&cur), &small, &p).unwrap())
    });
    // With sensor-like noise the best SAD is not zero, so fewer positions are eliminated
    // early: closer to real footage.
    let mut noisy = cur.clone();
    let mut rng = StdRng::seed_from_u64(3);
    for v in noisy.data.iter_mut() {
        *v = (*v + rng.random_range(-0.03f32..0.03)).clamp(0.0, 1.0);
    }
    c.bench_function("block_match 40x40 target, block 8, ±10, noisy", |b| {
        let p = AbmParams::default();
        b.iter(|| block_match(black_box(&prev), black_box(&noisy), &small, &p).unwrap())
    });
    c.bench_function(
        "block_match 80x80 target, for_target (block 16, ±20)",
        |b| {
            let p = AbmParams::for_target(&large);
            b.iter(|| block_match(black_box(&prev), black_box(&cur), &large, &p).unwrap())
        },
    );
    c.bench_function("block_match 80x80 target, block 8, ±10", |b| {
        let p = AbmParams::default();
        b.iter(|| block_match(black_box(&prev), black_box(&cur), &large, &p).unwrap())
    });
}

fn bench_fit(c: &mut Criterion) {
    let mut rng = StdRng::seed_from_u64(5);
    let e = Ellipse {
        cx: 100.0,
        cy: 80.0,
        a: 30.0,
        b: 18.0,
        theta: 0.4,
    };
    let pts: Vec<[f64; 2]> = (0..200)
        .map(|k| {
            let (x, y) = e.point_at(k as f64 * std::f64::consts::TAU / 200.0);
            [
                x + rng.random_range(-0.5..0.5),
                y + rng.random_range(-0.5..0.5),
            ]
        })
        .collect();
    c.bench_function("fit_ellipse 200 points", |b| {
        b.iter(|| fit_ellipse(black_box(&pts)).unwrap())
    });
}

criterion_group! {
    name = benches;
    // Plots need system fonts that a bare machine lacks (criterion panics without them).
    config = Criterion::default().without_plots();
    targets = bench_abm, bench_fit
}
criterion_main!(benches);
