//! Colour term (CPU twin of `shaders/colour.wgsl`): an 8×8×8 RGB histogram of the pixels inside
//! a particle's ellipse (or, for grayscale footage, a 64-level luma histogram in the same 512
//! bins: [`bin_in`], [`crate::likelihood::LikelihoodParams::colour_bins`]), compared with the
//! model histogram by the Bhattacharyya coefficient.
//!
//! # Pixel set (shared with the GPU; exact but for ties)
//! A pixel `(x, y)` of the frame (integer centre) belongs to an ellipse iff, in `f32`,
//! `dx = x - cx`, `dy = y - cy`, `u = (c*dx + s*dy)/a`, `v = (-s*dx + c*dy)/b` (with
//! `(s, c) = sin_cos(theta)`) satisfy `u*u + v*v <= 1`. (A GPU compiler may fuse those
//! products into multiply-adds, which moves `u*u + v*v` by ulps: a pixel centre whose test is
//! a tie, within a few ulps of 1, can then fall on the other side there; `tests/gpu.rs`
//! allows exactly those.) Only pixels of the frame count, and
//! no others: a scan of the ellipse's bounding box must use a box that contains every pixel
//! passing the test (e.g. widened by one pixel on each side; then the box's own rounding
//! cannot matter). This file finds the same set faster by solving, per row, the quadratic of
//! the ellipse for its span of x (in `f64`), counting the span's interior without a test and
//! deciding only the ends, with the exact `f32` test where `f64` is too close to call
//! ([`for_each_span`]). Equality with the per-pixel test over the whole frame is checked on
//! tens of thousands of random ellipses (`tests::span_matches_brute_force`,
//! `tests/likelihood_cpu.rs`).

use image::RgbImage;

use super::EllipseF32;
use crate::likelihood::{COLOUR_LUMA, HIST_BINS, LikelihoodError};

/// The histogram bin of an RGB pixel: `(r >> 5) * 64 + (g >> 5) * 8 + (b >> 5)`.
#[inline]
pub fn bin_of(r: u8, g: u8, b: u8) -> u16 {
    ((r as u16 >> 5) << 6) | ((g as u16 >> 5) << 3) | (b as u16 >> 5)
}

/// The histogram bin of an RGB pixel under `colour_bins` ([`crate::likelihood::COLOUR_RGB`]
/// or [`crate::likelihood::COLOUR_LUMA`]; the latter: `luma >> 2`, luma the integer
/// `(77 r + 150 g + 29 b + 128) >> 8`).
#[inline]
pub fn bin_in(colour_bins: u32, r: u8, g: u8, b: u8) -> u16 {
    if colour_bins == COLOUR_LUMA {
        let luma = (77 * r as u32 + 150 * g as u32 + 29 * b as u32 + 128) >> 8;
        (luma >> 2) as u16
    } else {
        bin_of(r, g, b)
    }
}

/// The exact `f32` inside test of the pixel centre `(x, y)` against an ellipse with
/// precomputed `(s, c) = sin_cos(theta)`; the definition of the pixel set (see the module
/// documentation). Written in the same operation order as the WGSL twin.
#[inline]
pub fn inside(e: &EllipseF32, s: f32, c: f32, x: i64, y: i64) -> bool {
    let dx = x as f32 - e.cx;
    let dy = y as f32 - e.cy;
    let u = (c * dx + s * dy) / e.a;
    let v = (-s * dx + c * dy) / e.b;
    u * u + v * v <= 1.0
}

/// Calls `f(y, x0, x1)` for every run `x0 ..= x1` of consecutive pixels of row `y` inside
/// the ellipse (rows in increasing order, runs left to right; in practice one run per row),
/// on a `width × height` frame. An ellipse with a non-finite parameter or a non-positive
/// semi-axis has no pixels.
///
/// Per row, `q(x) = u² + v²` is a convex quadratic in `x`, evaluated in `f64` from the same
/// `f32` `sin`/`cos` as the exact test. The `f32` test's rounding moves `q` by less than
/// `16 ε (1 + max(a,b)/min(a,b))` relative (ε = 2⁻²⁴); with the margin `tol` ten times that,
/// pixels with `q < 1 - tol` are inside, those with `q > 1 + tol` outside, and only pixels
/// in the band between get the exact `f32` test. The candidate pixels of a row come from the
/// roots of its quadratic for `q = 1 + tol` (widened by a margin covering their `f64`
/// rounding); by convexity, when the second and the second-to-last candidates are inside by
/// `q64`, so is everything between them, and only the two ends are classified.
pub fn for_each_span(
    e: &EllipseF32,
    width: u32,
    height: u32,
    mut f: impl FnMut(usize, usize, usize),
) {
    if !e.is_valid() || width == 0 || height == 0 {
        return;
    }
    let (s, c) = e.theta.sin_cos();
    let (cx, cy, a, b) = (e.cx as f64, e.cy as f64, e.a as f64, e.b as f64);
    let (s64, c64) = (s as f64, c as f64);
    // u² + v² = qa dx² + qb dx dy + qc dy², expanded from the f32 test's own formula.
    let ia2 = 1.0 / (a * a);
    let ib2 = 1.0 / (b * b);
    let qa = c64 * c64 * ia2 + s64 * s64 * ib2;
    let qb = 2.0 * c64 * s64 * (ia2 - ib2);
    let qc = s64 * s64 * ia2 + c64 * c64 * ib2;
    let tol = 1e-5 * (1.0 + a.max(b) / a.min(b));
    let (lim_in, lim_out) = (1.0 - tol, 1.0 + tol);
    // Half height of the bounding box of q <= lim_out, plus a pixel.
    let hh = ((a * s64).powi(2) + (b * c64).powi(2)).sqrt() * lim_out.sqrt() + 1.0;
    let wmax = width as i64 - 1;
    let hmax = height as i64 - 1;
    let fy0 = (cy - hh).floor();
    let fy1 = (cy + hh).ceil();
    if !(fy1 >= 0.0 && fy0 <= hmax as f64 && qa > 0.0 && qa.is_finite()) {
        return;
    }
    let y0 = clamp_i64(fy0, 0, hmax);
    let y1 = clamp_i64(fy1, 0, hmax);
    let inv_2qa = 0.5 / qa;
    // Bound on the f64 rounding of the roots below, in pixels (the roots' error is about
    // 1e-8 · max(a, b) at a tangent row, far less elsewhere).
    let margin = 1e-3 + 1e-6 * a.max(b);
    let wmax_f = wmax as f64;
    for y in y0..=y1 {
        let dy = y as f64 - cy;
        let bq = qb * dy;
        let cq = qc * dy * dy;
        // Roots of qa dx² + bq dx + cq = lim: the interval of x with q <= lim.
        let xm = cx - bq * inv_2qa;
        let roots = |lim: f64| {
            let disc = bq * bq - 4.0 * qa * (cq - lim);
            (disc >= 0.0).then(|| {
                let half = disc.sqrt() * inv_2qa;
                (xm - half, xm + half)
            })
        };
        // Outer range [lo, hi], widened by the margin: every pixel with q <= lim_out.
        let Some((o0, o1)) = roots(lim_out) else {
            continue;
        };
        let lo = ceil_f64(o0 - margin).max(0.0);
        let hi = floor_f64(o1 + margin).min(wmax_f);
        if lo > hi {
            continue;
        }
        let (lo, hi) = (lo as i64, hi as i64);
        let q64 = |x: i64| {
            let dx = x as f64 - cx;
            (qa * dx + bq) * dx + cq
        };
        // q64 decides away from 1; the exact f32 test only in the band between.
        let classify = |x: i64| {
            let q = q64(x);
            if q < lim_in {
                true
            } else if q > lim_out {
                false
            } else {
                inside(e, s, c, x, y)
            }
        };
        if hi - lo >= 2 && q64(lo + 1) < lim_in && q64(hi - 1) < lim_in {
            // The usual case. q64 is convex along the row, so every pixel strictly between
            // lo and hi has q64 < lim_in: inside. Only the two ends need classifying.
            let l = if classify(lo) { lo } else { lo + 1 };
            let r = if classify(hi) { hi } else { hi - 1 };
            f(y as usize, l as usize, r as usize);
            continue;
        }
        // Short or tangent rows: pixel by pixel, emitting runs.
        let mut run: Option<(i64, i64)> = None;
        for x in lo..=hi {
            if classify(x) {
                match &mut run {
                    Some((_, end)) if *end + 1 == x => *end = x,
                    _ => {
                        if let Some((r0, r1)) = run.take() {
                            f(y as usize, r0 as usize, r1 as usize);
                        }
                        run = Some((x, x));
                    }
                }
            }
        }
        if let Some((r0, r1)) = run {
            f(y as usize, r0 as usize, r1 as usize);
        }
    }
}

/// `floor` without a libm call (the baseline x86-64 target has no rounding instruction);
/// saturating, NaN -> 0.
#[inline]
fn floor_f64(v: f64) -> f64 {
    let t = v as i64;
    t.saturating_sub(((t as f64) > v) as i64) as f64
}

/// `ceil`, as [`floor_f64`].
#[inline]
fn ceil_f64(v: f64) -> f64 {
    let t = v as i64;
    t.saturating_add(((t as f64) < v) as i64) as f64
}

fn clamp_i64(v: f64, lo: i64, hi: i64) -> i64 {
    // NaN clamps to `lo` via the saturating cast of 0; callers reject NaN ellipses first.
    (v.max(lo as f64).min(hi as f64)) as i64
}

/// Per-pixel histogram bins of a frame, computed once per frame so that the per-particle
/// histograms only look bins up.
#[derive(Debug, Clone, Default)]
pub struct BinImage {
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Row-major bins.
    pub bins: Vec<u16>,
}

impl BinImage {
    /// The bins of every pixel of `image` under `colour_bins` ([`bin_in`]).
    pub fn new(image: &RgbImage, colour_bins: u32) -> Self {
        let mut b = Self::default();
        b.fill(image, colour_bins);
        b
    }

    /// Recomputes the bins for `image`, reusing the allocation.
    pub fn fill(&mut self, image: &RgbImage, colour_bins: u32) {
        self.width = image.width();
        self.height = image.height();
        self.bins.clear();
        self.bins.extend(
            crate::frames::rgb_bytes(image)
                .chunks_exact(3)
                .map(|p| bin_in(colour_bins, p[0], p[1], p[2])),
        );
    }
}

/// Integer histogram of the pixels of `image` inside the ellipse, binned under `colour_bins`
/// ([`bin_in`]): `(counts, total)`.
pub fn histogram(image: &RgbImage, e: &EllipseF32, colour_bins: u32) -> ([u32; HIST_BINS], u32) {
    let mut counts = [0u32; HIST_BINS];
    let mut total = 0u32;
    let w = image.width() as usize;
    let raw = image.as_raw();
    for_each_span(e, image.width(), image.height(), |y, x0, x1| {
        let row = &raw[3 * (y * w + x0)..3 * (y * w + x1 + 1)];
        for p in row.chunks_exact(3) {
            counts[bin_in(colour_bins, p[0], p[1], p[2]) as usize] += 1;
        }
        total += (x1 - x0 + 1) as u32;
    });
    (counts, total)
}

/// The counts inside `e` ([`histogram`]) and in the ring between `e` and `outer` (an ellipse
/// containing it): the counts inside `outer` less those inside `e`, bin by bin.
pub fn inside_and_ring(
    image: &RgbImage,
    e: &EllipseF32,
    outer: &EllipseF32,
    colour_bins: u32,
) -> (([u32; HIST_BINS], u32), [u32; HIST_BINS]) {
    let (inner, n) = histogram(image, e, colour_bins);
    let (mut ring, _) = histogram(image, outer, colour_bins);
    for (r, i) in ring.iter_mut().zip(inner) {
        *r = r.saturating_sub(i);
    }
    ((inner, n), ring)
}

/// [`histogram`] from a precomputed [`BinImage`] (same result, faster).
///
/// Neighbouring pixels often fall in one bin, and counting them into one array makes each
/// increment wait for the store of the one before; pixels are counted into four partial
/// histograms in turn and summed at the end (the same counts).
///
/// A `BinImage` whose `bins` are fewer than `width * height` (its fields are public) counts
/// the pixels it holds.
pub fn histogram_bins(bins: &BinImage, e: &EllipseF32, counts: &mut [u32; HIST_BINS]) -> u32 {
    let mut part = [[0u32; HIST_BINS]; 4];
    let mut total = 0u32;
    let w = bins.width as usize;
    for_each_span(e, bins.width, bins.height, |y, x0, x1| {
        let row = bins.bins.get(y * w + x0..=y * w + x1).unwrap_or(&[]);
        let mut quads = row.chunks_exact(4);
        for q in &mut quads {
            // Bins are < 512 by construction; the mask only spares a bounds check.
            part[0][(q[0] & 511) as usize] += 1;
            part[1][(q[1] & 511) as usize] += 1;
            part[2][(q[2] & 511) as usize] += 1;
            part[3][(q[3] & 511) as usize] += 1;
        }
        for &k in quads.remainder() {
            part[0][(k & 511) as usize] += 1;
        }
        total += row.len() as u32;
    });
    for (k, c) in counts.iter_mut().enumerate() {
        *c = part[0][k] + part[1][k] + part[2][k] + part[3][k];
    }
    total
}

/// `Σ_k count_k · L_k` in `f32`, in bin order, zero bins skipped: the sum of the contrast
/// table `table` ([`crate::likelihood::ContrastTable`]) over the pixels the histogram
/// counted. The contrast term is this times
/// [`crate::likelihood::LikelihoodParams::contrast_scale`].
pub fn contrast_sum(counts: &[u32; HIST_BINS], table: &[f32]) -> f32 {
    let mut acc = 0.0f32;
    for (&n, &l) in counts.iter().zip(table) {
        if n != 0 {
            acc += n as f32 * l;
        }
    }
    acc
}

/// The colour model prepared for comparisons: `q` and its `f32` sum in bin order.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// Normalised model histogram `q_k`.
    pub q: Vec<f32>,
    /// `Σ_k q_k`, summed in bin order in `f32`.
    pub q_sum: f32,
}

impl Model {
    /// Prepares a normalised histogram of [`HIST_BINS`] bins.
    pub fn new(q: &[f32]) -> Self {
        let mut q_sum = 0.0f32;
        for &v in q {
            q_sum += v;
        }
        Self {
            q: q.to_vec(),
            q_sum,
        }
    }

    /// The model of a colour histogram given to an engine, after the checks both engines make:
    /// [`HIST_BINS`] bins, none negative or non-finite, and a positive finite sum.
    pub fn checked(q: &[f32]) -> Result<Self, LikelihoodError> {
        if q.len() != HIST_BINS {
            return Err(LikelihoodError::Invalid(format!(
                "colour model has {} bins, expected {HIST_BINS}",
                q.len()
            )));
        }
        if !q.iter().all(|v| v.is_finite() && *v >= 0.0) {
            return Err(LikelihoodError::Invalid(
                "colour model has a negative or non-finite bin".into(),
            ));
        }
        let m = Self::new(q);
        if !(m.q_sum > 0.0 && m.q_sum.is_finite()) {
            return Err(LikelihoodError::Invalid("colour model is empty".into()));
        }
        Ok(m)
    }
}

/// Normalised histogram `p_k = count_k / total` (all zero when `total == 0`).
pub fn normalise(counts: &[u32; HIST_BINS], total: u32) -> Vec<f32> {
    if total == 0 {
        return vec![0.0; HIST_BINS];
    }
    let t = total as f32;
    counts.iter().map(|&c| c as f32 / t).collect()
}

/// Bhattacharyya coefficient `ρ` of the particle's histogram (`counts`, `total`) against the
/// model, in `[0, 1]`.
///
/// `ρ = Σ_k sqrt(p_k q_k) / sqrt(Σ_k p_k · Σ_k q_k)` with `p_k = count_k / total` (`f32`, bin
/// order, zero bins skipped: adding `+0` is exact, so the sum is the one over all bins). The
/// denominator is 1 in exact arithmetic, so this is the spec's `ρ = Σ sqrt(p q)`; in `f32` it
/// cancels the rounding of the two normalisations, so that a histogram compared with itself
/// gives `ρ = 1` exactly (`sqrt(p·p) = p` in IEEE arithmetic). `total == 0`, or an empty
/// model, gives `ρ = 0`. The result is clamped to at most 1.
pub fn bhattacharyya(counts: &[u32; HIST_BINS], total: u32, model: &Model) -> f32 {
    if total == 0 || model.q_sum <= 0.0 || model.q.len() != HIST_BINS {
        return 0.0;
    }
    let t = total as f32;
    let mut rho = 0.0f32;
    let mut p_sum = 0.0f32;
    for (k, &n) in counts.iter().enumerate() {
        if n != 0 {
            let p = n as f32 / t;
            rho += (p * model.q[k]).sqrt();
            p_sum += p;
        }
    }
    (rho / (p_sum * model.q_sum).sqrt()).min(1.0)
}

/// `ln p_colour = -(1 - ρ) / (2 σc²)`.
pub fn log_from_rho(rho: f32, sigma_colour: f32) -> f32 {
    -(1.0 - rho) / (2.0 * sigma_colour * sigma_colour)
}

/// ρ back from `ln p_colour` (the inverse of [`log_from_rho`], in `f64`):
/// `ρ = 1 + 2 σc² ln p_colour`.
pub fn rho_from_log(log: f32, sigma_colour: f32) -> f64 {
    1.0 + 2.0 * (sigma_colour as f64).powi(2) * log as f64
}

/// `ln p_colour` of an ellipse on a frame against the model, with the bins and σc of
/// `params`.
pub fn log_likelihood(
    image: &RgbImage,
    e: &EllipseF32,
    model: &Model,
    params: &crate::likelihood::LikelihoodParams,
) -> f32 {
    let (counts, total) = histogram(image, e, params.colour_bins);
    log_from_rho(bhattacharyya(&counts, total, model), params.sigma_colour)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng, rngs::StdRng};

    use crate::likelihood::COLOUR_RGB;

    fn brute(image: &RgbImage, e: &EllipseF32) -> ([u32; HIST_BINS], u32) {
        brute_in(image, e, COLOUR_RGB)
    }

    /// The histogram by the per-pixel test over the whole frame, each pixel binned by the
    /// spec's formulas (written out here, not [`bin_in`]).
    fn brute_in(image: &RgbImage, e: &EllipseF32, mode: u32) -> ([u32; HIST_BINS], u32) {
        let mut counts = [0u32; HIST_BINS];
        let mut total = 0;
        if !e.is_valid() {
            return (counts, 0);
        }
        let (s, c) = e.theta.sin_cos();
        for y in 0..image.height() {
            for x in 0..image.width() {
                if inside(e, s, c, x as i64, y as i64) {
                    let p = image.get_pixel(x, y).0;
                    let [r, g, b] = p.map(u32::from);
                    let bin = if mode == COLOUR_LUMA {
                        ((77 * r + 150 * g + 29 * b + 128) >> 8) >> 2
                    } else {
                        (r >> 5) * 64 + (g >> 5) * 8 + (b >> 5)
                    };
                    counts[bin as usize] += 1;
                    total += 1;
                }
            }
        }
        (counts, total)
    }

    fn noise_image(w: u32, h: u32, seed: u64) -> RgbImage {
        let mut rng = StdRng::seed_from_u64(seed);
        RgbImage::from_fn(w, h, |_, _| {
            image::Rgb([rng.random(), rng.random(), rng.random()])
        })
    }

    #[test]
    fn fast_floor_and_ceil() {
        for v in [-2.5, -2.0, -0.5, -0.0, 0.0, 0.3, 1.0, 7.9, 1e300, -1e300] {
            assert_eq!(
                floor_f64(v),
                v.floor().clamp(i64::MIN as f64, i64::MAX as f64),
                "{v}"
            );
            assert_eq!(
                ceil_f64(v),
                v.ceil().clamp(i64::MIN as f64, i64::MAX as f64),
                "{v}"
            );
        }
        assert_eq!(floor_f64(f64::NAN), 0.0);
    }

    #[test]
    fn bins_follow_the_spec_formula() {
        assert_eq!(bin_of(0, 0, 0), 0);
        assert_eq!(bin_of(255, 255, 255), 511);
        assert_eq!(bin_of(32, 0, 0), 64);
        assert_eq!(bin_of(0, 64, 0), 16);
        assert_eq!(bin_of(31, 31, 100), 3);
    }

    #[test]
    fn luma_bins_are_the_grey_level_over_four() {
        for v in 0..=255u8 {
            assert_eq!(bin_in(COLOUR_LUMA, v, v, v), u16::from(v >> 2), "{v}");
            assert_eq!(bin_in(COLOUR_RGB, v, v, v), bin_of(v, v, v));
        }
        assert_eq!(bin_in(COLOUR_LUMA, 255, 0, 0), 19); // (77·255 + 128) >> 8 = 77
        assert_eq!(bin_in(COLOUR_LUMA, 0, 0, 255), 7); // 29
    }

    #[test]
    fn span_matches_brute_force() {
        let img = noise_image(37, 29, 1);
        let mut rng = StdRng::seed_from_u64(7);
        for _ in 0..20000 {
            let e = EllipseF32 {
                cx: rng.random_range(-10.0..47.0),
                cy: rng.random_range(-10.0..39.0),
                a: rng.random_range(0.05..30.0),
                b: rng.random_range(0.05..30.0),
                theta: rng.random_range(-4.0..4.0),
            };
            for mode in [COLOUR_RGB, COLOUR_LUMA] {
                let want = brute_in(&img, &e, mode);
                assert_eq!(histogram(&img, &e, mode), want, "{e:?} {mode}");
                let bins = BinImage::new(&img, mode);
                let mut counts = [0; HIST_BINS];
                let t = histogram_bins(&bins, &e, &mut counts);
                assert_eq!((counts, t), want);
            }
        }
    }

    #[test]
    fn integer_and_half_integer_ellipses_match_brute_force() {
        // Pixel centres exactly on the contour are the hard cases for the span solver.
        let img = noise_image(30, 30, 2);
        for a in 1..12 {
            for b in 1..12 {
                for &(cx, cy) in &[(15.0, 15.0), (14.5, 15.5), (0.0, 0.0), (29.5, 3.0)] {
                    for &theta in &[
                        0.0,
                        std::f32::consts::FRAC_PI_2,
                        std::f32::consts::FRAC_PI_4,
                    ] {
                        let e = EllipseF32 {
                            cx,
                            cy,
                            a: a as f32,
                            b: b as f32,
                            theta,
                        };
                        assert_eq!(histogram(&img, &e, COLOUR_RGB), brute(&img, &e), "{e:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn invalid_or_outside_ellipses_are_empty() {
        let img = noise_image(10, 10, 3);
        let mut e = EllipseF32 {
            cx: 5.0,
            cy: 5.0,
            a: 0.0,
            b: 3.0,
            theta: 0.0,
        };
        assert_eq!(histogram(&img, &e, COLOUR_RGB).1, 0);
        e.a = f32::NAN;
        assert_eq!(histogram(&img, &e, COLOUR_RGB).1, 0);
        e.a = 3.0;
        e.cx = 100.0;
        assert_eq!(histogram(&img, &e, COLOUR_RGB).1, 0);
        e.cx = 1e30;
        assert_eq!(histogram(&img, &e, COLOUR_RGB).1, 0);
        e.cx = 5.0;
        e.a = 1e30;
        e.b = 1e30;
        // A huge ellipse covers the frame.
        assert_eq!(histogram(&img, &e, COLOUR_RGB).1, 100);
    }

    #[test]
    fn rho_is_one_against_itself_and_zero_when_disjoint() {
        let img = noise_image(50, 40, 4);
        let mut rng = StdRng::seed_from_u64(5);
        for _ in 0..200 {
            let e = EllipseF32 {
                cx: rng.random_range(0.0..50.0),
                cy: rng.random_range(0.0..40.0),
                a: rng.random_range(1.0..20.0),
                b: rng.random_range(1.0..20.0),
                theta: rng.random_range(-3.0..3.0),
            };
            let (c, t) = histogram(&img, &e, COLOUR_RGB);
            if t == 0 {
                continue;
            }
            let model = Model::new(&normalise(&c, t));
            assert_eq!(bhattacharyya(&c, t, &model), 1.0);
            assert_eq!(log_from_rho(1.0, 0.1), 0.0);
        }
        let mut c1 = [0u32; HIST_BINS];
        c1[3] = 10;
        let mut c2 = [0u32; HIST_BINS];
        c2[4] = 7;
        let m = Model::new(&normalise(&c2, 7));
        assert_eq!(bhattacharyya(&c1, 10, &m), 0.0);
        assert_eq!(bhattacharyya(&c1, 0, &m), 0.0);
        // Half overlap: p = (1/2, 1/2), q = (1, 0) -> rho = sqrt(1/2).
        c1[4] = 10;
        let rho = bhattacharyya(&c1, 20, &m);
        assert!((rho - 0.5f32.sqrt()).abs() < 1e-6, "{rho}");
        // SPEC: ln p_colour = -(1 - rho) / (2 sigma_c^2); at sigma_c 0.3, 2 sigma_c^2 = 0.18 (at
        // 0.5 it would equal sigma_c, and a division by sigma_c alone would pass).
        let expected = -(1.0 - 0.5f64.sqrt()) / 0.18;
        assert!((log_from_rho(rho, 0.3) as f64 - expected).abs() < 1e-5);
        // And back.
        for (r, sc) in [(rho, 0.5), (0.9, 0.1), (0.0, 0.1), (1.0, 0.3)] {
            let back = rho_from_log(log_from_rho(r, sc), sc);
            assert!((back - r as f64).abs() < 1e-6, "{r} {sc}: {back}");
        }
    }
}
