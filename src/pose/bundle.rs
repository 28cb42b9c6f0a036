//! Bundle adjustment of a keyframe's feature depths and the poses of the views that matched it
//! (beyond the paper).
//!
//! The keyframe fit of [`super::prior`] lifts a view's features onto an ellipsoid. Where the
//! object is not one (the synthetic `car` is a box) the lifted depths are wrong, and two views
//! cannot tell: under near-affine projection a turn by `θ` of points at depths `z` looks like a
//! turn by `kθ` of points at depths `z / k` (the bas-relief ambiguity). Several views spread over
//! a turn can, through the foreshortening that grows as `1 - cos θ`. This module refines, from
//! the views a keyframe was matched in, each feature's depth along its keyframe ray together
//! with every view's pose `(R, s, t)`, the model of [`super::prior::fit_points`]:
//!
//! `Σ_views Σ_j ρ(|q_ij − view_i(x_j(z_j))|²) + Σ_j ((z_j − z0_j) / σ_z)² +
//!  Σ_i |log(R_i R_{i−1}ᵀ)|²_{σ_ω √(f_i − f_{i−1})}`
//!
//! with `ρ` a Huber loss (1 px), `z0` the lifted depths and `σ_z` their prior, and the last
//! term the tracker's own random-walk prior on the rotation between successive views
//! (`R_{−1} = I`, the keyframe's pose, at the keyframe's frame). With
//! [`BundleParams::relief_sigma`] the depths are held near the lift's relief scaled by a free
//! factor `k` instead, `z0_j` becoming `m0 + k (z0_j − m0)` (`m0` the lifted depths' mean),
//! and `(ln k / σ_k)²` is added. The keyframe's own
//! observations hold exactly by construction (each point stays on its ray), which fixes the
//! gauge but for a common shift of the depths (with each view's centre moved to match,
//! exactly so under weak perspective), which the depth prior holds. Gauss-Newton with the
//! depths eliminated (Schur complement), Levenberg damping. The tracker adjusts its keyframes
//! with it ([`crate::tracker::TrackerConfig::bundle`]).

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, Vector2, Vector3};

use super::PoseError;
use super::prior::{Pinhole, project};
use crate::filter::rotation_mean::{exp_so3, log_so3};

/// One view of a keyframe's features: its pose relative to the keyframe (as
/// [`super::prior::PriorFit`] gives it) and where it saw which features.
#[derive(Debug, Clone, PartialEq)]
pub struct BundleView {
    /// The frame the view was taken in (for the rotation prior's spacing).
    pub frame: usize,
    /// Rotation from the keyframe's pose.
    pub rot: Matrix3<f64>,
    /// Scale relative to the keyframe.
    pub scale: f64,
    /// Image of the keyframe ellipse's centre (pixels).
    pub centre: Vector2<f64>,
    /// `(feature index in the keyframe, image position)` of each feature seen.
    pub seen: Vec<(usize, [f64; 2])>,
}

/// What [`refine`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct Adjusted {
    /// The refined points, one per keyframe point.
    pub points: Vec<Vector3<f64>>,
    /// The objective at the start (the views as given, the points as lifted).
    pub start_cost: f64,
    /// The objective at the end.
    pub cost: f64,
    /// Feature observations in the views.
    pub observations: usize,
    /// The refined relief of the lifted depths, with [`BundleParams::relief_sigma`]; `None`
    /// without it, or where the system leaves it undetermined.
    pub relief: Option<Relief>,
}

/// How [`refine`] found the relief of the lifted depths: the depths are held near the lift's
/// relief scaled by `k = e^log` (about their mean), and `log` comes with its variance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Relief {
    /// `ln k`: 0 where the lift's relief is kept, below 0 where the object is flatter than
    /// its model, above 0 where it is deeper.
    pub log: f64,
    /// The variance of `log`, the views' poses and the depths marginalised out (Gauss-Newton,
    /// at the end): large where the views say little about the relief.
    pub variance: f64,
}

/// Settings of [`refine`].
///
/// The rotation prior holds views that few features pin down, and costs a little turn where
/// they are pinned: on exact views of a box corner turning 30° (every third frame, depth σ
/// 100 px) the default rotation σ left about a tenth of the turn unread (measured), where
/// priors too weak to matter recover it to 0.01° (tested).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BundleParams {
    /// σ of the depth prior about the lifted depth (pixels).
    pub depth_sigma: f64,
    /// σ of the rotation's random walk per frame about each camera axis (radians;
    /// `rotation_sigma_deg` in a settings file, in degrees).
    #[serde(rename = "rotation_sigma_deg", with = "crate::io::degrees::three")]
    pub rotation_sigma: [f64; 3],
    /// Huber threshold of the reprojection error (pixels).
    pub huber: f64,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// σ of a prior on the log of one relief factor `k` for all the depths, which then are
    /// held near the lift's relief scaled by `k` (about the lifted depths' mean) rather than
    /// near the lift itself: the direction of the bas-relief ambiguity that several views
    /// can settle where the object is flatter or deeper than its model. `None` (the
    /// default): `k` is 1. The tracker pools what its keyframes' adjustments find and lifts
    /// every keyframe fit with it ([`crate::tracker::BundleAdjust`]).
    pub relief_sigma: Option<f64>,
}

impl Default for BundleParams {
    fn default() -> Self {
        Self {
            depth_sigma: 12.0,
            rotation_sigma: [0.05; 3],
            huber: 1.0,
            iterations: 8,
            relief_sigma: None,
        }
    }
}

/// Most views [`refine`] adjusts together: its normal equations are dense in the views' poses
/// (`6 n` unknowns, `(6 n)²` entries), so 256 views take 19 MB and a solve of about 4·10⁹
/// operations a step; the tracker uses 7 to 10.
pub const MAX_VIEWS: usize = 256;

/// Most Gauss-Newton iterations [`refine`] runs (the tracker runs 8).
pub const MAX_ITERATIONS: usize = 1000;

/// The range of [`BundleParams::relief_sigma`]: a σ of 0.001 on `ln k` holds the factor to
/// its start as firmly as any smaller one, and one of 1000 leaves it as free as any larger;
/// far beyond them `1 / σ²` leaves what `f64` holds (1e200 gave no adjustment at all).
pub const RELIEF_SIGMA_RANGE: std::ops::RangeInclusive<f64> = 1e-3..=1e3;

impl BundleParams {
    /// Checks the settings: positive, finite sigmas and Huber threshold, a relief σ (where
    /// there is one) in [`RELIEF_SIGMA_RANGE`], and 1 to [`MAX_ITERATIONS`] iterations.
    pub fn check(&self) -> Result<(), PoseError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.depth_sigma) || !self.rotation_sigma.iter().all(|&v| positive(v)) {
            return Err(PoseError::InvalidParameter(
                "bundle sigmas (depth, rotation) must be positive and finite",
            ));
        }
        if !self
            .relief_sigma
            .is_none_or(|v| RELIEF_SIGMA_RANGE.contains(&v))
        {
            return Err(PoseError::InvalidParameter(
                "bundle relief sigma must lie from 0.001 to 1000",
            ));
        }
        if !positive(self.huber) {
            return Err(PoseError::InvalidParameter(
                "bundle Huber threshold must be positive and finite",
            ));
        }
        if !(1..=MAX_ITERATIONS).contains(&self.iterations) {
            return Err(PoseError::InvalidParameter(
                "bundle iterations must be from 1 to 1000",
            ));
        }
        Ok(())
    }
}

/// The point of depth `z` on the keyframe ray through `x0`.
fn on_ray(
    x0: &Vector3<f64>,
    z: f64,
    camera: Option<&Pinhole>,
    key_centre: &Vector2<f64>,
) -> Vector3<f64> {
    match camera {
        None => Vector3::new(x0.x, x0.y, z),
        Some(c) => {
            let origin = Vector3::new(
                c.principal.x - key_centre.x,
                c.principal.y - key_centre.y,
                -c.focal,
            );
            let d = x0 - origin;
            origin + (z - origin.z) / d.z * d
        }
    }
}

/// The points `x` (lifted, in a keyframe's model frame whose centre projects to
/// `key_centre`) with their relief about the model's centre scaled by `k`: each moved along
/// its keyframe ray to `k` times its depth, so the keyframe still sees it where it did. About
/// the centre, not the points' mean as [`refine`] scales, so that a feature's depth does not
/// depend on which others matched; the mean depth that moves is a common shift, which a fit's
/// centre takes up (exactly under weak perspective).
pub(crate) fn relieved(
    x: &[Vector3<f64>],
    k: f64,
    camera: Option<&Pinhole>,
    key_centre: &Vector2<f64>,
) -> Vec<Vector3<f64>> {
    x.iter()
        .map(|x| on_ray(x, k * x.z, camera, key_centre))
        .collect()
}

/// Each view's rotation step from the view before it (from the keyframe's own pose, the
/// identity, for the first) and the frames the step spans (at least 1): what the rotation
/// prior weighs.
fn rotation_steps(
    views: &[BundleView],
    key_frame: usize,
) -> impl Iterator<Item = (Vector3<f64>, f64)> + '_ {
    let before = std::iter::once((Matrix3::identity(), key_frame))
        .chain(views.iter().map(|v| (v.rot, v.frame)));
    views.iter().zip(before).map(|(v, (rot, frame))| {
        (
            log_so3(&(v.rot * rot.transpose())),
            v.frame.saturating_sub(frame).max(1) as f64,
        )
    })
}

/// Refines the depths of the keyframe points `x0` (lifted, in the keyframe's model frame,
/// whose centre projects to `key_centre`) and the poses of `views` (sorted by frame, the
/// keyframe taken at `key_frame`). Returns the refined points and the objective before and
/// after; `views` get the refined poses. With [`BundleParams::relief_sigma`], the relief of
/// the lifted depths is refined too, and [`Adjusted::relief`] says by how much.
///
/// Errors: settings [`BundleParams::check`] refuses, more than [`MAX_VIEWS`] views,
/// non-finite input, or a feature index out of range. A system that stays singular however
/// much it is damped is no error: the points and poses come back unchanged (the objective
/// after equal to the one before).
pub fn refine(
    x0: &[Vector3<f64>],
    key_centre: &Vector2<f64>,
    key_frame: usize,
    camera: Option<&Pinhole>,
    views: &mut [BundleView],
    params: &BundleParams,
) -> Result<Adjusted, PoseError> {
    params.check()?;
    if views.len() > MAX_VIEWS {
        return Err(PoseError::InvalidParameter(
            "bundle adjustment of more than 256 views",
        ));
    }
    let np = x0.len();
    if views.iter().any(|v| {
        v.seen
            .iter()
            .any(|(j, q)| *j >= np || !q[0].is_finite() || !q[1].is_finite())
    }) {
        return Err(PoseError::InvalidParameter(
            "bundle view sees an unknown feature",
        ));
    }
    if x0.iter().any(|x| !x.iter().all(|v| v.is_finite())) {
        return Err(PoseError::NonFinite);
    }
    let problem = Problem::new(x0, key_centre, key_frame, camera, params, views.len());
    // The depths start at the lift's, which the prior holds.
    let mut z = problem.prior.z0.clone();
    let mut u = 0.0;
    let start_cost = problem.cost(views, &z, u);
    let current = problem.minimise(views, &mut z, &mut u, start_cost);
    if !current.is_finite() {
        return Err(PoseError::NonFinite);
    }
    Ok(Adjusted {
        points: (0..x0.len())
            .map(|j| on_ray(&x0[j], z[j], camera, key_centre))
            .collect(),
        start_cost,
        cost: current,
        observations: views.iter().map(|v| v.seen.len()).sum(),
        relief: problem.relief(views, &z, u),
    })
}

/// The objective [`refine`] minimises, for one keyframe's points and views: what it needs
/// besides the unknowns (the views' poses, the depths `z` and the log-relief `u`).
struct Problem<'a> {
    /// The lifted points.
    x0: &'a [Vector3<f64>],
    /// Where the keyframe's model centre projects.
    key_centre: &'a Vector2<f64>,
    /// The keyframe's frame (the rotation prior's first step starts there).
    key_frame: usize,
    camera: Option<&'a Pinhole>,
    params: &'a BundleParams,
    /// The prior on the depths and the relief.
    prior: DepthPrior,
    /// Index of the log-relief among the reduced unknowns (after 6 per view).
    iu: usize,
    /// Number of reduced unknowns: 6 per view, and the log-relief when it is free.
    nr: usize,
}

impl<'a> Problem<'a> {
    fn new(
        x0: &'a [Vector3<f64>],
        key_centre: &'a Vector2<f64>,
        key_frame: usize,
        camera: Option<&'a Pinhole>,
        params: &'a BundleParams,
        views: usize,
    ) -> Self {
        let z0: Vec<f64> = x0.iter().map(|x| x.z).collect();
        let prior = DepthPrior::new(&z0, params);
        // The unknowns the depths are eliminated onto: 6 per view, then the log-relief at `iu`.
        let iu = 6 * views;
        let nr = iu + usize::from(prior.relief.is_some());
        Self {
            x0,
            key_centre,
            key_frame,
            camera,
            params,
            prior,
            iu,
            nr,
        }
    }

    /// The objective at `(views, z, u)`.
    fn cost(&self, views: &[BundleView], z: &[f64], u: f64) -> f64 {
        let (x0, camera, key_centre, params) = (self.x0, self.camera, self.key_centre, self.params);
        let mut c = 0.0;
        for v in views {
            for (j, q) in &v.seen {
                let x = on_ray(&x0[*j], z[*j], camera, key_centre);
                let (y, _) = project(&x, &v.rot, v.scale, &v.centre, camera);
                let e = (Vector2::new(q[0], q[1]) - y).norm();
                c += if e <= params.huber {
                    e * e
                } else {
                    2.0 * params.huber * e - params.huber * params.huber
                };
            }
        }
        self.prior.add_cost(&mut c, z, u);
        for (e, df) in rotation_steps(views, self.key_frame) {
            for k in 0..3 {
                c += (e[k] / params.rotation_sigma[k]).powi(2) / df;
            }
        }
        c
    }

    /// Normal equations at `(views, z, u)`: the reduced block (6 per view and the
    /// log-relief), the depth diagonal, and their coupling.
    fn normal(&self, views: &[BundleView], z: &[f64], u: f64) -> Normal {
        let (np, nr) = (self.x0.len(), self.nr);
        let mut n = Normal {
            hpp: DMatrix::<f64>::zeros(nr, nr),
            bp: DVector::<f64>::zeros(nr),
            hzz: vec![0.0; np],
            bz: vec![0.0; np],
            hpz: DMatrix::<f64>::zeros(nr, np),
        };
        self.prior.add_to(&mut n, z, u, self.iu);
        self.add_observations(&mut n, views, z);
        self.add_rotation_prior(&mut n, views);
        n
    }

    /// The features' reprojections' Gauss-Newton terms (Huber-weighted).
    fn add_observations(&self, n: &mut Normal, views: &[BundleView], z: &[f64]) {
        let (x0, camera, key_centre, params) = (self.x0, self.camera, self.key_centre, self.params);
        for (i, v) in views.iter().enumerate() {
            for (j, q) in &v.seen {
                let x = on_ray(&x0[*j], z[*j], camera, key_centre);
                let (y, jp) = project(&x, &v.rot, v.scale, &v.centre, camera);
                let h = 1e-4;
                let x2 = on_ray(&x0[*j], z[*j] + h, camera, key_centre);
                let (y2, _) = project(&x2, &v.rot, v.scale, &v.centre, camera);
                let jz = (y2 - y) / h;
                let r = Vector2::new(q[0], q[1]) - y;
                let e = r.norm();
                let w = if e <= params.huber {
                    1.0
                } else {
                    params.huber / e
                };
                let jtj: SMatrix<f64, 6, 6> = jp.transpose() * jp * w;
                let jtr = jp.transpose() * r * w;
                let o = 6 * i;
                for a in 0..6 {
                    n.bp[o + a] += jtr[a];
                    for b in 0..6 {
                        n.hpp[(o + a, o + b)] += jtj[(a, b)];
                    }
                    n.hpz[(o + a, *j)] += w * (jp[(0, a)] * jz.x + jp[(1, a)] * jz.y);
                }
                n.hzz[*j] += w * jz.norm_squared();
                n.bz[*j] += w * jz.dot(&r);
            }
        }
    }

    /// The rotation prior between successive views (first order in the updates).
    fn add_rotation_prior(&self, n: &mut Normal, views: &[BundleView]) {
        for (i, (e, df)) in rotation_steps(views, self.key_frame).enumerate() {
            for k in 0..3 {
                let w = 1.0 / (self.params.rotation_sigma[k].powi(2) * df);
                let (a, b) = (6 * i + k, i.checked_sub(1).map(|p| 6 * p + k));
                n.hpp[(a, a)] += w;
                n.bp[a] -= w * e[k];
                if let Some(b) = b {
                    n.hpp[(b, b)] += w;
                    n.hpp[(a, b)] -= w;
                    n.hpp[(b, a)] -= w;
                    n.bp[b] += w * e[k];
                }
            }
        }
    }

    /// Levenberg-Marquardt from `(views, z, u)`, whose objective is `current`, for at most
    /// the settings' iterations: each step that lowers the objective is taken (and the
    /// damping eased), one that does not is tried again more damped, up to 6 times. Returns
    /// the objective at the end; the unknowns are left there.
    fn minimise(
        &self,
        views: &mut [BundleView],
        z: &mut Vec<f64>,
        u: &mut f64,
        mut current: f64,
    ) -> f64 {
        let mut lambda = 1e-3;
        for _ in 0..self.params.iterations {
            let n = self.normal(views, z, *u);
            let mut improved = false;
            for _ in 0..6 {
                let Some((dp, dz)) = n.solve(lambda) else {
                    lambda *= 10.0;
                    continue;
                };
                let mut trial = views.to_vec();
                for (i, v) in trial.iter_mut().enumerate() {
                    let o = 6 * i;
                    v.rot = exp_so3(&Vector3::new(dp[o], dp[o + 1], dp[o + 2])) * v.rot;
                    v.scale *= dp[o + 3].clamp(-0.5, 0.5).exp();
                    v.centre += Vector2::new(dp[o + 4], dp[o + 5]);
                }
                let tz: Vec<f64> = z.iter().zip(&dz).map(|(a, b)| a + b).collect();
                let tu = if self.prior.relief.is_some() {
                    *u + dp[self.iu].clamp(-0.5, 0.5)
                } else {
                    *u
                };
                let c = self.cost(&trial, &tz, tu);
                if c.is_finite() && c < current {
                    views.clone_from_slice(&trial);
                    *z = tz;
                    *u = tu;
                    current = c;
                    lambda = (lambda * 0.3).max(1e-6);
                    improved = true;
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        current
    }

    /// The log-relief and its variance at `(views, z, u)`: its entry in the inverse of the
    /// undamped reduced system (the depths and the views' poses marginalised out), without
    /// the solve's jitter, which would count as evidence. `None` without a free relief, or
    /// where that system is singular (the relief left unmeasured, though the points took it).
    fn relief(&self, views: &[BundleView], z: &[f64], u: f64) -> Option<Relief> {
        self.prior.relief?;
        let n = self.normal(views, z, u);
        let s = n.reduced(0.0, 0.0)?.0.cholesky()?;
        let mut e = DVector::<f64>::zeros(self.nr);
        e[self.iu] = 1.0;
        let variance = s.solve(&e)[self.iu];
        (variance.is_finite() && variance > 0.0).then_some(Relief { log: u, variance })
    }
}

/// The depth prior of [`refine`]: each depth about its lift, `((z_j − t_j(u)) / σ_z)²`, with
/// `t_j(u) = m0 + e^u (z0_j − m0)` the lift's relief scaled by `k = e^u` about the lifted
/// depths' mean `m0` (scaling about the model's centre would mostly move the mean depth,
/// which the views' centres take up as the gauge), and `(u / σ_k)²` on the log-relief when
/// it is free (`u` stays 0 otherwise).
struct DepthPrior {
    /// The lifted depths.
    z0: Vec<f64>,
    /// Their mean.
    m0: f64,
    /// `1 / σ_z²`.
    wz: f64,
    /// `1 / σ_k²` when the relief is free.
    relief: Option<f64>,
}

impl DepthPrior {
    fn new(z0: &[f64], params: &BundleParams) -> Self {
        let m0 = if z0.is_empty() {
            0.0
        } else {
            z0.iter().sum::<f64>() / z0.len() as f64
        };
        Self {
            z0: z0.to_vec(),
            m0,
            wz: 1.0 / (params.depth_sigma * params.depth_sigma),
            relief: params.relief_sigma.map(|s| 1.0 / (s * s)),
        }
    }

    /// The depth `z_j` is held near, and its derivative in `u` (the lift itself, exactly,
    /// when the relief is not free).
    fn target(&self, j: usize, u: f64) -> (f64, f64) {
        if self.relief.is_none() {
            return (self.z0[j], 0.0);
        }
        let d = u.exp() * (self.z0[j] - self.m0);
        (self.m0 + d, d)
    }

    /// Adds the prior's terms at `(z, u)` to the objective `c`.
    fn add_cost(&self, c: &mut f64, z: &[f64], u: f64) {
        for (j, zj) in z.iter().enumerate() {
            *c += self.wz * (zj - self.target(j, u).0).powi(2);
        }
        if let Some(w) = self.relief {
            *c += w * u * u;
        }
    }

    /// Adds the prior's Gauss-Newton terms at `(z, u)`, the log-relief at index `iu` of the
    /// reduced unknowns.
    fn add_to(&self, n: &mut Normal, z: &[f64], u: f64, iu: usize) {
        for (j, zj) in z.iter().enumerate() {
            let (t, dt) = self.target(j, u);
            let rho = zj - t;
            n.hzz[j] += self.wz;
            n.bz[j] -= self.wz * rho;
            if self.relief.is_some() {
                // d rho / d u = -dt.
                n.hpp[(iu, iu)] += self.wz * dt * dt;
                n.bp[iu] += self.wz * rho * dt;
                n.hpz[(iu, j)] -= self.wz * dt;
            }
        }
        if let Some(w) = self.relief {
            n.hpp[(iu, iu)] += w;
            n.bp[iu] -= w * u;
        }
    }
}

/// Gauss-Newton normal equations of [`refine`], the depths apart.
struct Normal {
    /// The reduced unknowns' block (6 per view, then the log-relief when free).
    hpp: DMatrix<f64>,
    bp: DVector<f64>,
    /// The depths' diagonal.
    hzz: Vec<f64>,
    bz: Vec<f64>,
    /// Reduced unknowns × depths.
    hpz: DMatrix<f64>,
}

impl Normal {
    /// The Schur complement of the depth diagonal, damped by `lambda` (Levenberg-Marquardt)
    /// and `jitter` added to its diagonal, its right-hand side and the damped diagonal; `None`
    /// where a depth has no information.
    fn reduced(&self, lambda: f64, jitter: f64) -> Option<(DMatrix<f64>, DVector<f64>, Vec<f64>)> {
        let hzd: Vec<f64> = self.hzz.iter().map(|h| h * (1.0 + lambda)).collect();
        if !hzd.iter().all(|h| *h > 0.0) {
            return None;
        }
        let mut s = self.hpp.clone();
        for k in 0..s.nrows() {
            s[(k, k)] += lambda * self.hpp[(k, k)] + jitter;
        }
        let mut rhs = self.bp.clone();
        for (j, h) in hzd.iter().enumerate() {
            let col = self.hpz.column(j);
            if col.iter().all(|v| *v == 0.0) {
                continue;
            }
            s -= col * col.transpose() / *h;
            rhs -= col * (self.bz[j] / *h);
        }
        Some((s, rhs, hzd))
    }

    /// The damped step: the reduced unknowns' and the depths'.
    fn solve(&self, lambda: f64) -> Option<(DVector<f64>, Vec<f64>)> {
        let (s, rhs, hzd) = self.reduced(lambda, 1e-9)?;
        let dp = s.cholesky()?.solve(&rhs);
        let dz = (0..hzd.len())
            .map(|j| (self.bz[j] - self.hpz.column(j).dot(&dp)) / hzd[j])
            .collect();
        Some((dp, dz))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::angle_between;
    use crate::pose::prior::view_of;

    fn camera() -> Pinhole {
        Pinhole {
            focal: 170.0,
            principal: Vector2::new(79.5, 59.5),
        }
    }

    /// A box's corner facing the camera (two faces meeting at a vertical edge, 40 x 20 px),
    /// its points' images in the keyframe, and `n` views turning 1° a frame about the vertical
    /// axis, every third frame, seen exactly.
    fn corner(n: usize) -> (Vec<Vector3<f64>>, Vec<[f64; 2]>, Vec<BundleView>) {
        let (cam, centre) = (camera(), Vector2::new(80.0, 60.0));
        let mut x = Vec::new();
        for i in 0..9 {
            for j in 0..5 {
                let u = -20.0 + 5.0 * f64::from(i) + 0.7 * f64::from(j);
                let v = -10.0 + 5.0 * f64::from(j);
                x.push(Vector3::new(u, v, -15.0 + 0.8 * u.abs()));
            }
        }
        let id = Matrix3::identity();
        let p = x
            .iter()
            .map(|xj| {
                let q = view_of(xj, &id, 1.0, &centre, Some(&cam));
                [q.x, q.y]
            })
            .collect();
        let views = (1..=n)
            .map(|k| {
                let frame = 3 * k;
                let rot =
                    *nalgebra::Rotation3::from_euler_angles(0.0, (frame as f64).to_radians(), 0.0)
                        .matrix();
                let seen = x
                    .iter()
                    .enumerate()
                    .map(|(j, xj)| {
                        let q = view_of(xj, &rot, 1.0, &centre, Some(&cam));
                        (j, [q.x, q.y])
                    })
                    .collect();
                BundleView {
                    frame,
                    rot,
                    scale: 1.0,
                    centre,
                    seen,
                }
            })
            .collect();
        (x, p, views)
    }

    #[test]
    fn several_views_recover_a_box_turn_the_wrong_depths_halved() {
        let (x, _, truth) = corner(10);
        let (cam, centre) = (camera(), Vector2::new(80.0, 60.0));
        // Start from a flat front (every depth -8) and views turned half as far as they are:
        // what a fit on the wrong shape reads (the bas-relief trade of depth for angle).
        let x0: Vec<Vector3<f64>> = x
            .iter()
            .map(|xj| on_ray(xj, -8.0, Some(&cam), &centre))
            .collect();
        let mut views: Vec<BundleView> = truth
            .iter()
            .map(|v| BundleView {
                rot: exp_so3(&(0.5 * log_so3(&v.rot))),
                ..v.clone()
            })
            .collect();
        let start_error = angle_between(&views[9].rot, &truth[9].rot).to_degrees();
        assert!(start_error > 14.0, "{start_error}");
        // Priors too weak to pull: the answer is the data's.
        let params = BundleParams {
            depth_sigma: 1000.0,
            rotation_sigma: [1.0; 3],
            iterations: 50,
            ..BundleParams::default()
        };
        let points = refine(&x0, &centre, 0, Some(&cam), &mut views, &params)
            .unwrap()
            .points;
        for (v, t) in views.iter().zip(&truth) {
            let e = angle_between(&v.rot, &t.rot).to_degrees();
            assert!(e < 0.02, "frame {}: {e}° off", v.frame);
        }
        // The depths come back up to a common offset: moving every point along the depth
        // axis and each view's centre to match is (nearly, under perspective) the same scene,
        // and only the depth prior holds it. The relief is the data's.
        let offset = points.iter().zip(&x).map(|(a, b)| a.z - b.z).sum::<f64>() / x.len() as f64;
        let worst = points
            .iter()
            .zip(&x)
            .map(|(a, b)| (a.z - offset - b.z).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.25, "a depth {worst} px off (offset {offset})");
        let start = x0
            .iter()
            .zip(&x)
            .map(|(a, b)| (a.z - b.z).abs())
            .fold(0.0, f64::max);
        assert!(start > 5.0, "{start}");
    }

    /// Depths lifted with half the box's relief and held to it firmly: with the relief fixed
    /// the views keep a good part of the bas-relief error, with it free the adjustment finds
    /// the factor of 2 and the turn.
    #[test]
    fn a_free_relief_recovers_the_depths_lifted_too_flat() {
        let (x, _, truth) = corner(10);
        let (cam, centre) = (camera(), Vector2::new(80.0, 60.0));
        let m = x.iter().map(|xj| xj.z).sum::<f64>() / x.len() as f64;
        let x0: Vec<Vector3<f64>> = x
            .iter()
            .map(|xj| on_ray(xj, m + 0.5 * (xj.z - m), Some(&cam), &centre))
            .collect();
        let half_turned = || -> Vec<BundleView> {
            truth
                .iter()
                .map(|v| BundleView {
                    rot: exp_so3(&(0.5 * log_so3(&v.rot))),
                    ..v.clone()
                })
                .collect()
        };
        let fixed = BundleParams {
            depth_sigma: 0.5,
            rotation_sigma: [1.0; 3],
            iterations: 50,
            ..BundleParams::default()
        };
        let worst = |views: &[BundleView]| {
            views
                .iter()
                .zip(&truth)
                .map(|(v, t)| angle_between(&v.rot, &t.rot).to_degrees())
                .fold(0.0, f64::max)
        };
        let mut views = half_turned();
        let held = refine(&x0, &centre, 0, Some(&cam), &mut views, &fixed).unwrap();
        assert!(held.relief.is_none());
        let held_error = worst(&views);
        assert!(held_error > 2.0, "{held_error}");
        let free = BundleParams {
            relief_sigma: Some(10.0),
            ..fixed
        };
        let mut views = half_turned();
        let adjusted = refine(&x0, &centre, 0, Some(&cam), &mut views, &free).unwrap();
        let relief = adjusted.relief.expect("a relief");
        let k = relief.log.exp();
        assert!((k - 2.0).abs() < 0.02, "k {k}");
        assert!(
            relief.variance > 0.0 && relief.variance < 0.01,
            "{relief:?}"
        );
        let free_error = worst(&views);
        assert!(free_error < 0.05, "{free_error}° off (held: {held_error}°)");
        for (a, b) in adjusted.points.iter().zip(&x) {
            assert!((a.z - b.z).abs() < 0.1, "{} against {}", a.z, b.z);
        }
    }

    /// Views that do not turn say nothing of the relief: its variance stays the prior's.
    #[test]
    fn views_without_a_turn_leave_the_relief_to_its_prior() {
        let (x, _, mut views) = corner(6);
        let centre = Vector2::new(80.0, 60.0);
        for v in &mut views {
            v.rot = Matrix3::identity();
            v.seen = x
                .iter()
                .enumerate()
                .map(|(j, xj)| (j, [xj.x + centre.x, xj.y + centre.y]))
                .collect();
        }
        let params = BundleParams {
            relief_sigma: Some(0.5),
            ..BundleParams::default()
        };
        let r = refine(&x, &centre, 0, None, &mut views, &params)
            .unwrap()
            .relief
            .expect("a relief");
        assert!(r.log.abs() < 1e-6, "{r:?}");
        assert!((r.variance / 0.25 - 1.0).abs() < 0.05, "{r:?}");
    }

    #[test]
    fn the_points_stay_on_their_keyframe_rays() {
        let (x, p, mut views) = corner(4);
        let (cam, centre) = (camera(), Vector2::new(80.0, 60.0));
        let x0: Vec<Vector3<f64>> = x
            .iter()
            .map(|xj| on_ray(xj, xj.z + 5.0, Some(&cam), &centre))
            .collect();
        let points = refine(
            &x0,
            &centre,
            0,
            Some(&cam),
            &mut views,
            &BundleParams::default(),
        )
        .unwrap()
        .points;
        for (xj, pj) in points.iter().zip(&p) {
            let q = view_of(xj, &Matrix3::identity(), 1.0, &centre, Some(&cam));
            assert!((q.x - pj[0]).abs() < 1e-9 && (q.y - pj[1]).abs() < 1e-9);
        }
        // Under weak perspective a ray is a line along z.
        let flat = refine(&x, &centre, 0, None, &mut views, &BundleParams::default())
            .unwrap()
            .points;
        for (a, b) in flat.iter().zip(&x) {
            assert_eq!((a.x, a.y), (b.x, b.y));
        }
    }

    #[test]
    fn a_view_of_an_unknown_feature_is_an_error() {
        let (x, _, mut views) = corner(2);
        views[1].seen.push((x.len(), [1.0, 2.0]));
        let centre = Vector2::new(80.0, 60.0);
        let r = refine(&x, &centre, 0, None, &mut views, &BundleParams::default());
        assert!(matches!(r, Err(PoseError::InvalidParameter(_))), "{r:?}");
        views[1].seen.pop();
        views[0].seen[0].1 = [f64::NAN, 0.0];
        let r = refine(&x, &centre, 0, None, &mut views, &BundleParams::default());
        assert!(r.is_err());
    }

    /// Settings that would divide by zero or run without end, and more views than the dense
    /// normal equations are sized for, are refused before any work.
    #[test]
    fn bad_settings_and_too_many_views_are_errors() {
        let (x, _, mut views) = corner(2);
        let centre = Vector2::new(80.0, 60.0);
        let d = BundleParams::default();
        for bad in [
            BundleParams {
                depth_sigma: 0.0,
                ..d
            },
            BundleParams {
                rotation_sigma: [0.05, f64::NAN, 0.05],
                ..d
            },
            BundleParams { huber: -1.0, ..d },
            BundleParams { iterations: 0, ..d },
            BundleParams {
                relief_sigma: Some(0.0),
                ..d
            },
            BundleParams {
                relief_sigma: Some(1e-200),
                ..d
            },
            BundleParams {
                relief_sigma: Some(1e200),
                ..d
            },
            BundleParams {
                relief_sigma: Some(f64::NAN),
                ..d
            },
            BundleParams {
                iterations: MAX_ITERATIONS + 1,
                ..d
            },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
            let r = refine(&x, &centre, 0, None, &mut views, &bad);
            assert!(matches!(r, Err(PoseError::InvalidParameter(_))), "{r:?}");
        }
        let mut many = vec![views[0].clone(); MAX_VIEWS + 1];
        let r = refine(&x, &centre, 0, None, &mut many, &d);
        assert!(matches!(r, Err(PoseError::InvalidParameter(_))), "{r:?}");
    }
}
