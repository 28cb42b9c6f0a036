//! Feature term (CPU twin of `shaders/feature.wgsl`): the matched features of the previous
//! frame, lifted to 3D on an ellipsoid prior, moved with the particle's rotation relative to
//! the previous estimate, compared with where they were matched in the current frame.
//!
//! # Semantics (exact, shared with the GPU)
//! For each pair `(p, q)`: `X = (p.x - prev.cx, p.y - prev.cy, z)`, with `z` the caller's
//! depth of the pair ([`crate::likelihood::FrameInput::depths`]) or else the facing prior,
//! `(u, v) = E_prev.to_unit(p)` (theta = `theta0 + prev.rz`), `z = (-depth_ratio ·
//! sqrt(a_prev b_prev)) · sqrt(max(0, (1 - u²) - v²))`, computed once per frame on the host
//! for both engines; `ΔR = R_i R_prevᵀ` with `R = (Rx Ry) Rz` in `f32`;
//! `s = sqrt((a b) / (a_prev b_prev))`; `q̂ = (cx, cy) + s (ΔR X)_xy`;
//! `ln p_feature = ln Σ_j 1 / (ε + ‖q_j − q̂_j‖)`; no features: 0.

use glam::{Mat3, Vec3};

use super::EllipseF32;
use crate::likelihood::{FeaturePair, LiftedFeature, LikelihoodParams, Particle};

/// `R = (Rx(rx) · Ry(ry)) · Rz(rz)` in `f32` (the project's convention, `geometry::Euler`), as
/// a glam [`Mat3`] (re-exported as `pftrack::glam`): column-major, so entry (i, j) is
/// `m.col(j)[i]` (or `m.row(i)[j]`).
///
/// glam's products sum each entry as `(a0 b0 + a1 b1) + a2 b2`, the order `feature.wgsl`'s
/// `mat_mul` writes out, so the two engines differ only in `sin` and `cos`.
pub fn rotation(rx: f32, ry: f32, rz: f32) -> Mat3 {
    (Mat3::from_rotation_x(rx) * Mat3::from_rotation_y(ry)) * Mat3::from_rotation_z(rz)
}

/// What the feature term needs per frame: the lifted features and `R_prevᵀ`.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureFrame {
    /// Lifted features.
    pub lifted: Vec<LiftedFeature>,
    /// `R_prevᵀ`.
    pub r_prev_t: Mat3,
    /// `a_prev · b_prev`.
    pub ab_prev: f32,
}

/// Lifts one feature `p` onto the ellipsoid prior of the previous estimate.
pub fn lift(p: [f32; 2], prev: &Particle, theta0: f32, depth_ratio: f32) -> [f32; 3] {
    let e = EllipseF32::from_particle(prev, theta0);
    let (s, c) = e.theta.sin_cos();
    let dx = p[0] - prev.cx;
    let dy = p[1] - prev.cy;
    let u = (c * dx + s * dy) / prev.a;
    let v = (-s * dx + c * dy) / prev.b;
    [dx, dy, prior_depth(u, v, prev.a, prev.b, depth_ratio)]
}

/// The depth of the ellipsoid prior at normalised ellipse position `(u, v)` of an ellipse
/// with semi-axes `a`, `b`: `z = (−depth_ratio · sqrt(a b)) · sqrt(max(0, 1 − u² − v²))`,
/// towards the camera; 0 on and outside the rim.
pub fn prior_depth(u: f32, v: f32, a: f32, b: f32, depth_ratio: f32) -> f32 {
    let r2 = (1.0 - u * u - v * v).max(0.0);
    -depth_ratio * (a * b).sqrt() * r2.sqrt()
}

impl FeatureFrame {
    /// Prepares the features of a frame against the previous estimate: each lifted with its
    /// depth from `depths` (one per feature, checked by the engines) when given, else with
    /// the facing ellipsoid prior ([`lift`]).
    pub fn new(
        features: &[FeaturePair],
        depths: Option<&[f32]>,
        prev: &Particle,
        theta0: f32,
        params: &LikelihoodParams,
    ) -> Self {
        let lifted = features
            .iter()
            .enumerate()
            .map(|(j, f)| {
                let x = match depths.and_then(|d| d.get(j)) {
                    Some(&z) => [f.p[0] - prev.cx, f.p[1] - prev.cy, z],
                    None => lift(f.p, prev, theta0, params.depth_ratio),
                };
                LiftedFeature { x, q: f.q }
            })
            .collect();
        Self {
            lifted,
            r_prev_t: rotation(prev.rx, prev.ry, prev.rz).transpose(),
            ab_prev: prev.a * prev.b,
        }
    }

    /// `ln p_feature` of a particle (0 without features).
    pub fn log_likelihood(&self, particle: &Particle, eps: f32) -> f32 {
        if self.lifted.is_empty() {
            return 0.0;
        }
        let dr = rotation(particle.rx, particle.ry, particle.rz) * self.r_prev_t;
        // Only the image rows of `ΔR X` are needed.
        let (r0, r1) = (dr.row(0), dr.row(1));
        let s = ((particle.a * particle.b) / self.ab_prev).sqrt();
        let mut sum = 0.0f32;
        for f in &self.lifted {
            let x = Vec3::from_array(f.x);
            let px = r0.dot(x);
            let py = r1.dot(x);
            let qx = particle.cx + s * px;
            let qy = particle.cy + s * py;
            let ex = f.q[0] - qx;
            let ey = f.q[1] - qy;
            sum += 1.0 / (eps + (ex * ex + ey * ey).sqrt());
        }
        sum.ln()
    }
}

/// `ln p_feature` of one particle (convenience over [`FeatureFrame`], same result).
pub fn log_likelihood(
    features: &[FeaturePair],
    particle: &Particle,
    prev: &Particle,
    theta0: f32,
    params: &LikelihoodParams,
) -> f32 {
    FeatureFrame::new(features, None, prev, theta0, params)
        .log_likelihood(particle, params.feature_eps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Euler;

    #[test]
    fn rotation_matches_geometry() {
        for &(rx, ry, rz) in &[(0.3, -0.2, 1.1), (-1.0, 0.5, 0.0), (2.0, 1.2, -2.5)] {
            let m = rotation(rx, ry, rz);
            let r = Euler::new(rx as f64, ry as f64, rz as f64).matrix();
            for i in 0..3 {
                for j in 0..3 {
                    assert!((m.col(j)[i] as f64 - r[(i, j)]).abs() < 1e-6);
                }
            }
        }
    }

    #[test]
    fn lift_puts_the_centre_forward_and_the_rim_at_zero() {
        let prev = Particle {
            cx: 10.0,
            cy: 20.0,
            a: 4.0,
            b: 9.0,
            ..Default::default()
        };
        let z = lift([10.0, 20.0], &prev, 0.0, 0.5);
        assert_eq!(z, [0.0, 0.0, -0.5 * 6.0]);
        assert_eq!(lift([14.0, 20.0], &prev, 0.0, 0.5), [4.0, 0.0, 0.0]);
        // outside the ellipse: clamped to the rim
        assert_eq!(lift([10.0, 40.0], &prev, 0.0, 0.5)[2], 0.0);
        // theta turns the ellipse: (0, 4) is the end of the a axis at theta = pi/2
        let z = lift([10.0, 24.0], &prev, std::f32::consts::FRAC_PI_2, 0.5)[2];
        assert!(z.abs() < 1e-3, "{z}");
    }

    #[test]
    fn identity_motion_with_exact_matches_scores_sum_of_inverse_eps() {
        let prev = Particle {
            cx: 50.0,
            cy: 40.0,
            a: 20.0,
            b: 20.0,
            ..Default::default()
        };
        let feats: Vec<FeaturePair> = [[45.0, 38.0], [55.0, 47.0], [50.0, 30.0]]
            .iter()
            .map(|&p| FeaturePair { p, q: p })
            .collect();
        let params = LikelihoodParams::default();
        let l = log_likelihood(&feats, &prev, &prev, 0.0, &params);
        assert!((l - (3.0 / params.feature_eps).ln()).abs() < 1e-5, "{l}");
        assert_eq!(log_likelihood(&[], &prev, &prev, 0.0, &params), 0.0);
    }
}
