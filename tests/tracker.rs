//! The whole tracker on short synthetic sequences with exact truth: it must follow the target
//! and its rotation, deterministically for a seed, and reject bad input without panicking.

use pftrack::eval::gain;
use pftrack::geometry::{Ellipse, Euler, PoseState, angle_between, rot_x};
use pftrack::motion::AbmParams;
use pftrack::pose::bundle::BundleParams;
use pftrack::synth::{HFOV_DEG, Renderer, Scenario, SynthConfig};
use pftrack::tracker::{
    AnchorRefit, BundleAdjust, ColourUpdate, Contrast, Init, InitFault, TemplateTerm, TrackError,
    Tracker, TrackerConfig,
};

type Track = (
    Vec<pftrack::tracker::Estimate>,
    Vec<pftrack::geometry::PoseState>,
);

fn run(scenario: Scenario, steps: usize, seed: u64) -> Track {
    // The trajectory spans the scenario's default length; only its first `steps` are tracked.
    run_cfg(SynthConfig::new(scenario), steps, seed)
}

fn run_cfg(cfg: SynthConfig, steps: usize, seed: u64) -> Track {
    run_with(
        cfg,
        steps,
        TrackerConfig {
            seed,
            ..TrackerConfig::default()
        },
    )
}

fn run_with(cfg: SynthConfig, steps: usize, tc: TrackerConfig) -> Track {
    let r = Renderer::new(&cfg).unwrap();
    let (first, _) = r.render(0);
    let mut t = Tracker::new(tc, &first, Init::frontal(r.init_ellipse())).unwrap();
    let mut est = vec![t.initial_estimate()];
    let mut truth = vec![r.truth(0)];
    for k in 1..steps {
        let (img, tr) = r.render(k);
        est.push(t.step(&img).unwrap());
        truth.push(tr);
    }
    (est, truth)
}

/// Per axis (tilt, pan, roll) over frames 1.., the RMSE of the estimate against the truth and
/// its gain (`eval::gain`: the slope of the estimate against the truth, in degrees; `None`
/// where that axis hardly moves), and the worst centre error (pixels).
fn axis_scores(
    est: &[pftrack::tracker::Estimate],
    truth: &[PoseState],
) -> ([f64; 3], [Option<f64>; 3], f64) {
    let mut pairs: [Vec<(f64, f64)>; 3] = Default::default();
    let mut worst_centre: f64 = 0.0;
    for (e, t) in est.iter().zip(truth).skip(1) {
        assert!(!e.lost, "frame {} declared lost", e.frame);
        assert!((0.0..=1.0).contains(&e.confidence));
        worst_centre =
            worst_centre.max(((e.state.cx - t.cx).powi(2) + (e.state.cy - t.cy).powi(2)).sqrt());
        let (es, ts) = ([e.state.rx, e.state.ry, e.state.rz], [t.rx, t.ry, t.rz]);
        for a in 0..3 {
            pairs[a].push((ts[a].to_degrees(), (es[a] - ts[a]).to_degrees()));
        }
    }
    let rmse = pairs
        .each_ref()
        .map(|p| (p.iter().map(|&(_, d)| d * d).sum::<f64>() / p.len() as f64).sqrt());
    (rmse, pairs.each_ref().map(|p| gain(p)), worst_centre)
}

#[test]
fn follows_each_axis_with_the_camera() {
    // The first 60 frames of `nod`, `pan` and `roll` (to 35, 60 and 45 degrees about x, y and
    // z by frames 45, 45 and 37, then back a little), tracked through the camera the frames were
    // rendered with, as `pftrack track` does with `synth`'s init file. Measured 2026-12-06 on
    // scenario and filter seeds 0-2: gains 0.99-1.05 about x on `nod`, 0.97-0.99 about y on
    // `pan`, 1.00-1.01 about z on `roll`; every axis's RMSE 0.8-2.9 degrees; the centre within
    // 1.1 px. A sign error on an axis gives a gain near -1, and a turn half read 0.5.
    for scenario in [Scenario::Nod, Scenario::Pan, Scenario::Roll] {
        let axis = match scenario {
            Scenario::Nod => 0,
            Scenario::Pan => 1,
            _ => 2,
        };
        for seed in 0..3 {
            let cfg = SynthConfig {
                seed,
                ..SynthConfig::new(scenario)
            };
            let tc = TrackerConfig {
                seed,
                camera_hfov_deg: Some(HFOV_DEG),
                ..TrackerConfig::default()
            };
            let (est, truth) = run_with(cfg, 60, tc);
            let (rmse, gains, centre) = axis_scores(&est, &truth);
            let what = format!("{scenario:?} seed {seed}: RMSE {rmse:.2?}, gains {gains:.3?}");
            let g = gains[axis].unwrap_or_else(|| panic!("{what}: the axis did not turn"));
            assert!((0.9..=1.1).contains(&g), "{what}");
            assert!(rmse.iter().all(|&e| e < 4.0), "{what}");
            assert!(centre < 2.0, "{what}: centre off by {centre:.2} px");
            for other in (0..3).filter(|&a| a != axis) {
                assert!(
                    gains[other].is_none(),
                    "{what}: axis {other} should not turn"
                );
            }
        }
    }
}

#[test]
fn follows_a_nodding_head() {
    // The first 40 frames of `nod` tilt the head to about 34 degrees, tracked with the default
    // settings: weak perspective, the paper's model, which reads a near head's tilt about 1.13
    // times too far (`TrackerConfig::camera_hfov_deg`). Measured 2026-12-06 (seed 0): gain
    // 1.16 about x, RMSE 3.25 / 0.87 / 0.99 degrees, centre within 0.9 px; seeds 1 and 2 gain
    // 1.05 and 1.13.
    let (est, truth) = run(Scenario::Nod, 40, 0);
    let (rmse, gains, centre) = axis_scores(&est, &truth);
    let what = format!("RMSE {rmse:.2?}, gains {gains:.3?}");
    let g = gains[0].unwrap_or_else(|| panic!("{what}: no tilt"));
    assert!((0.95..=1.3).contains(&g), "{what}");
    assert!(rmse.iter().all(|&e| e < 5.0), "{what}");
    assert!(centre < 2.0, "centre off by {centre:.2} px");
    let (e, t) = (est.last().unwrap(), truth.last().unwrap());
    let err = angle_between(&e.state.euler().matrix(), &t.euler().matrix()).to_degrees();
    assert!(t.rx.to_degrees() > 25.0, "the scenario should have tilted");
    // Tilted the right way: its Necker mirror is about 60 degrees off.
    let mirror = angle_between(&e.state.euler().matrix(), &rot_x(-t.rx)).to_degrees();
    assert!(
        e.state.rx > 0.0 && err < 8.0 && mirror > 40.0,
        "final rotation {:?}: {err:.1} deg from the truth, {mirror:.1} from its mirror",
        e.angles_deg()
    );
}

#[test]
fn comes_back_to_frontal_after_nodding_out_and_back() {
    // A 90-frame nod: up to 35 degrees by frame 22, back through frontal at frame 45. Between
    // successive frames the rotation is measured against keyframes; when the head comes back,
    // the first view (whose pose is exact) is in reach again, so the error accumulated on the
    // way out must not remain.
    let cfg = SynthConfig {
        frames: 90,
        ..SynthConfig::new(Scenario::Nod)
    };
    let (est, truth) = run_cfg(cfg, 51, 0);
    let peak = truth.iter().map(|t| t.rx.to_degrees()).fold(0.0, f64::max);
    assert!(peak > 30.0, "the scenario should have tilted ({peak:.1})");
    assert!(
        truth[45].rx.to_degrees().abs() < 2.0,
        "frame 45 should be near frontal"
    );
    // Around the return (frames 40-50, the truth from +10.9 to -13.3 degrees), the RMS of the
    // rotation's error and the gain about x. Measured 2026-12-06 on seeds 0-2: RMS 2.2, 2.3
    // and 2.2 degrees, gain about 1.2 on seed 0 (weak perspective's over-read). A tracker
    // that held still there would score 7.6 degrees; one reading half the turn, 3.8.
    let errs: Vec<f64> = (40..=50)
        .map(|k| {
            angle_between(&est[k].state.euler().matrix(), &truth[k].euler().matrix()).to_degrees()
        })
        .collect();
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
    let pairs: Vec<(f64, f64)> = (40..=50)
        .map(|k| {
            let t = truth[k].rx.to_degrees();
            (t, est[k].state.rx.to_degrees() - t)
        })
        .collect();
    let g = gain(&pairs).expect("the head turns through frontal there");
    assert!(
        rms < 3.0 && (0.8..=1.4).contains(&g),
        "back near frontal (frames 40-50) the rotation is off by {errs:.1?} deg, gain {g:.3}"
    );
}

#[test]
fn deterministic_for_a_seed() {
    let (a, _) = run(Scenario::Roll, 12, 5);
    let (b, _) = run(Scenario::Roll, 12, 5);
    assert_eq!(a, b);
}

/// The start's ellipse is the one seen in the first frame: with a rolled starting pose the
/// first estimate's ellipse is that ellipse, not turned by the roll again (SPEC: orientation
/// `theta0 + rz`, so `theta0` is the ellipse's angle less the roll).
#[test]
fn the_first_estimate_is_the_start_as_given() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Roll)).unwrap();
    let (first, _) = r.render(0);
    let mut ellipse = r.init_ellipse();
    ellipse.theta = 0.5;
    for rz in [0.0, 0.2, -0.7] {
        let init = Init {
            ellipse,
            pose: Euler::new(0.1, -0.05, rz),
        };
        let t = Tracker::new(TrackerConfig::default(), &first, init).unwrap();
        let e = t.initial_estimate();
        assert_eq!(e.ellipse, ellipse, "roll {rz}");
        assert_eq!(e.state.rz, rz);
        assert_eq!(e.state.ellipse(0.5 - rz), ellipse);
    }
}

#[test]
fn a_reinitialised_tracker_tracks_as_a_new_one_would() {
    // A tracker that has followed the head for a while and is then started over on frame 8
    // gives the track a tracker built on frame 8 gives, frame for frame (only the frame
    // numbers go on counting).
    let r = Renderer::new(&SynthConfig::new(Scenario::Combo)).unwrap();
    let cfg = TrackerConfig {
        seed: 3,
        ..TrackerConfig::default()
    };
    let (first, _) = r.render(0);
    let mut reused = Tracker::new(cfg.clone(), &first, Init::frontal(r.init_ellipse())).unwrap();
    for k in 1..8 {
        reused.step(&r.render(k).0).unwrap();
    }
    let (restart, truth) = r.render(8);
    let init = Init {
        ellipse: truth.ellipse(r.init_ellipse().theta),
        pose: truth.euler(),
    };
    reused.reinit(&restart, init).unwrap();
    let mut fresh = Tracker::new(cfg, &restart, init).unwrap();
    let same = |a: &pftrack::tracker::Estimate, b: &pftrack::tracker::Estimate| {
        (a.state, a.confidence, a.lost, a.matches, a.ess)
            == (b.state, b.confidence, b.lost, b.matches, b.ess)
    };
    assert!(same(&reused.initial_estimate(), &fresh.initial_estimate()));
    for k in 9..40 {
        let img = r.render(k).0;
        let (a, b) = (reused.step(&img).unwrap(), fresh.step(&img).unwrap());
        assert_eq!(a.frame, k);
        assert_eq!(b.frame, k - 8);
        assert!(same(&a, &b), "frame {k}: {a:?} against {b:?}");
    }
}

#[test]
fn the_block_matching_settings_given_are_the_ones_used() {
    // Blocks flatter than a full luma range everywhere: block matching finds nothing, and
    // the features' median motion moves the region instead. Until 2026-12-05 the tracker
    // built its block matching from the defaults and this setting did nothing.
    let flat = TrackerConfig {
        abm: AbmParams {
            min_texture: 1.0,
            ..AbmParams::default()
        },
        ..TrackerConfig::default()
    };
    let cfg = SynthConfig::new(Scenario::Pan);
    let (given, truth) = run_with(cfg, 8, flat);
    let (default, _) = run_with(cfg, 8, TrackerConfig::default());
    assert!(given.iter().zip(&default).any(|(g, d)| g.state != d.state));
    for (e, t) in given.iter().zip(&truth) {
        assert!(
            !e.lost && (e.state.cx - t.cx).hypot(e.state.cy - t.cy) < 3.0,
            "{e:?}"
        );
    }
}

#[test]
fn bad_input_is_an_error() {
    let r = Renderer::new(&SynthConfig {
        frames: 2,
        ..SynthConfig::new(Scenario::Nod)
    })
    .unwrap();
    let (img, _) = r.render(0);
    let (w, h) = img.dimensions();
    // Each start and setting refused here is refused as well by the public checks an
    // embedder can run before building a tracker (`Init::check`, `TrackerConfig::check`).
    assert!(Init::frontal(r.init_ellipse()).check(w, h).is_ok());
    assert!(TrackerConfig::default().check().is_ok());
    for (e, want) in [
        (
            Ellipse::new(500.0, 50.0, 10.0, 10.0),
            InitFault::CentreOutside,
        ),
        (Ellipse::new(50.0, 50.0, 0.0, 10.0), InitFault::NotAnEllipse),
        (Ellipse::new(50.0, 50.0, 1.5, 10.0), InitFault::AxesTooSmall),
        (
            Ellipse::new(f64::NAN, 5.0, 5.0, 5.0),
            InitFault::NotAnEllipse,
        ),
        // Wider than twice the frame.
        (
            Ellipse::new(50.0, 50.0, f64::from(w.max(h)) + 1.0, 10.0),
            InitFault::AxesTooLarge,
        ),
        // An angle of more than a turn (-1e30 degrees was taken, and changed the track).
        (
            Ellipse {
                theta: -1e30f64.to_radians(),
                ..r.init_ellipse()
            },
            InitFault::AngleOutOfRange,
        ),
    ] {
        let init = Init::frontal(e);
        // A program can tell what is wrong without reading the message.
        let got = init.check(w, h);
        assert!(
            matches!(got, Err(TrackError::BadInit { fault, .. }) if fault == want),
            "{e:?}: {got:?}"
        );
        assert!(Tracker::new(TrackerConfig::default(), &img, init).is_err());
    }
    // A frame without pixels, to start or start over on, is named as such (it was refused
    // as a start "at most 0 px" wide).
    let init = Init::frontal(r.init_ellipse());
    for (ew, eh) in [(0, 0), (0, 5), (5, 0)] {
        let empty = image::RgbImage::new(ew, eh);
        let empty_frame = |r: pftrack::Result<()>| {
            matches!(
                r,
                Err(pftrack::Error::Track(TrackError::EmptyFrame { width, height }))
                    if (width, height) == (ew, eh)
            )
        };
        assert!(empty_frame(
            Tracker::new(TrackerConfig::default(), &empty, init).map(|_| ())
        ));
        let mut t = Tracker::new(TrackerConfig::default(), &img, init).unwrap();
        assert!(empty_frame(t.reinit(&empty, init)));
        // The failed start left the tracker as it was.
        assert!(t.step(&r.render(1).0).is_ok());
    }
    // The largest ellipse and the widest angles allowed.
    let side = f64::from(w.max(h));
    let whole = Ellipse {
        theta: -std::f64::consts::TAU,
        ..Ellipse::new(f64::from(w) / 2.0, f64::from(h) / 2.0, side, side)
    };
    assert!(Init::frontal(whole).check(w, h).is_ok());
    let turned = Init {
        ellipse: r.init_ellipse(),
        pose: Euler::from_degrees(360.0, -360.0, 0.0),
    };
    assert!(turned.check(w, h).is_ok());
    for bad in [1000.0, f64::INFINITY, f64::NAN] {
        let init = Init {
            ellipse: r.init_ellipse(),
            pose: Euler::from_degrees(0.0, bad, 0.0),
        };
        assert!(matches!(
            init.check(w, h),
            Err(TrackError::BadInit {
                fault: InitFault::PoseOutOfRange,
                ..
            })
        ));
    }
    // The filter clamps every particle's semi-axes to its bounds: a start outside them is
    // refused, not clamped away.
    let init = Init::frontal(r.init_ellipse());
    for (min_axis, max_axis) in [(100.0, f64::INFINITY), (2.0, 5.0)] {
        let mut cfg = TrackerConfig::default();
        cfg.filter.min_axis = min_axis;
        cfg.filter.max_axis = max_axis;
        assert!(cfg.check().is_ok());
        assert!(init.check(w, h).is_ok());
        let Err(TrackError::BadInit {
            fault: InitFault::OutsideFilterBounds,
            why,
            ..
        }) = init.check_for(&cfg, w, h)
        else {
            panic!("a start outside the filter's axes {min_axis}..{max_axis} passed");
        };
        assert!(why.contains("filter.min_axis"), "{why}");
        let err = Tracker::new(cfg, &img, init).unwrap_err();
        assert!(
            matches!(err, pftrack::Error::Track(TrackError::BadInit { .. })),
            "{err}"
        );
    }
    // The contrast term's flag without its settings would fail on the first step.
    let mut cfg = TrackerConfig {
        contrast: None,
        ..TrackerConfig::default()
    };
    cfg.likelihood.terms |= pftrack::likelihood::TERM_CONTRAST;
    assert!(matches!(
        cfg.check(),
        Err(TrackError::BadConfig {
            setting: "contrast",
            ..
        })
    ));
    assert!(Tracker::new(cfg, &img, init).is_err());
    // The tracker's own errors convert with `?` into the crate's error.
    let checked = |cfg: &TrackerConfig| -> pftrack::Result<()> {
        cfg.check()?;
        init.check_for(cfg, w, h)?;
        Ok(())
    };
    assert!(checked(&TrackerConfig::default()).is_ok());
    // The keyframe fits' rotation prior needs positive sigmas.
    for px in [0.0, -1.0, f64::NAN] {
        let cfg = TrackerConfig {
            fit_pixel_sigma: Some(px),
            ..TrackerConfig::default()
        };
        let Err(TrackError::BadConfig {
            setting: "fit_pixel_sigma",
            why,
            ..
        }) = cfg.check()
        else {
            panic!("fit_pixel_sigma {px} passed the check");
        };
        assert!(why.contains("fit_pixel_sigma"), "{why}");
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("fit_pixel_sigma"), "{err}");
    }
    // The adaptive colour model's rate is a share in (0, 1], its threshold a confidence.
    for (rate, min_confidence) in [(0.0, 0.5), (1.5, 0.5), (f64::NAN, 0.5), (0.1, 2.0)] {
        let cfg = TrackerConfig {
            colour_update: Some(ColourUpdate {
                rate,
                min_confidence,
                ..ColourUpdate::default()
            }),
            ..TrackerConfig::default()
        };
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("colour update"), "{err}");
    }
    // The anchor refit needs a positive residual and enough inliers for its 6 parameters.
    for (max_residual, min_inliers) in [(0.0, 14), (f64::NAN, 14), (-1.0, 14), (0.5, 5)] {
        let cfg = TrackerConfig {
            anchor_refit: Some(AnchorRefit {
                max_residual,
                min_inliers,
            }),
            ..TrackerConfig::default()
        };
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("anchor refit"), "{err}");
    }
    // The bundle adjustment: positive sigmas, enough views, at least one iteration.
    let good = BundleAdjust::default();
    let bad = [
        BundleAdjust {
            params: BundleParams {
                depth_sigma: 0.0,
                ..good.params
            },
            ..good
        },
        BundleAdjust {
            params: BundleParams {
                rotation_sigma: [0.07, f64::NAN, 0.07],
                ..good.params
            },
            ..good
        },
        BundleAdjust {
            params: BundleParams {
                iterations: 0,
                ..good.params
            },
            ..good
        },
        BundleAdjust {
            min_views: 1,
            ..good
        },
        BundleAdjust {
            max_views: 6,
            ..good
        },
        BundleAdjust { every: 0, ..good },
        BundleAdjust {
            min_turn: -0.1,
            ..good
        },
    ];
    for b in bad {
        let cfg = TrackerConfig {
            bundle: Some(b),
            ..TrackerConfig::default()
        };
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("bundle"), "{b:?}: {err}");
    }
    // The colour update's gate is a similarity.
    for max_ring_similarity in [-0.1, 1.5, f64::NAN] {
        let cfg = TrackerConfig {
            colour_update: Some(ColourUpdate {
                max_ring_similarity,
                ..ColourUpdate::default()
            }),
            ..TrackerConfig::default()
        };
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("max_ring_similarity"), "{err}");
    }
    // The aspect bound's slack and the size hold are widening factors: finite, at least 1.
    for k in [0.5, 0.9, 0.0, -1.0, -1.2, f64::NAN, f64::INFINITY] {
        let aspect_slack = TrackerConfig {
            aspect_slack: Some(k),
            ..TrackerConfig::default()
        };
        let size_hold = TrackerConfig {
            size_hold: Some(k),
            ..TrackerConfig::default()
        };
        for (name, cfg) in [("aspect_slack", aspect_slack), ("size_hold", size_hold)] {
            let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
            assert!(err.to_string().contains(name), "{name} {k}: {err}");
        }
    }
    // The inter-frame consensus: a positive threshold and at least the 3 matches of a map.
    for (threshold, min_inliers) in [(0.0, 5), (f64::NAN, 5), (-1.0, 5), (1.0, 2)] {
        let cfg = TrackerConfig {
            interframe_consensus: Some(pftrack::pose::Consensus {
                threshold,
                min_inliers,
            }),
            ..TrackerConfig::default()
        };
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("consensus"), "{err}");
    }
    // The contrast term: a ring beyond the ellipse, a positive bound, shares in [0, 1].
    let d = Contrast::default();
    for c in [
        Contrast { ring: 1.0, ..d },
        Contrast {
            ring: f64::NAN,
            ..d
        },
        Contrast { limit: 0.0, ..d },
        Contrast {
            weight: f64::NAN,
            ..d
        },
        Contrast { weight: -1.0, ..d },
        Contrast {
            background_rate: 1.5,
            ..d
        },
        Contrast {
            min_confidence: -0.1,
            ..d
        },
    ] {
        let cfg = TrackerConfig {
            contrast: Some(c),
            ..TrackerConfig::default()
        };
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("contrast"), "{c:?}: {err}");
    }
    for w in [-1.0, f64::NAN, f64::INFINITY] {
        let cfg = TrackerConfig {
            feature_weight: w,
            ..TrackerConfig::default()
        };
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("feature_weight"), "{w}: {err}");
    }
    // The default template with one setting out of range.
    let t = TemplateTerm::default();
    let bad_templates = [
        TemplateTerm { weight: -1.0, ..t },
        TemplateTerm {
            weight: f64::NAN,
            ..t
        },
        TemplateTerm { grid: 1, ..t },
        TemplateTerm { grid: 65, ..t },
        TemplateTerm { rate: 1.5, ..t },
        TemplateTerm {
            min_confidence: f64::NAN,
            ..t
        },
        TemplateTerm {
            anchor_weight: -1.0,
            ..t
        },
        TemplateTerm {
            anchor_weight: f64::INFINITY,
            ..t
        },
        TemplateTerm {
            anchor_weight_camera: -1.0,
            ..t
        },
        TemplateTerm {
            anchor_weight_camera: f64::NAN,
            ..t
        },
        TemplateTerm {
            anchor_threshold: 1.0,
            ..t
        },
        TemplateTerm {
            anchor_threshold: f64::NAN,
            ..t
        },
    ];
    for template in bad_templates {
        let cfg = TrackerConfig {
            template: Some(template),
            ..TrackerConfig::default()
        };
        let err = Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).unwrap_err();
        assert!(err.to_string().contains("template"), "{err}");
    }
    // The pan held fixed (no proposal spread, no random walk): the keyframe fits' motion
    // prior needs a walk on every axis, and without the prior it is accepted.
    let mut cfg = TrackerConfig::default();
    cfg.filter.proposal.rotation[1] = 0.0;
    cfg.filter.dynamics.rotation[1] = 0.0;
    assert!(Tracker::new(cfg.clone(), &img, Init::frontal(r.init_ellipse())).is_err());
    cfg.fit_pixel_sigma = None;
    assert!(Tracker::new(cfg, &img, Init::frontal(r.init_ellipse())).is_ok());
    // A frame of another size.
    let mut t = Tracker::new(
        TrackerConfig::default(),
        &img,
        Init::frontal(r.init_ellipse()),
    )
    .unwrap();
    assert!(t.step(&image::RgbImage::new(10, 10)).is_err());
    // A frame with no texture: no features, the tracker still answers.
    let flat = image::RgbImage::from_pixel(img.width(), img.height(), image::Rgb([90, 90, 90]));
    let e = t.step(&flat).unwrap();
    assert_eq!(e.matches, 0);
    assert!(e.confidence < 0.9);
}

#[test]
fn the_adaptive_colour_model_follows_a_gradual_change_of_light() {
    // `nod` dimmed by 1.5 % a frame, to 48 % at frame 35: the geometry is the scenario's, only
    // the colours move, as under a passing shadow.
    let n = 36;
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let dim = |img: image::RgbImage, k: usize| {
        let f = 1.0 - 0.015 * k as f64;
        image::RgbImage::from_fn(img.width(), img.height(), |x, y| {
            image::Rgb(img.get_pixel(x, y).0.map(|c| (c as f64 * f).round() as u8))
        })
    };
    let run = |update: Option<ColourUpdate>| {
        let (first, _) = r.render(0);
        let cfg = TrackerConfig {
            colour_update: update,
            ..TrackerConfig::default()
        };
        let mut t = Tracker::new(cfg, &first, Init::frontal(r.init_ellipse())).unwrap();
        let mut worst: f64 = 0.0;
        let mut conf = Vec::new();
        for k in 1..n {
            let (img, truth) = r.render(k);
            let e = t.step(&dim(img, k)).unwrap();
            worst = worst.max((e.state.cx - truth.cx).hypot(e.state.cy - truth.cy));
            conf.push(e.confidence);
        }
        // The mean confidence over the last ten frames.
        let tail = conf[conf.len() - 10..].iter().sum::<f64>() / 10.0;
        (worst, tail)
    };
    let (worst, adaptive) = run(Some(ColourUpdate::default()));
    let (_, fixed) = run(None);
    // On the head (semi-axes about 20 px), and sure of it where the fixed model is not.
    // Measured 2026-12-06 with scenario and filter seeds 0-2: the adaptive model's centre
    // within 0.9-1.3 px, its confidence 0.79-0.88 over the last ten frames, the fixed one's
    // 0.42-0.46.
    assert!(worst < 4.0, "adaptive model: centre {worst:.2} px off");
    assert!(adaptive > 0.7, "adaptive model: confidence {adaptive:.3}");
    assert!(
        fixed < adaptive - 0.2,
        "fixed {fixed:.3} vs adaptive {adaptive:.3}"
    );
}

#[test]
fn the_colour_model_learns_only_while_it_tells_the_target_from_its_surroundings() {
    // `nod` dimmed by 1.5 % a frame as above; in the second sequence the same head is on a
    // background made of its own colours (each pixel outside the head's ellipse takes the
    // colour of a point of the head), so its model looks like its surroundings.
    let n = 20;
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let init = r.init_ellipse();
    let ring_like_target = |img: &image::RgbImage| {
        let (w, h) = img.dimensions();
        image::RgbImage::from_fn(w, h, |x, y| {
            let (u, v) = (x as f64 - init.cx, y as f64 - init.cy);
            let inside = (u / (1.05 * init.a)).powi(2) + (v / (1.05 * init.b)).powi(2) <= 1.0;
            if inside {
                *img.get_pixel(x, y)
            } else {
                // A point of the head: the pixel's direction from the centre, at a radius
                // that cycles through the inner ellipse.
                let t = v.atan2(u);
                let k = ((u.hypot(v) / 3.0) as u32 % 9) as f64 / 10.0;
                let px = (init.cx + k * init.a * t.cos()).round() as u32;
                let py = (init.cy + k * init.b * t.sin()).round() as u32;
                *img.get_pixel(px.min(w - 1), py.min(h - 1))
            }
        })
    };
    let run = |camouflage: bool, update: ColourUpdate| {
        let scene = |k: usize| {
            let (img, _) = r.render(k);
            let f = 1.0 - 0.015 * k as f64;
            let img = image::RgbImage::from_fn(img.width(), img.height(), |x, y| {
                image::Rgb(img.get_pixel(x, y).0.map(|c| (c as f64 * f).round() as u8))
            });
            if camouflage {
                ring_like_target(&img)
            } else {
                img
            }
        };
        let first = scene(0);
        let cfg = TrackerConfig {
            colour_update: Some(update),
            ..TrackerConfig::default()
        };
        let mut t = Tracker::new(cfg, &first, Init::frontal(init)).unwrap();
        let start = t.colour_model().clone();
        for k in 1..n {
            t.step(&scene(k)).unwrap();
        }
        (start, t.colour_model().clone())
    };
    let gate = ColourUpdate::default();
    let open = ColourUpdate {
        max_ring_similarity: 1.0,
        ..gate
    };
    // Where the head stands out, the model follows the light, with the gate or without.
    let (start, end) = run(false, gate);
    assert!(start.similarity(&end) < 0.99, "{}", start.similarity(&end));
    let (_, free) = run(false, open);
    assert_eq!(end, free);
    // Among its own colours the model holds still; without the gate it would have moved.
    let (start, end) = run(true, gate);
    assert_eq!(start, end);
    let (start, moved) = run(true, open);
    assert!(
        start.similarity(&moved) < 0.99,
        "{}",
        start.similarity(&moved)
    );
}

/// `img` moved `dx` pixels to the right (left when negative), wrapping around.
fn shifted(img: &image::RgbImage, dx: i64) -> image::RgbImage {
    let w = img.width() as i64;
    image::RgbImage::from_fn(w as u32, img.height(), |x, y| {
        *img.get_pixel((x as i64 - dx).rem_euclid(w) as u32, y)
    })
}

/// Frames of `nod` where, from frame `jump` on, the head is 55 px to the left of where it
/// was, alone on a flat grey frame: beyond the reach of block matching and of the features
/// searched around the last estimate.
fn jumped(r: &Renderer, k: usize, jump: usize) -> (image::RgbImage, (f64, f64)) {
    let (img, truth) = r.render(k);
    if k < jump {
        return (img, (truth.cx, truth.cy));
    }
    let mut img = shifted(&img, -55);
    let around = Ellipse::new(truth.cx - 55.0, truth.cy, 1.2 * truth.a, 1.2 * truth.b);
    for (x, y, p) in img.enumerate_pixels_mut() {
        if !around.contains(x as f64, y as f64) {
            *p = image::Rgb([128, 128, 128]);
        }
    }
    (img, (truth.cx - 55.0, truth.cy))
}

/// Frames 1 to `n - 1` of [`jumped`] tracked with `cfg` from frame 0: each estimate with the
/// head's true centre (`[k]` is frame `k + 1`).
fn track_jumped(
    r: &Renderer,
    cfg: TrackerConfig,
    jump: usize,
    n: usize,
) -> Vec<(pftrack::tracker::Estimate, (f64, f64))> {
    let (first, _) = jumped(r, 0, jump);
    let mut t = Tracker::new(cfg, &first, Init::frontal(r.init_ellipse())).unwrap();
    (1..n)
        .map(|k| {
            let (img, centre) = jumped(r, k, jump);
            (t.step(&img).unwrap(), centre)
        })
        .collect()
}

/// Every estimate of `track` within 3 px of its centre, and not lost.
fn assert_followed(track: &[(pftrack::tracker::Estimate, (f64, f64))]) {
    for (e, (cx, cy)) in track {
        let d = (e.state.cx - cx).hypot(e.state.cy - cy);
        assert!(
            d < 3.0 && !e.lost,
            "frame {}: {d:.1} px off, lost {}",
            e.frame,
            e.lost
        );
    }
}

#[test]
fn a_target_that_jumps_away_is_lost_then_reacquired_by_its_features() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let (jump, n) = (6, 30);
    let track = track_jumped(&r, TrackerConfig::default(), jump, n);
    // (`track[k]` is frame `k + 1`.) At the jump the filter stays where the head was, with
    // no confidence.
    let (e, (cx, _)) = &track[jump - 1];
    assert!((e.state.cx - cx).abs() > 20.0 && e.confidence < 0.25);
    // The filter alone does not get there: on the next frame it is still far off.
    let (e, (cx, _)) = &track[jump];
    assert!((e.state.cx - cx).abs() > 20.0 && e.confidence < 0.25);
    // On the third such frame (`lost_after`) the target is lost and searched for: the colour
    // search finds it, its features fit the anchor view, and the estimate is placed there in
    // the same step, with the found target's own confidence.
    let (e, (cx, cy)) = &track[jump + 1];
    assert!((e.state.cx - cx).hypot(e.state.cy - cy) < 3.0 && !e.lost);
    assert!(
        e.confidence >= 0.25,
        "frame {}: found, but with the lost track's confidence {}",
        e.frame,
        e.confidence
    );
    // The frame after, its features are matched with those found around the head on the
    // frame it was found, not with the flat grey where it had been (none: the frame after a
    // re-acquisition measured no rotation between the two).
    let (e, _) = &track[jump + 2];
    assert!(e.matches >= 5, "frame {}: {} matches", e.frame, e.matches);
    // Then followed.
    assert_followed(&track[n - 10..]);
}

#[test]
fn the_tracker_keeps_its_particles_to_the_models_aspect_range() {
    // `nod` starts on its ellipsoid's narrowest outline (a/b = 18.5/24.7, the depth between
    // them), so a free filter soon proposes narrower ellipses; the default config holds every
    // particle to [a/b, b/a] of the first ellipse, and `aspect_slack: None` does not.
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let init = r.init_ellipse();
    let (lo, hi) = (init.a / init.b, init.b / init.a);
    assert!(lo < 1.0);
    let outside = |slack: Option<f64>| {
        let cfg = TrackerConfig {
            aspect_slack: slack,
            ..TrackerConfig::default()
        };
        let mut t = Tracker::new(cfg, &r.render(0).0, Init::frontal(init)).unwrap();
        let mut n = 0;
        for k in 1..8 {
            t.step(&r.render(k).0).unwrap();
            n += t
                .filter()
                .particles()
                .iter()
                .filter(|p| !(lo * (1.0 - 1e-9)..=hi * (1.0 + 1e-9)).contains(&(p.a / p.b)))
                .count();
        }
        n
    };
    assert_eq!(outside(Some(1.0)), 0);
    let free = outside(None);
    assert!(
        free > 100,
        "only {free} free particles left the range in 7 frames"
    );
}

/// While the tracker is unsure of its target (after a frame below `trust_above`, or lost), its
/// particles keep the size of the last trusted estimate (within `size_hold`); without the
/// hold nothing keeps them there. The head of `nod` is followed for a few frames, then leaves
/// nothing but a flat grey frame: no likelihood can rank sizes there, and the random walk
/// (three times wider once the target is lost) spreads them.
#[test]
fn an_uncertain_tracker_holds_the_last_confident_size() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let (first, _) = r.render(0);
    let grey = image::RgbImage::from_pixel(first.width(), first.height(), image::Rgb([128; 3]));
    let (gone, n) = (6, 26);
    let run = |hold: Option<f64>| {
        let cfg = TrackerConfig {
            size_hold: hold,
            ..TrackerConfig::default()
        };
        let (lost_below, trust_above) = (cfg.lost_below, cfg.trust_above);
        let mut t = Tracker::new(cfg, &first, Init::frontal(r.init_ellipse())).unwrap();
        let mut held = (r.init_ellipse().a, r.init_ellipse().b);
        // The largest factor between a particle's semi-axis and the held one, over the frames
        // that followed one the tracker did not trust.
        let mut worst: f64 = 1.0;
        let mut unsure = 0;
        let mut trusted = true;
        for k in 1..n {
            let img = if k < gone {
                r.render(k).0
            } else {
                grey.clone()
            };
            let e = t.step(&img).unwrap();
            if k < gone {
                assert!(e.confidence >= lost_below && !e.lost, "frame {k}: {e:?}");
            }
            if !trusted {
                unsure += 1;
                for p in t.filter().particles() {
                    for (x, h) in [(p.a, held.0), (p.b, held.1)] {
                        worst = worst.max(x / h).max(h / x);
                    }
                }
            }
            trusted = !e.lost && e.confidence >= trust_above;
            if trusted {
                held = (e.state.a, e.state.b);
            }
        }
        assert!(
            t.step(&grey).unwrap().lost,
            "still not lost after {} empty frames",
            n - gone
        );
        assert!(unsure >= n - gone - 1, "unsure on only {unsure} frames");
        worst
    };
    let held = run(Some(1.2));
    assert!(
        held <= 1.2 + 1e-9,
        "a particle {held:.3} times the held size"
    );
    let free = run(None);
    assert!(
        free > 1.5,
        "free particles stayed within {free:.3} of the held size"
    );
}

/// A frame with every pixel replaced by its grey level (`R = G = B`), as grayscale footage
/// is read.
fn greyed(img: &image::RgbImage) -> image::RgbImage {
    let mut g = img.clone();
    for p in g.pixels_mut() {
        let [r, gr, b] = p.0.map(u32::from);
        let l = ((77 * r + 150 * gr + 29 * b + 128) >> 8) as u8;
        p.0 = [l, l, l];
    }
    g
}

/// The grey-footage switch is each start's: a tracker started over on colour frames after
/// grey ones (or the other way) counts the bins and tracks as one built on the new frames.
#[test]
fn a_reinit_between_grey_and_colour_footage_tracks_as_a_new_tracker_would() {
    use pftrack::likelihood::{COLOUR_LUMA, COLOUR_RGB};
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let cfg = TrackerConfig {
        seed: 2,
        ..TrackerConfig::default()
    };
    let shown =
        |grey: bool| move |img: &image::RgbImage| if grey { greyed(img) } else { img.clone() };
    for (before, after) in [(true, false), (false, true)] {
        let (was, now) = (shown(before), shown(after));
        let bins = if after { COLOUR_LUMA } else { COLOUR_RGB };
        let init = Init::frontal(r.init_ellipse());
        let mut reused = Tracker::new(cfg.clone(), &was(&r.render(0).0), init).unwrap();
        for k in 1..4 {
            reused.step(&was(&r.render(k).0)).unwrap();
        }
        let (restart, truth) = r.render(4);
        let init = Init {
            ellipse: truth.ellipse(r.init_ellipse().theta),
            pose: truth.euler(),
        };
        reused.reinit(&now(&restart), init).unwrap();
        let mut fresh = Tracker::new(cfg.clone(), &now(&restart), init).unwrap();
        assert_eq!(reused.likelihood().colour_bins, bins);
        assert_eq!(reused.likelihood(), fresh.likelihood());
        // The configuration stays as given: a tracker built from it starts as this one did.
        assert_eq!(reused.config(), &cfg);
        assert_eq!(fresh.config(), &cfg);
        for k in 5..12 {
            let img = now(&r.render(k).0);
            let (a, b) = (reused.step(&img).unwrap(), fresh.step(&img).unwrap());
            assert_eq!(
                (a.state, a.confidence, a.lost),
                (b.state, b.confidence, b.lost),
                "grey {before} -> {after}, frame {k}"
            );
        }
    }
}

#[test]
fn grayscale_footage_gets_luma_bins_and_is_followed() {
    use pftrack::likelihood::{COLOUR_LUMA, COLOUR_RGB};
    let cfg = SynthConfig::new(Scenario::Nod);
    let r = Renderer::new(&cfg).unwrap();
    let first = greyed(&r.render(0).0);
    let init = Init::frontal(r.init_ellipse());
    // Colour frames keep the RGB bins; grey ones get luma bins unless that is switched off.
    let colour = Tracker::new(TrackerConfig::default(), &r.render(0).0, init).unwrap();
    assert_eq!(colour.likelihood().colour_bins, COLOUR_RGB);
    let off = TrackerConfig {
        grey_luma: false,
        ..TrackerConfig::default()
    };
    let kept = Tracker::new(off, &first, init).unwrap();
    assert_eq!(kept.likelihood().colour_bins, COLOUR_RGB);
    let mut t = Tracker::new(TrackerConfig::default(), &first, init).unwrap();
    assert_eq!(t.likelihood().colour_bins, COLOUR_LUMA);
    // A grey start leaves the configuration as given (it used to read luma bins there, so a
    // colour tracker built from a clone of it counted luma too).
    assert_eq!(t.config(), &TrackerConfig::default());
    let mut worst: f64 = 0.0;
    for k in 1..30 {
        let (img, truth) = r.render(k);
        let e = t.step(&greyed(&img)).unwrap();
        assert!(!e.lost, "frame {k} declared lost");
        worst = worst.max((e.state.cx - truth.cx).hypot(e.state.cy - truth.cy));
    }
    // Measured 2026-12-06 with scenario and filter seeds 0-2: within 1.0-1.7 px.
    assert!(worst < 5.0, "centre off by {worst:.2} px");
}

/// A target lost before the footage turns grey is found again in the grey frames: the luma
/// model comes from the colour start's own frame (a lost track has nowhere else to learn
/// it). Before, the switch to luma waited for a followed frame, which the RGB model, scoring
/// every grey place 0, never gave: lost for the whole grey stretch. The same with
/// `lost_after` 1, where the first grey frame alone declared the target lost.
#[test]
fn a_target_lost_before_the_footage_turns_grey_is_found_in_it() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    // Frames 10-17 a noisy magenta screen (colour, no target), grey from frame 18 on.
    let shown = |k: usize| {
        let img = r.render(k).0;
        match k {
            10..=17 => image::RgbImage::from_fn(img.width(), img.height(), |x, y| {
                let n = ((x * 7 + y * 13 + k as u32 * 5) % 23) as u8;
                image::Rgb([200 + n, 20 + n, 190 + n])
            }),
            18.. => greyed(&img),
            _ => img,
        }
    };
    let grey_from_10 = |k: usize| {
        let img = r.render(k).0;
        if k >= 10 { greyed(&img) } else { img }
    };
    type Shown<'a> = &'a dyn Fn(usize) -> image::RgbImage;
    let seq: [(Shown, TrackerConfig, usize); 2] = [
        (&shown, TrackerConfig::default(), 18),
        (
            &grey_from_10,
            TrackerConfig {
                lost_after: 1,
                ..TrackerConfig::default()
            },
            10,
        ),
    ];
    for (case, (frame, cfg, grey_from)) in seq.into_iter().enumerate() {
        let mut t = Tracker::new(cfg, &frame(0), Init::frontal(r.init_ellipse())).unwrap();
        let mut lost_on = Vec::new();
        let mut worst: f64 = 0.0;
        for k in 1..40 {
            let e = t.step(&frame(k)).unwrap();
            if e.lost {
                lost_on.push(k);
            }
            if k >= grey_from + 10 {
                let truth = r.truth(k);
                worst = worst.max((e.state.cx - truth.cx).hypot(e.state.cy - truth.cy));
            }
        }
        if case == 0 {
            assert!(
                lost_on.contains(&12),
                "case {case}: never lost: {lost_on:?}"
            );
        }
        // Found again within a few grey frames, and followed from there.
        assert!(
            lost_on.iter().all(|&k| k < grey_from + 5),
            "case {case}: lost on {lost_on:?}"
        );
        assert!(worst < 5.0, "case {case}: centre off by {worst:.2} px");
    }
}

/// Mean and largest relative error of the ellipse's size `sqrt(a b)` over a track.
fn size_errors((est, truth): &Track) -> (f64, f64) {
    let errs: Vec<f64> = est
        .iter()
        .zip(truth)
        .map(|(e, t)| ((e.state.a * e.state.b).sqrt() / (t.a * t.b).sqrt() - 1.0).abs())
        .collect();
    let mean = errs.iter().sum::<f64>() / errs.len() as f64;
    (mean, errs.iter().cloned().fold(0.0, f64::max))
}

/// A head approaching to 0.6 of its depth and receding to 1.4: the contrast term (on by
/// default) keeps the ellipse to the head's size. Measured on this sequence (filter seed 0):
/// mean 1.2 %, largest 3.8 % with it; 3.5 % and 12.5 % without it (the colour term alone
/// cannot tell an ellipse a little too small or too large from the right one, and the
/// proposal does not scale it by default, `TrackerConfig::motion_scale`).
#[test]
fn the_contrast_term_keeps_the_ellipse_to_the_targets_size() {
    let cfg = SynthConfig::new(Scenario::Depth);
    let steps = cfg.frames;
    let with = size_errors(&run_with(cfg, steps, TrackerConfig::default()));
    let without = size_errors(&run_with(
        cfg,
        steps,
        TrackerConfig {
            contrast: None,
            ..TrackerConfig::default()
        },
    ));
    eprintln!("size error (mean, max): with contrast {with:?}, without {without:?}");
    assert!(with.0 < 0.02 && with.1 < 0.07, "{with:?}");
    assert!(with.0 < without.0, "{with:?} against {without:?}");
}

/// The contrast term's flag given in the settings, on a start whose ring around the ellipse
/// holds no pixel (a target filling the frame): the term has no background there, so the
/// tracker leaves it off, and the track goes on (every step had failed for want of a table).
#[test]
fn the_contrast_flag_on_a_target_filling_the_frame_leaves_the_term_off() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let (first, _) = r.render(0);
    let mut tc = TrackerConfig::default();
    tc.likelihood.terms = pftrack::likelihood::TERM_ALL;
    assert!(tc.contrast.is_some());
    let fill = Ellipse {
        cx: 79.5,
        cy: 59.5,
        a: 100.0,
        b: 100.0,
        theta: 0.0,
    };
    let mut t = Tracker::new(tc.clone(), &first, Init::frontal(fill)).unwrap();
    for k in 1..4 {
        let est = t.step(&r.render(k).0).unwrap();
        assert!(est.state.cx.is_finite() && est.confidence.is_finite());
    }
    // Where the ring has pixels, the flag given is the term the tracker turns on anyway.
    let mut given = Tracker::new(tc, &first, Init::frontal(r.init_ellipse())).unwrap();
    let mut default = Tracker::new(
        TrackerConfig::default(),
        &first,
        Init::frontal(r.init_ellipse()),
    )
    .unwrap();
    for k in 1..4 {
        let img = r.render(k).0;
        assert_eq!(
            given.step(&img).unwrap(),
            default.step(&img).unwrap(),
            "frame {k}"
        );
    }
}

/// Frames handed over in a camera's layout (BGRA rows padded to a stride) track as the same
/// frames in RGB do, and a view of another size is refused without changing the track.
#[test]
fn frames_in_a_cameras_buffer_track_as_rgb_frames_do() {
    use pftrack::frames::{FrameView, PixelFormat};
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let (first, _) = r.render(0);
    let init = Init::frontal(r.init_ellipse());
    let mut by_rgb = Tracker::new(TrackerConfig::default(), &first, init).unwrap();
    let mut by_view = Tracker::new(TrackerConfig::default(), &first, init).unwrap();
    let (w, h) = first.dimensions();
    let stride = 4 * w as usize + 12;
    for k in 1..6 {
        let img = r.render(k).0;
        let mut bgra = vec![0u8; stride * h as usize];
        for (x, y, p) in img.enumerate_pixels() {
            let at = y as usize * stride + 4 * x as usize;
            bgra[at..at + 4].copy_from_slice(&[p.0[2], p.0[1], p.0[0], 255]);
        }
        let view = FrameView::new(&bgra, w, h, stride, PixelFormat::Bgra8).unwrap();
        if k == 3 {
            // A view of another size: refused, and the next frame steps as if it had not come.
            let small = FrameView::new(&bgra, w - 1, h, stride, PixelFormat::Bgra8).unwrap();
            let err = by_view.step_view(&small).unwrap_err();
            assert!(
                matches!(err, pftrack::Error::Track(TrackError::FrameSize { .. })),
                "{err}"
            );
        }
        assert_eq!(
            by_view.step_view(&view).unwrap(),
            by_rgb.step(&img).unwrap(),
            "frame {k}"
        );
    }
}

/// The proposal leaves the semi-axes alone unless `motion_scale` is on: with no axis noise in
/// the filter (Σ_G and Σ_P zero on `a` and `b`), a track of the approaching head keeps the
/// first ellipse's size exactly by default, and follows the measured growth with the option.
#[test]
fn the_motion_scales_the_ellipse_only_when_asked() {
    let cfg = SynthConfig::new(Scenario::Depth);
    let r = Renderer::new(&cfg).unwrap();
    let init = r.init_ellipse();
    let mut tc = TrackerConfig::default();
    tc.filter.proposal.axes = 0.0;
    tc.filter.dynamics.axes = 0.0;
    let sizes = |motion_scale: bool| {
        let c = TrackerConfig {
            motion_scale,
            ..tc.clone()
        };
        let (est, truth) = run_with(cfg, 12, c);
        let last = est.last().unwrap().state;
        let grew = (truth.last().unwrap().a * truth.last().unwrap().b).sqrt()
            / (truth[0].a * truth[0].b).sqrt();
        (last.a, last.b, grew)
    };
    let (a, b, grew) = sizes(false);
    assert!(grew > 1.03, "the head grew only {grew:.3} times");
    // To rounding: the estimate is the weighted mean of equal values.
    assert!(
        (a - init.a).abs() < 1e-9 && (b - init.b).abs() < 1e-9,
        "{a} x {b} from {} x {}",
        init.a,
        init.b
    );
    let (a, b, _) = sizes(true);
    assert!(
        (a * b).sqrt() > 1.01 * (init.a * init.b).sqrt(),
        "with the motion's scale: {a:.2} x {b:.2} from {:.2} x {:.2}",
        init.a,
        init.b
    );
}

/// As above, but with no keyframe fit possible (more inliers asked of a fit than a frame has
/// features, and no anchor refit), as on a target too small for 10 matches: the features can
/// no longer recognise the head after its jump, and its template does.
#[test]
fn a_target_too_small_for_a_feature_fit_is_reacquired_by_its_template() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let (jump, n) = (6, 30);
    let run = |reacquire_ncc: Option<f64>| {
        let cfg = TrackerConfig {
            min_fit_inliers: usize::MAX,
            anchor_refit: None,
            reacquire_ncc,
            ..TrackerConfig::default()
        };
        track_jumped(&r, cfg, jump, n)
    };
    // By its features alone the head is not found on the frame it is declared lost: the
    // track is lost there, far off (its widened random walk may stumble on the head later).
    let blind = run(None);
    let (e, (cx, _)) = &blind[jump + 1];
    assert!(
        e.lost && (e.state.cx - cx).abs() > 20.0,
        "frame {}: found without a fit ({e:?})",
        e.frame
    );
    // With the template it is found on the frame it is declared lost, then followed.
    let track = run(TrackerConfig::default().reacquire_ncc);
    let (e, (cx, cy)) = &track[jump + 1];
    let d = (e.state.cx - cx).hypot(e.state.cy - cy);
    assert!(
        d < 5.0 && !e.lost,
        "frame {}: {d:.1} px off, {e:?}",
        e.frame
    );
    assert_followed(&track[n - 10..]);
}

/// A 160x120 frame of 4-px cells of muted green, and where `at` is `Some`, a small target
/// (semi-axes 7 x 9) of red cells that move with it.
fn small_target_frame(at: Option<(f64, f64)>) -> image::RgbImage {
    let hash = |i: i64, j: i64, k: u64| {
        let mut z = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ k.wrapping_mul(0x1656_67B1_9E37_79F9);
        z ^= z >> 31;
        z = z.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z ^= z >> 29;
        z
    };
    let channel = |z: u64, shift: u32, lo: u64, span: u64| (lo + (z >> shift) % span) as u8;
    image::RgbImage::from_fn(160, 120, |x, y| {
        let (xf, yf) = (x as f64, y as f64);
        if let Some((cx, cy)) = at {
            let (u, v) = ((xf - cx) / 7.0, (yf - cy) / 9.0);
            if u * u + v * v <= 1.0 {
                let (i, j) = (
                    ((xf - cx + 32.0) / 4.0) as i64,
                    ((yf - cy + 32.0) / 4.0) as i64,
                );
                let z = hash(i, j, 1);
                return image::Rgb([
                    channel(z, 0, 120, 136),
                    channel(z, 16, 0, 90),
                    channel(z, 32, 0, 90),
                ]);
            }
        }
        let z = hash(x as i64 / 4, y as i64 / 4, 2);
        image::Rgb([
            channel(z, 0, 40, 60),
            channel(z, 16, 80, 60),
            channel(z, 32, 60, 60),
        ])
    })
}

/// A target too small for a keyframe fit leaves the frame, and reappears standing still
/// elsewhere 37 frames later: on every seed its template recognises it on the frame it is
/// back, in the pose it was last trusted in. While lost, the estimate's rotation walks (a
/// roll of 25-55 degrees on a target that never turned), and the search laid its template
/// at that roll: 4 seeds of 16 never found the target again, though it stood in full view.
#[test]
fn a_lost_target_is_recognised_in_the_pose_it_was_last_trusted_in() {
    let at = |k: usize| match k {
        0..28 => Some((80.0 + 3.0 * k as f64, 60.0)),
        28..65 => None,
        _ => Some((40.0, 40.0)),
    };
    for seed in 0..4 {
        let cfg = TrackerConfig {
            seed,
            ..TrackerConfig::default()
        };
        let first = small_target_frame(at(0));
        let init = Init::frontal(Ellipse::new(80.0, 60.0, 7.0, 9.0));
        let mut t = Tracker::new(cfg, &first, init).unwrap();
        let track: Vec<_> = (1..80)
            .map(|k| t.step(&small_target_frame(at(k))).unwrap())
            .collect();
        assert!(
            track[40..64].iter().all(|e| e.lost),
            "seed {seed}: lost while the target is away"
        );
        let back = &track[64];
        assert_eq!(back.frame, 65);
        let d = (back.state.cx - 40.0).hypot(back.state.cy - 40.0);
        assert!(
            !back.lost && d < 3.0,
            "seed {seed}: {d:.1} px off, {back:?}"
        );
        let turned = [back.state.rx, back.state.ry, back.state.rz]
            .map(|a| a.to_degrees().abs())
            .into_iter()
            .fold(0.0, f64::max);
        assert!(
            turned < 15.0,
            "seed {seed}: found turned by {turned:.1} degrees: {back:?}"
        );
        assert!(track[70..].iter().all(|e| !e.lost), "seed {seed}: followed");
    }
}

/// A frame of `w x h`: a textured grey-green background (value noise on an 8-px lattice,
/// fixed) and a plain orange ellipse of semi-axes 18 x 14 centred on `(cx, cy)`.
fn plain_target_frame(w: u32, h: u32, cx: f64, cy: f64) -> image::RgbImage {
    let lattice = |i: i64, j: i64| {
        let mut z = (i * 7919 + j * 104_729) as u64;
        z = z.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        z ^= z >> 29;
        (z % 1000) as f64 / 1000.0
    };
    let noise = |x: f64, y: f64| {
        let (gx, gy) = (x / 8.0, y / 8.0);
        let (i, j) = (gx.floor() as i64, gy.floor() as i64);
        let (fx, fy) = (gx - gx.floor(), gy - gy.floor());
        let top = lattice(i, j) * (1.0 - fx) + lattice(i + 1, j) * fx;
        let bottom = lattice(i, j + 1) * (1.0 - fx) + lattice(i + 1, j + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    };
    image::RgbImage::from_fn(w, h, |x, y| {
        let (u, v) = ((x as f64 - cx) / 18.0, (y as f64 - cy) / 14.0);
        if u * u + v * v <= 1.0 {
            image::Rgb([225, 120, 40])
        } else {
            let g = 60.0 + 120.0 * noise(x as f64, y as f64);
            image::Rgb([(0.8 * g) as u8, g as u8, (0.7 * g) as u8])
        }
    })
}

/// The plain target of [`plain_target_frame`] (semi-axes 18 and 14) moving 1.5 px right
/// and 0.5 px down a frame for 30 frames, tracked with `cfg`: each frame's estimate and the
/// target's true centre.
fn track_plain_target(cfg: TrackerConfig) -> Vec<(pftrack::tracker::Estimate, (f64, f64))> {
    let (w, h) = (160, 120);
    let at = |k: usize| (50.0 + 1.5 * k as f64, 50.0 + 0.5 * k as f64);
    let first = plain_target_frame(w, h, at(0).0, at(0).1);
    let init = Ellipse::new(at(0).0, at(0).1, 18.0, 14.0);
    let mut t = Tracker::new(cfg, &first, Init::frontal(init)).unwrap();
    (1..30)
        .map(|k| {
            let (cx, cy) = at(k);
            (t.step(&plain_target_frame(w, h, cx, cy)).unwrap(), (cx, cy))
        })
        .collect()
}

#[test]
fn a_target_without_texture_is_followed_by_colour_and_contour_and_its_score_says_so() {
    // No texture on the target: SIFT has nothing to match there, so no rotation can be
    // measured. The ellipse must still follow it (colour and contour), and the confidence
    // must carry the missing rotation (at most 0.8 of the colour and contour support).
    // Re-anchoring on the first view is off here (the next test has it on).
    let cfg = TrackerConfig {
        reanchor: None,
        ..TrackerConfig::default()
    };
    for (e, (cx, cy)) in track_plain_target(cfg) {
        let k = e.frame;
        let off = (e.state.cx - cx).hypot(e.state.cy - cy);
        assert!(off < 2.0, "frame {k}: {off:.2} px off");
        assert!((e.state.a - 18.0).abs() < 2.0 && (e.state.b - 14.0).abs() < 2.0);
        assert_eq!(e.matches, 0, "frame {k}");
        assert!(!e.lost, "frame {k}");
        // Recognised (colour and contour agree), but not sure of its pose.
        assert!(
            (0.5..=0.8).contains(&e.confidence),
            "frame {k}: confidence {:.3}",
            e.confidence
        );
    }
}

#[test]
fn re_anchoring_a_target_without_texture_does_not_claim_its_pose_measured() {
    // With re-anchoring on (the default), the plain target is re-anchored on its first view
    // on most frames, at the first view's pose. Without features in that view the pose is
    // no better measured than before: the confidence keeps its discount (at most 0.8).
    // Before the first view's features were counted, 9 of 10 filter seeds reported 0.83-0.99.
    for seed in 0..4 {
        let cfg = TrackerConfig {
            seed,
            ..TrackerConfig::default()
        };
        assert!(cfg.reanchor.is_some());
        for (e, (cx, cy)) in track_plain_target(cfg) {
            let k = e.frame;
            let off = (e.state.cx - cx).hypot(e.state.cy - cy);
            assert!(off < 2.0, "seed {seed}, frame {k}: {off:.2} px off");
            assert!(!e.lost, "seed {seed}, frame {k}");
            assert!(
                (0.5..=0.8).contains(&e.confidence),
                "seed {seed}, frame {k}: confidence {:.3}",
                e.confidence
            );
        }
    }
}

/// `img` blurred by a box of `2 r + 1` pixels, `passes` times (about a Gaussian of σ
/// `r · sqrt(passes / 3)`): the colours stay, the texture SIFT needs goes.
fn blurred(img: &image::RgbImage, r: i64, passes: usize) -> image::RgbImage {
    let (w, h) = (i64::from(img.width()), i64::from(img.height()));
    let mut cur = img.clone();
    for _ in 0..passes {
        let src = cur.clone();
        for y in 0..h {
            for x in 0..w {
                let mut sum = [0u32; 3];
                let mut n = 0u32;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (u, v) = ((x + dx).clamp(0, w - 1), (y + dy).clamp(0, h - 1));
                        let p = src.get_pixel(u as u32, v as u32);
                        for c in 0..3 {
                            sum[c] += u32::from(p[c]);
                        }
                        n += 1;
                    }
                }
                cur.put_pixel(
                    x as u32,
                    y as u32,
                    image::Rgb(sum.map(|s| ((s + n / 2) / n) as u8)),
                );
            }
        }
    }
    cur
}

#[test]
fn a_turn_carries_on_through_frames_where_nothing_measures_it() {
    // The synthetic head pans about 1.9 degrees a frame at the start. Frames 8-12 are blurred
    // until no feature matches: nothing measures the rotation there (the confidence drops
    // to 0; `lost_after` is raised so that the track is not declared lost within the gap).
    // Held still (`coast_rate: None`), the pan falls behind by about what the head turned in
    // the gap, 9.5 degrees; with the estimate's recent turn carried on (the default
    // `coast_rate`) it does not. One seed's estimate wanders by a few degrees a frame with
    // nothing to measure, so the signed errors at the gap's end are compared over ten
    // filter seeds (measured: -1.9 against -8.5 degrees on average).
    let r = Renderer::new(&SynthConfig::new(Scenario::Pan)).unwrap();
    let (first, _) = r.render(0);
    let gap = 8..=12;
    let seeds = 0..10u64;
    let mut sums = [0.0f64; 2];
    for seed in seeds.clone() {
        for (i, coast_rate) in [TrackerConfig::default().coast_rate, None]
            .into_iter()
            .enumerate()
        {
            let cfg = TrackerConfig {
                seed,
                coast_rate,
                lost_after: 10,
                ..TrackerConfig::default()
            };
            let mut t = Tracker::new(cfg, &first, Init::frontal(r.init_ellipse())).unwrap();
            let mut error = f64::NAN;
            for k in 1..=*gap.end() {
                let (img, truth) = r.render(k);
                let img = if gap.contains(&k) {
                    blurred(&img, 3, 3)
                } else {
                    img
                };
                let e = t.step(&img).unwrap();
                assert!(!e.lost, "seed {seed}, frame {k}");
                if gap.contains(&k) {
                    assert_eq!(
                        e.matches, 0,
                        "seed {seed}, frame {k}: the blur left matches"
                    );
                }
                error = (e.state.ry - truth.ry).to_degrees();
            }
            sums[i] += error;
        }
    }
    let n = seeds.count() as f64;
    let [coasting, held] = sums.map(|s| s / n);
    assert!(
        held < -5.0 && coasting > held + 3.0 && coasting.abs() < 4.0,
        "mean signed pan error at the gap's end: {coasting:.2} degrees coasting, {held:.2} held"
    );
}

/// The last step's weighing is open to inspection: one entry per particle, the terms the
/// engine gave those very particles, the log-weights the terms' weighted sum, and the best
/// weighted particle on the target; nothing before a step or after a start.
#[test]
fn the_last_weighing_shows_each_particle_its_terms_and_log_weight() {
    use pftrack::likelihood::cpu::CpuEngine;
    use pftrack::likelihood::{FrameInput, LikelihoodEngine, Particle, TERM_COLOUR};
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let init = Init::frontal(r.init_ellipse());
    // The colour term alone, so that each log-weight is its particle's colour term.
    let mut cfg = TrackerConfig {
        template: None,
        contrast: None,
        ..TrackerConfig::default()
    };
    cfg.likelihood.terms = TERM_COLOUR;
    let n = cfg.filter.particles;
    let mut t = Tracker::new(cfg, &r.render(0).0, init).unwrap();
    assert!(t.last_weighing().is_none());
    for k in 1..4 {
        let (img, truth) = r.render(k);
        let model = t.colour_model().clone();
        t.step(&img).unwrap();
        let w = t.last_weighing().unwrap();
        assert_eq!(
            (w.particles.len(), w.terms.len(), w.totals.len()),
            (n, n, n)
        );
        for (term, total) in w.terms.iter().zip(w.totals) {
            assert_eq!(*total, term.colour, "frame {k}");
        }
        // The same particles scored again by an engine of our own give the same terms.
        let mut engine = CpuEngine::new();
        engine.set_colour_model(&model).unwrap();
        let input = FrameInput {
            image: &img,
            features: &[],
            depths: None,
            prev: Particle::default(),
            theta0: r.init_ellipse().theta as f32,
        };
        let mut again = Vec::new();
        engine
            .evaluate(&input, t.likelihood(), w.particles, &mut again)
            .unwrap();
        assert_eq!(again.as_slice(), w.terms, "frame {k}");
        let best = (0..n).max_by(|&i, &j| w.totals[i].total_cmp(&w.totals[j]));
        let p = w.particles[best.unwrap()];
        let off = (f64::from(p.cx) - truth.cx).hypot(f64::from(p.cy) - truth.cy);
        assert!(off < 3.0, "frame {k}: best particle {off} px off");
    }
    t.reinit(&r.render(4).0, init).unwrap();
    assert!(t.last_weighing().is_none());
}

/// A step that re-acquires its target scores the found target on its own; the weighing of
/// the step's particles stays whole (that single evaluation used to overwrite the terms with
/// its own one).
#[test]
fn the_weighing_stays_whole_through_a_reacquisition() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let jump = 6;
    let cfg = TrackerConfig::default();
    let n = cfg.filter.particles;
    let (first, _) = jumped(&r, 0, jump);
    let mut t = Tracker::new(cfg, &first, Init::frontal(r.init_ellipse())).unwrap();
    let mut reacquired = 0;
    let mut was_low = false;
    for k in 1..jump + 4 {
        let (img, _) = jumped(&r, k, jump);
        let e = t.step(&img).unwrap();
        let w = t.last_weighing().unwrap();
        assert_eq!(
            (w.particles.len(), w.terms.len(), w.totals.len()),
            (n, n, n),
            "frame {k}"
        );
        // Not one particle's terms repeated: each was scored where it stands.
        assert!(w.terms.iter().any(|t| *t != w.terms[0]), "frame {k}");
        if was_low && e.confidence >= 0.5 {
            reacquired += 1;
        }
        was_low = e.confidence < 0.25;
    }
    assert_eq!(reacquired, 1, "the head was not re-acquired once");
}

/// A likelihood engine around the CPU's that fails, while armed, as a GPU fault would; and,
/// when `small`, refuses every particle count, as a device too small would.
struct Flaky {
    inner: pftrack::likelihood::cpu::CpuEngine,
    armed: std::sync::Arc<std::sync::atomic::AtomicBool>,
    small: bool,
}

impl Flaky {
    fn fault(&self) -> Result<(), pftrack::likelihood::LikelihoodError> {
        if self.armed.load(std::sync::atomic::Ordering::SeqCst) {
            Err(pftrack::likelihood::LikelihoodError::Gpu(
                "armed fault".into(),
            ))
        } else {
            Ok(())
        }
    }
}

impl pftrack::likelihood::LikelihoodEngine for Flaky {
    fn name(&self) -> String {
        "flaky".into()
    }
    fn set_colour_model(
        &mut self,
        model: &pftrack::likelihood::ColourHistogram,
    ) -> Result<(), pftrack::likelihood::LikelihoodError> {
        self.fault()?;
        self.inner.set_colour_model(model)
    }
    fn set_contrast_table(
        &mut self,
        table: &pftrack::likelihood::ContrastTable,
    ) -> Result<(), pftrack::likelihood::LikelihoodError> {
        self.inner.set_contrast_table(table)
    }
    fn evaluate(
        &mut self,
        frame: &pftrack::likelihood::FrameInput<'_>,
        params: &pftrack::likelihood::LikelihoodParams,
        particles: &[pftrack::likelihood::Particle],
        out: &mut Vec<pftrack::likelihood::TermLogs>,
    ) -> Result<(), pftrack::likelihood::LikelihoodError> {
        self.fault()?;
        self.inner.evaluate(frame, params, particles, out)
    }
    fn check_capacity(
        &self,
        particles: usize,
        w: u32,
        h: u32,
        params: &pftrack::likelihood::LikelihoodParams,
    ) -> Result<(), pftrack::likelihood::LikelihoodError> {
        if self.small {
            return Err(pftrack::likelihood::LikelihoodError::Invalid(format!(
                "refusing {particles} particles"
            )));
        }
        self.inner.check_capacity(particles, w, h, params)
    }
}

/// A frame of the wrong size is refused and changes nothing: the track goes on as if it had
/// not come, bit for bit.
#[test]
fn a_wrong_sized_frame_changes_nothing() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let init = Init::frontal(r.init_ellipse());
    let (first, _) = r.render(0);
    let mut a = Tracker::new(TrackerConfig::default(), &first, init).unwrap();
    let mut b = Tracker::new(TrackerConfig::default(), &first, init).unwrap();
    let odd = image::RgbImage::new(first.width() + 1, first.height());
    assert_eq!(a.frame_size(), first.dimensions());
    for k in 1..=6 {
        let (img, _) = r.render(k);
        if k == 3 {
            assert_eq!(a.last_frame(), 2);
            let e = a.step(&odd).unwrap_err();
            assert_eq!(a.last_frame(), 2, "a refused frame is not counted");
            assert!(
                matches!(
                    e,
                    pftrack::Error::Track(TrackError::FrameSize { frame: 3, .. })
                ),
                "{e}"
            );
        }
        assert_eq!(a.step(&img).unwrap(), b.step(&img).unwrap(), "frame {k}");
    }
    // A restart on a frame of another size takes its size from then on.
    let small = image::RgbImage::from_pixel(64, 48, image::Rgb([90, 60, 30]));
    let e = pftrack::geometry::Ellipse::new(32.0, 24.0, 8.0, 10.0);
    a.reinit(&small, Init::frontal(e)).unwrap();
    assert_eq!((a.frame_size(), a.last_frame()), ((64, 48), 7));
    let err = a.step(&first).unwrap_err().to_string();
    assert!(
        err.contains("the frame the track started on was 64x48"),
        "{err}"
    );
}

/// A CPU engine on a pool of its own gives the same track as the one on the step's pool, on a
/// step's pool of one thread or of two. A step on a pool of one thread used to hang on the first
/// frame here: waiting for the engine's pool, its thread ran the step's own helper, which
/// served until a step that could not go on was done (`tracker::pool`). Watched, so that a
/// hang fails the test.
#[test]
fn an_engine_on_a_pool_of_its_own_tracks_as_the_one_on_the_steps_pool() {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
        let init = Init::frontal(r.init_ellipse());
        let (first, _) = r.render(0);
        let frames: Vec<_> = (1..=4).map(|k| r.render(k).0).collect();
        let track = |engine: pftrack::likelihood::cpu::CpuEngine, threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let cfg = TrackerConfig::default();
                let mut t = Tracker::with_engine(cfg, Box::new(engine), &first, init).unwrap();
                frames
                    .iter()
                    .map(|f| t.step(f).unwrap().state)
                    .collect::<Vec<_>>()
            })
        };
        let own = |n| pftrack::likelihood::cpu::CpuEngine::with_threads(n).unwrap();
        let want = track(pftrack::likelihood::cpu::CpuEngine::new(), 2);
        let got = [track(own(2), 1), track(own(2), 2), track(own(3), 1)];
        let _ = tx.send((want, got));
    });
    let (want, got) = rx
        .recv_timeout(std::time::Duration::from_secs(300))
        .expect("a tracker with its engine on a pool of its own never finished its steps");
    for g in got {
        assert_eq!(g, want);
    }
}

/// A step or restart that fails part-way (the engine's fault) stops the tracker: every later
/// step says so, naming the frame and the cause, with no weighing to read, until a restart
/// succeeds; then it tracks as a tracker started on that frame does.
#[test]
fn a_failed_step_stops_the_tracker_until_reinit() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let init = Init::frontal(r.init_ellipse());
    let (first, _) = r.render(0);
    let armed = Arc::new(AtomicBool::new(false));
    let engine = Flaky {
        inner: pftrack::likelihood::cpu::CpuEngine::new(),
        armed: armed.clone(),
        small: false,
    };
    let mut t =
        Tracker::with_engine(TrackerConfig::default(), Box::new(engine), &first, init).unwrap();
    for k in 1..=2 {
        t.step(&r.render(k).0).unwrap();
    }
    assert!(t.last_weighing().is_some());
    let (f3, _) = r.render(3);
    armed.store(true, Ordering::SeqCst);
    assert!(!t.is_failed());
    let e = t.step(&f3).unwrap_err();
    assert!(matches!(e, pftrack::Error::Likelihood(_)), "{e}");
    assert!(t.last_weighing().is_none());
    assert!(t.is_failed());
    armed.store(false, Ordering::SeqCst);
    for _ in 0..2 {
        let e = t.step(&f3).unwrap_err();
        let pftrack::Error::Track(TrackError::Failed { frame, cause }) = &e else {
            panic!("{e}")
        };
        assert_eq!(*frame, 3);
        assert!(cause.contains("armed fault"), "{cause}");
        assert!(e.to_string().contains("reinit"), "{e}");
    }

    // A restart that fails (setting the colour model) leaves it stopped too.
    armed.store(true, Ordering::SeqCst);
    assert!(t.reinit(&f3, init).is_err());
    armed.store(false, Ordering::SeqCst);
    let e = t.step(&r.render(4).0).unwrap_err();
    assert!(
        matches!(e, pftrack::Error::Track(TrackError::Failed { .. })),
        "{e}"
    );

    // Restarted from where the track was, the start is that estimate.
    let last = fresh_estimate(&r, 2);
    t.reinit(&f3, last.to_init()).unwrap();
    assert!(!t.is_failed() && !t.is_lost());
    let again = t.initial_estimate();
    assert_eq!((again.frame, again.state), (3, last.state));
    assert_eq!(again.ellipse, last.ellipse);

    // Restarted on frame 3, it tracks as a tracker built there.
    t.reinit(&f3, init).unwrap();
    let mut fresh = Tracker::new(TrackerConfig::default(), &f3, init).unwrap();
    for k in 4..=6 {
        let (img, _) = r.render(k);
        let (a, b) = (t.step(&img).unwrap(), fresh.step(&img).unwrap());
        assert_eq!(a.state, b.state, "frame {k}");
    }
}

/// The start's refinement ([`TrackerConfig::init_refine`]) stays within the bounds a start is
/// checked against: where it would shrink a 2 px start on a 1 px dot, the start is the one
/// given.
#[test]
fn a_refined_start_stays_within_the_starts_bounds() {
    let mut frame = image::RgbImage::from_pixel(48, 32, image::Rgb([40, 40, 40]));
    for (x, y) in [(2, 16), (3, 16), (2, 17), (3, 17)] {
        frame.put_pixel(x, y, image::Rgb([230, 230, 230]));
    }
    let cfg = TrackerConfig {
        init_refine: Some(pftrack::tracker::InitRefine::default()),
        ..TrackerConfig::default()
    };
    for cx in [2.0, 2.5, 3.0, 4.0] {
        let init = Init::frontal(Ellipse::new(cx, 16.5, 2.0, 2.0));
        init.check_for(&cfg, 48, 32).unwrap();
        let t = Tracker::new(cfg.clone(), &frame, init).unwrap();
        let used = t.initial_estimate().ellipse;
        let start = Init::frontal(used);
        assert!(start.check_for(&cfg, 48, 32).is_ok(), "{cx}: {used:?}");
    }
}

/// The estimate of frame `k` of `r`'s sequence by a default tracker started on frame 0.
fn fresh_estimate(r: &Renderer, k: usize) -> pftrack::tracker::Estimate {
    let init = Init::frontal(r.init_ellipse());
    let mut t = Tracker::new(TrackerConfig::default(), &r.render(0).0, init).unwrap();
    let mut est = t.initial_estimate();
    for i in 1..=k {
        est = t.step(&r.render(i).0).unwrap();
    }
    est
}

/// A target that turned past a whole turn still gives a start the tracker takes: `to_init`
/// takes the whole turns off, which changes neither the rotation nor the ellipse, so the
/// track goes on as from the same estimate within a turn.
#[test]
fn a_start_from_an_estimate_past_a_turn_is_taken() {
    use std::f64::consts::TAU;
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let last = fresh_estimate(&r, 2);
    let mut turned = last;
    turned.state.rx -= TAU;
    turned.state.rz += 2.0 * TAU;
    turned.ellipse.theta += 2.0 * TAU;
    let (w, h) = r.render(0).0.dimensions();
    // As given, such a start is refused; `to_init` brings it within a turn.
    let raw = Init {
        ellipse: turned.ellipse,
        pose: turned.state.euler(),
    };
    assert!(raw.check(w, h).is_err());
    let init = turned.to_init();
    init.check(w, h).unwrap();
    let (m, want) = (init.pose.matrix(), last.state.euler().matrix());
    assert!((m - want).abs().max() < 1e-12, "{m} against {want}");
    let (e, f) = (init.ellipse, last.ellipse);
    assert_eq!((e.cx, e.cy, e.a, e.b), (f.cx, f.cy, f.a, f.b));
    assert!((e.theta.sin() - f.theta.sin()).abs() < 1e-12);
    assert!((e.theta.cos() - f.theta.cos()).abs() < 1e-12);

    let (f3, _) = r.render(3);
    let mut a = Tracker::new(
        TrackerConfig::default(),
        &r.render(0).0,
        Init::frontal(r.init_ellipse()),
    )
    .unwrap();
    let mut b = Tracker::new(
        TrackerConfig::default(),
        &r.render(0).0,
        Init::frontal(r.init_ellipse()),
    )
    .unwrap();
    a.reinit(&f3, init).unwrap();
    b.reinit(&f3, last.to_init()).unwrap();
    for k in 4..=6 {
        let (img, _) = r.render(k);
        let (x, y) = (a.step(&img).unwrap(), b.step(&img).unwrap());
        let (sx, sy) = (x.state, y.state);
        let d = [sx.cx - sy.cx, sx.cy - sy.cy, sx.a - sy.a, sx.b - sy.b];
        assert!(
            d.iter().all(|v| v.abs() < 1e-6),
            "frame {k}: {sx:?} against {sy:?}"
        );
        let turn = x.state.euler().matrix() - y.state.euler().matrix();
        assert!(turn.abs().max() < 1e-6, "frame {k}: {sx:?} against {sy:?}");
    }
}

/// Replacing the likelihood engine keeps the track: a tracker whose engine is swapped for
/// another CPU engine part-way tracks bit for bit as one that kept its own; a replacement the
/// new engine refuses leaves the old one in place; and a tracker stopped by its engine's
/// fault goes on, on a new engine, from its last estimate.
#[test]
fn replacing_the_engine_keeps_the_track() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let r = Renderer::new(&SynthConfig::new(Scenario::Combo)).unwrap();
    let init = Init::frontal(r.init_ellipse());
    let (first, _) = r.render(0);
    // The contrast term is on by default, so its table is handed over too.
    let cfg = TrackerConfig::default();
    assert!(cfg.contrast.is_some());
    let mut kept = Tracker::new(cfg.clone(), &first, init).unwrap();
    let armed = Arc::new(AtomicBool::new(false));
    let flaky = Flaky {
        inner: pftrack::likelihood::cpu::CpuEngine::new(),
        armed: armed.clone(),
        small: false,
    };
    let mut swapped = Tracker::with_engine(cfg.clone(), Box::new(flaky), &first, init).unwrap();
    for k in 1..=8 {
        let (img, _) = r.render(k);
        if k == 4 {
            let old = swapped
                .replace_engine(Box::new(pftrack::likelihood::cpu::CpuEngine::new()))
                .unwrap();
            assert_eq!(old.name(), "flaky");
            assert_eq!(swapped.engine_name(), kept.engine_name());
        }
        assert_eq!(
            swapped.step(&img).unwrap(),
            kept.step(&img).unwrap(),
            "frame {k}"
        );
    }

    // An engine that cannot hold the particles is refused; the tracker keeps its own.
    let small = Flaky {
        inner: pftrack::likelihood::cpu::CpuEngine::new(),
        armed: Arc::new(AtomicBool::new(false)),
        small: true,
    };
    let Err(e) = swapped.replace_engine(Box::new(small)) else {
        panic!("an engine that refuses the particles was taken")
    };
    assert!(e.to_string().contains("refusing"), "{e}");
    let (img, _) = r.render(9);
    assert_eq!(swapped.step(&img).unwrap(), kept.step(&img).unwrap());

    // A fault stops the tracker; a new engine and a restart from the last estimate go on.
    let mut t = Tracker::with_engine(
        cfg,
        Box::new(Flaky {
            inner: pftrack::likelihood::cpu::CpuEngine::new(),
            armed: armed.clone(),
            small: false,
        }),
        &first,
        init,
    )
    .unwrap();
    let mut last = t.initial_estimate();
    for k in 1..=3 {
        last = t.step(&r.render(k).0).unwrap();
    }
    armed.store(true, Ordering::SeqCst);
    let (f4, _) = r.render(4);
    assert!(t.step(&f4).is_err());
    t.replace_engine(Box::new(pftrack::likelihood::cpu::CpuEngine::new()))
        .unwrap();
    assert!(matches!(
        t.step(&f4).unwrap_err(),
        pftrack::Error::Track(TrackError::Failed { frame: 4, .. })
    ));
    t.reinit(&f4, last.to_init()).unwrap();
    for k in 5..=7 {
        let e = t.step(&r.render(k).0).unwrap();
        assert!(!e.lost && e.confidence > 0.5, "frame {k}: {e:?}");
    }
}

/// Frame `k` of `r`'s `nod`, with the head hidden behind flat grey on frames `hidden`, and
/// on frames `scrambled` replaced by its own pixels in a scrambled order: the same colours
/// inside the same outline, the head's face gone.
fn hidden_or_scrambled(
    r: &Renderer,
    k: usize,
    hidden: std::ops::Range<usize>,
    scrambled: std::ops::Range<usize>,
) -> image::RgbImage {
    let (mut img, truth) = r.render(k);
    let head = Ellipse::new(truth.cx, truth.cy, truth.a, truth.b);
    let cover = Ellipse::new(truth.cx, truth.cy, 1.4 * truth.a, 1.4 * truth.b);
    if hidden.contains(&k) {
        for (x, y, p) in img.enumerate_pixels_mut() {
            if cover.contains(x as f64, y as f64) {
                *p = image::Rgb([128, 128, 128]);
            }
        }
    } else if scrambled.contains(&k) {
        let inside: Vec<(u32, u32)> = img
            .enumerate_pixels()
            .filter(|(x, y, _)| head.contains(*x as f64, *y as f64))
            .map(|(x, y, _)| (x, y))
            .collect();
        let mut pixels: Vec<image::Rgb<u8>> =
            inside.iter().map(|&(x, y)| *img.get_pixel(x, y)).collect();
        // A fixed shuffle (Fisher-Yates on a linear congruential sequence).
        let mut s: u64 = 12345;
        for i in (1..pixels.len()).rev() {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            pixels.swap(i, (s >> 33) as usize % (i + 1));
        }
        for (&(x, y), p) in inside.iter().zip(pixels) {
            img.put_pixel(x, y, p);
        }
    }
    img
}

/// A lost target is not declared found by colour and contour alone: where the head comes
/// back as its own colours scrambled (what background of the target's colours looks like to
/// those cues, as road and trees around a grey car did), the confidence is back above
/// `found_above` but the flag stays up; when the head itself comes back it is recognised
/// and the flag clears.
#[test]
fn a_lost_target_is_found_only_where_it_is_recognised() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let cfg = TrackerConfig::default();
    let (hidden, scrambled, n) = (8..14, 14..22, 34);
    let frame = |k| hidden_or_scrambled(&r, k, hidden.clone(), scrambled.clone());
    let mut t = Tracker::new(cfg.clone(), &frame(0), Init::frontal(r.init_ellipse())).unwrap();
    let track: Vec<_> = (1..n)
        .map(|k| {
            let e = t.step(&frame(k)).unwrap();
            assert_eq!(t.is_lost(), e.lost, "frame {k}");
            e
        })
        .collect();
    let at = |k: usize| &track[k - 1];
    // Hidden: lost by the end of the occlusion.
    assert!(at(hidden.end - 1).lost, "{:?}", at(hidden.end - 1));
    // Scrambled: colour and contour read it as the target, but it is not recognised.
    let confident = scrambled
        .clone()
        .filter(|&k| at(k).confidence >= cfg.found_above)
        .count();
    assert!(
        confident > 0,
        "the scrambled head never looked like the target"
    );
    for k in scrambled.clone() {
        assert!(
            at(k).lost,
            "frame {k}: found on a scrambled head: {:?}",
            at(k)
        );
    }
    // The head itself: found again, and followed.
    let found = (scrambled.end..n).find(|&k| !at(k).lost);
    assert!(
        found.is_some_and(|k| k < scrambled.end + 6),
        "not found again: {found:?}"
    );
    let (last, (_, truth)) = (at(n - 1), r.render(n - 1));
    let d = (last.state.cx - truth.cx).hypot(last.state.cy - truth.cy);
    assert!(!last.lost && d < 3.0, "{last:?} against {truth:?}");
}

/// The synthetic head's frame `k`, with the light halved from frame `from` on.
fn dimmed_from(r: &Renderer, k: usize, from: usize) -> (image::RgbImage, PoseState) {
    let (mut img, truth) = r.render(k);
    if k >= from {
        for p in img.pixels_mut() {
            p.0 = p.0.map(|v| v / 2);
        }
    }
    (img, truth)
}

/// Half the light from one frame to the next (a camera's exposure stepping) is undone: the
/// head is followed through it, never flagged lost, with the confidence it had before.
/// Without the compensation the same change drops the confidence under `found_above`, the
/// bar a found target must reach.
#[test]
fn a_sudden_change_of_light_is_not_a_lost_target() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let (from, n) = (10, 30);
    let track = |cfg: TrackerConfig| {
        let first = dimmed_from(&r, 0, from).0;
        let mut t = Tracker::new(cfg, &first, Init::frontal(r.init_ellipse())).unwrap();
        let steps: Vec<_> = (1..n)
            .map(|k| {
                let (img, truth) = dimmed_from(&r, k, from);
                (t.step(&img).unwrap(), truth)
            })
            .collect();
        // Every frame from the change on was brought back.
        let relit = if t.config().exposure_jump.is_some() {
            n - from
        } else {
            0
        };
        assert_eq!(t.frames_relit(), relit);
        let gain = t.exposure_gain();
        // A restart takes its frame's light as the reference.
        let (last, truth) = dimmed_from(&r, n - 1, from);
        let at = Ellipse::new(truth.cx, truth.cy, truth.a, truth.b);
        t.reinit(&last, Init::frontal(at)).unwrap();
        assert_eq!(t.exposure_gain(), [1.0; 3]);
        (steps, gain)
    };
    let (on, gain) = track(TrackerConfig::default());
    assert!(gain.iter().all(|g| (g - 0.5).abs() < 0.02), "{gain:?}");
    let mean = |s: &[(pftrack::tracker::Estimate, PoseState)]| {
        s.iter().map(|(e, _)| e.confidence).sum::<f64>() / s.len() as f64
    };
    let before = mean(&on[..from - 1]);
    for (k, (e, truth)) in on.iter().enumerate().map(|(i, s)| (i + 1, s)) {
        let d = (e.state.cx - truth.cx).hypot(e.state.cy - truth.cy);
        assert!(!e.lost && d < 3.0, "frame {k}: {e:?} against {truth:?}");
        if k >= from {
            assert!(
                e.confidence > 0.8 * before,
                "frame {k}: {} against {before}",
                e.confidence
            );
        }
    }
    let cfg = TrackerConfig {
        exposure_jump: None,
        ..TrackerConfig::default()
    };
    let found_above = cfg.found_above;
    let (off, gain) = track(cfg);
    assert_eq!(gain, [1.0; 3]);
    // The same frames up to the change; after it, a confidence under `found_above`.
    assert!((mean(&off[..from - 1]) - before).abs() < 1e-12);
    for (k, (e, _)) in off
        .iter()
        .enumerate()
        .map(|(i, s)| (i + 1, s))
        .skip(from - 1)
    {
        assert!(e.confidence < found_above, "frame {k}: {e:?}");
    }
}

/// Frame `k` of `r`, grey (its luma in all three channels) for `k` in one of `grey`, and all
/// black at `black`.
fn grey_within(
    r: &Renderer,
    k: usize,
    grey: &[std::ops::Range<usize>],
    black: usize,
) -> (image::RgbImage, PoseState) {
    let (img, truth) = r.render(k);
    if k == black {
        return (image::RgbImage::new(img.width(), img.height()), truth);
    }
    if !grey.iter().any(|g| g.contains(&k)) {
        return (img, truth);
    }
    let luma = image::DynamicImage::ImageRgb8(img).to_luma8();
    (image::DynamicImage::ImageLuma8(luma).to_rgb8(), truth)
}

/// A camera that turns grey mid-track (night or infrared mode) and back, twice: from the
/// second grey frame the colour term counts luma, learnt afresh on each grey stretch, and
/// from the second colour frame after it the RGB model it had, so the head is followed
/// throughout with the confidence it had, but for the one frame of each change. A single
/// black frame (grey too) changes nothing. With the binning fixed at the start's
/// (`grey_luma` off), the grey frames share no bin with the colour model: a confidence under
/// `found_above`.
#[test]
fn footage_that_turns_grey_and_back_is_followed() {
    use pftrack::likelihood::{COLOUR_LUMA, COLOUR_RGB};
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let (grey, black, n) = ([10..20, 30..36], 25, 40);
    let track = |cfg: TrackerConfig| {
        let first = grey_within(&r, 0, &grey, black).0;
        let mut t = Tracker::new(cfg, &first, Init::frontal(r.init_ellipse())).unwrap();
        (1..n)
            .map(|k| {
                let (img, truth) = grey_within(&r, k, &grey, black);
                let e = t.step(&img).unwrap();
                (e, truth, t.likelihood().colour_bins)
            })
            .collect::<Vec<_>>()
    };
    let on = track(TrackerConfig::default());
    let mean = |s: &[(pftrack::tracker::Estimate, PoseState, u32)]| {
        s.iter().map(|(e, _, _)| e.confidence).sum::<f64>() / s.len() as f64
    };
    let before = mean(&on[..grey[0].start - 1]);
    let is_grey = |k: usize| grey.iter().any(|g| g.contains(&k));
    for (k, (e, truth, bins)) in on.iter().enumerate().map(|(i, s)| (i + 1, s)) {
        let d = (e.state.cx - truth.cx).hypot(e.state.cy - truth.cy);
        assert!(!e.lost && d < 3.0, "frame {k}: {e:?} against {truth:?}");
        // The bins follow the frames' kind from the second frame of a kind on: the frame
        // after a grey stretch still counts luma, the black frame alone changes nothing.
        let luma = if is_grey(k) {
            is_grey(k - 1)
        } else {
            is_grey(k - 1) && k - 1 != black
        };
        let expect = if luma { COLOUR_LUMA } else { COLOUR_RGB };
        assert_eq!(*bins, expect, "frame {k}");
        let first_of_kind = is_grey(k) != is_grey(k - 1) || k == black || k == black + 1;
        if !first_of_kind {
            assert!(
                e.confidence > 0.8 * before,
                "frame {k}: {} against {before}",
                e.confidence
            );
        }
    }

    let cfg = TrackerConfig {
        grey_luma: false,
        ..TrackerConfig::default()
    };
    let found_above = cfg.found_above;
    let off = track(cfg);
    assert!((mean(&off[..grey[0].start - 1]) - before).abs() < 1e-12);
    for (k, (e, _, bins)) in off.iter().enumerate().map(|(i, s)| (i + 1, s)) {
        assert_eq!(*bins, COLOUR_RGB);
        if grey[0].contains(&k) {
            assert!(e.confidence < found_above, "frame {k}: {e:?}");
        }
    }
}
