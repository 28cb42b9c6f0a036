//! LSM: unconstrained least squares `R2 = B A^-1` (the paper's baseline, SPEC section 4).

use nalgebra::Matrix2;

use super::{BlockEstimate, Moments, PoseError, RotationSolver, estimate_from_block, moments};

/// Unconstrained least squares. The block is not forced onto the rotation blocks; completion
/// ([`super::complete_rotation`]) projects it.
#[derive(Debug, Clone, Copy, Default)]
pub struct Lsm;

/// `B A^-1` from the moments.
pub fn lsm_block(m: &Moments) -> Result<Matrix2<f64>, PoseError> {
    let inv = m.a.try_inverse().ok_or(PoseError::Singular("LSM"))?;
    Ok(m.b * inv)
}

impl RotationSolver for Lsm {
    fn name(&self) -> &'static str {
        "lsm"
    }

    fn solve(&self, p: &[[f64; 2]], q: &[[f64; 2]]) -> Result<BlockEstimate, PoseError> {
        let m = moments(p, q, 3)?;
        Ok(estimate_from_block(lsm_block(&m)?, &m, p, q))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_an_affine_map_exactly() {
        let m = Matrix2::new(0.9, -0.3, 0.2, 1.1);
        let p = [[0.0, 0.0], [3.0, 1.0], [-2.0, 4.0], [1.0, -5.0]];
        let q: Vec<[f64; 2]> = p
            .iter()
            .map(|x| {
                let y = m * nalgebra::Vector2::new(x[0], x[1]);
                [y[0] + 7.0, y[1] - 2.0]
            })
            .collect();
        let e = Lsm.solve(&p, &q).unwrap();
        assert!((e.r2 - m).norm() < 1e-12);
        assert!((e.translation - nalgebra::Vector2::new(7.0, -2.0)).norm() < 1e-12);
        assert!(e.residual < 1e-12);
    }
}
