//! Descriptor matching (nearest neighbour, Lowe's ratio test, mutual check) and the paper's
//! slope/length outlier rejection of matched displacements (SPEC section 2).

use super::{DESCRIPTOR_LEN, FeatureError, Features};

/// Parameters of [`match_features`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchParams {
    /// Lowe's ratio: a match is kept when `d1 < ratio · d2` (nearest and second nearest
    /// distances). 0.8 by default; 1 or more disables the test.
    pub ratio: f32,
    /// Keep a match only when the query is also the train descriptor's nearest neighbour
    /// (cross check). On by default.
    pub mutual: bool,
}

impl MatchParams {
    /// Checks the settings: a finite, positive `ratio` (a NaN or one of 0 would silently
    /// reject every match).
    pub fn check(&self) -> Result<(), FeatureError> {
        if self.ratio.is_finite() && self.ratio > 0.0 {
            Ok(())
        } else {
            Err(FeatureError::BadMatching(format!(
                "ratio {} must be finite and positive (1 or more disables the ratio test)",
                self.ratio
            )))
        }
    }
}

impl Default for MatchParams {
    fn default() -> Self {
        Self {
            ratio: 0.8,
            mutual: true,
        }
    }
}

/// A correspondence between `a.keypoints[query]` and `b.keypoints[train]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    /// Index into the first feature set.
    pub query: usize,
    /// Index into the second feature set.
    pub train: usize,
    /// Euclidean distance between the `u8` descriptors.
    pub distance: f32,
}

/// Squared Euclidean distance of two `u8` descriptors, exact (at most 128 · 255² < 2²³).
#[inline]
fn dist2(a: &[u8; DESCRIPTOR_LEN], b: &[u8; DESCRIPTOR_LEN]) -> u32 {
    let mut acc = [0u32; 16];
    for (ca, cb) in a.chunks_exact(16).zip(b.chunks_exact(16)) {
        for k in 0..16 {
            let d = ca[k].abs_diff(cb[k]) as u32;
            acc[k] += d * d;
        }
    }
    acc.iter().sum()
}

/// Nearest-neighbour matching of `a` (queries) against `b` (train) by brute force over
/// exact descriptor distances, with Lowe's ratio test and, if asked, a mutual check.
///
/// With a single train descriptor the ratio test has no second neighbour and passes. Ties
/// go to the lower index. Matches come sorted by `query`.
pub fn match_features(a: &Features, b: &Features, p: &MatchParams) -> Vec<Match> {
    if a.descriptors.is_empty() || b.descriptors.is_empty() {
        return Vec::new();
    }
    let ratio2 = p.ratio * p.ratio;
    let (row_best, col_best) = nearest(&a.descriptors, &b.descriptors);
    let mut out = Vec::new();
    for (i, &(d1, j1, d2)) in row_best.iter().enumerate() {
        if j1 == usize::MAX {
            continue;
        }
        let ratio_ok = p.ratio >= 1.0 || !d2.is_finite() || d1 < ratio2 * d2;
        let mutual_ok = !p.mutual || col_best[j1].1 == i;
        if ratio_ok && mutual_ok {
            out.push(Match {
                query: i,
                train: j1,
                distance: d1.sqrt(),
            });
        }
    }
    out
}

/// Per query `(d1, j1, d2)`: the nearest and second nearest squared distances and the nearest
/// train index; per train descriptor `(d, i)`: the nearest query. Squared distances are
/// whole numbers below 2²³, exact as `f32`.
type Nearest = (Vec<(f32, usize, f32)>, Vec<(f32, usize)>);

/// Each query's nearest and second nearest train distances `(d1, j1, d2)`, and each train
/// descriptor's nearest query `(d, i)`.
fn nearest(da: &[[u8; DESCRIPTOR_LEN]], db: &[[u8; DESCRIPTOR_LEN]]) -> Nearest {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        return nearest_with(da, db, |qa, out| {
            // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
            // calling a function compiled with that target feature.
            unsafe { avx2::distances(qa, db, out) }
        });
    }
    nearest_with(da, db, |qa, out| {
        for (d, tb) in out.iter_mut().zip(db) {
            *d = dist2(qa, tb);
        }
    })
}

/// [`nearest`] with `distances(query, out)` writing one query's squared distances to every
/// train descriptor into `out`.
fn nearest_with(
    da: &[[u8; DESCRIPTOR_LEN]],
    db: &[[u8; DESCRIPTOR_LEN]],
    mut distances: impl FnMut(&[u8; DESCRIPTOR_LEN], &mut [u32]),
) -> Nearest {
    let mut dists = vec![0u32; db.len()];
    let mut col_best = vec![(f32::INFINITY, usize::MAX); db.len()];
    let mut row_best = Vec::with_capacity(da.len());
    for (i, qa) in da.iter().enumerate() {
        distances(qa, &mut dists);
        let (mut d1, mut j1, mut d2) = (f32::INFINITY, usize::MAX, f32::INFINITY);
        for (j, (&d, cb)) in dists.iter().zip(col_best.iter_mut()).enumerate() {
            let d = d as f32;
            if d < d1 {
                d2 = d1;
                d1 = d;
                j1 = j;
            } else if d < d2 {
                d2 = d;
            }
            if d < cb.0 {
                *cb = (d, i);
            }
        }
        row_best.push((d1, j1, d2));
    }
    (row_best, col_best)
}

/// The AVX2 distance kernel: descriptors widened to 16-bit lanes, differences squared and
/// summed in pairs by `vpmaddwd` into 32-bit lanes. Integer arithmetic throughout, so the
/// distances are those of [`dist2`] exactly.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::DESCRIPTOR_LEN;
    use std::arch::x86_64::*;

    /// Squared distances of `q` to every descriptor of `train`, into `out` (same length).
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn distances(
        q: &[u8; DESCRIPTOR_LEN],
        train: &[[u8; DESCRIPTOR_LEN]],
        out: &mut [u32],
    ) {
        // The query, widened once: 8 registers of 16 lanes.
        let mut qw = [_mm256_setzero_si256(); 8];
        for (c, r) in qw.iter_mut().enumerate() {
            // SAFETY: bytes 16c..16c + 16 lie inside the 128-byte descriptor.
            *r = _mm256_cvtepu8_epi16(unsafe { _mm_loadu_si128(q.as_ptr().add(16 * c).cast()) });
        }
        let mut pairs = train.chunks_exact(2);
        let mut outs = out.chunks_exact_mut(2);
        for (t, o) in pairs.by_ref().zip(outs.by_ref()) {
            let (mut a0, mut a1) = (_mm256_setzero_si256(), _mm256_setzero_si256());
            for (c, &qc) in qw.iter().enumerate() {
                // SAFETY: as above, for each of the two train descriptors.
                let (t0, t1) = unsafe {
                    (
                        _mm_loadu_si128(t[0].as_ptr().add(16 * c).cast()),
                        _mm_loadu_si128(t[1].as_ptr().add(16 * c).cast()),
                    )
                };
                let d0 = _mm256_sub_epi16(qc, _mm256_cvtepu8_epi16(t0));
                let d1 = _mm256_sub_epi16(qc, _mm256_cvtepu8_epi16(t1));
                a0 = _mm256_add_epi32(a0, _mm256_madd_epi16(d0, d0));
                a1 = _mm256_add_epi32(a1, _mm256_madd_epi16(d1, d1));
            }
            o[0] = hsum(a0);
            o[1] = hsum(a1);
        }
        for (t, o) in pairs.remainder().iter().zip(outs.into_remainder()) {
            *o = super::dist2(q, t);
        }
    }

    /// Sum of the eight 32-bit lanes.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn hsum(v: __m256i) -> u32 {
        let s = _mm_add_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
        let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b01_00_11_10>(s));
        let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b10_11_00_01>(s));
        _mm_cvtsi128_si32(s) as u32
    }
}

/// The paper's angle tolerance of [`reject_slope_length`]: a match's displacement within
/// 0.2 rad of the mean direction (SPEC section 2).
pub const PAPER_ANGLE_TOL: f64 = 0.2;
/// The paper's length tolerance of [`reject_slope_length`]: a match's displacement within
/// 30 % of the mean length (SPEC section 2).
pub const PAPER_LENGTH_TOL: f64 = 0.3;

/// Median length below which displacements count as "no motion" (see
/// [`reject_slope_length`]).
pub const STILL_LENGTH_PX: f64 = 0.5;
/// Radius around the median displacement kept in the no-motion case.
pub const STILL_RADIUS_PX: f64 = 1.0;

/// The paper's outlier rejection of matches `p[j] → q[j]` (SPEC section 2): a match is
/// dropped when the angle of its displacement `q - p` is outside `mean ± angle_tol`
/// (circular mean, radians) or its length is outside `mean × (1 ± length_tol)`.
/// Returns the keep mask, one entry per match.
///
/// Means are taken over the inliers, not over everything, so that the outliers the test is
/// meant to remove do not drag the means away from the bulk: a first pass tests against the
/// median length and the circular mean direction of all matches, and the final pass tests
/// every match against the circular mean angle and mean length of the first pass's inliers
/// (falling back to the first pass's centres if it kept nothing).
///
/// When the median displacement is shorter than [`STILL_LENGTH_PX`] (0.5 px) the angles
/// are noise, and relative length bands around a near-zero mean keep nothing useful; then a
/// match is kept when its displacement lies within [`STILL_RADIUS_PX`] (1 px) of the
/// component-wise median displacement.
///
/// Non-finite points are dropped. `p` and `q` should have the same length; the mask has
/// `p.len()` entries and those without a partner in `q` are `false`.
pub fn reject_slope_length(
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    angle_tol: f64,
    length_tol: f64,
) -> Vec<bool> {
    let n = p.len();
    let mut keep = vec![false; n];
    let disp: Vec<Option<[f64; 2]>> = (0..n)
        .map(|j| {
            let (a, b) = (p[j], *q.get(j)?);
            let d = [b[0] - a[0], b[1] - a[1]];
            (d[0].is_finite() && d[1].is_finite()).then_some(d)
        })
        .collect();
    let valid: Vec<[f64; 2]> = disp.iter().flatten().copied().collect();
    if valid.is_empty() {
        return keep;
    }
    let len = |d: &[f64; 2]| d[0].hypot(d[1]);
    let median_len = median(valid.iter().map(len).collect());
    if median_len < STILL_LENGTH_PX {
        let mx = median(valid.iter().map(|d| d[0]).collect());
        let my = median(valid.iter().map(|d| d[1]).collect());
        for (k, d) in keep.iter_mut().zip(&disp) {
            *k = d.is_some_and(|d| (d[0] - mx).hypot(d[1] - my) <= STILL_RADIUS_PX);
        }
        return keep;
    }
    let test = |d: &[f64; 2], mean_angle: f64, mean_len: f64| {
        let l = len(d);
        let da = angle_diff(d[1].atan2(d[0]), mean_angle);
        da.abs() <= angle_tol
            && l >= mean_len * (1.0 - length_tol)
            && l <= mean_len * (1.0 + length_tol)
    };
    let first_angle = circular_mean(&valid);
    let inliers: Vec<[f64; 2]> = valid
        .iter()
        .filter(|d| test(d, first_angle, median_len))
        .copied()
        .collect();
    let (mean_angle, mean_len) = if inliers.is_empty() {
        (first_angle, median_len)
    } else {
        (
            circular_mean(&inliers),
            inliers.iter().map(len).sum::<f64>() / inliers.len() as f64,
        )
    };
    for (k, d) in keep.iter_mut().zip(&disp) {
        *k = d.is_some_and(|d| test(&d, mean_angle, mean_len));
    }
    keep
}

/// The matches `p[j] → q[j]` that [`reject_slope_length`] keeps, as two lists in match order
/// (the tracker's and `pftrack pose`'s tolerances: [`PAPER_ANGLE_TOL`], [`PAPER_LENGTH_TOL`]).
pub fn keep_slope_length(
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    angle_tol: f64,
    length_tol: f64,
) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let keep = reject_slope_length(p, q, angle_tol, length_tol);
    p.iter()
        .zip(q)
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|((p, q), _)| (*p, *q))
        .unzip()
}

/// Median of a non-empty list (mean of the middle pair for even lengths).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

/// Circular mean of the displacement directions (each direction counts once, whatever its
/// length).
fn circular_mean(d: &[[f64; 2]]) -> f64 {
    let (mut s, mut c) = (0.0, 0.0);
    for v in d {
        let l = v[0].hypot(v[1]);
        if l > 0.0 {
            s += v[1] / l;
            c += v[0] / l;
        }
    }
    s.atan2(c)
}

/// `a - b` wrapped to `(-π, π]`.
fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    if d > std::f64::consts::PI {
        d - std::f64::consts::TAU
    } else {
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::Keypoint;

    fn feats(descs: &[[u8; DESCRIPTOR_LEN]]) -> Features {
        Features {
            keypoints: vec![Keypoint::default(); descs.len()],
            descriptors: descs.to_vec(),
        }
    }

    fn desc(fill: &[(usize, u8)]) -> [u8; DESCRIPTOR_LEN] {
        let mut d = [0u8; DESCRIPTOR_LEN];
        for &(i, v) in fill {
            d[i] = v;
        }
        d
    }

    #[test]
    fn the_ratio_must_be_a_positive_number() {
        assert!(MatchParams::default().check().is_ok());
        let off = MatchParams {
            ratio: 1.5,
            ..MatchParams::default()
        };
        assert!(off.check().is_ok());
        for ratio in [0.0, -0.5, f32::NAN, f32::INFINITY] {
            let p = MatchParams {
                ratio,
                ..MatchParams::default()
            };
            assert!(
                matches!(p.check(), Err(FeatureError::BadMatching(_))),
                "{ratio}"
            );
        }
    }

    #[test]
    fn dist2_is_exact() {
        let a: [u8; 128] = std::array::from_fn(|i| if i % 2 == 0 { 255 } else { 0 });
        let b: [u8; 128] = std::array::from_fn(|i| if i % 2 == 0 { 0 } else { 255 });
        assert_eq!(dist2(&a, &b), 128 * 255 * 255);
    }

    #[test]
    fn the_avx2_distances_are_the_exact_ones() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            use rand::{Rng, SeedableRng, rngs::StdRng};
            let mut rng = StdRng::seed_from_u64(7);
            // Extremes (0 against 255 in every lane) and random descriptors; an odd train
            // count exercises the unpaired last descriptor.
            let mut descs: Vec<[u8; DESCRIPTOR_LEN]> =
                vec![[0; DESCRIPTOR_LEN], [255; DESCRIPTOR_LEN]];
            descs.extend((0..9).map(|_| std::array::from_fn(|_| rng.random())));
            for q in &descs {
                let mut out = vec![0u32; descs.len()];
                // SAFETY: AVX2 is available (checked above).
                unsafe { avx2::distances(q, &descs, &mut out) };
                let want: Vec<u32> = descs.iter().map(|t| dist2(q, t)).collect();
                assert_eq!(out, want);
            }
            assert_eq!(dist2(&descs[0], &descs[1]), 128 * 255 * 255);
        }
    }

    #[test]
    fn ratio_test_rejects_ambiguous_and_keeps_distinct() {
        // Query 0 is close to train 0 and far from train 1: kept.
        // Query 1 is equally close to train 2 and train 3: rejected by the ratio test.
        let a = feats(&[desc(&[(0, 100)]), desc(&[(10, 100)])]);
        let b = feats(&[
            desc(&[(0, 98)]),
            desc(&[(50, 100)]),
            desc(&[(10, 100), (11, 20)]),
            desc(&[(10, 100), (12, 21)]),
        ]);
        let m = match_features(&a, &b, &MatchParams::default());
        assert_eq!(m.len(), 1);
        assert_eq!((m[0].query, m[0].train), (0, 0));
        assert_eq!(m[0].distance, 2.0);
        // Without the ratio test query 1 goes to its nearest, train 2.
        let m = match_features(
            &a,
            &b,
            &MatchParams {
                ratio: 1.0,
                mutual: true,
            },
        );
        assert_eq!(m.len(), 2);
        assert_eq!((m[1].query, m[1].train), (1, 2));
    }

    #[test]
    fn ratio_test_compares_distances_not_squared_distances() {
        // Lowe's ratio is on distances: nearest over second nearest 85 / 100 fails 0.8 (its
        // square, 0.72, would pass), 75 / 100 passes (compared with 0.8² it would fail).
        let a = feats(&[desc(&[(20, 100)]), desc(&[(30, 100)])]);
        let b = feats(&[
            desc(&[(20, 100), (21, 85)]),
            desc(&[(20, 100), (22, 100)]),
            desc(&[(30, 100), (31, 75)]),
            desc(&[(30, 100), (32, 100)]),
        ]);
        let m = match_features(&a, &b, &MatchParams::default());
        assert_eq!(m.len(), 1, "{m:?}");
        assert_eq!((m[0].query, m[0].train), (1, 2));
        assert_eq!(m[0].distance, 75.0);
    }

    #[test]
    fn mutual_check_drops_one_sided_matches() {
        // Both queries' nearest train is train 0, but train 0's nearest query is query 0.
        let a = feats(&[desc(&[(0, 100)]), desc(&[(0, 60)])]);
        let b = feats(&[desc(&[(0, 101)]), desc(&[(90, 200)])]);
        let loose = MatchParams {
            ratio: 0.8,
            mutual: false,
        };
        let m = match_features(&a, &b, &loose);
        assert_eq!(
            m.iter().map(|m| (m.query, m.train)).collect::<Vec<_>>(),
            vec![(0, 0), (1, 0)]
        );
        let m = match_features(&a, &b, &MatchParams::default());
        assert_eq!(
            m.iter().map(|m| (m.query, m.train)).collect::<Vec<_>>(),
            vec![(0, 0)]
        );
    }

    #[test]
    fn empty_and_single_sets() {
        let one = feats(&[desc(&[(3, 7)])]);
        let none = Features::default();
        assert!(match_features(&none, &one, &MatchParams::default()).is_empty());
        assert!(match_features(&one, &none, &MatchParams::default()).is_empty());
        let m = match_features(&one, &one, &MatchParams::default());
        assert_eq!(m.len(), 1);
        assert_eq!(m[0].distance, 0.0);
    }

    #[test]
    fn angle_diff_wraps() {
        assert!((angle_diff(3.1, -3.1) - (6.2 - std::f64::consts::TAU)).abs() < 1e-12);
        assert!((angle_diff(0.1, 0.3) + 0.2).abs() < 1e-12);
    }

    #[test]
    fn slope_length_drops_planted_outliers() {
        // 20 inliers moving by about (5, 1), angles across the ±π seam handled below.
        let mut p = Vec::new();
        let mut q = Vec::new();
        for j in 0..20 {
            let (x, y) = (j as f64 * 3.0, (j * 7 % 11) as f64);
            let jit = ((j * 13 % 7) as f64 - 3.0) * 0.05;
            p.push([x, y]);
            q.push([x + 5.0 + jit, y + 1.0 - jit]);
        }
        // Outliers: wrong direction, too long, too short.
        p.push([1.0, 1.0]);
        q.push([1.0, 6.0]);
        p.push([2.0, 2.0]);
        q.push([2.0 + 12.0, 2.0 + 2.4]);
        p.push([3.0, 3.0]);
        q.push([3.0 + 2.0, 3.0 + 0.4]);
        let keep = reject_slope_length(&p, &q, 0.2, 0.3);
        assert!(keep[..20].iter().all(|&k| k));
        assert!(keep[20..].iter().all(|&k| !k));
        // The kept pairs themselves: the 20 inliers, in order.
        let (pk, qk) = keep_slope_length(&p, &q, PAPER_ANGLE_TOL, PAPER_LENGTH_TOL);
        assert_eq!((&pk[..], &qk[..]), (&p[..20], &q[..20]));
    }

    #[test]
    fn slope_length_uses_circular_mean_across_the_seam() {
        // Displacements pointing left (angles near ±π): the arithmetic mean of the angles
        // would be about 0 and reject everything.
        let mut p = Vec::new();
        let mut q = Vec::new();
        for j in 0..10 {
            let dy = if j % 2 == 0 { 0.3 } else { -0.3 };
            p.push([10.0 + j as f64, 5.0]);
            q.push([10.0 + j as f64 - 4.0, 5.0 + dy]);
        }
        p.push([0.0, 0.0]);
        q.push([4.0, 0.0]); // opposite direction
        let keep = reject_slope_length(&p, &q, 0.2, 0.3);
        assert!(keep[..10].iter().all(|&k| k), "{keep:?}");
        assert!(!keep[10]);
    }

    #[test]
    fn slope_length_still_scene_keeps_small_displacements() {
        // No motion: sub-pixel jitter in all directions, plus two planted mismatches.
        let mut p = Vec::new();
        let mut q = Vec::new();
        for j in 0..16 {
            let t = j as f64 * 0.7;
            p.push([j as f64, 2.0 * j as f64]);
            q.push([j as f64 + 0.3 * t.cos(), 2.0 * j as f64 + 0.3 * t.sin()]);
        }
        p.push([0.0, 0.0]);
        q.push([6.0, 0.0]);
        p.push([5.0, 5.0]);
        q.push([5.0, 3.0]);
        let keep = reject_slope_length(&p, &q, 0.2, 0.3);
        assert!(keep[..16].iter().all(|&k| k), "{keep:?}");
        assert!(!keep[16] && !keep[17]);
    }

    #[test]
    fn slope_length_bad_input() {
        assert!(reject_slope_length(&[], &[], 0.2, 0.3).is_empty());
        let keep = reject_slope_length(
            &[[0.0, 0.0], [f64::NAN, 0.0], [1.0, 1.0]],
            &[[3.0, 0.0], [3.0, 0.0]],
            0.2,
            0.3,
        );
        assert_eq!(keep, vec![true, false, false]);
    }
}
