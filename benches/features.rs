//! Benchmarks of the `features` stage (criterion, rayon's global pool set to one thread):
//! SIFT per frame at 160x120, 320x240 and 640x480, SIFT restricted to a tracker's region,
//! matching, and the tracker's per-frame-pair work (SIFT on both frames + matching +
//! slope/length rejection + SEA), on the full frame with and without the doubled first
//! octave and on a tracker's region.
//!
//! Frames are a synthetic textured scene (a sum of Gaussian blobs, fixed seed), so the
//! benches need no data files; the second frame of a pair is the scene moved by
//! (1.5, 0.7) px and turned by 3° (0.5° for the pair benches).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use pftrack::features::{
    Features, MatchParams, PAPER_ANGLE_TOL, PAPER_LENGTH_TOL, Sift, SiftParams, keep_slope_length,
    match_features,
};
use pftrack::frames::GrayF32;
use pftrack::geometry::BoxRect;
use pftrack::pose::{SolverKind, interframe};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// A `w x h` frame of a blob scene scaled to the frame size; `motion` = (dx, dy, angle).
fn frame(w: u32, h: u32, motion: (f32, f32, f32)) -> GrayF32 {
    let mut rng = StdRng::seed_from_u64(42);
    let k = w as f32 / 160.0;
    let blobs: Vec<(f32, f32, f32, f32)> = (0..150)
        .map(|_| {
            (
                rng.random_range(0.0..160.0) * k,
                rng.random_range(0.0..120.0) * k,
                rng.random_range(1.2..4.0) * k,
                rng.random_range(-0.4..0.4),
            )
        })
        .collect();
    let (dx, dy, a) = motion;
    let (c, s) = (a.cos(), a.sin());
    let (ox, oy) = (w as f32 / 2.0, h as f32 / 2.0);
    let mut g = GrayF32::new(w, h);
    for v in 0..h {
        for u in 0..w {
            // Scene point shown at (u, v): inverse of "rotate about the centre, then shift".
            let (px, py) = (u as f32 - dx - ox, v as f32 - dy - oy);
            let (x, y) = (c * px + s * py + ox, -s * px + c * py + oy);
            let mut val = 0.5;
            for &(bx, by, bs, amp) in &blobs {
                let d2 = (x - bx).powi(2) + (y - by).powi(2);
                if d2 < 25.0 * bs * bs {
                    val += amp * (-d2 / (2.0 * bs * bs)).exp();
                }
            }
            g.data[(v * w + u) as usize] = val.clamp(0.0, 1.0);
        }
    }
    g
}

fn bench(c: &mut Criterion) {
    // One thread: SIFT spreads its descriptors over rayon's pool when it has more than one.
    // (Only fails when the global pool already exists, which nothing here does before.)
    let _ = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build_global();
    let sift = Sift::new(SiftParams::default());
    let mut g = c.benchmark_group("sift");
    for (w, h) in [(160, 120), (320, 240), (640, 480)] {
        let img = frame(w, h, (0.0, 0.0, 0.0));
        let n = sift.detect(&img, None).map(|f| f.len()).unwrap_or(0);
        g.bench_function(format!("full/{w}x{h} ({n} kps)"), |b| {
            b.iter(|| sift.detect(black_box(&img), None))
        });
    }
    // A tracker's target: a 48x48 box (a head at 160x120) plus the default margin.
    let img = frame(160, 120, (0.0, 0.0, 0.0));
    let region = BoxRect::new(56.0, 36.0, 48.0, 48.0);
    let n = sift
        .detect(&img, Some(region))
        .map(|f| f.len())
        .unwrap_or(0);
    g.bench_function(format!("region48/160x120 ({n} kps)"), |b| {
        b.iter(|| sift.detect(black_box(&img), Some(region)))
    });
    g.finish();

    let a = frame(160, 120, (0.0, 0.0, 0.0));
    let b2 = frame(160, 120, (1.5, 0.7, 3f32.to_radians()));
    let fa = sift.detect(&a, None).unwrap_or_default();
    let fb = sift.detect(&b2, None).unwrap_or_default();
    let p = MatchParams::default();
    let mut g = c.benchmark_group("match");
    g.bench_function(format!("full/160x120 ({}x{})", fa.len(), fb.len()), |b| {
        b.iter(|| match_features(black_box(&fa), black_box(&fb), &p))
    });
    g.finish();

    // Per frame pair, as the tracker would run it with nothing cached: SIFT on both frames
    // (full, and restricted to the region), matching, slope/length rejection, then the SEA
    // inter-frame rotation (issue 3's target: all of it in <= 5 ms on one core at 160x120).
    // The pair moves by (1.5, 0.7) px and turns by 0.5°, a head's motion between frames:
    // the 3° turn above spreads the displacements past the slope/length bands, leaving SEA
    // too few matches to be representative.
    let b3 = frame(160, 120, (1.5, 0.7, 0.5f32.to_radians()));
    // "full-noup" is the full frame without the doubled first octave (Lowe's octave -1), the
    // option a caller who needs the whole frame at this size can take: it finds fewer, larger
    // keypoints for about a quarter of the pixels.
    let noup = Sift::new(SiftParams {
        upsample: false,
        ..SiftParams::default()
    });
    let mut g = c.benchmark_group("pair");
    for (name, s, reg) in [
        ("full", &sift, None),
        ("full-noup", &noup, None),
        ("region48", &sift, Some(region)),
    ] {
        let (m, k) = pair_work(s, &a, &b3, reg, &p);
        g.bench_function(
            format!("{name}+sea/160x120 ({m} matches, {k} kept)"),
            |bch| bch.iter(|| pair_work(s, black_box(&a), black_box(&b3), reg, &p)),
        );
    }
    // In steady state a tracker has the previous frame's features from the step before: per
    // new frame it pays SIFT once, then matching, rejection and SEA.
    let fa_full = sift.detect(&a, None).unwrap_or_default();
    let (m, k) = pair_work_cached(&sift, &fa_full, &b3, &p);
    g.bench_function(
        format!("full+sea, previous frame cached/160x120 ({m} matches, {k} kept)"),
        |bch| bch.iter(|| pair_work_cached(&sift, black_box(&fa_full), black_box(&b3), &p)),
    );
    g.finish();
}

/// The tracker's work on one frame pair: SIFT on both frames, matching, slope/length
/// rejection and the SEA rotation of the kept matches about the frame (or region) centre.
/// Returns the number of matches and of those kept for SEA (0 kept when SEA failed).
fn pair_work(
    sift: &Sift,
    a: &GrayF32,
    b: &GrayF32,
    reg: Option<BoxRect>,
    p: &MatchParams,
) -> (usize, usize) {
    let fa = sift.detect(a, reg).unwrap_or_default();
    let centre = reg.map_or([f64::from(a.width) / 2.0, f64::from(a.height) / 2.0], |r| {
        [r.x + r.w / 2.0, r.y + r.h / 2.0]
    });
    match_and_sea(&fa, &sift.detect(b, reg).unwrap_or_default(), centre, p)
}

/// [`pair_work`] on the full frame with the first frame's features already detected.
fn pair_work_cached(sift: &Sift, fa: &Features, b: &GrayF32, p: &MatchParams) -> (usize, usize) {
    let fb = sift.detect(b, None).unwrap_or_default();
    let centre = [f64::from(b.width) / 2.0, f64::from(b.height) / 2.0];
    match_and_sea(fa, &fb, centre, p)
}

/// Matching, slope/length rejection and SEA about `centre`: (matches, kept for SEA or 0).
fn match_and_sea(
    fa: &Features,
    fb: &Features,
    centre: [f64; 2],
    p: &MatchParams,
) -> (usize, usize) {
    let m = match_features(fa, fb, p);
    let xy = |k: &pftrack::features::Keypoint| [f64::from(k.x), f64::from(k.y)];
    let pp: Vec<[f64; 2]> = m.iter().map(|m| xy(&fa.keypoints[m.query])).collect();
    let qq: Vec<[f64; 2]> = m.iter().map(|m| xy(&fb.keypoints[m.train])).collect();
    let (pk, qk) = keep_slope_length(&pp, &qq, PAPER_ANGLE_TOL, PAPER_LENGTH_TOL);
    match interframe(&pk, &qk, centre, SolverKind::Sea) {
        Ok(i) => {
            black_box(i);
            (m.len(), pk.len())
        }
        Err(_) => (m.len(), 0),
    }
}

criterion_group! {
    name = benches;
    // Plots need system fonts that a bare machine lacks (criterion panics without them).
    config = Criterion::default().without_plots();
    targets = bench
}
criterion_main!(benches);
