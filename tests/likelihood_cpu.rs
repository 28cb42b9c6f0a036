//! The CPU likelihood engine and its stages on real and synthetic frames (issue 4, CPU path;
//! the reference of the GPU engine, issue 5).

mod shared_data;

use image::{Rgb, RgbImage};
use pftrack::geometry::{Ellipse, Euler};
use pftrack::likelihood::cpu::{self, CpuEngine, EllipseF32, colour, feature, gradient};
use pftrack::likelihood::{
    COLOUR_RGB, ColourHistogram, ContrastTable, DEGENERATE, FeaturePair, FrameInput, HIST_BINS,
    LikelihoodEngine, LikelihoodError, LikelihoodParams, Particle, TERM_ALL, TERM_COLOUR,
    TERM_CONTRAST, TERM_FEATURE, TERM_GRADIENT, TermLogs,
};
use rand::{Rng, SeedableRng, rngs::StdRng};

/// Girl frame 1 and its ground-truth ellipse, or `None` (with a printed reason).
fn girl_first() -> Option<(RgbImage, Ellipse)> {
    let dir = shared_data::path("girl")?;
    let img = image::open(dir.join("img/0001.jpg")).unwrap().to_rgb8();
    let boxes = pftrack::io::read_otb_boxes(&dir.join("groundtruth_rect.txt")).unwrap();
    Some((img, Ellipse::from_box(&boxes[0])))
}

fn particle_of(e: &Ellipse) -> (Particle, f32) {
    (
        Particle {
            cx: e.cx as f32,
            cy: e.cy as f32,
            a: e.a as f32,
            b: e.b as f32,
            ..Default::default()
        },
        e.theta as f32,
    )
}

fn brute_histogram(img: &RgbImage, e: &EllipseF32) -> ([u32; HIST_BINS], u32) {
    let mut counts = [0u32; HIST_BINS];
    let mut total = 0;
    let (s, c) = e.theta.sin_cos();
    for y in 0..img.height() {
        for x in 0..img.width() {
            // The spec's test, written out here independently of the crate.
            let dx = x as f32 - e.cx;
            let dy = y as f32 - e.cy;
            let u = (c * dx + s * dy) / e.a;
            let v = (-s * dx + c * dy) / e.b;
            if u * u + v * v <= 1.0 {
                let p = img.get_pixel(x, y).0;
                let k = (p[0] as usize >> 5) * 64 + (p[1] as usize >> 5) * 8 + (p[2] as usize >> 5);
                counts[k] += 1;
                total += 1;
            }
        }
    }
    (counts, total)
}

fn model_of(img: &RgbImage, e: &Ellipse) -> colour::Model {
    colour::Model::new(&ColourHistogram::from_ellipse(img, e, COLOUR_RGB).unwrap().0)
}

#[test]
fn colour_model_particle_has_rho_one_and_rho_falls_off_target() {
    let Some((img, e)) = girl_first() else { return };
    let model = model_of(&img, &e);
    let (p, theta0) = particle_of(&e);
    let ef = EllipseF32::from_particle(&p, theta0);
    let (c, t) = colour::histogram(&img, &ef, COLOUR_RGB);
    assert!(t > 500, "{t}");
    assert_eq!(colour::bhattacharyya(&c, t, &model), 1.0);
    assert_eq!(
        colour::log_likelihood(&img, &ef, &model, &LikelihoodParams::default()),
        0.0
    );

    // Moving off the target in each direction: rho falls, and further falls further.
    for (ux, uy) in [(1.0f32, 0.0f32), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)] {
        let rho_at = |d: f32| {
            let q = EllipseF32 {
                cx: ef.cx + ux * d,
                cy: ef.cy + uy * d,
                ..ef
            };
            let (c, t) = colour::histogram(&img, &q, COLOUR_RGB);
            colour::bhattacharyya(&c, t, &model)
        };
        let rhos: Vec<f32> = [0.0, 4.0, 10.0, 20.0].iter().map(|&d| rho_at(d)).collect();
        assert!(
            rhos.windows(2).all(|w| w[1] < w[0]),
            "direction ({ux}, {uy}): {rhos:?}"
        );
    }
}

#[test]
fn colour_histograms_equal_brute_force_on_random_ellipses() {
    let Some((img, _)) = girl_first() else { return };
    let bins = colour::BinImage::new(&img, COLOUR_RGB);
    let mut rng = StdRng::seed_from_u64(42);
    let (w, h) = (img.width() as f32, img.height() as f32);
    for i in 0..1000 {
        let e = EllipseF32 {
            cx: rng.random_range(-20.0..w + 20.0),
            cy: rng.random_range(-20.0..h + 20.0),
            a: rng.random_range(0.3..60.0),
            b: rng.random_range(0.3..60.0),
            theta: if i % 4 == 0 {
                0.0
            } else {
                rng.random_range(-7.0..7.0)
            },
        };
        let want = brute_histogram(&img, &e);
        assert_eq!(colour::histogram(&img, &e, COLOUR_RGB), want, "{e:?}");
        let mut counts = [0; HIST_BINS];
        let t = colour::histogram_bins(&bins, &e, &mut counts);
        assert_eq!((counts, t), want, "{e:?}");
    }
}

#[test]
fn colour_histograms_equal_brute_force_on_large_ellipses() {
    // Big frames and big ellipses stress the f64 span solver against the f32 test.
    let mut rng = StdRng::seed_from_u64(9);
    let img = RgbImage::from_fn(640, 480, |x, y| {
        Rgb([(x * 7) as u8, (y * 3) as u8, (x ^ y) as u8])
    });
    for _ in 0..40 {
        let e = EllipseF32 {
            cx: rng.random_range(-100.0..740.0),
            cy: rng.random_range(-100.0..580.0),
            a: rng.random_range(50.0..900.0),
            b: rng.random_range(0.5..900.0),
            theta: rng.random_range(-4.0..4.0),
        };
        assert_eq!(
            colour::histogram(&img, &e, COLOUR_RGB),
            brute_histogram(&img, &e),
            "{e:?}"
        );
    }
}

#[test]
fn colour_model_errors_on_empty_or_degenerate_ellipses() {
    let img = RgbImage::new(20, 20);
    assert!(
        ColourHistogram::from_ellipse(&img, &Ellipse::new(100.0, 100.0, 5.0, 5.0), COLOUR_RGB)
            .is_err()
    );
    assert!(
        ColourHistogram::from_ellipse(&img, &Ellipse::new(10.0, 10.0, 0.0, 5.0), COLOUR_RGB)
            .is_err()
    );
    assert!(
        ColourHistogram::from_ellipse(&img, &Ellipse::new(f64::NAN, 10.0, 3.0, 5.0), COLOUR_RGB)
            .is_err()
    );
    let m = ColourHistogram::from_ellipse(&img, &Ellipse::new(10.0, 10.0, 3.0, 5.0), COLOUR_RGB)
        .unwrap();
    assert_eq!(m.0.len(), HIST_BINS);
    assert_eq!(m.0[0], 1.0);
}

/// A white filled ellipse (the spec's pixel set) on black.
fn filled_ellipse(w: u32, h: u32, e: &EllipseF32) -> RgbImage {
    let (s, c) = e.theta.sin_cos();
    RgbImage::from_fn(w, h, |x, y| {
        if colour::inside(e, s, c, x as i64, y as i64) {
            Rgb([255, 255, 255])
        } else {
            Rgb([0, 0, 0])
        }
    })
}

#[test]
fn gradient_edges_sit_on_the_contour_of_a_filled_ellipse() {
    let params = LikelihoodParams::default();
    // Axis-aligned circle with its contour points on the axes between pixel centres, nearer
    // the inner one: the inner pixel (first of the two-pixel plateau that central differences
    // give a sharp step) is the sample at t = 0, so every axis line has d = 0.
    let e = EllipseF32 {
        cx: 40.0,
        cy: 30.0,
        a: 15.4,
        b: 15.4,
        theta: 0.0,
    };
    let img = filled_ellipse(80, 60, &e);
    let grad = gradient::GradientImage::new(&img);
    let p4 = LikelihoodParams {
        num_lines: 4,
        ..params
    };
    assert_eq!(
        gradient::edge_distances_ellipse(&grad, &e, &p4),
        vec![Some(0); 4]
    );

    // A rotated ellipse with the default lines: on every line the edge is within the one
    // pixel of the step (d = 0 or 1, depending on which side of the contour the nearest
    // pixel of the contour point lies), never missing.
    let e = EllipseF32 {
        cx: 40.3,
        cy: 29.6,
        a: 20.0,
        b: 14.0,
        theta: 0.5,
    };
    let img = filled_ellipse(80, 60, &e);
    let grad = gradient::GradientImage::new(&img);
    let d = gradient::edge_distances_ellipse(&grad, &e, &params);
    assert_eq!(d.len(), params.num_lines as usize);
    assert!(d.iter().all(|d| matches!(d, Some(0) | Some(1))), "{d:?}");
    assert!(
        d.iter().filter(|d| **d == Some(0)).count() >= d.len() / 3,
        "{d:?}"
    );

    // The true ellipse scores above every 3-px shift and every 3-px change of size.
    let p = Particle {
        cx: e.cx,
        cy: e.cy,
        a: e.a,
        b: e.b,
        ..Default::default()
    };
    let best = gradient::log_likelihood(&grad, &p, e.theta, &params);
    let k = gradient::clutter_gain(&params);
    let floor = params.num_lines as f32 * gradient::line_log(Some(1), k, params.sigma_z);
    assert!(best >= floor, "{best} < {floor}");
    for (dx, dy, da, db) in [
        (3.0, 0.0, 0.0, 0.0),
        (-3.0, 0.0, 0.0, 0.0),
        (0.0, 3.0, 0.0, 0.0),
        (0.0, -3.0, 0.0, 0.0),
        (2.1, 2.1, 0.0, 0.0),
        (0.0, 0.0, 3.0, 0.0),
        (0.0, 0.0, -3.0, -3.0),
        (0.0, 0.0, 0.0, 3.0),
    ] {
        let q = Particle {
            cx: p.cx + dx,
            cy: p.cy + dy,
            a: p.a + da,
            b: p.b + db,
            ..p
        };
        let l = gradient::log_likelihood(&grad, &q, e.theta, &params);
        assert!(l < best, "shift ({dx}, {dy}, {da}, {db}): {l} vs {best}");
    }
}

#[test]
fn gradient_of_an_image_without_edges_is_zero() {
    let img = RgbImage::from_pixel(64, 48, Rgb([120, 30, 200]));
    let grad = gradient::GradientImage::new(&img);
    assert!(grad.g.iter().all(|g| *g == [0, 0]));
    let p = Particle {
        cx: 30.0,
        cy: 20.0,
        a: 12.0,
        b: 9.0,
        rz: 0.3,
        ..Default::default()
    };
    let params = LikelihoodParams::default();
    assert_eq!(gradient::log_likelihood(&grad, &p, 0.1, &params), 0.0);
    assert!(
        gradient::edge_distances(&grad, &p, 0.1, &params)
            .iter()
            .all(|d| d.is_none())
    );
}

/// Features generated by exactly the spec's model (in f64, independently of the crate):
/// previous points `p` on the previous ellipse, current points `q = c + s ΔR X`.
fn model_features(
    prev: &Particle,
    truth: &Particle,
    depth_ratio: f64,
    n: usize,
) -> Vec<FeaturePair> {
    let mut rng = StdRng::seed_from_u64(11);
    let r_prev = Euler::new(prev.rx as f64, prev.ry as f64, prev.rz as f64).matrix();
    let r = Euler::new(truth.rx as f64, truth.ry as f64, truth.rz as f64).matrix();
    let dr = r * r_prev.transpose();
    let s = ((truth.a * truth.b) as f64 / (prev.a * prev.b) as f64).sqrt();
    let e = Ellipse {
        cx: prev.cx as f64,
        cy: prev.cy as f64,
        a: prev.a as f64,
        b: prev.b as f64,
        theta: prev.rz as f64,
    };
    (0..n)
        .map(|_| {
            let (u, v): (f64, f64) = loop {
                let u = rng.random_range(-1.0..1.0);
                let v = rng.random_range(-1.0..1.0);
                if u * u + v * v < 0.9 {
                    break (u, v);
                }
            };
            // point at unit coordinates (u, v) of the previous ellipse
            let (sn, cs) = e.theta.sin_cos();
            let (ex, ey) = (e.a * u, e.b * v);
            let dx = cs * ex - sn * ey;
            let dy = sn * ex + cs * ey;
            let z = -depth_ratio * (e.a * e.b).sqrt() * (1.0 - u * u - v * v).max(0.0).sqrt();
            let x = nalgebra::Vector3::new(dx, dy, z);
            let m = dr * x;
            FeaturePair {
                p: [(e.cx + dx) as f32, (e.cy + dy) as f32],
                q: [
                    (truth.cx as f64 + s * m.x) as f32,
                    (truth.cy as f64 + s * m.y) as f32,
                ],
            }
        })
        .collect()
}

#[test]
fn feature_term_is_highest_at_the_generating_particle() {
    let params = LikelihoodParams::default();
    let prev = Particle {
        cx: 60.0,
        cy: 50.0,
        a: 20.0,
        b: 24.0,
        rx: 0.1,
        ry: -0.05,
        rz: 0.2,
        _pad: 0.0,
    };
    let truth = Particle {
        cx: 63.0,
        cy: 48.0,
        a: 22.0,
        b: 25.0,
        rx: 0.25,
        ry: -0.2,
        rz: 0.3,
        _pad: 0.0,
    };
    let feats = model_features(&prev, &truth, params.depth_ratio as f64, 30);
    let best = feature::log_likelihood(&feats, &truth, &prev, 0.0, &params);
    // Every match is exact up to f32 rounding: ln(30 / eps).
    assert!(
        (best - (30.0 / params.feature_eps).ln()).abs() < 1e-2,
        "{best}"
    );
    let deltas = [
        [1.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, -1.5, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, -0.1, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.1, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, -0.1, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.05],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.05],
    ];
    for d in deltas {
        let q = Particle {
            cx: truth.cx + d[0],
            cy: truth.cy + d[1],
            a: truth.a + d[2],
            b: truth.b + d[3],
            rx: truth.rx + d[4],
            ry: truth.ry + d[5],
            rz: truth.rz + d[6],
            _pad: 0.0,
        };
        let l = feature::log_likelihood(&feats, &q, &prev, 0.0, &params);
        assert!(l < best, "{d:?}: {l} vs {best}");
    }
}

#[test]
fn feature_term_separates_the_necker_mirror_only_with_depth() {
    let prev = Particle {
        cx: 60.0,
        cy: 50.0,
        a: 20.0,
        b: 20.0,
        ..Default::default()
    };
    let truth = Particle {
        cx: 61.0,
        cy: 50.0,
        a: 20.0,
        b: 20.0,
        rx: 0.3,
        ..Default::default()
    };
    let mirror = Particle { rx: -0.3, ..truth };
    let params = LikelihoodParams::default();
    assert!(params.depth_ratio > 0.0);
    let feats = model_features(&prev, &truth, params.depth_ratio as f64, 25);
    let lt = feature::log_likelihood(&feats, &truth, &prev, 0.0, &params);
    let lm = feature::log_likelihood(&feats, &mirror, &prev, 0.0, &params);
    assert!(lt > lm + 0.5, "{lt} vs {lm}");

    let flat = LikelihoodParams {
        depth_ratio: 0.0,
        ..params
    };
    let feats = model_features(&prev, &truth, 0.0, 25);
    let lt = feature::log_likelihood(&feats, &truth, &prev, 0.0, &flat);
    let lm = feature::log_likelihood(&feats, &mirror, &prev, 0.0, &flat);
    assert_eq!(lt, lm);
}

/// A frame, features, model and 1000 random particles around the girl's head.
fn girl_setup() -> Option<(RgbImage, Ellipse, Vec<FeaturePair>, Vec<Particle>)> {
    let (img, e) = girl_first()?;
    let (prev, _) = particle_of(&e);
    let mut rng = StdRng::seed_from_u64(3);
    let truth = Particle {
        cx: prev.cx + 1.0,
        rx: 0.1,
        ry: 0.05,
        ..prev
    };
    let feats = model_features(&prev, &truth, 0.5, 20);
    let mut particles: Vec<Particle> = (0..1000)
        .map(|_| Particle {
            cx: prev.cx + rng.random_range(-15.0..15.0),
            cy: prev.cy + rng.random_range(-15.0..15.0),
            a: prev.a * rng.random_range(0.7..1.3),
            b: prev.b * rng.random_range(0.7..1.3),
            rx: rng.random_range(-0.5..0.5),
            ry: rng.random_range(-0.5..0.5),
            rz: rng.random_range(-0.5..0.5),
            _pad: 0.0,
        })
        .collect();
    particles[0] = prev;
    particles[1].a = 0.0;
    particles[2].b = -3.0;
    particles[3].rx = f32::NAN;
    particles[4].cy = f32::INFINITY;
    particles[5].cx = 3e38;
    Some((img, e, feats, particles))
}

#[test]
fn engine_is_deterministic_and_thread_count_independent() {
    let Some((img, e, feats, particles)) = girl_setup() else {
        return;
    };
    let (prev, theta0) = particle_of(&e);
    let frame = FrameInput {
        image: &img,
        features: &feats,
        depths: None,
        prev,
        theta0,
    };
    let params = LikelihoodParams::default();
    let model = ColourHistogram::from_ellipse(&img, &e, COLOUR_RGB).unwrap();
    let whole = ColourHistogram::from_ellipse(&img, &Ellipse::new(64.0, 48.0, 96.0, 72.0), 0);
    let table = ContrastTable::from_histograms(&model, &whole.unwrap(), 3.0).unwrap();
    let with_contrast = LikelihoodParams {
        terms: TERM_ALL,
        contrast_scale: 0.01,
        ..params
    };

    let mut one = CpuEngine::with_threads(1).unwrap();
    let mut all = CpuEngine::new();
    let mut two = CpuEngine::with_threads(2).unwrap();
    for eng in [&mut one, &mut all, &mut two] {
        eng.set_colour_model(&model).unwrap();
        eng.set_contrast_table(&table).unwrap();
    }
    let (mut k1, mut k2) = (Vec::new(), Vec::new());
    one.evaluate(&frame, &with_contrast, &particles, &mut k1)
        .unwrap();
    two.evaluate(&frame, &with_contrast, &particles, &mut k2)
        .unwrap();
    assert_eq!(k1, k2);
    assert!(k1.iter().skip(6).all(|t| t.contrast != 0.0));
    let (mut r1, mut r2, mut r3, mut r4) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    one.evaluate(&frame, &params, &particles, &mut r1).unwrap();
    all.evaluate(&frame, &params, &particles, &mut r2).unwrap();
    two.evaluate(&frame, &params, &particles, &mut r3).unwrap();
    all.evaluate(&frame, &params, &particles, &mut r4).unwrap();
    assert_eq!(r1.len(), particles.len());
    let bits = |r: &[TermLogs]| -> Vec<[u32; 5]> {
        r.iter()
            .map(|t| {
                [
                    t.colour.to_bits(),
                    t.gradient.to_bits(),
                    t.feature.to_bits(),
                    t.contrast.to_bits(),
                    t.total.to_bits(),
                ]
            })
            .collect()
    };
    assert_eq!(bits(&r1), bits(&r2));
    assert_eq!(bits(&r1), bits(&r3));
    assert_eq!(bits(&r2), bits(&r4));

    // Degenerate particles, and nothing non-finite anywhere.
    let degenerate = TermLogs {
        colour: 0.0,
        gradient: 0.0,
        feature: 0.0,
        contrast: 0.0,
        total: DEGENERATE,
    };
    for (i, r) in r1.iter().enumerate().take(6).skip(1) {
        assert_eq!(*r, degenerate, "particle {i}");
    }
    assert!(
        r1.iter()
            .all(|t| t.total.is_finite() && t.colour.is_finite())
    );
    // The true ellipse has the best colour term.
    assert_eq!(r1[0].colour, 0.0);
    assert!(r1.iter().all(|t| t.colour <= 0.0 && t.gradient >= 0.0));

    // The engine equals the stage functions called one by one.
    let grad = gradient::GradientImage::new(&img);
    let cm = colour::Model::new(&model.0);
    for (p, t) in particles.iter().zip(&r1).skip(6).take(100) {
        let ef = EllipseF32::from_particle(p, theta0);
        let c = colour::log_likelihood(&img, &ef, &cm, &params);
        let g = gradient::log_likelihood(&grad, p, theta0, &params);
        let f = feature::log_likelihood(&feats, p, &prev, theta0, &params);
        assert_eq!(*t, cpu::combine::combine([c, g, f, 0.0], &params));
    }
}

#[test]
fn engine_terms_flags_and_errors() {
    let img = RgbImage::from_fn(32, 24, |x, y| Rgb([(x * 8) as u8, (y * 10) as u8, 50]));
    let e = Ellipse::new(16.0, 12.0, 6.0, 5.0);
    let (prev, theta0) = particle_of(&e);
    let feats = [FeaturePair {
        p: [15.0, 12.0],
        q: [15.5, 12.0],
    }];
    let frame = FrameInput {
        image: &img,
        features: &feats,
        depths: None,
        prev,
        theta0,
    };
    let mut eng = CpuEngine::with_threads(1).unwrap();
    let mut out = vec![TermLogs::default(); 7];
    let params = LikelihoodParams::default();
    assert!(matches!(
        eng.evaluate(&frame, &params, &[prev], &mut out),
        Err(LikelihoodError::NoModel)
    ));
    // Without the colour term no model is needed; the disabled slot is 0.
    let no_colour = LikelihoodParams {
        terms: TERM_GRADIENT | TERM_FEATURE,
        ..params
    };
    eng.evaluate(&frame, &no_colour, &[prev, prev], &mut out)
        .unwrap();
    assert_eq!(out.len(), 2);
    assert_eq!(out[0].colour, 0.0);
    assert_eq!(out[0].total, out[0].gradient + out[0].feature);
    eng.set_colour_model(&ColourHistogram::from_ellipse(&img, &e, COLOUR_RGB).unwrap())
        .unwrap();
    let only_colour = LikelihoodParams {
        terms: TERM_COLOUR,
        ..params
    };
    eng.evaluate(&frame, &only_colour, &[prev], &mut out)
        .unwrap();
    assert_eq!(out[0], TermLogs::default());
    eng.evaluate(&frame, &params, &[], &mut out).unwrap();
    assert!(out.is_empty());
    let only_feature = LikelihoodParams {
        terms: TERM_FEATURE,
        ..params
    };
    eng.evaluate(&frame, &only_feature, &[prev], &mut out)
        .unwrap();
    assert!(
        (out[0].feature - (1.0 / 1.5f32).ln()).abs() < 1e-6,
        "{:?}",
        out[0]
    );

    // The contrast term needs its table; with one, it works without the colour term.
    let contrast = LikelihoodParams {
        terms: TERM_CONTRAST,
        contrast_scale: 0.5,
        ..params
    };
    assert!(matches!(
        eng.evaluate(&frame, &contrast, &[prev], &mut out),
        Err(LikelihoodError::NoContrastTable)
    ));
    let mut table = ContrastTable(vec![0.0; HIST_BINS]);
    table.0[colour::bin_of(130, 120, 50) as usize] = 2.0;
    eng.set_contrast_table(&table).unwrap();
    eng.evaluate(&frame, &contrast, &[prev], &mut out).unwrap();
    let ef = EllipseF32::from_particle(&prev, theta0);
    let (counts, _) = brute_histogram(&img, &ef);
    let want = 0.5 * 2.0 * counts[colour::bin_of(130, 120, 50) as usize] as f32;
    assert!(want > 0.0);
    assert_eq!(out[0].contrast, want);
    assert_eq!(out[0].total, want);
    assert!(matches!(
        eng.set_contrast_table(&ContrastTable(vec![f32::NAN; HIST_BINS])),
        Err(LikelihoodError::Invalid(_))
    ));
    assert!(matches!(
        eng.set_contrast_table(&ContrastTable(vec![0.0; 3])),
        Err(LikelihoodError::Invalid(_))
    ));

    let bad = |p: LikelihoodParams, eng: &mut CpuEngine| {
        let mut o = Vec::new();
        matches!(
            eng.evaluate(&frame, &p, &[prev], &mut o),
            Err(LikelihoodError::Invalid(_))
        )
    };
    assert!(bad(
        LikelihoodParams {
            sigma_colour: 0.0,
            ..params
        },
        &mut eng
    ));
    assert!(bad(
        LikelihoodParams {
            sigma_z: f32::NAN,
            ..params
        },
        &mut eng
    ));
    assert!(bad(
        LikelihoodParams {
            clutter_density: -1.0,
            ..params
        },
        &mut eng
    ));
    // p0 is a probability; a clutter gain below f32's epsilon reads 0 on every line, which
    // made the tracker's confidence 0 / 0 (NaN) and never lost.
    assert!(bad(
        LikelihoodParams {
            p_no_contour: 2.0,
            ..params
        },
        &mut eng
    ));
    assert!(bad(
        LikelihoodParams {
            sigma_z: 1e30,
            ..params
        },
        &mut eng
    ));
    assert!(bad(
        LikelihoodParams {
            p_no_contour: 1.0,
            clutter_density: 1e30,
            ..params
        },
        &mut eng
    ));
    assert!(!bad(
        LikelihoodParams {
            p_no_contour: 1.0,
            ..params
        },
        &mut eng
    ));
    assert!(bad(
        LikelihoodParams {
            feature_eps: 0.0,
            ..params
        },
        &mut eng
    ));
    assert!(bad(
        LikelihoodParams {
            line_half_length: 1e9,
            ..params
        },
        &mut eng
    ));
    assert!(bad(
        LikelihoodParams {
            terms: 16,
            ..params
        },
        &mut eng
    ));
    assert!(bad(
        LikelihoodParams {
            terms: TERM_CONTRAST,
            contrast_scale: f32::INFINITY,
            ..params
        },
        &mut eng
    ));
    let nan_frame = FrameInput {
        theta0: f32::NAN,
        ..frame
    };
    let mut o = Vec::new();
    assert!(eng.evaluate(&nan_frame, &params, &[prev], &mut o).is_err());
    assert!(CpuEngine::with_threads(0).is_err());
    let many = pftrack::likelihood::cpu::MAX_THREADS + 1;
    assert!(CpuEngine::with_threads(many).is_err());
    assert!(CpuEngine::with_threads(usize::MAX).is_err());
    assert!(
        eng.set_colour_model(&ColourHistogram(vec![0.0; 10]))
            .is_err()
    );
    assert!(
        eng.set_colour_model(&ColourHistogram(vec![0.0; HIST_BINS]))
            .is_err()
    );
    assert!(
        eng.set_colour_model(&ColourHistogram(vec![f32::NAN; HIST_BINS]))
            .is_err()
    );
    assert!(eng.name().contains("cpu"));
    let _ = TERM_FEATURE;
}

/// A dark disc on a bright textured background: the colour term cannot tell an ellipse
/// inside the disc from the disc (both hold only its colours), the contrast term can. Its
/// value is the table summed over the particle's pixels (brute force), and over sizes it
/// peaks at the disc's.
#[test]
fn contrast_term_is_the_table_summed_over_the_pixels_and_peaks_at_the_target_size() {
    let (w, h) = (96u32, 72u32);
    let disc = Ellipse::new(47.0, 35.0, 15.0, 12.0);
    let ef = EllipseF32::from_ellipse(&disc);
    let (s, c) = ef.theta.sin_cos();
    let mut rng = StdRng::seed_from_u64(3);
    let img = RgbImage::from_fn(w, h, |x, y| {
        let n: u8 = rng.random_range(0..40);
        if colour::inside(&ef, s, c, x as i64, y as i64) {
            Rgb([30 + n, 40 + n, 20 + n])
        } else {
            Rgb([160 + n, 170 + n / 2, 120 + n])
        }
    });
    let fg = ColourHistogram::from_ellipse(&img, &disc, COLOUR_RGB).unwrap();
    let bg = ColourHistogram::from_ellipse(&img, &Ellipse::new(48.0, 36.0, 60.0, 60.0), 0).unwrap();
    let table = ContrastTable::from_histograms(&fg, &bg, 3.0).unwrap();
    // Log-odds by hand for two bins: one only in the disc, one mostly background.
    let eps = ContrastTable::EPSILON;
    for k in 0..HIST_BINS {
        let want = ((fg.0[k] + eps) / (bg.0[k] + eps)).ln().clamp(-3.0, 3.0);
        assert_eq!(table.0[k], want, "bin {k}");
    }
    assert!(table.0[colour::bin_of(40, 50, 30) as usize] > 0.0);
    assert!(table.0[colour::bin_of(170, 175, 130) as usize] < 0.0);

    let mut eng = CpuEngine::with_threads(1).unwrap();
    eng.set_colour_model(&fg).unwrap();
    eng.set_contrast_table(&table).unwrap();
    let params = LikelihoodParams {
        terms: TERM_COLOUR | TERM_CONTRAST,
        contrast_scale: 0.02,
        ..LikelihoodParams::default()
    };
    let scales: Vec<f32> = (0..=20).map(|k| 0.5 + 0.05 * k as f32).collect();
    let ps: Vec<Particle> = scales
        .iter()
        .map(|k| Particle {
            cx: 47.0,
            cy: 35.0,
            a: 15.0 * k,
            b: 12.0 * k,
            ..Default::default()
        })
        .collect();
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: ps[10],
        theta0: 0.0,
    };
    let mut out = Vec::new();
    eng.evaluate(&frame, &params, &ps, &mut out).unwrap();
    for (p, t) in ps.iter().zip(&out) {
        let (counts, _) = brute_histogram(&img, &EllipseF32::from_particle(p, 0.0));
        let exact: f64 = counts
            .iter()
            .zip(&table.0)
            .map(|(&n, &l)| n as f64 * l as f64)
            .sum();
        let got = t.contrast as f64;
        assert!(
            (got - 0.02 * exact).abs() <= 1e-5 * (0.02 * exact).abs().max(1.0),
            "{p:?}"
        );
    }
    // Every ellipse inside the disc has the colour term's best value; the contrast term
    // grows up to the disc and falls beyond it.
    for (k, t) in scales.iter().zip(&out) {
        if *k <= 1.0 {
            assert!(t.colour > -0.05, "scale {k}: {t:?}");
        }
    }
    let best = (0..out.len())
        .max_by(|&i, &j| out[i].contrast.total_cmp(&out[j].contrast))
        .unwrap();
    assert!(
        (scales[best] - 1.0).abs() <= 0.051,
        "peak at {}",
        scales[best]
    );
    assert!(out[best].contrast > out[0].contrast + 1.0);
    assert!(out[best].contrast > out[20].contrast + 1.0);
}

/// Depths given with the features replace the facing ellipsoid prior of the feature term and
/// nothing else: the prior's own depths give the same result bit for bit, other depths move
/// the feature term as the model `q̂ = c + s (ΔR X)_xy`, `X = (p − c_prev, z)`, predicts, and
/// depths that do not fit the features are an error.
#[test]
fn given_feature_depths_replace_the_facing_prior() {
    let mut rng = StdRng::seed_from_u64(41);
    let image = RgbImage::from_fn(120, 90, |x, y| {
        Rgb([(x * 2) as u8, (y * 2) as u8, ((x * y) % 251) as u8])
    });
    let prev = Particle {
        cx: 60.0,
        cy: 45.0,
        a: 18.0,
        b: 24.0,
        rx: 0.2,
        ry: -0.3,
        rz: 0.1,
        ..Default::default()
    };
    let theta0 = 0.15;
    let features: Vec<FeaturePair> = (0..30)
        .map(|_| {
            let p = [
                prev.cx + prev.a * rng.random_range(-0.9..0.9),
                prev.cy + prev.b * rng.random_range(-0.9..0.9),
            ];
            let q = [
                p[0] + rng.random_range(-3.0..3.0),
                p[1] + rng.random_range(-3.0..3.0),
            ];
            FeaturePair { p, q }
        })
        .collect();
    let params = LikelihoodParams {
        terms: TERM_FEATURE | TERM_GRADIENT,
        ..LikelihoodParams::default()
    };
    let facing: Vec<f32> = features
        .iter()
        .map(|f| feature::lift(f.p, &prev, theta0, params.depth_ratio)[2])
        .collect();
    let ps: Vec<Particle> = (0..20)
        .map(|_| Particle {
            cx: prev.cx + rng.random_range(-3.0..3.0),
            cy: prev.cy + rng.random_range(-3.0..3.0),
            a: prev.a * rng.random_range(0.9..1.1),
            b: prev.b * rng.random_range(0.9..1.1),
            rx: prev.rx + rng.random_range(-0.3..0.3),
            ry: prev.ry + rng.random_range(-0.3..0.3),
            rz: prev.rz + rng.random_range(-0.2..0.2),
            ..Default::default()
        })
        .collect();
    let mut eng = CpuEngine::new();
    let mut run = |depths: Option<&[f32]>| -> Result<Vec<TermLogs>, LikelihoodError> {
        let frame = FrameInput {
            image: &image,
            features: &features,
            depths,
            prev,
            theta0,
        };
        let mut out = Vec::new();
        eng.evaluate(&frame, &params, &ps, &mut out).map(|_| out)
    };
    let prior = run(None).unwrap();
    assert_eq!(run(Some(&facing)).unwrap(), prior);

    // Other depths: the gradient term is untouched, the feature term follows the model.
    let other: Vec<f32> = facing
        .iter()
        .map(|z| 0.5 * z + rng.random_range(-4.0..0.0))
        .collect();
    let given = run(Some(&other)).unwrap();
    let r_prev = Euler::new(prev.rx as f64, prev.ry as f64, prev.rz as f64).matrix();
    let mut moved = 0.0f32;
    for ((p, g), w) in ps.iter().zip(&given).zip(&prior) {
        assert_eq!(g.gradient, w.gradient);
        let dr = Euler::new(p.rx as f64, p.ry as f64, p.rz as f64).matrix() * r_prev.transpose();
        let s = ((p.a * p.b) as f64 / (prev.a * prev.b) as f64).sqrt();
        let sum: f64 = features
            .iter()
            .zip(&other)
            .map(|(f, &z)| {
                let x = nalgebra::Vector3::new(
                    (f.p[0] - prev.cx) as f64,
                    (f.p[1] - prev.cy) as f64,
                    z as f64,
                );
                let y = dr * x;
                let (qx, qy) = (p.cx as f64 + s * y.x, p.cy as f64 + s * y.y);
                let e = ((f.q[0] as f64 - qx).powi(2) + (f.q[1] as f64 - qy).powi(2)).sqrt();
                1.0 / (params.feature_eps as f64 + e)
            })
            .sum();
        assert!(
            (g.feature as f64 - sum.ln()).abs() < 1e-4,
            "{} against {}",
            g.feature,
            sum.ln()
        );
        moved = moved.max((g.feature - w.feature).abs());
    }
    assert!(
        moved > 0.05,
        "the depths changed the feature term by {moved} at most"
    );

    // Depths that do not fit the features.
    for bad in [&facing[..10], &[f32::NAN; 30][..]] {
        match run(Some(bad)) {
            Err(LikelihoodError::Invalid(m)) => assert!(m.contains("depth"), "{m}"),
            other => panic!("accepted bad depths: {other:?}"),
        }
    }
}

/// The stage functions are public for the GPU comparisons, with public fields: data shorter
/// than the size says, extreme line lengths and unchecked settings give values, not panics
/// or huge allocations (each of these panicked, overflowed or aborted in a debug build).
#[test]
fn stage_functions_take_inconsistent_inputs() {
    let e = EllipseF32 {
        cx: 10.0,
        cy: 8.0,
        a: 5.0,
        b: 4.0,
        theta: 0.3,
    };
    let bins = colour::BinImage {
        width: 20,
        height: 16,
        bins: Vec::new(),
    };
    let mut counts = [0u32; pftrack::likelihood::HIST_BINS];
    assert_eq!(colour::histogram_bins(&bins, &e, &mut counts), 0);
    let grad = gradient::GradientImage {
        width: 20,
        height: 16,
        g: Vec::new(),
    };
    assert_eq!(grad.at(5, 5), [0, 0]);
    for h in [i32::MIN, -1, i32::MAX] {
        let _ = gradient::line_edge_distance(&grad, 10.0, 8.0, 1.0, 0.0, h, 0.1);
        let _ = gradient::line_edges(&grad, 10.0, 8.0, 1.0, 0.0, h, 0.1).count();
    }
    let params = LikelihoodParams {
        num_lines: u32::MAX,
        line_half_length: 1e30,
        ..LikelihoodParams::default()
    };
    let tables = gradient::LineTables::new(&params);
    assert!(tables.angles.len() <= 4096 && tables.logs.len() <= 4097);
    let short = gradient::LineTables {
        logs: Vec::new(),
        ..gradient::LineTables::new(&LikelihoodParams::default())
    };
    let full = RgbImage::from_fn(20, 16, |x, y| {
        let v = ((x * 37 + y * 91) % 255) as u8;
        Rgb([v, v / 2, 255 - v])
    });
    let g = gradient::GradientImage::new(&full);
    let v = gradient::log_likelihood_ellipse(&g, &e, &short, &LikelihoodParams::default());
    assert!(v.is_finite());
}

/// Settings whose 2σ² or 1/ε leave f32's normal range are refused: they scored the best
/// particle as degenerate (a subnormal ε made an exact match infinite; σz of 1e-30 read 0/0 on
/// a contour; σc of 1e-20 gave every imperfect colour match -inf).
#[test]
fn likelihood_settings_outside_f32s_range_are_refused() {
    let d = LikelihoodParams::default();
    assert!(d.check().is_ok());
    for bad in [
        LikelihoodParams {
            feature_eps: 1e-39,
            ..d
        },
        LikelihoodParams {
            feature_eps: 1e-7,
            ..d
        },
        LikelihoodParams {
            sigma_z: 1e-30,
            ..d
        },
        LikelihoodParams {
            sigma_colour: 1e-20,
            ..d
        },
    ] {
        assert!(
            matches!(bad.check(), Err(LikelihoodError::Invalid(_))),
            "{bad:?}"
        );
    }
    for ok in [
        LikelihoodParams {
            feature_eps: 1e-6,
            ..d
        },
        LikelihoodParams {
            sigma_colour: 1e-3,
            ..d
        },
    ] {
        assert!(ok.check().is_ok(), "{ok:?}");
    }
}

/// A frame without pixels, and a previous estimate whose area underflows or overflows f32
/// (which scored every particle, the perfect one too, as degenerate), are refused.
#[test]
fn an_empty_frame_and_an_unusable_previous_estimate_are_refused() {
    let mut e = CpuEngine::new();
    let img = RgbImage::from_pixel(32, 32, Rgb([100, 50, 20]));
    let model =
        ColourHistogram::from_ellipse(&img, &Ellipse::new(16.0, 16.0, 6.0, 6.0), COLOUR_RGB)
            .unwrap();
    e.set_colour_model(&model).unwrap();
    let p = Particle {
        cx: 16.0,
        cy: 16.0,
        a: 6.0,
        b: 6.0,
        ..Default::default()
    };
    let params = LikelihoodParams::default();
    let mut out = Vec::new();
    let empty = RgbImage::new(0, 0);
    let frame = FrameInput {
        image: &empty,
        features: &[],
        depths: None,
        prev: p,
        theta0: 0.0,
    };
    let r = e.evaluate(&frame, &params, &[p], &mut out);
    assert!(matches!(r, Err(LikelihoodError::Invalid(_))), "{r:?}");
    let features = [FeaturePair {
        p: [16.0, 16.0],
        q: [16.0, 16.0],
    }];
    for side in [1e-23f32, 1e20] {
        let frame = FrameInput {
            image: &img,
            features: &features,
            depths: None,
            prev: Particle {
                a: side,
                b: side,
                ..p
            },
            theta0: 0.0,
        };
        let r = e.evaluate(&frame, &params, &[p], &mut out);
        assert!(
            matches!(r, Err(LikelihoodError::Invalid(_))),
            "{side}: {r:?}"
        );
    }
}

/// The template terms follow the engines' rule: a degenerate particle, or a degenerate first
/// view, scores 0; a particle far off the frame (1e19 px, infinite) samples the edge without
/// overflowing (it panicked); a template of non-finite grey levels is not usable.
#[test]
fn template_terms_take_degenerate_and_far_particles() {
    use pftrack::frames::GrayF32;
    use pftrack::likelihood::template::{FirstView, Template, normalise};
    let img = RgbImage::from_fn(64, 64, |x, y| Rgb([(x * 4) as u8, (y * 3) as u8, 60]));
    let gray = GrayF32::from_rgb(&img);
    let p = Particle {
        cx: 32.0,
        cy: 32.0,
        a: 15.0,
        b: 15.0,
        ..Default::default()
    };
    let t = Template::new(&gray, &p, 0.0, 12);
    assert!(t.is_usable());
    let far = [
        Particle { cx: 1e19, ..p },
        Particle {
            cx: f32::INFINITY,
            ..p
        },
        Particle { a: -15.0, ..p },
        Particle { a: 0.0, ..p },
        Particle { cx: f32::NAN, ..p },
    ];
    let mut out = Vec::new();
    t.correlate(&gray, &far, 0.0, &mut out);
    assert!(out[0].abs() <= 1.0 + 1e-6, "{out:?}");
    assert_eq!(&out[1..], &[0.0; 4], "degenerate particles");
    let mut turned = Vec::new();
    t.correlate_turned(&gray, &far, 0.0, &FirstView::weak(p), &mut turned);
    assert!(turned[0].abs() <= 1.0 + 1e-6, "{turned:?}");
    assert_eq!(&turned[1..], &[0.0; 4]);
    let flat_first = FirstView::weak(Particle { a: 0.0, ..p });
    t.correlate_turned(&gray, &[p], 0.0, &flat_first, &mut turned);
    assert_eq!(turned, vec![0.0]);
    let mut nan = vec![1.0, f32::NAN, 3.0];
    assert!(!normalise(&mut nan));
}
