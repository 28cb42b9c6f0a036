//! EM baseline: the essential matrix by the normalised 8-point algorithm on calibrated points,
//! decomposed into rotation and translation (SPEC section 4).
//!
//! Convention: camera-frame points of frame t map to frame t+1 as `X2 = R X1 + t`, so with
//! normalised image points `x = K^-1 (u, v, 1)`, `x2^T E x1 = 0` with `E = [t]_x R`.
//! Steps: pixels to normalised coordinates with the intrinsics; Hartley normalisation (centre,
//! mean distance `sqrt 2`); the null vector of the stacked constraints (eigenvector of the
//! smallest eigenvalue of `M^T M`); denormalise; project onto the essential manifold
//! (singular values `1, 1, 0`); the four decompositions `(U W V^T, ±u3)`, `(U W^T V^T, ±u3)`;
//! the chirality check keeps the one with the most points in front of both cameras.

use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};

use super::PoseError;

/// Pinhole intrinsics (pixels): focal lengths and principal point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Focal length along x (pixels).
    pub fx: f64,
    /// Focal length along y (pixels).
    pub fy: f64,
    /// Principal point x (pixels).
    pub cx: f64,
    /// Principal point y (pixels).
    pub cy: f64,
}

impl Intrinsics {
    /// Normalised camera coordinates `K^-1 (u, v, 1)` of a pixel.
    pub fn normalise(&self, p: [f64; 2]) -> Vector3<f64> {
        Vector3::new((p[0] - self.cx) / self.fx, (p[1] - self.cy) / self.fy, 1.0)
    }
}

/// The outcome of the essential-matrix method.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EssentialPose {
    /// Inter-frame rotation (frame-t camera points to frame t+1).
    pub rotation: Matrix3<f64>,
    /// Unit translation direction.
    pub translation: Vector3<f64>,
    /// The essential matrix (singular values 1, 1, 0).
    pub essential: Matrix3<f64>,
    /// Matches triangulated in front of both cameras by the chosen decomposition.
    pub in_front: usize,
}

fn hartley(x: &[Vector3<f64>]) -> (Vec<Vector2<f64>>, Matrix3<f64>) {
    let n = x.len() as f64;
    let m = x
        .iter()
        .map(|v| Vector2::new(v[0], v[1]))
        .sum::<Vector2<f64>>()
        / n;
    let d = x
        .iter()
        .map(|v| (Vector2::new(v[0], v[1]) - m).norm())
        .sum::<f64>()
        / n;
    let s = if d > 0.0 { 2f64.sqrt() / d } else { 1.0 };
    let t = Matrix3::new(s, 0.0, -s * m[0], 0.0, s, -s * m[1], 0.0, 0.0, 1.0);
    let y = x
        .iter()
        .map(|v| (Vector2::new(v[0], v[1]) - m) * s)
        .collect();
    (y, t)
}

/// Depths `(z1, z2)` of a match under `(R, t)`: least squares of `z2 x2 = z1 R x1 + t`.
fn depths(r: &Matrix3<f64>, t: &Vector3<f64>, x1: &Vector3<f64>, x2: &Vector3<f64>) -> (f64, f64) {
    let a = r * x1;
    // [a, -x2] [z1, z2]^T = -t
    let m = SMatrix::<f64, 3, 2>::from_columns(&[a, -x2]);
    let mtm = m.transpose() * m;
    match mtm.try_inverse() {
        Some(inv) => {
            let z = inv * (m.transpose() * (-t));
            (z[0], z[1])
        }
        None => (-1.0, -1.0),
    }
}

/// Rotation (and translation direction) from at least 8 matches by the essential matrix.
///
/// Errors: fewer than 8 matches, non-finite input, a degenerate configuration (rank-deficient
/// constraints, as an exactly zero translation gives), or no decomposition with points in
/// front. A translation too small to measure against the matches' noise is not detected: its
/// direction is then noise, and the rotation chosen by the points' depths can be the twisted
/// pair's, half a turn off.
pub fn essential_rotation(
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    k: &Intrinsics,
) -> Result<EssentialPose, PoseError> {
    if p.len() != q.len() {
        return Err(PoseError::LengthMismatch {
            p: p.len(),
            q: q.len(),
        });
    }
    if p.len() < 8 {
        return Err(PoseError::TooFewMatches {
            got: p.len(),
            need: 8,
        });
    }
    let finite = [k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite());
    if !finite || p.iter().chain(q).flatten().any(|v| !v.is_finite()) {
        return Err(PoseError::NonFinite);
    }
    if k.fx == 0.0 || k.fy == 0.0 {
        return Err(PoseError::Degenerate("zero focal length"));
    }
    let x1: Vec<Vector3<f64>> = p.iter().map(|v| k.normalise(*v)).collect();
    let x2: Vec<Vector3<f64>> = q.iter().map(|v| k.normalise(*v)).collect();
    let (y1, t1) = hartley(&x1);
    let (y2, t2) = hartley(&x2);
    let mut mtm = SMatrix::<f64, 9, 9>::zeros();
    for (a, b) in y1.iter().zip(&y2) {
        let row = SMatrix::<f64, 9, 1>::from_column_slice(&[
            b[0] * a[0],
            b[0] * a[1],
            b[0],
            b[1] * a[0],
            b[1] * a[1],
            b[1],
            a[0],
            a[1],
            1.0,
        ]);
        mtm += row * row.transpose();
    }
    let eig = mtm.symmetric_eigen();
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let scale = eig.eigenvalues[order[8]].abs().max(1e-300);
    if eig.eigenvalues[order[1]] <= 1e-14 * scale {
        return Err(PoseError::Degenerate(
            "essential-matrix constraints are rank deficient",
        ));
    }
    let e = eig.eigenvectors.column(order[0]);
    let en = Matrix3::new(e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7], e[8]);
    let e = t2.transpose() * en * t1;
    let svd = e.svd(true, true);
    let (mut u, mut vt) = (
        svd.u.ok_or(PoseError::Singular("SVD"))?,
        svd.v_t.ok_or(PoseError::Singular("SVD"))?,
    );
    // order singular values descending (smallest last)
    let sv = svd.singular_values;
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| sv[j].total_cmp(&sv[i]));
    u = Matrix3::from_columns(&[u.column(idx[0]), u.column(idx[1]), u.column(idx[2])]);
    vt = Matrix3::from_rows(&[vt.row(idx[0]), vt.row(idx[1]), vt.row(idx[2])]);
    if u.determinant() < 0.0 {
        u = -u;
    }
    if vt.determinant() < 0.0 {
        vt = -vt;
    }
    let essential = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0)) * vt;
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let u3: Vector3<f64> = u.column(2).into_owned();
    let mut best: Option<EssentialPose> = None;
    for r in [u * w * vt, u * w.transpose() * vt] {
        for t in [u3, -u3] {
            let count = x1
                .iter()
                .zip(&x2)
                .filter(|(a, b)| {
                    let (z1, z2) = depths(&r, &t, a, b);
                    z1 > 0.0 && z2 > 0.0
                })
                .count();
            if best.as_ref().is_none_or(|b| count > b.in_front) {
                best = Some(EssentialPose {
                    rotation: r,
                    translation: t,
                    essential,
                    in_front: count,
                });
            }
        }
    }
    match best {
        Some(b) if b.in_front > 0 => Ok(b),
        _ => Err(PoseError::NoSolution(
            "no decomposition has points in front",
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Euler, angle_between};
    use rand::{Rng, SeedableRng, rngs::StdRng};

    #[test]
    fn recovers_rotation_from_noise_free_perspective_data() {
        let k = Intrinsics {
            fx: 500.0,
            fy: 480.0,
            cx: 160.0,
            cy: 120.0,
        };
        let mut rng = StdRng::seed_from_u64(7);
        for _ in 0..20 {
            let r = Euler::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
            )
            .matrix();
            let t = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.5..0.5),
            );
            let mut p = Vec::new();
            let mut q = Vec::new();
            for _ in 0..20 {
                let x = Vector3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(6.0..10.0),
                );
                let y = r * x + t;
                p.push([k.fx * x[0] / x[2] + k.cx, k.fy * x[1] / x[2] + k.cy]);
                q.push([k.fx * y[0] / y[2] + k.cx, k.fy * y[1] / y[2] + k.cy]);
            }
            let e = essential_rotation(&p, &q, &k).unwrap();
            assert!(angle_between(&e.rotation, &r) < 1e-8);
            assert!((e.translation - t.normalize()).norm() < 1e-7);
            assert_eq!(e.in_front, 20);
        }
        assert!(matches!(
            essential_rotation(&[[0.0; 2]; 5], &[[0.0; 2]; 5], &k),
            Err(PoseError::TooFewMatches { .. })
        ));
    }
}
