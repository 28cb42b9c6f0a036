//! The renderer: per-pixel ray casting of the analytic shape, shading, background, noise, and
//! the truth of every frame.

use image::RgbImage;
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use rayon::prelude::*;

use super::camera::Camera;
use super::shape::{Hit, Outline, Shape, ellipsoid_outline};
use super::texture::{Background, Material, Rgb, SolidTexture, noise};
use super::trajectory::{ObjectPose, Trajectory};
use super::{Scenario, SynthConfig, SynthError};
use crate::geometry::rotation::{rot_x, rot_y};
use crate::geometry::{Ellipse, Euler, PoseState, rad};

/// Ambient light level.
const AMBIENT: f32 = 0.5;
/// Directional light level (Lambertian).
const DIFFUSE: f32 = 0.55;
/// Standard deviation of the sensor noise, in 8-bit levels.
pub const NOISE_SIGMA: f64 = 2.0;
/// Subsamples per pixel side when rendering (2×2, antialiased edges and texture).
const RENDER_SS: usize = 2;
/// Subsamples per pixel side when measuring the silhouette's moments (4×4).
const MOMENT_SS: usize = 4;

/// Renders the frames of one [`SynthConfig`] and gives their truth. Cheap to query per frame;
/// the background is computed once in [`Renderer::new`].
#[derive(Debug, Clone)]
pub struct Renderer {
    cfg: SynthConfig,
    camera: Camera,
    shape: Shape,
    orientation0: Matrix3<f64>,
    texture: SolidTexture,
    /// Background colour per pixel (2×2 subsample average), row major.
    background: Vec<Rgb>,
    trajectory: Trajectory,
}

impl Renderer {
    /// A renderer for a configuration (checked with [`SynthConfig::validate`]).
    pub fn new(cfg: &SynthConfig) -> Result<Renderer, SynthError> {
        cfg.validate()?;
        let camera = Camera::new(cfg.width, cfg.height);
        let shape = cfg.scenario.shape();
        let (orientation0, material, texel) = match cfg.scenario {
            // The car seen from 15° above, its nose turned 25° towards the camera.
            Scenario::Car => (rot_x(rad(15.0)) * rot_y(rad(25.0)), Material::Car, 0.05),
            // The head faces the camera at frame 0.
            _ => (Matrix3::identity(), Material::Head, 0.035),
        };
        let texture = SolidTexture::new(cfg.seed, material, texel);
        let trajectory = Trajectory::new(cfg.scenario, cfg.frames, cfg.seed, &orientation0);
        let background = render_background(cfg.seed, cfg.width, cfg.height);
        Ok(Renderer {
            cfg: *cfg,
            camera,
            shape,
            orientation0,
            texture,
            background,
            trajectory,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SynthConfig {
        &self.cfg
    }

    /// Number of frames.
    pub fn frames(&self) -> usize {
        self.cfg.frames
    }

    /// The camera.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The object.
    pub fn shape(&self) -> &Shape {
        &self.shape
    }

    /// `R_obj0`: the object's orientation (object to camera coordinates) at frame 0.
    pub fn reference_orientation(&self) -> Matrix3<f64> {
        self.orientation0
    }

    /// The object's rotation `R_t` and centre at frame `k`.
    pub fn pose(&self, k: usize) -> ObjectPose {
        self.trajectory.pose(k)
    }

    /// The object's orientation at frame `k`: `R_t · R_obj0`, object to camera coordinates.
    pub fn orientation(&self, k: usize) -> Matrix3<f64> {
        self.pose(k).rotation * self.orientation0
    }

    /// Maps an object-frame point to camera coordinates at frame `k`:
    /// `R_t · R_obj0 · p + centre_t`.
    pub fn to_camera(&self, k: usize, p: &Vector3<f64>) -> Vector3<f64> {
        let pose = self.pose(k);
        pose.rotation * (self.orientation0 * p) + pose.centre
    }

    /// Where an object-frame point appears in frame `k` (pixels).
    pub fn project_point(&self, k: usize, p: &Vector3<f64>) -> (f64, f64) {
        self.camera.project(&self.to_camera(k, p))
    }

    /// Casts the ray through image position `(u, v)` in frame `k`: the first surface hit, with
    /// the point and normal in object coordinates.
    pub fn cast(&self, k: usize, u: f64, v: f64) -> Option<Hit> {
        let pose = self.pose(k);
        let m = pose.rotation * self.orientation0;
        let mt = m.transpose();
        self.shape
            .intersect(&(mt * -pose.centre), &(mt * self.camera.ray(u, v)))
    }

    /// The surface colour (albedo, before lighting) at an object-frame point.
    pub fn albedo(&self, p: &Vector3<f64>) -> [f32; 3] {
        self.texture.albedo(p)
    }

    /// The lighting of frame `k`: the unit direction towards the directional light (camera
    /// coordinates; it turns slowly) and the global exposure gain (it drifts by ±8 %). Periods
    /// of 300 to 420 frames, whatever the sequence length.
    pub fn light(&self, k: usize) -> (Vector3<f64>, f32) {
        let t = k as f64 * std::f64::consts::TAU;
        let dir = Vector3::new(
            -0.45 + 0.3 * (t / 420.0).sin(),
            -0.55 + 0.15 * (t / 300.0).cos(),
            -1.0,
        )
        .normalize();
        let gain = 1.0 + 0.08 * (t / 350.0).sin() as f32;
        (dir, gain)
    }

    /// A conservative image bounding box `[u0, u1, v0, v1]` of the object in frame `k` (from its
    /// bounding sphere; not clipped to the image), or `None` when the sphere reaches behind the
    /// camera.
    pub fn image_bounds(&self, k: usize) -> Option<[f64; 4]> {
        let c = self.pose(k).centre;
        let r = self.shape.bounding_radius();
        let (z0, z1) = (c.z - r, c.z + r);
        if z0 <= 1e-3 {
            return None;
        }
        let f = self.camera.focal;
        let range = |lo: f64, hi: f64| {
            let vals = [lo / z0, lo / z1, hi / z0, hi / z1];
            let mn = vals.iter().copied().fold(f64::INFINITY, f64::min);
            let mx = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (mn * f, mx * f)
        };
        let (u0, u1) = range(c.x - r, c.x + r);
        let (v0, v1) = range(c.y - r, c.y + r);
        Some([
            self.camera.pu + u0,
            self.camera.pu + u1,
            self.camera.pv + v0,
            self.camera.pv + v1,
        ])
    }

    /// The silhouette's area, centroid and covariance in frame `k`, sampled at 4×4 points per
    /// pixel over the object's bounds (not clipped by the image border, so an object partly out
    /// of view keeps its true shape).
    pub fn silhouette(&self, k: usize) -> Outline {
        let pose = self.pose(k);
        let m = pose.rotation * self.orientation0;
        let mt = m.transpose();
        let origin = mt * -pose.centre;
        let (w, h) = (self.cfg.width as f64, self.cfg.height as f64);
        let [u0, u1, v0, v1] = self.image_bounds(k).unwrap_or([0.0, w - 1.0, 0.0, h - 1.0]);
        // The window is bounded (an object at the camera has unbounded bounds) by the longer
        // side beyond each border, on both axes: the field of view is horizontal, so on a wide
        // frame a head reaches far past the short side (a window of one height beyond the
        // top and bottom cut a 320x48 head's outline, its b 7 % short).
        let m = w.max(h);
        let u0 = (u0.floor() - 1.0).max(-m) as i64;
        let u1 = (u1.ceil() + 1.0).min(w - 1.0 + m) as i64;
        let v0 = (v0.floor() - 1.0).max(-m) as i64;
        let v1 = (v1.ceil() + 1.0).min(h - 1.0 + m) as i64;
        // Sums relative to the projected centre, to keep them well conditioned.
        let (ru, rv) = self.camera.project(&pose.centre);
        let rows: Vec<[f64; 6]> = (v0..=v1)
            .into_par_iter()
            .map(|v| {
                let mut s = [0.0; 6];
                for j in 0..MOMENT_SS {
                    let sv = v as f64 + (j as f64 + 0.5) / MOMENT_SS as f64 - 0.5;
                    // the ray direction is affine in (su, sv): d = d0 + su · du
                    let d0 = mt * self.camera.ray(0.0, sv);
                    let du = mt * Vector3::new(1.0 / self.camera.focal, 0.0, 0.0);
                    for u in u0..=u1 {
                        for i in 0..MOMENT_SS {
                            let su = u as f64 + (i as f64 + 0.5) / MOMENT_SS as f64 - 0.5;
                            if self.shape.hits(&origin, &(d0 + du * su)) {
                                let (x, y) = (su - ru, sv - rv);
                                s[0] += 1.0;
                                s[1] += x;
                                s[2] += y;
                                s[3] += x * x;
                                s[4] += x * y;
                                s[5] += y * y;
                            }
                        }
                    }
                }
                s
            })
            .collect();
        let mut s = [0.0; 6];
        for r in &rows {
            for (acc, x) in s.iter_mut().zip(r) {
                *acc += x;
            }
        }
        moments_from_sums(&s, (MOMENT_SS * MOMENT_SS) as f64, ru, rv)
    }

    /// The exact perspective outline of the head in frame `k` (see
    /// [`super::ellipsoid_outline`]); `None` for the box.
    pub fn analytic_outline(&self, k: usize) -> Option<Outline> {
        match self.shape {
            Shape::Ellipsoid { semi } => {
                let pose = self.pose(k);
                ellipsoid_outline(&self.camera, &semi, &self.orientation(k), &pose.centre)
            }
            Shape::Box { .. } => None,
        }
    }

    /// The truth of frame `k` (see the module docs), without rendering the image.
    pub fn truth(&self, k: usize) -> PoseState {
        let pose = self.pose(k);
        let e = Euler::from_matrix(&pose.rotation);
        let (cx, cy) = self.camera.project(&pose.centre);
        let sil = self.silhouette(k);
        let (mut a, mut b) = sil.axes_along(e.rz);
        if !(a > 0.0 && b > 0.0) {
            // No silhouette sample (cannot happen along the built-in trajectories): fall back
            // to the bounding sphere's projected radius so the file stays valid.
            let r = self.camera.focal * self.shape.bounding_radius() / pose.centre.z.abs();
            a = r;
            b = r;
        }
        PoseState {
            cx,
            cy,
            a,
            b,
            // `+ 0.0` turns a -0 from atan2 into 0, so files never show "-0.000000".
            rx: e.rx + 0.0,
            ry: e.ry + 0.0,
            rz: e.rz + 0.0,
        }
    }

    /// The ellipse of frame 0 (`cx, cy, a, b`, orientation 0): what `init.txt` holds.
    pub fn init_ellipse(&self) -> Ellipse {
        let s = self.truth(0);
        Ellipse::new(s.cx, s.cy, s.a, s.b)
    }

    /// Frame `k` and its truth (angles in radians). Frames are independent: any `k` may be
    /// rendered in any order (a `k` past the last frame extrapolates the trajectory).
    pub fn render(&self, k: usize) -> (RgbImage, PoseState) {
        (self.render_image(k), self.truth(k))
    }

    /// Frame `k` only.
    pub fn render_image(&self, k: usize) -> RgbImage {
        let (w, h) = (self.cfg.width as usize, self.cfg.height as usize);
        let pose = self.pose(k);
        let m = pose.rotation * self.orientation0;
        let mt = m.transpose();
        let origin = mt * -pose.centre;
        let (light, gain) = self.light(k);
        let bounds =
            self.image_bounds(k)
                .map_or([0, w as i64 - 1, 0, h as i64 - 1], |[u0, u1, v0, v1]| {
                    [
                        u0.floor() as i64 - 1,
                        u1.ceil() as i64 + 1,
                        v0.floor() as i64 - 1,
                        v1.ceil() as i64 + 1,
                    ]
                });
        let seed = self.cfg.seed;
        let mut buf = vec![0u8; 3 * w * h];
        buf.par_chunks_mut(3 * w).enumerate().for_each(|(v, row)| {
            let vi = v as i64;
            let in_rows = vi >= bounds[2] && vi <= bounds[3];
            for u in 0..w {
                let bg = self.background[v * w + u];
                let ui = u as i64;
                let col = if in_rows && ui >= bounds[0] && ui <= bounds[1] {
                    let mut sum = [0f32; 3];
                    let mut hits = 0;
                    for j in 0..RENDER_SS {
                        let sv = v as f64 + (j as f64 + 0.5) / RENDER_SS as f64 - 0.5;
                        for i in 0..RENDER_SS {
                            let su = u as f64 + (i as f64 + 0.5) / RENDER_SS as f64 - 0.5;
                            let d = mt * self.camera.ray(su, sv);
                            if let Some(hit) = self.shape.intersect(&origin, &d) {
                                let n = m * hit.normal;
                                let shade = AMBIENT + DIFFUSE * n.dot(&light).max(0.0) as f32;
                                let alb = self.texture.albedo(&hit.point);
                                for c in 0..3 {
                                    sum[c] += alb[c] * shade;
                                }
                                hits += 1;
                            }
                        }
                    }
                    let n = (RENDER_SS * RENDER_SS) as f32;
                    let rest = (n - hits as f32) / n;
                    [
                        sum[0] / n + rest * bg[0],
                        sum[1] / n + rest * bg[1],
                        sum[2] / n + rest * bg[2],
                    ]
                } else {
                    bg
                };
                let pix = (v * w + u) as u64;
                for c in 0..3 {
                    let x = (col[c] * gain) as f64 * 255.0
                        + NOISE_SIGMA * noise(seed, k as u64, pix, c as u64);
                    row[3 * u + c] = x.round().clamp(0.0, 255.0) as u8;
                }
            }
        });
        // The buffer has exactly 3·w·h bytes, so this cannot fail.
        RgbImage::from_raw(self.cfg.width, self.cfg.height, buf).unwrap_or_default()
    }
}

/// Area, centroid and covariance from point sums `[n, Σx, Σy, Σx², Σxy, Σy²]` taken relative to
/// `(ru, rv)`, each point standing for `1 / per_px` square pixels.
fn moments_from_sums(s: &[f64; 6], per_px: f64, ru: f64, rv: f64) -> Outline {
    let n = s[0];
    if n == 0.0 {
        return Outline {
            centre: Vector2::new(ru, rv),
            cov: Matrix2::zeros(),
            area: 0.0,
        };
    }
    let (mx, my) = (s[1] / n, s[2] / n);
    let cxx = s[3] / n - mx * mx;
    let cxy = s[4] / n - mx * my;
    let cyy = s[5] / n - my * my;
    Outline {
        centre: Vector2::new(ru + mx, rv + my),
        cov: Matrix2::new(cxx, cxy, cxy, cyy),
        area: n / per_px,
    }
}

/// The background at pixel resolution, each pixel the mean of 2×2 subsamples.
fn render_background(seed: u64, width: u32, height: u32) -> Vec<Rgb> {
    let (w, h) = (width as usize, height as usize);
    let bg = Background::new(seed, height as f64 / width as f64);
    let mut out = vec![[0f32; 3]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        for (u, px) in row.iter_mut().enumerate() {
            let mut acc = [0f32; 3];
            for j in 0..RENDER_SS {
                let y = (v as f64 + (j as f64 + 0.5) / RENDER_SS as f64) / w as f64;
                for i in 0..RENDER_SS {
                    let x = (u as f64 + (i as f64 + 0.5) / RENDER_SS as f64) / w as f64;
                    let c = bg.colour(x, y);
                    for k in 0..3 {
                        acc[k] += c[k];
                    }
                }
            }
            let n = (RENDER_SS * RENDER_SS) as f32;
            *px = [acc[0] / n, acc[1] / n, acc[2] / n];
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lighting_changes_slowly() {
        let r = Renderer::new(&SynthConfig {
            width: 24,
            height: 24,
            ..SynthConfig::new(Scenario::Long)
        })
        .unwrap();
        let (mut lo, mut hi) = (f32::INFINITY, 0f32);
        let mut turned: f64 = 0.0;
        for k in 1..2400 {
            let (d0, g0) = r.light(k - 1);
            let (d1, g1) = r.light(k);
            assert!((d1.norm() - 1.0).abs() < 1e-12);
            // under 0.3° and 0.2 % per frame
            assert!(d0.angle(&d1).to_degrees() < 0.3, "frame {k}");
            assert!((g1 - g0).abs() < 2e-3, "frame {k}");
            lo = lo.min(g1);
            hi = hi.max(g1);
            turned = turned.max(r.light(0).0.angle(&d1).to_degrees());
        }
        // but it does change: ±8 % exposure, the light turns by more than 10°
        assert!(lo < 0.93 && hi > 1.07, "{lo} {hi}");
        assert!(turned > 10.0, "{turned}");
    }

    #[test]
    fn moments_of_a_sampled_axis_aligned_rectangle() {
        // 4 × 2 grid of unit-spaced points: var x = (4² - 1)/12, var y = (2² - 1)/12.
        let mut s = [0.0; 6];
        for x in 0..4 {
            for y in 0..2 {
                let (x, y) = (x as f64, y as f64);
                s[0] += 1.0;
                s[1] += x;
                s[2] += y;
                s[3] += x * x;
                s[4] += x * y;
                s[5] += y * y;
            }
        }
        let o = moments_from_sums(&s, 1.0, 10.0, 20.0);
        assert!((o.centre.x - 11.5).abs() < 1e-12 && (o.centre.y - 20.5).abs() < 1e-12);
        assert!((o.cov[(0, 0)] - 15.0 / 12.0).abs() < 1e-12);
        assert!((o.cov[(1, 1)] - 3.0 / 12.0).abs() < 1e-12);
        assert!(o.cov[(0, 1)].abs() < 1e-12);
        assert_eq!(o.area, 8.0);
    }

    #[test]
    fn filled_ellipse_moments_give_its_semi_axes() {
        // Sample a rotated filled ellipse densely and read a, b back along its own axes.
        let (a, b, th) = (12.0_f64, 7.0_f64, 0.4_f64);
        let e = Ellipse {
            cx: 0.0,
            cy: 0.0,
            a,
            b,
            theta: th,
        };
        let mut s = [0.0; 6];
        let step = 0.05;
        let mut y = -15.0;
        while y < 15.0 {
            let mut x = -15.0;
            while x < 15.0 {
                if e.contains(x, y) {
                    s[0] += 1.0;
                    s[1] += x;
                    s[2] += y;
                    s[3] += x * x;
                    s[4] += x * y;
                    s[5] += y * y;
                }
                x += step;
            }
            y += step;
        }
        let o = moments_from_sums(&s, 1.0 / (step * step), 0.0, 0.0);
        let (ea, eb) = o.axes_along(th);
        assert!((ea - a).abs() / a < 2e-3, "{ea}");
        assert!((eb - b).abs() / b < 2e-3, "{eb}");
        assert!((o.area - e.area()).abs() / e.area() < 2e-3);
    }
}
