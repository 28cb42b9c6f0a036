//! How sure the tracker is of an estimate: the confidence in `[0, 1]` every frame reports,
//! from the weighted colour similarity and the contour's support, and the same for one
//! hypothesis scored on its own (a loop closure's or a re-acquisition's candidate).

use super::*;
use crate::likelihood::cpu::colour::rho_from_log;

/// Confidence in `[0, 1]`: the weighted colour similarity ρ̄ (recovered from the colour
/// term, `ρ = 1 + 2σc² ln p_colour`) mapped from [0.5, 1] to [0, 1], times the weighted
/// share of normal lines with contour support, square-rooted (a geometric mean); times 0.8
/// when no features measured the rotation. An undefined term (NaN) supports nothing.
pub(super) fn confidence(
    terms: &[TermLogs],
    lp: &LikelihoodParams,
    w: &[f64],
    rotation_measured: bool,
) -> f64 {
    let mut colour = 1.0;
    if lp.terms & TERM_COLOUR != 0 {
        let rho: f64 = terms
            .iter()
            .zip(w)
            .map(|(t, &w)| supported(w, rho_from_log(t.colour, lp.sigma_colour)))
            .sum();
        colour = ((rho - 0.5) / 0.5).clamp(0.0, 1.0);
    }
    let mut edges = 1.0;
    if lp.terms & TERM_GRADIENT != 0 && lp.num_lines > 0 {
        // Every line's edge on the contour: the term's largest value.
        let k = f64::from(crate::likelihood::cpu::gradient::clutter_gain(lp));
        let full = lp.num_lines as f64 * (1.0 + k).ln();
        let g: f64 = terms
            .iter()
            .zip(w)
            .map(|(t, &w)| supported(w, t.gradient as f64))
            .sum();
        // `check` holds K at f32's epsilon or more, so `full` is positive.
        edges = if full > 0.0 {
            (g / full).clamp(0.0, 1.0)
        } else {
            0.0
        };
    }
    // Should anything still come out undefined, the frame reads as lost rather than as a NaN
    // the lost bar never catches.
    let c = (colour * edges).sqrt();
    let c = if c.is_nan() { 0.0 } else { c };
    if rotation_measured { c } else { 0.8 * c }
}

/// A particle's share `w · v` of a weighted term in [`confidence`]: nothing from a particle of
/// no weight or a term an engine left undefined (NaN: only a third-party engine's), which
/// supports nothing; `0 · NaN` made the whole frame's sum NaN for one such particle.
fn supported(w: f64, v: f64) -> f64 {
    if w > 0.0 && v.is_finite() { w * v } else { 0.0 }
}

impl Tracker {
    /// The colour similarity and confidence of one hypothesis on this frame's `input`, as
    /// the frame reports it: from the colour and contour terms of `lp` alone, discounted as
    /// [`confidence`] does unless `rotation_measured`.
    pub(super) fn own_confidence(
        &mut self,
        input: &FrameInput<'_>,
        mut lp: LikelihoodParams,
        h: &Hypothesis,
        rotation_measured: bool,
    ) -> crate::Result<(f64, f64)> {
        let mut shown = self.likelihood;
        shown.terms &= TERM_COLOUR | TERM_GRADIENT;
        lp.terms = TERM_COLOUR | shown.terms;
        let terms = &mut self.own_terms;
        self.helper.beside(&mut *self.engine, |e| {
            e.evaluate(input, &lp, &[h.to_particle()], terms)
        })?;
        let rho = self
            .own_terms
            .first()
            .map_or(0.0, |t| rho_from_log(t.colour, lp.sigma_colour));
        Ok((
            rho,
            confidence(&self.own_terms, &shown, &[1.0], rotation_measured),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Terms an engine left undefined support nothing (alone, a confidence of 0: the frame
    /// reads as lost, not a NaN that compares false against the lost bar); defined ones give
    /// one in [0, 1].
    #[test]
    fn undefined_terms_give_no_confidence() {
        let lp = LikelihoodParams::default();
        let good = TermLogs {
            colour: 0.0,
            gradient: 5.0,
            ..TermLogs::default()
        };
        let c = confidence(&[good], &lp, &[1.0], true);
        assert!((0.0..=1.0).contains(&c) && c > 0.0, "{c}");
        for bad in [
            TermLogs {
                colour: f32::NAN,
                ..good
            },
            TermLogs {
                gradient: f32::NAN,
                ..good
            },
        ] {
            // Supporting nothing, it halves its half's share; of no weight, it changes
            // nothing (one such particle among thousands made the frame's confidence NaN,
            // then 0).
            let half = confidence(&[good, bad], &lp, &[0.5, 0.5], true);
            assert!(half < c, "{half} against {c}");
            assert_eq!(confidence(&[good, bad], &lp, &[1.0, 0.0], true), c);
            assert_eq!(confidence(&[bad], &lp, &[1.0], false), 0.0);
        }
    }
}
