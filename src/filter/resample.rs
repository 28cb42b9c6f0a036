//! Weight normalisation, effective sample size and systematic resampling: small pure
//! functions, each tested against what it must compute.

/// Normalises log-weights in place into probabilities (returned), subtracting the maximum
/// first so no term overflows. NaN and `-inf` count as zero weight; if every weight is zero
/// the result is uniform. A `+inf` outweighs every finite log-weight: the `+inf` entries share
/// the whole weight equally.
pub fn normalise_log_weights(log_w: &[f64]) -> Vec<f64> {
    let infinite = log_w.iter().filter(|&&v| v == f64::INFINITY).count();
    if infinite > 0 {
        let share = 1.0 / infinite as f64;
        return log_w
            .iter()
            .map(|&v| if v == f64::INFINITY { share } else { 0.0 })
            .collect();
    }
    let max = log_w
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(f64::NEG_INFINITY, f64::max);
    if !max.is_finite() {
        let n = log_w.len().max(1) as f64;
        return vec![1.0 / n; log_w.len()];
    }
    let mut w: Vec<f64> = log_w
        .iter()
        .map(|&l| if l.is_finite() { (l - max).exp() } else { 0.0 })
        .collect();
    let sum: f64 = w.iter().sum();
    for v in &mut w {
        *v /= sum;
    }
    w
}

/// Effective sample size `1 / Σ w²` of normalised weights.
pub fn effective_sample_size(w: &[f64]) -> f64 {
    let s: f64 = w.iter().map(|v| v * v).sum();
    if s > 0.0 { 1.0 / s } else { 0.0 }
}

/// Systematic resampling: `n` indices drawn with the comb `(u0 + k) / n`, `u0 ∈ [0, 1)`,
/// against the cumulative weights. Each particle `i` is drawn `⌊n wᵢ⌋` or `⌈n wᵢ⌉` times.
pub fn systematic(w: &[f64], n: usize, u0: f64) -> Vec<usize> {
    if w.is_empty() {
        return Vec::new();
    }
    let mut out = Vec::with_capacity(n);
    let mut cum = w[0];
    let mut i = 0;
    for k in 0..n {
        let u = (u0 + k as f64) / n as f64;
        while u >= cum && i + 1 < w.len() {
            i += 1;
            cum += w[i];
        }
        out.push(i);
    }
    out
}

/// How far the cumulative weights may move before [`systematic`] draws differently: the
/// smallest distance between a comb tooth `(u0 + k) / n` and a cumulative-weight boundary that
/// decides a draw (the running sums `w₀ + … + wᵢ`, `i < len − 1`, summed as [`systematic`]
/// sums them). Two weight vectors whose running sums all differ by less than this draw the
/// same indices with the same `u0`; a larger difference may (a tie at the comb) but need not
/// change a draw. `f64::INFINITY` with fewer than two weights or no draws.
pub fn systematic_margin(w: &[f64], n: usize, u0: f64) -> f64 {
    let mut margin = f64::INFINITY;
    if w.len() < 2 {
        return margin;
    }
    // The running sums as `systematic` forms them: `cum[i] = w[0] + ... + w[i]`.
    let mut cum = Vec::with_capacity(w.len() - 1);
    let mut acc = 0.0;
    for &wi in &w[..w.len() - 1] {
        acc += wi;
        cum.push(acc);
    }
    // Every boundary splits the teeth into those below and those at or above it; the nearest
    // teeth on either side decide its margin.
    for &c in &cum {
        // Smallest k with (u0 + k) / n >= c, and the tooth just below it.
        let k = (c * n as f64 - u0).ceil().max(0.0) as usize;
        for kk in [k.checked_sub(1), Some(k), k.checked_add(1)]
            .into_iter()
            .flatten()
        {
            if kk < n {
                let u = (u0 + kk as f64) / n as f64;
                margin = margin.min((u - c).abs());
            }
        }
    }
    margin
}

/// The largest difference between the running sums ([`systematic`]'s) of two weight vectors of
/// the same length.
pub fn max_cumulative_difference(a: &[f64], b: &[f64]) -> f64 {
    let (mut ca, mut cb, mut d) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        ca += x;
        cb += y;
        d = d.max((ca - cb).abs());
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalise_is_stable_and_sums_to_one() {
        let w = normalise_log_weights(&[-1000.0, -1001.0, f64::NEG_INFINITY, f64::NAN]);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!((w[0] / w[1] - std::f64::consts::E).abs() < 1e-9);
        assert_eq!(w[2], 0.0);
        assert_eq!(w[3], 0.0);
        let u = normalise_log_weights(&[f64::NEG_INFINITY; 4]);
        assert_eq!(u, vec![0.25; 4]);
        // A log-weight that overflowed to +inf is the best, not the worst.
        let b = normalise_log_weights(&[0.0, f64::INFINITY, 5.0, f64::INFINITY, f64::NAN]);
        assert_eq!(b, vec![0.0, 0.5, 0.0, 0.5, 0.0]);
    }

    #[test]
    fn degenerate_inputs_do_not_panic() {
        // No weights: nothing to draw, whatever the count (it was allocated first).
        assert!(systematic(&[], usize::MAX, 0.0).is_empty());
        // A boundary far beyond the comb (its tooth index saturates).
        for (w, u0) in [([1e20, 1.0], 0.0), ([0.5, 0.5], f64::NEG_INFINITY)] {
            let m = systematic_margin(&w, 1, u0);
            assert!(!m.is_nan() || u0.is_infinite(), "{w:?} {u0}: {m}");
        }
    }

    #[test]
    fn ess_bounds() {
        assert!((effective_sample_size(&[0.25; 4]) - 4.0).abs() < 1e-12);
        assert!((effective_sample_size(&[1.0, 0.0, 0.0]) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn systematic_counts_are_floor_or_ceil() {
        let w = [0.1, 0.45, 0.05, 0.4];
        // (u0 = 0 puts comb teeth exactly on cumulative sums such as 0.1 + 0.45 + 0.05, where
        // rounding of the sum decides; the property is exact away from such ties.)
        for &u0 in &[0.001, 0.13, 0.5, 0.999] {
            let idx = systematic(&w, 20, u0);
            assert_eq!(idx.len(), 20);
            assert!(idx.windows(2).all(|p| p[0] <= p[1]));
            for (i, wi) in w.iter().enumerate() {
                let c = idx.iter().filter(|&&j| j == i).count() as f64;
                let e = 20.0 * wi;
                assert!(
                    c >= e.floor() - 1e-9 && c <= e.ceil() + 1e-9,
                    "particle {i}: {c} vs {e}"
                );
            }
        }
        // A zero-weight particle is never drawn.
        assert!(!systematic(&[0.5, 0.0, 0.5], 10, 0.3).contains(&1));
    }

    #[test]
    fn margin_known_answer() {
        // Teeth at 0.025, 0.275, 0.525, 0.775; the only deciding boundary is 0.5.
        let m = systematic_margin(&[0.5, 0.5], 4, 0.1);
        assert!((m - 0.025).abs() < 1e-12, "{m}");
        assert_eq!(systematic_margin(&[1.0], 4, 0.1), f64::INFINITY);
        assert!(
            (max_cumulative_difference(&[0.2, 0.3, 0.5], &[0.25, 0.2, 0.55]) - 0.05).abs() < 1e-12
        );
    }

    #[test]
    fn draws_hold_within_the_margin_and_change_just_beyond_it() {
        // Moving the comb by delta / n moves every tooth by delta / n, as moving every running
        // sum by -delta / n would: within the margin nothing changes, just beyond it on one
        // side a draw does.
        let mut seed = 12345u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for trial in 0..200 {
            let len = 2 + trial % 30;
            let raw: Vec<f64> = (0..len).map(|_| next().powi(3)).collect();
            let sum: f64 = raw.iter().sum();
            let w: Vec<f64> = raw.iter().map(|x| x / sum).collect();
            let n = 1 + trial % 50;
            let u0 = 0.05 + 0.9 * next();
            let m = systematic_margin(&w, n, u0);
            let base = systematic(&w, n, u0);
            let shift = m * n as f64;
            for s in [0.99 * shift, -0.99 * shift] {
                let u = u0 + s;
                if (0.0..1.0).contains(&u) {
                    assert_eq!(
                        systematic(&w, n, u),
                        base,
                        "trial {trial}: inside the margin"
                    );
                }
            }
            let beyond = [1.01 * shift, -1.01 * shift]
                .iter()
                .map(|s| u0 + s)
                .filter(|u| (0.0..1.0).contains(u))
                .collect::<Vec<_>>();
            if beyond.len() == 2 {
                assert!(
                    beyond.iter().any(|&u| systematic(&w, n, u) != base),
                    "trial {trial}: nothing changed beyond the margin {m}"
                );
            }
        }
    }
}
