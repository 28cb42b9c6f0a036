//! GPU likelihood engine on a real Vulkan adapter (lavapipe in CI): known answers, limits,
//! errors, and agreement with the CPU reference engine.
//!
//! Without a Vulkan adapter every test skips with a printed reason, unless
//! `PFTRACK_REQUIRE_GPU=1` (CI), where a missing adapter fails.

use std::io::Write;

use image::{Rgb, RgbImage};
use pftrack::likelihood::gpu::{GpuDevice, GpuEngine, NO_EDGE, SHRINK_AFTER_CALLS};
use pftrack::likelihood::{
    COLOUR_LUMA, COLOUR_RGB, ColourHistogram, ContrastTable, FrameInput, HIST_BINS,
    LikelihoodEngine, LikelihoodError, LikelihoodParams, Particle, TERM_ALL, TERM_COLOUR,
    TERM_CONTRAST, TERM_GRADIENT,
};

mod common;
mod shared_data;
use common::{engine, engine_alone, skip};

fn particle(cx: f32, cy: f32, a: f32, b: f32) -> Particle {
    Particle {
        cx,
        cy,
        a,
        b,
        ..Default::default()
    }
}

fn one_hot(bin: usize) -> ColourHistogram {
    let mut h = vec![0.0; HIST_BINS];
    h[bin] = 1.0;
    ColourHistogram(h)
}

fn bin_of(p: Rgb<u8>) -> usize {
    ((p[0] >> 5) as usize) * 64 + ((p[1] >> 5) as usize) * 8 + (p[2] >> 5) as usize
}

#[test]
fn names_the_adapter_and_its_backend() {
    let Some(e) = engine() else { return };
    let name = e.name();
    assert!(name.contains("Vulkan"), "{name}");
}

#[test]
fn an_unknown_adapter_name_is_an_error_listing_the_available_ones() {
    // Held to the end: the adapters are enumerated beside it.
    let Some(_gpu) = engine() else { return };
    match GpuDevice::open_matching(Some("no-such-adapter-4f2a")) {
        Err(LikelihoodError::AdapterNotFound { wanted, available }) => {
            assert_eq!(wanted, "no-such-adapter-4f2a");
            assert!(!available.is_empty());
            let msg = LikelihoodError::AdapterNotFound { wanted, available }.to_string();
            assert!(msg.contains("available"), "{msg}");
        }
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("matched a nonexistent adapter"),
    }
}

#[test]
fn uniform_frame_histogram_counts_the_pixel_centres_inside_and_rho_is_one() {
    let Some(mut e) = engine() else { return };
    let colour = Rgb([200, 100, 50]);
    let img = RgbImage::from_pixel(64, 48, colour);
    e.set_colour_model(&one_hot(bin_of(colour))).unwrap();
    let params = LikelihoodParams {
        terms: TERM_COLOUR,
        ..Default::default()
    };
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: particle(32.0, 24.0, 10.0, 10.0),
        theta0: 0.0,
    };
    // A circle of radius 10.3 around a pixel centre: no pixel centre near its boundary, so
    // the count below is exact.
    let r = 10.3f64;
    let inside = |x: i32, y: i32| ((x * x + y * y) as f64) <= r * r;
    let full = (-11..=11)
        .flat_map(|y| (-11..=11).map(move |x| (x, y)))
        .filter(|&(x, y)| inside(x, y))
        .count() as u32;
    let quarter = (0..=11)
        .flat_map(|y| (0..=11).map(move |x| (x, y)))
        .filter(|&(x, y)| inside(x, y))
        .count() as u32;
    // Second particle clipped by the frame's corner, third fully outside (empty).
    let ps = [
        particle(20.0, 20.0, 10.3, 10.3),
        particle(0.0, 0.0, 10.3, 10.3),
        particle(-100.0, -100.0, 5.0, 5.0),
    ];
    let dbg = e.evaluate_debug(&frame, &params, &ps).unwrap();
    let h0 = &dbg.histograms[..HIST_BINS];
    assert_eq!(h0[bin_of(colour)], full);
    assert_eq!(h0.iter().sum::<u32>(), full);
    assert_eq!(
        dbg.histograms[HIST_BINS..2 * HIST_BINS].iter().sum::<u32>(),
        quarter
    );
    assert_eq!(dbg.histograms[2 * HIST_BINS..].iter().sum::<u32>(), 0);
    // rho = 1 -> ln p = 0; empty -> rho = 0 -> -1 / (2 sigma^2).
    assert!(dbg.terms[0].colour.abs() < 1e-6, "{:?}", dbg.terms[0]);
    assert!(dbg.terms[1].colour.abs() < 1e-6, "{:?}", dbg.terms[1]);
    let empty = -1.0 / (2.0 * params.sigma_colour * params.sigma_colour);
    assert!(
        (dbg.terms[2].colour - empty).abs() < 1e-4,
        "{:?}",
        dbg.terms[2]
    );
    assert_eq!(dbg.terms[0].total, dbg.terms[0].colour);
    assert_eq!(dbg.terms[0].gradient, 0.0);
}

#[test]
fn a_painted_disk_puts_an_edge_on_every_normal_line_at_its_contour() {
    let Some(mut e) = engine() else { return };
    let (cx, cy, r) = (40.0f32, 30.0f32, 12.0f32);
    let img = RgbImage::from_fn(80, 60, |x, y| {
        let d = ((x as f32 - cx).powi(2) + (y as f32 - cy).powi(2)).sqrt();
        if d <= r {
            Rgb([230, 230, 230])
        } else {
            Rgb([20, 20, 20])
        }
    });
    e.set_colour_model(&one_hot(0)).unwrap();
    let params = LikelihoodParams {
        terms: TERM_GRADIENT,
        num_lines: 16,
        ..Default::default()
    };
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: particle(cx, cy, r, r),
        theta0: 0.0,
    };
    // On the contour, 3 px inside it, and far from any edge.
    let ps = [
        particle(cx, cy, r, r),
        particle(cx, cy, r - 3.0, r - 3.0),
        particle(10.0, 50.0, 3.0, 3.0),
    ];
    let dbg = e.evaluate_debug(&frame, &params, &ps).unwrap();
    let l = 16;
    let d = &dbg.line_distances;
    for k in 0..l {
        assert!((0..=1).contains(&d[k]), "{:?}", &d[..l]);
        assert!((2..=4).contains(&d[l + k]), "{:?}", &d[l..2 * l]);
        assert_eq!(d[2 * l + k], NO_EDGE);
    }
    assert!(dbg.terms[0].gradient > dbg.terms[1].gradient);
    assert!(dbg.terms[1].gradient > 0.0);
    assert_eq!(dbg.terms[2].gradient, 0.0);
    assert_eq!(dbg.terms[0].colour, 0.0);
}

#[test]
fn degenerate_particles_get_the_degenerate_total_and_zero_terms() {
    let Some(mut e) = engine() else { return };
    let img = RgbImage::from_pixel(32, 32, Rgb([10, 200, 30]));
    e.set_colour_model(&one_hot(bin_of(Rgb([10, 200, 30]))))
        .unwrap();
    let params = LikelihoodParams::default();
    let features = [pftrack::likelihood::FeaturePair {
        p: [16.0, 16.0],
        q: [17.0, 16.0],
    }];
    let frame = FrameInput {
        image: &img,
        features: &features,
        depths: None,
        prev: particle(16.0, 16.0, 5.0, 5.0),
        theta0: 0.0,
    };
    let mut ps = vec![
        particle(16.0, 16.0, 0.0, 5.0),
        particle(16.0, 16.0, 5.0, -1.0),
        particle(f32::NAN, 16.0, 5.0, 5.0),
        particle(16.0, 16.0, f32::INFINITY, 5.0),
        particle(16.0, 16.0, 5.0, 5.0),
    ];
    ps[4].rz = f32::NEG_INFINITY;
    ps.push(particle(16.0, 16.0, 5.0, 5.0));
    let mut out = Vec::new();
    e.evaluate(&frame, &params, &ps, &mut out).unwrap();
    for t in &out[..5] {
        assert_eq!(
            (t.colour, t.gradient, t.feature, t.total),
            (0.0, 0.0, 0.0, pftrack::likelihood::DEGENERATE)
        );
    }
    assert!(
        out[5].total.is_finite() && out[5].total > -1e3,
        "{:?}",
        out[5]
    );
}

#[test]
fn a_frame_without_features_has_a_zero_feature_term_after_one_with_features() {
    let Some(mut e) = engine() else { return };
    let img = RgbImage::from_pixel(32, 32, Rgb([10, 200, 30]));
    e.set_colour_model(&one_hot(bin_of(Rgb([10, 200, 30]))))
        .unwrap();
    let params = LikelihoodParams::default();
    let features = [pftrack::likelihood::FeaturePair {
        p: [16.0, 16.0],
        q: [20.0, 16.0],
    }];
    let mut frame = FrameInput {
        image: &img,
        features: &features,
        depths: None,
        prev: particle(16.0, 16.0, 5.0, 5.0),
        theta0: 0.0,
    };
    let ps = [particle(16.0, 16.0, 5.0, 5.0)];
    let mut out = Vec::new();
    e.evaluate(&frame, &params, &ps, &mut out).unwrap();
    // 1 / (eps + 4) with eps = 1.
    assert!(
        (out[0].feature - (0.2f32).ln()).abs() < 1e-5,
        "{:?}",
        out[0]
    );
    frame.features = &[];
    e.evaluate(&frame, &params, &ps, &mut out).unwrap();
    assert_eq!(out[0].feature, 0.0);
    assert_eq!(out[0].total, out[0].colour + out[0].gradient);
}

/// Bad colour models are refused as on the CPU (one owner for the checks), and an engine that
/// refused them all has no model: a colour evaluation is then an error.
#[test]
fn colour_without_a_valid_model_is_an_error() {
    let Some(mut e) = engine() else { return };
    let mut neg = vec![0.0; HIST_BINS];
    neg[3] = -1.0;
    neg[4] = 2.0;
    for bad in [
        vec![1.0; 10],
        vec![0.0; HIST_BINS],
        vec![f32::NAN; HIST_BINS],
        neg,
    ] {
        let r = e.set_colour_model(&ColourHistogram(bad));
        assert!(matches!(r, Err(LikelihoodError::Invalid(_))), "{r:?}");
    }
    let img = RgbImage::new(8, 8);
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: particle(4.0, 4.0, 2.0, 2.0),
        theta0: 0.0,
    };
    let mut out = Vec::new();
    let r = e.evaluate(
        &frame,
        &LikelihoodParams::default(),
        &[frame.prev],
        &mut out,
    );
    assert!(matches!(r, Err(LikelihoodError::NoModel)), "{r:?}");
}

#[test]
fn a_frame_beyond_the_buffer_limits_is_frame_too_large() {
    let Some(e) = engine() else { return };
    let limit = e.device().limits.max_storage_buffer_binding_size;
    // Checked before any allocation: no such frame is ever built on the host.
    let side = ((limit / 8) as f64).sqrt() as u32 + 16;
    match e.check_frame_size(side, side) {
        Err(LikelihoodError::FrameTooLarge { width, bytes, .. }) => {
            assert_eq!(width, side);
            assert!(bytes > limit);
        }
        r => panic!("expected FrameTooLarge, got {r:?}"),
    }
    assert!(e.check_frame_size(640, 480).is_ok());
}

#[test]
fn more_particle_lines_than_a_buffer_holds_is_too_many_particles() {
    let Some(mut e) = engine() else { return };
    let limit = e.device().limits.max_storage_buffer_binding_size;
    let img = RgbImage::from_pixel(16, 16, Rgb([1, 2, 3]));
    e.set_colour_model(&one_hot(0)).unwrap();
    let params = LikelihoodParams {
        num_lines: 4096,
        ..Default::default()
    };
    // One i32 distance per (particle, line): just over the limit, checked before allocating.
    let n = (limit / (4 * 4096)) as usize + 1;
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: particle(8.0, 8.0, 3.0, 3.0),
        theta0: 0.0,
    };
    let ps = vec![frame.prev; n];
    let mut out = Vec::new();
    let r = e.evaluate(&frame, &params, &ps, &mut out);
    assert!(
        matches!(r, Err(LikelihoodError::TooManyParticles { .. })),
        "{r:?}"
    );
}

#[test]
fn a_lost_device_is_a_clear_error_from_then_on() {
    let Some(mut e) = engine_alone() else { return };
    let img = RgbImage::from_pixel(16, 16, Rgb([1, 2, 3]));
    e.set_colour_model(&one_hot(0)).unwrap();
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: particle(8.0, 8.0, 3.0, 3.0),
        theta0: 0.0,
    };
    let mut out = Vec::new();
    let params = LikelihoodParams::default();
    e.evaluate(&frame, &params, &[frame.prev], &mut out)
        .unwrap();
    e.simulate_device_loss();
    for _ in 0..2 {
        let r = e.evaluate(&frame, &params, &[frame.prev], &mut out);
        assert!(matches!(r, Err(LikelihoodError::DeviceLost(_))), "{r:?}");
    }
    // Lost with no poll since (nothing has run the device-lost callback), on a frame with
    // features, whose upload fails before any readback: still a lost device, not a wgpu
    // validation error that a fallback would not act on.
    drop(e);
    let Some(mut e) = engine_alone() else { return };
    e.set_colour_model(&one_hot(0)).unwrap();
    e.evaluate(&frame, &params, &[frame.prev], &mut out)
        .unwrap();
    e.device().device.destroy();
    assert_lost_with_and_without_features(&mut e, &frame);
}

/// More features than an engine's buffer held before: evaluated, they go to a buffer made
/// afresh, uploaded before anything is read back.
const FRESH_FEATURES: [FeaturePair; 500] = [FeaturePair {
    p: [8.0, 8.0],
    q: [8.5, 8.0],
}; 500];

/// Asserts that `e`, whose device is lost, reports the loss on `frame` with
/// [`FRESH_FEATURES`], without features, and with them again (all terms on): the upload's
/// failure is the lost device too, not a wgpu validation error a fallback would not act on.
fn assert_lost_with_and_without_features(e: &mut GpuEngine, frame: &FrameInput) {
    let with_features = FrameInput {
        features: &FRESH_FEATURES,
        ..*frame
    };
    let mut out = Vec::new();
    for f in [&with_features, frame, &with_features] {
        let r = e.evaluate(f, &LikelihoodParams::default(), &[frame.prev], &mut out);
        assert!(matches!(r, Err(LikelihoodError::DeviceLost(_))), "{r:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// Agreement with the CPU reference engine.
//
// Stated tolerances (and why):
// - histograms: exact (integer counts of the same f32 inside test; the ellipse's sin/cos come
//   from the host, see common.wgsl), except for pixel centres whose test is a tie (`q = u² + v²`
//   within `INSIDE_TIE` of 1): a compiler may fuse `c dx + s dy` and `u u + v v` into FMAs,
//   which moves q by ulps. lavapipe does not; on an NVIDIA H200 (2026-12-04) one particle of
//   403 differed by such a pixel. A histogram that differs must differ by no more pixels than
//   its ties, and at most `MAX_HIST_TIE_FRACTION` of the particles may;
// - line edge distances: identical except rounding ties, at most `MAX_LINE_TIE_FRACTION` of
//   the lines: the line angles phi_k use the GPU's sin/cos (a few ulp from Rust's) and FMA
//   contraction may fuse `cx + c*ex - s*ey`, so a sample within an ulp of a pixel boundary
//   (floor(x + 0.5)) may round to the neighbour (none seen on lavapipe so far);
// - ln p_colour within 1e-4 absolute: rho and sum p are summed in a 64-way tree on the GPU,
//   in bin order on the CPU (f32, <= 512 terms, relative error ~1e-6), then scaled by
//   1 / (2 sigma_c^2) (34.7 with the defaults); measured max 1.5e-5;
// - ln p_gradient within 1e-4 absolute per particle with identical distances: the GPU's
//   exp/ln differ by ulps, summed over <= 40 lines of values up to ~4; measured max 3.1e-5;
// - ln p_feature within 1e-5 absolute: sin/cos ulps of the rotations and FMA contraction;
//   measured max 4.8e-7.
// ---------------------------------------------------------------------------------------------

use pftrack::likelihood::cpu::{self, CpuEngine, EllipseF32};
use pftrack::likelihood::{FeaturePair, TermLogs};
use rand::{Rng, SeedableRng, rngs::StdRng};

const MAX_LINE_TIE_FRACTION: f64 = 1e-3;
/// A pixel centre whose `q = u² + v²` (in `f64`, from the particle's `f32` values and the host's
/// `sin_cos`) lies within this of 1 may be inside for one engine and outside for the other.
/// Fused or not, `q` moves by a few ulps of `(|c dx| + |s dy|) / a` and of its squares, about
/// 1e-7 for the aspect ratios here: this leaves a factor of 100.
const INSIDE_TIE: f64 = 1e-5;
/// Most particles (a share) whose histograms may differ by tie pixels.
const MAX_HIST_TIE_FRACTION: f64 = 1e-2;
const TOL_COLOUR: f32 = 1e-4;
const TOL_GRADIENT: f32 = 1e-4;
const TOL_FEATURE: f32 = 1e-5;
/// The contrast term's sum runs in bin order on the CPU and by a tree on the GPU: relative
/// to the sum of its magnitudes, `f32` rounding.
const TOL_CONTRAST_REL: f32 = 1e-5;
/// The contrast term in the tests is at most about `60 · 3 = 180` (a share of the area times
/// the limit), so its rounding is well within this.
const TOL_CONTRAST_ABS: f32 = 2e-3;

/// Random particles around an ellipse (centre ±15 %, axes ×0.6..1.4, angles ±0.5 rad), plus a
/// few degenerate and off-frame ones.
fn random_particles(rng: &mut StdRng, e: &Particle, n: usize) -> Vec<Particle> {
    let mut ps: Vec<Particle> = (0..n)
        .map(|_| Particle {
            cx: e.cx + e.a * rng.random_range(-0.3..0.3),
            cy: e.cy + e.b * rng.random_range(-0.3..0.3),
            a: e.a * rng.random_range(0.6..1.4),
            b: e.b * rng.random_range(0.6..1.4),
            rx: rng.random_range(-0.5..0.5),
            ry: rng.random_range(-0.5..0.5),
            rz: rng.random_range(-0.5..0.5),
            _pad: 0.0,
        })
        .collect();
    ps.push(Particle { a: -1.0, ..*e });
    ps.push(Particle { cx: -500.0, ..*e });
    ps.push(Particle {
        cx: 5.0,
        cy: 5.0,
        ..*e
    });
    ps
}

fn random_features(rng: &mut StdRng, e: &Particle, n: usize) -> Vec<FeaturePair> {
    (0..n)
        .map(|_| {
            let p = [
                e.cx + e.a * rng.random_range(-0.8..0.8),
                e.cy + e.b * rng.random_range(-0.8..0.8),
            ];
            FeaturePair {
                p,
                q: [
                    p[0] + rng.random_range(-2.0..2.0),
                    p[1] + rng.random_range(-2.0..2.0),
                ],
            }
        })
        .collect()
}

#[derive(Debug, Default)]
struct Agreement {
    particles: usize,
    hist_mismatch: usize,
    /// Histograms that differ by more pixels than their ellipse has tie pixels.
    hist_unexplained: usize,
    lines: usize,
    line_mismatch: usize,
    max_colour: f32,
    max_gradient: f32,
    max_feature: f32,
    /// Largest contrast difference relative to `contrast_scale · Σ count_k |L_k|`.
    max_contrast_rel: f32,
    max_total: f32,
}

/// Evaluates on both engines and measures the differences.
fn compare(
    gpu: &mut GpuEngine,
    image: &RgbImage,
    model_ellipse: &Particle,
    frame: &FrameInput<'_>,
    params: &LikelihoodParams,
    ps: &[Particle],
) -> Agreement {
    let model = ColourHistogram::from_ellipse(
        image,
        &pftrack::geometry::Ellipse::new(
            model_ellipse.cx as f64,
            model_ellipse.cy as f64,
            model_ellipse.a as f64,
            model_ellipse.b as f64,
        ),
        params.colour_bins,
    )
    .unwrap();
    // The contrast table of the model against the whole frame.
    let whole = ColourHistogram::from_ellipse(
        image,
        &pftrack::geometry::Ellipse::new(
            image.width() as f64 / 2.0,
            image.height() as f64 / 2.0,
            image.width() as f64,
            image.height() as f64,
        ),
        params.colour_bins,
    )
    .unwrap();
    let table = ContrastTable::from_histograms(&model, &whole, 3.0).unwrap();
    let mut cpu_engine = CpuEngine::new();
    cpu_engine.set_colour_model(&model).unwrap();
    cpu_engine.set_contrast_table(&table).unwrap();
    gpu.set_colour_model(&model).unwrap();
    gpu.set_contrast_table(&table).unwrap();
    let mut want = Vec::new();
    cpu_engine.evaluate(frame, params, ps, &mut want).unwrap();
    let got = gpu.evaluate_debug(frame, params, ps).unwrap();
    // The debug path returns what the plain path returns.
    let mut plain = Vec::new();
    gpu.evaluate(frame, params, ps, &mut plain).unwrap();
    assert_eq!(plain, got.terms);

    let grad = cpu::gradient::GradientImage::new(image);
    let l = params.num_lines as usize;
    let mut a = Agreement::default();
    for (i, p) in ps.iter().enumerate() {
        a.particles += 1;
        let (w, g): (&TermLogs, &TermLogs) = (&want[i], &got.terms[i]);
        if cpu::is_degenerate(p) {
            assert_eq!(w, g, "degenerate particle {i}");
            continue;
        }
        let want_d = cpu_decisions(image, &grad, p, frame.theta0, params);
        let counts = &want_d.counts;
        let flipped = hist_difference(counts, &got.histograms[i * HIST_BINS..(i + 1) * HIST_BINS]);
        let same_hist = flipped == 0;
        if !same_hist {
            a.hist_mismatch += 1;
            let e = EllipseF32::from_particle(p, frame.theta0);
            if flipped > tie_pixels(&e, image.width(), image.height()) {
                a.hist_unexplained += 1;
            }
        }
        let mut same_lines = true;
        for (k, d) in want_d.lines.iter().enumerate() {
            a.lines += 1;
            if got.line_distances[i * l + k] != *d {
                a.line_mismatch += 1;
                same_lines = false;
            }
        }
        if same_hist {
            a.max_colour = a.max_colour.max((w.colour - g.colour).abs());
            if params.terms & TERM_CONTRAST != 0 {
                // The exact term from the histogram, and the scale of its rounding.
                let (mut exact, mut size) = (0.0f64, 0.0f64);
                for (c, l) in counts.iter().zip(&table.0) {
                    exact += *c as f64 * *l as f64;
                    size += *c as f64 * l.abs() as f64;
                }
                let scale = params.contrast_scale as f64;
                let size = (scale * size).max(1e-30);
                let rel = |v: f32| ((v as f64 - scale * exact).abs() / size) as f32;
                a.max_contrast_rel = a.max_contrast_rel.max(rel(w.contrast)).max(rel(g.contrast));
            }
        }
        if same_lines {
            a.max_gradient = a.max_gradient.max((w.gradient - g.gradient).abs());
        }
        a.max_feature = a.max_feature.max((w.feature - g.feature).abs());
        if same_hist && same_lines {
            a.max_total = a.max_total.max((w.total - g.total).abs());
        }
    }
    a
}

/// What the CPU twin decides for a (non-degenerate) particle: its histogram counts and, with
/// the gradient term on, each normal line's edge distance as the GPU writes it.
struct Decisions {
    counts: [u32; HIST_BINS],
    lines: Vec<i32>,
}

fn cpu_decisions(
    image: &RgbImage,
    grad: &cpu::gradient::GradientImage,
    p: &Particle,
    theta0: f32,
    params: &LikelihoodParams,
) -> Decisions {
    let e = EllipseF32::from_particle(p, theta0);
    let (counts, _) = cpu::colour::histogram(image, &e, params.colour_bins);
    let lines = if params.terms & TERM_GRADIENT != 0 {
        cpu::gradient::edge_distances(grad, p, theta0, params)
            .iter()
            .map(|d| d.map_or(NO_EDGE, |d| d as i32))
            .collect()
    } else {
        Vec::new()
    };
    Decisions { counts, lines }
}

/// Pixels counted by one histogram and not the other (the L1 distance of the counts).
fn hist_difference(a: &[u32], b: &[u32]) -> usize {
    a.iter().zip(b).map(|(x, y)| x.abs_diff(*y) as usize).sum()
}

/// Pixel centres of a `w × h` frame whose inside test against `e` is a tie (`INSIDE_TIE`).
fn tie_pixels(e: &EllipseF32, w: u32, h: u32) -> usize {
    let (s, c) = e.theta.sin_cos();
    let (s, c) = (s as f64, c as f64);
    let (cx, cy, a, b) = (e.cx as f64, e.cy as f64, e.a as f64, e.b as f64);
    let r = a.max(b) + 2.0;
    let span = |lo: f64, hi: f64, n: u32| {
        let lo = lo.floor().max(0.0) as i64;
        let hi = hi.ceil().min(n as f64 - 1.0) as i64;
        lo..=hi
    };
    let mut ties = 0;
    for y in span(cy - r, cy + r, h) {
        for x in span(cx - r, cx + r, w) {
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            let u = (c * dx + s * dy) / a;
            let v = (-s * dx + c * dy) / b;
            if (u * u + v * v - 1.0).abs() <= INSIDE_TIE {
                ties += 1;
            }
        }
    }
    ties
}

fn assert_agreement(what: &str, a: &Agreement) {
    let _ = writeln!(std::io::stderr(), "{what}: {a:?}");
    assert_eq!(
        a.hist_unexplained, 0,
        "{what}: histograms differ beyond their tie pixels: {a:?}"
    );
    assert!(
        (a.hist_mismatch as f64) <= MAX_HIST_TIE_FRACTION * a.particles as f64,
        "{what}: too many histograms differ: {a:?}"
    );
    assert!(
        (a.line_mismatch as f64) <= MAX_LINE_TIE_FRACTION * a.lines as f64,
        "{what}: too many line distances differ: {a:?}"
    );
    assert!(a.max_colour <= TOL_COLOUR, "{what}: {a:?}");
    assert!(a.max_gradient <= TOL_GRADIENT, "{what}: {a:?}");
    assert!(a.max_feature <= TOL_FEATURE, "{what}: {a:?}");
    assert!(a.max_contrast_rel <= TOL_CONTRAST_REL, "{what}: {a:?}");
    // The contrast term's share of the total is checked against its own tolerance above.
    assert!(
        a.max_total <= TOL_COLOUR + TOL_GRADIENT + TOL_FEATURE + TOL_CONTRAST_ABS,
        "{what}: {a:?}"
    );
}

/// `(frame path, OTB box)` pairs of a sequence, every `step`-th frame.
fn sequence(name: &str, step: usize, count: usize) -> Option<Vec<(std::path::PathBuf, Particle)>> {
    let dir = shared_data::path(name)?;
    let boxes = std::fs::read_to_string(dir.join("groundtruth_rect.txt")).unwrap();
    let rows: Vec<Vec<f32>> = boxes
        .lines()
        .map(|l| {
            l.split([',', '\t', ' '])
                .filter(|s| !s.is_empty())
                .filter_map(|s| s.trim().parse().ok())
                .collect()
        })
        .collect();
    Some(
        rows.iter()
            .enumerate()
            .step_by(step)
            .take(count)
            .filter(|(_, r)| r.len() == 4)
            .map(|(i, r)| {
                let e = Particle {
                    cx: r[0] - 1.0 + r[2] / 2.0,
                    cy: r[1] - 1.0 + r[3] / 2.0,
                    a: r[2] / 2.0,
                    b: r[3] / 2.0,
                    ..Default::default()
                };
                (dir.join("img").join(format!("{:04}.jpg", i + 1)), e)
            })
            .collect(),
    )
}

/// Both colour binnings: the RGB bins, and the luma bins the tracker uses on grayscale
/// footage (car4), here also on colour frames (girl), where luma is a weighted sum.
#[test]
fn gpu_agrees_with_cpu_on_real_frames() {
    let Some(mut gpu) = engine() else { return };
    let mut rng = StdRng::seed_from_u64(5);
    let mut any = false;
    for name in ["girl", "car4"] {
        let Some(frames) = sequence(name, 40, 4) else {
            skip(&format!("../shared/data/{name} missing"));
            continue;
        };
        let model_e = frames[0].1;
        for (path, e) in &frames {
            let image = image::open(path).unwrap().to_rgb8();
            let features = random_features(&mut rng, e, 40);
            let mut prev = *e;
            prev.rx = 0.1;
            prev.rz = -0.05;
            let frame = FrameInput {
                image: &image,
                features: &features,
                depths: None,
                prev,
                theta0: 0.02,
            };
            let ps = random_particles(&mut rng, e, 300);
            for colour_bins in [COLOUR_RGB, COLOUR_LUMA] {
                let params = LikelihoodParams {
                    colour_bins,
                    terms: TERM_ALL,
                    contrast_scale: 60.0 / (std::f32::consts::PI * e.a * e.b),
                    ..LikelihoodParams::default()
                };
                let a = compare(&mut gpu, &image, &model_e, &frame, &params, &ps);
                assert_agreement(&format!("{} bins {colour_bins}", path.display()), &a);
            }
            any = true;
        }
    }
    if !any {
        skip("no real frames");
    }
}

/// Unturned ellipses with half-pixel centres, as odd-sized boxes give: the lines at 90, 180
/// and 270 degrees run along a column or row boundary, and a line angle's sin or cos a few
/// 1e-8 off 0 puts the whole line in the next column. The shader computed them with WGSL's
/// sin and cos (promised only to 2^-11); it now reads the CPU's, and every line agrees.
/// (lavapipe's sin and cos already matched Rust's here, so on lavapipe this passed before the
/// change too: it is a guard for hardware drivers, whose may not.)
#[test]
fn lines_along_pixel_boundaries_agree() {
    let Some(mut gpu) = engine() else { return };
    let (image, e) = synthetic_frame(96, 80, 11);
    let mut ps = Vec::new();
    for (i, (a, b)) in [(20.0, 20.0), (12.5, 18.0), (9.0, 9.0), (15.0, 7.5)]
        .into_iter()
        .enumerate()
    {
        for (dx, dy) in [(0.5, 0.5), (-3.5, 0.0), (0.0, 2.5), (4.5, -1.5)] {
            ps.push(Particle {
                cx: e.cx.round() + dx,
                cy: e.cy.round() + dy + i as f32,
                a,
                b,
                ..Default::default()
            });
        }
    }
    for num_lines in [4, 8, 24, 36] {
        let params = LikelihoodParams {
            terms: TERM_COLOUR | TERM_GRADIENT,
            num_lines,
            ..LikelihoodParams::default()
        };
        let frame = FrameInput {
            image: &image,
            features: &[],
            depths: None,
            prev: e,
            theta0: 0.0,
        };
        let a = compare(&mut gpu, &image, &e, &frame, &params, &ps);
        assert_eq!(a.line_mismatch, 0, "{num_lines} lines: {a:?}");
        assert_agreement(&format!("{num_lines} lines on pixel boundaries"), &a);
    }
}

/// A textured synthetic frame: smooth colour ramps, a noise texture and a bright ellipse.
fn synthetic_frame(w: u32, h: u32, seed: u64) -> (RgbImage, Particle) {
    let mut rng = StdRng::seed_from_u64(seed);
    let e = Particle {
        cx: w as f32 * 0.45,
        cy: h as f32 * 0.55,
        a: w as f32 * 0.15,
        b: h as f32 * 0.2,
        ..Default::default()
    };
    let img = RgbImage::from_fn(w, h, |x, y| {
        let n: u8 = rng.random_range(0..40);
        let (dx, dy) = ((x as f32 - e.cx) / e.a, (y as f32 - e.cy) / e.b);
        if dx * dx + dy * dy <= 1.0 {
            Rgb([200 + n / 2, 120 + n, 60 + n])
        } else {
            Rgb([
                (x * 255 / w) as u8 / 2 + n,
                (y * 255 / h) as u8 / 2 + n,
                ((x + y) % 64) as u8 + n,
            ])
        }
    });
    (img, e)
}

#[test]
fn gpu_agrees_with_cpu_on_synthetic_frames() {
    let Some(mut gpu) = engine() else { return };
    let mut rng = StdRng::seed_from_u64(9);
    for (w, h, seed) in [(160, 120, 1), (97, 61, 2), (320, 240, 3)] {
        let (image, e) = synthetic_frame(w, h, seed);
        let features = random_features(&mut rng, &e, 25);
        for (theta0, params) in [
            (0.0, LikelihoodParams::default()),
            (
                0.7,
                LikelihoodParams {
                    num_lines: 40,
                    line_half_length: 12.4,
                    edge_threshold: 0.02,
                    terms: TERM_COLOUR | TERM_GRADIENT,
                    ..Default::default()
                },
            ),
            (
                0.3,
                LikelihoodParams {
                    terms: TERM_CONTRAST,
                    contrast_scale: 0.05,
                    ..Default::default()
                },
            ),
        ] {
            let frame = FrameInput {
                image: &image,
                features: &features,
                depths: None,
                prev: e,
                theta0,
            };
            let ps = random_particles(&mut rng, &e, 400);
            let a = compare(&mut gpu, &image, &e, &frame, &params, &ps);
            assert_agreement(&format!("synthetic {w}x{h} theta0 {theta0}"), &a);
        }
    }
}

/// Depths given with the features (the tracker's turned object model when the camera is
/// known) reach the GPU's feature term as they reach the CPU's, and do move it.
#[test]
fn gpu_agrees_with_cpu_with_given_feature_depths() {
    let Some(mut gpu) = engine() else { return };
    let mut rng = StdRng::seed_from_u64(12);
    let (image, e) = synthetic_frame(160, 120, 4);
    let features = random_features(&mut rng, &e, 30);
    let depths: Vec<f32> = (0..features.len())
        .map(|_| rng.random_range(-25.0..0.0))
        .collect();
    let mut prev = e;
    prev.ry = 0.4;
    prev.rx = -0.1;
    let params = LikelihoodParams::default();
    let ps = random_particles(&mut rng, &e, 300);
    let mut feature_terms = Vec::new();
    for d in [None, Some(&depths[..])] {
        let frame = FrameInput {
            image: &image,
            features: &features,
            depths: d,
            prev,
            theta0: 0.1,
        };
        let a = compare(&mut gpu, &image, &e, &frame, &params, &ps);
        assert_agreement(&format!("given depths {}", d.is_some()), &a);
        let mut out = Vec::new();
        gpu.evaluate(&frame, &params, &ps, &mut out).unwrap();
        feature_terms.push(out.iter().map(|t| t.feature).collect::<Vec<_>>());
    }
    let moved = feature_terms[0]
        .iter()
        .zip(&feature_terms[1])
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(
        moved > 0.05,
        "the depths moved the GPU's feature term by {moved} at most"
    );
}

#[test]
fn seventy_thousand_particles_agree_with_cpu_on_a_subset() {
    let Some(mut gpu) = engine() else { return };
    let (image, e) = synthetic_frame(64, 48, 7);
    let mut rng = StdRng::seed_from_u64(70);
    let features = random_features(&mut rng, &e, 10);
    let params = LikelihoodParams {
        num_lines: 8,
        ..Default::default()
    };
    let frame = FrameInput {
        image: &image,
        features: &features,
        depths: None,
        prev: e,
        theta0: 0.0,
    };
    let ps = random_particles(&mut rng, &e, 70_000);
    let model = ColourHistogram::from_ellipse(
        &image,
        &pftrack::geometry::Ellipse::new(e.cx as f64, e.cy as f64, e.a as f64, e.b as f64),
        COLOUR_RGB,
    )
    .unwrap();
    gpu.set_colour_model(&model).unwrap();
    let mut got = Vec::new();
    gpu.evaluate(&frame, &params, &ps, &mut got).unwrap();
    assert_eq!(got.len(), ps.len());
    // Particles past the first 65535 workgroups (colour: one workgroup per particle) are
    // evaluated exactly as when they come alone.
    let mut part = Vec::new();
    for start in [0usize, 65_000, 69_000] {
        gpu.evaluate(&frame, &params, &ps[start..start + 1000], &mut part)
            .unwrap();
        assert_eq!(&got[start..start + 1000], &part[..], "batch at {start}");
    }
    // Every 97th particle, so the sample spans both rows of the 2D dispatch: each gets in the
    // whole dispatch exactly what it gets in a small one, and that agrees with the CPU twin,
    // every difference a proven tie (`compare`, as on every other frame here).
    let idx: Vec<usize> = (0..ps.len()).step_by(97).chain([ps.len() - 1]).collect();
    let sub: Vec<Particle> = idx.iter().map(|&i| ps[i]).collect();
    gpu.evaluate(&frame, &params, &sub, &mut part).unwrap();
    for (j, &i) in idx.iter().enumerate() {
        assert_eq!(
            got[i], part[j],
            "particle {i} in the whole dispatch and alone"
        );
    }
    let a = compare(&mut gpu, &image, &e, &frame, &params, &sub);
    assert_agreement("every 97th of 70000 particles", &a);

    // The buffers grown for the 70000 shrink back once enough calls in a row need far less,
    // and the terms come out the same from the new buffers.
    let big = gpu.buffer_bytes();
    assert!(big > 70_000 * 32, "{big} bytes for 70000 particles");
    let mut again = Vec::new();
    for _ in 0..SHRINK_AFTER_CALLS {
        gpu.evaluate(&frame, &params, &sub, &mut again).unwrap();
    }
    let small = gpu.buffer_bytes();
    assert!(small < big / 4, "{small} bytes held after {big}");
    assert_eq!(again, part, "the terms from the shrunk buffers");
    // Another large call grows them again (those of the debug histograms, grown by
    // `compare`, stay small).
    gpu.evaluate(&frame, &params, &ps, &mut again).unwrap();
    assert_eq!(again, got);
    assert!(
        gpu.buffer_bytes() > 4 * small,
        "{} bytes",
        gpu.buffer_bytes()
    );
}

/// `auto` takes a hardware adapter or a named one; the best adapter when it renders in
/// software (lavapipe in CI) is left for the CPU engine, with a notice naming it. `gpu` opens
/// whatever adapter there is.
#[test]
fn auto_backend_takes_a_hardware_or_named_adapter_and_leaves_a_software_one_to_the_cpu() {
    use pftrack::likelihood::{Backend, create_engine_for};
    // Held to the end, so that the engines below open beside it, as the others' do.
    let Some(gpu) = engine() else { return };
    let info = gpu.device().info.clone();
    let named = pftrack::likelihood::gpu::named_adapter();
    let (e, notice) = create_engine_for(Backend::Auto, named.as_deref()).unwrap();
    if info.device_type == wgpu::DeviceType::Cpu && named.is_none() {
        assert!(e.name().starts_with("cpu"), "{}", e.name());
        let notice = notice.expect("a notice when auto leaves the GPU");
        assert!(
            notice.contains("software") && notice.contains(&info.name),
            "{notice}"
        );
    } else {
        assert!(e.name().contains("Vulkan"), "{}", e.name());
        assert!(notice.is_none(), "{notice:?}");
    }
    // Named, the same adapter is opened whatever it is.
    let (e, notice) = create_engine_for(Backend::Auto, Some(&info.name)).unwrap();
    assert!(e.name().contains(&info.name), "{}", e.name());
    assert!(notice.is_none(), "{notice:?}");
    let (e, notice) = create_engine_for(Backend::Gpu, named.as_deref()).unwrap();
    assert!(e.name().contains("Vulkan"), "{}", e.name());
    assert!(notice.is_none(), "{notice:?}");
}

// ---------------------------------------------------------------------------------------------
// The filter's weighting and systematic resampling on CPU and GPU log-likelihoods.
//
// Same particles, same frame, same seed: the two filters draw with the same comb offset u0, so
// their index sets are identical whenever the running sums of their normalised weights differ
// by less than the comb's margin (`systematic_margin`: the distance from the nearest tooth to
// a deciding cumulative sum). A log-likelihood difference of ~1e-5 moves a running sum by
// ~1e-5 times the weight involved, so a tooth closer than that to a boundary (a tie) may draw
// the neighbouring particle. Asserted: the running sums agree within `TOL_CUM_WEIGHT` (the
// weights agree) unless one to `MAX_FLIPS` particles had a pixel or an edge decided
// differently (a tie of the inside test or of a line sample, as in the agreement tests above:
// that particle's log-likelihood then differs by 1e-3 to 1; seen on an NVIDIA H200, never on
// lavapipe), every draw outside a tie is identical, and an index set that differs does so at a
// tie. Ties, flips (index sets that differ) and such draws are counted and printed; flips and
// such draws together are at most a quarter: most draws must give the same particles. Ties
// themselves are not bounded, since how many there are follows from how closely the engines'
// weights agree: on an NVIDIA H200 (2026-12-04, synthetic frames only) the running sums
// differed by up to 3.1e-6, and 14 of 48 draws had a tooth that close to a boundary (a
// 1000-particle comb nearly always does); 5 drew different particles, 43 the same.
// ---------------------------------------------------------------------------------------------

use pftrack::filter::resample::{max_cumulative_difference, systematic_margin};
use pftrack::filter::{FilterParams, Hypothesis, Motion, ParticleFilter};

/// Largest difference allowed between the running sums of the CPU's and the GPU's normalised
/// weights: log-likelihoods within 2.1e-4 of each other (the sum of the term tolerances) change
/// a normalised weight w by at most about 2 · 2.1e-4 · w, and the running sums by at most
/// 4.2e-4; measured differences are ~1e-5, so 1e-4 still catches a drift beyond the
/// measured agreement.
const TOL_CUM_WEIGHT: f64 = 1e-4;

#[derive(Debug, Default)]
struct DrawStats {
    draws: usize,
    identical: usize,
    ties: usize,
    flips: usize,
    /// Draws whose weights differ because a particle's pixel or edge was decided differently.
    flip_draws: usize,
    max_dcum: f64,
    min_margin: f64,
}

#[allow(clippy::too_many_arguments)]
fn draw_on_both(
    stats: &mut DrawStats,
    cpu_engine: &mut CpuEngine,
    gpu: &mut GpuEngine,
    frame: &FrameInput<'_>,
    params: &LikelihoodParams,
    init: &Hypothesis,
    n: usize,
    seed: u64,
    spread: f64,
) {
    let fp = FilterParams {
        particles: n,
        // Resample on every update (the ESS is always below 2 N).
        resample_below: 2.0,
        ..FilterParams::default()
    };
    let mut fc = ParticleFilter::new(fp, seed, init).unwrap();
    fc.propose(&Motion::still(), spread);
    let mut ps = Vec::new();
    fc.particles_f32(&mut ps);
    let (mut c, mut g) = (Vec::new(), Vec::new());
    cpu_engine.evaluate(frame, params, &ps, &mut c).unwrap();
    gpu.evaluate(frame, params, &ps, &mut g).unwrap();
    let lc: Vec<f32> = c.iter().map(|t| t.total).collect();
    let lg: Vec<f32> = g.iter().map(|t| t.total).collect();
    let mut fg = fc.clone();
    assert!(fc.update(&lc).unwrap().resampled && fg.update(&lg).unwrap().resampled);
    let (rc, rg) = (fc.last_resampling().unwrap(), fg.last_resampling().unwrap());
    assert_eq!(rc.u0, rg.u0, "the same seed draws the same comb");
    let dcum = max_cumulative_difference(&rc.weights, &rg.weights);
    let margin = systematic_margin(&rc.weights, n, rc.u0);
    stats.draws += 1;
    stats.max_dcum = stats.max_dcum.max(dcum);
    stats.min_margin = if stats.draws == 1 {
        margin
    } else {
        stats.min_margin.min(margin)
    };
    if dcum > TOL_CUM_WEIGHT {
        // Only a particle whose pixel or edge decision was a tie that the engines decided
        // differently (see the agreement tests) may move the weights this much.
        let flipped = decided_differently(gpu, frame, params, &ps);
        assert!(
            (1..=MAX_FLIPS).contains(&flipped),
            "weights disagree: running sums differ by {dcum:e}, and {flipped} particles' \
             pixels or edges were decided differently"
        );
        stats.flip_draws += 1;
        return;
    }
    let tie = dcum >= margin;
    stats.ties += usize::from(tie);
    if rc.indices == rg.indices {
        stats.identical += 1;
        assert_eq!(fc.particles(), fg.particles());
    } else {
        assert!(
            tie,
            "index sets differ although the weights agree within the margin ({dcum:e} < {margin:e})"
        );
        stats.flips += 1;
    }
}

/// Most particles of one draw whose likelihoods may flip: a flip is one particle's tie.
const MAX_FLIPS: usize = 3;

/// The particles (non-degenerate) whose histogram or line distances differ between the
/// engines.
fn decided_differently(
    gpu: &mut GpuEngine,
    frame: &FrameInput<'_>,
    params: &LikelihoodParams,
    ps: &[Particle],
) -> usize {
    let got = gpu.evaluate_debug(frame, params, ps).unwrap();
    let grad = cpu::gradient::GradientImage::new(frame.image);
    let l = params.num_lines as usize;
    ps.iter()
        .enumerate()
        .filter(|(i, p)| {
            if cpu::is_degenerate(p) {
                return false;
            }
            let want = cpu_decisions(frame.image, &grad, p, frame.theta0, params);
            let hist = &got.histograms[i * HIST_BINS..(i + 1) * HIST_BINS];
            let lines = &got.line_distances[i * l..i * l + want.lines.len()];
            hist_difference(&want.counts, hist) > 0 || want.lines[..] != lines[..]
        })
        .count()
}

fn hypothesis(p: &Particle) -> Hypothesis {
    Hypothesis::from_state(&pftrack::geometry::PoseState {
        cx: p.cx as f64,
        cy: p.cy as f64,
        a: p.a as f64,
        b: p.b as f64,
        rx: p.rx as f64,
        ry: p.ry as f64,
        rz: p.rz as f64,
    })
}

fn model_of(image: &RgbImage, e: &Particle) -> ColourHistogram {
    ColourHistogram::from_ellipse(
        image,
        &pftrack::geometry::Ellipse::new(e.cx as f64, e.cy as f64, e.a as f64, e.b as f64),
        COLOUR_RGB,
    )
    .unwrap()
}

#[test]
fn resampling_draws_the_same_particles_on_cpu_and_gpu_likelihoods() {
    let Some(mut gpu) = engine() else { return };
    let mut cpu_engine = CpuEngine::new();
    let params = LikelihoodParams::default();
    let mut rng = StdRng::seed_from_u64(21);
    let mut stats = DrawStats::default();
    // (frame, its target, the colour model's frame and target)
    let mut cases: Vec<(RgbImage, Particle, RgbImage, Particle)> = Vec::new();
    for name in ["girl", "car4"] {
        match sequence(name, 50, 3) {
            Some(frames) => {
                let model_img = image::open(&frames[0].0).unwrap().to_rgb8();
                for (path, e) in &frames {
                    let img = image::open(path).unwrap().to_rgb8();
                    cases.push((img, *e, model_img.clone(), frames[0].1));
                }
            }
            None => skip(&format!("../shared/data/{name} missing")),
        }
    }
    for scenario in [pftrack::synth::Scenario::Nod, pftrack::synth::Scenario::Pan] {
        let r = pftrack::synth::Renderer::new(&pftrack::synth::SynthConfig::new(scenario)).unwrap();
        let (img0, t0) = r.render(0);
        let at = |t: &pftrack::geometry::PoseState| Particle {
            cx: t.cx as f32,
            cy: t.cy as f32,
            a: t.a as f32,
            b: t.b as f32,
            rx: t.rx as f32,
            ry: t.ry as f32,
            rz: t.rz as f32,
            _pad: 0.0,
        };
        for k in [5, 20] {
            let (img, t) = r.render(k);
            cases.push((img, at(&t), img0.clone(), at(&t0)));
        }
    }
    for (img, e, model_img, model_e) in &cases {
        let model = model_of(model_img, model_e);
        cpu_engine.set_colour_model(&model).unwrap();
        gpu.set_colour_model(&model).unwrap();
        let features = random_features(&mut rng, e, 30);
        let frame = FrameInput {
            image: img,
            features: &features,
            depths: None,
            prev: *e,
            theta0: 0.0,
        };
        let init = hypothesis(e);
        for (n, spread) in [(200, 1.0), (200, 3.0), (1000, 2.0)] {
            for seed in 0..4 {
                draw_on_both(
                    &mut stats,
                    &mut cpu_engine,
                    &mut gpu,
                    &frame,
                    &params,
                    &init,
                    n,
                    seed,
                    spread,
                );
            }
        }
    }
    let _ = writeln!(
        std::io::stderr(),
        "resampling on CPU vs GPU weights: {stats:?}"
    );
    assert!(stats.draws >= 48, "{stats:?}");
    // Differences are the exception: most draws must give the same particles, with the same
    // decisions for every pixel and edge.
    assert!(
        (stats.flips + stats.flip_draws) * 4 <= stats.draws,
        "{stats:?}"
    );
}

#[test]
fn a_frame_beyond_the_buffer_limits_fails_evaluate_before_any_allocation() {
    let Some(mut e) = engine() else { return };
    let limit = e.device().limits.max_storage_buffer_binding_size;
    let side = ((limit / 8) as f64).sqrt() as u32 + 16;
    if side > 6000 {
        // A hardware adapter's limits: the frame would take gigabytes of host memory here.
        skip(&format!(
            "a {side}x{side} frame is too large to build in a test"
        ));
        return;
    }
    let img = RgbImage::new(side, side);
    e.set_colour_model(&one_hot(0)).unwrap();
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: particle(100.0, 100.0, 20.0, 20.0),
        theta0: 0.0,
    };
    let mut out = Vec::new();
    let r = e.evaluate(
        &frame,
        &LikelihoodParams::default(),
        &[frame.prev],
        &mut out,
    );
    match r {
        Err(err @ LikelihoodError::FrameTooLarge { .. }) => {
            let msg = err.to_string();
            assert!(
                msg.contains(&format!("{side}x{side}")) && msg.contains("Backend::Cpu"),
                "{msg}"
            );
        }
        r => panic!("expected FrameTooLarge, got {r:?}"),
    }
    // The engine is still usable on a frame that fits.
    let small = RgbImage::new(64, 48);
    let frame = FrameInput {
        image: &small,
        prev: particle(32.0, 24.0, 8.0, 8.0),
        ..frame
    };
    e.evaluate(
        &frame,
        &LikelihoodParams::default(),
        &[frame.prev],
        &mut out,
    )
    .unwrap();
    assert_eq!(out.len(), 1);
}

/// An engine on a device the application opened itself (`GpuDevice::from_wgpu`) gives the
/// same terms as one on a device the engine opened, on the same adapter.
#[test]
fn an_engine_on_the_applications_own_device_gives_the_same_terms() {
    let Some(mut own) = engine() else { return };
    let name = own.name();
    let (device, queue) = app_device(&name);
    let gpu = GpuDevice::from_wgpu(device, queue);
    assert!(name.contains(&gpu.info.name), "{name} / {:?}", gpu.info);
    let mut theirs = GpuEngine::with_device(gpu).unwrap();

    let r = pftrack::synth::Renderer::new(&pftrack::synth::SynthConfig::new(
        pftrack::synth::Scenario::Nod,
    ))
    .unwrap();
    let (img, t) = r.render(3);
    let e = particle(t.cx as f32, t.cy as f32, t.a as f32, t.b as f32);
    let model = ColourHistogram::from_ellipse(
        &img,
        &pftrack::geometry::Ellipse::new(t.cx, t.cy, t.a, t.b),
        COLOUR_RGB,
    )
    .unwrap();
    let ps: Vec<Particle> = (0..50)
        .map(|i| {
            let d = i as f32 * 0.37;
            particle(
                e.cx + d.sin() * 4.0,
                e.cy + d.cos() * 3.0,
                e.a,
                e.b + d % 2.0,
            )
        })
        .collect();
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: e,
        theta0: 0.0,
    };
    let params = LikelihoodParams {
        terms: TERM_COLOUR | TERM_GRADIENT,
        ..Default::default()
    };
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for (engine, out) in [
        (&mut *own as &mut dyn LikelihoodEngine, &mut a),
        (&mut theirs, &mut b),
    ] {
        engine.set_colour_model(&model).unwrap();
        engine.evaluate(&frame, &params, &ps, out).unwrap();
    }
    assert_eq!(a.len(), ps.len());
    assert_eq!(a, b);
}

/// A frame input on `img`, one flat colour, with the engine's colour model that colour's bin
/// and the previous estimate a 3 px circle at (8, 8).
fn flat_frame<'a>(e: &mut GpuEngine, img: &'a RgbImage) -> FrameInput<'a> {
    e.set_colour_model(&one_hot(bin_of(*img.get_pixel(0, 0))))
        .unwrap();
    FrameInput {
        image: img,
        features: &[],
        depths: None,
        prev: particle(8.0, 8.0, 3.0, 3.0),
        theta0: 0.0,
    }
}

/// A device opened as an application would, on the adapter an engine named `name` runs on.
fn app_device(name: &str) -> (pftrack::wgpu::Device, pftrack::wgpu::Queue) {
    app_device_limited(name, |l| l)
}

/// [`app_device`] with the adapter's limits changed by `limits`.
fn app_device_limited(
    name: &str,
    limits: impl FnOnce(pftrack::wgpu::Limits) -> pftrack::wgpu::Limits,
) -> (pftrack::wgpu::Device, pftrack::wgpu::Queue) {
    use pftrack::wgpu;
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::VULKAN;
    let instance = wgpu::Instance::new(desc);
    let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN));
    let adapter = adapters
        .into_iter()
        .find(|a| name.contains(&a.get_info().name))
        .expect("the engine's adapter is listed");
    pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("the application's device"),
        required_limits: limits(adapter.limits()),
        ..Default::default()
    }))
    .unwrap()
}

/// On the application's own device the engine leaves the application's uncaptured-error
/// handler and device-lost callback in place: an error of the application's work reaches its
/// handler (not the engine's next call), and a lost device reaches both.
#[test]
fn the_applications_error_handlers_stay_in_place() {
    use pftrack::wgpu;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::{Arc, Mutex};
    let Some(own) = engine() else { return };
    let (device, queue) = app_device(&own.name());
    drop(own);
    let errors = Arc::new(Mutex::new(Vec::<String>::new()));
    let lost = Arc::new(AtomicUsize::new(0));
    {
        let errors = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            errors.lock().unwrap().push(e.to_string());
        }));
        let lost = lost.clone();
        device.set_device_lost_callback(move |_, _| {
            lost.fetch_add(1, Ordering::SeqCst);
        });
    }
    let app = device.clone();
    let mut e = GpuEngine::with_device(GpuDevice::from_wgpu(device, queue)).unwrap();
    let img = RgbImage::from_pixel(16, 16, Rgb([1, 2, 3]));
    let frame = flat_frame(&mut e, &img);
    let params = LikelihoodParams {
        terms: TERM_COLOUR,
        ..Default::default()
    };
    let mut out = Vec::new();
    e.evaluate(&frame, &params, &[frame.prev], &mut out)
        .unwrap();
    assert_eq!(out.len(), 1);
    assert!(errors.lock().unwrap().is_empty(), "{:?}", errors.lock());

    // The application's mistake: a buffer both mapped for reading and for writing.
    let _bad = app.create_buffer(&wgpu::BufferDescriptor {
        label: Some("the application's mistake"),
        size: 16,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::MAP_WRITE,
        mapped_at_creation: false,
    });
    assert_eq!(
        errors.lock().unwrap().len(),
        1,
        "the application's handler saw it"
    );
    let again = e.evaluate(&frame, &params, &[frame.prev], &mut out);
    assert!(again.is_ok(), "not the engine's error: {again:?}");

    app.destroy();
    let _ = app.poll(wgpu::PollType::wait_indefinitely());
    assert_eq!(
        lost.load(Ordering::SeqCst),
        1,
        "the application's callback ran"
    );
    assert_lost_with_and_without_features(&mut e, &frame);
    assert!(e.device().is_lost());
    assert_eq!(errors.lock().unwrap().len(), 1, "{:?}", errors.lock());
}

/// A buffer wgpu refuses to create fails that call only: the engine makes its buffers and
/// bind group afresh on the next. The engine checks every buffer against the limits it was
/// given, so the refusal (out of memory on a shared device in use) is staged by giving it
/// larger limits than the device has: 60,000 features of 20 bytes pass its check and not
/// the device's 1 MB. And a frame whose gradient image, rounded up to the engine's 256-byte
/// allocation, passes the limit is refused before anything is made.
#[test]
fn a_refused_allocation_fails_that_call_only() {
    let Some(own) = engine() else { return };
    let name = own.name();
    drop(own);
    let limited = || {
        let (device, queue) = app_device_limited(&name, |l| pftrack::wgpu::Limits {
            max_buffer_size: 1_000_001,
            ..l
        });
        GpuDevice::from_wgpu(device, queue)
    };
    let honest = GpuEngine::with_device(limited()).unwrap();
    // 500 x 250 x 8 bytes is 1,000,000, allocated as 1,000,192.
    assert!(matches!(
        honest.check_frame_size(500, 250),
        Err(LikelihoodError::FrameTooLarge {
            bytes: 1_000_192,
            ..
        })
    ));
    drop(honest);
    let mut gpu = limited();
    gpu.limits.max_buffer_size = 1 << 30;
    let mut e = GpuEngine::with_device(gpu).unwrap();
    let img = RgbImage::from_pixel(16, 16, Rgb([1, 2, 3]));
    let frame = flat_frame(&mut e, &img);
    let params = LikelihoodParams {
        terms: TERM_COLOUR | TERM_GRADIENT | pftrack::likelihood::TERM_FEATURE,
        ..Default::default()
    };
    let (mut before, mut after) = (Vec::new(), Vec::new());
    e.evaluate(&frame, &params, &[frame.prev], &mut before)
        .unwrap();
    let many = vec![
        FeaturePair {
            p: [8.0, 8.0],
            q: [8.0, 8.0],
        };
        60_000
    ];
    let heavy = FrameInput {
        features: &many,
        ..frame
    };
    let r = e.evaluate(&heavy, &params, &[frame.prev], &mut after);
    let Err(LikelihoodError::Gpu(msg)) = r else {
        panic!("{r:?}")
    };
    assert!(!msg.contains('\n') && msg.contains("features"), "{msg}");
    assert!(!e.device().is_lost());
    for _ in 0..2 {
        e.evaluate(&frame, &params, &[frame.prev], &mut after)
            .unwrap();
        assert_eq!(after, before);
    }
}

/// More matched features than a device's buffers hold is a typed error naming them, and only
/// when the feature term reads them: without it, the same call runs.
#[test]
fn features_beyond_the_buffer_limit_are_a_typed_error() {
    let Some(own) = engine() else { return };
    let (device, queue) = app_device_limited(&own.name(), |l| pftrack::wgpu::Limits {
        max_storage_buffer_binding_size: 1 << 20,
        ..l
    });
    let mut small = GpuEngine::with_device(GpuDevice::from_wgpu(device, queue)).unwrap();
    let img = RgbImage::from_fn(64, 48, |x, y| Rgb([(x * 4) as u8, (y * 5) as u8, 90]));
    // 1 MiB holds 52,428 lifted features of 20 bytes.
    let features: Vec<pftrack::likelihood::FeaturePair> = (0..60_000)
        .map(|i| {
            let (x, y) = ((i % 60) as f32, (i / 60 % 44) as f32);
            pftrack::likelihood::FeaturePair {
                p: [x, y],
                q: [x + 0.5, y],
            }
        })
        .collect();
    let frame = FrameInput {
        image: &img,
        features: &features,
        depths: None,
        prev: particle(32.0, 24.0, 8.0, 6.0),
        theta0: 0.0,
    };
    let ps = [
        particle(32.0, 24.0, 8.0, 6.0),
        particle(33.0, 24.0, 8.0, 6.0),
    ];
    let mut out = Vec::new();
    let params = LikelihoodParams {
        terms: pftrack::likelihood::TERM_FEATURE | TERM_GRADIENT,
        ..Default::default()
    };
    let r = small.evaluate(&frame, &params, &ps, &mut out);
    match r {
        Err(LikelihoodError::TooManyFeatures { n, bytes, limit }) => {
            assert_eq!((n, limit), (60_000, 1 << 20));
            assert!(bytes >= 1_200_000, "{bytes}");
        }
        other => panic!("{other:?}"),
    }
    let params = LikelihoodParams {
        terms: TERM_GRADIENT,
        ..Default::default()
    };
    small.evaluate(&frame, &params, &ps, &mut out).unwrap();
    assert_eq!(out.len(), 2);
    // Within the limit, the feature term runs on the small device.
    let params = LikelihoodParams {
        terms: pftrack::likelihood::TERM_FEATURE,
        ..Default::default()
    };
    let fewer = FrameInput {
        features: &features[..50_000],
        ..frame
    };
    small.evaluate(&fewer, &params, &ps, &mut out).unwrap();
    assert!(
        out.iter()
            .all(|t| t.feature.is_finite() && t.feature != 0.0)
    );
}

/// `evaluate_batched` gives as many particles as asked for in batches the engine's buffers
/// hold, the same terms bit for bit as one call on a device whose buffers hold them all.
#[test]
fn batched_evaluation_passes_the_buffer_limit_with_the_same_terms() {
    let Some(mut own) = engine() else { return };
    let (device, queue) = app_device_limited(&own.name(), |l| pftrack::wgpu::Limits {
        max_storage_buffer_binding_size: 1 << 20,
        ..l
    });
    let mut small = GpuEngine::with_device(GpuDevice::from_wgpu(device, queue)).unwrap();
    let img = RgbImage::from_fn(64, 48, |x, y| Rgb([(x * 4) as u8, (y * 5) as u8, 90]));
    let model = ColourHistogram::from_ellipse(
        &img,
        &pftrack::geometry::Ellipse::new(32.0, 24.0, 8.0, 6.0),
        COLOUR_RGB,
    )
    .unwrap();
    let frame = FrameInput {
        image: &img,
        features: &[],
        depths: None,
        prev: particle(32.0, 24.0, 8.0, 6.0),
        theta0: 0.0,
    };
    let params = LikelihoodParams {
        terms: TERM_COLOUR | TERM_GRADIENT,
        ..Default::default()
    };
    // 1 MiB holds 32,768 particles of 32 bytes; with 24 lines each, 10,922.
    let ps: Vec<Particle> = (0..40_000)
        .map(|i| {
            let t = i as f32 * 0.618;
            particle(
                32.0 + 20.0 * t.sin(),
                24.0 + 15.0 * (1.3 * t).cos(),
                3.0 + (i % 9) as f32,
                3.0 + (i % 7) as f32,
            )
        })
        .collect();
    let (mut whole, mut batched) = (Vec::new(), Vec::new());
    for e in [&mut *own as &mut dyn LikelihoodEngine, &mut small] {
        e.set_colour_model(&model).unwrap();
    }
    let r = small.evaluate(&frame, &params, &ps, &mut batched);
    assert!(
        matches!(r, Err(LikelihoodError::TooManyParticles { .. })),
        "{r:?}"
    );
    own.evaluate(&frame, &params, &ps, &mut whole).unwrap();
    small
        .evaluate_batched(&frame, &params, &ps, &mut batched)
        .unwrap();
    assert_eq!(batched.len(), ps.len());
    assert!(whole == batched, "the batches' terms differ");
    // Where one call fits, it is that call.
    own.evaluate_batched(&frame, &params, &ps[..100], &mut batched)
        .unwrap();
    assert!(whole[..100] == batched[..], "one batch");
}

/// A target lost on a large frame is searched for over the whole frame, more candidates than
/// the filter's particles: on a device whose buffers hold only a few thousand, the search runs
/// in batches, where it failed every frame once the target was lost.
#[test]
fn a_lost_targets_search_fits_the_devices_buffers() {
    use pftrack::geometry::Ellipse;
    use pftrack::tracker::{Init, Tracker, TrackerConfig};
    let Some(own) = engine() else { return };
    let (device, queue) = app_device_limited(&own.name(), |l| pftrack::wgpu::Limits {
        max_storage_buffer_binding_size: 1 << 20,
        ..l
    });
    drop(own);
    let gpu = GpuEngine::with_device(GpuDevice::from_wgpu(device, queue)).unwrap();
    let first = RgbImage::from_fn(320, 240, |x, y| {
        let r2 = (x as i32 - 160).pow(2) + (y as i32 - 120).pow(2);
        if r2 <= 16 {
            Rgb([220, 40, 40])
        } else {
            Rgb([(x % 7 * 9) as u8, (y % 5 * 11) as u8, 60])
        }
    });
    let blank = RgbImage::from_pixel(320, 240, Rgb([60, 60, 60]));
    let mut t = Tracker::with_engine(
        TrackerConfig::default(),
        Box::new(gpu),
        &first,
        Init::frontal(Ellipse::new(160.0, 120.0, 4.0, 4.0)),
    )
    .unwrap();
    let mut lost = 0;
    for k in 1..=8 {
        let est = t.step(&blank).unwrap_or_else(|e| panic!("frame {k}: {e}"));
        lost += usize::from(est.lost);
    }
    assert!(lost > 0, "the target was lost and searched for");
}
