//! Weight normalisation, effective sample size and systematic resampling: small pure
//! functions, each tested against what it must compute.

/// Normalises log-weights in place into probabilities (returned), subtracting the maximum
/// first so no term overflows. Non-finite log-weights count as zero weight; if every weight is
/// zero the result is uniform.
pub fn normalise_log_weights(log_w: &[f64]) -> Vec<f64> {
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
    let mut out = Vec::with_capacity(n);
    if w.is_empty() {
        return out;
    }
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
}
