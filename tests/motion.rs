//! Adaptive block matching on synthetic textures with known motion and on real footage.

mod shared_data;

use std::path::Path;

use pftrack::frames::GrayF32;
use pftrack::geometry::Ellipse;
use pftrack::io::read_otb_boxes;
use pftrack::motion::{AbmParams, BlockStatus, Fallback, MotionError, block_match, fit_ellipse};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// A smooth random texture: value noise on a 3-px lattice, bilinear between lattice nodes,
/// defined everywhere so shifted and scaled copies can be sampled exactly.
struct Texture {
    n: usize,
    v: Vec<f32>,
}

impl Texture {
    fn new(seed: u64) -> Self {
        let n = 128;
        let mut rng = StdRng::seed_from_u64(seed);
        let v = (0..n * n).map(|_| rng.random_range(0.0..1.0)).collect();
        Self { n, v }
    }

    fn at(&self, x: f64, y: f64) -> f32 {
        let (gx, gy) = (x / 3.0 + 10.0, y / 3.0 + 10.0);
        let (x0, y0) = (gx.floor(), gy.floor());
        let (fx, fy) = ((gx - x0) as f32, (gy - y0) as f32);
        let g = |i: f64, j: f64| {
            let i = (i as i64).rem_euclid(self.n as i64) as usize;
            let j = (j as i64).rem_euclid(self.n as i64) as usize;
            self.v[j * self.n + i]
        };
        let top = g(x0, y0) * (1.0 - fx) + g(x0 + 1.0, y0) * fx;
        let bot = g(x0, y0 + 1.0) * (1.0 - fx) + g(x0 + 1.0, y0 + 1.0) * fx;
        top * (1.0 - fy) + bot * fy
    }

    /// An image whose pixel `(x, y)` shows the texture at `map(x, y)`.
    fn render(&self, w: u32, h: u32, map: impl Fn(f64, f64) -> (f64, f64)) -> GrayF32 {
        let mut g = GrayF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let (u, v) = map(x as f64, y as f64);
                g.data[(y * w + x) as usize] = self.at(u, v);
            }
        }
        g
    }
}

#[test]
fn integer_shift_gives_exact_translation_and_unit_scale() {
    let tex = Texture::new(1);
    let prev = tex.render(160, 120, |x, y| (x, y));
    let region = Ellipse::new(80.0, 60.0, 20.0, 20.0);
    for (k, &(dx, dy)) in [(3, -2), (0, 0), (-7, 5), (10, 10), (-1, -9)]
        .iter()
        .enumerate()
    {
        let cur = tex.render(160, 120, |x, y| (x - dx as f64, y - dy as f64));
        let mut r = region;
        r.theta = 0.3 * k as f64; // any orientation
        r.b = 14.0 + 2.0 * k as f64;
        let res = block_match(&prev, &cur, &r, &AbmParams::default()).unwrap();
        assert!(res.is_fitted(), "{:?}", res.fallback);
        assert!(
            (res.translation[0] - dx as f64).abs() < 1e-9
                && (res.translation[1] - dy as f64).abs() < 1e-9,
            "shift ({dx},{dy}) -> {:?}",
            res.translation
        );
        assert!((res.scale - 1.0).abs() < 1e-9, "{}", res.scale);
        assert_eq!(res.median_displacement, [dx as f64, dy as f64]);
        assert!(res.matched_fraction > 0.95, "{}", res.matched_fraction);
        assert!((res.ellipse.cx - (r.cx + dx as f64)).abs() < 1e-9);
        assert!((res.ellipse.a - r.a).abs() < 1e-9 && res.ellipse.theta == r.theta);
        // The mask is the region's blocks moved by the shift.
        let m = res.mask(160, 120);
        assert_eq!(m[(60 + dy) as usize * 160 + (80 + dx) as usize], 1);
        assert_eq!(m[0], 0);
    }
}

#[test]
fn scale_change_is_recovered() {
    let tex = Texture::new(2);
    let prev = tex.render(160, 120, |x, y| (x, y));
    let (cx, cy) = (80.0, 60.0);
    for &s in &[1.1, 0.9] {
        // Frame t shows the texture enlarged by s about (cx, cy), then moved by (2, -1).
        let cur = tex.render(160, 120, |x, y| {
            (cx + (x - 2.0 - cx) / s, cy + (y + 1.0 - cy) / s)
        });
        let region = Ellipse::new(cx, cy, 20.0, 20.0);
        let res = block_match(&prev, &cur, &region, &AbmParams::default()).unwrap();
        assert!(res.is_fitted(), "{:?}", res.fallback);
        assert!(
            (res.scale - s).abs() < 0.03 * s,
            "scale {s}: got {}",
            res.scale
        );
        assert!(
            (res.translation[0] - 2.0).abs() < 0.5 && (res.translation[1] + 1.0).abs() < 0.5,
            "{:?}",
            res.translation
        );
        assert!((res.ellipse.a - 20.0 * res.scale).abs() < 1e-9);
    }
}

#[test]
fn flat_region_is_flagged_not_a_panic() {
    let mut prev = GrayF32::new(128, 96);
    prev.data.fill(0.5);
    let cur = prev.clone();
    let region = Ellipse::new(64.0, 48.0, 20.0, 20.0);
    let res = block_match(&prev, &cur, &region, &AbmParams::default()).unwrap();
    assert_eq!(res.matched_fraction, 0.0);
    assert_eq!(res.fallback, Some(Fallback::NoMatchedBlocks));
    assert_eq!(res.translation, [0.0, 0.0]);
    assert_eq!(res.scale, 1.0);
    assert!(res.blocks.iter().all(|b| b.status == BlockStatus::Flat));
    // Split down to the minimum block size before giving up.
    assert!(res.blocks.iter().all(|b| b.w == 4 && b.h == 4));

    // Half textured: the flat half is rejected, the textured half still matches.
    let tex = Texture::new(3);
    let prev = tex.render(128, 96, |x, y| (x, y));
    let cur = tex.render(128, 96, |x, y| (x - 2.0, y));
    let mut prev_half = prev.clone();
    let mut cur_half = cur.clone();
    for y in 0..96 {
        for x in 0..64 {
            prev_half.data[y * 128 + x] = 0.5;
            cur_half.data[y * 128 + x] = 0.5;
        }
    }
    let res = block_match(&prev_half, &cur_half, &region, &AbmParams::default()).unwrap();
    assert!(
        res.matched_fraction > 0.2 && res.matched_fraction < 0.7,
        "{}",
        res.matched_fraction
    );
    assert_eq!(res.median_displacement, [2.0, 0.0]);
}

#[test]
fn region_partly_outside_is_clipped_and_wholly_outside_is_an_error() {
    let tex = Texture::new(4);
    let prev = tex.render(128, 96, |x, y| (x, y));
    let cur = tex.render(128, 96, |x, y| (x - 3.0, y - 1.0));
    // Centre near the left edge: a third of the region is outside the frame.
    let region = Ellipse::new(8.0, 50.0, 20.0, 20.0);
    let res = block_match(&prev, &cur, &region, &AbmParams::default()).unwrap();
    assert!(
        res.blocks
            .iter()
            .all(|b| b.x >= 0 && b.x as u32 + b.w <= 128)
    );
    assert!(
        (res.translation[0] - 3.0).abs() < 1e-9 && (res.translation[1] - 1.0).abs() < 1e-9,
        "{:?} {:?}",
        res.translation,
        res.fallback
    );
    let far = Ellipse::new(-100.0, 50.0, 20.0, 20.0);
    assert_eq!(
        block_match(&prev, &cur, &far, &AbmParams::default()),
        Err(MotionError::RegionOutside)
    );
    let far = Ellipse::new(64.0, 1e300, 20.0, 20.0);
    assert_eq!(
        block_match(&prev, &cur, &far, &AbmParams::default()),
        Err(MotionError::RegionOutside)
    );
    let tiny = Ellipse::new(64.0, 48.0, 1.0, 1.0);
    assert_eq!(
        block_match(&prev, &cur, &tiny, &AbmParams::default()),
        Err(MotionError::RegionTooSmall)
    );
    let bad = Ellipse::new(64.0, 48.0, 0.0, 20.0);
    assert_eq!(
        block_match(&prev, &cur, &bad, &AbmParams::default()),
        Err(MotionError::InvalidRegion)
    );
    let small = GrayF32::new(64, 48);
    assert!(matches!(
        block_match(&prev, &small, &region, &AbmParams::default()),
        Err(MotionError::FrameSize(..))
    ));
}

#[test]
fn block_match_result_is_an_abm_result_struct() {
    // Compile-time check of the public field set the tracker relies on.
    let tex = Texture::new(5);
    let prev = tex.render(96, 96, |x, y| (x, y));
    let res = block_match(
        &prev,
        &prev,
        &Ellipse::new(48.0, 48.0, 16.0, 22.0),
        &AbmParams::default(),
    )
    .unwrap();
    let pftrack::motion::AbmResult {
        ellipse,
        translation,
        scale,
        blocks,
        matched_fraction,
        median_displacement,
        fallback,
    } = res;
    assert_eq!(translation, [0.0, 0.0]);
    assert_eq!(median_displacement, [0.0, 0.0]);
    assert!((scale - 1.0).abs() < 1e-12 && fallback.is_none());
    assert!((ellipse.b - 22.0).abs() < 1e-9);
    assert!(matched_fraction > 0.95 && !blocks.is_empty());
}

#[test]
fn marked_points_fit_an_init_ellipse() {
    // "--init-points": a handful of clicks around a head.
    let pts = [
        [60.0, 20.0],
        [75.0, 30.0],
        [78.0, 45.0],
        [70.0, 62.0],
        [58.0, 66.0],
        [45.0, 55.0],
        [42.0, 38.0],
        [48.0, 24.0],
    ];
    let e = fit_ellipse(&pts).unwrap();
    assert!(
        (e.cx - 60.0).abs() < 3.0 && (e.cy - 43.0).abs() < 3.0,
        "{e:?}"
    );
    assert!(
        e.b > e.a && e.theta.abs() < std::f64::consts::FRAC_PI_4 + 1e-12,
        "{e:?}"
    );
}

fn girl_dir() -> Option<std::path::PathBuf> {
    shared_data::path("girl")
}

fn load_gray(path: &Path) -> GrayF32 {
    GrayF32::from_rgb(&image::open(path).unwrap().to_rgb8())
}

#[test]
fn girl_translation_follows_ground_truth() {
    let Some(dir) = girl_dir() else { return };
    let boxes = read_otb_boxes(&dir.join("groundtruth_rect.txt")).unwrap();
    let mut prev = load_gray(&dir.join("img/0001.jpg"));
    let mut errs = Vec::new();
    for t in 1..20usize {
        let cur = load_gray(&dir.join(format!("img/{:04}.jpg", t + 1)));
        let e0 = Ellipse::from_box(&boxes[t - 1]);
        let e1 = Ellipse::from_box(&boxes[t]);
        let res = block_match(&prev, &cur, &e0, &AbmParams::for_target(&e0)).unwrap();
        let gt = [e1.cx - e0.cx, e1.cy - e0.cy];
        let err = (res.translation[0] - gt[0]).hypot(res.translation[1] - gt[1]);
        errs.push((
            t,
            err,
            res.translation,
            gt,
            res.fallback,
            res.matched_fraction,
        ));
        prev = cur;
    }
    let mean = errs.iter().map(|e| e.1).sum::<f64>() / errs.len() as f64;
    let worst = errs.iter().map(|e| e.1).fold(0.0, f64::max);
    // The boxes are hand-drawn (their height jumps by 2 px between frames, moving the centre
    // by 1 px on its own): "a couple of pixels" per frame, about one on average.
    assert!(
        worst < 3.0 && mean < 1.5,
        "mean {mean} worst {worst}: {errs:#?}"
    );

    // Chained: block matching alone, from its own previous estimate, stays on the head.
    let mut region = Ellipse::from_box(&boxes[0]);
    let mut prev = load_gray(&dir.join("img/0001.jpg"));
    for t in 1..20usize {
        let cur = load_gray(&dir.join(format!("img/{:04}.jpg", t + 1)));
        let res = block_match(&prev, &cur, &region, &AbmParams::for_target(&region)).unwrap();
        region = res.ellipse;
        prev = cur;
    }
    let gt = Ellipse::from_box(&boxes[19]);
    let drift = (region.cx - gt.cx).hypot(region.cy - gt.cy);
    assert!(drift < 3.0, "after 19 frames: {region:?} vs {gt:?}");
    assert!((region.a / gt.a - 1.0).abs() < 0.2 && (region.b / gt.b - 1.0).abs() < 0.2);
}
