//! How much of the keyframe fit's bias on a synthetic sequence a bundle adjustment of the
//! keyframe's depths and its views' poses removes ([`pftrack::pose::bundle`]).
//!
//! `cargo run --release --example bundle_bias -- [--scenario car] [--seed S] [--key K]
//! [--to T] [--every N] [--min-seen M] [--depth-sigma PX] [--rotation-sigma RAD]
//! [--positions sift|exact] [--noise PX] [--from-truth] [--iterations N]`
//!
//! - The view at frame `K` (default 95, where the car starts to turn) is the keyframe, at its
//!   true pose and ellipse; its SIFT features inside the ellipse are lifted onto the first
//!   view's ellipsoid turned to that pose, as the tracker lifts them (true camera).
//! - Frames `K + N, K + 2N, ... <= T` (default N = 3, T = 150) are matched to it; a view with
//!   fewer than `M` matches (default 10) is left out.
//! - Each view is fitted alone ([`pftrack::pose::prior::fit_points`] on the lifted points,
//!   started from the true rotation, no prior): the fit's bias with everything else exact.
//! - `--positions exact` replaces each match's SIFT position by the true image of its
//!   keyframe feature's point (cast into the rendered object), plus Gaussian noise of σ
//!   `--noise` pixels (default 0): what the adjustment makes of the views when only the
//!   matches' noise is left. With SIFT positions, the RMS distance of each view's matches
//!   from those true images (within 3 px) is printed.
//! - From those fits, or from the true rotations with `--from-truth`,
//!   [`pftrack::pose::bundle::refine`] adjusts all views' poses and the points' depths
//!   together (depth prior σ `PX`, default 12; the rotation's random walk σ `RAD` a frame,
//!   default 0.05, the filter's; `--iterations`, default 8).
//! - Printed: per view the matches, the true rotation angle, and each estimate's error; then
//!   the RMS error and the gain about each camera axis of the single fits and of the
//!   adjustment.
//!
//! Measured 2026-12-05 (frames 95-150, every third, the defaults): `car` seeds 0-3, RMS error
//! 17.9 / 17.9 / 17.7 / 17.8 degrees for the single fits (gain about y 0.17-0.46) and 3.5 /
//! 5.2 / 9.6 / 6.8 after adjustment (gain about y 0.68-1.02). On the heads, whose shape the
//! ellipsoid is, it helps where the single fits over-read and hurts where they were right
//! (`--min-seen 8`, every frame): `nod` seed 0, frames 0-40, 10.0 -> 4.7 (gain about x 1.40
//! -> 1.13); `combo` seed 0, frames 0-40, 5.2 -> 3.4; `pan` seed 0, frames 0-30, 2.0 -> 2.1;
//! `pan` seed 1, frames 30-60, 2.0 -> 12.5 (gain about y 0.95 -> 2.23). The tracker adjusts
//! only keyframes with 7 views or more ([`pftrack::tracker::TrackerConfig::bundle`]).
//!
//! What limits the adjustment on the car (2026-12-05, keyframe 109, frames 112-136 every
//! third, the turn 2-24 degrees, `--rotation-sigma 1`; gain about y on seeds 0 / 1 / 2 / 3):
//!
//! | matches | depth σ 12 px | depth σ 100 px |
//! |---|---|---|
//! | SIFT | 0.77 / 1.06 / 0.70 / 1.19 | 0.38 / 0.90 / 0.84 / 0.80 |
//! | SIFT, adjusted from the true rotations | | 0.38 / 0.90 / 0.93 / 0.99 |
//! | exact | | 1.00 / 1.00 / 1.00 / 1.01 (0.07-0.31 degrees RMS) |
//! | exact + 0.2 px noise | | 0.97 / 0.93 / 0.85 / 0.98 |
//! | exact + 0.4 px noise | 1.03 / 0.78 / 0.67 / 1.08 | 0.86 / 0.85 / 0.69 / 0.97 |
//!
//! The box's depths and turn are in the matches: exact ones give both back to a tenth of a
//! degree with the depths all but free. SIFT's matches lie 0.23-0.46 px RMS from their true
//! images on seed 0, and at that noise the free depths take up what the views' turn should
//! explain, the more so the freer they are: adjusted with free depths from the true
//! rotations, seed 0 still ends at 0.38 of its turn. A 24-degree span of views of one
//! keyframe does not measure the depths well enough; the ellipsoid prior holds them, and
//! where it is wrong (the box) the adjustment keeps part of its error either way.
//!
//! Tried against that noise in a throwaway build and not kept: each match moved to where
//! the keyframe's patch around its feature aligns in the view (Gauss-Newton on an affine
//! warp started from the two keypoints' scale and orientation, with gain and offset, patch
//! radius 3σ clamped to 4-8 px, kept at correlation 0.8 and a move under 1.5 px). The
//! matches' RMS distance from the true images went from 0.22-0.73 to 0.09-0.68 px per view
//! (seeds 0-3), about a tenth less, with some matches moved the wrong way; patches of 3-6
//! or 6-12 px did no better. The adjustment's gain about y at depth σ 100 went 0.38 / 0.90 /
//! 0.84 / 0.80 -> 0.49 / 0.90 / 0.83 / 1.06, at σ 12 0.77 / 1.06 / 0.70 / 1.19 -> 0.80 /
//! 1.07 / 0.72 / 1.24: too little for what 40 alignments a frame would cost the tracker
//! (not measured there; each samples a few hundred points a dozen times).
//!
//! Nor weighting the matches by their keypoints' scale (2026-12-05, same views): SIFT's
//! error from the true image grows with the scale of the pair's larger keypoint, 0.24-0.29 px
//! RMS below σ 1.6 px (468 matches over seeds 0-3), 0.41-0.49 px from 1.6 to 5 px (318) and
//! 1.4 px above (23). Each point weighted by `min(1, (σ_ref / σ_key)²)` in the adjustment
//! (its keyframe keypoint's scale, σ_ref 1.4 or 2 px): RMS error over seeds 0-3 at depth σ 12
//! 4.08 / 1.84 / 6.65 / 5.77 degrees -> 7.59 / 1.85 / 4.89 / 7.01 and 7.26 / 1.71 / 4.89 /
//! 5.82; at σ 100 the gain about y rose on seeds 0 and 2 (0.38 -> 0.63-0.69, 0.84 -> 0.91-0.94)
//! and fell on seed 3. Leaving out the matches whose larger keypoint is above 2.2 px did
//! about the same (gain at σ 100: 0.71 / 0.90 / 1.08 / 0.88 against 0.38 / 0.90 / 0.85 /
//! 0.80; at σ 12: 0.74 / 1.07 / 0.89 / 1.28 against 0.77 / 1.06 / 0.71 / 1.19): the large
//! keypoints' noise is not what holds the adjustment back.

#[path = "common/gain.rs"]
mod gain;
#[path = "common/positions.rs"]
mod positions;

use nalgebra::Vector2;
use pftrack::features::{MatchParams, Sift, SiftParams, match_features};
use pftrack::filter::rotation_mean::log_so3;
use pftrack::frames::GrayF32;
use pftrack::geometry::angle_between;
use pftrack::pose::bundle::{BundleParams, BundleView, refine};
use pftrack::pose::prior::{Ellipsoid, FitStart, fit_points, lift};
use pftrack::synth::{Renderer, Scenario, SynthConfig};
use rand::{SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};

const USAGE: &str = "usage: bundle_bias [--scenario NAME] [--seed S] [--key K] [--to T] \
                     [--every N] [--min-seen M] [--depth-sigma PX] [--rotation-sigma RAD] \
                     [--positions sift|exact] [--noise PX] [--from-truth] [--iterations N]";

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let (mut scenario, mut seed) = (Scenario::Car, 0u64);
    let (mut key, mut to, mut every, mut min_seen) = (95usize, 150usize, 3usize, 10usize);
    let mut params = BundleParams::default();
    let (mut exact, mut noise, mut from_truth) = (false, 0.0f64, false);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(USAGE);
        match a.as_str() {
            "--scenario" => scenario = Scenario::from_name(&value()?)?,
            "--seed" => seed = value()?.parse()?,
            "--key" => key = value()?.parse()?,
            "--to" => to = value()?.parse()?,
            "--every" => every = value()?.parse()?,
            "--min-seen" => min_seen = value()?.parse()?,
            "--depth-sigma" => params.depth_sigma = value()?.parse()?,
            "--rotation-sigma" => params.rotation_sigma = [value()?.parse()?; 3],
            "--positions" => exact = positions::exact_positions(&value()?)?,
            "--noise" => noise = value()?.parse()?,
            "--from-truth" => from_truth = true,
            "--iterations" => params.iterations = value()?.parse()?,
            _ => return Err(format!("unknown argument '{a}'; {USAGE}").into()),
        }
    }
    let positive = |v: f64| v > 0.0 && v.is_finite();
    if every == 0 || !positive(params.depth_sigma) || !positive(params.rotation_sigma[0]) {
        return Err("--every must be at least 1 and the sigmas positive".into());
    }
    if !(noise.is_finite() && noise >= 0.0) || params.iterations == 0 {
        return Err("--noise must be finite and not negative, --iterations at least 1".into());
    }
    let mut rng = StdRng::seed_from_u64(seed);
    let normal = Normal::new(0.0, noise)?;
    let mut cfg = SynthConfig::new(scenario);
    cfg.seed = seed;
    let ren = Renderer::new(&cfg)?;
    if to >= ren.frames() || key >= to {
        return Err(format!(
            "frames must lie in 0..{} with --key below --to",
            ren.frames()
        )
        .into());
    }
    let c = ren.camera();
    let cam = c.pinhole();
    let gray = |k: usize| GrayF32::from_rgb(&ren.render_image(k));
    // The rotation from the keyframe's pose to frame k's.
    let truth = |k: usize| ren.pose(k).rotation * ren.pose(key).rotation.transpose();

    // The keyframe: its features inside the true ellipse, lifted as the tracker lifts them.
    let ek = ren.truth(key).ellipse(0.0);
    let turned = ren.pose(key).rotation * ren.pose(0).rotation.transpose();
    let model = Ellipsoid::posed(&ren.truth(0).ellipse(0.0), 1.0, &turned, &ek);
    let sift = Sift::new(SiftParams::default());
    let matching = MatchParams::default();
    let fk = sift.detect(&gray(key), None)?;
    let keep: Vec<usize> = (0..fk.keypoints.len())
        .filter(|&i| ek.contains(f64::from(fk.keypoints[i].x), f64::from(fk.keypoints[i].y)))
        .collect();
    let p: Vec<[f64; 2]> = keep
        .iter()
        .map(|&i| [f64::from(fk.keypoints[i].x), f64::from(fk.keypoints[i].y)])
        .collect();
    let x0 = lift(&p, &model, Some(&cam));

    // Each later view alone, fitted on the lifted points from its true rotation.
    let mut views = Vec::new();
    for k in (key + every..=to).step_by(every) {
        let fv = sift.detect(&gray(k), None)?;
        let seen: Vec<(usize, [f64; 2])> = match_features(&fk, &fv, &matching)
            .iter()
            .filter_map(|m| {
                let j = keep.iter().position(|&i| i == m.query)?;
                let b = &fv.keypoints[m.train];
                Some((j, [f64::from(b.x), f64::from(b.y)]))
            })
            .collect();
        // Each match's true image: its keyframe feature's ray cast into the object, seen at k.
        let true_image = |j: usize| {
            let hit = ren.cast(key, p[j][0], p[j][1])?;
            let (u, v) = ren.project_point(k, &hit.point);
            Some(Vector2::new(u, v))
        };
        let seen: Vec<(usize, [f64; 2])> = if exact {
            seen.iter()
                .filter_map(|&(j, _)| {
                    let t = true_image(j)?;
                    Some((
                        j,
                        [t.x + normal.sample(&mut rng), t.y + normal.sample(&mut rng)],
                    ))
                })
                .collect()
        } else {
            let off: Vec<f64> = seen
                .iter()
                .filter_map(|&(j, q)| Some((Vector2::from(q) - true_image(j)?).norm()))
                .filter(|&d| d < 3.0)
                .collect();
            let rms = (off.iter().map(|d| d * d).sum::<f64>() / off.len().max(1) as f64).sqrt();
            eprintln!(
                "frame {k}: SIFT {rms:.2} px RMS from the true images ({} of {} matches within 3 px)",
                off.len(),
                seen.len()
            );
            seen
        };
        if seen.len() < min_seen {
            continue;
        }
        let xs: Vec<_> = seen.iter().map(|(j, _)| x0[*j]).collect();
        let qs: Vec<[f64; 2]> = seen.iter().map(|(_, q)| *q).collect();
        let t = ren.truth(k);
        let start = FitStart {
            rot: truth(k),
            scale: 1.0,
            centre: Vector2::new(t.cx, t.cy),
        };
        let Ok(fit) = fit_points(&xs, &qs, Some(&cam), &start, None) else {
            continue;
        };
        views.push(BundleView {
            frame: k,
            rot: fit.rot,
            scale: fit.scale,
            centre: fit.centre,
            seen,
        });
    }
    if views.len() < 2 {
        return Err("fewer than two views could be fitted".into());
    }
    let single = views.clone();
    if from_truth {
        for v in &mut views {
            v.rot = truth(v.frame);
        }
    }
    refine(&x0, &model.centre, key, Some(&cam), &mut views, &params)?;

    println!(
        "keyframe {key}: {} features; {} views",
        p.len(),
        views.len()
    );
    println!("frame matches   true | single fit err | adjusted err");
    let mut gains = [gain::AxisGain::default(); 2];
    let mut sq = [0.0f64; 2];
    for (s, a) in single.iter().zip(&views) {
        let t = truth(s.frame);
        let wt = log_so3(&t);
        let mut line = format!(
            "{:5} {:7} {:6.2}",
            s.frame,
            s.seen.len(),
            wt.norm().to_degrees()
        );
        for (i, r) in [&s.rot, &a.rot].into_iter().enumerate() {
            let err = angle_between(r, &t).to_degrees();
            gains[i].add(&log_so3(r), &wt);
            sq[i] += err * err;
            line += &format!(" | {err:14.2}");
        }
        println!("{line}");
    }
    for (i, name) in ["single fits", "adjusted"].iter().enumerate() {
        println!(
            "{name}: RMS error {:.2} deg over {} views, {}",
            (sq[i] / views.len() as f64).sqrt(),
            views.len(),
            gains[i].describe()
        );
    }
    Ok(())
}
