//! The optimal solver: the certified global minimiser of
//! `f(R2) = Σ_j |q'_j - R2 p'_j|^2` over the blocks of rotations (SPEC section 6).
//!
//! # Reduction
//!
//! Write points as complex numbers `π_j = p'_j` and `κ_j = q'_j`. Any 2x2 matrix acts as
//! `R2 π = z π + w conj(π)` (similarity part `z`, anti-similarity part `w`, see
//! [`super::complete::to_zw`]), and its singular values are `|z| ± |w|`. The blocks of
//! rotations are exactly the matrices with largest singular value 1 (proved in
//! [`super::complete`]), i.e. `{ |z| + |w| = 1 }`: with `ρ ∈ [0, 1]`, `z = ρ e^{iα}`,
//! `w = (1 - ρ) e^{iβ}` the parametrisation `(ρ, α, β) ∈ [0,1] × [-π,π]^2` covers every block.
//! Expanding the objective, with `n = Σ|π|^2 = tr A`, `m = Σ π^2`, `g_z = Σ κ conj(π)`,
//! `g_w = Σ κ π`, `K = Σ|κ|^2`, `σ = 1 - ρ`:
//!
//! `f = K + n (ρ² + σ²) + 2ρσ|m| cos(α - β + arg m) - 2ρ|g_z| cos(α - arg g_z)
//!      - 2σ|g_w| cos(β - arg g_w)`,
//!
//! a smooth trigonometric polynomial on a compact box.
//!
//! # Certified global minimum (branch and bound)
//!
//! On a box with centre `x_c` and half-widths `h`, Taylor's theorem with the Hessian at some
//! point of the box gives `f ≥ f(x_c) - Σ|∂_i f(x_c)| h_i + ½ dᵀ H d`. `H_ρρ = 4n - 4|m| cos(·)
//! ≥ 0` because `|m| ≤ n`, and every other entry is bounded on the box in closed form
//! (`|H_ρα| ≤ 2|m| + 2|g_z|`, `|H_ρβ| ≤ 2|m| + 2|g_w|`, `|H_αα| ≤ 2 max(ρσ)|m| + 2 max(ρ)|g_z|`,
//! `|H_ββ| ≤ 2 max(ρσ)|m| + 2 max(σ)|g_w|`, `|H_αβ| ≤ 2 max(ρσ)|m|`), which yields a rigorous
//! lower bound per box. A second, third-order bound (Hessian at the centre, the quadratic model
//! bounded by `-½ gᵀH⁻¹g` where `H` is positive definite, every third partial bounded on the box
//! by interval enclosures) is tighter near minima; the larger of the two is used. Best-first branch and bound (split the dimension that contributes most
//! to the bound gap) stops when no box can hold a value below `best - ε`, with
//! `ε = eps_rel · (K + n)`; candidate minima found on the way are polished by a damped Newton
//! method. SEA's KKT Newton (from the same moments) supplies one more upper-bound candidate
//! and the final refinement: where it ends lower than the polished search point (possible
//! within ε near `s = 1`, where `β` is flat and the polar Newton stalls), its block is
//! returned, so the result is never above SEA's on the objective. The result is thus certified within `ε` of the global minimum in value (reported as
//! [`OptimalSolution::gap`]). Cost: a few thousand boxes for noisy data, more when the minimum
//! lies near `s = 1` (nearly in-plane rotation: the polar parametrisation degenerates there and
//! `β` becomes a flat direction); the search stops at `max_boxes` and then reports the larger,
//! still rigorous, gap.

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::f64::consts::PI;

use nalgebra::{Matrix2, Matrix3, Vector3};

use super::complete::{from_zw, nearest_valid_block, to_zw};
use super::lsm::lsm_block;
use super::sea::Sea;
use super::{BlockEstimate, Moments, PoseError, RotationSolver, estimate_from_block, moments};

/// The certified global minimiser.
#[derive(Debug, Clone, Copy)]
pub struct Optimal {
    /// Certification tolerance relative to `K + tr A` (the objective's scale).
    pub eps_rel: f64,
    /// Boxes examined at most, the initial grid's aside (it is always examined: 72 boxes);
    /// beyond, the best value so far is returned with its gap.
    pub max_boxes: usize,
}

/// Most boxes [`Optimal::max_boxes`] may ask for: each holds about 100 bytes while it waits.
pub const MAX_BOXES: usize = 10_000_000;

impl Optimal {
    /// Checks the settings, as every solve does: `eps_rel` finite and at least 0 (a negative
    /// one never prunes a box, and with `max_boxes` at usize::MAX the search never ended),
    /// `max_boxes` in `1..=MAX_BOXES`.
    pub fn check(&self) -> Result<(), PoseError> {
        if !(self.eps_rel.is_finite() && self.eps_rel >= 0.0) {
            return Err(PoseError::InvalidParameter(
                "optimal solver eps_rel must be finite and at least 0",
            ));
        }
        if !(1..=MAX_BOXES).contains(&self.max_boxes) {
            return Err(PoseError::InvalidParameter(
                "optimal solver max_boxes must lie in 1..=10000000",
            ));
        }
        Ok(())
    }
}

impl Default for Optimal {
    fn default() -> Self {
        Self {
            eps_rel: 1e-8,
            max_boxes: 100_000,
        }
    }
}

/// The outcome of the optimal solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimalSolution {
    /// The minimising block.
    pub r2: Matrix2<f64>,
    /// Its objective value `f(R2)` (units of the input).
    pub value: f64,
    /// Certified: the global minimum is at least `value - gap`.
    pub gap: f64,
    /// Boxes examined.
    pub boxes: usize,
}

/// The objective in `(ρ, α, β)` coordinates, in normalised units (`n = tr A = 1`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Trig {
    k: f64,
    n: f64,
    m: f64,
    mu: f64,
    gz: f64,
    phz: f64,
    gw: f64,
    phw: f64,
}

impl Trig {
    pub(crate) fn new(mo: &Moments) -> Self {
        let s = mo.a.trace();
        let (a, b) = (mo.a / s, mo.b / s);
        let mre = a[(0, 0)] - a[(1, 1)];
        let mim = 2.0 * a[(0, 1)];
        let gzr = b[(0, 0)] + b[(1, 1)];
        let gzi = b[(1, 0)] - b[(0, 1)];
        let gwr = b[(0, 0)] - b[(1, 1)];
        let gwi = b[(0, 1)] + b[(1, 0)];
        Self {
            k: mo.k / s,
            n: 1.0,
            // |m| ≤ n holds mathematically; clamp against rounding
            m: mre.hypot(mim).min(1.0),
            mu: mim.atan2(mre),
            gz: gzr.hypot(gzi),
            phz: gzi.atan2(gzr),
            gw: gwr.hypot(gwi),
            phw: gwi.atan2(gwr),
        }
    }

    pub(crate) fn value(&self, x: &Vector3<f64>) -> f64 {
        let (r, al, be) = (x[0], x[1], x[2]);
        let s = 1.0 - r;
        self.k + self.n * (r * r + s * s) + 2.0 * r * s * self.m * (al - be + self.mu).cos()
            - 2.0 * r * self.gz * (al - self.phz).cos()
            - 2.0 * s * self.gw * (be - self.phw).cos()
    }

    fn grad_hess(&self, x: &Vector3<f64>) -> (f64, Vector3<f64>, Matrix3<f64>) {
        let (r, al, be) = (x[0], x[1], x[2]);
        let s = 1.0 - r;
        let t1 = al - be + self.mu;
        let (s1, c1) = t1.sin_cos();
        let (sz, cz) = (al - self.phz).sin_cos();
        let (sw, cw) = (be - self.phw).sin_cos();
        let (m, gz, gw, n) = (self.m, self.gz, self.gw, self.n);
        let f = self.k + n * (r * r + s * s) + 2.0 * r * s * m * c1
            - 2.0 * r * gz * cz
            - 2.0 * s * gw * cw;
        let g = Vector3::new(
            2.0 * n * (r - s) + 2.0 * (s - r) * m * c1 - 2.0 * gz * cz + 2.0 * gw * cw,
            -2.0 * r * s * m * s1 + 2.0 * r * gz * sz,
            2.0 * r * s * m * s1 + 2.0 * s * gw * sw,
        );
        let hra = -2.0 * (s - r) * m * s1 + 2.0 * gz * sz;
        let hrb = 2.0 * (s - r) * m * s1 - 2.0 * gw * sw;
        let haa = -2.0 * r * s * m * c1 + 2.0 * r * gz * cz;
        let hbb = -2.0 * r * s * m * c1 + 2.0 * s * gw * cw;
        let hab = 2.0 * r * s * m * c1;
        let h = Matrix3::new(
            4.0 * n - 4.0 * m * c1,
            hra,
            hrb,
            hra,
            haa,
            hab,
            hrb,
            hab,
            hbb,
        );
        (f, g, h)
    }

    /// Rigorous lower bound of `f` on the box `centre ± half`, and the value at the centre.
    fn lower_bound(&self, c: &Vector3<f64>, h: &Vector3<f64>) -> (f64, f64, Vector3<f64>) {
        let (f, g, hess) = self.grad_hess(c);
        let (rl, ru) = (c[0] - h[0], c[0] + h[0]);
        // max of ρ(1-ρ) on [rl, ru]
        let rs = if rl <= 0.5 && ru >= 0.5 {
            0.25
        } else {
            (rl * (1.0 - rl)).max(ru * (1.0 - ru))
        };
        let b_ra = 2.0 * self.m + 2.0 * self.gz;
        let b_rb = 2.0 * self.m + 2.0 * self.gw;
        let b_aa = 2.0 * rs * self.m + 2.0 * ru * self.gz;
        let b_bb = 2.0 * rs * self.m + 2.0 * (1.0 - rl) * self.gw;
        let b_ab = 2.0 * rs * self.m;
        let quad = 2.0 * b_ra * h[0] * h[1]
            + 2.0 * b_rb * h[0] * h[2]
            + b_aa * h[1] * h[1]
            + b_bb * h[2] * h[2]
            + 2.0 * b_ab * h[1] * h[2];
        // per-dimension share of the gap, to choose the split
        let share = Vector3::new(
            g[0].abs() * h[0] + b_ra * h[0] * h[1] + b_rb * h[0] * h[2],
            g[1].abs() * h[1] + b_ra * h[0] * h[1] + b_aa * h[1] * h[1] + b_ab * h[1] * h[2],
            g[2].abs() * h[2] + b_rb * h[0] * h[2] + b_bb * h[2] * h[2] + b_ab * h[1] * h[2],
        );
        let lb2 = f - g.abs().dot(h) - 0.5 * quad;
        // Third-order bound: f(c+d) ≥ f(c) + g·d + ½ dᵀH(c)d - R3, with R3 the sum of the
        // third partials bounded on the box (interval enclosures of sin/cos, of ρσ and 1-2ρ)
        // times h_i h_j h_k with multiplicities; the quadratic model is bounded below by
        // -½ gᵀH⁻¹g when H(c) is positive definite, else by -|g|·h - ½‖H‖_∞ |h|².
        let hc = hess;
        let (hr, ha, hb) = (h[0], h[1], h[2]);
        let th1 = c[1] - c[2] + self.mu;
        let enc = |v: f64, w: f64| (v.abs() + w).min(1.0);
        let (s1b, c1b) = (enc(th1.sin(), ha + hb), enc(th1.cos(), ha + hb));
        let (szb, czb) = (
            enc((c[1] - self.phz).sin(), ha),
            enc((c[1] - self.phz).cos(), ha),
        );
        let (swb, cwb) = (
            enc((c[2] - self.phw).sin(), hb),
            enc((c[2] - self.phw).cos(), hb),
        );
        let p1 = (1.0 - 2.0 * rl).abs().max((1.0 - 2.0 * ru).abs());
        let (m, gz, gw) = (self.m, self.gz, self.gw);
        let d_rra = 4.0 * m * s1b;
        let d_raa = 2.0 * m * p1 * c1b + 2.0 * gz * czb;
        let d_rab = 2.0 * m * p1 * c1b;
        let d_rbb = 2.0 * m * p1 * c1b + 2.0 * gw * cwb;
        let d_ang = 2.0 * m * rs * s1b;
        let d_aaa = d_ang + 2.0 * gz * ru * szb;
        let d_bbb = d_ang + 2.0 * gw * (1.0 - rl) * swb;
        let t = [
            3.0 * d_rra * hr * hr * ha,
            3.0 * d_rra * hr * hr * hb,
            3.0 * d_raa * hr * ha * ha,
            6.0 * d_rab * hr * ha * hb,
            3.0 * d_rbb * hr * hb * hb,
            d_aaa * ha * ha * ha,
            3.0 * d_ang * ha * ha * hb,
            3.0 * d_ang * ha * hb * hb,
            d_bbb * hb * hb * hb,
        ];
        let r3 = t.iter().sum::<f64>() / 6.0;
        let quad_lb = match hc.cholesky() {
            Some(ch) => (-0.5 * g.dot(&ch.solve(&g))).max(-g.abs().dot(h)),
            None => {
                let norm = (0..3)
                    .map(|i| (0..3).map(|j| hc[(i, j)].abs()).sum::<f64>())
                    .fold(0.0, f64::max);
                -g.abs().dot(h) - 0.5 * norm * h.norm_squared()
            }
        };
        let lb3 = f + quad_lb - r3;
        let share3 = Vector3::new(
            t[0] + t[1] + t[2] + t[3] + t[4],
            t[0] + t[2] + t[3] + t[5] + t[6] + t[7],
            t[1] + t[3] + t[4] + t[6] + t[7] + t[8],
        );
        let share = if lb3 > lb2 {
            share3 + g.abs().component_mul(h) * 1e-3
        } else {
            share
        };
        (lb2.max(lb3), f, share)
    }

    /// Damped Newton from `x`, keeping `ρ` in `[0, 1]`; returns the polished point and value.
    fn polish(&self, mut x: Vector3<f64>) -> (Vector3<f64>, f64) {
        let (mut f, mut g, mut h) = self.grad_hess(&x);
        let mut mu = 1e-9;
        for _ in 0..60 {
            if g.norm() < 1e-15 {
                break;
            }
            let mut improved = false;
            for _ in 0..20 {
                let hm = h + Matrix3::identity() * mu;
                let step = match hm.cholesky() {
                    Some(ch) => ch.solve(&(-g)),
                    None => {
                        mu = (mu * 10.0).max(1e-6);
                        continue;
                    }
                };
                let mut xn = x + step;
                xn[0] = xn[0].clamp(0.0, 1.0);
                let fnew = self.value(&xn);
                // f is computed with cancellation (K - ...): once values tie to rounding,
                // a step that lowers the gradient is still progress
                let tie = fnew <= f + 1e-13 * (self.k + self.n);
                if fnew < f || (tie && self.grad_hess(&xn).1.norm() < g.norm()) {
                    x = xn;
                    let (f2, g2, h2) = self.grad_hess(&x);
                    f = f2;
                    g = g2;
                    h = h2;
                    mu = (mu * 0.1).max(1e-12);
                    improved = true;
                    break;
                }
                mu *= 10.0;
            }
            if !improved {
                break;
            }
        }
        (x, f)
    }

    fn block(x: &Vector3<f64>) -> Matrix2<f64> {
        let (r, al, be) = (x[0], x[1], x[2]);
        let s = 1.0 - r;
        from_zw([r * al.cos(), r * al.sin()], [s * be.cos(), s * be.sin()])
    }

    fn coords(m: &Matrix2<f64>) -> Vector3<f64> {
        let (z, w) = to_zw(m);
        let nz = z[0].hypot(z[1]);
        let nw = w[0].hypot(w[1]);
        let r = if nz + nw > 0.0 { nz / (nz + nw) } else { 1.0 };
        Vector3::new(r, z[1].atan2(z[0]), w[1].atan2(w[0]))
    }
}

struct Node {
    lb: f64,
    c: Vector3<f64>,
    h: Vector3<f64>,
    share: Vector3<f64>,
}

impl PartialEq for Node {
    fn eq(&self, o: &Self) -> bool {
        self.lb == o.lb
    }
}
impl Eq for Node {}
impl PartialOrd for Node {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Node {
    fn cmp(&self, o: &Self) -> Ordering {
        // min-heap on the lower bound
        o.lb.total_cmp(&self.lb)
    }
}

impl Optimal {
    /// Global minimisation from the moments.
    pub fn solve_moments(&self, mo: &Moments) -> Result<OptimalSolution, PoseError> {
        self.check()?;
        let t = Trig::new(mo);
        let scale = mo.a.trace();
        let eps = self.eps_rel * (t.k + t.n);
        // Upper bound from closed-form candidates: projected LSM, best pure rotation
        // (ρ = 1, α = arg g_z), best pure reflection (ρ = 0, β = arg g_w).
        let mut cands = vec![Vector3::new(1.0, t.phz, 0.0), Vector3::new(0.0, 0.0, t.phw)];
        if let Ok(l) = lsm_block(mo).and_then(|l| nearest_valid_block(&l)) {
            cands.push(Trig::coords(&l));
        }
        // SEA's Newton on the KKT system (cheap next to the search) as one more upper-bound
        // candidate and, at the end, as the refinement of the returned point: the polar
        // coordinates degenerate near s = 1, where the polish above can stop within ε of
        // the minimum in value but visibly away from it in angle.
        let sea = Sea::default().solve_moments(mo).ok();
        if let Some(sol) = &sea {
            cands.push(Trig::coords(&sol.r2));
        }
        let mut best = (Vector3::new(1.0, 0.0, 0.0), f64::INFINITY);
        for c in cands {
            let (x, f) = t.polish(c);
            if f < best.1 {
                best = (x, f);
            }
        }
        let mut heap = BinaryHeap::new();
        let (nr, na) = (2usize, 6usize);
        let h0 = Vector3::new(0.5 / nr as f64, PI / na as f64, PI / na as f64);
        for i in 0..nr {
            for j in 0..na {
                for k in 0..na {
                    let c = Vector3::new(
                        (2 * i + 1) as f64 * h0[0],
                        -PI + (2 * j + 1) as f64 * h0[1],
                        -PI + (2 * k + 1) as f64 * h0[2],
                    );
                    let (lb, f, share) = t.lower_bound(&c, &h0);
                    if f < best.1 {
                        best = (c, f);
                    }
                    heap.push(Node {
                        lb,
                        c,
                        h: h0,
                        share,
                    });
                }
            }
        }
        let mut boxes = heap.len();
        let mut polished_at = f64::INFINITY;
        // Lower bound of the boxes not yet pruned when the search stops (pruned boxes have
        // lb ≥ best - ε, best only decreasing).
        let mut open_lb = f64::INFINITY;
        while let Some(node) = heap.pop() {
            if node.lb >= best.1 - eps {
                open_lb = node.lb;
                break;
            }
            if boxes >= self.max_boxes {
                open_lb = node.lb;
                break;
            }
            // polish promising centres (each basin once it is clearly the best so far)
            if best.1 < polished_at - eps {
                let (x, f) = t.polish(best.0);
                if f < best.1 {
                    best = (x, f);
                }
                polished_at = best.1;
            }
            let d = if node.share[0] >= node.share[1] && node.share[0] >= node.share[2] {
                0
            } else if node.share[1] >= node.share[2] {
                1
            } else {
                2
            };
            let mut h = node.h;
            h[d] *= 0.5;
            for sgn in [-1.0, 1.0] {
                let mut c = node.c;
                c[d] += sgn * h[d];
                let (lb, f, share) = t.lower_bound(&c, &h);
                boxes += 1;
                if f < best.1 {
                    best = (c, f);
                }
                if lb < best.1 - eps {
                    heap.push(Node { lb, c, h, share });
                }
            }
        }
        let (x, f) = t.polish(best.0);
        if f < best.1 {
            best = (x, f);
        }
        let mut gap = eps.max(best.1 - open_lb) * scale;
        let mut r2 = nearest_valid_block(&Trig::block(&best.0))?;
        // Compared by their excess over the unconstrained fit: the objective from the moments
        // cancels to rounding noise near an exact fit, where a block 1e-7 px off read as
        // better than SEA's exact one (and the value as negative).
        let mut excess = mo.excess_over_lsm(&r2);
        if let Some(sol) = sea {
            let v = mo.excess_over_lsm(&sol.r2);
            if v < excess {
                // Still certified: the global minimum is ≥ the old value - gap.
                gap = (gap - (excess - v)).max(0.0);
                r2 = sol.r2;
                excess = v;
            }
        }
        Ok(OptimalSolution {
            r2,
            value: mo.lsm_floor() + excess,
            gap,
            boxes,
        })
    }

    /// Global minimisation on matches.
    pub fn solve_detailed(
        &self,
        p: &[[f64; 2]],
        q: &[[f64; 2]],
    ) -> Result<(OptimalSolution, Moments), PoseError> {
        let mo = moments(p, q, 3)?;
        Ok((self.solve_moments(&mo)?, mo))
    }
}

impl RotationSolver for Optimal {
    fn name(&self) -> &'static str {
        "optimal"
    }

    fn solve(&self, p: &[[f64; 2]], q: &[[f64; 2]]) -> Result<BlockEstimate, PoseError> {
        let (sol, mo) = self.solve_detailed(p, q)?;
        Ok(estimate_from_block(sol.r2, &mo, p, q))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_moments(seed: u64) -> Moments {
        use rand::{Rng, SeedableRng, rngs::StdRng};
        let mut rng = StdRng::seed_from_u64(seed);
        let p: Vec<[f64; 2]> = (0..8)
            .map(|_| [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)])
            .collect();
        let q: Vec<[f64; 2]> = (0..8)
            .map(|_| [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)])
            .collect();
        moments(&p, &q, 3).unwrap()
    }

    #[test]
    fn settings_that_would_never_stop_are_refused() {
        let mo = sample_moments(3);
        for bad in [
            Optimal {
                eps_rel: -1.0,
                max_boxes: usize::MAX,
            },
            Optimal {
                eps_rel: f64::NAN,
                ..Optimal::default()
            },
            Optimal {
                max_boxes: 0,
                ..Optimal::default()
            },
        ] {
            assert!(
                matches!(bad.solve_moments(&mo), Err(PoseError::InvalidParameter(_))),
                "{bad:?}"
            );
        }
        assert!(Optimal::default().check().is_ok());
    }

    #[test]
    fn trig_form_equals_matrix_objective() {
        let mo = sample_moments(3);
        let t = Trig::new(&mo);
        let s = mo.a.trace();
        for i in 0..100 {
            let x = Vector3::new((i as f64 * 0.137) % 1.0, i as f64 * 0.7, i as f64 * -1.3);
            let m = Trig::block(&x);
            assert!((t.value(&x) * s - mo.objective(&m)).abs() < 1e-10);
            // every parameter gives a rotation block
            let (s1, _) = super::super::complete::singular_values(&m);
            assert!((s1 - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn gradient_and_hessian_match_finite_differences() {
        let t = Trig::new(&sample_moments(5));
        let x = Vector3::new(0.3, 0.4, -2.0);
        let (_, g, h) = t.grad_hess(&x);
        let e = 1e-6;
        for i in 0..3 {
            let mut xp = x;
            let mut xm = x;
            xp[i] += e;
            xm[i] -= e;
            assert!(((t.value(&xp) - t.value(&xm)) / (2.0 * e) - g[i]).abs() < 1e-6);
            let (_, gp, _) = t.grad_hess(&xp);
            let (_, gm, _) = t.grad_hess(&xm);
            for j in 0..3 {
                assert!(((gp[j] - gm[j]) / (2.0 * e) - h[(j, i)]).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn lower_bound_is_valid_on_random_boxes() {
        let t = Trig::new(&sample_moments(9));
        for i in 0..200 {
            let fi = i as f64;
            let h = Vector3::new(0.05 + (fi * 0.01) % 0.2, 0.1 + (fi * 0.03) % 0.5, 0.2);
            let c = Vector3::new(
                h[0] + (fi * 0.071) % (1.0 - 2.0 * h[0]),
                fi * 0.3,
                -fi * 0.2,
            );
            let (lb, _, _) = t.lower_bound(&c, &h);
            for a in 0..5 {
                for b in 0..5 {
                    for d in 0..5 {
                        let u = |k: usize| k as f64 / 2.0 - 1.0;
                        let x = c + Vector3::new(u(a) * h[0], u(b) * h[1], u(d) * h[2]);
                        assert!(t.value(&x) >= lb - 1e-12);
                    }
                }
            }
        }
    }
}
