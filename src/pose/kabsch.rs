//! The 3D-3D case (paper Sec. III-G): Kabsch/SVD and SEA's equation solved in 3D.
//!
//! With centred 3D points, `A = P'P'^T`, `B = Q'P'^T` (3x3), the constrained least squares
//! `min_R Σ|q'_j - R p'_j|^2`, `R ∈ SO(3)`, has the stationarity condition `Λ R + R A = B`
//! with symmetric Λ. Right-multiplying by `R^T`: `Λ + R A R^T = B R^T`, so `S = B R^T` is
//! symmetric and `B = S R`: a polar decomposition, solved by the SVD `B = U Σ V^T`,
//! `R = U diag(1, 1, det(U V^T)) V^T` ([`kabsch`]). [`sea_3d`] instead solves Sylvester's
//! equation for `R(Λ)` by the Kronecker product and iterates Λ (Newton on its 6 entries against
//! the 6 equations `R R^T = I`), starting from `Λ0 = sym(B - A)` as in 2D; the tests show both
//! give the same rotation.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use super::PoseError;

type M9 = SMatrix<f64, 9, 9>;
type V9 = SVector<f64, 9>;
type M6 = SMatrix<f64, 6, 6>;
type V6 = SVector<f64, 6>;

fn moments3(p: &[[f64; 3]], q: &[[f64; 3]]) -> Result<(Matrix3<f64>, Matrix3<f64>), PoseError> {
    if p.len() != q.len() {
        return Err(PoseError::LengthMismatch {
            p: p.len(),
            q: q.len(),
        });
    }
    if p.len() < 3 {
        return Err(PoseError::TooFewMatches {
            got: p.len(),
            need: 3,
        });
    }
    if p.iter().chain(q).flatten().any(|x| !x.is_finite()) {
        return Err(PoseError::NonFinite);
    }
    let n = p.len() as f64;
    let mp = p.iter().map(|x| Vector3::from(*x)).sum::<Vector3<f64>>() / n;
    let mq = q.iter().map(|x| Vector3::from(*x)).sum::<Vector3<f64>>() / n;
    let mut a = Matrix3::zeros();
    let mut b = Matrix3::zeros();
    let mut c = Matrix3::zeros();
    for (x, y) in p.iter().zip(q) {
        let pp = Vector3::from(*x) - mp;
        let qq = Vector3::from(*y) - mq;
        a += pp * pp.transpose();
        b += qq * pp.transpose();
        c += qq * qq.transpose();
    }
    // Finite coordinates as large as 1e200 overflow the moments.
    if a.iter()
        .chain(b.iter())
        .chain(c.iter())
        .any(|x| !x.is_finite())
    {
        return Err(PoseError::NonFinite);
    }
    // Each set spans at least a plane: coincident or collinear points leave a turn about
    // their line undetermined, in either set.
    for (scatter, coincide, collinear) in [
        (
            &a,
            "the first 3D points coincide",
            "the first 3D points are collinear",
        ),
        (
            &c,
            "the second 3D points coincide",
            "the second 3D points are collinear",
        ),
    ] {
        let t = scatter.trace();
        if t <= 0.0 {
            return Err(PoseError::Degenerate(coincide));
        }
        let ev = scatter.symmetric_eigenvalues();
        let mut e = [ev[0], ev[1], ev[2]];
        e.sort_by(f64::total_cmp);
        if e[1] <= 1e-10 * t {
            return Err(PoseError::Degenerate(collinear));
        }
    }
    Ok((a, b))
}

/// Rotation minimising `Σ|q'_j - R p'_j|^2` (centred sets) by the SVD (Kabsch):
/// `B = U S V^T`, `R = U diag(1, 1, det(U V^T)) V^T`. Errors: sets of two lengths, fewer
/// than 3 points, coordinates that are not finite or overflow the moments
/// ([`PoseError::NonFinite`]), and either set coincident or collinear
/// ([`PoseError::Degenerate`]).
pub fn kabsch(p3: &[[f64; 3]], q3: &[[f64; 3]]) -> Result<Matrix3<f64>, PoseError> {
    let (_, b) = moments3(p3, q3)?;
    let svd = b.svd(true, true);
    let (u, vt) = (
        svd.u.ok_or(PoseError::Singular("SVD"))?,
        svd.v_t.ok_or(PoseError::Singular("SVD"))?,
    );
    // make the smallest singular value the one that takes the sign
    let sv = svd.singular_values;
    let mut imin = 0;
    for i in 1..3 {
        if sv[i] < sv[imin] {
            imin = i;
        }
    }
    let mut d = Vector3::new(1.0, 1.0, 1.0);
    d[imin] = (u * vt).determinant().signum();
    Ok(u * Matrix3::from_diagonal(&d) * vt)
}

fn vec3(m: &Matrix3<f64>) -> V9 {
    V9::from_column_slice(m.as_slice())
}

fn unvec3(v: &V9) -> Matrix3<f64> {
    Matrix3::from_column_slice(v.as_slice())
}

fn kron3(a: &Matrix3<f64>, lam: &Matrix3<f64>) -> M9 {
    let mut k = M9::zeros();
    for i in 0..3 {
        for r in 0..3 {
            for s in 0..3 {
                k[(3 * i + r, 3 * i + s)] += lam[(r, s)];
            }
        }
        for j in 0..3 {
            for r in 0..3 {
                k[(3 * i + r, 3 * j + r)] += a[(j, i)];
            }
        }
    }
    k
}

const SYM: [(usize, usize); 6] = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];

fn sym_of(x: &V6) -> Matrix3<f64> {
    Matrix3::new(x[0], x[3], x[4], x[3], x[1], x[5], x[4], x[5], x[2])
}

fn residual3(a: &Matrix3<f64>, b: &Matrix3<f64>, x: &V6) -> Option<(V6, M6, Matrix3<f64>)> {
    let lam = sym_of(x);
    let lu = kron3(a, &lam).lu();
    let r = unvec3(&lu.solve(&vec3(b))?);
    if r.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let g = r * r.transpose() - Matrix3::identity();
    let f = V6::from_fn(|i, _| g[SYM[i]]);
    let mut j = M6::zeros();
    for k in 0..6 {
        let mut e = V6::zeros();
        e[k] = 1.0;
        let de = sym_of(&e);
        let dr = unvec3(&lu.solve(&(-vec3(&(de * r))))?);
        let dg = dr * r.transpose() + r * dr.transpose();
        for i in 0..6 {
            j[(i, k)] = dg[SYM[i]];
        }
    }
    Some((f, j, r))
}

/// SEA's equation `Λ R + R A = B` solved in 3D: Kronecker solution for `R(Λ)`, Newton on the
/// six entries of the symmetric Λ against `R R^T = I`, from `Λ0 = sym(B - A)`, with a
/// backtracking line search that accepts a step only if it lowers `|R R^T - I|` and keeps
/// `det R(Λ) > 0`.
///
/// Every stationary point of the least squares solves the equation, and Newton from `Λ0`
/// reaches one other than the minimum for large turns (on exact data, for turns of about 110
/// degrees or more, the rotation half a turn from the truth about an axis of `A`'s). The
/// solution is therefore checked (`is_minimum`), and one that is not the minimum is moved to
/// it (`minimum_beside`: the stationary points differ by the signs of `S = B R^T`'s
/// eigenvalues) and solved for again from that Λ. Where Newton from `Λ0` does not converge
/// (it can fail for turns past about 130 degrees), it starts again from `Λ = 0`, and then the
/// minimum is followed by continuation from the trivial problem `B = A` (`Λ = 0`, `R = I`)
/// along `B_τ = (1 - τ) A + τ B`, Newton correcting at each step, a step halved where the
/// correction fails or leaves the minimum.
///
/// Errors: bad input as in [`kabsch`]; [`PoseError::Degenerate`] for coplanar first points
/// (three, or more on one plane: `A` is singular, and so is the Kronecker system near
/// `Λ = 0`), which [`kabsch`] solves; [`PoseError::NoSolution`] where no solution of the
/// equation found is the minimum: a few per cent of sets of four or five points under heavy
/// noise (0.2-0.3 of their spread), none on exact data of four points or more (tested over
/// the whole range of turns).
pub fn sea_3d(p3: &[[f64; 3]], q3: &[[f64; 3]]) -> Result<Matrix3<f64>, PoseError> {
    let (a, b) = moments3(p3, q3)?;
    let s = a.trace();
    let (a, b) = (a / s, b / s);
    // Coplanar first points (three always are): `A` is singular, and with it the Kronecker
    // system at and near `Λ = 0`, where the minimum lies on exact data.
    if a.symmetric_eigenvalues().min() <= 1e-12 {
        return Err(PoseError::Degenerate(
            "the first 3D points are coplanar: SEA's Kronecker system is singular there \
             (kabsch solves them)",
        ));
    }
    let l0 = b - a;
    let l0 = (l0 + l0.transpose()) * 0.5;
    let x0 = V6::from_fn(|i, _| l0[SYM[i]]);
    let minimum = |(_, r): (V6, Matrix3<f64>)| {
        if is_minimum(&b, &r) {
            Some(r)
        } else {
            minimum_beside(&a, &b, &r)
        }
    };
    // From Λ0, then from Λ = 0 (where `R(Λ) = B A^-1`, the unconstrained least squares, which
    // exact data make a rotation), then along the continuation.
    newton3(&a, &b, x0)
        .and_then(minimum)
        .or_else(|| newton3(&a, &b, V6::zeros()).and_then(minimum))
        .or_else(|| follow(&a, &b).and_then(minimum))
        .ok_or(PoseError::NoSolution(
            "3D SEA found no solution that is the least-squares rotation",
        ))
}

/// Continuation: `B_τ = (1 - τ) A + τ B` joins the trivial problem (`B = A`, `Λ = 0`, `R = I`,
/// the minimum) to ours; the minimum is followed in τ with Newton as the corrector, a step
/// halved where the correction fails or leaves the minimum. `None` when the steps fall under
/// 1e-6 of the path.
fn follow(a: &Matrix3<f64>, b: &Matrix3<f64>) -> Option<(V6, Matrix3<f64>)> {
    let mut x = V6::zeros();
    let mut r = Matrix3::identity();
    let (mut tau, mut step) = (0.0, 1.0 / 16.0);
    while tau < 1.0 {
        let next = f64::min(tau + step, 1.0);
        let bt = a * (1.0 - next) + b * next;
        match newton3(a, &bt, x) {
            Some((xn, rn)) if is_minimum(&bt, &rn) => {
                (x, r, tau) = (xn, rn, next);
                step = f64::min(step * 2.0, 1.0 / 16.0);
            }
            _ => {
                step *= 0.5;
                if step < 1e-6 {
                    return None;
                }
            }
        }
    }
    Some((x, r))
}

/// The signs the eigenvalues of `S = B R^T` have at the minimum, for eigenvalues `mu` of a
/// stationary point's `S` and `det B`: all positive, but where `det B < 0` the one smallest
/// in magnitude negative (with `B = U Σ V^T`, the stationary points are `R = U D V^T`, `D`
/// diagonal of ±1 with `det R = 1`, and `S = U Σ D U^T`: the minimum keeps the most of `Σ`).
fn minimum_signs(mu: &Vector3<f64>, det_b: f64) -> [f64; 3] {
    let mut signs = [1.0; 3];
    if det_b < 0.0 {
        let smallest = (0..3)
            .min_by(|&i, &j| mu[i].abs().total_cmp(&mu[j].abs()))
            .unwrap_or(0);
        signs[smallest] = -1.0;
    }
    signs
}

/// Whether `r`, a stationary point (`S = B R^T` symmetric), is the least-squares minimum:
/// the eigenvalues of `S` have the signs [`minimum_signs`] gives, to within `1e-9` of their
/// scale (a zero eigenvalue, `B` singular, is either sign).
fn is_minimum(b: &Matrix3<f64>, r: &Matrix3<f64>) -> bool {
    let s = b * r.transpose();
    let mu = ((s + s.transpose()) * 0.5).symmetric_eigenvalues();
    let tol = 1e-9 * mu.iter().map(|v| v.abs()).sum::<f64>();
    let signs = minimum_signs(&mu, b.determinant());
    (0..3).all(|i| mu[i] * signs[i] >= -tol)
}

/// The minimum from another stationary point `r`: `S = B R^T = W M W^T` (eigenvectors `W`),
/// and the minimum is `W F W^T R` with `F` flipping the eigenvalues whose signs are not the
/// minimum's ([`minimum_signs`]); then solved for again by Newton from its Λ
/// (`sym(B R^T) - R A R^T`), so that the rotation returned is one of SEA's equation's.
fn minimum_beside(a: &Matrix3<f64>, b: &Matrix3<f64>, r: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let s = b * r.transpose();
    let eig = ((s + s.transpose()) * 0.5).symmetric_eigen();
    let signs = minimum_signs(&eig.eigenvalues, b.determinant());
    let flip = Vector3::from_fn(|i, _| {
        if eig.eigenvalues[i] * signs[i] < 0.0 {
            -1.0
        } else {
            1.0
        }
    });
    let w = eig.eigenvectors;
    let turned = w * Matrix3::from_diagonal(&flip) * w.transpose() * r;
    if turned.determinant() <= 0.0 {
        return None;
    }
    let s = b * turned.transpose();
    let lam = (s + s.transpose()) * 0.5 - turned * a * turned.transpose();
    let x = V6::from_fn(|i, _| lam[SYM[i]]);
    let (_, r) = newton3(a, b, x)?;
    is_minimum(b, &r).then_some(r)
}

/// Newton on Λ for `R(Λ) R(Λ)^T = I`; `None` without convergence to a proper rotation.
fn newton3(a: &Matrix3<f64>, b: &Matrix3<f64>, mut x: V6) -> Option<(V6, Matrix3<f64>)> {
    let (mut f, mut jac, mut r) = residual3(a, b, &x)?;
    for _ in 0..100 {
        if f.norm() < 1e-13 {
            break;
        }
        let step = jac.lu().solve(&(-f))?;
        let f0 = f.norm();
        let mut t = 1.0;
        let mut ok = false;
        for _ in 0..40 {
            let xn = x + step * t;
            // accept only steps that reduce the residual and keep det R(Λ) > 0 (the iterate
            // must not jump to the reflection branch of the polar equation)
            if let Some((fnew, jn, rn)) = residual3(a, b, &xn)
                && fnew.norm() < f0
                && rn.determinant() > 0.0
            {
                (x, f, jac, r) = (xn, fnew, jn, rn);
                ok = true;
                break;
            }
            t *= 0.5;
        }
        if !ok {
            break;
        }
    }
    (f.norm() <= 1e-9 && r.determinant() > 0.0).then_some((x, r))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Euler, angle_between};
    use rand::{Rng, SeedableRng, rngs::StdRng};

    fn cloud(rng: &mut StdRng, r: &Matrix3<f64>, noise: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let mut p = Vec::new();
        let mut q = Vec::new();
        for _ in 0..15 {
            let x = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let y = r * x
                + Vector3::new(0.5, -0.2, 3.0)
                + Vector3::new(
                    rng.random_range(-noise..=noise),
                    rng.random_range(-noise..=noise),
                    rng.random_range(-noise..=noise),
                );
            p.push([x[0], x[1], x[2]]);
            q.push([y[0], y[1], y[2]]);
        }
        (p, q)
    }

    #[test]
    fn kabsch_and_sea_3d_agree() {
        let mut rng = StdRng::seed_from_u64(1);
        for i in 0..100 {
            let r = Euler::new(
                rng.random_range(-0.8..0.8),
                rng.random_range(-0.8..0.8),
                rng.random_range(-0.8..0.8),
            )
            .matrix();
            let noise = if i % 2 == 0 { 0.0 } else { 0.1 };
            let (p, q) = cloud(&mut rng, &r, noise);
            let k = kabsch(&p, &q).unwrap();
            let s = sea_3d(&p, &q).unwrap();
            assert!(angle_between(&k, &s) < 1e-8, "case {i}");
            if noise == 0.0 {
                assert!(angle_between(&k, &r) < 1e-10);
            }
        }
    }

    /// Over the whole range of rotations: Newton from `Λ0` reaches a rotation half a turn
    /// from the truth for turns past about 110 degrees (on exact data a stationary point that
    /// solves the equation as well), which was returned as the answer, and the continuation
    /// of 16 fixed steps gave up on others.
    #[test]
    fn sea_3d_finds_the_minimum_for_any_turn() {
        let mut rng = StdRng::seed_from_u64(3);
        let pi = std::f64::consts::PI;
        for i in 0..200 {
            let r = Euler::new(
                rng.random_range(-pi..pi),
                rng.random_range(-pi / 2.0..pi / 2.0),
                rng.random_range(-pi..pi),
            )
            .matrix();
            let noise = if i % 2 == 0 { 0.0 } else { 0.1 };
            let (p, q) = cloud(&mut rng, &r, noise);
            let k = kabsch(&p, &q).unwrap();
            let s = sea_3d(&p, &q).unwrap_or_else(|e| panic!("case {i}: {e}"));
            assert!(
                angle_between(&k, &s) < 1e-8,
                "case {i}: {}",
                angle_between(&k, &s)
            );
            if noise == 0.0 {
                assert!(angle_between(&k, &r) < 1e-10);
            }
        }
        // Half turns about each axis and a turn of 100 degrees about z (which Newton from
        // Λ0 took to the rotation half a turn away).
        for r in [
            Euler::new(0.0, 0.0, 100f64.to_radians()).matrix(),
            Euler::new(pi * 0.99, 0.0, 0.0).matrix(),
            Euler::new(0.0, 0.0, pi * 0.99).matrix(),
            Euler::new(1.0, 0.7, 1.0).matrix(),
        ] {
            let (p, q) = cloud(&mut rng, &r, 0.0);
            let s = sea_3d(&p, &q).unwrap();
            assert!(angle_between(&s, &r) < 1e-8, "{}", angle_between(&s, &r));
        }
    }

    #[test]
    fn a_stationary_point_other_than_the_minimum_is_told_apart() {
        let mut rng = StdRng::seed_from_u64(4);
        let truth = Euler::new(0.3, -0.2, 0.5).matrix();
        let (p, q) = cloud(&mut rng, &truth, 0.0);
        let (a, b) = moments3(&p, &q).unwrap();
        assert!(is_minimum(&b, &truth));
        // Half a turn about an eigenvector of A, after the truth: B R^T is then symmetric
        // (a stationary point), and not the minimum.
        let axis = a.symmetric_eigen().eigenvectors.column(0).into_owned();
        let half = nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(axis),
            std::f64::consts::PI,
        );
        let other = truth * half.matrix();
        let s = b * other.transpose();
        assert!((s - s.transpose()).norm() < 1e-9 * s.norm());
        assert!(!is_minimum(&b, &other));
    }

    #[test]
    fn coplanar_points_are_degenerate_for_sea_3d_and_solved_by_kabsch() {
        let r = Euler::new(0.3, -0.4, 0.2).matrix();
        for n in [3, 6] {
            let p: Vec<[f64; 3]> = (0..n)
                .map(|i| {
                    let t = i as f64;
                    [t.cos() * (1.0 + t), t.sin(), 0.5]
                })
                .collect();
            let q: Vec<[f64; 3]> = p
                .iter()
                .map(|x| {
                    let y = r * Vector3::from(*x);
                    [y[0], y[1], y[2]]
                })
                .collect();
            assert!(
                matches!(sea_3d(&p, &q), Err(PoseError::Degenerate(_))),
                "{n}"
            );
            assert!(angle_between(&kabsch(&p, &q).unwrap(), &r) < 1e-10, "{n}");
        }
    }

    #[test]
    fn bad_3d_input() {
        assert!(kabsch(&[[0.0; 3]; 2], &[[0.0; 3]; 2]).is_err());
        let line: Vec<[f64; 3]> = (0..5).map(|i| [i as f64, 0.0, 0.0]).collect();
        assert!(matches!(
            kabsch(&line, &line),
            Err(PoseError::Degenerate(_))
        ));
        let mut p = line.clone();
        p[1][1] = f64::NAN;
        assert_eq!(kabsch(&p, &line), Err(PoseError::NonFinite));
        // The second set degenerate while the first spans space: it gave the identity (all one
        // point) or an arbitrary rotation (collinear), where SEA's 3D solve refused.
        let mut rng = StdRng::seed_from_u64(2);
        let (cloud_p, _) = cloud(&mut rng, &Matrix3::identity(), 0.0);
        let n = cloud_p.len();
        let one = vec![[1.0, 2.0, 3.0]; n];
        let on_line: Vec<[f64; 3]> = (0..n).map(|i| [i as f64, 2.0 * i as f64, 0.5]).collect();
        for q in [&one, &on_line] {
            for r in [kabsch(&cloud_p, q), sea_3d(&cloud_p, q)] {
                assert!(matches!(r, Err(PoseError::Degenerate(_))), "{r:?}");
            }
        }
        // Finite coordinates whose moments overflow.
        let huge: Vec<[f64; 3]> = cloud_p.iter().map(|x| x.map(|v| v * 1e200)).collect();
        assert_eq!(kabsch(&huge, &huge), Err(PoseError::NonFinite));
    }
}
