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
//! (`R_{−1} = I`, the keyframe's pose, at the keyframe's frame). The keyframe's own
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
}

impl Default for BundleParams {
    fn default() -> Self {
        Self {
            depth_sigma: 12.0,
            rotation_sigma: [0.05; 3],
            huber: 1.0,
            iterations: 8,
        }
    }
}

/// Most views [`refine`] adjusts together: its normal equations are dense in the views' poses
/// (`6 n` unknowns, `(6 n)²` entries), so 256 views take 19 MB and a solve of about 4·10⁹
/// operations a step; the tracker uses 7 to 10.
pub const MAX_VIEWS: usize = 256;

/// Most Gauss-Newton iterations [`refine`] runs (the tracker runs 8).
pub const MAX_ITERATIONS: usize = 1000;

impl BundleParams {
    /// Checks the settings: positive, finite sigmas and Huber threshold, and 1 to
    /// [`MAX_ITERATIONS`] iterations.
    pub fn check(&self) -> Result<(), PoseError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.depth_sigma) || !self.rotation_sigma.iter().all(|&v| positive(v)) {
            return Err(PoseError::InvalidParameter(
                "bundle sigmas (depth, rotation) must be positive and finite",
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
/// after; `views` get the refined poses.
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
    let (nv, np) = (views.len(), x0.len());
    if views.iter().any(|v| {
        v.seen
            .iter()
            .any(|(j, q)| *j >= np || !q[0].is_finite() || !q[1].is_finite())
    }) {
        return Err(PoseError::InvalidParameter(
            "bundle view sees an unknown feature",
        ));
    }
    let mut z: Vec<f64> = x0.iter().map(|x| x.z).collect();
    let z0 = z.clone();
    let wz = 1.0 / (params.depth_sigma * params.depth_sigma);
    let cost = |views: &[BundleView], z: &[f64]| -> f64 {
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
        for j in 0..z.len() {
            c += wz * (z[j] - z0[j]).powi(2);
        }
        for (e, df) in rotation_steps(views, key_frame) {
            for k in 0..3 {
                c += (e[k] / params.rotation_sigma[k]).powi(2) / df;
            }
        }
        c
    };
    let mut current = cost(views, &z);
    let start_cost = current;
    let mut lambda = 1e-3;
    for _ in 0..params.iterations {
        // Normal equations: pose block (6 per view), depth diagonal, and their coupling.
        let mut hpp = DMatrix::<f64>::zeros(6 * nv, 6 * nv);
        let mut bp = DVector::<f64>::zeros(6 * nv);
        let mut hzz = vec![wz; np];
        let mut bz: Vec<f64> = (0..np).map(|j| -wz * (z[j] - z0[j])).collect();
        let mut hpz = DMatrix::<f64>::zeros(6 * nv, np);
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
                    bp[o + a] += jtr[a];
                    for b in 0..6 {
                        hpp[(o + a, o + b)] += jtj[(a, b)];
                    }
                    hpz[(o + a, *j)] += w * (jp[(0, a)] * jz.x + jp[(1, a)] * jz.y);
                }
                hzz[*j] += w * jz.norm_squared();
                bz[*j] += w * jz.dot(&r);
            }
        }
        // The rotation prior between successive views (first order in the updates).
        for (i, (e, df)) in rotation_steps(views, key_frame).enumerate() {
            for k in 0..3 {
                let w = 1.0 / (params.rotation_sigma[k].powi(2) * df);
                let (a, b) = (6 * i + k, i.checked_sub(1).map(|p| 6 * p + k));
                hpp[(a, a)] += w;
                bp[a] -= w * e[k];
                if let Some(b) = b {
                    hpp[(b, b)] += w;
                    hpp[(a, b)] -= w;
                    hpp[(b, a)] -= w;
                    bp[b] += w * e[k];
                }
            }
        }
        let mut improved = false;
        for _ in 0..6 {
            // Schur complement of the (damped) depth diagonal.
            let hzd: Vec<f64> = hzz.iter().map(|h| h * (1.0 + lambda)).collect();
            let mut s = hpp.clone();
            for k in 0..6 * nv {
                s[(k, k)] += lambda * hpp[(k, k)] + 1e-9;
            }
            let mut rhs = bp.clone();
            for j in 0..np {
                let col = hpz.column(j);
                if col.iter().all(|v| *v == 0.0) {
                    continue;
                }
                s -= col * col.transpose() / hzd[j];
                rhs -= col * (bz[j] / hzd[j]);
            }
            let Some(chol) = s.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let dp = chol.solve(&rhs);
            let dz: Vec<f64> = (0..np)
                .map(|j| (bz[j] - hpz.column(j).dot(&dp)) / hzd[j])
                .collect();
            let mut trial = views.to_vec();
            for (i, v) in trial.iter_mut().enumerate() {
                let o = 6 * i;
                v.rot = exp_so3(&Vector3::new(dp[o], dp[o + 1], dp[o + 2])) * v.rot;
                v.scale *= dp[o + 3].clamp(-0.5, 0.5).exp();
                v.centre += Vector2::new(dp[o + 4], dp[o + 5]);
            }
            let tz: Vec<f64> = z.iter().zip(&dz).map(|(a, b)| a + b).collect();
            let c = cost(&trial, &tz);
            if c.is_finite() && c < current {
                views.clone_from_slice(&trial);
                z = tz;
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
    if !current.is_finite() {
        return Err(PoseError::NonFinite);
    }
    Ok(Adjusted {
        points: (0..np)
            .map(|j| on_ray(&x0[j], z[j], camera, key_centre))
            .collect(),
        start_cost,
        cost: current,
        observations: views.iter().map(|v| v.seen.len()).sum(),
    })
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
