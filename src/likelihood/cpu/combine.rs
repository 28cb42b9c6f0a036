//! Combination of the terms into one log-likelihood per particle (CPU twin of
//! `shaders/combine.wgsl`).

use crate::likelihood::{
    DEGENERATE, LikelihoodParams, TERM_COLOUR, TERM_CONTRAST, TERM_FEATURE, TERM_GRADIENT, TermLogs,
};

/// The result given to a degenerate particle: `total = DEGENERATE`, every term 0.
pub const DEGENERATE_LOGS: TermLogs = TermLogs {
    colour: 0.0,
    gradient: 0.0,
    feature: 0.0,
    contrast: 0.0,
    total: DEGENERATE,
};

/// Combines the term logs `[colour, gradient, feature, contrast]`: a disabled term's slot is
/// 0; `total` is the sum of the enabled terms in that order (`(((0 + c) + g) + f) + k` in
/// `f32`).
///
/// Non-finite results never escape: if the total is not finite (a finite but absurd particle,
/// e.g. a centre at 1e38 whose feature prediction overflows), the particle is treated as
/// degenerate ([`DEGENERATE_LOGS`]).
pub fn combine(logs: [f32; 4], params: &LikelihoodParams) -> TermLogs {
    let flags = [TERM_COLOUR, TERM_GRADIENT, TERM_FEATURE, TERM_CONTRAST];
    let [colour, gradient, feature, contrast] = std::array::from_fn(|i| {
        if params.terms & flags[i] != 0 {
            logs[i]
        } else {
            0.0
        }
    });
    let mut total = 0.0f32;
    total += colour;
    total += gradient;
    total += feature;
    total += contrast;
    if !total.is_finite() {
        return DEGENERATE_LOGS;
    }
    TermLogs {
        colour,
        gradient,
        feature,
        contrast,
        total,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_enabled_terms_and_zeroes_disabled_ones() {
        let mut p = LikelihoodParams {
            terms: TERM_COLOUR | TERM_GRADIENT | TERM_FEATURE,
            ..Default::default()
        };
        let t = combine([-1.0, -2.0, 0.5, 0.0], &p);
        assert_eq!(
            t,
            TermLogs {
                colour: -1.0,
                gradient: -2.0,
                feature: 0.5,
                contrast: 0.0,
                total: -2.5
            }
        );
        p.terms = TERM_GRADIENT;
        let t = combine([-1.0, -2.0, 0.5, 0.0], &p);
        assert_eq!(
            t,
            TermLogs {
                colour: 0.0,
                gradient: -2.0,
                feature: 0.0,
                contrast: 0.0,
                total: -2.0
            }
        );
        p.terms = TERM_COLOUR | TERM_FEATURE;
        let t = combine([-1.0, f32::NAN, 0.5, 0.0], &p);
        assert_eq!(
            t,
            TermLogs {
                colour: -1.0,
                gradient: 0.0,
                feature: 0.5,
                contrast: 0.0,
                total: -0.5
            }
        );
        p.terms = TERM_COLOUR | TERM_CONTRAST;
        assert_eq!(
            combine([-1.0, -2.0, 0.5, 0.25], &p),
            TermLogs {
                colour: -1.0,
                gradient: 0.0,
                feature: 0.0,
                contrast: 0.25,
                total: -0.75
            }
        );
        p.terms = 0;
        assert_eq!(combine([-1.0, -2.0, 0.5, 0.0], &p), TermLogs::default());
    }

    #[test]
    fn non_finite_totals_become_degenerate() {
        let p = LikelihoodParams::default();
        assert_eq!(
            combine([-1.0, 0.0, f32::NEG_INFINITY, 0.0], &p),
            DEGENERATE_LOGS
        );
        assert_eq!(combine([f32::NAN, 0.0, 0.0, 0.0], &p), DEGENERATE_LOGS);
        assert_eq!(combine([-3e38, -3e38, 0.0, 0.0], &p), DEGENERATE_LOGS);
        let all = LikelihoodParams {
            terms: crate::likelihood::TERM_ALL,
            ..p
        };
        assert_eq!(combine([0.0, 0.0, 0.0, f32::NAN], &all), DEGENERATE_LOGS);
    }
}
