//! Benchmarks of the `filter` stage and of the whole tracker step.
//!
//! - `filter propose+update N`: one frame of the particle filter without the likelihood
//!   (proposal from the rotation-candidate mixture, weighting, estimate, resampling) at
//!   N = 200, 1000, 10000 particles, on fixed pseudo-random log-likelihoods.
//! - `systematic resampling N`.
//! - `tracker step WxH, N particles`: [`Tracker::step`] on the synthetic `nod` head (SIFT,
//!   matching, Sylvester, keyframe fit, block matching, filter, CPU likelihoods on all
//!   threads) at 128x96, 160x120 and 320x240 with 200 particles, and at 160x120 with 1000 and
//!   10000; and at 160x120 with 200 particles without the re-anchoring on the first view
//!   (`, no re-anchoring`), without the turned first view (`, no turned first view`) and
//!   without the appearance template (`, no template`), to show what each costs. Run it
//!   under `taskset -c 0` (and `RAYON_NUM_THREADS=1`) for one core.
//! - `tracker step WxH, N particles, gpu`: the same step with the likelihoods on the GPU
//!   engine (the adapter `PFTRACK_ADAPTER` names, or the best one) at 160x120 with 200 and
//!   10000 particles and at 320x240 with 200; skipped with a note when no Vulkan adapter
//!   opens.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use pftrack::filter::{FilterParams, Hypothesis, Motion, ParticleFilter, resample};
use pftrack::geometry::{Euler, PoseState};
use pftrack::likelihood::{Backend, create_engine};
use pftrack::synth::{Renderer, Scenario, SynthConfig};
use pftrack::tracker::{Init, Tracker, TrackerConfig};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn start() -> Hypothesis {
    Hypothesis::from_state(&PoseState {
        cx: 80.0,
        cy: 60.0,
        a: 18.0,
        b: 24.0,
        rx: 0.0,
        ry: 0.0,
        rz: 0.0,
    })
}

fn bench_filter(c: &mut Criterion) {
    let mut g = c.benchmark_group("filter propose+update");
    for n in [200usize, 1000, 10000] {
        let params = FilterParams {
            particles: n,
            ..FilterParams::default()
        };
        let mut f = ParticleFilter::new(params, 1, &start()).expect("valid filter settings");
        let mut rng = StdRng::seed_from_u64(2);
        let lik: Vec<f32> = (0..n).map(|_| rng.random_range(-40.0f32..0.0)).collect();
        let motion = Motion {
            dx: 0.5,
            dy: -0.3,
            scale: 1.0,
            rotations: vec![
                (0.5, Euler::from_degrees(1.0, 0.0, 0.0).matrix()),
                (0.5, Euler::from_degrees(-1.0, 0.0, 0.0).matrix()),
            ],
        };
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                f.propose(black_box(&motion), 1.0);
                let info = f.update(black_box(&lik));
                black_box((info, f.estimate()))
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("systematic resampling");
    for n in [200usize, 1000, 10000] {
        let mut rng = StdRng::seed_from_u64(3);
        let log_w: Vec<f64> = (0..n).map(|_| rng.random_range(-20.0..0.0)).collect();
        let w = resample::normalise_log_weights(&log_w);
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, &n| {
            b.iter(|| resample::systematic(black_box(&w), n, 0.37))
        });
    }
    g.finish();
}

fn bench_tracker(c: &mut Criterion) {
    let mut g = c.benchmark_group("tracker step");
    g.sample_size(20);
    // The last field is what of the appearance template is on (`Full`, `NoReanchor`: without
    // the re-anchoring on the first view, `NoAnchor`: without the turned first view, which
    // the re-anchoring needs too, `Off`), to show what each part costs.
    // `Gpu` is the whole template on the GPU likelihood engine.
    enum Tpl {
        Full,
        NoReanchor,
        NoAnchor,
        Off,
        Gpu,
    }
    let mut gpu_note = None;
    for (w, h, n, template) in [
        (128u32, 96u32, 200usize, Tpl::Full),
        (160, 120, 200, Tpl::Full),
        (160, 120, 200, Tpl::NoReanchor),
        (160, 120, 200, Tpl::NoAnchor),
        (160, 120, 200, Tpl::Off),
        (320, 240, 200, Tpl::Full),
        (160, 120, 1000, Tpl::Full),
        (160, 120, 10000, Tpl::Full),
        (160, 120, 200, Tpl::Gpu),
        (320, 240, 200, Tpl::Gpu),
        (160, 120, 10000, Tpl::Gpu),
    ] {
        let cfg = SynthConfig {
            width: w,
            height: h,
            frames: 60,
            ..SynthConfig::new(Scenario::Nod)
        };
        let Ok(r) = Renderer::new(&cfg) else {
            continue;
        };
        let frames: Vec<image::RgbImage> = (0..cfg.frames).map(|k| r.render(k).0).collect();
        let mut tc = TrackerConfig::default();
        tc.filter.particles = n;
        match template {
            Tpl::Full => {}
            Tpl::NoReanchor => tc.reanchor = None,
            Tpl::NoAnchor => {
                if let Some(t) = tc.template.as_mut() {
                    t.anchor_weight = 0.0;
                }
            }
            Tpl::Off => tc.template = None,
            Tpl::Gpu => {}
        }
        let init = Init::frontal(r.init_ellipse());
        let made = if let Tpl::Gpu = template {
            match create_engine(Backend::Gpu) {
                Ok((engine, _)) => Tracker::with_engine(tc, engine, &frames[0], init),
                Err(e) => {
                    gpu_note.get_or_insert_with(|| e.to_string());
                    continue;
                }
            }
        } else {
            Tracker::new(tc, &frames[0], init)
        };
        let Ok(mut t) = made else {
            continue;
        };
        let mut k = 1;
        let name = match template {
            Tpl::Full => format!("{w}x{h}, {n} particles"),
            Tpl::NoReanchor => format!("{w}x{h}, {n} particles, no re-anchoring"),
            Tpl::NoAnchor => format!("{w}x{h}, {n} particles, no turned first view"),
            Tpl::Off => format!("{w}x{h}, {n} particles, no template"),
            Tpl::Gpu => format!("{w}x{h}, {n} particles, gpu"),
        };
        g.bench_function(name, |b| {
            // Only the steps are timed: the restart on the first frame (SIFT, the colour
            // model, the templates) is not a step's cost. A failed step fails the bench, as a
            // failed tracker returns at once and would time nothing.
            b.iter_custom(|iters| {
                let mut spent = std::time::Duration::ZERO;
                for _ in 0..iters {
                    if k == frames.len() {
                        // Start over on the first frame so every step sees a real motion.
                        t.reinit(&frames[0], init).expect("reinit");
                        k = 1;
                    }
                    let t0 = std::time::Instant::now();
                    let e = t.step(black_box(&frames[k])).expect("step");
                    spent += t0.elapsed();
                    black_box(e);
                    k += 1;
                }
                spent
            })
        });
    }
    g.finish();
    if let Some(e) = gpu_note {
        println!("note: no GPU rows of the tracker step ({e})");
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = bench_filter, bench_tracker
}
criterion_main!(benches);
