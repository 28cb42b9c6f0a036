//! Benchmarks of the `likelihood` stage (criterion): the whole CPU pass (colour, gradient and
//! feature terms, per-frame preparation included) for N = 200, 1k, 10k, 100k particles, on one
//! thread and on all threads, at 160x120 (a ~40 px target, the tracker's working size) and
//! 640x480 (the same scene scaled 4x); and the three terms alone at 160x120, N = 200, with
//! the tracker's appearance template (`likelihood::template`: the plain and the turned
//! correlation of 200 particles, 16x16 grid, one thread).
//! The GPU engine (`likelihood_gpu/...`) runs the same frames and particles when a Vulkan
//! adapter exists (upload, all kernels and readback included, as a tracker pays them; the
//! contrast term, which the tracker adds by default and reads from the same histograms, is
//! left out, as in `pftrack bench`).
//!
//! `PFTRACK_BENCH_MAX_N` caps N (a 100k pass takes minutes on a software Vulkan device and on
//! 2 cores).
//!
//! The frame is synthesised: a smooth colour gradient background with pseudo-random texture
//! and an elliptical target of its own colours and texture, so histograms spread over many
//! bins and normal lines meet both the target's edge and clutter.

use std::hint::black_box;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use image::{Rgb, RgbImage};
use pftrack::frames::GrayF32;
use pftrack::geometry::Ellipse;
use pftrack::likelihood::cpu::CpuEngine;
use pftrack::likelihood::gpu::GpuEngine;
use pftrack::likelihood::template::{FirstView, Template};
use pftrack::likelihood::{
    COLOUR_RGB, ColourHistogram, FeaturePair, FrameInput, LikelihoodEngine, LikelihoodParams,
    Particle, TERM_COLOUR, TERM_FEATURE, TERM_GRADIENT,
};
use rand::{Rng, SeedableRng, rngs::StdRng};

/// A textured frame with an elliptical target of semi-axes `(20, 24) · scale` at its centre.
fn scene(scale: u32) -> (RgbImage, Ellipse) {
    let (w, h) = (160 * scale, 120 * scale);
    let target = Ellipse::new(
        w as f64 / 2.0 + 3.0,
        h as f64 / 2.0 - 2.0,
        20.0 * scale as f64,
        24.0 * scale as f64,
    );
    let mut rng = StdRng::seed_from_u64(1);
    let img = RgbImage::from_fn(w, h, |x, y| {
        let n: u8 = rng.random_range(0..48);
        let (fx, fy) = (x as f64 / w as f64, y as f64 / h as f64);
        if target.contains(x as f64, y as f64) {
            let (u, v) = target.to_unit(x as f64, y as f64);
            Rgb([
                (180.0 + 40.0 * u) as u8 + n / 2,
                (120.0 + 40.0 * v) as u8 + n / 2,
                (60.0 + n as f64) as u8,
            ])
        } else {
            Rgb([
                (40.0 + 150.0 * fx) as u8 + n,
                (60.0 + 120.0 * fy) as u8 + n,
                (200.0 - 100.0 * fx) as u8 + n / 2,
            ])
        }
    });
    (img, target)
}

fn prev_of(e: &Ellipse) -> Particle {
    Particle {
        cx: e.cx as f32,
        cy: e.cy as f32,
        a: e.a as f32,
        b: e.b as f32,
        ..Default::default()
    }
}

/// `n` particles spread around the target as a tracker's proposal spreads them.
fn particles(e: &Ellipse, n: usize, scale: f32) -> Vec<Particle> {
    let p = prev_of(e);
    let mut rng = StdRng::seed_from_u64(2);
    (0..n)
        .map(|_| Particle {
            cx: p.cx + scale * rng.random_range(-4.0..4.0),
            cy: p.cy + scale * rng.random_range(-4.0..4.0),
            a: p.a * rng.random_range(0.9..1.1),
            b: p.b * rng.random_range(0.9..1.1),
            rx: rng.random_range(-0.2..0.2),
            ry: rng.random_range(-0.2..0.2),
            rz: rng.random_range(-0.2..0.2),
            _pad: 0.0,
        })
        .collect()
}

/// 40 matched features inside the target, moved by one pixel.
fn features(e: &Ellipse) -> Vec<FeaturePair> {
    let mut rng = StdRng::seed_from_u64(3);
    (0..40)
        .map(|_| {
            let x = (e.cx + e.a * rng.random_range(-0.7..0.7)) as f32;
            let y = (e.cy + e.b * rng.random_range(-0.7..0.7)) as f32;
            FeaturePair {
                p: [x, y],
                q: [x + 1.0, y],
            }
        })
        .collect()
}

/// Particle counts, capped by `PFTRACK_BENCH_MAX_N`.
fn counts() -> Vec<usize> {
    let max_n: usize = std::env::var("PFTRACK_BENCH_MAX_N")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(usize::MAX);
    [200usize, 1000, 10000, 100000]
        .into_iter()
        .filter(|&n| n <= max_n)
        .collect()
}

fn whole_pass(c: &mut Criterion) {
    let all = rayon::current_num_threads();
    for scale in [1u32, 4] {
        let (img, target) = scene(scale);
        let feats = features(&target);
        let frame = FrameInput {
            image: &img,
            features: &feats,
            depths: None,
            prev: prev_of(&target),
            theta0: 0.0,
        };
        let model = ColourHistogram::from_ellipse(&img, &target, COLOUR_RGB).expect("model");
        let params = LikelihoodParams::default();
        let mut group =
            c.benchmark_group(format!("likelihood_cpu/{}x{}", img.width(), img.height()));
        group.sample_size(10);
        group.warm_up_time(Duration::from_millis(300));
        group.measurement_time(Duration::from_secs(2));
        for n in counts() {
            let ps = particles(&target, n, scale as f32);
            // One entry when the pool has one thread (`taskset -c 0`, `RAYON_NUM_THREADS=1`):
            // two would give criterion the same ID twice, which it refuses with a panic.
            let mut thread_counts = vec![1];
            if all > 1 {
                thread_counts.push(all);
            }
            for threads in thread_counts {
                let mut eng = if threads == 1 {
                    CpuEngine::with_threads(1).expect("engine")
                } else {
                    CpuEngine::new()
                };
                eng.set_colour_model(&model).expect("model");
                let mut out = Vec::new();
                group.bench_with_input(
                    BenchmarkId::new(format!("{threads}thr"), n),
                    &ps,
                    |b, ps| {
                        b.iter(|| {
                            eng.evaluate(&frame, &params, black_box(ps), &mut out)
                                .expect("evaluate");
                            black_box(&out);
                        })
                    },
                );
            }
        }
        group.finish();
    }
}

fn per_term(c: &mut Criterion) {
    let (img, target) = scene(1);
    let feats = features(&target);
    let frame = FrameInput {
        image: &img,
        features: &feats,
        depths: None,
        prev: prev_of(&target),
        theta0: 0.0,
    };
    let model = ColourHistogram::from_ellipse(&img, &target, COLOUR_RGB).expect("model");
    let ps = particles(&target, 200, 1.0);
    let mut group = c.benchmark_group("likelihood_cpu_terms/160x120/1thr/200");
    group.sample_size(20);
    group.warm_up_time(Duration::from_millis(300));
    group.measurement_time(Duration::from_secs(2));
    for (name, terms) in [
        ("colour", TERM_COLOUR),
        ("gradient", TERM_GRADIENT),
        ("feature", TERM_FEATURE),
    ] {
        let params = LikelihoodParams {
            terms,
            ..Default::default()
        };
        let mut eng = CpuEngine::with_threads(1).expect("engine");
        eng.set_colour_model(&model).expect("model");
        let mut out = Vec::new();
        group.bench_function(name, |b| {
            b.iter(|| {
                eng.evaluate(&frame, &params, black_box(&ps), &mut out)
                    .expect("evaluate");
                black_box(&out);
            })
        });
    }
    // The template terms run on rayon's pool: one thread, as the terms above.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let gray = GrayF32::from_rgb(&img);
    let first = prev_of(&target);
    let template = Template::new(&gray, &first, 0.0, 16);
    let view = FirstView::weak(first);
    let mut ncc = Vec::new();
    group.bench_function("template", |b| {
        b.iter(|| {
            pool.install(|| template.correlate(&gray, black_box(&ps), 0.0, &mut ncc));
            black_box(&ncc);
        })
    });
    group.bench_function("template turned", |b| {
        b.iter(|| {
            pool.install(|| template.correlate_turned(&gray, black_box(&ps), 0.0, &view, &mut ncc));
            black_box(&ncc);
        })
    });
    group.finish();
}

/// The GPU engine on the scenes and particles of [`whole_pass`].
fn gpu_pass(c: &mut Criterion) {
    let mut gpu = match GpuEngine::new() {
        Ok(g) => g,
        Err(e) => {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "GPU benches skipped: {e}");
            return;
        }
    };
    for scale in [1u32, 4] {
        let (img, target) = scene(scale);
        let feats = features(&target);
        let frame = FrameInput {
            image: &img,
            features: &feats,
            depths: None,
            prev: prev_of(&target),
            theta0: 0.0,
        };
        let model = ColourHistogram::from_ellipse(&img, &target, COLOUR_RGB).expect("model");
        gpu.set_colour_model(&model).expect("model");
        let params = LikelihoodParams::default();
        let mut group =
            c.benchmark_group(format!("likelihood_gpu/{}x{}", img.width(), img.height()));
        group.sample_size(10);
        group.warm_up_time(Duration::from_millis(300));
        group.measurement_time(Duration::from_secs(2));
        for n in counts() {
            let ps = particles(&target, n, scale as f32);
            let mut out = Vec::new();
            group.bench_with_input(BenchmarkId::new("gpu", n), &ps, |b, ps| {
                b.iter(|| {
                    gpu.evaluate(&frame, &params, black_box(ps), &mut out)
                        .expect("evaluate");
                    black_box(&out);
                })
            });
        }
        group.finish();
    }
}

criterion_group! {
    name = benches;
    // No plots: plotters needs system fonts that CI machines may lack.
    config = Criterion::default().without_plots();
    targets = whole_pass, per_term, gpu_pass
}
criterion_main!(benches);
