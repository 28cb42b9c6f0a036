//! Benchmarks of the `likelihood` stage (criterion): one full likelihood pass (all terms) over
//! N particles, CPU on 1 thread, CPU on all threads, and the GPU engine (when a Vulkan adapter
//! exists), at 160x120 and 640x480, N = 200, 1k, 10k, 100k, on the synthetic workload of
//! `pftrack::likelihood::gpu::workload` (the same as `pftrack bench`).
//!
//! `PFTRACK_BENCH_MAX_N` caps N (a 100k pass takes minutes on a software Vulkan device);
//! `PFTRACK_BENCH_SIZES` picks sizes, e.g. `160x120`.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::io::Write;
use std::time::Duration;

use pftrack::likelihood::cpu::CpuEngine;
use pftrack::likelihood::gpu::GpuEngine;
use pftrack::likelihood::gpu::workload::{particles, workload};
use pftrack::likelihood::{FrameInput, LikelihoodEngine};

const SIZES: [(u32, u32); 2] = [(160, 120), (640, 480)];
const COUNTS: [usize; 4] = [200, 1_000, 10_000, 100_000];

fn likelihood(c: &mut Criterion) {
    let max_n: usize = std::env::var("PFTRACK_BENCH_MAX_N")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(usize::MAX);
    let sizes = std::env::var("PFTRACK_BENCH_SIZES").unwrap_or_default();
    let mut gpu = match GpuEngine::new() {
        Ok(g) => Some(g),
        Err(e) => {
            let _ = writeln!(std::io::stderr(), "GPU benches skipped: {e}");
            None
        }
    };
    let mut cpu1 = CpuEngine::with_threads(1).expect("one thread");
    let mut cpu_all = CpuEngine::new();
    for (w, h) in SIZES {
        if !sizes.is_empty() && !sizes.split(',').any(|s| s == format!("{w}x{h}")) {
            continue;
        }
        let wl = workload(w, h, 1).expect("workload");
        let frame = FrameInput {
            image: &wl.image,
            features: &wl.features,
            prev: wl.target,
            theta0: 0.0,
        };
        cpu1.set_colour_model(&wl.model).unwrap();
        cpu_all.set_colour_model(&wl.model).unwrap();
        if let Some(g) = gpu.as_mut() {
            g.set_colour_model(&wl.model).unwrap();
        }
        let mut group = c.benchmark_group(format!("likelihood_{w}x{h}"));
        group.sample_size(10);
        group.warm_up_time(Duration::from_millis(500));
        group.measurement_time(Duration::from_secs(3));
        for n in COUNTS.into_iter().filter(|&n| n <= max_n) {
            let ps = particles(&wl.target, n, 7);
            let mut out = Vec::new();
            let mut engines: Vec<(&str, &mut dyn LikelihoodEngine)> =
                vec![("cpu_1t", &mut cpu1), ("cpu_all", &mut cpu_all)];
            if let Some(g) = gpu.as_mut() {
                engines.push(("gpu", g));
            }
            for (name, engine) in engines {
                group.bench_with_input(BenchmarkId::new(name, n), &ps, |b, ps| {
                    b.iter(|| {
                        engine
                            .evaluate(&frame, &wl.params, black_box(ps), &mut out)
                            .unwrap();
                        black_box(&out);
                    })
                });
            }
        }
        group.finish();
    }
}

criterion_group! {
    name = benches;
    // No plots: plotters needs system fonts that CI machines may lack.
    config = Criterion::default().without_plots();
    targets = likelihood
}
criterion_main!(benches);
