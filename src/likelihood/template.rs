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
//! `θ = theta0 + rz` (the orientation the ellipse is drawn with), or `θ + π`, the same
//! ellipse, where the target's up axis points that way ([`upright_sin_cos`]): the template
//! turns and scales with the ellipse, and stays upright as the angles pass a pan of 90°.
//!
//! The same template can also be turned out of the image plane
//! ([`Template::correlate_turned`]): its grid points lifted onto the feature term's ellipsoid
//! prior and moved with each particle's 3D rotation from the view it was taken in. The
//! tracker keeps the first view so and compares every particle with it, a cue that sees
//! tilt and pan where the plain correlation sees only the ellipse
//! ([`crate::tracker::TemplateTerm::anchor_weight`]).

use crate::frames::GrayF32;
use crate::likelihood::Particle;
use crate::likelihood::cpu::is_degenerate;
use crate::pose::prior::Pinhole;

/// Most cells a side of [`disk_grid`]: a larger grid is taken as this (about 50 000 points;
/// `usize::MAX` overflowed the allocation's size, 2^20 asked for 8.8 TB).
pub const MAX_GRID: usize = 256;

/// The sample grid in the ellipse's unit disk: `grid x grid` cell centres on `[-1, 1]²` that
/// lie inside the unit circle, in row-major order (`grid` within `1..=MAX_GRID`).
pub fn disk_grid(grid: usize) -> Vec<[f32; 2]> {
    let g = grid.clamp(1, MAX_GRID);
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

/// `(sin, cos)` of the orientation a template is laid on the ellipse of particle `p` with:
/// the ellipse's own `theta0 + p.rz`, or that turned by half a turn (the same ellipse) where
/// the target's up axis, the image direction `(r12, r22)` of its rotation's y axis, points
/// against the roll's own, `(−sin rz, cos rz)`.
///
/// Why: a rotation has two sets of angles, and [`crate::geometry::Euler::from_matrix`] keeps
/// the pan within ±90°, so a target that pans past 90° is given the other set, its roll
/// turned by 180°: the ellipse is the same, but a template laid by the roll alone turned
/// upside down there, and compared particles on either side of 90° with it the wrong way up
/// (a head could not be tracked across a pan of 90° with the template on). The up axis
/// belongs to the rotation, not to its angles. With a pan and tilt within 60° it agrees with
/// the roll, whatever the roll, and nothing turns (the first turn comes with both near 66°
/// and the roll near 45°).
pub fn upright_sin_cos(theta0: f32, p: &Particle) -> (f32, f32) {
    let (s, c) = (theta0 + p.rz).sin_cos();
    if upside_down(p) { (-s, -c) } else { (s, c) }
}

/// Whether the target's up axis points against its roll's direction, so that
/// [`upright_sin_cos`] turns the roll's orientation by half a turn.
pub fn upside_down(p: &Particle) -> bool {
    let (sx, cx) = p.rx.sin_cos();
    let (sy, cy) = p.ry.sin_cos();
    let (sz, cz) = p.rz.sin_cos();
    // R = Rx Ry Rz: r12 = −cos ry sin rz, r22 = cos rx cos rz − sin rx sin ry sin rz; the up
    // axis (r12, r22) against the roll's own (−sin rz, cos rz).
    let (r12, r22) = (-cy * sz, cx * cz - sx * sy * sz);
    r12 * -sz + r22 * cz < 0.0
}

/// The grey levels of `gray` at the grid points `pts` of the ellipse of particle `p`
/// (orientation [`upright_sin_cos`]), bilinear, edges replicated; into `out` (cleared first).
pub fn sample(gray: &GrayF32, p: &Particle, theta0: f32, pts: &[[f32; 2]], out: &mut Vec<f32>) {
    out.clear();
    out.resize(pts.len(), 0.0);
    let (s, c) = upright_sin_cos(theta0, p);
    // The positions of a chunk of points, then their samples in one batch.
    let (mut xs, mut ys) = ([0f32; CHUNK], [0f32; CHUNK]);
    for (chunk, o) in pts.chunks(CHUNK).zip(out.chunks_mut(CHUNK)) {
        for ((&[u, v], x_out), y_out) in chunk.iter().zip(&mut xs).zip(&mut ys) {
            let (x, y) = (p.a * u, p.b * v);
            *x_out = p.cx + c * x - s * y;
            *y_out = p.cy + s * x + c * y;
        }
        let m = chunk.len();
        gray.sample_many(&xs[..m], &ys[..m], o);
    }
}

/// Points placed, then sampled together ([`GrayF32::sample_many`]), at a time.
const CHUNK: usize = 64;

/// `values` made zero-mean and unit-norm in place; `false` (and all zeros) when they are flat
/// (their spread below `1e-6` per sample), which no template can correlate with.
pub fn normalise(values: &mut [f32]) -> bool {
    let n = values.len().max(1) as f64;
    let mean = values.iter().map(|&v| v as f64).sum::<f64>() / n;
    let ss: f64 = values.iter().map(|&v| (v as f64 - mean).powi(2)).sum();
    // (`!(a >= b)`: NaN or infinite values give no usable vector either.)
    if !(ss.is_finite() && ss.sqrt() >= 1e-6 * n.sqrt()) {
        values.iter_mut().for_each(|v| *v = 0.0);
        return false;
    }
    let k = 1.0 / ss.sqrt();
    values
        .iter_mut()
        .for_each(|v| *v = ((*v as f64 - mean) * k) as f32);
    true
}

/// The correlation of raw samples `b` with a normalised template `t` ([`normalise`]) in
/// `[-1, 1]`, from the sums of one pass, `Σb`, `Σb²` and `Σbt`: `(Σbt − Σb·Σt/n) /
/// sqrt(var_b · var_t)`, with `t`'s own sums `st = Σt` (0 up to rounding) and `stt = Σt²` (1).
/// 0 for samples flat by the rule of [`normalise`]. The same value as normalising `b` and
/// taking the dot product, without the passes that mean, normalise and then multiply.
fn correlate_raw(b: &[f32], t: &[f32], st: f64, stt: f64) -> f32 {
    let (mut sb, mut sbb, mut sbt) = (0.0f64, 0.0f64, 0.0f64);
    for (&b, &t) in b.iter().zip(t) {
        let (b, t) = (b as f64, t as f64);
        sb += b;
        sbb += b * b;
        sbt += b * t;
    }
    let n = b.len().max(1) as f64;
    let vb = (sbb - sb * sb / n).max(0.0);
    let vt = (stt - st * st / n).max(0.0);
    if vb.sqrt() < 1e-6 * n.sqrt() || vt <= 0.0 {
        return 0.0;
    }
    ((sbt - sb * st / n) / (vb * vt).sqrt()).clamp(-1.0, 1.0) as f32
}

/// The target's template: the mean grey levels at the grid points over the frames it has
/// learnt from, and their normalised form that the correlation uses.
#[derive(Debug, Clone, PartialEq)]
pub struct Template {
    pts: Vec<[f32; 2]>,
    raw: Vec<f32>,
    unit: Vec<f32>,
    /// `Σ unit` and `Σ unit²` (0 and 1 up to rounding), for [`correlate_raw`].
    unit_sums: (f64, f64),
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
            unit_sums: (0.0, 0.0),
            usable: false,
        };
        t.refresh();
        t
    }

    fn refresh(&mut self) {
        self.unit.clone_from(&self.raw);
        self.usable = normalise(&mut self.unit);
        self.unit_sums = self.unit.iter().fold((0.0, 0.0), |(s, ss), &t| {
            let t = t as f64;
            (s + t, ss + t * t)
        });
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
                    // A degenerate particle (the engines' rule) sees nothing: a negative
                    // semi-axis sampled the mirrored ellipse.
                    if is_degenerate(p) {
                        return 0.0;
                    }
                    sample(gray, p, theta0, &self.pts, buf);
                    let (st, stt) = self.unit_sums;
                    correlate_raw(buf, &self.unit, st, stt)
                },
            )
            .collect_into_vec(out);
    }
}

impl Template {
    /// The NCC in `[-1, 1]` of each particle's view with this template turned by the
    /// particle's rotation from `first`, the particle the template was taken from; into `out`
    /// (one per particle, in order).
    ///
    /// Each grid point of the first view's ellipse (`view.particle`) is lifted onto the
    /// ellipsoid prior of the feature term (`z = −depth_ratio · sqrt(a b) · sqrt(1 − u² −
    /// v²)`, towards the camera), turned by `R_p R_firstᵀ`, scaled by
    /// `sqrt(a_p b_p / (a_first b_first))` and moved to the particle's centre (weak
    /// perspective), and the frame is sampled there. With a camera (`view.camera`) the grid
    /// points are lifted along their viewing rays instead and the turned points projected
    /// through it, as the keyframe fits do ([`crate::pose::prior`]): on a near object the
    /// near side moves faster in the image than the centre, which weak perspective matches
    /// with a larger turn. Points turned away from the camera (depth beyond the centre's)
    /// are left out, and the correlation is over the rest, each side normalised over them;
    /// 0 when fewer than half remain, for a flat patch, or for an unusable template. A
    /// particle equal to the first gives [`Template::correlate`]'s value.
    pub fn correlate_turned(
        &self,
        gray: &GrayF32,
        particles: &[Particle],
        theta0: f32,
        view: &FirstView,
        out: &mut Vec<f32>,
    ) {
        let (first, depth_ratio) = (&view.particle, view.depth_ratio);
        use crate::likelihood::cpu::feature::{prior_depth, rotation};
        use rayon::prelude::*;
        out.clear();
        // A degenerate first view (a semi-axis of 0 made every turned point infinite) turns
        // nothing.
        if !self.usable || is_degenerate(first) || !(first.a * first.b).is_normal() {
            out.resize(particles.len(), 0.0);
            return;
        }
        // Laid as the template was sampled ([`sample`]).
        let (s0, c0) = upright_sin_cos(theta0, first);
        let mut lifted: Vec<[f32; 3]> = self
            .pts
            .iter()
            .map(|&[u, v]| {
                let (x, y) = (first.a * u, first.b * v);
                [
                    c0 * x - s0 * y,
                    s0 * x + c0 * y,
                    prior_depth(u, v, first.a, first.b, depth_ratio),
                ]
            })
            .collect();
        if let Some(cam) = &view.camera {
            // Along the viewing rays onto the same ellipsoid, as the keyframe fits lift.
            let e = crate::geometry::Ellipse {
                cx: first.cx as f64,
                cy: first.cy as f64,
                a: first.a as f64,
                b: first.b as f64,
                theta: f64::from(theta0 + first.rz)
                    + if upside_down(first) {
                        std::f64::consts::PI
                    } else {
                        0.0
                    },
            };
            let seen: Vec<[f64; 2]> = lifted
                .iter()
                .map(|x| [e.cx + x[0] as f64, e.cy + x[1] as f64])
                .collect();
            let model = crate::pose::prior::Ellipsoid::facing(&e, depth_ratio as f64);
            lifted = crate::pose::prior::lift(&seen, &model, Some(cam))
                .iter()
                .map(|x| [x.x as f32, x.y as f32, x.z as f32])
                .collect();
        }
        let camera = view.camera.as_ref().map(CameraF32::from);
        let r0t = rotation(first.rx, first.ry, first.rz).transpose();
        let ab0 = first.a * first.b;
        let n = self.pts.len();
        particles
            .par_iter()
            .map(|p| {
                if is_degenerate(p) {
                    return 0.0;
                }
                let dr = rotation(p.rx, p.ry, p.rz) * r0t;
                let (r0, r1, r2) = (dr.row(0), dr.row(1), dr.row(2));
                let k = ((p.a * p.b) / ab0).sqrt();
                // One pass: the sums the correlation over the visible points needs.
                let (mut m, mut sb, mut sbb, mut st, mut stt, mut sbt) =
                    (0usize, 0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
                // By chunks: every point placed (hidden ones too) and sampled in one batch,
                // then the visible ones summed in the points' order.
                let (mut xs, mut ys, mut zs) = ([0f32; CHUNK], [0f32; CHUNK], [0f32; CHUNK]);
                let mut seen = [0f32; CHUNK];
                for (chunk, raw) in lifted.chunks(CHUNK).zip(self.raw.chunks(CHUNK)) {
                    for (j, x) in chunk.iter().enumerate() {
                        let x = glam::Vec3::from_array(*x);
                        let (px, py, z) = (r0.dot(x), r1.dot(x), r2.dot(x));
                        [xs[j], ys[j]] = match &camera {
                            None => [p.cx + k * px, p.cy + k * py],
                            Some(cam) => cam.project([p.cx, p.cy], [k * px, k * py, k * z]),
                        };
                        zs[j] = z;
                    }
                    let c = chunk.len();
                    gray.sample_many(&xs[..c], &ys[..c], &mut seen[..c]);
                    for ((&z, &b), &t) in zs[..c].iter().zip(&seen[..c]).zip(raw) {
                        if z > 0.0 {
                            continue;
                        }
                        let (b, t) = (b as f64, t as f64);
                        m += 1;
                        sb += b;
                        sbb += b * b;
                        st += t;
                        stt += t * t;
                        sbt += b * t;
                    }
                }
                if m * 2 < n {
                    return 0.0;
                }
                let mf = m as f64;
                let vb = (sbb - sb * sb / mf).max(0.0);
                let vt = (stt - st * st / mf).max(0.0);
                // Flat by the same rule as `normalise`.
                let flat = 1e-6 * mf.sqrt();
                if vb.sqrt() < flat || vt.sqrt() < flat {
                    return 0.0;
                }
                ((sbt - sb * st / mf) / (vb * vt).sqrt()).clamp(-1.0, 1.0) as f32
            })
            .collect_into_vec(out);
    }
}

/// The first view as [`Template::correlate_turned`] turns it: the particle it was taken
/// from, the depth of the object model (the feature term's `depth_ratio`) and the camera
/// (`None` for weak perspective).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FirstView {
    /// The particle the template was taken from.
    pub particle: Particle,
    /// Depth of the ellipsoid prior relative to `sqrt(a b)`.
    pub depth_ratio: f32,
    /// The camera the view is projected through; `None` for weak perspective.
    pub camera: Option<Pinhole>,
}

impl FirstView {
    /// The first view of `particle` with a depth ratio of 1 under weak perspective.
    pub fn weak(particle: Particle) -> Self {
        Self {
            particle,
            depth_ratio: 1.0,
            camera: None,
        }
    }
}

/// [`Pinhole`] in `f32`, for the turned first view's projection.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CameraF32 {
    /// `1 / focal`.
    inv_focal: f32,
    principal: [f32; 2],
}

/// The smallest `1 + z / focal` a projection divides by, as the keyframe fits' projection
/// holds it ([`crate::pose::prior`]).
const MIN_DEPTH_FACTOR: f32 = crate::pose::prior::MIN_DEPTH_FACTOR as f32;

impl From<&Pinhole> for CameraF32 {
    fn from(c: &Pinhole) -> Self {
        Self {
            inv_focal: (1.0 / c.focal) as f32,
            principal: [c.principal.x as f32, c.principal.y as f32],
        }
    }
}

impl CameraF32 {
    /// The image of `y`, a point relative to an object whose centre projects to `c`, in
    /// pixels at the centre's depth (`z` away from the camera): `pp + ((c − pp) + y_xy) / g`,
    /// `g = max(1 + y_z / focal, MIN_DEPTH_FACTOR)`.
    fn project(&self, c: [f32; 2], y: [f32; 3]) -> [f32; 2] {
        // One division per point: this runs for every grid point of every particle.
        let inv_g = 1.0 / (1.0 + y[2] * self.inv_focal).max(MIN_DEPTH_FACTOR);
        let [px, py] = self.principal;
        [
            px + ((c[0] - px) + y[0]) * inv_g,
            py + ((c[1] - py) + y[1]) * inv_g,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_is_bounded() {
        assert_eq!(disk_grid(usize::MAX), disk_grid(MAX_GRID));
        assert_eq!(disk_grid(0), disk_grid(1));
    }

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

    /// The template stays upright as a pan passes 90°: the angles `Euler::from_matrix`
    /// gives there (tilt and roll turned by 180°, pan mirrored) sample what the angles just
    /// short of 90° sample, and so does the other set of angles of any rotation; with pan and
    /// tilt within 60° nothing turns, whatever the roll.
    #[test]
    fn the_template_stays_upright_through_a_pan_of_90_degrees() {
        use crate::geometry::Euler;
        let g = scene(80, 60);
        let pts = disk_grid(14);
        let at = |e: &Euler| Particle {
            rx: e.rx as f32,
            ry: e.ry as f32,
            rz: e.rz as f32,
            ..particle(40.0, 30.0, 12.0, 16.0, 0.0)
        };
        let (mut before, mut after) = (Vec::new(), Vec::new());
        let short = Euler::new(0.0, 89f64.to_radians(), 0.0);
        let past = Euler::from_matrix(&Euler::new(0.0, 91f64.to_radians(), 0.0).matrix());
        assert!(past.rz.abs() > 3.0, "the other set of angles: {past:?}");
        sample(&g, &at(&short), 0.3, &pts, &mut before);
        sample(&g, &at(&past), 0.3, &pts, &mut after);
        let worst = before
            .iter()
            .zip(&after)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "{worst}");
        // Either set of angles of one rotation, laid alike.
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * std::f64::consts::TAU
        };
        for _ in 0..500 {
            let e = Euler::new(next(), next() / 2.0, next());
            let other = Euler::new(
                e.rx + std::f64::consts::PI,
                std::f64::consts::PI - e.ry,
                e.rz + std::f64::consts::PI,
            );
            let (a, b) = (
                upright_sin_cos(0.3, &at(&e)),
                upright_sin_cos(0.3, &at(&other)),
            );
            assert!(
                (a.0 - b.0).abs() < 1e-5 && (a.1 - b.1).abs() < 1e-5,
                "{e:?}: {a:?} {b:?}"
            );
            let moderate = Euler::new(e.rx / 3.0, e.ry / 1.5, e.rz);
            assert!(!upside_down(&at(&moderate)), "{moderate:?}");
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

    /// The texture of the test spheres at the camera-frame point `p` of an object turned by
    /// `rot`: the object point `X = Rᵀ p`.
    fn shade(p: [f32; 3], rot: &glam::Mat3) -> f32 {
        let [x, y, z] = rot.transpose_mul_vec3(glam::Vec3::from_array(p)).to_array();
        0.5 + 0.2 * (0.45 * x).sin() * (0.35 * y).cos()
            + 0.15 * (0.3 * y + 0.25 * z).sin()
            + 0.1 * (0.2 * x - 0.4 * z).cos()
    }

    /// A textured sphere of radius `r` centred at `(cx, cy)`, turned by `rot`, on a flat
    /// background: each pixel inside the outline shows the texture at the object point its
    /// ray meets first (weak perspective, depth towards the camera negative).
    fn sphere(w: u32, h: u32, cx: f32, cy: f32, r: f32, rot: &glam::Mat3) -> GrayF32 {
        let mut g = GrayF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as f32 - cx, y as f32 - cy);
                let d2 = r * r - dx * dx - dy * dy;
                g.data[(y * w + x) as usize] = if d2 >= 0.0 {
                    // The camera-frame point, back to the object frame: X = Rᵀ X'.
                    let p = [dx, dy, -d2.sqrt()];
                    shade(p, rot)
                } else {
                    0.3
                };
            }
        }
        g
    }

    #[test]
    fn a_turned_sphere_is_recognised_at_its_turn() {
        use crate::likelihood::cpu::feature::rotation;
        let (cx, cy, r) = (60.0, 50.0, 30.0);
        let first = particle(cx, cy, r, r, 0.0);
        let t = Template::new(
            &sphere(120, 100, cx, cy, r, &rotation(0.0, 0.0, 0.0)),
            &first,
            0.0,
            16,
        );
        let at = |rx: f32, ry: f32| Particle { rx, ry, ..first };
        let mut out = Vec::new();
        for (rx, ry) in [(0.3f32, 0.0f32), (0.0, -0.35), (0.2, 0.25)] {
            let g = sphere(120, 100, cx, cy, r, &rotation(rx, ry, 0.0));
            let cands = [
                at(rx, ry),
                at(0.0, 0.0),
                at(-rx, -ry),
                at(0.5 * rx, 0.5 * ry),
            ];
            t.correlate_turned(&g, &cands, 0.0, &FirstView::weak(first), &mut out);
            // Recognised at the turn it was shown with, and clearly better there than at no
            // turn, the opposite one or half of it.
            assert!(out[0] > 0.95, "{rx} {ry}: {out:?}");
            assert!(
                out[1..].iter().all(|&c| c < out[0] - 0.05),
                "{rx} {ry}: {out:?}"
            );
            // The plain correlation cannot tell the turn: it sees the same at every rotation.
            let mut plain = Vec::new();
            t.correlate(&g, &cands, 0.0, &mut plain);
            assert!(
                plain.windows(2).all(|w| (w[0] - w[1]).abs() < 1e-6),
                "{plain:?}"
            );
        }
    }

    /// The sphere of [`sphere`] seen by a pinhole camera of focal length `f` whose principal
    /// point is `pp`: each pixel's ray from the camera centre meets the sphere, centred on the
    /// ray through `(cx, cy)` at depth `f` (pixels at that depth).
    #[allow(clippy::too_many_arguments)]
    fn near_sphere(
        w: u32,
        h: u32,
        (cx, cy, r): (f32, f32, f32),
        f: f32,
        pp: [f32; 2],
        rot: &glam::Mat3,
    ) -> GrayF32 {
        let c = [cx - pp[0], cy - pp[1], f];
        let mut g = GrayF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let d = [x as f32 - pp[0], y as f32 - pp[1], f];
                let (dd, dc) = (
                    d[0] * d[0] + d[1] * d[1] + d[2] * d[2],
                    d[0] * c[0] + d[1] * c[1] + d[2] * c[2],
                );
                let cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
                let disc = dc * dc - dd * (cc - r * r);
                g.data[(y * w + x) as usize] = if disc >= 0.0 {
                    let t = (dc - disc.sqrt()) / dd;
                    let p = [t * d[0] - c[0], t * d[1] - c[1], t * d[2] - c[2]];
                    shade(p, rot)
                } else {
                    0.3
                };
            }
        }
        g
    }

    #[test]
    fn with_its_camera_a_near_sphere_is_recognised_at_its_true_turn_and_without_further() {
        use crate::likelihood::cpu::feature::rotation;
        // A sphere 8 radii from the camera, as the synthetic heads are.
        let (w, h, r, f) = (120u32, 100u32, 30.0f32, 240.0f32);
        let pp = [59.5f32, 49.5];
        let cam = Pinhole {
            focal: f as f64,
            principal: nalgebra::Vector2::new(pp[0] as f64, pp[1] as f64),
        };
        let (cx, cy) = (62.0, 48.0);
        let first_view = near_sphere(w, h, (cx, cy, r), f, pp, &rotation(0.0, 0.0, 0.0));
        // The outline of the near sphere: the ellipse the tracker would start from.
        let ro = f
            * (r / (f * f + (cx - pp[0]).powi(2) + (cy - pp[1]).powi(2)).sqrt())
                .asin()
                .tan();
        let first = particle(cx, cy, ro, ro, 0.0);
        let t = Template::new(&first_view, &first, 0.0, 16);
        let gains = [0.8f32, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4];
        let best = |g: &GrayF32, rx: f32, ry: f32, camera: Option<&Pinhole>| {
            let cands: Vec<Particle> = gains
                .iter()
                .map(|k| Particle {
                    rx: k * rx,
                    ry: k * ry,
                    ..first
                })
                .collect();
            let mut out = Vec::new();
            let view = FirstView {
                camera: camera.copied(),
                ..FirstView::weak(first)
            };
            t.correlate_turned(g, &cands, 0.0, &view, &mut out);
            let i = (0..out.len())
                .max_by(|&a, &b| out[a].total_cmp(&out[b]))
                .unwrap_or(0);
            (gains[i], out[i])
        };
        for (rx, ry) in [(0.4f32, 0.0f32), (0.0, -0.4)] {
            let g = near_sphere(w, h, (cx, cy, r), f, pp, &rotation(rx, ry, 0.0));
            let (with, c) = best(&g, rx, ry, Some(&cam));
            assert_eq!(with, 1.0, "{rx} {ry}: best at {with} of the turn ({c})");
            assert!(c > 0.9, "{rx} {ry}: {c}");
            let (weak, _) = best(&g, rx, ry, None);
            assert!(weak > 1.0, "{rx} {ry}: weak perspective best at {weak}");
        }
    }

    #[test]
    fn an_unturned_particle_of_the_first_shape_gives_the_plain_correlation() {
        let g = scene(120, 90);
        let first = particle(60.0, 45.0, 14.0, 11.0, 0.2);
        let t = Template::new(&g, &first, 0.1, 16);
        // Same aspect as the first ellipse, any place, size and roll.
        let cands = [
            first,
            particle(63.0, 41.0, 14.0, 11.0, 0.2),
            particle(58.0, 47.0, 16.8, 13.2, -0.3),
        ];
        let (mut turned, mut plain) = (Vec::new(), Vec::new());
        t.correlate_turned(&g, &cands, 0.1, &FirstView::weak(first), &mut turned);
        t.correlate(&g, &cands, 0.1, &mut plain);
        assert!((turned[0] - 1.0).abs() < 1e-5, "{turned:?}");
        for (a, b) in turned.iter().zip(&plain) {
            assert!((a - b).abs() < 1e-4, "{turned:?} {plain:?}");
        }
    }

    #[test]
    fn a_view_turned_mostly_away_scores_zero() {
        let g = scene(120, 90);
        let first = particle(60.0, 45.0, 14.0, 11.0, 0.0);
        let t = Template::new(&g, &first, 0.0, 16);
        let away = Particle { ry: 2.6, ..first };
        let mut out = Vec::new();
        t.correlate_turned(&g, &[away], 0.0, &FirstView::weak(first), &mut out);
        assert_eq!(out, vec![0.0]);
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
    fn the_one_pass_correlation_equals_normalising_then_the_dot_product() {
        // Grey levels with an offset far above their spread, where a one-pass variance
        // loses the most to cancellation.
        let mut state = 12345u32;
        let mut next = || {
            state = state.wrapping_mul(1664525).wrapping_add(1013904223);
            (state >> 8) as f32 / (1u32 << 24) as f32
        };
        for (offset, spread) in [(0.0, 1.0), (0.5, 0.1), (0.9, 0.001)] {
            let b: Vec<f32> = (0..201).map(|_| offset + spread * next()).collect();
            let mut t: Vec<f32> = b.iter().map(|&v| v + 0.3 * spread * next()).collect();
            assert!(normalise(&mut t));
            let (st, stt) = t.iter().fold((0.0, 0.0), |(s, ss), &v| {
                (s + v as f64, ss + v as f64 * v as f64)
            });
            let mut unit = b.clone();
            assert!(normalise(&mut unit));
            let dot: f64 = unit
                .iter()
                .zip(&t)
                .map(|(&x, &y)| x as f64 * y as f64)
                .sum();
            let one_pass = correlate_raw(&b, &t, st, stt);
            assert!(
                (one_pass as f64 - dot).abs() < 1e-5,
                "offset {offset} spread {spread}: {one_pass} against {dot}"
            );
            assert!(dot > 0.5, "the test's samples should correlate: {dot}");
        }
        // Flat samples score 0, as `normalise` calls them flat.
        let flat = vec![0.25f32; 201];
        let t: Vec<f32> = (0..201)
            .map(|i| if i % 2 == 0 { 0.07 } else { -0.07 })
            .collect();
        assert_eq!(correlate_raw(&flat, &t, 0.0, 1.0), 0.0);
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
