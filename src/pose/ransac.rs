//! RLS: RANSAC on the matches, then least squares on the inliers (the paper's baseline).
//!
//! Minimal sample: 3 matches, which fix the affine map `q = M p + l` exactly. A match is an
//! inlier when `|q - M p - l| < threshold` (pixels). The number of iterations adapts to the
//! best inlier ratio `w` found so far: `N = ln(1 - confidence) / ln(1 - w^3)`, capped at
//! `max_iter`. Ties in the inlier count go to the smaller inlier residual. Deterministic for
//! the seed (`StdRng`). The final block is `B A^-1` on the inliers (unconstrained, like LSM).

use nalgebra::{Matrix2, Vector2};
use rand::{SeedableRng, rngs::StdRng, seq::index::sample};

use super::lsm::lsm_block;
use super::{BlockEstimate, PoseError, RotationSolver, moments, rms_residual};

/// RANSAC then least squares.
#[derive(Debug, Clone, Copy)]
pub struct Rls {
    /// Inlier threshold on the transfer error (pixels).
    pub threshold: f64,
    /// Probability of drawing at least one all-inlier sample.
    pub confidence: f64,
    /// Iterations at most.
    pub max_iter: usize,
    /// Seed of the sampler.
    pub seed: u64,
}

impl Default for Rls {
    fn default() -> Self {
        Self {
            threshold: 2.0,
            confidence: 0.99,
            max_iter: 1000,
            seed: 0,
        }
    }
}

/// Most RANSAC iterations [`affine_consensus`] accepts (`max_iter`).
pub const MAX_ITER: usize = 1_000_000;

fn affine3(p: &[[f64; 2]; 3], q: &[[f64; 2]; 3]) -> Option<(Matrix2<f64>, Vector2<f64>)> {
    let m = moments(p, q, 3).ok()?;
    let r2 = lsm_block(&m).ok()?;
    Some((r2, m.mean_q - r2 * m.mean_p))
}

/// The largest set of matches `p -> q` that one affine map `q = M p + l` carries to within
/// `threshold` pixels, found by RANSAC on minimal samples of 3 (see the module's notes on the
/// number of iterations and ties); `true` marks an inlier. Deterministic for the seed.
///
/// Errors: fewer than 3 matches, NaN/inf or degenerate points ([`moments`]), a threshold that
/// is not positive and finite, a confidence outside (0, 1) or `max_iter` out of range
/// ([`PoseError::InvalidParameter`]), or no sample that fixes a map
/// ([`PoseError::NoSolution`]).
pub fn affine_consensus(
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    threshold: f64,
    confidence: f64,
    max_iter: usize,
    seed: u64,
) -> Result<Vec<bool>, PoseError> {
    moments(p, q, 3)?;
    if !(threshold.is_finite() && threshold > 0.0) {
        return Err(PoseError::InvalidParameter(
            "RANSAC threshold must be positive and finite",
        ));
    }
    // A confidence of 1 or more asks for every sample there is (with `max_iter` at
    // usize::MAX the loop never ended); NaN or 0 or less stopped after one sample.
    if !(confidence > 0.0 && confidence < 1.0) {
        return Err(PoseError::InvalidParameter(
            "RANSAC confidence must lie strictly between 0 and 1",
        ));
    }
    if max_iter == 0 || max_iter > MAX_ITER {
        return Err(PoseError::InvalidParameter(
            "RANSAC max_iter must lie in 1..=1000000",
        ));
    }
    let n = p.len();
    let mut rng = StdRng::seed_from_u64(seed);
    let t2 = threshold * threshold;
    let mut best: Option<(usize, f64, Vec<bool>)> = None;
    let mut needed = max_iter;
    let mut it = 0;
    while it < needed.min(max_iter) {
        it += 1;
        let idx = sample(&mut rng, n, 3);
        let (i, j, k) = (idx.index(0), idx.index(1), idx.index(2));
        let Some((r2, l)) = affine3(&[p[i], p[j], p[k]], &[q[i], q[j], q[k]]) else {
            continue;
        };
        let mut mask = vec![false; n];
        let mut count = 0;
        let mut err = 0.0;
        for (jj, (x, y)) in p.iter().zip(q).enumerate() {
            let e = (Vector2::new(y[0], y[1]) - r2 * Vector2::new(x[0], x[1]) - l).norm_squared();
            if e < t2 {
                mask[jj] = true;
                count += 1;
                err += e;
            }
        }
        let better = match &best {
            None => true,
            Some((c, e, _)) => count > *c || (count == *c && err < *e),
        };
        if better {
            let w = count as f64 / n as f64;
            let denom = (1.0 - w.powi(3)).ln();
            needed = if denom < 0.0 {
                ((1.0 - confidence).ln() / denom).ceil().max(1.0) as usize
            } else {
                max_iter
            };
            best = Some((count, err, mask));
        }
    }
    best.map(|(_, _, mask)| mask)
        .ok_or(PoseError::NoSolution("RANSAC found no model"))
}

/// The matches `p -> q` that `mask` marks (`true`), as two point sets.
pub fn select(p: &[[f64; 2]], q: &[[f64; 2]], mask: &[bool]) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    p.iter()
        .zip(q)
        .zip(mask)
        .filter(|(_, m)| **m)
        .map(|((a, b), _)| (*a, *b))
        .unzip()
}

impl RotationSolver for Rls {
    fn name(&self) -> &'static str {
        "rls"
    }

    fn solve(&self, p: &[[f64; 2]], q: &[[f64; 2]]) -> Result<BlockEstimate, PoseError> {
        let mask = affine_consensus(
            p,
            q,
            self.threshold,
            self.confidence,
            self.max_iter,
            self.seed,
        )?;
        let (pi, qi) = select(p, q, &mask);
        let mo = moments(&pi, &qi, 3)
            .map_err(|_| PoseError::NoSolution("RANSAC inliers are degenerate"))?;
        let r2 = lsm_block(&mo)?;
        let translation = mo.mean_q - r2 * mo.mean_p;
        let residual = rms_residual(&r2, &translation, p, q, Some(&mask));
        Ok(BlockEstimate {
            r2,
            translation,
            residual,
            inliers: mask,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_outliers_and_is_deterministic() {
        let m = Matrix2::new(0.95, -0.2, 0.25, 0.9);
        let mut p = Vec::new();
        let mut q = Vec::new();
        for i in 0..30 {
            let x = [
                (i as f64 * 7.3) % 40.0 - 20.0,
                (i as f64 * 3.1) % 30.0 - 15.0,
            ];
            let y = m * Vector2::new(x[0], x[1]) + Vector2::new(3.0, -1.0);
            p.push(x);
            q.push([y[0], y[1]]);
        }
        for i in [2usize, 9, 17, 25] {
            q[i][0] += 15.0 + i as f64;
        }
        let r = Rls::default();
        let e = r.solve(&p, &q).unwrap();
        assert!((e.r2 - m).norm() < 1e-10);
        assert_eq!(e.inliers.iter().filter(|b| !**b).count(), 4);
        assert!(!e.inliers[9]);
        assert_eq!(e, r.solve(&p, &q).unwrap());
        // Settings that never stop (confidence 1 with no iteration bound) or stop after one
        // sample (NaN, 0 or less, more than 1) are refused.
        for bad in [
            Rls {
                confidence: 1.0,
                max_iter: usize::MAX,
                ..r
            },
            Rls {
                confidence: f64::NAN,
                ..r
            },
            Rls {
                confidence: 1.5,
                ..r
            },
            Rls {
                confidence: -1.0,
                ..r
            },
            Rls { max_iter: 0, ..r },
            // A threshold of 0 or less, NaN or infinite (every match an inlier).
            Rls {
                threshold: 0.0,
                ..r
            },
            Rls {
                threshold: -1.0,
                ..r
            },
            Rls {
                threshold: f64::NAN,
                ..r
            },
            Rls {
                threshold: f64::INFINITY,
                ..r
            },
        ] {
            assert!(
                matches!(bad.solve(&p, &q), Err(PoseError::InvalidParameter(_))),
                "{bad:?}"
            );
        }
    }
}
