//! Checks of a tracker's settings and start, before anything is built from them: each bad
//! value is a [`TrackError`] naming it and saying what to do instead.

use nalgebra::Matrix3;

use super::{Init, InitFault, MAX_DEPTH_RATIO, TrackError, TrackerConfig};

/// The least semi-axis of a start (px), and so of the filter's floor.
pub const MIN_START_AXIS: f64 = 2.0;

impl TrackError {
    /// A [`TrackError::BadInit`].
    pub(crate) fn bad_init(fault: InitFault, why: String) -> Self {
        Self::BadInit { fault, why }
    }

    /// A [`TrackError::BadConfig`] of `setting`.
    pub(crate) fn bad_config(setting: &'static str, why: String) -> Self {
        Self::BadConfig { setting, why }
    }
}

impl Init {
    /// Checks the start against a `w x h` frame, as [`super::Tracker::new`] and
    /// [`super::Tracker::reinit`] do: a valid ellipse of semi-axes at least 2 px and at most
    /// the frame's longer side, whose centre lies in the frame, and angles (the ellipse's and
    /// the pose's) within a turn either way ([`TrackError::BadInit`]). The tracker also holds
    /// the semi-axes to its filter's bounds ([`Init::check_for`]).
    pub fn check(&self, w: u32, h: u32) -> Result<(), TrackError> {
        let e = &self.ellipse;
        check_ellipse(e)?;
        if e.a < MIN_START_AXIS || e.b < MIN_START_AXIS {
            return Err(TrackError::bad_init(
                InitFault::AxesTooSmall,
                format!(
                    "semi-axes {} x {} px: at least {MIN_START_AXIS} px each",
                    short(e.a),
                    short(e.b)
                ),
            ));
        }
        let side = f64::from(w.max(h));
        if side < MIN_START_AXIS {
            return Err(TrackError::bad_init(
                InitFault::FrameTooSmall,
                format!(
                    "a {w}x{h} frame holds no start: semi-axes must be at least \
                     {MIN_START_AXIS} px and at most the frame's longer side"
                ),
            ));
        }
        if e.a > side || e.b > side {
            return Err(TrackError::bad_init(
                InitFault::AxesTooLarge,
                format!(
                    "semi-axes {} x {} px: at most {side} px each, the {w}x{h} frame's longer side",
                    short(e.a),
                    short(e.b)
                ),
            ));
        }
        // A turn either way, with room for rounding from degrees.
        let turn = std::f64::consts::TAU * (1.0 + 1e-12);
        if e.theta.abs() > turn {
            return Err(TrackError::bad_init(
                InitFault::AngleOutOfRange,
                format!(
                    "ellipse angle {} degrees: at most 360 either way",
                    short(e.theta.to_degrees())
                ),
            ));
        }
        if !e.centre_inside(w, h) {
            return Err(TrackError::bad_init(
                InitFault::CentreOutside,
                format!(
                    "centre ({}, {}) lies outside the {w}x{h} frame",
                    short(e.cx),
                    short(e.cy)
                ),
            ));
        }
        let p = &self.pose;
        if ![p.rx, p.ry, p.rz].iter().all(|v| v.abs() <= turn) {
            return Err(TrackError::bad_init(
                InitFault::PoseOutOfRange,
                format!(
                    "initial pose {}, {}, {} degrees: each angle finite and at most 360 either way",
                    short(p.rx.to_degrees()),
                    short(p.ry.to_degrees()),
                    short(p.rz.to_degrees())
                ),
            ));
        }
        Ok(())
    }
}
impl Init {
    /// [`Init::check`], and the semi-axes within the particle filter's bounds
    /// (`cfg.filter.min_axis`, `cfg.filter.max_axis`), to which it would clamp every particle:
    /// a start outside them could not be tracked as given.
    pub fn check_for(&self, cfg: &TrackerConfig, w: u32, h: u32) -> Result<(), TrackError> {
        self.check(w, h)?;
        let (e, f) = (&self.ellipse, &cfg.filter);
        let inside = |v: f64| (f.min_axis..=f.max_axis).contains(&v);
        if !inside(e.a) || !inside(e.b) {
            // No upper bound is `null` in a settings file, `inf` in the library: said in words.
            let bounds = if f.max_axis == f64::INFINITY {
                format!("at least {} px, with no upper bound", short(f.min_axis))
            } else {
                format!("{} to {} px", short(f.min_axis), short(f.max_axis))
            };
            return Err(TrackError::bad_init(
                InitFault::OutsideFilterBounds,
                format!(
                    "semi-axes {} x {} px: outside the filter's bounds, {bounds} \
                     (filter.min_axis, filter.max_axis)",
                    short(e.a),
                    short(e.b),
                ),
            ));
        }
        Ok(())
    }
}

impl TrackerConfig {
    /// Checks every setting, as [`super::Tracker::new`] does before anything else, with a
    /// [`TrackError::BadConfig`] that names the setting (and, for an optional part, what
    /// `None` would do instead): the filter's ([`crate::filter::FilterParams::check`], and a
    /// floor on the semi-axes of at least the 2 px a start needs, since an estimate is one:
    /// [`super::Estimate::to_init`]), the
    /// likelihood's with the colour term included, which re-acquisition always uses
    /// ([`crate::likelihood::LikelihoodParams::check`]), SIFT's, matching's and block
    /// matching's own checks; the lost and re-acquisition thresholds; the keyframe fits'
    /// bounds, their motion prior by the rule of the fit itself
    /// ([`crate::pose::prior::MotionPrior::check`]) and the camera; and each optional part's
    /// own `check` (anchor refit, bundle adjustment, colour update, contrast, inter-frame
    /// consensus, re-anchoring, template; the start's refinement with the gradient settings,
    /// which it scores with whether or not the term is on) and widening factors (size hold,
    /// aspect slack).
    pub fn check(&self) -> Result<(), TrackError> {
        let bad = TrackError::bad_config;
        self.filter
            .check()
            .map_err(|e| bad("filter", e.to_string()))?;
        // The filter holds every estimate to its semi-axes' floor, and an estimate is a start
        // (`Estimate::to_init`), which needs 2 px at least ([`Init::check`]).
        if self.filter.min_axis < MIN_START_AXIS {
            return Err(bad(
                "filter.min_axis",
                format!(
                    "filter.min_axis {} px: at least {MIN_START_AXIS} px, the least semi-axis a \
                     start may have, since every estimate must be one",
                    short(self.filter.min_axis)
                ),
            ));
        }
        if self.likelihood.terms & crate::likelihood::TERM_CONTRAST != 0 && self.contrast.is_none()
        {
            return Err(bad(
                "contrast",
                "likelihood.terms has the contrast term but contrast is None: the term needs its \
                 settings (set contrast, and the tracker adds the flag itself)"
                    .into(),
            ));
        }
        // Re-acquisition weighs its candidates by colour whatever the terms, and the tracker
        // sets the contrast term's scale itself every frame.
        let likelihood = crate::likelihood::LikelihoodParams {
            terms: self.likelihood.terms | crate::likelihood::TERM_COLOUR,
            contrast_scale: 0.0,
            ..self.likelihood
        };
        likelihood
            .check()
            .map_err(|e| bad("likelihood", e.to_string()))?;
        // The object model's depth shapes the aspect bound, the keyframe fits and the turned
        // first view whatever the terms; the edge threshold is on gradients scaled to [0, 1].
        let depth = f64::from(self.likelihood.depth_ratio);
        if !(0.0..=MAX_DEPTH_RATIO).contains(&depth) {
            return Err(bad(
                "likelihood.depth_ratio",
                format!("likelihood.depth_ratio {depth} is not in [0, {MAX_DEPTH_RATIO}]"),
            ));
        }
        let edge = f64::from(self.likelihood.edge_threshold);
        if !(0.0..=1.0).contains(&edge) {
            return Err(bad(
                "likelihood.edge_threshold",
                format!("likelihood.edge_threshold {edge} is not in [0, 1]"),
            ));
        }
        self.sift.check().map_err(|e| bad("sift", e.to_string()))?;
        self.matching
            .check()
            .map_err(|e| bad("matching", e.to_string()))?;
        self.abm.check().map_err(|e| bad("abm", e.to_string()))?;
        if self.lost_after == 0 {
            return Err(bad(
                "lost_after",
                "lost_after 0: at least 1 low frame must come before the target is declared lost"
                    .into(),
            ));
        }
        if !(0.0..=1.0).contains(&self.reacquire_rho) {
            return Err(bad(
                "reacquire_rho",
                format!(
                    "reacquire_rho {} is not a colour similarity in [0, 1]",
                    self.reacquire_rho
                ),
            ));
        }
        let step = self.max_rotation_step;
        if !(step.is_finite() && step > 0.0) {
            return Err(bad(
                "max_rotation_step",
                format!(
                    "max_rotation_step {step} rad ({:.4}°) must be finite and positive",
                    step.to_degrees()
                ),
            ));
        }
        let residual = self.max_fit_residual;
        if !(residual.is_finite() && residual > 0.0) {
            return Err(bad(
                "max_fit_residual",
                format!("max_fit_residual {residual} must be finite and positive"),
            ));
        }
        if self.min_fit_inliers < 3 {
            return Err(bad(
                "min_fit_inliers",
                format!(
                    "min_fit_inliers {}: a fit of 6 parameters needs at least 3 matches",
                    self.min_fit_inliers
                ),
            ));
        }
        if self.keyframe_refresh_percent > 100 {
            return Err(bad(
                "keyframe_refresh_percent",
                format!(
                    "keyframe_refresh_percent {} is a share of at most 100",
                    self.keyframe_refresh_percent
                ),
            ));
        }
        let hfov = &super::config::HFOV_RANGE_DEG;
        if let Some(h) = self.camera_hfov_deg
            && !hfov.contains(&h)
        {
            return Err(bad(
                "camera_hfov_deg",
                format!(
                    "camera_hfov_deg {h} must lie between {} and {} degrees; set it to None for \
                     weak perspective",
                    hfov.start(),
                    hfov.end()
                ),
            ));
        }
        if !super::config::weight_ok(self.feature_weight) {
            return Err(TrackError::bad_config(
                "feature_weight",
                format!(
                    "feature_weight {} must lie in [0, {:e}] (0 leaves the rotation to the motion \
                     alone)",
                    self.feature_weight,
                    super::config::MAX_WEIGHT
                ),
            ));
        }
        if let Some(prior) = self.fit_prior() {
            prior.check().map_err(|e| {
                // The prior's sigmas are three settings: the error names the one refused.
                use crate::pose::prior::PriorSigma;
                let setting = match prior.bad_sigma() {
                    Some(PriorSigma::Rotation) => "filter.dynamics.rotation",
                    Some(PriorSigma::Centre) => "fit_centre_sigma",
                    Some(PriorSigma::Pixel) | None => "fit_pixel_sigma",
                };
                let centre = self
                    .fit_centre_sigma
                    .map_or_else(|| "None".to_string(), |c| c.to_string());
                let walk = self.filter.dynamics.rotation;
                TrackError::bad_config(
                    setting,
                    format!(
                        "the keyframe fits' motion prior (fit_pixel_sigma {}, fit_centre_sigma \
                         {centre}, the filter's rotation walk {walk:?} rad, {:?}°): {e}; set \
                         fit_pixel_sigma to None to fit without the prior, fit_centre_sigma to \
                         None to leave the centre free",
                        prior.pixel_sigma,
                        walk.map(|r| (r.to_degrees() * 1e4).round() / 1e4)
                    ),
                )
            })?;
        }
        if let Some(rate) = self.coast_rate
            && !(rate > 0.0 && rate <= 1.0)
        {
            return Err(TrackError::bad_config(
                "coast_rate",
                format!(
                    "coast_rate {rate} must lie in (0, 1]; set it to None to hold the rotation \
                     still where nothing measured it"
                ),
            ));
        }
        check_part(
            "init_refine",
            self.init_refine.as_ref().map(|p| p.check()),
            "to keep the given ellipse",
        )?;
        // The refinement scores outlines with the gradient term's settings, on or off.
        if self.init_refine.is_some() {
            let scoring = super::init_refine::scoring_params(&self.likelihood);
            scoring.check().map_err(|e| {
                // The refused value is the likelihood's, as `refine_ellipse` names it.
                TrackError::bad_config(
                    "likelihood",
                    format!(
                        "init_refine scores outlines with the gradient settings: {e}; set \
                         init_refine to None to keep the given ellipse"
                    ),
                )
            })?;
        }
        if let Some(d) = self.sift_upsample_below
            && !(d.is_finite() && d > 0.0)
        {
            return Err(TrackError::bad_config(
                "sift_upsample_below",
                format!(
                    "sift_upsample_below {d} must be a positive size in pixels; set it to None to \
                     keep the SIFT settings for every target size"
                ),
            ));
        }
        check_part(
            "bundle",
            self.bundle.as_ref().map(|p| p.check()),
            "to fit every keyframe on its ellipsoid alone",
        )?;
        check_part(
            "anchor_refit",
            self.anchor_refit.as_ref().map(|p| p.check()),
            "to measure against the nearest views alone",
        )?;
        // An anchor fit of fewer matches than any fit needs is taken, and then counts as no
        // fit at all when the next keyframe is weighed: one would be due on every frame.
        if let Some(r) = &self.anchor_refit
            && r.min_inliers < self.min_fit_inliers
        {
            return Err(TrackError::bad_config(
                "anchor_refit.min_inliers",
                format!(
                    "anchor_refit.min_inliers {} is fewer than min_fit_inliers {}: the anchor's \
                     fit needs at least the matches any fit does",
                    r.min_inliers, self.min_fit_inliers
                ),
            ));
        }
        check_part(
            "colour_update",
            self.colour_update.as_ref().map(|p| p.check()),
            "for a fixed colour model",
        )?;
        check_part(
            "contrast",
            self.contrast.as_ref().map(|p| p.check()),
            "for the paper's three terms alone",
        )?;
        check_part(
            "interframe_consensus",
            self.interframe_consensus.as_ref().map(|p| p.check()),
            "to estimate the rotation from any 3 matches",
        )?;
        check_part(
            "reanchor",
            self.reanchor.as_ref().map(|p| p.check()),
            "to leave the estimate to the filter",
        )?;
        check_part(
            "template",
            self.template.as_ref().map(|p| p.check()),
            "to weigh the particles without a template",
        )?;
        if !(0.0..=1.0).contains(&self.lost_below) {
            return Err(TrackError::bad_config(
                "lost_below",
                format!("lost_below {} must lie in [0, 1]", self.lost_below),
            ));
        }
        if !(self.lost_below..=1.0).contains(&self.found_above) {
            return Err(TrackError::bad_config(
                "found_above",
                format!(
                    "found_above {} must lie between lost_below ({}, the confidence under which \
                     the target is lost) and 1",
                    self.found_above, self.lost_below
                ),
            ));
        }
        if let Some(n) = self.reacquire_ncc
            && !(-1.0..=1.0).contains(&n)
        {
            return Err(TrackError::bad_config(
                "reacquire_ncc",
                format!(
                    "reacquire_ncc {n} is not in [-1, 1]; set it to None to recognise a \
                     re-acquired target by its features alone"
                ),
            ));
        }
        // Below the lost bar, frames counting towards a loss would be trusted.
        if !(self.lost_below..=1.0).contains(&self.trust_above) {
            return Err(TrackError::bad_config(
                "trust_above",
                format!(
                    "trust_above {} must lie between lost_below ({}, the confidence under \
                     which the target is lost) and 1",
                    self.trust_above, self.lost_below
                ),
            ));
        }
        check_factor(
            "size_hold",
            self.size_hold,
            "leave the ellipse's size free while the target is uncertain",
        )?;
        check_factor(
            "aspect_slack",
            self.aspect_slack,
            "leave the ellipse's aspect free",
        )?;
        if let Some(j) = self.exposure_jump
            && !(j.is_finite() && j > 0.0)
        {
            return Err(TrackError::bad_config(
                "exposure_jump",
                format!(
                    "exposure_jump {j} is not a finite share above 0; set it to None to take every \
                     frame's light as it comes"
                ),
            ));
        }
        Ok(())
    }

    /// The keyframe fits' motion prior from the configuration (its mean is each fit's start):
    /// the filter's rotation walk, [`TrackerConfig::fit_pixel_sigma`] and
    /// [`TrackerConfig::fit_centre_sigma`]; `None` without a pixel σ.
    pub(crate) fn fit_prior(&self) -> Option<crate::pose::prior::MotionPrior> {
        self.fit_pixel_sigma
            .map(|px| crate::pose::prior::MotionPrior {
                mean: Matrix3::identity(),
                sigma: self.filter.dynamics.rotation,
                pixel_sigma: px,
                centre_sigma: self.fit_centre_sigma,
            })
    }
}

/// A start's ellipse has finite values and positive semi-axes (the part of [`Init::check`]
/// that needs no frame; [`super::refine_ellipse`] checks it too).
pub(crate) fn check_ellipse(e: &crate::geometry::Ellipse) -> Result<(), TrackError> {
    if e.is_valid() {
        return Ok(());
    }
    Err(TrackError::bad_init(
        InitFault::NotAnEllipse,
        format!(
            "cx {}, cy {}, a {}, b {}, theta {}: values must be finite and the semi-axes positive",
            e.cx, e.cy, e.a, e.b, e.theta
        ),
    ))
}

/// `x` for a message: two decimals, trailing zeros dropped, or in exponent form when large.
/// The bounds a start is held to are whole or half pixels and degrees, so a value that two
/// decimals would round onto a half (1.999 px against at least 2, a centre at 63.501 where
/// the frame's edge is 63.5) gets six: a refused value is never shown as an accepted one.
fn short(x: f64) -> String {
    if x.abs() >= 1e6 {
        return format!("{x:.3e}");
    }
    let two = (x * 100.0).round() / 100.0;
    let onto_half = (two * 2.0).fract() == 0.0 && x != two;
    let text = if onto_half {
        format!("{x:.6}")
    } else {
        format!("{x:.2}")
    };
    let text = text.trim_end_matches('0').trim_end_matches('.');
    let text = if text == "-0" { "0" } else { text };
    text.to_string()
}

/// An optional part of the configuration, `name`, passes its own `check` (`None` when the
/// part is off); the error says what setting it to `None` does instead (`instead`).
fn check_part(
    name: &'static str,
    check: Option<Result<(), String>>,
    instead: &str,
) -> Result<(), TrackError> {
    match check {
        Some(Err(e)) => Err(TrackError::bad_config(
            name,
            format!("{e}; set {name} to None {instead}"),
        )),
        _ => Ok(()),
    }
}

/// A widening factor of the configuration, `name`, must be finite and at least 1; the
/// error says what setting it to `None` does instead (`none_does`).
fn check_factor(name: &'static str, k: Option<f64>, none_does: &str) -> Result<(), TrackError> {
    match k {
        Some(k) if !(k.is_finite() && k >= 1.0) => Err(TrackError::bad_config(
            name,
            format!(
                "{name} {k} is not a finite factor of at least 1; set {name} to None to {none_does}"
            ),
        )),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ellipse;
    use crate::tracker::Reanchor;

    #[test]
    fn a_refused_value_is_not_shown_rounded_into_its_range() {
        assert_eq!(short(1.96), "1.96");
        assert_eq!(short(63.54), "63.54");
        assert_eq!(short(360.04f64.to_radians().to_degrees()), "360.04");
        assert_eq!(short(2.0), "2");
        assert_eq!(short(-0.0000001), "0");
        assert_eq!(short(7.428929), "7.43");
        assert_eq!(short(1.999), "1.999");
        assert_eq!(short(63.5004), "63.5004");
        assert_eq!(short(63.5), "63.5");
        assert_eq!(short(-12.5), "-12.5");
        assert_eq!(short(1e308), "1.000e308");
        let start = |cx, a, rx: f64| Init {
            ellipse: Ellipse::new(cx, 23.0, a, 5.0),
            pose: crate::geometry::Euler::new(rx.to_radians(), 0.0, 0.0),
        };
        for (init, want) in [
            (start(31.0, 1.96, 0.0), "semi-axes 1.96 x 5 px"),
            (start(63.54, 5.0, 0.0), "centre (63.54, 23)"),
            (
                start(31.0, 5.0, 360.04),
                "initial pose 360.04, 0, 0 degrees",
            ),
        ] {
            let e = init.check(64, 48).unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
    }

    /// A contrast limit that passes the check is one the engine takes: 1e-50 is 0 in f32,
    /// which `Tracker::new` refused with the engine's error after `check()` had passed it.
    #[test]
    fn a_contrast_limit_passes_only_where_the_engine_takes_it() {
        use crate::tracker::Contrast;
        let frame = image::RgbImage::from_pixel(40, 30, image::Rgb([90, 120, 60]));
        let init = Init::frontal(Ellipse::new(20.0, 15.0, 6.0, 8.0));
        for (limit, ok) in [(1e-50, false), (1e-40, true), (0.5, true)] {
            let cfg = TrackerConfig {
                contrast: Some(Contrast {
                    limit,
                    ..Contrast::default()
                }),
                ..TrackerConfig::default()
            };
            assert_eq!(cfg.check().is_ok(), ok, "{limit}");
            if ok {
                assert!(
                    crate::tracker::Tracker::new(cfg, &frame, init).is_ok(),
                    "{limit}"
                );
            }
        }
    }

    #[test]
    fn found_above_and_reacquire_ncc_are_checked() {
        let bad = [
            (
                TrackerConfig {
                    found_above: 0.2,
                    ..TrackerConfig::default()
                },
                "found_above",
            ),
            (
                TrackerConfig {
                    found_above: 1.5,
                    ..TrackerConfig::default()
                },
                "found_above",
            ),
            (
                TrackerConfig {
                    reacquire_ncc: Some(f64::NAN),
                    ..TrackerConfig::default()
                },
                "reacquire_ncc",
            ),
            (
                TrackerConfig {
                    reacquire_ncc: Some(1.1),
                    ..TrackerConfig::default()
                },
                "reacquire_ncc",
            ),
        ];
        for (cfg, want) in bad {
            assert!(
                matches!(cfg.check(), Err(TrackError::BadConfig { setting, .. }) if setting == want),
                "{cfg:?}"
            );
        }
        assert!(TrackerConfig::default().check().is_ok());
    }

    #[test]
    fn every_part_of_the_settings_is_checked_by_name() {
        let d = TrackerConfig::default;
        // Each case: the settings, what the message must say, and the setting it names.
        let mut cases: Vec<(TrackerConfig, &str, &str)> = Vec::new();
        let mut c = d();
        c.filter.particles = 0;
        cases.push((c, "particles 0", "filter"));
        let mut c = d();
        c.filter.min_axis = f64::NAN;
        cases.push((c, "min_axis NaN", "filter"));
        let mut c = d();
        if let Some(r) = c.anchor_refit.as_mut() {
            r.min_inliers = 8;
        }
        cases.push((c, "anchor_refit.min_inliers 8", "anchor_refit.min_inliers"));
        // An estimate under 2 px would be a start `reinit` refuses.
        let mut c = d();
        c.filter.min_axis = 0.5;
        cases.push((c, "filter.min_axis 0.5", "filter.min_axis"));
        // The start's refinement scores outlines with the gradient settings, term on or off.
        let mut c = d();
        c.likelihood.terms = crate::likelihood::TERM_COLOUR;
        c.likelihood.sigma_z = 0.0;
        c.init_refine = Some(Default::default());
        cases.push((c, "init_refine", "likelihood"));
        // Re-acquisition weighs by colour even when the filter's weights do not.
        let mut c = d();
        c.likelihood.terms = crate::likelihood::TERM_GRADIENT;
        c.likelihood.sigma_colour = f32::NAN;
        cases.push((c, "sigma_colour", "likelihood"));
        let mut c = d();
        c.sift.sigma = -1.0;
        cases.push((c, "sigma -1", "sift"));
        let mut c = d();
        c.matching.ratio = f32::NAN;
        cases.push((c, "ratio NaN", "matching"));
        let mut c = d();
        c.abm.min_block = 0;
        cases.push((c, "min_block", "abm"));
        let mut c = d();
        c.lost_after = 0;
        cases.push((c, "lost_after 0", "lost_after"));
        let mut c = d();
        c.trust_above = 1.5;
        cases.push((c, "trust_above 1.5", "trust_above"));
        // Below the lost bar, frames counting towards a loss would be trusted.
        let mut c = d();
        c.trust_above = 0.1;
        cases.push((c, "trust_above 0.1", "trust_above"));
        let mut c = d();
        c.reacquire_rho = 1.5;
        cases.push((c, "reacquire_rho 1.5", "reacquire_rho"));
        let mut c = d();
        c.max_rotation_step = f64::INFINITY;
        cases.push((c, "max_rotation_step inf", "max_rotation_step"));
        let mut c = d();
        c.max_fit_residual = 0.0;
        cases.push((c, "max_fit_residual 0", "max_fit_residual"));
        let mut c = d();
        c.min_fit_inliers = 2;
        cases.push((c, "min_fit_inliers 2", "min_fit_inliers"));
        let mut c = d();
        c.keyframe_refresh_percent = 101;
        cases.push((
            c,
            "keyframe_refresh_percent 101",
            "keyframe_refresh_percent",
        ));
        let mut c = d();
        c.camera_hfov_deg = Some(180.0);
        cases.push((c, "camera_hfov_deg 180", "camera_hfov_deg"));
        let mut c = d();
        c.camera_hfov_deg = Some(1e-300);
        cases.push((c, "camera_hfov_deg 0.000", "camera_hfov_deg"));
        // Weights beyond MAX_WEIGHT: 1e300 overflowed mid-run, 1e39 split GPU from CPU.
        let mut c = d();
        c.feature_weight = 2e6;
        cases.push((c, "feature_weight 2000000", "feature_weight"));
        let mut c = d();
        if let Some(t) = c.template.as_mut() {
            t.weight = 1e300;
        }
        cases.push((c, "template weight 1000", "template"));
        let mut c = d();
        if let Some(k) = c.contrast.as_mut() {
            k.weight = 1e39;
        }
        cases.push((c, "contrast weight 1000", "contrast"));
        // The keyframe fits' motion prior is refused for any of three settings.
        let mut c = d();
        c.fit_centre_sigma = Some(0.0);
        cases.push((c, "fit_centre_sigma 0", "fit_centre_sigma"));
        let mut c = d();
        c.filter.dynamics.rotation[1] = 0.0;
        c.filter.proposal.rotation[1] = 0.0;
        cases.push((c, "motion prior", "filter.dynamics.rotation"));
        for (cfg, name, want) in cases {
            let Err(TrackError::BadConfig { why, setting }) = cfg.check() else {
                panic!("{name}: accepted");
            };
            assert!(why.contains(name), "{why} does not name {name}");
            assert_eq!(setting, want, "{why}");
        }
        // The contrast term's scale is the tracker's to set each frame, not a setting.
        let mut c = d();
        c.likelihood.contrast_scale = f32::NAN;
        assert!(c.check().is_ok());
    }

    #[test]
    fn coast_rate_is_checked() {
        for rate in [0.0, -0.1, 1.5, f64::NAN] {
            let cfg = TrackerConfig {
                coast_rate: Some(rate),
                ..TrackerConfig::default()
            };
            assert!(
                matches!(
                    cfg.check(),
                    Err(TrackError::BadConfig {
                        setting: "coast_rate",
                        ..
                    })
                ),
                "{rate}"
            );
        }
        for rate in [Some(1.0), Some(0.01), None] {
            let cfg = TrackerConfig {
                coast_rate: rate,
                ..TrackerConfig::default()
            };
            assert!(cfg.check().is_ok(), "{rate:?}");
        }
    }

    #[test]
    fn exposure_jump_is_checked() {
        for j in [0.0, -0.1, f64::NAN, f64::INFINITY] {
            let cfg = TrackerConfig {
                exposure_jump: Some(j),
                ..TrackerConfig::default()
            };
            assert!(
                matches!(
                    cfg.check(),
                    Err(TrackError::BadConfig {
                        setting: "exposure_jump",
                        ..
                    })
                ),
                "{j}"
            );
        }
        for j in [Some(0.01), Some(2.0), None] {
            let cfg = TrackerConfig {
                exposure_jump: j,
                ..TrackerConfig::default()
            };
            assert!(cfg.check().is_ok(), "{j:?}");
        }
    }

    #[test]
    fn reanchor_settings_are_checked() {
        let bad = [
            Reanchor {
                min_ncc: 1.5,
                ..Reanchor::default()
            },
            Reanchor {
                min_ncc: f64::NAN,
                ..Reanchor::default()
            },
            Reanchor {
                margin: -0.1,
                ..Reanchor::default()
            },
            Reanchor {
                min_confidence: 2.0,
                ..Reanchor::default()
            },
        ];
        for r in bad {
            let cfg = TrackerConfig {
                reanchor: Some(r),
                ..TrackerConfig::default()
            };
            assert!(
                matches!(
                    cfg.check(),
                    Err(TrackError::BadConfig {
                        setting: "reanchor",
                        ..
                    })
                ),
                "{r:?}"
            );
        }
    }

    #[test]
    fn init_checks() {
        let ok = Init::frontal(Ellipse::new(50.0, 40.0, 10.0, 12.0));
        assert!(ok.check(100, 80).is_ok());
        let fault = |e: Ellipse| match Init::frontal(e).check(100, 80) {
            Err(TrackError::BadInit { fault, .. }) => Some(fault),
            _ => None,
        };
        let outside = Ellipse::new(150.0, 40.0, 10.0, 12.0);
        assert_eq!(fault(outside), Some(InitFault::CentreOutside));
        let zero = Ellipse::new(50.0, 40.0, 0.0, 12.0);
        assert_eq!(fault(zero), Some(InitFault::NotAnEllipse));
        let nan = Ellipse::new(f64::NAN, 40.0, 10.0, 12.0);
        assert_eq!(fault(nan), Some(InitFault::NotAnEllipse));
        // A frame smaller than the least start: said so, not "at most 1 px" against "at least 2".
        let least = Init::frontal(Ellipse::new(0.0, 0.0, 2.0, 2.0));
        assert!(least.check(2, 1).is_ok());
        let Err(TrackError::BadInit {
            fault: InitFault::FrameTooSmall,
            why,
        }) = least.check(1, 1)
        else {
            panic!("a start in a 1x1 frame passed");
        };
        assert!(why.contains("a 1x1 frame holds no start"), "{why}");
    }
}
