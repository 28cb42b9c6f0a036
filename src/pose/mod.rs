//! Rotation from 2D correspondences: Sylvester's equation (SEA), the optimal solver and the
//! baselines (SPEC section 2).
//!
//! Model: matched points `p_j` (frame t) and `q_j` (frame t+1) under weak perspective,
//! `q_j = R2 p_j + l`, `R2` the top-left 2x2 block of the inter-frame rotation `ΔR`.
//! Both sets are centred (`P' = P - mean(P)`, `Q' = Q - mean(Q)`), `A = P' P'^T`,
//! `B = Q' P'^T`, and every solver minimises (or approximates the minimum of)
//! `f(R2) = Σ_j |q'_j - R2 p'_j|^2 = tr(Q'Q'^T) - 2 tr(R2^T B) + tr(R2 A R2^T)`.
//!
//! * [`sea::Sea`]: the paper's Sylvester-equation algorithm (iterated Lagrange multiplier Λ).
//! * [`optimal::Optimal`]: the certified global minimiser of `f` over the blocks of rotations.
//! * [`lsm::Lsm`]: unconstrained least squares `R2 = B A^-1`.
//! * [`ransac::Rls`]: RANSAC on the matches, then least squares on the inliers.
//! * [`kabsch`](mod@kabsch): the 3D-3D case (SVD and SEA's equation in 3D).
//! * [`essential`]: the essential-matrix (8-point) baseline on calibrated perspective points.
//! * [`prior`]: the tracker's keyframe fit with an ellipsoid depth prior, and [`bundle`] the
//!   adjustment of a keyframe's depths with its views' poses.
//!
//! A block determines the rotation up to the Necker pair ([`complete`]); inter-frame rotations
//! are chained by [`accumulate::PoseAccumulator`]; [`noise`] reproduces the paper's Fig. 3.

pub mod accumulate;
pub mod bundle;
pub mod complete;
pub mod essential;
pub mod kabsch;
pub mod lsm;
pub mod noise;
pub mod optimal;
pub mod prior;
pub mod ransac;
pub mod sea;

pub use accumulate::PoseAccumulator;
pub use complete::{
    NeckerPair, complete_rotation, nearest_valid_block, resolve_by_continuity, resolve_by_parallax,
};
pub use essential::{Intrinsics, essential_rotation};
pub use kabsch::{kabsch, sea_3d};
pub use lsm::Lsm;
pub use optimal::Optimal;
pub use ransac::Rls;
pub use sea::Sea;

use nalgebra::{Matrix2, Vector2};

/// Errors of this module.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PoseError {
    /// Fewer matches than the solver needs.
    #[error("too few matches: {got} (need at least {need})")]
    TooFewMatches {
        /// Matches given.
        got: usize,
        /// Matches needed.
        need: usize,
    },
    /// The two point sets differ in length.
    #[error("point sets differ in length: {p} vs {q}")]
    LengthMismatch {
        /// Length of the first set.
        p: usize,
        /// Length of the second set.
        q: usize,
    },
    /// A coordinate is NaN or infinite, or so large (beyond about 1e150) that its moments
    /// overflow.
    #[error("non-finite coordinate in the input, or one too large to square")]
    NonFinite,
    /// The points are all identical or collinear: the rotation is not determined.
    #[error("degenerate point configuration ({0})")]
    Degenerate(&'static str),
    /// A linear system of a solver is singular.
    #[error("singular system in {0}")]
    Singular(&'static str),
    /// A matrix is not (close to) the block of a rotation and cannot be completed.
    #[error("not a valid rotation block: {0}")]
    InvalidBlock(&'static str),
    /// An unknown solver name.
    #[error("unknown solver `{0}` (expected sea, optimal, lsm or rls)")]
    UnknownSolver(String),
    /// No consistent solution (e.g. RANSAC found no model, chirality failed).
    #[error("no solution: {0}")]
    NoSolution(&'static str),
    /// A setting of a solver is out of range (e.g. a prior's σ not positive and finite).
    #[error("invalid parameter: {0}")]
    InvalidParameter(&'static str),
}

/// The estimate of one 2D solver: the rotation block, the translation and the fit quality.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockEstimate {
    /// Estimated top-left 2x2 block `R2` of the inter-frame rotation.
    pub r2: Matrix2<f64>,
    /// Translation `l = mean(Q) - R2 mean(P)` (pixels), so that `q ≈ R2 p + l`.
    pub translation: Vector2<f64>,
    /// RMS reprojection error `sqrt(mean_j |q_j - R2 p_j - l|^2)` over the inliers (pixels).
    pub residual: f64,
    /// Which matches were used (all `true` except for RANSAC).
    pub inliers: Vec<bool>,
}

/// A solver of the rotation block from 2D matches.
pub trait RotationSolver {
    /// Short name (`sea`, `optimal`, `lsm`, `rls`).
    fn name(&self) -> &'static str;
    /// Estimates `R2` and `l` from matches `p[j] -> q[j]`.
    fn solve(&self, p: &[[f64; 2]], q: &[[f64; 2]]) -> Result<BlockEstimate, PoseError>;
}

/// The solvers by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SolverKind {
    /// The paper's Sylvester-equation algorithm.
    Sea,
    /// The certified global minimiser.
    Optimal,
    /// Unconstrained least squares.
    Lsm,
    /// RANSAC then least squares.
    Rls,
}

impl SolverKind {
    /// All kinds, in the order of the Fig. 3 CSV.
    pub const ALL: [SolverKind; 4] = [
        SolverKind::Sea,
        SolverKind::Optimal,
        SolverKind::Lsm,
        SolverKind::Rls,
    ];

    /// Parses `sea`, `optimal`, `lsm`, `rls` (case-insensitive).
    pub fn from_name(name: &str) -> Result<Self, PoseError> {
        match name.to_ascii_lowercase().as_str() {
            "sea" => Ok(Self::Sea),
            "optimal" | "opt" => Ok(Self::Optimal),
            "lsm" => Ok(Self::Lsm),
            "rls" | "ransac" => Ok(Self::Rls),
            _ => Err(PoseError::UnknownSolver(name.to_string())),
        }
    }

    /// The short name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Sea => "sea",
            Self::Optimal => "optimal",
            Self::Lsm => "lsm",
            Self::Rls => "rls",
        }
    }
}

/// The solver of a kind with its default settings.
pub fn solver(kind: SolverKind) -> Box<dyn RotationSolver + Send + Sync> {
    match kind {
        SolverKind::Sea => Box::new(Sea::default()),
        SolverKind::Optimal => Box::new(Optimal::default()),
        SolverKind::Lsm => Box::new(Lsm),
        SolverKind::Rls => Box::new(Rls::default()),
    }
}

/// Centred moments of a set of matches: the means and `A = P'P'^T`, `B = Q'P'^T`,
/// `K = tr(Q'Q'^T)`. Shared by the solvers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moments {
    /// Mean of `p`.
    pub mean_p: Vector2<f64>,
    /// Mean of `q`.
    pub mean_q: Vector2<f64>,
    /// `A = Σ p'_j p'_j^T`.
    pub a: Matrix2<f64>,
    /// `B = Σ q'_j p'_j^T`.
    pub b: Matrix2<f64>,
    /// `K = Σ |q'_j|^2`.
    pub k: f64,
    /// Number of matches.
    pub n: usize,
}

impl Moments {
    /// The objective `f(R2) = Σ |q'_j - R2 p'_j|^2` from the moments. Its three terms are each
    /// of the order of `K`, so near an exact fit it is rounding noise of that order (it can
    /// come out below 0); [`Self::excess_over_lsm`] compares blocks there.
    pub fn objective(&self, r2: &Matrix2<f64>) -> f64 {
        self.k - 2.0 * (r2.transpose() * self.b).trace() + (r2 * self.a * r2.transpose()).trace()
    }

    /// `f(R2) − f(M)`, with `M = B A⁻¹` the unconstrained minimiser: `tr((R2 − M) A (R2 −
    /// M)ᵀ)`, never below 0 and free of [`Self::objective`]'s cancellation, so that two blocks
    /// near an exact fit compare by how far they are from it. ([`Self::objective`] where `A`
    /// has no inverse, which [`moments`] does not return.)
    pub fn excess_over_lsm(&self, r2: &Matrix2<f64>) -> f64 {
        match lsm::lsm_block(self) {
            Ok(m) => {
                let d = r2 - m;
                (d * self.a * d.transpose()).trace().max(0.0)
            }
            Err(_) => self.objective(r2),
        }
    }

    /// `f(M) = K − tr(B A⁻¹ Bᵀ)`, the unconstrained least-squares residual: the least any
    /// block can reach, clamped at 0 (it cancels as [`Self::objective`] does).
    pub fn lsm_floor(&self) -> f64 {
        lsm::lsm_block(self).map_or(0.0, |m| {
            (self.k - (m * self.b.transpose()).trace()).max(0.0)
        })
    }
}

/// The points' spread across their best-fitting line: the root mean square distance from it
/// (the square root of the smaller eigenvalue of their covariance), in the points' units;
/// `None` for no points or a non-finite one. Points nearly on a line leave the rotation
/// undetermined in practice well before [`moments`]' scale-free test calls them collinear:
/// where this is not several times the points' own error (some 0.3 px for SIFT's), the turn
/// about the line is noise.
pub fn spread_across(points: &[[f64; 2]]) -> Option<f64> {
    if points.is_empty() || points.iter().flatten().any(|v| !v.is_finite()) {
        return None;
    }
    let n = points.len() as f64;
    let mean = points
        .iter()
        .fold(Vector2::zeros(), |m, p| m + Vector2::new(p[0], p[1]))
        / n;
    let c = points.iter().fold(Matrix2::zeros(), |c, p| {
        let d = Vector2::new(p[0], p[1]) - mean;
        c + d * d.transpose()
    }) / n;
    // The smaller eigenvalue of a symmetric 2x2: (tr - sqrt(tr^2 - 4 det)) / 2.
    let (tr, det) = (c.trace(), c.determinant());
    let small = 0.5 * (tr - (tr * tr - 4.0 * det).max(0.0).sqrt());
    let v = small.max(0.0).sqrt();
    v.is_finite().then_some(v)
}

/// Checks the input (lengths, at least `need` matches, finite, not degenerate) and returns the
/// centred moments.
///
/// Degenerate: the frame-t points are all identical or collinear (`A` singular relative to its
/// scale), or the frame-t+1 points are all identical (no rotation can map a spread set to a
/// point).
pub fn moments(p: &[[f64; 2]], q: &[[f64; 2]], need: usize) -> Result<Moments, PoseError> {
    if p.len() != q.len() {
        return Err(PoseError::LengthMismatch {
            p: p.len(),
            q: q.len(),
        });
    }
    if p.len() < need {
        return Err(PoseError::TooFewMatches { got: p.len(), need });
    }
    if p.iter()
        .chain(q)
        .any(|x| !x[0].is_finite() || !x[1].is_finite())
    {
        return Err(PoseError::NonFinite);
    }
    let n = p.len() as f64;
    let mut mp = Vector2::zeros();
    let mut mq = Vector2::zeros();
    for (a, b) in p.iter().zip(q) {
        mp += Vector2::new(a[0], a[1]);
        mq += Vector2::new(b[0], b[1]);
    }
    mp /= n;
    mq /= n;
    let mut a = Matrix2::zeros();
    let mut b = Matrix2::zeros();
    let mut k = 0.0;
    for (x, y) in p.iter().zip(q) {
        let pp = Vector2::new(x[0], x[1]) - mp;
        let qq = Vector2::new(y[0], y[1]) - mq;
        a += pp * pp.transpose();
        b += qq * pp.transpose();
        k += qq.norm_squared();
    }
    // Finite coordinates as large as 1e154 overflow the moments (or the tests below), as in
    // the 3D case: a NaN block would otherwise come back as an estimate.
    let scale = mp.norm().max(mq.norm()).max(1.0);
    let ta = a.trace();
    if a.iter().chain(b.iter()).any(|x| !x.is_finite())
        || !(k * ta * ta).is_finite()
        || !(scale * scale).is_finite()
    {
        return Err(PoseError::NonFinite);
    }
    if ta <= n * (1e-12 * scale).powi(2) {
        return Err(PoseError::Degenerate("frame-t points coincide"));
    }
    if a.determinant() <= 1e-10 * ta * ta {
        return Err(PoseError::Degenerate("frame-t points are collinear"));
    }
    if k <= 1e-10 * ta {
        return Err(PoseError::Degenerate("frame-t+1 points coincide"));
    }
    Ok(Moments {
        mean_p: mp,
        mean_q: mq,
        a,
        b,
        k,
        n: p.len(),
    })
}

/// Builds a [`BlockEstimate`] for a block fitted on all matches: `l = mean(Q) - R2 mean(P)` and
/// the RMS residual.
pub fn estimate_from_block(
    r2: Matrix2<f64>,
    m: &Moments,
    p: &[[f64; 2]],
    q: &[[f64; 2]],
) -> BlockEstimate {
    let translation = m.mean_q - r2 * m.mean_p;
    BlockEstimate {
        r2,
        translation,
        residual: rms_residual(&r2, &translation, p, q, None),
        inliers: vec![true; p.len()],
    }
}

/// RMS of `|q_j - R2 p_j - l|` over all matches (or over those with `mask[j]`; a mask
/// shorter than the matches leaves the rest out). 0 with no match counted.
pub fn rms_residual(
    r2: &Matrix2<f64>,
    l: &Vector2<f64>,
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    mask: Option<&[bool]>,
) -> f64 {
    let mut s = 0.0;
    let mut c = 0usize;
    for (j, (x, y)) in p.iter().zip(q).enumerate() {
        // A mask shorter than the points leaves the rest out.
        if mask.is_some_and(|m| !m.get(j).copied().unwrap_or(false)) {
            continue;
        }
        let e = Vector2::new(y[0], y[1]) - r2 * Vector2::new(x[0], x[1]) - l;
        s += e.norm_squared();
        c += 1;
    }
    if c == 0 { 0.0 } else { (s / c as f64).sqrt() }
}

/// One inter-frame estimate, ready for the tracker.
#[derive(Debug, Clone, PartialEq)]
pub struct InterFrame {
    /// The solver's block estimate.
    pub block: BlockEstimate,
    /// The two rotations consistent with the block (Necker pair).
    pub pair: NeckerPair,
    /// Image motion of the point `centre_prev` under the fitted map `x -> R2 x + l`:
    /// `R2 centre_prev + l - centre_prev` (pixels). Subtract the motion of the object's
    /// centre (e.g. the silhouette/ellipse centre) to get the parallax offset of
    /// [`resolve_by_parallax`].
    pub translation: Vector2<f64>,
}

/// Estimates the inter-frame rotation from matches `p -> q` with the solver `kind`, completes
/// it to the Necker pair and reports the feature translation relative to `centre_prev`.
///
/// Errors: fewer than 3 matches ([`PoseError::TooFewMatches`]), NaN/inf
/// ([`PoseError::NonFinite`]), coincident or collinear points ([`PoseError::Degenerate`]).
pub fn interframe(
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    centre_prev: [f64; 2],
    kind: SolverKind,
) -> Result<InterFrame, PoseError> {
    if !centre_prev[0].is_finite() || !centre_prev[1].is_finite() {
        return Err(PoseError::NonFinite);
    }
    moments(p, q, 3)?;
    let block = solver(kind).solve(p, q)?;
    let pair = complete_rotation(&block.r2)?;
    let c = Vector2::new(centre_prev[0], centre_prev[1]);
    let translation = block.r2 * c + block.translation - c;
    Ok(InterFrame {
        block,
        pair,
        translation,
    })
}

/// A consensus test on the matches before an inter-frame rotation is estimated from them: the
/// rotation is computed from the largest set one affine map carries to within `threshold`
/// pixels ([`ransac::affine_consensus`]), and only when that set holds at least
/// `min_inliers` matches.
///
/// Why: the paper's slope/length rejection keeps a match whose displacement is near the
/// mean's, but a wrong match a pixel or two off survives it, and with three or four matches
/// there is no residual to expose it: three matches fix an affine map exactly, and the
/// Sylvester block's out-of-plane angles then follow the noise (on OTB car4, seed 6, the
/// rotation between two frames came out at 15-20 degrees from 3-5 matches and at 85 degrees
/// from 3). Five matches leave four residual degrees of freedom to check the map against.
///
/// Measured with `pftrack track --backend cpu` and `pftrack eval` (success AUC, filter seeds
/// 0-15): girl 0.40 without the test and 0.41 with it, car4 0.53 and 0.57. On the synthetic
/// scenarios (scene seeds 0-11) the angle RMSE summed over scenarios and axes went from 70.9
/// to 64.9 degrees with filter seed 0, and from 68.3 to 63.9 with the filter seed equal to
/// the scene's; nearly all of it on `combo` (its worst seed from 60.7 to 23.9, and from 48.9
/// to 20.7), the rest within 0.1 degree.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Consensus {
    /// Inlier threshold on the affine transfer error (pixels); 1 by default, about two to
    /// three times SIFT's localisation error at the tracker's scales.
    pub threshold: f64,
    /// Fewest inliers for an estimate, at least 3; 5 by default.
    pub min_inliers: usize,
}

impl Default for Consensus {
    fn default() -> Self {
        Self {
            threshold: 1.0,
            min_inliers: 5,
        }
    }
}

impl Consensus {
    /// Checks the settings: a finite positive threshold and at least 3 inliers.
    pub fn check(&self) -> Result<(), String> {
        if !(self.threshold.is_finite() && self.threshold > 0.0) {
            return Err(format!(
                "consensus threshold {} is not a positive number of pixels",
                self.threshold
            ));
        }
        if self.min_inliers < 3 {
            return Err(format!(
                "consensus min_inliers {} is below 3, the matches an affine map needs",
                self.min_inliers
            ));
        }
        Ok(())
    }

    /// The consensus set of `p -> q` (`true` for an inlier), when it holds at least
    /// [`Self::min_inliers`] matches. Deterministic.
    ///
    /// Errors: fewer matches or inliers than [`Self::min_inliers`]
    /// ([`PoseError::TooFewMatches`], `got` the inliers found), and those of
    /// [`ransac::affine_consensus`].
    pub fn inliers(&self, p: &[[f64; 2]], q: &[[f64; 2]]) -> Result<Vec<bool>, PoseError> {
        let need = self.min_inliers.max(3);
        if p.len() < need {
            return Err(PoseError::TooFewMatches { got: p.len(), need });
        }
        // The sampler's settings are RLS's: one owner for RANSAC's confidence, cap and seed.
        let r = Rls::default();
        let mask =
            ransac::affine_consensus(p, q, self.threshold, r.confidence, r.max_iter, r.seed)?;
        let got = mask.iter().filter(|m| **m).count();
        if got < need {
            return Err(PoseError::TooFewMatches { got, need });
        }
        Ok(mask)
    }
}

/// [`interframe`] on the matches that pass `consensus` ([`Consensus::inliers`]); with `None`,
/// on all of them, as the paper does. The returned block's `inliers` refer to the consensus
/// set.
pub fn interframe_consensus(
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    centre_prev: [f64; 2],
    kind: SolverKind,
    consensus: Option<&Consensus>,
) -> Result<InterFrame, PoseError> {
    let Some(c) = consensus else {
        return interframe(p, q, centre_prev, kind);
    };
    let (pi, qi) = ransac::select(p, q, &c.inliers(p, q)?);
    interframe(&pi, &qi, centre_prev, kind)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_spread_across_a_line_is_the_rms_distance_from_it() {
        // Pairs of points 0.1 either side of the line y = x / 2.
        let dir = Vector2::new(2.0, 1.0).normalize();
        let across = Vector2::new(-dir.y, dir.x);
        let pts: Vec<[f64; 2]> = (0..20)
            .map(|i| {
                let off = if i % 2 == 0 { 0.1 } else { -0.1 };
                let v = dir * (3.0 * (i / 2) as f64) + across * off + Vector2::new(40.0, 7.0);
                [v.x, v.y]
            })
            .collect();
        let got = spread_across(&pts).unwrap();
        assert!((got - 0.1).abs() < 1e-9, "{got}");
        // A square's corners: the spread is the same every way, half the side.
        let square = [[0.0, 0.0], [4.0, 0.0], [0.0, 4.0], [4.0, 4.0]];
        assert!((spread_across(&square).unwrap() - 2.0).abs() < 1e-12);
        assert_eq!(spread_across(&[[1.0, 2.0]]), Some(0.0));
        assert_eq!(spread_across(&[]), None);
        assert_eq!(spread_across(&[[f64::NAN, 0.0], [1.0, 1.0]]), None);
    }

    use super::*;

    /// Matches of a known weak-perspective motion (a 4-degree turn about the vertical axis
    /// and a shift) on a grid, the first `n` of them.
    fn turned_grid(n: usize) -> (Vec<[f64; 2]>, Vec<[f64; 2]>, nalgebra::Matrix3<f64>) {
        let r = nalgebra::Rotation3::from_euler_angles(0.0, 4f64.to_radians(), 0.0).into_inner();
        let mut p = Vec::new();
        let mut q = Vec::new();
        for i in 0..n {
            let x = [
                60.0 + (i % 4) as f64 * 7.0 + (i / 4) as f64 * 1.3,
                40.0 + (i / 4) as f64 * 6.0 - (i % 4) as f64 * 0.9,
            ];
            let d = Vector2::new(x[0] - 70.0, x[1] - 50.0);
            let m = r.fixed_view::<2, 2>(0, 0) * d;
            p.push(x);
            q.push([m[0] + 70.0 + 2.0, m[1] + 50.0 - 1.0]);
        }
        (p, q, r)
    }

    fn angle_deg(a: &nalgebra::Matrix3<f64>, b: &nalgebra::Matrix3<f64>) -> f64 {
        crate::geometry::rotation::angle_between(a, b).to_degrees()
    }

    #[test]
    fn a_short_mask_leaves_the_rest_out() {
        let (p, q, _) = turned_grid(8);
        let r2 = Matrix2::identity();
        let l = Vector2::zeros();
        let first = rms_residual(&r2, &l, &p[..1], &q[..1], None);
        assert_eq!(rms_residual(&r2, &l, &p, &q, Some(&[true])), first);
        assert_eq!(rms_residual(&r2, &l, &p, &q, Some(&[])), 0.0);
    }

    #[test]
    fn the_consensus_drops_a_wrong_match_the_plain_estimate_follows() {
        let (p, mut q, r) = turned_grid(8);
        // One match two pixels off: within the slope/length test's reach, not the map's.
        q[5][0] += 2.0;
        q[5][1] -= 1.0;
        let c = Consensus::default();
        let plain = interframe(&p, &q, [70.0, 50.0], SolverKind::Sea).unwrap();
        let robust = interframe_consensus(&p, &q, [70.0, 50.0], SolverKind::Sea, Some(&c)).unwrap();
        let err = |i: &InterFrame| angle_deg(&i.pair.a, &r).min(angle_deg(&i.pair.b, &r));
        assert!(err(&robust) < 1e-6, "robust error {}", err(&robust));
        assert!(err(&plain) > 1.0, "plain error {}", err(&plain));
        assert_eq!(robust.block.inliers.len(), 7);
        // Without a consensus test, the same as the plain estimate.
        assert_eq!(
            interframe_consensus(&p, &q, [70.0, 50.0], SolverKind::Sea, None).unwrap(),
            plain
        );
    }

    #[test]
    fn the_consensus_needs_its_inliers() {
        let c = Consensus::default();
        let (p, q, _) = turned_grid(4);
        assert_eq!(
            c.inliers(&p, &q),
            Err(PoseError::TooFewMatches { got: 4, need: 5 })
        );
        // Five matches, two of them wrong: three inliers are too few.
        let (p, mut q, _) = turned_grid(5);
        q[1][0] += 6.0;
        q[3][1] -= 5.0;
        assert_eq!(
            c.inliers(&p, &q),
            Err(PoseError::TooFewMatches { got: 3, need: 5 })
        );
        assert!(interframe_consensus(&p, &q, [70.0, 50.0], SolverKind::Sea, Some(&c)).is_err());
        // Bad settings are named.
        assert!(
            Consensus {
                threshold: 0.0,
                ..c
            }
            .check()
            .is_err()
        );
        assert!(
            Consensus {
                threshold: f64::NAN,
                ..c
            }
            .check()
            .is_err()
        );
        assert!(
            Consensus {
                min_inliers: 2,
                ..c
            }
            .check()
            .is_err()
        );
        assert!(c.check().is_ok());
    }

    #[test]
    fn moments_reject_bad_input() {
        let p = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
        assert!(matches!(
            moments(&p[..2], &p[..2], 3),
            Err(PoseError::TooFewMatches { got: 2, need: 3 })
        ));
        assert!(matches!(
            moments(&p, &p[..2], 3),
            Err(PoseError::LengthMismatch { .. })
        ));
        let nan = [[0.0, 0.0], [f64::NAN, 0.0], [0.0, 1.0]];
        assert_eq!(moments(&nan, &p, 3), Err(PoseError::NonFinite));
        // Finite but too large to square: an error, not a NaN block from a solver.
        let huge = [[0.0, 0.0], [1e200, 0.0], [0.0, 1e200], [1e200, 3e200]];
        let small = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 3.0]];
        for (p, q) in [(&huge, &small), (&small, &huge), (&huge, &huge)] {
            assert_eq!(moments(p, q, 3), Err(PoseError::NonFinite));
            for kind in SolverKind::ALL {
                let got = solver(kind).solve(p, q);
                assert!(
                    got.as_ref().is_err()
                        || got
                            .as_ref()
                            .is_ok_and(|e| e.r2.iter().all(|v| v.is_finite())),
                    "{kind:?}: {got:?}"
                );
            }
        }
        let same = [[2.0, 3.0]; 4];
        assert!(matches!(
            moments(&same, &same, 3),
            Err(PoseError::Degenerate(_))
        ));
        let line = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 5.0]];
        assert!(matches!(
            moments(&line, &line, 3),
            Err(PoseError::Degenerate(_))
        ));
        let m = moments(&p, &p, 3).unwrap();
        assert!(m.objective(&Matrix2::identity()).abs() < 1e-12);
    }

    #[test]
    fn solver_names_round_trip() {
        for k in SolverKind::ALL {
            assert_eq!(SolverKind::from_name(k.name()).unwrap(), k);
            assert_eq!(solver(k).name(), k.name());
        }
        assert!(SolverKind::from_name("nope").is_err());
    }
}
