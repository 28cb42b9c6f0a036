//! The whole tracker on the GPU likelihood engine against the CPU engine on synthetic
//! sequences, through the library and through `pftrack track --backend gpu`; and the tracker's
//! behaviour when the GPU device is lost or no Vulkan driver exists.
//!
//! Without a Vulkan adapter every test skips with a printed reason, unless
//! `PFTRACK_REQUIRE_GPU=1` (CI), where a missing adapter fails.
//!
//! # How the tracks are compared
//!
//! The two engines' log-likelihoods differ by ~1e-5 (summation order, ulps of exp/ln; see
//! `tests/gpu.rs`). Everything else in the tracker is the same code with the same seed, so the
//! two runs draw the same random numbers and stay within ~1e-4 px and ~1e-3° of each other
//! (the [`TIGHT`] tolerance) until a discrete decision comes out differently. The usual one is
//! systematic resampling: when a comb tooth lies closer to a cumulative-weight boundary than the
//! two runs' cumulative weights differ (a tie, ~1e-6 apart), the GPU run draws the
//! neighbouring particle. From there the runs are two different samples of the same filter and
//! separate by its Monte Carlo spread. So per frame:
//!
//! 1. While no discrete decision has differed, the estimates agree within [`TIGHT`], and each
//!    resampling draws with the same comb offset from weights whose running sums agree within
//!    [`TOL_CUM_WEIGHT`]. A resampling whose index sets differ must be a tie
//!    (`max_cumulative_difference >= systematic_margin`).
//! 2. After a differing decision (an index flip at a tie, a different resampling decision, a
//!    different number of feature matches, a particle's likelihood that flipped) the estimates
//!    may leave [`TIGHT`]; a departure without such a decision before it fails the test. A
//!    flip: the two runs' particles differ by ~1e-6 px, and when one's ellipse passes that
//!    close to a pixel centre (colour) or an edge sample (gradient), the pixel goes in for one
//!    run and out for the other; that particle's log-weight then differs by 1e-3 to 1 while
//!    the others agree within ~5e-5 (measured on pan and nod). More than [`MAX_FLIPS`] at
//!    once fails the test: that is the engines disagreeing, not a flip.
//! 3. After the departure the GPU run is one more Monte Carlo run of the tracker: its distance
//!    to the reference CPU run may be at most [`ENVELOPE_FACTOR`] times the largest distance
//!    of CPU runs with other seeds to the reference, up to that frame.

use std::io::Write;
use std::process::Command;

use pftrack::filter::Resampling;
use pftrack::filter::resample::{max_cumulative_difference, systematic_margin};
use pftrack::likelihood::cpu::CpuEngine;
use pftrack::likelihood::gpu::GpuEngine;
use pftrack::likelihood::{FallbackEngine, LikelihoodEngine, LikelihoodError};
use pftrack::synth::{Renderer, Scenario, SynthConfig};
use pftrack::tracker::{Estimate, Init, Tracker, TrackerConfig};

mod common;
use common::{engine, engine_alone, skip};

/// Frames tracked per scenario: short, so CI stays cheap (one 160x120 frame takes a few ms of
/// likelihood and ~20 ms of SIFT and matching).
const FRAMES: usize = 20;
/// Seeds of the CPU runs that measure the tracker's Monte Carlo spread.
const OTHER_SEEDS: [u64; 4] = [1, 2, 3, 4];

/// Agreement while the runs are synchronised: centre and semi-axes in pixels, angles in
/// degrees. Log-likelihoods within ~2e-5 of each other change the normalised weights by a
/// relative ~4e-5, and the weighted mean by that times the particles' spread (~1.5 px, ~2°);
/// the estimate feeds the next frame's motion, so the difference builds up over the frames.
/// Measured over 20 frames of nod, pan and roll: at most 5.4e-5 px and 2.1e-4°, below these
/// bounds by a factor of 20 and 50.
const TIGHT: Diff = Diff {
    centre: 1e-3,
    axes: 1e-3,
    angles: 1e-2,
};
/// Largest difference allowed between the running sums of the two runs' normalised weights
/// while they are synchronised (as in `tests/gpu.rs`).
const TOL_CUM_WEIGHT: f64 = 1e-4;
/// Multiple of the CPU's seed-to-seed spread that a desynchronised GPU run may reach.
const ENVELOPE_FACTOR: f64 = 2.0;

/// Per-frame distance between two estimates.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Diff {
    centre: f64,
    axes: f64,
    angles: f64,
}

impl Diff {
    fn between(a: &Estimate, b: &Estimate) -> Self {
        Self {
            centre: (a.state.cx - b.state.cx).hypot(a.state.cy - b.state.cy),
            axes: (a.state.a - b.state.a)
                .abs()
                .max((a.state.b - b.state.b).abs()),
            angles: a
                .angles_deg()
                .iter()
                .zip(b.angles_deg())
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max),
        }
    }

    fn max(self, o: Self) -> Self {
        Self {
            centre: self.centre.max(o.centre),
            axes: self.axes.max(o.axes),
            angles: self.angles.max(o.angles),
        }
    }

    fn scaled(self, k: f64) -> Self {
        Self {
            centre: self.centre * k,
            axes: self.axes * k,
            angles: self.angles * k,
        }
    }

    fn within(&self, tol: &Self) -> bool {
        self.centre <= tol.centre && self.axes <= tol.axes && self.angles <= tol.angles
    }
}

/// One tracker run: the estimates and each frame's resampling.
struct Run {
    est: Vec<Estimate>,
    res: Vec<Option<Resampling>>,
    /// Each frame's normalised weights, before any resampling.
    w: Vec<Vec<f64>>,
}

fn track(
    r: &Renderer,
    frames: &[image::RgbImage],
    seed: u64,
    engine: Box<dyn LikelihoodEngine + Send>,
) -> Run {
    let cfg = TrackerConfig {
        seed,
        ..TrackerConfig::default()
    };
    let mut t =
        Tracker::with_engine(cfg, engine, &frames[0], Init::frontal(r.init_ellipse())).unwrap();
    let mut run = Run {
        est: vec![t.initial_estimate()],
        res: vec![None],
        w: vec![t.filter().weights().to_vec()],
    };
    for img in &frames[1..] {
        run.est.push(t.step(img).unwrap());
        let res = t.filter().last_resampling().cloned();
        run.w.push(match &res {
            Some(r) => r.weights.clone(),
            None => t.filter().weights().to_vec(),
        });
        run.res.push(res);
    }
    run
}

/// The first `n` frames of a scenario at its default length and size (160x120).
fn scenario_frames(scenario: Scenario, n: usize) -> (Renderer, Vec<image::RgbImage>) {
    let r = Renderer::new(&SynthConfig::new(scenario)).unwrap();
    let frames = (0..n).map(|k| r.render_image(k)).collect();
    (r, frames)
}

/// What the comparison of one scenario found.
#[derive(Debug, Default)]
struct Comparison {
    /// Resamplings compared while synchronised.
    resamplings: usize,
    /// Of those, ties (`max_cumulative_difference >= systematic_margin`).
    ties: usize,
    /// The first frame where a discrete decision differed, and which.
    first_decision: Option<(usize, String)>,
    /// The first frame beyond [`TIGHT`].
    departure: Option<usize>,
    /// Largest difference while within [`TIGHT`].
    max_tight: Diff,
    /// Largest difference after the departure.
    max_after: Diff,
    /// The seed-to-seed spread at the last frame (zero when not needed).
    envelope_at_end: Diff,
}

fn compare_tracks(name: &str, cpu: &Run, gpu: &Run, others: &[Run]) -> Comparison {
    let mut c = Comparison::default();
    let mut envelope = Diff::default();
    for k in 0..cpu.est.len() {
        for o in others {
            envelope = envelope.max(Diff::between(&cpu.est[k], &o.est[k]));
        }
        // This frame's decisions first: a flipped likelihood or a resampling of frame k
        // already moves frame k's estimate (the weighted mean after the update).
        if c.first_decision.is_none()
            && let Some(why) = frame_decision(name, k, cpu, gpu, &mut c)
        {
            c.first_decision = Some((k, why));
        }
        let d = Diff::between(&cpu.est[k], &gpu.est[k]);
        if c.departure.is_none() && !d.within(&TIGHT) {
            assert!(
                c.first_decision.is_some(),
                "{name} frame {k}: the GPU track left the CPU track ({d:?}) with no differing \
                 decision before it or in that frame"
            );
            c.departure = Some(k);
        }
        match c.departure {
            None => c.max_tight = c.max_tight.max(d),
            Some(_) => {
                c.max_after = c.max_after.max(d);
                let bound = envelope.scaled(ENVELOPE_FACTOR);
                assert!(
                    d.within(&bound),
                    "{name} frame {k}: the GPU track is {d:?} from the CPU track, beyond \
                     {ENVELOPE_FACTOR} x the seed-to-seed spread {envelope:?}"
                );
            }
        }
    }
    c.envelope_at_end = envelope;
    c
}

/// The first discrete decision of frame `k` that differs between two synchronised runs
/// (checking along the way that everything else agrees), or `None`.
fn frame_decision(
    name: &str,
    k: usize,
    cpu: &Run,
    gpu: &Run,
    c: &mut Comparison,
) -> Option<String> {
    let (ec, eg) = (&cpu.est[k], &gpu.est[k]);
    let (flipped, largest) = likelihood_flips(&cpu.w[k], &gpu.w[k]);
    if flipped > 0 {
        assert!(
            flipped <= MAX_FLIPS,
            "{name} frame {k}: {flipped} particles' weights differ by more than \
             {TOL_FLIP:e} (largest {largest:e}): not a flip, the engines disagree"
        );
        return Some(format!(
            "{flipped} particle likelihood flip(s), log-weight off by {largest:.2e}"
        ));
    }
    if ec.matches != eg.matches {
        return Some(format!("matches {} vs {}", ec.matches, eg.matches));
    }
    match (&cpu.res[k], &gpu.res[k]) {
        (None, None) => None,
        (Some(rc), Some(rg)) => {
            c.resamplings += 1;
            assert_eq!(rc.u0, rg.u0, "{name} frame {k}: different comb offsets");
            let dcum = max_cumulative_difference(&rc.weights, &rg.weights);
            let margin = systematic_margin(&rc.weights, rc.indices.len(), rc.u0);
            assert!(
                dcum <= TOL_CUM_WEIGHT,
                "{name} frame {k}: weights differ, running sums by {dcum:e}"
            );
            let tie = dcum >= margin;
            c.ties += usize::from(tie);
            if rc.indices == rg.indices {
                return None;
            }
            assert!(
                tie,
                "{name} frame {k}: index sets differ without a tie ({dcum:e} < {margin:e})"
            );
            Some(format!(
                "resampling tie: margin {margin:.2e} < weight difference {dcum:.2e}"
            ))
        }
        _ => {
            // One resampled, the other not: the ESS straddles the threshold.
            let rel = (ec.ess - eg.ess).abs() / ec.ess.max(1.0);
            assert!(
                rel <= 1e-3,
                "{name} frame {k}: ESS {} vs {}",
                ec.ess,
                eg.ess
            );
            Some("resampling decision at the ESS threshold".into())
        }
    }
}

/// A particle's log-weight (relative to the others) may differ between the runs by this much
/// before its likelihood counts as flipped; synchronised runs differ by about 5e-5.
const TOL_FLIP: f64 = 1e-3;
/// Most particles whose likelihoods may flip in one frame: a flip is a single particle's
/// boundary crossing a pixel centre, so several at once means the engines disagree.
const MAX_FLIPS: usize = 3;

/// Particles whose likelihood flipped between the runs: the number whose log-weight differs
/// from the median difference by more than [`TOL_FLIP`] (among those above 1e-9 in both
/// runs), and the largest such deviation.
fn likelihood_flips(wc: &[f64], wg: &[f64]) -> (usize, f64) {
    let d: Vec<f64> = wc
        .iter()
        .zip(wg)
        .filter(|(a, b)| **a > 1e-9 && **b > 1e-9)
        .map(|(a, b)| a.ln() - b.ln())
        .collect();
    if d.is_empty() {
        return (0, 0.0);
    }
    let mut sorted = d.clone();
    sorted.sort_by(f64::total_cmp);
    let med = sorted[sorted.len() / 2];
    let dev: Vec<f64> = d.iter().map(|v| (v - med).abs()).collect();
    let largest = dev.iter().copied().fold(0.0, f64::max);
    (dev.iter().filter(|v| **v > TOL_FLIP).count(), largest)
}

#[test]
fn gpu_track_follows_the_cpu_track_on_synthetic_scenarios() {
    // Held to the end, so that the engines below open beside it, as the others' do.
    let Some(_gpu) = engine() else { return };
    for scenario in [Scenario::Nod, Scenario::Pan, Scenario::Roll] {
        let (r, frames) = scenario_frames(scenario, FRAMES);
        let cpu = track(&r, &frames, 0, Box::new(CpuEngine::new()));
        let gpu = track(&r, &frames, 0, Box::new(GpuEngine::new().unwrap()));
        // The seed-to-seed spread is needed only once the tracks have separated.
        let separated = cpu
            .est
            .iter()
            .zip(&gpu.est)
            .any(|(a, b)| !Diff::between(a, b).within(&TIGHT));
        let others: Vec<Run> = if separated {
            OTHER_SEEDS
                .iter()
                .map(|&s| track(&r, &frames, s, Box::new(CpuEngine::new())))
                .collect()
        } else {
            Vec::new()
        };
        let c = compare_tracks(&format!("{scenario:?}"), &cpu, &gpu, &others);
        let _ = writeln!(std::io::stderr(), "{scenario:?}, {FRAMES} frames: {c:?}");
        // At least the first frame's resampling was compared while synchronised.
        assert!(c.resamplings >= 1, "{scenario:?}: {c:?}");
    }
}

/// `pftrack track` on PNG frames gives, for each backend, the library's track for that engine
/// (to the CSV's 6 decimals): what the library test above establishes for the engines holds
/// for the command.
#[test]
fn pftrack_track_backend_gpu_writes_the_library_gpu_track() {
    // Held to the end, so that the engines below open beside it, as the others' do.
    let Some(_gpu) = engine() else { return };
    const N: usize = 10;
    let (r, frames) = scenario_frames(Scenario::Nod, N);
    let dir = std::env::temp_dir().join(format!("pftrack-gpu-track-{}", std::process::id()));
    let fdir = dir.join("frames");
    std::fs::create_dir_all(&fdir).unwrap();
    for (k, f) in frames.iter().enumerate() {
        f.save(fdir.join(format!("{k:05}.png"))).unwrap();
    }
    let e = r.init_ellipse();
    let init = format!("{},{},{},{}", e.cx, e.cy, e.a, e.b);
    for (backend, engine) in [
        (
            "gpu",
            Box::new(GpuEngine::new().unwrap()) as Box<dyn LikelihoodEngine + Send>,
        ),
        ("cpu", Box::new(CpuEngine::new())),
    ] {
        let csv = dir.join(format!("{backend}.csv"));
        let out = Command::new(env!("CARGO_BIN_EXE_pftrack"))
            .args(["track", fdir.to_str().unwrap(), "--init-ellipse", &init])
            .args(["--backend", backend, "-o", csv.to_str().unwrap()])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{backend}: {stderr}");
        if backend == "gpu" {
            assert!(stderr.contains("Vulkan"), "{stderr}");
        }
        let rows = pftrack::io::read_pose_csv(&csv).unwrap();
        let lib = track(&r, &frames, 0, engine);
        assert_eq!(rows.len(), N);
        for (row, est) in rows.iter().zip(&lib.est) {
            let (a, b) = (&row.state, &est.state);
            let d = [
                a.cx - b.cx,
                a.cy - b.cy,
                a.a - b.a,
                a.b - b.b,
                (a.rx - b.rx).to_degrees(),
                (a.ry - b.ry).to_degrees(),
                (a.rz - b.rz).to_degrees(),
            ];
            assert!(
                d.iter().all(|x| x.abs() <= 1e-6),
                "{backend} frame {}: CLI {a:?} vs library {b:?}",
                row.frame
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_tracker_whose_gpu_device_is_lost_goes_on_on_the_cpu_with_one_notice() {
    let Some(gpu) = engine_alone() else { return };
    // A handle on the device, to destroy it as a driver reset would.
    let device = gpu.device().device.clone();
    let (r, frames) = scenario_frames(Scenario::Roll, 8);
    let mut t = Tracker::with_engine(
        TrackerConfig::default(),
        Box::new(FallbackEngine::new(Box::new(gpu.engine))),
        &frames[0],
        Init::frontal(r.init_ellipse()),
    )
    .unwrap();
    for img in &frames[1..4] {
        t.step(img).unwrap();
        assert!(t.take_engine_notice().is_none());
    }
    assert!(t.engine_name().contains("Vulkan"), "{}", t.engine_name());
    device.destroy();
    let _ = device.poll(wgpu::PollType::wait_indefinitely());
    let est = t.step(&frames[4]).unwrap();
    let notice = t.take_engine_notice().expect("a notice after the loss");
    assert!(
        notice.contains("GPU device lost") && notice.contains("CPU"),
        "{notice}"
    );
    assert!(t.engine_name().starts_with("cpu"), "{}", t.engine_name());
    let truth = r.truth(4);
    assert!((est.state.cx - truth.cx).hypot(est.state.cy - truth.cy) < 5.0);
    for (k, img) in frames.iter().enumerate().skip(5) {
        let est = t.step(img).unwrap();
        assert!(t.take_engine_notice().is_none(), "one notice only");
        let truth = r.truth(k);
        assert!(!est.lost);
        assert!((est.state.cx - truth.cx).hypot(est.state.cy - truth.cy) < 5.0);
    }
}

#[test]
fn more_particles_than_the_gpu_buffers_hold_are_refused_when_the_tracker_is_built() {
    let Some(gpu) = engine() else { return };
    let (r, frames) = scenario_frames(Scenario::Nod, 1);
    let params = TrackerConfig::default().likelihood;
    let (w, h) = frames[0].dimensions();
    assert!(gpu.engine.check_capacity(200, w, h, &params).is_ok());
    // Beyond what one dispatch can index, on any adapter.
    let n = 5_000_000_000;
    let Some(err) = gpu.engine.check_capacity(n, w, h, &params).err() else {
        panic!("{n} particles accepted");
    };
    assert!(
        matches!(err, LikelihoodError::TooManyParticles { .. }),
        "{err}"
    );
    // The most the filter takes, 32 bytes each (160 MB), is beyond lavapipe's 128 MiB binding: the tracker
    // refuses it before its filter allocates anything, with the error the first frame gave.
    let n = pftrack::filter::MAX_PARTICLES;
    if gpu.engine.check_capacity(n, w, h, &params).is_ok() {
        skip(&format!("{} holds {n} particles", gpu.engine.name()));
        return;
    }
    let mut cfg = TrackerConfig::default();
    cfg.filter.particles = n;
    let Err(err) = Tracker::with_engine(
        cfg,
        Box::new(FallbackEngine::new(Box::new(gpu.engine))),
        &frames[0],
        Init::frontal(r.init_ellipse()),
    ) else {
        panic!("{n} particles accepted by the tracker");
    };
    assert!(err.to_string().contains("particles need"), "{err}");
}

/// With the Vulkan loader pointed at no driver, `--backend gpu` fails with the fix named and
/// `--backend auto` runs on the CPU with a notice. Needs no adapter, so it runs everywhere.
#[test]
fn without_a_vulkan_driver_backend_gpu_fails_clearly_and_auto_falls_back() {
    let (r, frames) = scenario_frames(Scenario::Nod, 3);
    let dir = std::env::temp_dir().join(format!("pftrack-no-driver-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (k, f) in frames.iter().enumerate() {
        f.save(dir.join(format!("{k:05}.png"))).unwrap();
    }
    let e = r.init_ellipse();
    let init = format!("{},{},{},{}", e.cx, e.cy, e.a, e.b);
    let missing = dir.join("no-such-icd.json");
    let run = |backend: &str| {
        Command::new(env!("CARGO_BIN_EXE_pftrack"))
            .args(["track", dir.to_str().unwrap(), "--init-ellipse", &init])
            .args(["--backend", backend])
            // The loader's driver list (VK_DRIVER_FILES, and its older name) names a file that
            // does not exist: no Vulkan driver at all.
            .env("VK_DRIVER_FILES", &missing)
            .env("VK_ICD_FILENAMES", &missing)
            .env_remove("VK_ADD_DRIVER_FILES")
            .env_remove("PFTRACK_ADAPTER")
            .output()
            .unwrap()
    };
    let out = run("gpu");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("no Vulkan adapter found")
            && stderr.contains("apt-get install mesa-vulkan-drivers libvulkan1"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    let out = run("auto");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    // It says what to install, not to use the CPU engine it is already on.
    assert!(
        stderr.contains("note: likelihood on the CPU: no Vulkan adapter found")
            && stderr.contains("apt-get install mesa-vulkan-drivers libvulkan1")
            && !stderr.contains("--backend cpu"),
        "{stderr}"
    );
    assert_eq!(String::from_utf8_lossy(&out.stdout).lines().count(), 1 + 3);
    let _ = std::fs::remove_dir_all(&dir);
}

/// An `RgbImage` may hold a buffer longer than its pixels (`ImageBuffer::from_raw` takes one
/// at least `3 w h` bytes long). The GPU engine had uploaded all of it, past its pixel
/// buffer's end, which wgpu refused on every frame; both engines now read the pixels only,
/// and the tracks are those of the same frames held exactly.
#[test]
fn frames_held_in_longer_buffers_track_as_exact_ones() {
    let (r, frames) = scenario_frames(Scenario::Roll, 6);
    let padded = |img: &image::RgbImage| {
        let mut raw = img.as_raw().clone();
        // Bytes that are no pixel: white, and not a whole pixel.
        raw.extend([255; 7]);
        image::RgbImage::from_raw(img.width(), img.height(), raw).expect("a longer buffer")
    };
    let track = |engine: Box<dyn LikelihoodEngine + Send>, pad: bool| {
        let hold = |img: &image::RgbImage| if pad { padded(img) } else { img.clone() };
        let mut t = Tracker::with_engine(
            TrackerConfig::default(),
            engine,
            &hold(&frames[0]),
            Init::frontal(r.init_ellipse()),
        )
        .unwrap();
        frames[1..]
            .iter()
            .map(|img| {
                let e = t.step(&hold(img)).unwrap();
                (e.state, e.confidence, e.lost)
            })
            .collect::<Vec<_>>()
    };
    // One engine at a time, each held (with its device's slot) for its own track only.
    let on_gpu = |pad| engine().map(|gpu| track(Box::new(gpu.engine), pad));
    let Some(gpu_exact) = on_gpu(false) else {
        return;
    };
    assert_eq!(on_gpu(true), Some(gpu_exact));
    let cpu_exact = track(Box::new(CpuEngine::new()), false);
    assert_eq!(track(Box::new(CpuEngine::new()), true), cpu_exact);
}

/// Sizes past anything an adapter holds are refused, whatever they are: the byte counts had
/// been multiplied unchecked, which panics in a debug build for counts near the integer
/// limits and wraps in a release one.
#[test]
fn absurd_sizes_are_refused_not_overflowed() {
    let Some(gpu) = engine() else { return };
    let params = TrackerConfig::default().likelihood;
    for (n, w, h) in [
        (200, u32::MAX, u32::MAX),
        (usize::MAX, 160, 120),
        (usize::MAX / 3, 160, 120),
        (usize::MAX, u32::MAX, u32::MAX),
    ] {
        assert!(
            gpu.engine.check_capacity(n, w, h, &params).is_err(),
            "{n} particles, {w}x{h}"
        );
    }
    assert!(gpu.engine.check_capacity(200, 160, 120, &params).is_ok());
}
