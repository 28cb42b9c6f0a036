//! Completion of a rotation from its top-left 2x2 block, and the Necker ambiguity.
//!
//! # Which 2x2 matrices are blocks of rotations
//!
//! Write `R = [[M, c], [d^T, r33]]` with `M` 2x2, `c = (r13, r23)`. From `R R^T = I`,
//! `M M^T + c c^T = I`, so `M M^T` has eigenvalues `1` and `1 - |c|^2`: the singular values
//! of `M` are `1` and `s = sqrt(1 - |c|^2) = |r33|` (the cofactor identity of `SO(3)` gives
//! `r33 = det M`, so `det M = ±s` and both signs occur). Conversely, any
//! `M = U diag(1, s) V^T` with `U, V ∈ O(2)`, `0 ≤ s ≤ 1`, is a block: a reflection in `U`
//! or `V` can be moved onto the middle factor (`diag(1,-1) diag(1,s) = diag(1,-s) diag(1,-1)`),
//! so `M = Rz(α)₂ diag(1, cos θ) Rz(β)₂^T` with `cos θ = ±s`, which is the block of the
//! rotation `Rz(α) Rx(θ) Rz(-β)` (ZXZ angles). Hence
//!
//! > `M` is the block of some `R ∈ SO(3)` **iff** its largest singular value is exactly 1.
//!
//! In the similarity / anti-similarity split used throughout this module,
//! `M p ≅ z·π + w·conj(π)` for the complex point `π = u + i v`, the singular values are
//! `|z| + |w|` and `||z| - |w||`, so the blocks are exactly `{ |z| + |w| = 1 }`.
//!
//! # The Necker pair
//!
//! Given a valid `M`, `c` is fixed up to sign by `c c^T = I - M M^T`, and the third row is
//! `r3 = r1 × r2`. The two completions are `R` and `D R D` with `D = diag(1, 1, -1)`: `D R D`
//! has the same block, negated `r13, r23, r31, r32` and the same `r33`. Weak perspective
//! cannot tell them apart (a tilt and its mirror); see [`resolve_by_parallax`] and
//! [`resolve_by_continuity`].

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

use super::PoseError;
use crate::geometry::angle_between;

/// Similarity part `z = a + i b` and anti-similarity part `w = c + i d` of a 2x2 matrix:
/// `M = [[a + c, d - b], [b + d, a - c]]`.
pub fn to_zw(m: &Matrix2<f64>) -> ([f64; 2], [f64; 2]) {
    let a = 0.5 * (m[(0, 0)] + m[(1, 1)]);
    let b = 0.5 * (m[(1, 0)] - m[(0, 1)]);
    let c = 0.5 * (m[(0, 0)] - m[(1, 1)]);
    let d = 0.5 * (m[(0, 1)] + m[(1, 0)]);
    ([a, b], [c, d])
}

/// Inverse of [`to_zw`].
pub fn from_zw(z: [f64; 2], w: [f64; 2]) -> Matrix2<f64> {
    let ([a, b], [c, d]) = (z, w);
    Matrix2::new(a + c, d - b, b + d, a - c)
}

/// Singular values `(σ1 ≥ σ2)` of a 2x2 matrix, in closed form (`|z| ± |w|`).
pub fn singular_values(m: &Matrix2<f64>) -> (f64, f64) {
    let (z, w) = to_zw(m);
    let nz = z[0].hypot(z[1]);
    let nw = w[0].hypot(w[1]);
    (nz + nw, (nz - nw).abs())
}

/// The nearest valid block (Frobenius norm) to a 2x2 matrix.
///
/// With `M = U diag(σ1, σ2) V^T`, the nearest matrix with singular values `(1, s)`,
/// `0 ≤ s ≤ 1`, keeps `U, V` (von Neumann's trace inequality) and takes `s = clamp(σ2, 0, 1)`.
/// In the `(z, w)` split this rescales `|z|` and `|w|` keeping their phases. When a phase is
/// undefined (`z` or `w` zero) every phase is equally near; phase 0 is taken.
pub fn nearest_valid_block(m: &Matrix2<f64>) -> Result<Matrix2<f64>, PoseError> {
    if m.iter().any(|x| !x.is_finite()) {
        return Err(PoseError::NonFinite);
    }
    let (z, w) = to_zw(m);
    let nz = z[0].hypot(z[1]);
    let nw = w[0].hypot(w[1]);
    let s = (nz - nw).abs().min(1.0);
    let (big, small) = ((1.0 + s) / 2.0, (1.0 - s) / 2.0);
    let (tz, tw) = if nz >= nw { (big, small) } else { (small, big) };
    let scale = |v: [f64; 2], n: f64, t: f64| -> [f64; 2] {
        if n > 1e-300 {
            [v[0] / n * t, v[1] / n * t]
        } else {
            [t, 0.0]
        }
    };
    Ok(from_zw(scale(z, nz, tz), scale(w, nw, tw)))
}

/// The two rotations with a given block: `b = D a D`, `D = diag(1, 1, -1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeckerPair {
    /// The completion whose out-of-plane column `(r13, r23)` has its larger-magnitude
    /// component non-negative.
    pub a: Matrix3<f64>,
    /// The mirror `D a D`.
    pub b: Matrix3<f64>,
}

impl NeckerPair {
    /// The member nearer (geodesic angle) to `r`; ties go to `a`.
    pub fn closest_to(&self, r: &Matrix3<f64>) -> Matrix3<f64> {
        if angle_between(&self.b, r) < angle_between(&self.a, r) {
            self.b
        } else {
            self.a
        }
    }

    /// Whether the two members coincide (pure in-plane rotation, `r13 = r23 = 0`).
    pub fn is_unique(&self) -> bool {
        (self.a - self.b).norm() < 1e-12
    }
}

/// Completes a block to its Necker pair of rotations.
///
/// The block is first projected onto the nearest valid block ([`nearest_valid_block`]), so a
/// slightly invalid block (LSM, noise) is accepted. Then `c c^T = I - M M^T` gives
/// `c = (r13, r23)` up to sign (taken from the larger diagonal entry for accuracy), rows
/// `r1 = (m11, m12, c1)`, `r2 = (m21, m22, c2)` and `r3 = r1 × r2`.
///
/// Errors: a non-finite entry, or a block too far from any rotation block (largest singular
/// value outside `[0.5, 2]`: no rotation explains it).
pub fn complete_rotation(r2: &Matrix2<f64>) -> Result<NeckerPair, PoseError> {
    if r2.iter().any(|x| !x.is_finite()) {
        return Err(PoseError::NonFinite);
    }
    let (s1, _) = singular_values(r2);
    if !(0.5..=2.0).contains(&s1) {
        return Err(PoseError::InvalidBlock("largest singular value far from 1"));
    }
    let m = nearest_valid_block(r2)?;
    let e = Matrix2::identity() - m * m.transpose();
    let (e11, e22, e12) = (e[(0, 0)].max(0.0), e[(1, 1)].max(0.0), e[(0, 1)]);
    let c = if e11 >= e22 {
        let c1 = e11.sqrt();
        if c1 > 0.0 {
            Vector2::new(c1, e12 / c1)
        } else {
            Vector2::zeros()
        }
    } else {
        let c2 = e22.sqrt();
        Vector2::new(e12 / c2, c2)
    };
    let r1 = Vector3::new(m[(0, 0)], m[(0, 1)], c[0]);
    let r2v = Vector3::new(m[(1, 0)], m[(1, 1)], c[1]);
    let a = rows_to_rotation(r1, r2v);
    let d = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
    let b = d * a * d;
    Ok(NeckerPair { a, b })
}

/// Rotation from its first two rows (re-orthonormalised symmetrically), third row `r1 × r2`.
fn rows_to_rotation(r1: Vector3<f64>, r2: Vector3<f64>) -> Matrix3<f64> {
    // Symmetric Gram-Schmidt keeps the block as close as possible to the given one.
    let (r1, r2) = (r1.normalize(), r2.normalize());
    let dot = r1.dot(&r2);
    let (x, y) = (r1 - 0.5 * dot * r2, r2 - 0.5 * dot * r1);
    let (x, y) = (x.normalize(), y.normalize());
    let z = x.cross(&y);
    Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()])
}

/// Picks the Necker branch from the parallax of the features against the object's centre.
///
/// `offset` = (image motion of the previous centre under the fitted feature map, i.e.
/// [`super::InterFrame::translation`]) − (motion of the object's centre, e.g. the
/// silhouette/ellipse centre).
///
/// Derivation: an object point at `X` relative to the rotation centre (camera axes, z forward)
/// projects (weak perspective, image scale `s`) to `p = o + s X_xy`; after `ΔR` about the centre
/// it projects to `q = o' + s (R2 X_xy + c X_z)` with `c = (r13, r23)`. So
/// `q = o' + R2 (p - o) + s c X_z`, and averaged over the features
/// `offset = s · c · z̄`. The visible surface points of a convex object lie in front of its
/// centre (`z̄ < 0`), so the true branch has `c · offset < 0`. Rule: return `a` if
/// `c_a · offset ≤ 0`, else `b` (a tie, e.g. an in-plane rotation, returns `a`).
pub fn resolve_by_parallax(pair: &NeckerPair, offset: Vector2<f64>) -> Matrix3<f64> {
    let ca = Vector2::new(pair.a[(0, 2)], pair.a[(1, 2)]);
    if ca.dot(&offset) <= 0.0 {
        pair.a
    } else {
        pair.b
    }
}

/// Picks the Necker branch nearer (geodesic angle) to the previous inter-frame rotation:
/// smooth motion keeps the sign of the out-of-plane rotation. Ties go to `a`.
pub fn resolve_by_continuity(pair: &NeckerPair, previous_delta: &Matrix3<f64>) -> Matrix3<f64> {
    pair.closest_to(previous_delta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Euler;
    use crate::geometry::rotation::{rot_x, rot_y, rot_z};

    fn block(r: &Matrix3<f64>) -> Matrix2<f64> {
        r.fixed_view::<2, 2>(0, 0).into_owned()
    }

    #[test]
    fn zw_round_trip_and_singular_values() {
        let m = Matrix2::new(0.3, -1.2, 0.7, 0.4);
        let (z, w) = to_zw(&m);
        assert!((from_zw(z, w) - m).norm() < 1e-15);
        let svd = m.svd(false, false);
        let (s1, s2) = singular_values(&m);
        let mut sv = [svd.singular_values[0], svd.singular_values[1]];
        sv.sort_by(|a, b| b.partial_cmp(a).unwrap());
        assert!((s1 - sv[0]).abs() < 1e-12 && (s2 - sv[1]).abs() < 1e-12);
    }

    #[test]
    fn blocks_of_rotations_have_top_singular_value_one_both_det_signs() {
        let mut neg = 0;
        for i in 0..200 {
            let t = i as f64 * 0.37;
            let r = Euler::new(t.sin() * 3.0, (t * 1.3).cos() * 1.5, t * 0.7).matrix();
            let m = block(&r);
            let (s1, s2) = singular_values(&m);
            assert!((s1 - 1.0).abs() < 1e-12);
            assert!((s2 - r[(2, 2)].abs()).abs() < 1e-12);
            assert!((m.determinant() - r[(2, 2)]).abs() < 1e-12);
            if m.determinant() < 0.0 {
                neg += 1;
            }
            // completion reproduces R as one of the pair
            let pair = complete_rotation(&m).unwrap();
            let e = angle_between(&pair.a, &r).min(angle_between(&pair.b, &r));
            assert!(e < 1e-7, "{e}");
            assert!((block(&pair.a) - m).norm() < 1e-9);
            assert!((block(&pair.b) - m).norm() < 1e-9);
        }
        assert!(neg > 0, "negative-determinant blocks occur");
    }

    #[test]
    fn any_top_singular_one_matrix_is_a_zxz_block() {
        // U diag(1, t) V^T with U, V rotations, t in [-1, 1] is the block of Rz Rx Rz.
        for i in 0..50 {
            let (al, th, be) = (i as f64 * 0.5, i as f64 * 0.13 - 3.0, i as f64 * 0.9);
            let r = rot_z(al) * rot_x(th) * rot_z(-be);
            let u = block(&rot_z(al));
            let v = block(&rot_z(be));
            let m = u * Matrix2::new(1.0, 0.0, 0.0, th.cos()) * v.transpose();
            assert!((block(&r) - m).norm() < 1e-12);
        }
    }

    #[test]
    fn necker_pair_is_mirror_with_same_block() {
        let r = Euler::from_degrees(12.0, -7.0, 30.0).matrix();
        let pair = complete_rotation(&block(&r)).unwrap();
        let d = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        assert!((d * pair.a * d - pair.b).norm() < 1e-12);
        assert!((pair.a.determinant() - 1.0).abs() < 1e-12);
        assert!((pair.a * pair.a.transpose() - Matrix3::identity()).norm() < 1e-12);
        assert!(!pair.is_unique());
        assert!(complete_rotation(&block(&rot_z(0.3))).unwrap().is_unique());
        // the larger out-of-plane component of `a` is non-negative
        let (c1, c2) = (pair.a[(0, 2)], pair.a[(1, 2)]);
        assert!(if c1.abs() >= c2.abs() {
            c1 >= 0.0
        } else {
            c2 >= 0.0
        });
    }

    #[test]
    fn projection_onto_valid_blocks() {
        // valid blocks are fixed points
        let r = Euler::from_degrees(20.0, 10.0, -40.0).matrix();
        let m = block(&r);
        assert!((nearest_valid_block(&m).unwrap() - m).norm() < 1e-12);
        // an invalid matrix lands on σ1 = 1 and nothing valid nearby is nearer
        let x = Matrix2::new(1.1, 0.2, -0.1, 0.7);
        let p = nearest_valid_block(&x).unwrap();
        assert!((singular_values(&p).0 - 1.0).abs() < 1e-12);
        let d0 = (p - x).norm();
        for i in 0..2000 {
            let t = i as f64;
            let r = Euler::new(t * 0.31, (t * 0.17).sin() * 1.5, t * 0.23).matrix();
            assert!((block(&r) - x).norm() >= d0 - 1e-12);
        }
        // shrunken identity projects back to a rotation
        let p = nearest_valid_block(&(Matrix2::identity() * 0.5)).unwrap();
        assert!((singular_values(&p).0 - 1.0).abs() < 1e-12);
        assert!(complete_rotation(&Matrix2::new(f64::NAN, 0.0, 0.0, 1.0)).is_err());
        assert!(complete_rotation(&(Matrix2::identity() * 10.0)).is_err());
    }

    #[test]
    fn continuity_picks_the_nearer_branch() {
        let r = rot_x(0.1) * rot_y(0.05);
        let pair = complete_rotation(&block(&r)).unwrap();
        assert!(angle_between(&resolve_by_continuity(&pair, &r), &r) < 1e-9);
        let d = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let m = d * r * d;
        assert!(angle_between(&resolve_by_continuity(&pair, &m), &m) < 1e-9);
    }
}
