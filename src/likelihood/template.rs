//! The appearance-template term: the normalised cross-correlation (NCC) between the grey
//! levels inside a particle's ellipse and a template of the target, sampled on the same
//! grid of the ellipse's own coordinates. The project's addition to the paper's three terms
//! (like the contrast term), evaluated on the CPU for every likelihood engine: it needs only
//! the frame's grey image, which the tracker has anyway, and costs about 200 bilinear samples
//! per particle.
//!
//! Why: the colour and contrast terms see a histogram, not where its pixels lie, so on
//! grayscale footage a patch of dark foliage scores like a dark car. On OTB car4, frames
//! 444-480 (the camera pans, the background streams past the car), the histogram terms
//! preferred the trees beside the car over the car by 10-60 in log-likelihood. A template
//! keeps the layout: the car's rear (window, plate, lights) correlates with itself, not with
//! leaves. NCC is also blind to a gain and an offset of the grey levels, so it survives the
//! changes of light the colour model cannot follow.
//!
//! The grid: `grid x grid` points `(u, v)` on `[-1, 1]²` (cell centres), those with
//! `u² + v² <= 1` kept, mapped to the image by the ellipse, `centre + Rθ (a u, b v)` with
//! `θ = theta0 + rz` (the orientation the ellipse is drawn with): the template turns and
//! scales with the ellipse.

use crate::frames::GrayF32;
use crate::likelihood::Particle;

/// The sample grid in the ellipse's unit disk: `grid x grid` cell centres on `[-1, 1]²` that
/// lie inside the unit circle, in row-major order.
pub fn disk_grid(grid: usize) -> Vec<[f32; 2]> {
    let g = grid.max(1);
    let mut pts = Vec::with_capacity(g * g);
    for j in 0..g {
        let v = (2.0 * j as f32 + 1.0) / g as f32 - 1.0;
        for i in 0..g {
            let u = (2.0 * i as f32 + 1.0) / g as f32 - 1.0;
            if u * u + v * v <= 1.0 {
                pts.push([u, v]);
            }
        }
    }
    pts
}

/// The grey levels of `gray` at the grid points `pts` of the ellipse of particle `p`
/// (orientation `theta0 + p.rz`), bilinear, edges replicated; into `out` (cleared first).
pub fn sample(gray: &GrayF32, p: &Particle, theta0: f32, pts: &[[f32; 2]], out: &mut Vec<f32>) {
    out.clear();
    let (s, c) = (theta0 + p.rz).sin_cos();
    out.extend(pts.iter().map(|&[u, v]| {
        let (x, y) = (p.a * u, p.b * v);
        gray.sample(p.cx + c * x - s * y, p.cy + s * x + c * y)
    }));
}

/// `values` made zero-mean and unit-norm in place; `false` (and all zeros) when they are flat
/// (their spread below `1e-6` per sample), which no template can correlate with.
pub fn normalise(values: &mut [f32]) -> bool {
    let n = values.len().max(1) as f64;
    let mean = values.iter().map(|&v| v as f64).sum::<f64>() / n;
    let ss: f64 = values.iter().map(|&v| (v as f64 - mean).powi(2)).sum();
    if ss.sqrt() < 1e-6 * n.sqrt() {
        values.iter_mut().for_each(|v| *v = 0.0);
        return false;
    }
    let k = 1.0 / ss.sqrt();
    values
        .iter_mut()
        .for_each(|v| *v = ((*v as f64 - mean) * k) as f32);
    true
}

/// The target's template: the mean grey levels at the grid points over the frames it has
/// learnt from, and their normalised form that the correlation uses.
#[derive(Debug, Clone, PartialEq)]
pub struct Template {
    pts: Vec<[f32; 2]>,
    raw: Vec<f32>,
    unit: Vec<f32>,
    usable: bool,
}

impl Template {
    /// The template of the target as particle `p` shows it in `gray`, on a `grid x grid` grid.
    pub fn new(gray: &GrayF32, p: &Particle, theta0: f32, grid: usize) -> Self {
        let pts = disk_grid(grid);
        let mut raw = Vec::new();
        sample(gray, p, theta0, &pts, &mut raw);
        let mut t = Self {
            pts,
            raw,
            unit: Vec::new(),
            usable: false,
        };
        t.refresh();
        t
    }

    fn refresh(&mut self) {
        self.unit.clone_from(&self.raw);
        self.usable = normalise(&mut self.unit);
    }

    /// Whether the template has any contrast to correlate with (a flat target has none).
    pub fn is_usable(&self) -> bool {
        self.usable
    }

    /// Moves the template a share `rate` (in `[0, 1]`) of the way towards what particle `p`
    /// shows in `gray`: `T ← (1 − rate) T + rate S`.
    pub fn blend_towards(&mut self, gray: &GrayF32, p: &Particle, theta0: f32, rate: f32) {
        let mut seen = Vec::with_capacity(self.pts.len());
        sample(gray, p, theta0, &self.pts, &mut seen);
        let r = rate.clamp(0.0, 1.0);
        for (t, s) in self.raw.iter_mut().zip(seen) {
            *t += r * (s - *t);
        }
        self.refresh();
    }

    /// The NCC in `[-1, 1]` of each particle's grey levels with the template, into `out`
    /// (one per particle, in order); 0 for a flat patch or an unusable template.
    pub fn correlate(
        &self,
        gray: &GrayF32,
        particles: &[Particle],
        theta0: f32,
        out: &mut Vec<f32>,
    ) {
        use rayon::prelude::*;
        out.clear();
        if !self.usable {
            out.resize(particles.len(), 0.0);
            return;
        }
        // Each particle's correlation is its own: the same on any number of threads.
        let n = self.pts.len();
        particles
            .par_iter()
            .map_init(
                || Vec::with_capacity(n),
                |buf, p| {
                    sample(gray, p, theta0, &self.pts, buf);
                    if !normalise(buf) {
                        return 0.0;
                    }
                    let d: f64 = buf
                        .iter()
                        .zip(&self.unit)
                        .map(|(&a, &b)| a as f64 * b as f64)
                        .sum();
                    d.clamp(-1.0, 1.0) as f32
                },
            )
            .collect_into_vec(out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn particle(cx: f32, cy: f32, a: f32, b: f32, rz: f32) -> Particle {
        Particle {
            cx,
            cy,
            a,
            b,
            rz,
            ..Particle::default()
        }
    }

    /// A smooth, structured test image: no two 20-px patches alike.
    fn scene(w: u32, h: u32) -> GrayF32 {
        let mut g = GrayF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let (xf, yf) = (x as f32, y as f32);
                g.data[(y * w + x) as usize] = 0.5
                    + 0.2 * (0.21 * xf).sin() * (0.13 * yf).cos()
                    + 0.15 * (0.07 * xf + 0.11 * yf).sin()
                    + 0.1
                        * ((xf - 40.0).powi(2) + (yf - 30.0).powi(2))
                            .sqrt()
                            .mul_add(0.3, 0.0)
                            .cos();
            }
        }
        g
    }

    #[test]
    fn the_grid_fills_the_unit_disk_symmetrically() {
        let pts = disk_grid(16);
        assert!(pts.iter().all(|[u, v]| u * u + v * v <= 1.0));
        // The share of the square's cells inside the circle is about π/4.
        let share = pts.len() as f64 / 256.0;
        assert!(
            (share - std::f64::consts::FRAC_PI_4).abs() < 0.05,
            "{share}"
        );
        let (su, sv) = pts.iter().fold((0.0, 0.0), |(a, b), [u, v]| (a + u, b + v));
        assert!(su.abs() < 1e-4 && sv.abs() < 1e-4);
    }

    #[test]
    fn the_target_itself_correlates_perfectly_and_a_shifted_one_less() {
        let g = scene(120, 90);
        let at = particle(60.0, 45.0, 14.0, 11.0, 0.0);
        let t = Template::new(&g, &at, 0.0, 16);
        assert!(t.is_usable());
        let shifted: Vec<Particle> = [0.0f32, 2.0, 5.0, 10.0]
            .iter()
            .map(|d| particle(60.0 + d, 45.0, 14.0, 11.0, 0.0))
            .collect();
        let mut out = Vec::new();
        t.correlate(&g, &shifted, 0.0, &mut out);
        assert!((out[0] - 1.0).abs() < 1e-5, "{out:?}");
        assert!(
            out[1] < out[0] && out[2] < out[1] && out[3] < out[2],
            "{out:?}"
        );
    }

    #[test]
    fn correlation_ignores_a_gain_and_an_offset_of_the_grey_levels() {
        let g = scene(100, 80);
        let at = particle(50.0, 40.0, 12.0, 10.0, 0.3);
        let t = Template::new(&g, &at, 0.0, 16);
        let mut dim = g.clone();
        dim.data.iter_mut().for_each(|v| *v = 0.4 * *v + 0.1);
        let mut out = Vec::new();
        t.correlate(&dim, &[at], 0.0, &mut out);
        assert!((out[0] - 1.0).abs() < 1e-5, "{out:?}");
    }

    #[test]
    fn the_template_turns_with_the_ellipse() {
        // An image rotated by 90° about the ellipse's centre: the template taken at
        // orientation 0 matches the particle turned by 90° (rz, or theta0 alike).
        let (w, h) = (81u32, 81u32);
        let g = scene(w, h);
        let mut r = GrayF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                // r(x, y) = g at the point rotated back by -90° about (40, 40).
                let (dx, dy) = (x as i64 - 40, y as i64 - 40);
                let (sx, sy) = (40 + dy, 40 - dx);
                r.data[(y * w + x) as usize] = g.get_clamped(sx, sy);
            }
        }
        let t = Template::new(&g, &particle(40.0, 40.0, 15.0, 9.0, 0.0), 0.0, 16);
        let mut out = Vec::new();
        let turned = particle(40.0, 40.0, 15.0, 9.0, std::f32::consts::FRAC_PI_2);
        let unturned = particle(40.0, 40.0, 15.0, 9.0, 0.0);
        t.correlate(&r, &[turned, unturned], 0.0, &mut out);
        assert!(out[0] > 0.999, "{out:?}");
        assert!(out[1] < 0.9, "{out:?}");
        t.correlate(&r, &[unturned], std::f32::consts::FRAC_PI_2, &mut out);
        assert!(out[0] > 0.999, "{out:?}");
    }

    #[test]
    fn a_flat_patch_or_template_scores_zero() {
        let flat = GrayF32::new(40, 40);
        let t = Template::new(&flat, &particle(20.0, 20.0, 8.0, 8.0, 0.0), 0.0, 12);
        assert!(!t.is_usable());
        let mut out = Vec::new();
        t.correlate(
            &scene(40, 40),
            &[particle(20.0, 20.0, 8.0, 8.0, 0.0)],
            0.0,
            &mut out,
        );
        assert_eq!(out, vec![0.0]);
        let t = Template::new(
            &scene(40, 40),
            &particle(20.0, 20.0, 8.0, 8.0, 0.0),
            0.0,
            12,
        );
        t.correlate(&flat, &[particle(20.0, 20.0, 8.0, 8.0, 0.0)], 0.0, &mut out);
        assert_eq!(out, vec![0.0]);
    }

    #[test]
    fn blending_moves_the_template_towards_what_it_sees() {
        let g = scene(120, 90);
        let a = particle(50.0, 45.0, 14.0, 11.0, 0.0);
        let b = particle(70.0, 40.0, 14.0, 11.0, 0.0);
        let mut t = Template::new(&g, &a, 0.0, 16);
        let mut out = Vec::new();
        t.correlate(&g, &[b], 0.0, &mut out);
        let before = out[0];
        t.blend_towards(&g, &b, 0.0, 0.5);
        t.correlate(&g, &[b], 0.0, &mut out);
        assert!(out[0] > before, "{before} -> {}", out[0]);
        t.blend_towards(&g, &b, 0.0, 1.0);
        t.correlate(&g, &[b], 0.0, &mut out);
        assert!((out[0] - 1.0).abs() < 1e-5);
    }
}
