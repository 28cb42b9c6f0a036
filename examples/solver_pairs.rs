//! The rotation between two frames of a synthetic sequence by each of the paper's solvers,
//! against the truth: issue 3's per-frame-pair comparison on rendered footage instead of
//! Fig. 3's synthetic points.
//!
//! `cargo run --release --example solver_pairs -- [--scenario NAME|all] [--seed S] [--gap N]
//! [--every K] [--consensus]`
//!
//! For frames `k = 0, K, 2K, ...` (default K = 1) of each scenario (default: the six that
//! `scripts/eval_seeds.sh synth` scores; `long` by name), rendered in memory with seed `S`
//! (default 0):
//!
//! - SIFT on frames `k` and `k + N` (default N = 1: successive frames), matched with the ratio
//!   and cross checks, the matches whose first point lies inside the **true** ellipse at `k`,
//!   then the paper's slope/length rejection (mean ± 0.2 rad, mean × (1 ± 0.3)); with
//!   `--consensus`, also the tracker's affine consensus (`pose::Consensus`, 1 px, 5 matches).
//! - Each 2x2 solver (SEA, Optimal, LSM, RLS) through `pose::interframe`, completed to its
//!   Necker pair, scored by the member nearer the truth (so the block's error is measured,
//!   not the choice between the two); the essential matrix (8-point on all the matches, with
//!   the renderer's true intrinsics); the tracker's keyframe fit (`pose::prior`: the first
//!   view's ellipsoid turned to the true pose at `k`, the true camera, started from the
//!   identity with no rotation prior); and doing nothing (the identity), for scale.
//! - The error of a pair is the angle of `R_est · R_trueᵀ`, `R_true = R(k+N) · R(k)ᵀ` in camera
//!   coordinates.
//!
//! Printed per scenario and solver: the pairs with an estimate (a solver may refuse: too few
//! matches, a degenerate set), and the mean and median error in degrees over them, beside the
//! mean true inter-frame angle. Means over different numbers of pairs are not comparable:
//! the essential matrix needs 8 matches, the 2x2 solvers 3.
//!
//! Measured 2026-12-05 (scenario seed 0, slope/length rejection), mean error in degrees:
//!
//! - Successive frames (gap 1), true turns of 0.3-1.4° a frame: SEA 3.1-5.5, Optimal the same
//!   within 0.06, LSM and RLS 0.01-0.25 above them, the essential matrix 1.5-3.0, the prior fit
//!   0.5-1.5, the identity 0-1.4. Every 2x2 solver is further from the truth than doing
//!   nothing: an out-of-plane turn of 1° changes the block's second singular value by
//!   `1 - cos 1° = 0.00015`, far below what the matches' noise puts there, and the completion
//!   reads a singular value `s` as a turn of `acos s` (0.998 gives 3.6°). On `depth`, which
//!   does not turn at all, a receding object's shrinking reads the same way (5.5°).
//! - Eight frames apart (true turns of 2.5-11°): on `pan` SEA 7.8, Optimal 7.8, LSM 7.9, RLS
//!   8.1, the essential matrix 16.6 (on 121 pairs of 172), the prior fit 2.7, the identity
//!   10.4; on `nod` the 2x2 solvers 6.2-6.3 against the identity's 6.1 and the prior fit's
//!   1.8; on `car` the prior fit 2.4 against the identity's 2.5 (the box's turn is what the
//!   ellipsoid misses). On `roll` the slope/length test leaves three matches or more on only
//!   17 pairs of 142: an in-plane turn spreads the displacements' directions past its ±0.2
//!   rad.

use nalgebra::{Matrix3, Vector2};
use pftrack::features::{
    Features, MatchParams, Sift, SiftParams, keep_slope_length, match_features,
};
use pftrack::frames::GrayF32;
use pftrack::geometry::angle_between;
use pftrack::pose::prior::{Ellipsoid, FitStart, fit_with_depth_prior};
use pftrack::pose::{Consensus, Intrinsics, SolverKind, essential_rotation, interframe_consensus};
use pftrack::synth::{Renderer, Scenario, SynthConfig};

const USAGE: &str =
    "usage: solver_pairs [--scenario NAME|all] [--seed S] [--gap N] [--every K] [--consensus]";

/// The scenarios `all` stands for: those the seed evaluation scores, every one but `long`.
fn scored() -> Vec<Scenario> {
    Scenario::all()
        .iter()
        .copied()
        .filter(|s| *s != Scenario::Long)
        .collect()
}

/// The errors (degrees) of one estimator over a scenario's pairs, and how many it refused.
#[derive(Default)]
struct Tally {
    errors: Vec<f64>,
    refused: usize,
}

impl Tally {
    fn add(&mut self, error: Option<f64>) {
        match error {
            Some(e) => self.errors.push(e),
            None => self.refused += 1,
        }
    }

    fn line(&self, name: &str) -> String {
        let n = self.errors.len();
        if n == 0 {
            return format!("{name:>9} {:>5}/{:<5}        -        -", 0, self.refused);
        }
        let mut sorted = self.errors.clone();
        sorted.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        };
        let mean = self.errors.iter().sum::<f64>() / n as f64;
        format!(
            "{name:>9} {n:>5}/{:<5} {mean:8.3} {median:8.3}",
            n + self.refused
        )
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let (mut scenarios, mut seed) = (scored(), 0u64);
    let (mut gap, mut every, mut consensus) = (1usize, 1usize, None);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(USAGE);
        match a.as_str() {
            "--scenario" => {
                let v = value()?;
                scenarios = if v == "all" {
                    scored()
                } else {
                    vec![Scenario::from_name(&v)?]
                };
            }
            "--seed" => seed = value()?.parse()?,
            "--gap" => gap = value()?.parse()?,
            "--every" => every = value()?.parse()?,
            "--consensus" => consensus = Some(Consensus::default()),
            _ => return Err(format!("unknown argument '{a}'; {USAGE}").into()),
        }
    }
    if gap == 0 || every == 0 {
        return Err(format!("--gap and --every must be at least 1; {USAGE}").into());
    }
    println!(
        "frame pairs k -> k + {gap}, every {every} frames, scenario seed {seed}, {}",
        if consensus.is_some() {
            "slope/length rejection and affine consensus"
        } else {
            "slope/length rejection"
        }
    );
    println!("   solver pairs/all     mean   median  (error in degrees)");
    let sift = Sift::new(SiftParams::default());
    let matching = MatchParams::default();
    for scenario in scenarios {
        let mut cfg = SynthConfig::new(scenario);
        cfg.seed = seed;
        let ren = Renderer::new(&cfg)?;
        let n = ren.frames();
        if n <= gap {
            return Err(format!(
                "{} has {n} frames, too few for --gap {gap}",
                scenario.name()
            )
            .into());
        }
        let c = ren.camera();
        let intrinsics = Intrinsics {
            fx: c.focal,
            fy: c.focal,
            cx: c.pu,
            cy: c.pv,
        };
        let camera = c.pinhole();
        let reference = ren.truth(0).ellipse(0.0);
        let mut features: Vec<Option<Features>> = vec![None; n];
        let mut detect = |k: usize| -> Result<Features, Box<dyn std::error::Error>> {
            if features[k].is_none() {
                features[k] = Some(sift.detect(&GrayF32::from_rgb(&ren.render_image(k)), None)?);
            }
            Ok(features[k].clone().ok_or("no features")?)
        };
        let mut tallies: Vec<(String, Tally)> = SolverKind::ALL
            .iter()
            .map(|k| k.name().to_string())
            .chain(["essential", "prior fit", "identity"].map(String::from))
            .map(|name| (name, Tally::default()))
            .collect();
        let (mut true_angle, mut pairs, mut matches) = (0.0, 0usize, 0usize);
        for k in (0..n - gap).step_by(every) {
            let (fa, fb) = (detect(k)?, detect(k + gap)?);
            let truth_k = ren.truth(k);
            let e = truth_k.ellipse(0.0);
            let (mut p, mut q) = (Vec::new(), Vec::new());
            for m in match_features(&fa, &fb, &matching) {
                let (a, b) = (&fa.keypoints[m.query], &fb.keypoints[m.train]);
                if e.contains(f64::from(a.x), f64::from(a.y)) {
                    p.push([f64::from(a.x), f64::from(a.y)]);
                    q.push([f64::from(b.x), f64::from(b.y)]);
                }
            }
            let (p, q) = keep_slope_length(&p, &q, 0.2, 0.3);
            let truth: Matrix3<f64> = ren.pose(k + gap).rotation * ren.pose(k).rotation.transpose();
            let error = |r: &Matrix3<f64>| angle_between(r, &truth).to_degrees();
            for (i, kind) in SolverKind::ALL.iter().enumerate() {
                let est = interframe_consensus(&p, &q, [e.cx, e.cy], *kind, consensus.as_ref());
                tallies[i]
                    .1
                    .add(est.ok().map(|f| error(&f.pair.a).min(error(&f.pair.b))));
            }
            let essential = essential_rotation(&p, &q, &intrinsics).ok();
            tallies[4].1.add(essential.map(|f| error(&f.rotation)));
            let rk = ren.pose(k).rotation * ren.pose(0).rotation.transpose();
            let model = Ellipsoid::posed(&reference, 1.0, &rk, &e);
            let start = FitStart {
                rot: Matrix3::identity(),
                scale: 1.0,
                centre: Vector2::new(e.cx, e.cy),
            };
            let fit = fit_with_depth_prior(&p, &q, &model, Some(&camera), &start, None).ok();
            tallies[5].1.add(fit.map(|f| error(&f.rot)));
            tallies[6].1.add(Some(error(&Matrix3::identity())));
            true_angle += error(&Matrix3::identity());
            pairs += 1;
            matches += p.len();
        }
        println!(
            "{} ({pairs} pairs, {:.1} matches a pair after rejection, true inter-frame angle \
             {:.3} degrees on average)",
            scenario.name(),
            matches as f64 / pairs.max(1) as f64,
            true_angle / pairs.max(1) as f64
        );
        for (name, tally) in &tallies {
            println!("{}", tally.line(name));
        }
    }
    Ok(())
}
