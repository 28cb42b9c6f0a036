//! Benchmarks of the `pose` stage (criterion): each 2D solver on 20, 50 and 100 matches of
//! noisy weak-perspective data (Fig. 3 setup at 20 dB), Necker completion, Kabsch.

use criterion::{Criterion, criterion_group, criterion_main};
use pftrack::pose::noise::{NoiseConfig, make_trial};
use pftrack::pose::{SolverKind, complete_rotation, kabsch, solver};
use rand::{SeedableRng, rngs::StdRng};
use std::hint::black_box;

fn solvers(c: &mut Criterion) {
    for n in [20usize, 50, 100] {
        let cfg = NoiseConfig {
            points: n,
            ..NoiseConfig::default()
        };
        let trials: Vec<_> = (0..16u64)
            .map(|k| make_trial(&cfg, &mut StdRng::seed_from_u64(k), Some(20.0)).unwrap())
            .collect();
        for kind in SolverKind::ALL {
            let s = solver(kind);
            let mut i = 0;
            c.bench_function(&format!("pose/{}/{n}", kind.name()), |b| {
                b.iter(|| {
                    let t = &trials[i % trials.len()];
                    i += 1;
                    black_box(s.solve(black_box(&t.p), black_box(&t.q)).unwrap())
                })
            });
        }
    }
    let t = make_trial(
        &NoiseConfig::default(),
        &mut StdRng::seed_from_u64(1),
        Some(20.0),
    )
    .unwrap();
    let r2 = solver(SolverKind::Sea).solve(&t.p, &t.q).unwrap().r2;
    c.bench_function("pose/complete_rotation", |b| {
        b.iter(|| black_box(complete_rotation(black_box(&r2)).unwrap()))
    });
    let p3: Vec<[f64; 3]> = (0..50)
        .map(|i| {
            let f = i as f64;
            [f.sin(), (1.3 * f).cos(), (0.7 * f).sin()]
        })
        .collect();
    let q3: Vec<[f64; 3]> = p3.iter().map(|p| [p[1], -p[0], p[2] + 1.0]).collect();
    c.bench_function("pose/kabsch/50", |b| {
        b.iter(|| black_box(kabsch(black_box(&p3), black_box(&q3)).unwrap()))
    });
}

// No plots: criterion's plotters backend needs a registered font (plotters is built with
// ab_glyph here and has no system font lookup), so plotting would panic.
criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = solvers
}
criterion_main!(benches);
