//! Rotation against a keyframe with an ellipsoid depth prior (beyond the paper).
//!
//! The paper's weak-perspective block model `q = R2 p + l` treats the object as flat: on a
//! curved object such as a head, out-of-plane rotation moves the visible surface across the
//! silhouette (parallax) far more than it foreshortens it, so the block's second singular value
//! (`cos θ`) stays near 1 while features slide by `r·sin θ`. Lifting each keyframe feature onto
//! an ellipsoid fitted to the keyframe's ellipse — `X = (p − c, z)` with
//! `z = −k·sqrt(a b)·sqrt(max(0, 1 − u² − v²))`, `(u, v)` the feature's normalised ellipse
//! coordinates — makes that parallax part of the model: `q ≈ t + s·(R X)_xy`. This module fits
//! `(R, s, t)` to the matches by robust Gauss-Newton from a starting pose (the previous
//! estimate), so the fit stays on the branch of the Necker pair the track is on. The same model
//! is the feature likelihood of [`crate::likelihood`].

use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};

use super::PoseError;
use crate::filter::rotation_mean::exp_so3;
use crate::geometry::Ellipse;

/// The result of [`fit_with_depth_prior`].
#[derive(Debug, Clone, PartialEq)]
pub struct PriorFit {
    /// Rotation from the keyframe's pose to the current one.
    pub rot: Matrix3<f64>,
    /// Scale of the current view relative to the keyframe.
    pub scale: f64,
    /// Image position of the keyframe ellipse's centre now (pixels).
    pub centre: Vector2<f64>,
    /// Matches within the final inlier threshold.
    pub inliers: Vec<bool>,
    /// RMS reprojection error over the inliers (pixels).
    pub residual: f64,
}

/// Lifts image points of the keyframe onto the ellipsoid prior (see the module docs).
pub fn lift(p: &[[f64; 2]], key: &Ellipse, depth_ratio: f64) -> Vec<Vector3<f64>> {
    let d = depth_ratio * (key.a * key.b).sqrt();
    p.iter()
        .map(|p| {
            let (u, v) = key.to_unit(p[0], p[1]);
            let z = -d * (1.0 - u * u - v * v).max(0.0).sqrt();
            Vector3::new(p[0] - key.cx, p[1] - key.cy, z)
        })
        .collect()
}

fn residuals(
    x: &[Vector3<f64>],
    q: &[[f64; 2]],
    r: &Matrix3<f64>,
    s: f64,
    t: &Vector2<f64>,
    out: &mut Vec<Vector2<f64>>,
) {
    out.clear();
    for (xj, qj) in x.iter().zip(q) {
        let y = r * xj;
        out.push(Vector2::new(qj[0] - t.x - s * y.x, qj[1] - t.y - s * y.y));
    }
}

/// Fits `q ≈ t + s·(R X)_xy` to matches `p` (keyframe) → `q` (current frame), with `X` the
/// keyframe points lifted by [`lift`], starting from `(rot0, scale0, centre0)`. Residuals
/// beyond `3 × max(1 px, median)` are dropped after each of a few rounds (robust to
/// mismatches). Needs at least 4 matches.
pub fn fit_with_depth_prior(
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    key: &Ellipse,
    depth_ratio: f64,
    rot0: &Matrix3<f64>,
    scale0: f64,
    centre0: Vector2<f64>,
) -> Result<PriorFit, PoseError> {
    if p.len() != q.len() {
        return Err(PoseError::Degenerate("p and q differ in length"));
    }
    if p.len() < 4 {
        return Err(PoseError::TooFewMatches {
            got: p.len(),
            need: 4,
        });
    }
    if p.iter()
        .chain(q)
        .any(|v| !v[0].is_finite() || !v[1].is_finite())
        || !key.is_valid()
    {
        return Err(PoseError::NonFinite);
    }
    let x = lift(p, key, depth_ratio);
    let mut rot = *rot0;
    let mut s = if scale0.is_finite() && scale0 > 0.0 {
        scale0
    } else {
        1.0
    };
    let mut t = centre0;
    let mut inl = vec![true; p.len()];
    let mut res = Vec::with_capacity(p.len());
    for round in 0..3 {
        for _ in 0..8 {
            // Parameters δ = (ω, ln s, t): R ← exp(ω) R, s ← s e^{δs}, t ← t + δt.
            let mut jtj = SMatrix::<f64, 6, 6>::zeros();
            let mut jtr = SVector::<f64, 6>::zeros();
            for (j, (xj, qj)) in x.iter().zip(q).enumerate() {
                if !inl[j] {
                    continue;
                }
                let y = rot * xj;
                let r = Vector2::new(qj[0] - t.x - s * y.x, qj[1] - t.y - s * y.y);
                // d(s (exp(ω) y))_xy / dω at ω = 0 is s [ω× y]_xy = -s [y×] ω.
                let jx = SVector::<f64, 6>::from_column_slice(&[
                    0.0,
                    s * y.z,
                    -s * y.y,
                    s * y.x,
                    1.0,
                    0.0,
                ]);
                let jy = SVector::<f64, 6>::from_column_slice(&[
                    -s * y.z,
                    0.0,
                    s * y.x,
                    s * y.y,
                    0.0,
                    1.0,
                ]);
                jtj += jx * jx.transpose() + jy * jy.transpose();
                jtr += jx * r.x + jy * r.y;
            }
            // A light damping keeps the step defined when the points are nearly planar.
            for k in 0..6 {
                jtj[(k, k)] += 1e-6 + 1e-3 * jtj[(k, k)];
            }
            let Some(delta) = jtj.cholesky().map(|c| c.solve(&jtr)) else {
                return Err(PoseError::Degenerate("depth-prior fit is singular"));
            };
            rot = exp_so3(&Vector3::new(delta[0], delta[1], delta[2])) * rot;
            s *= delta[3].clamp(-0.5, 0.5).exp();
            t += Vector2::new(delta[4], delta[5]);
            if delta.norm() < 1e-9 {
                break;
            }
        }
        residuals(&x, q, &rot, s, &t, &mut res);
        let mut norms: Vec<f64> = res.iter().map(|r| r.norm()).collect();
        let mut sorted = norms.clone();
        sorted.sort_by(f64::total_cmp);
        let med = sorted[sorted.len() / 2];
        let thr = 3.0 * med.max(1.0);
        let new: Vec<bool> = norms.iter().map(|&n| n <= thr).collect();
        let count = new.iter().filter(|&&b| b).count();
        if count < 4 || (new == inl && round > 0) {
            break;
        }
        inl = new;
        norms.clear();
    }
    residuals(&x, q, &rot, s, &t, &mut res);
    let (mut sum, mut n) = (0.0, 0usize);
    for (r, &k) in res.iter().zip(&inl) {
        if k {
            sum += r.norm_squared();
            n += 1;
        }
    }
    let residual = if n > 0 {
        (sum / n as f64).sqrt()
    } else {
        f64::INFINITY
    };
    if !residual.is_finite() || !s.is_finite() {
        return Err(PoseError::NonFinite);
    }
    Ok(PriorFit {
        rot,
        scale: s,
        centre: t,
        inliers: inl,
        residual,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Euler, angle_between};

    fn scene(truth: &Euler, s: f64, t: Vector2<f64>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>, Ellipse) {
        let key = Ellipse::new(80.0, 60.0, 20.0, 24.0);
        let mut p = Vec::new();
        for i in 0..40 {
            let a = i as f64 * 2.399;
            let r = 0.85 * ((i as f64 + 0.5) / 40.0).sqrt();
            let (u, v) = (r * a.cos(), r * a.sin());
            p.push([key.cx + u * key.a, key.cy + v * key.b]);
        }
        let x = lift(&p, &key, 1.0);
        let rm = truth.matrix();
        let q = x.iter().map(|x| {
            let y = rm * x;
            [t.x + s * y.x, t.y + s * y.y]
        });
        (p, q.collect(), key)
    }

    #[test]
    fn recovers_the_pose_exactly_from_model_data_and_keeps_the_sign() {
        for truth in [
            Euler::from_degrees(20.0, 0.0, 0.0),
            Euler::from_degrees(-20.0, 0.0, 0.0),
            Euler::from_degrees(10.0, -25.0, 15.0),
        ] {
            let t = Vector2::new(83.0, 57.5);
            let (p, q, key) = scene(&truth, 1.1, t);
            let f = fit_with_depth_prior(
                &p,
                &q,
                &key,
                1.0,
                &Matrix3::identity(),
                1.0,
                Vector2::new(80.0, 60.0),
            )
            .unwrap();
            assert!(
                angle_between(&f.rot, &truth.matrix()) < 1e-6,
                "{truth:?}: {:?}",
                Euler::from_matrix(&f.rot)
            );
            assert!((f.scale - 1.1).abs() < 1e-6 && (f.centre - t).norm() < 1e-6);
        }
    }

    #[test]
    fn drops_mismatches() {
        let truth = Euler::from_degrees(15.0, 10.0, 0.0);
        let (p, mut q, key) = scene(&truth, 1.0, Vector2::new(80.0, 60.0));
        q[3] = [0.0, 0.0];
        q[17][0] += 25.0;
        let f = fit_with_depth_prior(
            &p,
            &q,
            &key,
            1.0,
            &Matrix3::identity(),
            1.0,
            Vector2::new(80.0, 60.0),
        )
        .unwrap();
        assert!(!f.inliers[3] && !f.inliers[17]);
        assert!(angle_between(&f.rot, &truth.matrix()) < 1e-6);
    }

    #[test]
    fn bad_input_is_an_error() {
        let key = Ellipse::new(80.0, 60.0, 20.0, 24.0);
        let p = [[80.0, 60.0]; 3];
        assert!(
            fit_with_depth_prior(
                &p,
                &p,
                &key,
                1.0,
                &Matrix3::identity(),
                1.0,
                Vector2::zeros()
            )
            .is_err()
        );
        let p = [[f64::NAN, 60.0]; 5];
        assert!(
            fit_with_depth_prior(
                &p,
                &p,
                &key,
                1.0,
                &Matrix3::identity(),
                1.0,
                Vector2::zeros()
            )
            .is_err()
        );
    }
}
