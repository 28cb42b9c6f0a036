//! The target's appearance, as the tracker keeps it: the colour model and its adaptation on
//! confident frames, the contrast term's background ring, the switch to luma bins where the
//! footage turns grey (and back), and the template with the turned first view.

use super::*;

/// The normalised histogram of the pixels of `frame` in the ring between `e` and `e` scaled
/// by `c.ring` (the contrast term's background); `None` when the ring holds no pixel of the
/// frame (a target filling it).
fn ring_histogram(
    frame: &image::RgbImage,
    e: &Ellipse,
    c: &Contrast,
    colour_bins: u32,
) -> Option<ColourHistogram> {
    use crate::likelihood::cpu::{EllipseF32, colour};
    let outer = Ellipse {
        a: e.a * c.ring,
        b: e.b * c.ring,
        ..*e
    };
    let (_, ring) = colour::inside_and_ring(
        frame,
        &EllipseF32::from_ellipse(e),
        &EllipseF32::from_ellipse(&outer),
        colour_bins,
    );
    let total: u32 = ring.iter().sum();
    (total > 0).then(|| ColourHistogram(colour::normalise(&ring, total)))
}

/// Frames of the other kind in a row (grey among colour frames, or colour among grey ones)
/// after which the colour term turns to their bins ([`TrackerConfig::grey_luma`]): a single
/// black or white frame (a cut, a flash) is grey too, and no change of the camera's mode.
pub(super) const GREY_SWITCH_AFTER: usize = 2;

/// Whether every pixel of `frame` is grey (`R = G = B`): grayscale footage read as RGB.
pub(super) fn is_grey(frame: &image::RgbImage) -> bool {
    crate::frames::rgb_bytes(frame)
        .chunks_exact(3)
        .all(|p| p[0] == p[1] && p[1] == p[2])
}

impl Tracker {
    /// The particles' correlations with the template into `self.correlations`, for
    /// [`Self::weighted_totals`]; left empty when the term is off.
    pub(super) fn correlate_template(&mut self, gray: &GrayF32) {
        if let Some(t) = &self.template {
            t.correlate(
                gray,
                &self.particles,
                self.theta0 as f32,
                &mut self.correlations,
            );
        }
        if let Some((t, first)) = &self.anchor {
            t.correlate_turned(
                gray,
                &self.particles,
                self.theta0 as f32,
                first,
                &mut self.anchor_correlations,
            );
        }
    }

    /// After a frame with at least [`TemplateTerm::min_confidence`], moves the template
    /// towards the estimate's view.
    pub(super) fn adapt_template(&mut self, gray: &GrayF32, est: &Hypothesis, confidence: f64) {
        let (Some(cfg), Some(t)) = (self.cfg.template, self.template.as_mut()) else {
            return;
        };
        let rate = cfg.rate;
        if confidence >= cfg.min_confidence && rate > 0.0 {
            t.blend_towards(gray, &est.to_particle(), self.theta0 as f32, rate as f32);
        }
    }

    /// Turns the colour term to the other binning (RGB to luma where the footage turned grey,
    /// luma back to RGB where it turned to colour again), and says whether it did. Luma is
    /// learnt afresh from `frame` at the previous estimate `at` (the target moves little in a
    /// frame; an infrared image shows it in other grey levels than the luma of its colours,
    /// so the new frame, not the old one). RGB is the model and background put aside when the
    /// footage turned grey, or, for a track started on grey frames, learnt the same way. A
    /// lost track, or an estimate that holds no pixel of the frame, teaches nothing: a lost
    /// track turning to luma takes the luma of its colour start's frame at the start's
    /// ellipse instead, and otherwise the switch waits for a frame where the target is
    /// followed.
    pub(super) fn switch_colour_bins(
        &mut self,
        frame: &image::RgbImage,
        at: &Ellipse,
    ) -> crate::Result<bool> {
        let to_luma = self.likelihood.colour_bins != COLOUR_LUMA;
        let bins = if to_luma {
            COLOUR_LUMA
        } else {
            self.cfg.likelihood.colour_bins
        };
        let (model, background) = match self.other_appearance.take() {
            Some(rgb) if !to_luma => rgb,
            other => {
                self.other_appearance = other;
                if self.lost {
                    // The estimate rests on nothing to learn from: the start's own luma
                    // appearance, so that the lost target can be recognised in the grey
                    // frames (the RGB model shares no bin with them, and scores every
                    // place 0).
                    match self.luma_start.clone().filter(|_| to_luma) {
                        Some(start) => start,
                        None => return Ok(false),
                    }
                } else {
                    let Ok(learnt) = self.appearance_at(frame, at, bins) else {
                        return Ok(false);
                    };
                    learnt
                }
            }
        };
        self.engine.set_colour_model(&model)?;
        let old_model = std::mem::replace(&mut self.colour_model, model);
        let old_background = std::mem::replace(&mut self.background, background);
        // The RGB appearance is put aside for the colour frames' return; a luma one, learnt on
        // one grey stretch, is not kept for the next (another light, another mode).
        self.other_appearance = to_luma.then_some((old_model, old_background));
        self.likelihood.colour_bins = bins;
        self.send_contrast_table()?;
        Ok(true)
    }

    /// The target's colour model at `e` on `frame` in `bins`, and the contrast term's
    /// background, the ring around it, when that term is on: what a start and a switch of
    /// the bins learn.
    pub(super) fn appearance_at(
        &self,
        frame: &image::RgbImage,
        e: &Ellipse,
        bins: u32,
    ) -> Result<(ColourHistogram, Option<ColourHistogram>), crate::likelihood::LikelihoodError>
    {
        let model = ColourHistogram::from_ellipse(frame, e, bins)?;
        let ring = self.cfg.contrast;
        Ok((model, ring.and_then(|c| ring_histogram(frame, e, &c, bins))))
    }

    /// Turns the contrast term on in `lp` when it is configured and has a background, as the
    /// mean log-odds over an ellipse of semi-axes product `ab` ([`Contrast::weight`]).
    pub(super) fn enable_contrast(&self, lp: &mut LikelihoodParams, ab: f64) {
        if let (Some(c), Some(_)) = (self.cfg.contrast, &self.background) {
            let area = std::f64::consts::PI * ab;
            if c.weight > 0.0 && area > 0.0 {
                lp.terms |= TERM_CONTRAST;
                lp.contrast_scale = (c.weight / area) as f32;
            }
        }
    }

    /// Gives the engine the contrast table of the colour model against the background, when
    /// the contrast term is on.
    pub(super) fn send_contrast_table(&mut self) -> crate::Result<()> {
        if let Some(table) = self.contrast_table()? {
            self.engine.set_contrast_table(&table)?;
        }
        Ok(())
    }

    /// The contrast term's table from the colour model and the background, when the term is
    /// on and has a background.
    pub(super) fn contrast_table(&self) -> crate::Result<Option<ContrastTable>> {
        match (self.cfg.contrast, &self.background) {
            (Some(c), Some(bg)) => Ok(Some(ContrastTable::from_histograms(
                &self.colour_model,
                bg,
                c.limit as f32,
            )?)),
            _ => Ok(None),
        }
    }

    /// After a frame with at least [`Contrast::min_confidence`], moves the contrast term's
    /// background towards the ring around the estimate `est`
    /// ([`Contrast::background_rate`]). Returns whether it moved; the caller then sends the
    /// new table ([`Self::send_contrast_table`]).
    pub(super) fn adapt_background(
        &mut self,
        frame: &image::RgbImage,
        est: &Hypothesis,
        confidence: f64,
    ) -> bool {
        let (Some(c), Some(bg)) = (self.cfg.contrast, self.background.as_mut()) else {
            return false;
        };
        if confidence < c.min_confidence || c.background_rate <= 0.0 {
            return false;
        }
        let e = est.to_state().ellipse(self.theta0);
        let Some(seen) = ring_histogram(frame, &e, &c, self.likelihood.colour_bins) else {
            return false;
        };
        bg.blend_towards(&seen, c.background_rate as f32);
        true
    }

    /// After a frame with at least [`ColourUpdate::min_confidence`], moves the colour model
    /// towards the histogram inside the estimate `est` and hands it to the engine. An estimate
    /// whose ellipse holds no pixel of the frame leaves the model as it is. Returns whether
    /// the model moved; the contrast table, which depends on it, is then the caller's to send
    /// ([`Self::send_contrast_table`]).
    pub(super) fn adapt_colour(
        &mut self,
        frame: &image::RgbImage,
        est: &Hypothesis,
        confidence: f64,
    ) -> crate::Result<bool> {
        let Some(u) = self.cfg.colour_update else {
            return Ok(false);
        };
        if confidence < u.min_confidence {
            return Ok(false);
        }
        let e = est.to_state().ellipse(self.theta0);
        let bins = self.likelihood.colour_bins;
        // Held back while the model's colours are those of the surroundings.
        if u.max_ring_similarity < 1.0 {
            // The contrast term's background, else the ring around the estimate; a target
            // with no ring in the frame has no surroundings to be mistaken for.
            let around;
            let ring = match &self.background {
                Some(bg) => Some(bg),
                None => {
                    around =
                        ring_histogram(frame, &e, &self.cfg.contrast.unwrap_or_default(), bins);
                    around.as_ref()
                }
            };
            if ring.is_some_and(|r| self.colour_model.similarity(r) > u.max_ring_similarity) {
                return Ok(false);
            }
        }
        let Ok(seen) = ColourHistogram::from_ellipse(frame, &e, bins) else {
            return Ok(false);
        };
        self.colour_model.blend_towards(&seen, u.rate as f32);
        self.engine.set_colour_model(&self.colour_model)?;
        Ok(true)
    }
}
