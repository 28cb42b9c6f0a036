//! Known answers and invariants of SIFT and matching (`pftrack::features`).

use std::f32::consts::{FRAC_PI_2, TAU};

use pftrack::features::{
    FeatureError, Features, Keypoint, MatchParams, Sift, SiftParams, UpsampleGrid, match_features,
    reject_slope_length,
};
use pftrack::frames::GrayF32;
use pftrack::geometry::BoxRect;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

mod shared_data;

fn load(rel: &str) -> Option<GrayF32> {
    let path = shared_data::path(rel)?;
    let img = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    Some(GrayF32::from_rgb(&img.to_rgb8()))
}

/// A smooth random scene: a sum of Gaussian blobs, evaluable anywhere (so it can be rendered
/// rotated or at another resolution exactly).
struct Scene {
    blobs: Vec<(f32, f32, f32, f32)>, // x, y, sigma, amplitude
}

impl Scene {
    fn random(seed: u64, w: f32, h: f32, n: usize) -> Self {
        let mut rng = StdRng::seed_from_u64(seed);
        let blobs = (0..n)
            .map(|_| {
                (
                    rng.random_range(0.0..w),
                    rng.random_range(0.0..h),
                    rng.random_range(1.5..5.0),
                    rng.random_range(-0.5..0.5),
                )
            })
            .collect();
        Self { blobs }
    }

    fn eval(&self, x: f32, y: f32) -> f32 {
        let mut v = 0.5;
        for &(bx, by, s, a) in &self.blobs {
            let d2 = (x - bx).powi(2) + (y - by).powi(2);
            v += a * (-d2 / (2.0 * s * s)).exp();
        }
        v.clamp(0.0, 1.0)
    }

    /// Renders a `w x h` image whose pixel `(u, v)` shows the scene at `map(u, v)`.
    fn render(&self, w: u32, h: u32, map: impl Fn(f32, f32) -> (f32, f32)) -> GrayF32 {
        let mut g = GrayF32::new(w, h);
        for v in 0..h {
            for u in 0..w {
                let (x, y) = map(u as f32, v as f32);
                g.data[(v * w + u) as usize] = self.eval(x, y);
            }
        }
        g
    }
}

fn angle_diff(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(TAU);
    d.min(TAU - d)
}

/// Share of `kps` (filtered by `take`) that have a partner in `other` after mapping.
fn share_found(
    kps: &[Keypoint],
    other: &[Keypoint],
    take: impl Fn(&Keypoint) -> bool,
    found: impl Fn(&Keypoint, &Keypoint) -> bool,
) -> (f64, usize) {
    let sel: Vec<&Keypoint> = kps.iter().filter(|k| take(k)).collect();
    let hits = sel
        .iter()
        .filter(|k| other.iter().any(|o| found(k, o)))
        .count();
    (hits as f64 / sel.len().max(1) as f64, sel.len())
}

#[test]
fn gaussian_blob_gives_one_keypoint_at_its_centre() {
    let (cx, cy, s) = (31.3f32, 32.6f32, 3.0f32);
    let scene = Scene {
        blobs: vec![(cx, cy, s, 0.6)],
    };
    let img = scene.render(64, 64, |u, v| (u, v));
    let f = Sift::new(SiftParams::default()).detect(&img, None).unwrap();
    assert!(!f.is_empty(), "no keypoint on a blob");
    // An isotropic blob has no dominant orientation, so one location may carry several
    // angles; every keypoint must be that one location.
    for k in &f.keypoints {
        assert!((k.x - cx).abs() < 0.1 && (k.y - cy).abs() < 0.1, "{k:?}");
        assert!(
            (k.scale / s - 1.0).abs() < 0.15,
            "scale {} for blob sigma {s}",
            k.scale
        );
    }
    // And a bigger blob gives a proportionally bigger scale.
    let big = Scene {
        blobs: vec![(cx, cy, 2.0 * s, 0.6)],
    };
    let f2 = Sift::new(SiftParams::default())
        .detect(&big.render(64, 64, |u, v| (u, v)), None)
        .unwrap();
    assert!(!f2.is_empty());
    for k in &f2.keypoints {
        assert!((k.x - cx).abs() < 0.2 && (k.y - cy).abs() < 0.2, "{k:?}");
        assert!(
            (k.scale / (2.0 * s) - 1.0).abs() < 0.15,
            "scale {}",
            k.scale
        );
    }
}

#[test]
fn keypoints_rotate_with_the_image_by_90_degrees() {
    // W - 1 and H - 1 divisible by 8 so every octave's sampling grid maps onto itself.
    let (w, h) = (97u32, 81u32);
    let scene = Scene::random(3, w as f32, h as f32, 60);
    let img = scene.render(w, h, |u, v| (u, v));
    // Rotated clockwise on screen: pixel (u, v) of the new h x w image shows (v, h - 1 - u).
    let rot = scene.render(h, w, |u, v| (v, h as f32 - 1.0 - u));
    let sift = Sift::new(SiftParams::default());
    let a = sift.detect(&img, None).unwrap();
    let b = sift.detect(&rot, None).unwrap();
    assert!(a.len() > 40, "too few keypoints: {}", a.len());
    let map = |k: &Keypoint| (h as f32 - 1.0 - k.y, k.x, k.angle + FRAC_PI_2);
    let interior =
        |k: &Keypoint| k.x > 8.0 && k.y > 8.0 && k.x < w as f32 - 9.0 && k.y < h as f32 - 9.0;
    let (share, n) = share_found(&a.keypoints, &b.keypoints, interior, |k, o| {
        let (x, y, ang) = map(k);
        (o.x - x).abs() < 0.05
            && (o.y - y).abs() < 0.05
            && (o.scale / k.scale - 1.0).abs() < 0.01
            && angle_diff(o.angle, ang) < 0.02
    });
    assert!(
        share > 0.9,
        "only {share:.2} of {n} keypoints map under a 90° rotation"
    );

    // Descriptors of the rotated image match the original's, at the mapped positions.
    let m = match_features(&a, &b, &MatchParams::default());
    let correct = m
        .iter()
        .filter(|m| {
            let (x, y, _) = map(&a.keypoints[m.query]);
            let o = &b.keypoints[m.train];
            (o.x - x).abs() < 1.0 && (o.y - y).abs() < 1.0
        })
        .count();
    assert!(
        correct as f64 > 0.8 * a.len() as f64,
        "{correct} correct matches of {}",
        a.len()
    );
    assert!(
        correct as f64 > 0.95 * m.len() as f64,
        "{correct} correct of {} matches",
        m.len()
    );
}

#[test]
fn descriptors_survive_an_arbitrary_rotation() {
    // 30° about the centre, rendered exactly from the scene (no resampling blur).
    let (w, h) = (120u32, 100u32);
    let scene = Scene::random(5, w as f32, h as f32, 80);
    let img = scene.render(w, h, |u, v| (u, v));
    let (c, s) = (30f32.to_radians().cos(), 30f32.to_radians().sin());
    let (ox, oy) = (w as f32 / 2.0, h as f32 / 2.0);
    // New pixel p shows the scene at R^-1 (p - o) + o; a scene point q appears at R (q - o) + o.
    let rot = scene.render(w, h, |u, v| {
        let (dx, dy) = (u - ox, v - oy);
        (c * dx + s * dy + ox, -s * dx + c * dy + oy)
    });
    let sift = Sift::new(SiftParams::default());
    let a = sift.detect(&img, None).unwrap();
    let b = sift.detect(&rot, None).unwrap();
    let map = |k: &Keypoint| {
        let (dx, dy) = (k.x - ox, k.y - oy);
        (c * dx - s * dy + ox, s * dx + c * dy + oy)
    };
    let m = match_features(&a, &b, &MatchParams::default());
    let correct: Vec<_> = m
        .iter()
        .filter(|m| {
            let (x, y) = map(&a.keypoints[m.query]);
            let o = &b.keypoints[m.train];
            (o.x - x).hypot(o.y - y) < 1.5
        })
        .collect();
    assert!(m.len() >= 30, "{} matches", m.len());
    assert!(
        correct.len() as f64 > 0.9 * m.len() as f64,
        "{} correct of {}",
        correct.len(),
        m.len()
    );
    // The keypoint angles shift by the rotation.
    let angle_ok = correct
        .iter()
        .filter(|m| {
            angle_diff(
                b.keypoints[m.train].angle,
                a.keypoints[m.query].angle + 30f32.to_radians(),
            ) < 0.15
        })
        .count();
    assert!(
        angle_ok as f64 > 0.8 * correct.len() as f64,
        "{angle_ok} of {}",
        correct.len()
    );
}

#[test]
fn keypoints_are_scale_covariant_under_2x_upsampling() {
    let (w, h) = (90u32, 70u32);
    let scene = Scene::random(9, w as f32, h as f32, 50);
    let img = scene.render(w, h, |u, v| (u, v));
    // Twice the resolution: pixel u shows the scene at u / 2.
    let big = scene.render(2 * w, 2 * h, |u, v| (u / 2.0, v / 2.0));
    let sift = Sift::new(SiftParams::default());
    let a = sift.detect(&img, None).unwrap();
    let b = sift.detect(&big, None).unwrap();
    let take = |k: &Keypoint| {
        k.scale > 1.5 && k.x > 8.0 && k.y > 8.0 && k.x < w as f32 - 9.0 && k.y < h as f32 - 9.0
    };
    let (share, n) = share_found(&a.keypoints, &b.keypoints, take, |k, o| {
        (o.x - 2.0 * k.x).hypot(o.y - 2.0 * k.y) < 1.5
            && (o.scale / (2.0 * k.scale) - 1.0).abs() < 0.25
    });
    assert!(n > 15, "{n} keypoints");
    assert!(
        share > 0.75,
        "only {share:.2} of {n} keypoints reappear at twice the resolution"
    );
}

#[test]
fn real_frame_pair_matches_consistently() {
    let (Some(a), Some(b)) = (load("girl/img/0001.jpg"), load("girl/img/0002.jpg")) else {
        return;
    };
    let sift = Sift::new(SiftParams::default());
    let fa = sift.detect(&a, None).unwrap();
    let fb = sift.detect(&b, None).unwrap();
    let m = match_features(&fa, &fb, &MatchParams::default());
    assert!(m.len() >= 20, "{} matches", m.len());
    let p: Vec<[f64; 2]> = m
        .iter()
        .map(|m| {
            [
                fa.keypoints[m.query].x as f64,
                fa.keypoints[m.query].y as f64,
            ]
        })
        .collect();
    let q: Vec<[f64; 2]> = m
        .iter()
        .map(|m| {
            [
                fb.keypoints[m.train].x as f64,
                fb.keypoints[m.train].y as f64,
            ]
        })
        .collect();
    // Successive frames: most matches move by about the same small amount.
    let mut dx: Vec<f64> = p.iter().zip(&q).map(|(p, q)| q[0] - p[0]).collect();
    let mut dy: Vec<f64> = p.iter().zip(&q).map(|(p, q)| q[1] - p[1]).collect();
    dx.sort_by(f64::total_cmp);
    dy.sort_by(f64::total_cmp);
    let (mx, my) = (dx[dx.len() / 2], dy[dy.len() / 2]);
    let near = p
        .iter()
        .zip(&q)
        .filter(|(p, q)| (q[0] - p[0] - mx).hypot(q[1] - p[1] - my) < 2.0)
        .count();
    assert!(
        near as f64 > 0.85 * m.len() as f64,
        "{near} of {} near the median motion",
        m.len()
    );
    let keep = reject_slope_length(&p, &q, 0.2, 0.3);
    assert!(keep.iter().filter(|&&k| k).count() >= 10);
}

#[test]
fn region_restriction_matches_the_full_run_inside() {
    let scene = Scene::random(11, 160.0, 120.0, 120);
    let img = scene.render(160, 120, |u, v| (u, v));
    let region = BoxRect::new(50.0, 30.0, 45.0, 50.0);
    let sift = Sift::new(SiftParams::default());
    let full = sift.detect(&img, None).unwrap();
    let part = sift.detect(&img, Some(region)).unwrap();
    let inside = |k: &Keypoint| {
        let (x, y) = (k.x as f64, k.y as f64);
        x >= region.x && x <= region.x + region.w && y >= region.y && y <= region.y + region.h
    };
    assert!(part.len() >= 10, "{} keypoints in the region", part.len());
    assert!(part.keypoints.iter().all(inside));
    assert_eq!(part.keypoints.len(), part.descriptors.len());
    let same = |k: &Keypoint, o: &Keypoint| {
        (k.x - o.x).abs() < 0.01 && (k.y - o.y).abs() < 0.01 && (k.scale - o.scale).abs() < 0.01
    };
    let (share, n) = share_found(&part.keypoints, &full.keypoints, |_| true, same);
    assert!(
        share > 0.95,
        "{share:.2} of {n} region keypoints are in the full run"
    );
    let (share, n) = share_found(
        &full.keypoints,
        &part.keypoints,
        |k| inside(k) && k.scale < 4.0,
        same,
    );
    assert!(
        share > 0.9,
        "{share:.2} of {n} full-run keypoints reappear in the region run"
    );
    // Descriptors of the same keypoint agree closely (windows within the margin).
    let m = match_features(&part, &full, &MatchParams::default());
    let good = m
        .iter()
        .filter(|m| same(&part.keypoints[m.query], &full.keypoints[m.train]))
        .count();
    assert!(
        good as f64 > 0.8 * part.len() as f64,
        "{good} of {}",
        part.len()
    );
    // A region outside the image gives nothing.
    let out = sift
        .detect(&img, Some(BoxRect::new(500.0, 500.0, 20.0, 20.0)))
        .unwrap();
    assert!(out.is_empty());
    // A region beyond any image is the whole image (its bounds once overflowed an i64: a
    // 1e19 px region found nothing, and panicked in a debug build).
    for huge in [
        BoxRect::new(0.0, 0.0, 1e19, 1e19),
        BoxRect::new(-1e30, -1e30, 1e31, 1e31),
        BoxRect::new(-1e300, 0.0, 1e308, 1e308),
    ] {
        assert_eq!(sift.detect(&img, Some(huge)).unwrap(), full, "{huge:?}");
    }
    // Results do not depend on the buffers left over from earlier calls.
    Sift::release_thread_buffers();
    assert_eq!(sift.detect(&img, Some(region)).unwrap(), part);
    assert_eq!(sift.detect(&img, None).unwrap(), full);
}

#[test]
fn degenerate_images_do_not_panic() {
    let sift = Sift::new(SiftParams::default());
    for (w, h) in [
        (0, 0),
        (0, 5),
        (1, 1),
        (2, 3),
        (5, 3),
        (6, 6),
        (11, 11),
        (12, 40),
        (33, 17),
    ] {
        let mut g = GrayF32::new(w, h);
        let f = sift.detect(&g, None).unwrap();
        assert!(f.is_empty(), "constant {w}x{h} gave keypoints");
        let mut rng = StdRng::seed_from_u64(1);
        for v in &mut g.data {
            *v = rng.random();
        }
        let f = sift.detect(&g, None).unwrap();
        assert_eq!(f.keypoints.len(), f.descriptors.len());
        let f = sift
            .detect(&g, Some(BoxRect::new(1.0, 1.0, 3.0, 3.0)))
            .unwrap();
        assert_eq!(f.keypoints.len(), f.descriptors.len());
    }
    // A NaN or infinite pixel in the window is refused, named in image coordinates (one
    // NaN spreads through the blurs and took a quarter of the keypoints away); one outside
    // a region's window is not seen.
    let mut g = Scene::random(2, 80.0, 80.0, 40).render(80, 80, |u, v| (u, v));
    let clean = sift.detect(&g, None).unwrap();
    assert!(!clean.keypoints.is_empty());
    g.data[300] = f32::NAN;
    match sift.detect(&g, None) {
        Err(FeatureError::NonFinitePixel { x: 60, y: 3, value }) => assert!(value.is_nan()),
        other => panic!("{other:?}"),
    }
    g.data[300] = 0.5;
    g.data[70 * 80 + 61] = f32::INFINITY;
    let region = Some(BoxRect::new(50.0, 60.0, 20.0, 15.0));
    match sift.detect(&g, region) {
        Err(FeatureError::NonFinitePixel { x: 61, y: 70, .. }) => {}
        other => panic!("{other:?}"),
    }
    let elsewhere = Some(BoxRect::new(0.0, 0.0, 20.0, 20.0));
    sift.detect(&g, elsewhere).unwrap();
    // Typed errors.
    let bad = GrayF32 {
        width: 10,
        height: 10,
        data: vec![0.0; 7],
    };
    assert!(matches!(
        sift.detect(&bad, None),
        Err(FeatureError::BadImage { .. })
    ));
    let g = GrayF32::new(20, 20);
    assert!(matches!(
        sift.detect(&g, Some(BoxRect::new(f64::NAN, 0.0, 5.0, 5.0))),
        Err(FeatureError::BadRegion(_))
    ));
    assert!(matches!(
        sift.detect(&g, Some(BoxRect::new(0.0, 0.0, -5.0, 5.0))),
        Err(FeatureError::BadRegion(_))
    ));
    // A scale space over the budget is refused before it is built, by window: the whole
    // 300x300 image upsampled (4 · 90,000 px · 11 images · 4 bytes · 4/3 = 21.1 MB) is over
    // 10 MB; without the upsampled octave (5.3 MB), or within a region, it is not.
    let budget = SiftParams {
        max_scale_space_bytes: 10_000_000,
        ..SiftParams::default()
    };
    assert_eq!(budget.scale_space_bytes(300, 300), 21_120_000);
    let big = GrayF32::new(300, 300);
    match Sift::new(budget.clone()).detect(&big, None) {
        Err(FeatureError::TooLarge {
            width: 300,
            height: 300,
            upsampled: true,
            bytes: 21_120_000,
            limit: 10_000_000,
            fits_without_upsampling: true,
        }) => {}
        other => panic!("{other:?}"),
    }
    let region = Some(BoxRect::new(100.0, 100.0, 50.0, 50.0));
    assert!(Sift::new(budget.clone()).detect(&big, region).is_ok());
    let plain = SiftParams {
        upsample: false,
        ..budget
    };
    assert!(Sift::new(plain).detect(&big, None).is_ok());
    let odd = Sift::new(SiftParams {
        sigma: -1.0,
        ..SiftParams::default()
    });
    assert!(matches!(
        odd.detect(&g, None),
        Err(FeatureError::BadParams(ref why)) if why.contains("sigma -1")
    ));
    for (bad, name) in [
        (
            SiftParams {
                n_octave_layers: 0,
                ..SiftParams::default()
            },
            "n_octave_layers",
        ),
        (
            SiftParams {
                region_margin: -1.0,
                ..SiftParams::default()
            },
            "region_margin",
        ),
        (
            SiftParams {
                max_octaves: Some(0),
                ..SiftParams::default()
            },
            "max_octaves",
        ),
        // A blur of 1e4 px took 37 s on a 48x40 image, 1e9 px aborted on its kernel's
        // allocation and 1e20 px overflowed its size.
        (
            SiftParams {
                sigma: 1e20,
                ..SiftParams::default()
            },
            "sigma 100000000000000000000",
        ),
        (
            SiftParams {
                input_sigma: 1e4,
                ..SiftParams::default()
            },
            "input_sigma",
        ),
        (
            SiftParams {
                n_octave_layers: usize::MAX,
                ..SiftParams::default()
            },
            "n_octave_layers",
        ),
    ] {
        let err = bad.check().unwrap_err().to_string();
        assert!(err.contains(name), "{err}");
        // Built anyway, the detector refuses to run with the same error, at once.
        let err = Sift::new(bad).detect(&g, None).unwrap_err().to_string();
        assert!(err.contains(name), "{err}");
    }
    assert!(SiftParams::default().check().is_ok());
}

/// OpenCV's default doubling samples the input a quarter pixel back and does not undo it, so
/// the same structure is reported a quarter pixel further right and down than on the exact
/// grid (the shift between OpenCV's default and its `enable_precise_upscale`).
#[test]
fn opencv_grid_reports_keypoints_a_quarter_pixel_off() {
    let img = Scene::random(11, 160.0, 120.0, 150).render(160, 120, |u, v| (u, v));
    let exact = Sift::new(SiftParams::default()).detect(&img, None).unwrap();
    let cv = Sift::new(SiftParams {
        upsample_grid: UpsampleGrid::OpenCv,
        ..SiftParams::default()
    })
    .detect(&img, None)
    .unwrap();
    let (mut dx, mut dy) = (Vec::new(), Vec::new());
    for k in &exact.keypoints {
        let near = cv.keypoints.iter().min_by(|a, b| {
            let da = (a.x - k.x).hypot(a.y - k.y);
            let db = (b.x - k.x).hypot(b.y - k.y);
            da.total_cmp(&db)
        });
        if let Some(n) = near
            && (n.x - k.x).hypot(n.y - k.y) < 1.0
            && (n.scale / k.scale - 1.0).abs() < 0.2
        {
            dx.push(n.x - k.x);
            dy.push(n.y - k.y);
        }
    }
    assert!(
        dx.len() * 10 >= exact.len() * 7,
        "{} of {} keypoints paired",
        dx.len(),
        exact.len()
    );
    let median = |v: &mut Vec<f32>| {
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    let (mx, my) = (median(&mut dx), median(&mut dy));
    assert!(
        (mx - 0.25).abs() < 0.08 && (my - 0.25).abs() < 0.08,
        "median shift ({mx}, {my})"
    );
}

/// Orientations and descriptors go to rayon's threads when there are enough extrema; the
/// keypoints, their order and their descriptors must not depend on how many threads there are.
#[test]
fn the_same_features_on_one_thread_and_on_several() {
    let img = Scene::random(5, 160.0, 120.0, 150).render(160, 120, |u, v| (u, v));
    let sift = Sift::new(SiftParams::default());
    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let one = pool(1).install(|| sift.detect(&img, None)).unwrap();
    let three = pool(3).install(|| sift.detect(&img, None)).unwrap();
    assert!(one.len() >= 50, "{} keypoints", one.len());
    assert_eq!(one.keypoints, three.keypoints);
    assert_eq!(one.descriptors, three.descriptors);
}

#[test]
fn angles_and_descriptors_are_well_formed() {
    let img = Scene::random(4, 80.0, 60.0, 40).render(80, 60, |u, v| (u, v));
    let f: Features = Sift::new(SiftParams::default()).detect(&img, None).unwrap();
    assert!(!f.is_empty());
    for (k, d) in f.keypoints.iter().zip(&f.descriptors) {
        assert!((0.0..TAU).contains(&k.angle), "{k:?}");
        assert!(k.response >= 0.04 / 3.0 - 1e-6);
        assert!(k.octave >= -1);
        // Normalised to 512 after clamping at 0.2: the norm is about 512.
        let norm = d.iter().map(|&v| (v as f32).powi(2)).sum::<f32>().sqrt();
        assert!((norm - 512.0).abs() < 8.0, "descriptor norm {norm}");
    }
}
