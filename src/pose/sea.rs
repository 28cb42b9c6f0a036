//! SEA: the paper's Sylvester-equation algorithm (SPEC section 2, paper Sec. III-D..F).
//!
//! Least squares under the constraint that `R2` is a rotation block, with the Lagrangian
//! `f(R2) + tr(Λ (R2 R2^T + c c^T - I))` (`c = (r13, r23)`, `Λ` symmetric), has the stationarity
//! conditions
//!
//! * `Λ R2 + R2 A = B` (Sylvester's equation; `∂/∂R2`),
//! * `Λ c = 0` (`∂/∂c`; with out-of-plane rotation `Λ` is singular),
//! * `R2 R2^T + c c^T = I` (the constraint: row norms `|R_i|^2 + c_i^2 = 1` and
//!   `R1·R2 + c1 c2 = 0`, i.e. the paper's `R1·R2 ± sqrt((1-|R1|^2)(1-|R2|^2)) = 0`).
//!
//! # The iteration (our design; the paper leaves the update of Λ open)
//!
//! `R2(Λ)` is always the Kronecker solution `vec(R2) = (I ⊗ Λ + A^T ⊗ I)^-1 vec(B)`
//! (column-major `vec`), as in the paper. The unknowns are the three entries of Λ and
//! `c = (r13, r23)`; the five equations are the three constraint equations and `Λ c = 0`.
//! They are solved by Newton's method with an analytic Jacobian (`dR2` from differentiating
//! Sylvester's equation, which reuses the same Kronecker matrix) and a backtracking line search
//! on the residual norm.
//!
//! Starts. (1) The paper's: `Λ0 = B - A` with its off-diagonal pair averaged, and `c0` from
//! `R2(Λ0)`: `c0 c0^T = I - R2 R2^T` after projecting `R2(Λ0)` onto the valid blocks, so
//! `|c0_i| = sqrt(1 - |R_i|^2)` and the relative sign of `c0` is the sign of `-R1·R2` (the
//! "sign follows the direction of rotation" of the paper). If that leaves `c0 ≈ 0` (an
//! in-plane first guess), `c0` is seeded with `1e-3` in that sign pattern, so that an
//! out-of-plane solution stays reachable (at `c = 0` exactly, Newton never leaves the in-plane
//! family). (2) Because `Λ0` assumes `R2 ≈ I` and Newton from it can end on another stationary
//! point for larger rotations, a second start is taken from the projected unconstrained fit
//! `M = proj(B A^-1)`: `c` from `M` as above and the Λ consistent with it,
//! `Λ = sym((B - M A) M^-1)` (exact on noise-free data, where `Λ* = 0`). Of the converged
//! results the one with the lower objective is returned. The overall sign of `c` is the Necker
//! ambiguity and does not affect `R2`.
//!
//! Convergence: residual norm below `tol` (default `1e-12`, in units where `tr A = 1`).
//! Without convergence in `max_iter` iterations, the iterate with the smallest residual is
//! returned, projected onto the valid blocks ([`SeaSolution::converged`] says which).
//! The result is a stationary point (KKT point) of the constrained problem; unlike
//! [`super::Optimal`] it need not be the global minimum.

use nalgebra::{Matrix2, Matrix4, Matrix5, Vector2, Vector4, Vector5};

use super::complete::nearest_valid_block;
use super::{BlockEstimate, Moments, PoseError, RotationSolver, estimate_from_block, moments};

/// The paper's Sylvester-equation algorithm.
#[derive(Debug, Clone, Copy)]
pub struct Sea {
    /// Newton iterations at most.
    pub max_iter: usize,
    /// Convergence threshold on the residual norm (normalised units, `tr A = 1`).
    pub tol: f64,
}

impl Default for Sea {
    fn default() -> Self {
        Self {
            max_iter: 60,
            tol: 1e-12,
        }
    }
}

/// The full outcome of SEA.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeaSolution {
    /// The block (projected onto the valid blocks).
    pub r2: Matrix2<f64>,
    /// The final Lagrange multiplier Λ (in the units of `A`, `B`).
    pub lambda: Matrix2<f64>,
    /// The out-of-plane column `(r13, r23)` (up to the Necker sign).
    pub c: Vector2<f64>,
    /// Newton iterations taken.
    pub iterations: usize,
    /// Whether the residual fell below the tolerance.
    pub converged: bool,
    /// Final residual norm (normalised units).
    pub residual_norm: f64,
}

/// The Kronecker matrix `I ⊗ Λ + A^T ⊗ I` (column-major `vec`).
fn kron_matrix(a: &Matrix2<f64>, lambda: &Matrix2<f64>) -> Matrix4<f64> {
    let mut k = Matrix4::zeros();
    for i in 0..2 {
        for j in 0..2 {
            // I ⊗ Λ: block (i, i) is Λ
            if i == j {
                for r in 0..2 {
                    for s in 0..2 {
                        k[(2 * i + r, 2 * j + s)] += lambda[(r, s)];
                    }
                }
            }
            // A^T ⊗ I: block (i, j) is A[(j, i)] I
            for r in 0..2 {
                k[(2 * i + r, 2 * j + r)] += a[(j, i)];
            }
        }
    }
    k
}

fn vec2(m: &Matrix2<f64>) -> Vector4<f64> {
    Vector4::new(m[(0, 0)], m[(1, 0)], m[(0, 1)], m[(1, 1)])
}

fn unvec2(v: &Vector4<f64>) -> Matrix2<f64> {
    Matrix2::new(v[0], v[2], v[1], v[3])
}

/// Solves Sylvester's equation `Λ R2 + R2 A = B` for `R2` by the Kronecker product (paper
/// eq. 16). Errors when `I ⊗ Λ + A^T ⊗ I` is singular (an eigenvalue of Λ equals minus one of
/// `A`).
pub fn sylvester_block(
    a: &Matrix2<f64>,
    b: &Matrix2<f64>,
    lambda: &Matrix2<f64>,
) -> Result<Matrix2<f64>, PoseError> {
    let lu = kron_matrix(a, lambda).lu();
    let x = lu
        .solve(&vec2(b))
        .ok_or(PoseError::Singular("Sylvester equation"))?;
    if x.iter().any(|v| !v.is_finite()) {
        return Err(PoseError::Singular("Sylvester equation"));
    }
    Ok(unvec2(&x))
}

fn lambda_of(x: &Vector5<f64>) -> Matrix2<f64> {
    Matrix2::new(x[0], x[2], x[2], x[1])
}

/// Residual of the KKT system and its Jacobian at `x = (λ1, λ2, λ3, c1, c2)`.
fn kkt(
    a: &Matrix2<f64>,
    b: &Matrix2<f64>,
    x: &Vector5<f64>,
) -> Option<(Vector5<f64>, Matrix5<f64>, Matrix2<f64>)> {
    let lam = lambda_of(x);
    let lu = kron_matrix(a, &lam).lu();
    let m = unvec2(&lu.solve(&vec2(b))?);
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let c = Vector2::new(x[3], x[4]);
    let g = m * m.transpose() + c * c.transpose() - Matrix2::identity();
    let lc = lam * c;
    let f = Vector5::new(g[(0, 0)], g[(1, 1)], g[(0, 1)], lc[0], lc[1]);
    let mut j = Matrix5::zeros();
    let basis = [
        Matrix2::new(1.0, 0.0, 0.0, 0.0),
        Matrix2::new(0.0, 0.0, 0.0, 1.0),
        Matrix2::new(0.0, 1.0, 1.0, 0.0),
    ];
    for (k, e) in basis.iter().enumerate() {
        // d(Λ R2 + R2 A) = 0  =>  (I⊗Λ + A^T⊗I) vec(dR2) = -vec(dΛ R2)
        let dm = unvec2(&lu.solve(&(-vec2(&(e * m))))?);
        let dg = dm * m.transpose() + m * dm.transpose();
        let dlc = e * c;
        j[(0, k)] = dg[(0, 0)];
        j[(1, k)] = dg[(1, 1)];
        j[(2, k)] = dg[(0, 1)];
        j[(3, k)] = dlc[0];
        j[(4, k)] = dlc[1];
    }
    // d/dc of c c^T and of Λ c
    j[(0, 3)] = 2.0 * c[0];
    j[(1, 4)] = 2.0 * c[1];
    j[(2, 3)] = c[1];
    j[(2, 4)] = c[0];
    j[(3, 3)] = lam[(0, 0)];
    j[(3, 4)] = lam[(0, 1)];
    j[(4, 3)] = lam[(1, 0)];
    j[(4, 4)] = lam[(1, 1)];
    Some((f, j, m))
}

impl Sea {
    /// Runs SEA from the paper's start `Λ0 = sym(B - A)`.
    pub fn solve_moments(&self, mo: &Moments) -> Result<SeaSolution, PoseError> {
        let s = mo.a.trace();
        let (a, b) = (mo.a / s, mo.b / s);
        let l0 = b - a;
        let off = 0.5 * (l0[(0, 1)] + l0[(1, 0)]);
        let lam0 = Matrix2::new(l0[(0, 0)], off, off, l0[(1, 1)]);
        let mut starts = Vec::with_capacity(2);
        // The paper's start is skipped, not fatal, where its Sylvester system is singular (an
        // eigenvalue of Λ0 equal to minus one of A, e.g. a half turn in the image plane):
        // the second start still solves such sets.
        if let Ok(m0) = sylvester_block(&a, &b, &lam0) {
            let c0 = out_of_plane_guess(&m0)?;
            starts.push(Vector5::new(lam0[(0, 0)], lam0[(1, 1)], off, c0[0], c0[1]));
        }
        // second start: the projected unconstrained fit and the Λ consistent with it
        let ml = nearest_valid_block(&(b * a.try_inverse().ok_or(PoseError::Singular("SEA: A"))?))?;
        if let Some(inv) = ml.try_inverse() {
            let l1 = (b - ml * a) * inv;
            let off1 = 0.5 * (l1[(0, 1)] + l1[(1, 0)]);
            let c1 = out_of_plane_guess(&ml)?;
            starts.push(Vector5::new(l1[(0, 0)], l1[(1, 1)], off1, c1[0], c1[1]));
        }
        let mut best: Option<(f64, SeaSolution)> = None;
        for x0 in starts {
            let Some(sol) = self.newton(&a, &b, x0, s) else {
                continue;
            };
            let value = mo.objective(&sol.r2);
            let better = match &best {
                None => true,
                Some((v, b)) => {
                    (sol.converged && !b.converged) || (sol.converged == b.converged && value < *v)
                }
            };
            if better {
                best = Some((value, sol));
            }
        }
        best.map(|(_, s)| s).ok_or(PoseError::Singular("SEA start"))
    }

    /// Newton on the KKT system from `x0 = (λ1, λ2, λ3, c1, c2)` (normalised units).
    fn newton(
        &self,
        a: &Matrix2<f64>,
        b: &Matrix2<f64>,
        mut x: Vector5<f64>,
        scale: f64,
    ) -> Option<SeaSolution> {
        let (mut f, mut jac, mut m) = kkt(a, b, &x)?;
        let mut best = (f.norm(), x, m);
        let mut iterations = 0;
        while iterations < self.max_iter && best.0 > self.tol {
            iterations += 1;
            let Some(step) = jac.lu().solve(&(-f)) else {
                break;
            };
            let f0 = f.norm();
            let mut t = 1.0;
            let mut accepted = false;
            for _ in 0..30 {
                let xn = x + step * t;
                if let Some((fn_, jn, mn)) = kkt(a, b, &xn)
                    && fn_.norm() < f0
                {
                    x = xn;
                    f = fn_;
                    jac = jn;
                    m = mn;
                    accepted = true;
                    break;
                }
                t *= 0.5;
            }
            if !accepted {
                break;
            }
            if f.norm() < best.0 {
                best = (f.norm(), x, m);
            }
        }
        let (res, x, m) = best;
        Some(SeaSolution {
            r2: nearest_valid_block(&m).ok()?,
            lambda: lambda_of(&x) * scale,
            c: Vector2::new(x[3], x[4]),
            iterations,
            converged: res <= self.tol,
            residual_norm: res,
        })
    }

    /// Runs SEA on matches.
    pub fn solve_detailed(
        &self,
        p: &[[f64; 2]],
        q: &[[f64; 2]],
    ) -> Result<(SeaSolution, Moments), PoseError> {
        let mo = moments(p, q, 3)?;
        Ok((self.solve_moments(&mo)?, mo))
    }
}

/// `c0` with `c0 c0^T = I - M M^T` after projecting `M` onto the valid blocks: magnitudes
/// `sqrt(1 - |R_i|^2)`, relative sign that of `-R1·R2` (the paper's sign rule). A vanishing
/// guess is seeded with `1e-3` in that sign pattern (at `c = 0` exactly Newton never leaves the
/// in-plane family).
fn out_of_plane_guess(m: &Matrix2<f64>) -> Result<Vector2<f64>, PoseError> {
    let mv = nearest_valid_block(m)?;
    let e = Matrix2::identity() - mv * mv.transpose();
    let (e11, e22, e12) = (e[(0, 0)].max(0.0), e[(1, 1)].max(0.0), e[(0, 1)]);
    let sign = if e12 < 0.0 { -1.0 } else { 1.0 };
    let c = Vector2::new(e11.sqrt(), sign * e22.sqrt());
    Ok(if c.norm() < 1e-3 {
        Vector2::new(1e-3, sign * 1e-3)
    } else {
        c
    })
}

impl RotationSolver for Sea {
    fn name(&self) -> &'static str {
        "sea"
    }

    fn solve(&self, p: &[[f64; 2]], q: &[[f64; 2]]) -> Result<BlockEstimate, PoseError> {
        let (sol, mo) = self.solve_detailed(p, q)?;
        Ok(estimate_from_block(sol.r2, &mo, p, q))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kronecker_solves_sylvester() {
        let a = Matrix2::new(3.0, 0.5, 0.5, 2.0);
        let lam = Matrix2::new(0.3, -0.2, -0.2, 0.1);
        let m = Matrix2::new(0.9, -0.3, 0.25, 0.8);
        let b = lam * m + m * a;
        let got = sylvester_block(&a, &b, &lam).unwrap();
        assert!((got - m).norm() < 1e-12);
        // singular: Λ = -A
        assert!(sylvester_block(&a, &b, &(-a)).is_err());
    }

    #[test]
    fn a_singular_paper_start_leaves_the_other_start() {
        // A half turn in the image plane: A = diag(4, 2), B = -A, Λ0 = -2A, and the Kronecker
        // matrix of Λ0 has a zero on its diagonal.
        let p = [
            [1.0, 0.0],
            [-1.0, 0.0],
            [1.0, 0.0],
            [-1.0, 0.0],
            [0.0, 1.0],
            [0.0, -1.0],
        ];
        let q: Vec<[f64; 2]> = p.iter().map(|v| [-v[0], -v[1]]).collect();
        let mo = crate::pose::moments(&p, &q, 3).unwrap();
        let s = mo.a.trace();
        let (a, b) = (mo.a / s, mo.b / s);
        let l0 = b - a;
        assert!(sylvester_block(&a, &b, &l0).is_err());
        let est = Sea::default().solve(&p, &q).unwrap();
        let want = Matrix2::new(-1.0, 0.0, 0.0, -1.0);
        assert!((est.r2 - want).norm() < 1e-9, "{:?}", est.r2);
    }

    #[test]
    fn kkt_jacobian_matches_finite_differences() {
        let a = Matrix2::new(0.6, 0.1, 0.1, 0.4);
        let b = Matrix2::new(0.5, -0.1, 0.15, 0.35);
        let x = Vector5::new(0.05, -0.02, 0.01, 0.3, -0.2);
        let (_, j, _) = kkt(&a, &b, &x).unwrap();
        let h = 1e-6;
        for k in 0..5 {
            let mut xp = x;
            let mut xm = x;
            xp[k] += h;
            xm[k] -= h;
            let d = (kkt(&a, &b, &xp).unwrap().0 - kkt(&a, &b, &xm).unwrap().0) / (2.0 * h);
            for r in 0..5 {
                assert!(
                    (d[r] - j[(r, k)]).abs() < 1e-6,
                    "({r},{k}) {} {}",
                    d[r],
                    j[(r, k)]
                );
            }
        }
    }
}
