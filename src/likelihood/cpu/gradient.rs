//! Gradient (contour) term (CPU twin of `shaders/gradient.wgsl`): edges along `L` normal lines
//! of the particle's ellipse, scored with the clutter model of SPEC section 3.
//!
//! # Semantics (exact, shared with the GPU)
//! - Gradient image in exact integers: `L = 299 r + 587 g + 114 b`, `gx = L(x+1,y) - L(x-1,y)`,
//!   `gy = L(x,y+1) - L(x,y-1)`, indices clamped to the frame.
//! - Line `k` (of `L = num_lines`): `phi = (2π · k) / L`; contour point and outward unit normal
//!   as `geometry::Ellipse::point_at` / `normal_at`, in `f32`.
//! - Samples `t = -H ..= H`, `H = round(line_half_length)`, at `lambda + t · n`, nearest pixel
//!   `floor(x + 0.5)`; a sample outside the frame (or at a non-finite position) has strength 0.
//!   Strength `g(t) = |gx nx + gy ny| / 510000` (luma per pixel).
//! - Edge at `t` iff `g(t) >= threshold`, `g(t) > g(t-1)`, `g(t) >= g(t+1)`, with `g = 0`
//!   beyond both ends. `d = min |t|` over the edges.
//!
//! # Likelihood of a line
//! `ln p_line = ln(1 + K exp(-d² / (2 σz²)))`, `K = 1 / (sqrt(2π) σz p0 γ)`, and `0` for a
//! line without edges. This is the contour likelihood of MacCormick & Blake with Poisson
//! clutter (density γ) and probability p0 that the contour is not detected, up to a constant
//! factor, keeping only the nearest edge: its leading term is the SPEC's
//! `1/(sqrt(2π) σz p0 γ) exp(-d²/(2σz²))`, and the `1 +` is the floor for a line whose edges
//! are all clutter (or which has none), so that one missing edge cannot veto a particle.
//! `ln p_gradient = Σ_k ln p_line`, always `>= 0`.

use image::RgbImage;

use super::EllipseF32;
use crate::likelihood::{LikelihoodParams, Particle};

/// `2 · 255 · 1000`: turns `gx · n` into luma units per pixel (central difference over 2 px).
pub const STRENGTH_SCALE: f32 = 510000.0;

/// The integer gradient image of a frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GradientImage {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Row-major `(gx, gy)`.
    pub g: Vec<[i32; 2]>,
}

/// `299 r + 587 g + 114 b`: luma × 1000 × 255, exact.
#[inline]
pub fn luma_int(r: u8, g: u8, b: u8) -> u32 {
    299 * r as u32 + 587 * g as u32 + 114 * b as u32
}

impl GradientImage {
    /// The gradient image of `image`.
    pub fn new(image: &RgbImage) -> Self {
        let mut g = Self::default();
        g.fill(image, &mut Vec::new(), false);
        g
    }

    /// Recomputes the gradient for `image`, reusing allocations (`luma` is scratch space);
    /// rows in parallel (rayon, current pool) when `parallel`. Same result either way.
    pub fn fill(&mut self, image: &RgbImage, luma: &mut Vec<u32>, parallel: bool) {
        use rayon::prelude::*;
        let (w, h) = (image.width() as usize, image.height() as usize);
        self.width = w as u32;
        self.height = h as u32;
        luma.clear();
        luma.extend(
            crate::frames::rgb_bytes(image)
                .chunks_exact(3)
                .map(|p| luma_int(p[0], p[1], p[2])),
        );
        self.g.clear();
        self.g.resize(w * h, [0, 0]);
        if w == 0 || h == 0 {
            return;
        }
        let luma = &luma[..];
        let row = |y: usize, out: &mut [[i32; 2]]| {
            let up = &luma[y.saturating_sub(1) * w..][..w];
            let mid = &luma[y * w..][..w];
            let down = &luma[(y + 1).min(h - 1) * w..][..w];
            let g = |xl: usize, x: usize, xr: usize| {
                [
                    mid[xr] as i32 - mid[xl] as i32,
                    down[x] as i32 - up[x] as i32,
                ]
            };
            out[0] = g(0, 0, 1.min(w - 1));
            if w > 1 {
                out[w - 1] = g(w - 2, w - 1, w - 1);
            }
            if w > 2 {
                // Interior: no clamping, written for the vectoriser.
                for (((o, m), u), d) in out[1..w - 1]
                    .iter_mut()
                    .zip(mid.windows(3))
                    .zip(&up[1..w - 1])
                    .zip(&down[1..w - 1])
                {
                    *o = [m[2] as i32 - m[0] as i32, *d as i32 - *u as i32];
                }
            }
        };
        if parallel {
            self.g
                .par_chunks_mut(w)
                .enumerate()
                .for_each(|(y, out)| row(y, out));
        } else {
            self.g
                .chunks_mut(w)
                .enumerate()
                .for_each(|(y, out)| row(y, out));
        }
    }

    /// `(gx, gy)` at a pixel of the frame (`[0, 0]` where `g` holds no such pixel: its
    /// fields are public).
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> [i32; 2] {
        self.g
            .get(y * self.width as usize + x)
            .copied()
            .unwrap_or([0, 0])
    }
}

/// `(cos phi_k, sin phi_k)` of the `L` normal lines, `phi_k = (2π · k) / L` in `f32`.
pub fn line_angles(num_lines: u32) -> Vec<(f32, f32)> {
    (0..num_lines)
        .map(|k| {
            let phi = std::f32::consts::TAU * k as f32 / num_lines as f32;
            let (sp, cp) = phi.sin_cos();
            (cp, sp)
        })
        .collect()
}

/// `H = round(line_half_length)` (half away from zero), at least 0.
pub fn half_samples(params: &LikelihoodParams) -> i32 {
    (params.line_half_length.round().max(0.0) as i32).min(MAX_HALF_SAMPLES)
}

/// Most samples either side of a normal line's contour point the functions here take
/// (`line_half_length` above it, which [`LikelihoodParams::check`] refuses, is taken as
/// this: 1e30 px asked for 8 GB of tables, `h = i32::MAX` overflowed).
pub const MAX_HALF_SAMPLES: i32 = 4096;

/// Contour point and outward unit normal of the ellipse at `(cos phi, sin phi)`, given
/// `(s, c) = sin_cos(theta)`: `(x, y, nx, ny)`.
#[inline]
pub fn contour_point(e: &EllipseF32, s: f32, c: f32, cp: f32, sp: f32) -> (f32, f32, f32, f32) {
    let ex = e.a * cp;
    let ey = e.b * sp;
    let x = e.cx + c * ex - s * ey;
    let y = e.cy + s * ex + c * ey;
    let mx = cp / e.a;
    let my = sp / e.b;
    let n = (mx * mx + my * my).sqrt();
    let mx = mx / n;
    let my = my / n;
    (x, y, c * mx - s * my, s * mx + c * my)
}

/// Edge strength at the nearest pixel of `(x, y)` along `(nx, ny)`; 0 outside the frame.
#[inline]
pub fn strength(grad: &GradientImage, x: f32, y: f32, nx: f32, ny: f32) -> f32 {
    // Nearest pixel floor(x + 0.5): for px >= 0, the truncating cast is the floor, and
    // floor(px) lies in [0, W) iff px does (W an integer). Written so NaN fails the test.
    let px = x + 0.5;
    let py = y + 0.5;
    if !(px >= 0.0 && py >= 0.0 && px < grad.width as f32 && py < grad.height as f32) {
        return 0.0;
    }
    // In range, so the (cheap) i32 cast is exact.
    let [gx, gy] = grad.at(px as i32 as usize, py as i32 as usize);
    (gx as f32 * nx + gy as f32 * ny).abs() / STRENGTH_SCALE
}

/// Edge strength at sample `t` of the line through `(x, y)` along `(nx, ny)`: at
/// `(x + t nx, y + t ny)`, the position both walks along a line ([`line_edge_distance`],
/// [`line_edges`]) sample.
#[inline]
fn line_strength(grad: &GradientImage, x: f32, y: f32, nx: f32, ny: f32, t: i32) -> f32 {
    let tf = t as f32;
    strength(grad, x + tf * nx, y + tf * ny, nx, ny)
}

/// Longest line ([`line_edge_distance`]) whose strengths are gathered on the stack first.
const STACK_SAMPLES: usize = 61;

/// Distance `d = min |t|` to the nearest edge on the line through `(x, y)` along `(nx, ny)`,
/// samples `t = -h ..= h` (`h` taken within `0..=MAX_HALF_SAMPLES`); `None` when the line
/// has no edge.
pub fn line_edge_distance(
    grad: &GradientImage,
    x: f32,
    y: f32,
    nx: f32,
    ny: f32,
    h: i32,
    threshold: f32,
) -> Option<u32> {
    let at = |t: i32| line_strength(grad, x, y, nx, ny, t);
    let h = h.clamp(0, MAX_HALF_SAMPLES);
    let n = (2 * h + 1) as usize;
    if n <= STACK_SAMPLES {
        // Search outwards from the contour, d = 0, 1, 2, ..., and stop at the first edge:
        // the same `min |t|`, usually from a fraction of the samples. Slot i holds
        // t = i - 1 - h; slots 0 and n + 1 are the zeros beyond the ends. Before step d,
        // slots c - d - 1 ..= c + d + 1 are filled (c: the slot of t = 0).
        let mut g = [0.0f32; STACK_SAMPLES + 2];
        let c = (h + 1) as usize;
        let hu = h as usize;
        g[c] = at(0);
        if hu >= 1 {
            g[c - 1] = at(-1);
            g[c + 1] = at(1);
        }
        for d in 0..=hu {
            let l = c - d;
            let cur = g[l];
            if cur >= threshold && cur > g[l - 1] && cur >= g[l + 1] {
                return Some(d as u32);
            }
            let r = c + d;
            let cur = g[r];
            if d > 0 && cur >= threshold && cur > g[r - 1] && cur >= g[r + 1] {
                return Some(d as u32);
            }
            if d + 2 <= hu {
                let t = (d + 2) as i32;
                g[c - d - 2] = at(-t);
                g[c + d + 2] = at(t);
            }
        }
        return None;
    }
    scan_edge_distance(grad, x, y, nx, ny, h, threshold)
}

/// [`line_edge_distance`] by a plain scan over every sample (the definition; used for long
/// lines).
fn scan_edge_distance(
    grad: &GradientImage,
    x: f32,
    y: f32,
    nx: f32,
    ny: f32,
    h: i32,
    threshold: f32,
) -> Option<u32> {
    line_edges(grad, x, y, nx, ny, h, threshold)
        .map(i32::unsigned_abs)
        .min()
}

/// Every edge of the line through `(x, y)` along `(nx, ny)`, samples `t = -h ..= h` (`h`
/// taken within `0..=MAX_HALF_SAMPLES`), as its
/// `t`, in increasing order: the definition of the module's semantics, one pass over the
/// samples.
pub fn line_edges(
    grad: &GradientImage,
    x: f32,
    y: f32,
    nx: f32,
    ny: f32,
    h: i32,
    threshold: f32,
) -> impl Iterator<Item = i32> + '_ {
    let at = move |t: i32| line_strength(grad, x, y, nx, ny, t);
    let h = h.clamp(0, MAX_HALF_SAMPLES);
    let mut t = -h;
    let mut prev = 0.0f32;
    let mut cur = at(-h);
    std::iter::from_fn(move || {
        while t <= h {
            let next = if t < h { at(t + 1) } else { 0.0 };
            let edge = cur >= threshold && cur > prev && cur >= next;
            let here = t;
            prev = cur;
            cur = next;
            t += 1;
            if edge {
                return Some(here);
            }
        }
        None
    })
}

/// The per-line edge distances of an ellipse (`None`: no edge on that line), in line order.
pub fn edge_distances_ellipse(
    grad: &GradientImage,
    e: &EllipseF32,
    params: &LikelihoodParams,
) -> Vec<Option<u32>> {
    let (s, c) = e.theta.sin_cos();
    let h = half_samples(params);
    line_angles(params.num_lines)
        .into_iter()
        .map(|(cp, sp)| {
            let (x, y, nx, ny) = contour_point(e, s, c, cp, sp);
            line_edge_distance(grad, x, y, nx, ny, h, params.edge_threshold)
        })
        .collect()
}

/// The per-line edge distances of a particle (ellipse turned by `theta0 + rz`).
pub fn edge_distances(
    grad: &GradientImage,
    particle: &Particle,
    theta0: f32,
    params: &LikelihoodParams,
) -> Vec<Option<u32>> {
    edge_distances_ellipse(grad, &EllipseF32::from_particle(particle, theta0), params)
}

/// `K = 1 / (sqrt(2π) σz p0 γ)`, evaluated as `1 / (((sqrt(2π) σz) p0) γ)`.
pub fn clutter_gain(params: &LikelihoodParams) -> f32 {
    let sqrt_2pi = (2.0 * std::f32::consts::PI).sqrt();
    1.0 / (sqrt_2pi * params.sigma_z * params.p_no_contour * params.clutter_density)
}

/// `ln p_line` of a line whose nearest edge is at distance `d` (`None`: no edge -> 0).
#[inline]
pub fn line_log(d: Option<u32>, k_gain: f32, sigma_z: f32) -> f32 {
    match d {
        None => 0.0,
        Some(d) => {
            let d = d as f32;
            (1.0 + k_gain * (-(d * d) / (2.0 * sigma_z * sigma_z)).exp()).ln()
        }
    }
}

/// What the gradient term needs per frame besides the image: the line directions and
/// `ln p_line` for every possible distance `d = 0 ..= H` (exactly [`line_log`]'s values).
#[derive(Debug, Clone, PartialEq)]
pub struct LineTables {
    /// `(cos phi_k, sin phi_k)` ([`line_angles`]).
    pub angles: Vec<(f32, f32)>,
    /// `ln p_line` for `d = 0 ..= H`.
    pub logs: Vec<f32>,
    /// `H`.
    pub h: i32,
}

impl LineTables {
    /// The tables for `params`.
    pub fn new(params: &LikelihoodParams) -> Self {
        let h = half_samples(params);
        let k_gain = clutter_gain(params);
        Self {
            // As many as `LikelihoodParams::check` allows (2^32 wanted 34 GB).
            angles: line_angles(params.num_lines.min(4096)),
            logs: (0..=h as u32)
                .map(|d| line_log(Some(d), k_gain, params.sigma_z))
                .collect(),
            h,
        }
    }
}

/// `ln p_gradient` of an ellipse, with the per-frame [`LineTables`]; lines summed in order.
pub fn log_likelihood_ellipse(
    grad: &GradientImage,
    e: &EllipseF32,
    tables: &LineTables,
    params: &LikelihoodParams,
) -> f32 {
    let (s, c) = e.theta.sin_cos();
    let mut sum = 0.0f32;
    for &(cp, sp) in &tables.angles {
        let (x, y, nx, ny) = contour_point(e, s, c, cp, sp);
        if let Some(d) = line_edge_distance(grad, x, y, nx, ny, tables.h, params.edge_threshold) {
            sum += tables.logs.get(d as usize).copied().unwrap_or(0.0);
        }
    }
    sum
}

/// `ln p_gradient` of a particle (ellipse turned by `theta0 + rz`).
pub fn log_likelihood(
    grad: &GradientImage,
    particle: &Particle,
    theta0: f32,
    params: &LikelihoodParams,
) -> f32 {
    log_likelihood_ellipse(
        grad,
        &EllipseF32::from_particle(particle, theta0),
        &LineTables::new(params),
        params,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ellipse;

    #[test]
    fn integer_gradient_of_a_3x3_image() {
        // Channels equal: L = 1000 v.
        let v = [[0u8, 10, 20], [30, 40, 50], [60, 70, 200]];
        let img = RgbImage::from_fn(3, 3, |x, y| {
            let c = v[y as usize][x as usize];
            image::Rgb([c, c, c])
        });
        let g = GradientImage::new(&img);
        let l = |x: usize, y: usize| 1000 * v[y][x] as i32;
        // centre: central differences
        assert_eq!(g.at(1, 1), [l(2, 1) - l(0, 1), l(1, 2) - l(1, 0)]);
        assert_eq!(g.at(1, 1), [20000, 60000]);
        // corners: replicated edges
        assert_eq!(g.at(0, 0), [10000, 30000]);
        assert_eq!(g.at(2, 2), [130000, 150000]);
        assert_eq!(g.at(2, 0), [10000, 30000]);
        // A coloured pixel: 299*255 = 76245 on the red channel alone.
        let mut img = RgbImage::new(3, 1);
        img.put_pixel(2, 0, image::Rgb([255, 0, 0]));
        let g = GradientImage::new(&img);
        assert_eq!(g.at(1, 0), [76245, 0]);
        assert_eq!(g.at(2, 0), [76245, 0]); // L(2) - L(1), x + 1 clamped
        assert_eq!(g.at(0, 0), [0, 0]);
    }

    #[test]
    fn gradient_matches_the_clamped_definition_on_any_size() {
        let mut seed = 1u32;
        for (w, h) in [(1, 1), (1, 5), (5, 1), (2, 2), (3, 7), (17, 9)] {
            let img = RgbImage::from_fn(w, h, |_, _| {
                seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
                let b = seed.to_le_bytes();
                image::Rgb([b[1], b[2], b[3]])
            });
            let l = |x: i64, y: i64| {
                let p = img.get_pixel(
                    x.clamp(0, w as i64 - 1) as u32,
                    y.clamp(0, h as i64 - 1) as u32,
                );
                luma_int(p[0], p[1], p[2]) as i32
            };
            for parallel in [false, true] {
                let mut g = GradientImage::default();
                g.fill(&img, &mut Vec::new(), parallel);
                for y in 0..h as i64 {
                    for x in 0..w as i64 {
                        let want = [l(x + 1, y) - l(x - 1, y), l(x, y + 1) - l(x, y - 1)];
                        assert_eq!(g.at(x as usize, y as usize), want, "{w}x{h} at ({x}, {y})");
                    }
                }
            }
        }
    }

    #[test]
    fn contour_point_matches_geometry() {
        let e64 = Ellipse {
            cx: 40.0,
            cy: 30.0,
            a: 15.0,
            b: 9.0,
            theta: 0.7,
        };
        let e = EllipseF32::from_ellipse(&e64);
        let (s, c) = e.theta.sin_cos();
        for (k, (cp, sp)) in line_angles(16).into_iter().enumerate() {
            let phi = std::f64::consts::TAU * k as f64 / 16.0;
            let (x, y, nx, ny) = contour_point(&e, s, c, cp, sp);
            let (px, py) = e64.point_at(phi);
            let (qx, qy) = e64.normal_at(phi);
            assert!((x as f64 - px).abs() < 1e-4 && (y as f64 - py).abs() < 1e-4);
            assert!((nx as f64 - qx).abs() < 1e-5 && (ny as f64 - qy).abs() < 1e-5);
        }
    }

    #[test]
    fn edges_are_local_maxima_above_threshold() {
        // A vertical step at x = 10 | 11 in a 21-px-wide strip: gradient at x = 10 and 11.
        let img = RgbImage::from_fn(21, 3, |x, _| {
            if x <= 10 {
                image::Rgb([0, 0, 0])
            } else {
                image::Rgb([255, 255, 255])
            }
        });
        let g = GradientImage::new(&img);
        // Line along +x from x = 5: samples x = 5 + t, t in -3..=8 -> edges at x 10, 11:
        // equal strengths, the first one (t = 5) is the maximum (> left, >= right).
        assert_eq!(line_edge_distance(&g, 5.0, 1.0, 1.0, 0.0, 8, 0.1), Some(5));
        // Along -x from x = 15: samples x = 15 - t; x = 11 (t = 4) comes first.
        assert_eq!(
            line_edge_distance(&g, 15.0, 1.0, -1.0, 0.0, 8, 0.1),
            Some(4)
        );
        // Too short a line.
        assert_eq!(line_edge_distance(&g, 5.0, 1.0, 1.0, 0.0, 4, 0.1), None);
        // Threshold above the strength (1000 * 255 / 510000 = 0.5).
        assert_eq!(line_edge_distance(&g, 5.0, 1.0, 1.0, 0.0, 8, 0.51), None);
        assert_eq!(line_edge_distance(&g, 5.0, 1.0, 1.0, 0.0, 8, 0.5), Some(5));
        // Perpendicular line: no gradient along it.
        assert_eq!(line_edge_distance(&g, 5.0, 1.0, 0.0, 1.0, 8, 0.1), None);
        // An edge at the very end of the line compares against 0 beyond it.
        assert_eq!(line_edge_distance(&g, 5.0, 1.0, 1.0, 0.0, 5, 0.1), Some(5));
        // Entirely outside the frame: nothing.
        assert_eq!(line_edge_distance(&g, -50.0, 1.0, 1.0, 0.0, 8, 0.0), None);
        assert_eq!(
            line_edge_distance(&g, f32::NAN, 1.0, 1.0, 0.0, 8, 0.0),
            None
        );
    }

    #[test]
    fn outward_search_equals_the_full_scan() {
        let img = RgbImage::from_fn(120, 90, |x, y| {
            let v = ((x * 37 + y * 11 + (x * y) % 13) % 97) as u8;
            image::Rgb([v, v / 2, 255 - v])
        });
        let g = GradientImage::new(&img);
        let mut found = 0;
        for k in 0..400 {
            let (x, y) = (-10.0 + k as f32 * 0.37, 20.0 + (k % 17) as f32 * 3.1);
            let ang = k as f32 * 0.7;
            let (nx, ny) = (ang.cos(), ang.sin());
            for h in [0, 1, 2, 5, 8, 13, 30] {
                for thr in [0.0, 0.02, 0.1, 0.3] {
                    let a = line_edge_distance(&g, x, y, nx, ny, h, thr);
                    let b = scan_edge_distance(&g, x, y, nx, ny, h, thr);
                    assert_eq!(a, b, "line {k} h {h} thr {thr}");
                    found += a.is_some() as usize;
                }
            }
        }
        assert!(found > 1000, "{found}");
        // Long lines take the scan.
        assert!(line_edge_distance(&g, 60.0, 45.0, 1.0, 0.0, 40, 0.05).is_some());
    }

    #[test]
    fn line_log_peaks_at_the_contour() {
        let p = LikelihoodParams::default();
        let k = clutter_gain(&p);
        assert_eq!(line_log(None, k, p.sigma_z), 0.0);
        let l0 = line_log(Some(0), k, p.sigma_z);
        assert!((l0 - (1.0 + k).ln()).abs() < 1e-6);
        let l3 = line_log(Some(3), k, p.sigma_z);
        assert!(l0 > l3 && l3 > 0.0);
        // Known answers (SPEC section 3) with numbers of their own, where a missing 2, a σz
        // in place of σz² or a dropped factor of the clutter gain would show:
        // k = 1 / (sqrt(2π) σz p0 γ) = 1 / (sqrt(2π) · 2 · 0.1 · 0.05).
        let q = LikelihoodParams {
            sigma_z: 2.0,
            p_no_contour: 0.1,
            clutter_density: 0.05,
            ..LikelihoodParams::default()
        };
        let k = clutter_gain(&q);
        let expected_k = 1.0 / ((2.0 * std::f64::consts::PI).sqrt() * 0.01);
        assert!((k as f64 / expected_k - 1.0).abs() < 1e-6, "{k}");
        // ln(1 + k exp(-d² / (2 σz²))) at d = 3: exp(-9 / 8).
        let l3 = line_log(Some(3), k, 2.0) as f64;
        let expected = (1.0 + expected_k * (-9.0f64 / 8.0).exp()).ln();
        assert!((l3 - expected).abs() < 1e-5, "{l3} against {expected}");
    }
}
