//! GPU likelihood engine on a real Vulkan adapter (lavapipe in CI): known answers, limits,
//! errors, and agreement with the CPU reference engine.
//!
//! Without a Vulkan adapter every test skips with a printed reason, unless
//! `PFTRACK_REQUIRE_GPU=1` (CI), where a missing adapter fails.

use std::io::Write;

use image::{Rgb, RgbImage};
use pftrack::likelihood::gpu::{GpuDevice, GpuEngine, NO_EDGE};
use pftrack::likelihood::{
    ColourHistogram, FrameInput, HIST_BINS, LikelihoodEngine, LikelihoodError, LikelihoodParams,
    Particle, TERM_COLOUR, TERM_GRADIENT,
};

fn skip(reason: &str) {
    let _ = writeln!(std::io::stderr(), "SKIPPED: {reason}");
}

/// The engine, or `None` (with a printed reason) when there is no adapter and the GPU is not
/// required.
fn engine() -> Option<GpuEngine> {
    match GpuEngine::new() {
        Ok(e) => Some(e),
        Err(e) => {
            if std::env::var("PFTRACK_REQUIRE_GPU").as_deref() == Ok("1") {
                panic!("PFTRACK_REQUIRE_GPU=1 but no GPU engine: {e}");
            }
            skip(&format!("no GPU engine ({e})"));
            None
        }
    }
}

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
    if engine().is_none() {
        return;
    }
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
fn colour_without_a_model_is_an_error() {
    let Some(mut e) = engine() else { return };
    let img = RgbImage::new(8, 8);
    let frame = FrameInput {
        image: &img,
        features: &[],
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
    let limit = e.device().limits.max_storage_buffer_binding_size as u64;
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
fn a_lost_device_is_a_clear_error_from_then_on() {
    let Some(mut e) = engine() else { return };
    let img = RgbImage::from_pixel(16, 16, Rgb([1, 2, 3]));
    e.set_colour_model(&one_hot(0)).unwrap();
    let frame = FrameInput {
        image: &img,
        features: &[],
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
}

#[test]
fn seventy_thousand_particles_use_a_2d_dispatch_and_match_small_batches() {
    let Some(mut e) = engine() else { return };
    let img = RgbImage::from_fn(48, 40, |x, y| {
        Rgb([(x * 5) as u8, (y * 6) as u8, ((x + y) * 3) as u8])
    });
    let mut model = vec![1.0 / HIST_BINS as f32; HIST_BINS];
    model[0] = 0.5;
    let s: f32 = model.iter().sum();
    model.iter_mut().for_each(|v| *v /= s);
    e.set_colour_model(&ColourHistogram(model)).unwrap();
    let params = LikelihoodParams {
        num_lines: 8,
        line_half_length: 3.0,
        ..Default::default()
    };
    let frame = FrameInput {
        image: &img,
        features: &[],
        prev: particle(24.0, 20.0, 6.0, 5.0),
        theta0: 0.1,
    };
    let n = 70_000;
    let ps: Vec<Particle> = (0..n)
        .map(|i| {
            let f = i as f32;
            let mut p = particle(
                (f * 0.37) % 48.0,
                (f * 0.61) % 40.0,
                3.0 + (f * 0.13) % 4.0,
                3.0 + (f * 0.29) % 4.0,
            );
            p.rz = (f * 0.01) % 1.0;
            p
        })
        .collect();
    let mut all = Vec::new();
    e.evaluate(&frame, &params, &ps, &mut all).unwrap();
    assert_eq!(all.len(), n);
    // Particles past the first 65535 workgroups (colour: one workgroup per particle) must be
    // evaluated as when they come alone.
    let mut part = Vec::new();
    for start in [0usize, 65_000, 69_000] {
        e.evaluate(&frame, &params, &ps[start..start + 1000], &mut part)
            .unwrap();
        assert_eq!(&all[start..start + 1000], &part[..], "batch at {start}");
    }
    assert!(all.iter().all(|t| t.total.is_finite() && t.total > -1e3));
}
