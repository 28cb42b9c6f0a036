//! Direct least-squares ellipse fitting (Fitzgibbon, Pilu & Fisher 1999) in the numerically
//! stable form of Halír & Flusser (1998).
//!
//! The conic `A x² + B xy + C y² + D x + E y + F = 0` minimising the algebraic distance
//! `Σ (conic(p_i))²` under the ellipse constraint `4AC − B² = 1` is the eigenvector of a 3x3
//! problem (the quadratic part; the linear part follows from it) whose `4AC − B² > 0`. The
//! points are centred on their mean and scaled to unit RMS distance first, which keeps the
//! scatter matrices well conditioned for image coordinates in the hundreds.
//!
//! Convention of the result ([`Ellipse`]): the fit is returned with `theta` in `(−π/4, π/4]`,
//! i.e. `a` is the semi-axis closer to the image x axis and `b` the one closer to y. `a ≥ b`
//! is **not** enforced: an upright head gives `a < b, theta ≈ 0`, the same form
//! [`Ellipse::from_box`] produces, so boxes and fitted points agree without a quarter turn.

use nalgebra::{Matrix2, Matrix3, Vector3};

use super::MotionError;
use crate::geometry::Ellipse;

/// The largest semi-axis, and distance of the centre from the points' mean, of a fit, in
/// units of the points' RMS distance from their mean over √2.
const MAX_SPREAD: f64 = 100.0;

/// Fits an ellipse to at least 5 points by the direct least-squares method.
///
/// Errors: [`MotionError::TooFewPoints`] for fewer than 5 points,
/// [`MotionError::NonFinite`] for a NaN or infinite coordinate, and
/// [`MotionError::Degenerate`] when the points do not determine an ellipse (all identical,
/// collinear, on two parallel lines, or the best conic is not a real ellipse), or the ellipse
/// would be more than a hundred times their spread across or away.
pub fn fit_ellipse(points: &[[f64; 2]]) -> Result<Ellipse, MotionError> {
    if points.len() < 5 {
        return Err(MotionError::TooFewPoints {
            needed: 5,
            got: points.len(),
        });
    }
    if points
        .iter()
        .any(|p| !p[0].is_finite() || !p[1].is_finite())
    {
        return Err(MotionError::NonFinite);
    }
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p[0]).sum::<f64>() / n;
    let my = points.iter().map(|p| p[1]).sum::<f64>() / n;
    let rms = (points
        .iter()
        .map(|p| (p[0] - mx).powi(2) + (p[1] - my).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let extent = mx.abs().max(my.abs()).max(1.0);
    if rms <= 1e-9 * extent {
        return Err(MotionError::Degenerate("all points coincide"));
    }
    let s = rms / std::f64::consts::SQRT_2;

    // Scatter matrices of D1 = [x², xy, y²] and D2 = [x, y, 1] on the normalised points.
    let mut s1 = Matrix3::<f64>::zeros();
    let mut s2 = Matrix3::<f64>::zeros();
    let mut s3 = Matrix3::<f64>::zeros();
    for p in points {
        let x = (p[0] - mx) / s;
        let y = (p[1] - my) / s;
        let d1 = Vector3::new(x * x, x * y, y * y);
        let d2 = Vector3::new(x, y, 1.0);
        s1 += d1 * d1.transpose();
        s2 += d1 * d2.transpose();
        s3 += d2 * d2.transpose();
    }
    // Collinear points make S3 (the scatter of [x, y, 1]) singular.
    let s3_inv = match s3.try_inverse() {
        Some(m) if s3.determinant().abs() > 1e-10 * n.powi(3) => m,
        _ => {
            return Err(MotionError::Degenerate(
                "points are collinear, or nearly so at their scale",
            ));
        }
    };
    let t = -(s3_inv * s2.transpose());
    let m = s1 + s2 * t;
    // Premultiply by C1⁻¹, C1 = [[0,0,2],[0,-1,0],[2,0,0]].
    let m = Matrix3::new(
        m[(2, 0)] / 2.0,
        m[(2, 1)] / 2.0,
        m[(2, 2)] / 2.0,
        -m[(1, 0)],
        -m[(1, 1)],
        -m[(1, 2)],
        m[(0, 0)] / 2.0,
        m[(0, 1)] / 2.0,
        m[(0, 2)] / 2.0,
    );
    let a1 =
        ellipse_eigenvector(&m).ok_or(MotionError::Degenerate("no ellipse fits the points"))?;
    let a2 = t * a1;
    let conic = [a1[0], a1[1], a1[2], a2[0], a2[1], a2[2]];
    let e = conic_to_ellipse(&conic)
        .ok_or(MotionError::Degenerate("the conic is not a real ellipse"))?;
    // The points have unit RMS distance here. An ellipse a hundred times their spread, or
    // centred that far off, bounds nothing: points on two parallel lines, whose best conic is
    // the line pair on the ellipses' border, came back 1e4 times their spread from round-off
    // (a partial arc of 3 degrees would need about 30).
    if e.a.max(e.b) > MAX_SPREAD || e.cx.hypot(e.cy) > MAX_SPREAD {
        return Err(MotionError::Degenerate(
            "no ellipse bounds the points (they lie on two parallel lines, or nearly)",
        ));
    }
    let out = Ellipse {
        cx: mx + s * e.cx,
        cy: my + s * e.cy,
        a: s * e.a,
        b: s * e.b,
        theta: e.theta,
    };
    if out.is_valid() {
        Ok(out)
    } else {
        Err(MotionError::Degenerate("the fitted ellipse is not finite"))
    }
}

/// The eigenvector of the (non-symmetric) 3x3 reduced problem with `4ac − b² > 0`.
/// Among several candidates (only possible through round-off) the one with the largest
/// constraint value after normalisation wins.
fn ellipse_eigenvector(m: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let scale = m.abs().max().max(1e-300);
    let mn = m / scale;
    let mut best: Option<(f64, Vector3<f64>)> = None;
    for ev in mn.complex_eigenvalues().iter() {
        if ev.im.abs() > 1e-9 * (1.0 + ev.re.abs()) {
            continue;
        }
        let k = mn - Matrix3::identity() * ev.re;
        let Some(v) = null_vector(&k) else { continue };
        let cond = 4.0 * v[0] * v[2] - v[1] * v[1];
        if cond > 0.0 && best.as_ref().is_none_or(|(c, _)| cond > *c) {
            best = Some((cond, v));
        }
    }
    best.map(|(_, v)| v)
}

/// A unit vector in the (numerical) null space of a rank-2 3x3 matrix: the largest cross
/// product of two of its rows.
fn null_vector(k: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let r: [Vector3<f64>; 3] = [
        k.row(0).transpose(),
        k.row(1).transpose(),
        k.row(2).transpose(),
    ];
    let cands = [r[0].cross(&r[1]), r[0].cross(&r[2]), r[1].cross(&r[2])];
    let best = cands
        .iter()
        .max_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()))?;
    let nrm = best.norm();
    if nrm > 0.0 && nrm.is_finite() {
        Some(best / nrm)
    } else {
        None
    }
}

/// Converts the conic `[A, B, C, D, E, F]` to centre, semi-axes and orientation, with
/// `theta ∈ (−π/4, π/4]` (see the module docs). `None` unless it is a real, non-degenerate
/// ellipse.
pub(crate) fn conic_to_ellipse(c: &[f64; 6]) -> Option<Ellipse> {
    let [a, b, cc, d, e, f] = *c;
    let det = 4.0 * a * cc - b * b;
    if det.is_nan() || det <= 0.0 {
        return None;
    }
    // Centre: gradient zero, [2A B; B 2C] [x y]ᵀ = −[D E]ᵀ.
    let x0 = (b * e - 2.0 * cc * d) / det;
    let y0 = (b * d - 2.0 * a * e) / det;
    let f0 = f + 0.5 * (d * x0 + e * y0);
    // (p − c)ᵀ Q (p − c) = −f0 with Q = [[A, B/2], [B/2, C]].
    let q = Matrix2::new(a, b / 2.0, b / 2.0, cc);
    let eig = q.symmetric_eigen();
    let (l0, l1) = (eig.eigenvalues[0], eig.eigenvalues[1]);
    let r0 = -f0 / l0;
    let r1 = -f0 / l1;
    if !(r0 > 0.0 && r1 > 0.0) {
        return None;
    }
    let v0 = eig.eigenvectors.column(0);
    let (mut ax0, mut ax1) = (r0.sqrt(), r1.sqrt());
    // Orientation of eigenvector 0, folded into (−π/2, π/2].
    let mut theta = fold_half_turn(v0[1].atan2(v0[0]));
    // Bring theta into (−π/4, π/4] by swapping the axes (a quarter turn).
    if theta > std::f64::consts::FRAC_PI_4 {
        theta -= std::f64::consts::FRAC_PI_2;
        std::mem::swap(&mut ax0, &mut ax1);
    } else if theta <= -std::f64::consts::FRAC_PI_4 {
        theta += std::f64::consts::FRAC_PI_2;
        std::mem::swap(&mut ax0, &mut ax1);
    }
    Some(Ellipse {
        cx: x0,
        cy: y0,
        a: ax0,
        b: ax1,
        theta,
    })
}

/// An angle folded into `(−π/2, π/2]` (an ellipse is symmetric under a half turn).
fn fold_half_turn(t: f64) -> f64 {
    let pi = std::f64::consts::PI;
    let mut t = t % pi;
    if t > pi / 2.0 {
        t -= pi;
    } else if t <= -pi / 2.0 {
        t += pi;
    }
    t
}

/// Whether two ellipses describe the same curve (up to the symmetric choices of axis order
/// and orientation), comparing contour points: the largest distance from a contour point of
/// `e` to the contour of `f` measured in `f`'s unit metric scaled by its mean radius.
pub fn contour_distance(e: &Ellipse, f: &Ellipse) -> f64 {
    let r = 0.5 * (f.a + f.b);
    (0..72)
        .map(|k| {
            let (x, y) = e.point_at(k as f64 * std::f64::consts::TAU / 72.0);
            let (u, v) = f.to_unit(x, y);
            ((u * u + v * v).sqrt() - 1.0).abs() * r
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    fn random_ellipse(rng: &mut StdRng) -> Ellipse {
        Ellipse {
            cx: rng.random_range(-200.0..400.0),
            cy: rng.random_range(-100.0..300.0),
            a: rng.random_range(3.0..80.0),
            b: rng.random_range(3.0..80.0),
            theta: rng.random_range(-3.2..3.2),
        }
    }

    fn points_on(e: &Ellipse, n: usize, phi0: f64, span: f64) -> Vec<[f64; 2]> {
        (0..n)
            .map(|k| {
                let (x, y) = e.point_at(phi0 + span * k as f64 / n as f64);
                [x, y]
            })
            .collect()
    }

    #[test]
    fn recovers_random_ellipses_exactly_in_canonical_form() {
        let mut rng = StdRng::seed_from_u64(1);
        for _ in 0..200 {
            let e = random_ellipse(&mut rng);
            let n = rng.random_range(5..40);
            let pts = points_on(&e, n, rng.random_range(0.0..6.3), std::f64::consts::TAU);
            let f = fit_ellipse(&pts).unwrap();
            assert!(
                (f.cx - e.cx).abs() < 1e-6 && (f.cy - e.cy).abs() < 1e-6,
                "{e:?} {f:?}"
            );
            assert!(contour_distance(&e, &f) < 1e-6, "{e:?} {f:?}");
            assert!(contour_distance(&f, &e) < 1e-6, "{e:?} {f:?}");
            let q = std::f64::consts::FRAC_PI_4;
            assert!(f.theta > -q - 1e-12 && f.theta <= q + 1e-12, "{f:?}");
            // Same area, axes the same up to order.
            let (lo, hi) = (e.a.min(e.b), e.a.max(e.b));
            assert!((f.a.min(f.b) - lo).abs() < 1e-6 && (f.a.max(f.b) - hi).abs() < 1e-6);
        }
    }

    /// Points on two parallel lines (block centres in two rows, as a region two blocks tall
    /// gives): the best conic is the line pair, on the ellipses' border, and no ellipse
    /// bounds them. Round-off left its `4AC − B²` a hair above 0, and an "ellipse" 1e33 px
    /// across, centred 1e33 px away, came back as a fit.
    #[test]
    fn two_parallel_rows_are_degenerate() {
        let mut bad = Vec::new();
        for cols in 3..=12 {
            for (gap, x0, turn) in [
                (8.0, 3.5, 0.0),
                (8.0, 0.0, 0.0),
                (4.0, 11.5, 0.0),
                (16.0, -20.25, 0.0),
                (8.0, 3.5, 0.3),
                (6.0, 100.0, -1.1),
            ] {
                let (c, s) = (f64::cos(turn), f64::sin(turn));
                let pts: Vec<[f64; 2]> = (0..cols)
                    .flat_map(|i| [11.5, 11.5 + gap].map(|y| (x0 + 8.0 * i as f64, y)))
                    .map(|(x, y)| [40.0 + c * x - s * y, 30.0 + s * x + c * y])
                    .collect();
                if let Ok(e) = fit_ellipse(&pts) {
                    bad.push((cols, gap, x0, turn, e));
                }
            }
        }
        assert!(
            bad.is_empty(),
            "{} fits: {:?}",
            bad.len(),
            &bad[..bad.len().min(3)]
        );
    }

    #[test]
    fn axis_aligned_upright_ellipse_keeps_a_along_x() {
        let e = Ellipse::new(60.0, 40.0, 15.0, 22.0);
        let f = fit_ellipse(&points_on(&e, 30, 0.0, std::f64::consts::TAU)).unwrap();
        assert!(f.theta.abs() < 1e-9);
        assert!((f.a - 15.0).abs() < 1e-9 && (f.b - 22.0).abs() < 1e-9);
    }

    #[test]
    fn noisy_points_give_a_close_ellipse() {
        let mut rng = StdRng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.5).unwrap();
        let mut worst: f64 = 0.0;
        for _ in 0..50 {
            let mut e = random_ellipse(&mut rng);
            e.a = rng.random_range(20.0..60.0);
            e.b = rng.random_range(20.0..60.0);
            let pts: Vec<[f64; 2]> = points_on(&e, 200, 0.0, std::f64::consts::TAU)
                .into_iter()
                .map(|p| [p[0] + noise.sample(&mut rng), p[1] + noise.sample(&mut rng)])
                .collect();
            let f = fit_ellipse(&pts).unwrap();
            worst = worst.max(contour_distance(&e, &f));
            assert!((f.cx - e.cx).hypot(f.cy - e.cy) < 0.5, "{e:?} {f:?}");
        }
        // Pixel-level noise moves the contour by a fraction of a pixel.
        assert!(worst < 0.6, "worst contour distance {worst}");
    }

    #[test]
    fn partial_arc_is_enough() {
        let mut rng = StdRng::seed_from_u64(3);
        let noise = Normal::new(0.0, 0.05).unwrap();
        for _ in 0..20 {
            let mut e = random_ellipse(&mut rng);
            e.a = rng.random_range(20.0..60.0);
            e.b = rng.random_range(20.0..60.0);
            // A third of the contour, exact: recovered exactly.
            let pts = points_on(
                &e,
                30,
                rng.random_range(0.0..6.3),
                std::f64::consts::TAU / 3.0,
            );
            let f = fit_ellipse(&pts).unwrap();
            assert!(contour_distance(&e, &f) < 1e-5, "{e:?} {f:?}");
            // Half the contour with small noise: still close.
            let pts: Vec<[f64; 2]> =
                points_on(&e, 100, rng.random_range(0.0..6.3), std::f64::consts::PI)
                    .into_iter()
                    .map(|p| [p[0] + noise.sample(&mut rng), p[1] + noise.sample(&mut rng)])
                    .collect();
            let f = fit_ellipse(&pts).unwrap();
            assert!(contour_distance(&e, &f) < 1.0, "{e:?} {f:?}");
        }
    }

    #[test]
    fn bad_inputs_are_typed_errors() {
        let four = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]];
        assert!(matches!(
            fit_ellipse(&four),
            Err(MotionError::TooFewPoints { got: 4, .. })
        ));
        let same = [[5.0, 5.0]; 10];
        assert!(matches!(
            fit_ellipse(&same),
            Err(MotionError::Degenerate(_))
        ));
        let line: Vec<[f64; 2]> = (0..10).map(|i| [i as f64, 2.0 * i as f64 + 1.0]).collect();
        assert!(matches!(
            fit_ellipse(&line),
            Err(MotionError::Degenerate(_))
        ));
        let mut nan = points_on(&Ellipse::new(0.0, 0.0, 5.0, 3.0), 10, 0.0, 6.0);
        nan[3][1] = f64::NAN;
        assert!(matches!(fit_ellipse(&nan), Err(MotionError::NonFinite)));
        // Points on a hyperbola: no ellipse through them, but the fit still returns the
        // best ellipse or a typed error — never a panic or a non-finite ellipse.
        let hyp: Vec<[f64; 2]> = (1..20).map(|i| [i as f64, 10.0 / i as f64]).collect();
        if let Ok(e) = fit_ellipse(&hyp) {
            assert!(e.is_valid());
        }
    }

    #[test]
    fn fold_and_conic_conversion() {
        assert!((fold_half_turn(3.0) - (3.0 - std::f64::consts::PI)).abs() < 1e-12);
        assert!((fold_half_turn(-2.0) - (-2.0 + std::f64::consts::PI)).abs() < 1e-12);
        // x²/4 + y² − 1 = 0 → a = 2, b = 1 at the origin.
        let e = conic_to_ellipse(&[0.25, 0.0, 1.0, 0.0, 0.0, -1.0]).unwrap();
        assert!((e.a - 2.0).abs() < 1e-12 && (e.b - 1.0).abs() < 1e-12 && e.theta.abs() < 1e-12);
        // A hyperbola is rejected.
        assert!(conic_to_ellipse(&[1.0, 0.0, -1.0, 0.0, 0.0, -1.0]).is_none());
        // An imaginary ellipse x² + y² + 1 = 0 is rejected.
        assert!(conic_to_ellipse(&[1.0, 0.0, 1.0, 0.0, 0.0, 1.0]).is_none());
    }
}
