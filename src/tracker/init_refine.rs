//! Refining a rough initial ellipse on the first frame, before any model is learnt from it.
//!
//! Every model the tracker keeps (the colour histogram, the templates, the keyframe's object
//! model) is learnt inside the initial ellipse, and the pose is measured against that
//! ellipse. An ellipse a few pixels off the object is not corrected later without cost: the
//! contour and contrast terms pull it onto the outline over the next frames, the texture then
//! seems to move inside it, and the filter reads that as a turn that stays in every later
//! angle (on the synthetic `nod`, an initial ellipse 3 px high gave a tilt RMSE of 7-8°
//! instead of 1.4-1.7°). Refining by the tracker's own likelihood on the first frame does not
//! help, since its models are learnt from the ellipse being refined: it stays put.
//!
//! So the refinement scores an ellipse by what needs no model: how well its outline lies on
//! edges (the gradient term's normal lines, [`crate::likelihood::cpu::gradient`]) and how
//! well its inside's colours differ from a ring around it (one minus the Bhattacharyya
//! coefficient of the two histograms). A coarse-to-fine search over the centre and the two
//! semi-axes, the orientation kept, climbs that score from the given ellipse, within a bound
//! of the given size.

use image::RgbImage;

use crate::geometry::Ellipse;
use crate::likelihood::LikelihoodParams;
use crate::likelihood::cpu::gradient::{GradientImage, LineTables, log_likelihood_ellipse};
use crate::likelihood::cpu::{EllipseF32, colour};
use crate::tracker::TrackError;

/// How the initial ellipse is refined ([`refine_ellipse`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitRefine {
    /// Farthest the centre may move, as a share of the initial smaller semi-axis (0.3).
    pub max_shift: f64,
    /// Farthest each semi-axis may grow or shrink, as a share of itself (0.25).
    pub max_scale: f64,
    /// The colour ring lies between the ellipse and the ellipse scaled by this (1.5).
    pub ring: f64,
    /// Weight of the colour separation (in `[0, 1]`) against the mean `ln p` per normal line
    /// of the contour (4).
    pub colour_weight: f64,
}

impl Default for InitRefine {
    fn default() -> Self {
        Self {
            max_shift: 0.3,
            max_scale: 0.25,
            ring: 1.5,
            colour_weight: 4.0,
        }
    }
}

impl InitRefine {
    /// Checks the settings: finite, shares in `(0, 1)`, a ring above 1, a weight of at
    /// least 0.
    pub fn check(&self) -> Result<(), String> {
        let share = |v: f64| v.is_finite() && v > 0.0 && v < 1.0;
        if !share(self.max_shift) || !share(self.max_scale) {
            return Err(format!(
                "init refinement max_shift {} and max_scale {} must lie in (0, 1)",
                self.max_shift, self.max_scale
            ));
        }
        if !(self.ring.is_finite() && self.ring > 1.0) {
            return Err(format!(
                "init refinement ring {} must be above 1",
                self.ring
            ));
        }
        if !(self.colour_weight.is_finite() && self.colour_weight >= 0.0) {
            return Err(format!(
                "init refinement colour_weight {} must be finite and at least 0",
                self.colour_weight
            ));
        }
        Ok(())
    }
}

/// What [`refine_ellipse`] scores an ellipse by, per frame.
struct Scorer<'a> {
    frame: &'a RgbImage,
    grad: GradientImage,
    tables: LineTables,
    params: &'a LikelihoodParams,
    cfg: &'a InitRefine,
}

impl Scorer<'_> {
    /// Mean `ln p` per contour line plus `colour_weight` times the colour separation.
    fn score(&self, e: &Ellipse) -> f64 {
        let ef = EllipseF32::from_ellipse(e);
        let lines = self.tables.angles.len().max(1) as f64;
        let contour = log_likelihood_ellipse(&self.grad, &ef, &self.tables, self.params) as f64;
        contour / lines + self.cfg.colour_weight * self.separation(e)
    }

    /// One minus the Bhattacharyya coefficient of the colours inside `e` and in the ring
    /// around it; 0 when either is empty.
    fn separation(&self, e: &Ellipse) -> f64 {
        let bins = self.params.colour_bins;
        let outer = Ellipse {
            a: e.a * self.cfg.ring,
            b: e.b * self.cfg.ring,
            ..*e
        };
        let ((inner, n_in), ring) = colour::inside_and_ring(
            self.frame,
            &EllipseF32::from_ellipse(e),
            &EllipseF32::from_ellipse(&outer),
            bins,
        );
        let n_ring: u32 = ring.iter().sum();
        if n_in == 0 || n_ring == 0 {
            return 0.0;
        }
        let around = colour::Model::new(&colour::normalise(&ring, n_ring));
        (1.0 - f64::from(colour::bhattacharyya(&inner, n_in, &around))).max(0.0)
    }
}

/// `params` as the refinement reads them: its outline score is the gradient term's, whether
/// or not the filter's weights use it, so the gradient settings are checked as if it were on.
pub(crate) fn scoring_params(params: &LikelihoodParams) -> LikelihoodParams {
    LikelihoodParams {
        terms: params.terms | crate::likelihood::TERM_GRADIENT,
        ..*params
    }
}

/// The ellipse near `init` whose outline best lies on edges and whose inside best differs in
/// colour from its surroundings (see the module documentation): centre within
/// `max_shift · min(a, b)` of the initial one, semi-axes within a factor `1 ± max_scale` of
/// the initial ones, orientation unchanged. Deterministic; `init` itself when nothing scores
/// higher. Errors: settings their checks refuse ([`LikelihoodParams::check`],
/// [`InitRefine::check`]; unchecked, 2^32 normal lines would allocate 34 GB), or an invalid
/// `init`.
pub fn refine_ellipse(
    frame: &RgbImage,
    init: &Ellipse,
    params: &LikelihoodParams,
    cfg: &InitRefine,
) -> Result<Ellipse, TrackError> {
    scoring_params(params)
        .check()
        .map_err(|e| TrackError::bad_config("likelihood", e.to_string()))?;
    cfg.check()
        .map_err(|e| TrackError::bad_config("init_refine", e))?;
    super::checks::check_ellipse(init)?;
    let scorer = Scorer {
        frame,
        grad: GradientImage::new(frame),
        tables: LineTables::new(params),
        params,
        cfg,
    };
    let reach = cfg.max_shift * init.a.min(init.b);
    let (lo_a, hi_a) = (
        init.a * (1.0 - cfg.max_scale),
        init.a * (1.0 + cfg.max_scale),
    );
    let (lo_b, hi_b) = (
        init.b * (1.0 - cfg.max_scale),
        init.b * (1.0 + cfg.max_scale),
    );
    let allowed = |e: &Ellipse| {
        (e.cx - init.cx).hypot(e.cy - init.cy) <= reach + 1e-9
            && (lo_a..=hi_a).contains(&e.a)
            && (lo_b..=hi_b).contains(&e.b)
            && e.a >= 1.0
            && e.b >= 1.0
    };
    let mut best = *init;
    let mut best_score = scorer.score(init);
    // Steps: a quarter of the reach in position and of the scale bound in size, halved
    // each round; in each round the best of the 3^4 neighbours is taken until none is
    // better, then the steps halve.
    let mut step_px = 0.25 * reach;
    let mut step_scale = 0.25 * cfg.max_scale;
    for _ in 0..4 {
        loop {
            let mut moved = false;
            let centre = best;
            for dy in [-1.0, 0.0, 1.0] {
                for dx in [-1.0, 0.0, 1.0] {
                    for db in [-1.0, 0.0, 1.0] {
                        for da in [-1.0, 0.0, 1.0] {
                            if dx == 0.0 && dy == 0.0 && da == 0.0 && db == 0.0 {
                                continue;
                            }
                            let e = Ellipse {
                                cx: centre.cx + dx * step_px,
                                cy: centre.cy + dy * step_px,
                                a: centre.a * (1.0 + da * step_scale),
                                b: centre.b * (1.0 + db * step_scale),
                                ..centre
                            };
                            if !allowed(&e) {
                                continue;
                            }
                            let s = scorer.score(&e);
                            if s > best_score {
                                best = e;
                                best_score = s;
                                moved = true;
                            }
                        }
                    }
                }
            }
            if !moved {
                break;
            }
        }
        step_px *= 0.5;
        step_scale *= 0.5;
    }
    Ok(best)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w x h` frame: a blue-grey background of small random blocks, and inside `e` an
    /// orange object with its own mottling.
    fn scene(w: u32, h: u32, e: &Ellipse) -> RgbImage {
        let mut state = 7u32;
        let mut noise = move || {
            state = state.wrapping_mul(1664525).wrapping_add(1013904223);
            (state >> 24) as u8 % 40
        };
        let mut img = RgbImage::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let n = noise();
                let (u, v) = (x as f64 - e.cx, y as f64 - e.cy);
                let (s, c) = e.theta.sin_cos();
                let (p, q) = ((c * u + s * v) / e.a, (-s * u + c * v) / e.b);
                let px = if p * p + q * q <= 1.0 {
                    [200 + n / 2, 120 + n, 40 + n / 2]
                } else {
                    [60 + n, 80 + n, 110 + n]
                };
                img.put_pixel(x, y, image::Rgb(px));
            }
        }
        img
    }

    #[test]
    fn a_shifted_or_scaled_start_lands_on_the_object() {
        let truth = Ellipse {
            cx: 60.0,
            cy: 45.0,
            a: 16.0,
            b: 22.0,
            theta: 0.2,
        };
        let img = scene(120, 90, &truth);
        let params = LikelihoodParams::default();
        let cfg = InitRefine::default();
        for (dx, dy, k) in [
            (0.0, 0.0, 1.0),
            (0.0, -3.0, 1.0),
            (0.0, 3.0, 1.0),
            (-3.0, 0.0, 1.0),
            (2.5, 2.5, 1.0),
            (0.0, 0.0, 0.85),
            (0.0, 0.0, 1.15),
        ] {
            let start = Ellipse {
                cx: truth.cx + dx,
                cy: truth.cy + dy,
                a: truth.a * k,
                b: truth.b * k,
                ..truth
            };
            let e = refine_ellipse(&img, &start, &params, &cfg).unwrap();
            let shift = (e.cx - truth.cx).hypot(e.cy - truth.cy);
            assert!(shift < 0.75, "from {dx},{dy},{k}: {e:?}");
            assert!(
                (e.a / truth.a - 1.0).abs() < 0.05,
                "from {dx},{dy},{k}: {e:?}"
            );
            assert!(
                (e.b / truth.b - 1.0).abs() < 0.05,
                "from {dx},{dy},{k}: {e:?}"
            );
            assert_eq!(e.theta, start.theta);
        }
    }

    #[test]
    fn it_keeps_within_its_bounds_and_keeps_a_featureless_start() {
        let params = LikelihoodParams::default();
        let cfg = InitRefine::default();
        let start = Ellipse::new(60.0, 45.0, 16.0, 22.0);
        // Nothing to refine onto: the start itself.
        let flat = RgbImage::from_pixel(120, 90, image::Rgb([90, 90, 90]));
        assert_eq!(refine_ellipse(&flat, &start, &params, &cfg).unwrap(), start);
        // Settings their checks refuse, and a start that is no ellipse, are errors (2^32
        // normal lines once went straight to a 34 GB allocation).
        let lines = LikelihoodParams {
            num_lines: u32::MAX,
            ..params
        };
        let shift = InitRefine {
            max_shift: f64::NAN,
            ..cfg
        };
        let nan = Ellipse::new(f64::NAN, 45.0, 16.0, 22.0);
        assert!(matches!(
            refine_ellipse(&flat, &start, &lines, &cfg),
            Err(TrackError::BadConfig {
                setting: "likelihood",
                ..
            })
        ));
        assert!(matches!(
            refine_ellipse(&flat, &start, &params, &shift),
            Err(TrackError::BadConfig {
                setting: "init_refine",
                ..
            })
        ));
        assert!(matches!(
            refine_ellipse(&flat, &nan, &params, &cfg),
            Err(TrackError::BadInit {
                fault: crate::tracker::InitFault::NotAnEllipse,
                ..
            })
        ));
        // The object well beyond the reach: the result stays within the bounds.
        let far = Ellipse {
            cx: 90.0,
            ..Ellipse::new(60.0, 45.0, 10.0, 14.0)
        };
        let e = refine_ellipse(&scene(120, 90, &far), &start, &params, &cfg).unwrap();
        let reach = cfg.max_shift * start.a.min(start.b);
        assert!(
            (e.cx - start.cx).hypot(e.cy - start.cy) <= reach + 1e-9,
            "{e:?}"
        );
        for (got, was) in [(e.a, start.a), (e.b, start.b)] {
            assert!(got >= was * (1.0 - cfg.max_scale) - 1e-9, "{e:?}");
            assert!(got <= was * (1.0 + cfg.max_scale) + 1e-9, "{e:?}");
        }
    }

    #[test]
    fn bad_settings_are_rejected() {
        assert!(InitRefine::default().check().is_ok());
        for bad in [
            InitRefine {
                max_shift: 0.0,
                ..Default::default()
            },
            InitRefine {
                max_scale: 1.0,
                ..Default::default()
            },
            InitRefine {
                ring: 1.0,
                ..Default::default()
            },
            InitRefine {
                colour_weight: f64::NAN,
                ..Default::default()
            },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
    }
}
