//! Losing the target and finding it again: the lost flag ([`lost_state`]), the loop
//! closures on the first view (re-anchoring beside the estimate, [`Tracker::reanchor`], and
//! re-posing at it, [`Tracker::repose`]) and the search over the whole frame once the target
//! is lost ([`Tracker::reacquire`]), each recognising the target by its colours, its features
//! against the keyframes and its templates.

use super::keyframe::FitContext;
use super::{KEYFRAMES, Reanchor, Tracker, TrackerConfig, search_margin, search_region};
use crate::filter::Hypothesis;
use crate::frames::GrayF32;
use crate::geometry::{BoxRect, Ellipse, Euler, PoseState};
use crate::likelihood::cpu::colour::rho_from_log;
use crate::likelihood::{FrameInput, LikelihoodParams, Particle, TERM_COLOUR};

/// Candidates of a re-acquisition placed to the template on a finer grid, the best by their
/// correlation on the search's grid first ([`Tracker::refine_by_template`]).
const TEMPLATE_REFINED: usize = 3;

/// Sizes a re-acquisition searches at, times the initial ellipse's: an octave either way in
/// half-octave steps.
const REACQUIRE_SCALES: [f64; 5] = [
    0.5,
    std::f64::consts::FRAC_1_SQRT_2,
    1.0,
    std::f64::consts::SQRT_2,
    2.0,
];

/// Spacing (degrees) of the tilts and pans [`Tracker::repose`] tries first.
const REPOSE_STEP_DEG: f32 = 5.0;
/// How far (degrees) from the estimate's tilt and pan [`Tracker::repose`] looks.
const REPOSE_REACH_DEG: f32 = 30.0;

impl Tracker {
    /// The correlation of each of `cands` with the target's templates (the learning one and
    /// the first view's, unturned), the lower of the two: a candidate is recognised only as
    /// much as both see the target in it. `None` without the template term.
    ///
    /// Why both: each alone recognises what is not the target. The first view, placed finely
    /// enough, correlates 0.5-0.6 with patches of road and trees on OTB car4 (filter seed 31,
    /// frame 304: 0.59 at a spot 140 px from the car, where the learning template gave 0.19),
    /// and the learning template has followed whatever drift lost the target. On girl's
    /// face at frame 481 they gave 0.69 and 0.57; on the synthetic head of the tests, 0.64
    /// and 0.66.
    fn template_correlations(&self, gray: &GrayF32, cands: &[Particle]) -> Option<Vec<f32>> {
        let theta0 = self.theta0 as f32;
        let mut best: Option<Vec<f32>> = None;
        let templates = self
            .template
            .iter()
            .chain(self.anchor.iter().map(|(t, _)| t));
        for t in templates.filter(|t| t.is_usable()) {
            let mut ncc = Vec::new();
            t.correlate(gray, cands, theta0, &mut ncc);
            best = Some(match best {
                None => ncc,
                Some(b) => b.into_iter().zip(ncc).map(|(x, y)| x.min(y)).collect(),
            });
        }
        best
    }

    /// Whether a lost target's estimate `est` is the target by more than colour and contour,
    /// which background that looks like it meets (on grey footage, road and trees around a
    /// car read 0.5-0.76): its templates correlate there, placed as re-acquisition places a
    /// candidate, at least [`TrackerConfig::reacquire_ncc`]. Without a usable template or
    /// that bar, nothing but colour and contour can say, and they do (`true`). The caller
    /// counts a keyframe fit on the frame as recognition too.
    pub(super) fn recognised_at(&self, gray: &GrayF32, est: &Hypothesis) -> bool {
        let Some(min_ncc) = self.cfg.reacquire_ncc else {
            return true;
        };
        match self.refine_by_template(gray, &est.to_particle()) {
            None => true,
            Some((_, ncc)) => f64::from(ncc) >= min_ncc,
        }
    }

    /// `c` moved and scaled to where it correlates best with the target's templates
    /// ([`Self::template_correlations`]), on a grid of a quarter of the search's step either
    /// way by two (5 x 5 positions) at three sizes a quarter octave apart; with that
    /// correlation. `None` without a template.
    fn refine_by_template(&self, gray: &GrayF32, c: &Particle) -> Option<(Particle, f32)> {
        let step = search_step(f64::from(c.a), f64::from(c.b)) as f32 / 4.0;
        let local = local_grid(std::slice::from_ref(c), step, 2, &[-0.25, 0.0, 0.25]);
        let ncc = self.template_correlations(gray, &local)?;
        local
            .into_iter()
            .zip(ncc)
            .filter(|(_, n)| n.is_finite())
            .max_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// The re-anchoring's settings and how well the first view, turned by the estimate's
    /// pose, correlates at the estimate: the common start of [`Self::reanchor`] and
    /// [`Self::repose`]. `None` when re-anchoring or the first view is off, or the frame's
    /// confidence is below [`Reanchor::min_confidence`].
    fn first_view_at(
        &self,
        gray: &GrayF32,
        est: &Hypothesis,
        confidence: f64,
    ) -> Option<(Reanchor, f64)> {
        let r = self.cfg.reanchor?;
        let (t, first) = self.anchor.as_ref()?;
        if confidence < r.min_confidence {
            return None;
        }
        let mut at_estimate = Vec::with_capacity(1);
        let theta0 = self.theta0 as f32;
        t.correlate_turned(gray, &[est.to_particle()], theta0, first, &mut at_estimate);
        Some((r, f64::from(at_estimate.first().copied().unwrap_or(0.0))))
    }

    /// The target re-anchored on its first view ([`TrackerConfig::reanchor`]): on a frame of
    /// at least [`Reanchor::min_confidence`], the first view's template is looked for
    /// unturned beside the estimate ([`Self::find_first_view`]), at the estimate's area and
    /// the first ellipse's aspect. When it correlates there at least [`Reanchor::min_ncc`],
    /// and by [`Reanchor::margin`] more than the first view turned by the estimate's pose
    /// correlates at the estimate itself, the target is where the first view was found, in
    /// the first pose. `None` otherwise, or without a first view (the template or its
    /// anchor off).
    pub(super) fn reanchor(
        &self,
        gray: &GrayF32,
        est: &Hypothesis,
        confidence: f64,
    ) -> Option<Hypothesis> {
        let (r, explained) = self.first_view_at(gray, est, confidence)?;
        let (_, first) = self.anchor.as_ref()?;
        // No correlation passes 1, so an estimate that explains the first view within the
        // margin of that keeps it without the search.
        if explained + r.margin > 1.0 {
            return None;
        }
        let f = first.particle;
        let k = ((est.a * est.b) / (f64::from(f.a) * f64::from(f.b))).sqrt() as f32;
        let like_first = Particle {
            cx: est.cx as f32,
            cy: est.cy as f32,
            a: f.a * k,
            b: f.b * k,
            ..f
        };
        let (p, ncc) = self.find_first_view(gray, &like_first)?;
        let ncc = f64::from(ncc);
        if ncc < r.min_ncc || ncc < explained + r.margin {
            return None;
        }
        let first_pose = PoseState {
            rx: f64::from(f.rx),
            ry: f64::from(f.ry),
            rz: f64::from(f.rz),
            ..PoseState::default()
        };
        // The estimate's area at the first ellipse's aspect, in full precision: an estimate of
        // the first ellipse's size keeps it exactly.
        let (area, aspect) = (est.a * est.b, self.first_outline.a / self.first_outline.b);
        Some(Hypothesis {
            cx: f64::from(p.cx),
            cy: f64::from(p.cy),
            a: (area * aspect).sqrt(),
            b: (area / aspect).sqrt(),
            rot: Hypothesis::from_state(&first_pose).rot,
        })
    }

    /// The estimate turned to the tilt and pan at which the first view, turned with it
    /// ([`Template::correlate_turned`]), correlates best ([`TrackerConfig::reanchor`]): on a
    /// frame of at least [`Reanchor::min_confidence`] whose estimate explains the first view
    /// less than [`Reanchor::min_ncc`], tilts and pans [`REPOSE_STEP_DEG`] apart, up to
    /// [`REPOSE_REACH_DEG`] either way from the estimate's, at its place, size and roll; then
    /// a quarter step apart around the best. Taken when the best is at least a step from the
    /// estimate's tilt or pan, and correlates at least `min_ncc` and by [`Reanchor::margin`]
    /// more than the estimate does.
    ///
    /// Why: the first view counts in the weights only above
    /// [`TemplateTerm::anchor_threshold`], a few degrees from the true pose, so a track that
    /// has slipped further than that (on `combo` seed 9 the pan sat 20° short for 60
    /// frames, where the first view correlated 0.2 at the estimate and 0.77 at the truth)
    /// gets no pull back from it.
    pub(super) fn repose(
        &self,
        gray: &GrayF32,
        est: &Hypothesis,
        confidence: f64,
    ) -> Option<Hypothesis> {
        let (r, explained) = self.first_view_at(gray, est, confidence)?;
        if explained >= r.min_ncc {
            return None;
        }
        let (t, first) = self.anchor.as_ref()?;
        let (theta0, p) = (self.theta0 as f32, est.to_particle());
        let mut ncc = Vec::new();
        // The estimate's correlation came from an `f32`, so this is exact.
        let mut best = (p, explained as f32);
        for (step, reach) in [
            (REPOSE_STEP_DEG, REPOSE_REACH_DEG),
            (REPOSE_STEP_DEG / 4.0, REPOSE_STEP_DEG / 2.0),
        ] {
            let n = (reach / step).round() as i32;
            let c = best.0;
            let grid: Vec<Particle> = (-n..=n)
                .flat_map(|i| (-n..=n).map(move |j| (i, j)))
                .map(|(i, j)| Particle {
                    rx: c.rx + (i as f32 * step).to_radians(),
                    ry: c.ry + (j as f32 * step).to_radians(),
                    ..c
                })
                .collect();
            t.correlate_turned(gray, &grid, theta0, first, &mut ncc);
            if let Some((q, v)) = grid
                .into_iter()
                .zip(ncc.iter().copied())
                .filter(|(_, v)| v.is_finite())
                .max_by(|a, b| a.1.total_cmp(&b.1))
                && v > best.1
            {
                best = (q, v);
            }
        }
        let (q, v) = best;
        // A slip within a step is one the filter's own walk closes; and near the estimate a
        // small turn looks much like a small shift, so a better turn there says as much
        // about the place as about the pose.
        // (A turn of exactly one step, the coarse grid's neighbour, comes back from f32 a
        // hair short of it in about half the cases: hence the thousandth of a degree.)
        let turn = (q.rx - p.rx).abs().max((q.ry - p.ry).abs()).to_degrees();
        if turn < REPOSE_STEP_DEG - 1e-3 {
            return None;
        }
        if f64::from(v) < r.min_ncc || f64::from(v) < explained + r.margin {
            return None;
        }
        let s = est.to_state();
        Some(Hypothesis::from_state(&PoseState {
            rx: f64::from(q.rx),
            ry: f64::from(q.ry),
            ..s
        }))
    }

    /// Where the first view's template correlates best (plain, unturned: `c` carries the
    /// first pose) near `c`: on a grid of half the search's step (the step is half the
    /// smaller semi-axis) four either way, at sizes from half an octave smaller to a quarter
    /// octave larger in quarter octaves; then around the best three on a grid of an eighth
    /// of the step, two either way, at sizes an eighth of an octave apart, and around the
    /// best of those a thirty-second of the step apart at sizes a sixteenth of an octave
    /// apart ([`local_grid`]); with that correlation. `None` without a first view. The sizes
    /// only place the template: the NCC of a small view of a face's middle runs high, so the
    /// size it finds is not taken.
    fn find_first_view(&self, gray: &GrayF32, c: &Particle) -> Option<(Particle, f32)> {
        let (t, _) = self.anchor.as_ref()?;
        let theta0 = self.theta0 as f32;
        let step = search_step(f64::from(c.a), f64::from(c.b)) as f32;
        let coarse = local_grid(
            std::slice::from_ref(c),
            step / 2.0,
            4,
            &[-0.5, -0.25, 0.0, 0.25],
        );
        let mut ncc = Vec::new();
        t.correlate(gray, &coarse, theta0, &mut ncc);
        let mut order: Vec<usize> = (0..coarse.len()).filter(|&i| ncc[i].is_finite()).collect();
        order.sort_by(|&x, &y| ncc[y].total_cmp(&ncc[x]).then(x.cmp(&y)));
        let best: Vec<Particle> = order.iter().take(3).map(|&i| coarse[i]).collect();
        // Then around the best three an eighth of a step apart, and around the best of those
        // a thirty-second (a sharp texture decorrelates within a pixel).
        let (mut around, mut found) = (best, None);
        for (step, octaves) in [
            (step / 8.0, [-0.125, 0.0, 0.125]),
            (step / 32.0, [-0.0625, 0.0, 0.0625]),
        ] {
            let fine = local_grid(&around, step, 2, &octaves);
            t.correlate(gray, &fine, theta0, &mut ncc);
            let top = fine
                .into_iter()
                .zip(ncc.iter().copied())
                .filter(|(_, n)| n.is_finite())
                .max_by(|x, y| x.1.total_cmp(&y.1))?;
            around = vec![top.0];
            found = Some(top);
        }
        found
    }

    /// Looks for the target over the whole frame: by colour first, ellipses at
    /// [`REACQUIRE_SCALES`] times the initial ellipse's size on a grid of half a semi-axis,
    /// all evaluated together (in batches the engine's buffers hold) and ranked by the colour
    /// term plus, when it is on, the contrast term (which prefers the size holding the
    /// target's colours and no more);
    /// the best one, when its colour similarity reaches [`TrackerConfig::reacquire_rho`], is
    /// then verified by its features, which must fit one of the keyframes (any pose), and
    /// when they do not, the few of those colours its templates rank best, in turn (on grey
    /// car4 the best by colour was always a patch of trees).
    /// With [`TrackerConfig::reacquire_ncc`], the candidate of the target's colours that
    /// correlates best with its templates ([`Self::template_correlations`]) is taken instead
    /// when it reaches that correlation, and is recognised by it even when its features fit
    /// no keyframe.
    /// Returns the target as the fit places it (or as the template found it), with its own
    /// confidence, when it lies where it was searched ([`placed_within`]), passes the
    /// candidate's colour test and is as confident as a found track ([`reacquired`]).
    ///
    /// The candidates are laid in `est`'s rotation, which the tracker gives as the last
    /// trusted estimate's (a lost estimate's own has walked), and a candidate the templates
    /// alone recognised is found in it.
    ///
    /// The sizes come from the initial ellipse, not from the track: a track is declared lost
    /// only after its estimate has drifted for a while, and by then its size is no guide (on
    /// OTB girl the last estimate above the lost threshold was 2 x 2 px on a 13 x 17 px head,
    /// on car4 96 x 104 px on a 34 x 26 px car).
    pub(super) fn reacquire(
        &mut self,
        frame: &image::RgbImage,
        gray: &GrayF32,
        est: &Hypothesis,
    ) -> crate::Result<Option<(Hypothesis, f64)>> {
        let (w, h) = self.size;
        let cands = search_grid(&self.first_outline, w, h, &Euler::from_matrix(&est.rot));
        let (lp, input) = self.search_terms(frame);
        let mut out = Vec::new();
        // The grid covers the frame, so its size has no bound the filter's count sets: in
        // batches the engine's buffers hold (a 4 px target on a 4K frame is 7.8 million
        // candidates, 249 MB of GPU buffer).
        self.helper.beside(&mut *self.engine, |e| {
            e.evaluate_batched(&input, &lp, &cands, &mut out)
        })?;
        let rhos: Vec<f64> = out
            .iter()
            .map(|t| rho_from_log(t.colour, lp.sigma_colour))
            .collect();
        // total_cmp ranks NaN above every number: a NaN candidate is not a best one.
        let best = out
            .iter()
            .enumerate()
            .filter(|(_, t)| t.total.is_finite())
            .max_by(|a, b| a.1.total.total_cmp(&b.1.total))
            .map(|(i, _)| (i, rhos[i]));
        // Among the candidates of the target's colours, the one its template recognises best,
        // each of the best few placed first to the template on a finer grid (the search's
        // grid, half a semi-axis, is too coarse for a sharp texture to correlate).
        // (The correlations are computed only when the template may recognise a candidate.)
        let ranked = self
            .cfg
            .reacquire_ncc
            .and_then(|_| self.template_correlations(gray, &cands))
            .map(|ncc| best_by_template(&rhos, &ncc, self.cfg.reacquire_rho, TEMPLATE_REFINED))
            .unwrap_or_default();
        let recognised = self.cfg.reacquire_ncc.and_then(|min_ncc| {
            ranked
                .iter()
                .filter_map(|&(i, _)| self.refine_by_template(gray, &cands[i]))
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .filter(|&(_, n)| f64::from(n) >= min_ncc)
        });
        if let Some((p, _)) = recognised {
            return self.verify_candidate(frame, gray, est, p, true);
        }
        // None recognised: each candidate is verified by its features.
        for i in verification_order(best, &ranked, self.cfg.reacquire_rho) {
            if let Some(found) = self.verify_candidate(frame, gray, est, cands[i], false)? {
                return Ok(Some(found));
            }
        }
        Ok(None)
    }

    /// The likelihood settings and input a re-acquisition scores candidates with: the colour
    /// term, and the contrast term summed over the initial ellipse's area for every size;
    /// no features.
    fn search_terms<'a>(&self, frame: &'a image::RgbImage) -> (LikelihoodParams, FrameInput<'a>) {
        let mut lp = self.likelihood;
        lp.terms = TERM_COLOUR;
        self.enable_contrast(&mut lp, self.first_outline.a * self.first_outline.b);
        let input = FrameInput {
            image: frame,
            features: &[],
            depths: None,
            prev: self.prev.to_particle(),
            theta0: self.theta0 as f32,
        };
        (lp, input)
    }

    /// A re-acquisition candidate `chosen` verified ([`Self::reacquire`]): its features fitted
    /// to one of the keyframes place it, or, `recognised` by the templates, it stands where
    /// it was found when they fit none; then it must lie where it was searched and pass the
    /// found target's tests. The target so placed with its own confidence, or `None`.
    fn verify_candidate(
        &mut self,
        frame: &image::RgbImage,
        gray: &GrayF32,
        est: &Hypothesis,
        chosen: Particle,
        recognised: bool,
    ) -> crate::Result<Option<(Hypothesis, f64)>> {
        let (w, h) = self.size;
        let (lp, input) = self.search_terms(frame);
        let found = Hypothesis {
            cx: chosen.cx as f64,
            cy: chosen.cy as f64,
            a: chosen.a as f64,
            b: chosen.b as f64,
            rot: est.rot,
        };
        // Colour alone is not enough: another object of the target's colours (a brown box
        // for a face) is not the target. The candidate must be recognised: its features
        // fitted to one of the keyframes (the fit then places the target), or its grey levels
        // by both templates (above).
        let e = found.to_state().ellipse(self.theta0);
        let region = search_region(&e, w, h);
        let features = self.detect_features(&e, gray, region)?;
        let camera = self.camera();
        let ctx = FitContext {
            // Any pose, with no prior: the candidate's rotation is unknown.
            max_step: std::f64::consts::PI,
            prior: None,
            ..self.fit_context(&found, nalgebra::Vector2::zeros(), camera.as_ref())
        };
        let fit = self
            .keyframes
            .best_fit(&features, &ctx, KEYFRAMES, std::f64::consts::PI);
        // Its features place it when they fit; a candidate the template recognised stands
        // where it was found when they do not (a small target has too few for a fit).
        let fitted = fit.is_some();
        let Some(placed) = fit.map(|k| k.placed()).or(recognised.then_some(found)) else {
            return Ok(None);
        };
        // The fit may place the target only where its evidence came from, and the target so
        // placed must still look like it: a fit to a few stray matches can put a target
        // larger than the frame beside it (seen on OTB car4: a 1230 px ellipse centred at
        // (-290, -198), reported found).
        if !placed_within(&placed.to_state().ellipse(self.theta0), &e, &region) {
            return Ok(None);
        }
        // The frame will report the target found, so its confidence is the found target's
        // own, not the lost track's, lowered as any is where no features measured the
        // rotation (a candidate the templates alone recognised stands in the trusted pose);
        // one evaluation gives the colour test and the confidence.
        let (rho, c) = self.own_confidence(&input, lp, &placed, fitted)?;
        Ok(reacquired(&self.cfg, rho, c).then_some((placed, c)))
    }
}

/// Whether a re-acquisition candidate placed with colour similarity `rho` and confidence `c`
/// is taken as the target found: of the target's colours ([`TrackerConfig::reacquire_rho`])
/// and as confident as a lost track must be to count as found
/// ([`TrackerConfig::found_above`]). A re-acquisition clears the lost flag, so it meets the
/// same bar as the track's own frames: at [`TrackerConfig::lost_below`] a found target at
/// the corner of OTB girl's frame, 0.31, half outside it, was taken and followed for the
/// rest of the sequence at 0.3-0.5 (filter seed 11).
fn reacquired(cfg: &TrackerConfig, rho: f64, c: f64) -> bool {
    rho >= cfg.reacquire_rho && c >= cfg.found_above
}

/// The tracker's lost state after a frame of confidence `c`, from `low` (consecutive frames
/// below [`TrackerConfig::lost_below`], or more while lost) and `lost`: a frame below
/// `lost_below` counts one more; a lost target stays lost, and `low` where it was, until a
/// frame reaches [`TrackerConfig::found_above`] where the target is `recognised`
/// ([`Tracker::recognised_at`]); otherwise the count starts over. The target is declared
/// lost once `low` reaches [`TrackerConfig::lost_after`] (the caller then searches for it).
pub(super) fn lost_state(
    cfg: &TrackerConfig,
    low: usize,
    lost: bool,
    c: f64,
    recognised: bool,
) -> (usize, bool) {
    if c < cfg.lost_below {
        let low = low.saturating_add(1);
        (low, lost || low >= cfg.lost_after)
    } else if lost && (c < cfg.found_above || !recognised) {
        (low, true)
    } else {
        (0, false)
    }
}

/// The candidates a re-acquisition that no template recognised verifies by their features,
/// in order: the `best` by colour (its index and colour similarity) where its similarity
/// reaches `min_rho`, then those the templates rank best (`ranked`, best first), each once.
/// The best by colour alone is not enough: on grey footage it is as often a patch of trees
/// as the target, and on car4 trying it alone never found the car again.
fn verification_order(
    best: Option<(usize, f64)>,
    ranked: &[(usize, f32)],
    min_rho: f64,
) -> Vec<usize> {
    let mut order: Vec<usize> = best
        .filter(|&(_, rho)| rho >= min_rho)
        .map(|(i, _)| i)
        .into_iter()
        .collect();
    for &(i, _) in ranked {
        if !order.contains(&i) {
            order.push(i);
        }
    }
    order
}

/// Among re-acquisition candidates with colour similarities `rho` and template correlations
/// `ncc`, the `k` that correlate best among those of at least `min_rho`, best first, with
/// their correlations.
fn best_by_template(rho: &[f64], ncc: &[f32], min_rho: f64, k: usize) -> Vec<(usize, f32)> {
    let mut ranked: Vec<(usize, f32)> = rho
        .iter()
        .zip(ncc)
        .enumerate()
        .filter(|(_, (r, n))| **r >= min_rho && n.is_finite())
        .map(|(i, (_, &n))| (i, n))
        .collect();
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    ranked.truncate(k);
    ranked
}

/// The ellipses about each of `around`, in order: for each size `2^o` times its semi-axes
/// (`o` in `octaves`), the centres `step` apart on a square grid `reach` either way, row by
/// row. The local searches of the re-acquisition and the re-anchoring place the templates on
/// it.
fn local_grid(around: &[Particle], step: f32, reach: i32, octaves: &[f32]) -> Vec<Particle> {
    let side = (2 * reach + 1) as usize;
    let mut out = Vec::with_capacity(around.len() * side * side * octaves.len());
    for p in around {
        for &o in octaves {
            let s = o.exp2();
            for j in -reach..=reach {
                for i in -reach..=reach {
                    out.push(Particle {
                        cx: p.cx + i as f32 * step,
                        cy: p.cy + j as f32 * step,
                        a: p.a * s,
                        b: p.b * s,
                        ..*p
                    });
                }
            }
        }
    }
    out
}

/// The step of a re-acquisition's grid for ellipses of semi-axes `a`, `b`: half the smaller
/// semi-axis, at least 2 px.
fn search_step(a: f64, b: f64) -> f64 {
    (0.5 * a.min(b)).max(2.0)
}

/// The candidates of a re-acquisition in a `w x h` frame: for each of [`REACQUIRE_SCALES`],
/// ellipses of `reference`'s semi-axes times the scale, centred on a grid from the frame's
/// corner with a step of half the smaller semi-axis (at least 2 px), at angles `e`.
fn search_grid(reference: &Ellipse, w: u32, h: u32, e: &Euler) -> Vec<Particle> {
    let mut cands = Vec::new();
    for scale in REACQUIRE_SCALES {
        let (a, b) = (scale * reference.a, scale * reference.b);
        let step = search_step(a, b);
        let mut y = 0.0;
        while y < h as f64 {
            let mut x = 0.0;
            while x < w as f64 {
                cands.push(Particle {
                    cx: x as f32,
                    cy: y as f32,
                    a: a as f32,
                    b: b as f32,
                    rx: e.rx as f32,
                    ry: e.ry as f32,
                    rz: e.rz as f32,
                    _pad: 0.0,
                });
                x += step;
            }
            y += step;
        }
    }
    cands
}

/// Whether `placed`, the target as a re-acquisition fit places it, lies where that fit's
/// features were searched: its centre inside `region` (the search region around the colour
/// candidate `searched`, clipped to the frame), and each semi-axis at most half the extent of
/// that region before clipping, so no bigger than the largest target it can hold.
fn placed_within(placed: &Ellipse, searched: &Ellipse, region: &BoxRect) -> bool {
    let inside = placed.cx >= region.x
        && placed.cx <= region.x + region.w
        && placed.cy >= region.y
        && placed.cy <= region.y + region.h;
    let bb = placed.bounding_box();
    let sb = searched.bounding_box();
    let m = search_margin(searched);
    inside && bb.w <= sb.w + 2.0 * m && bb.h <= sb.h + 2.0 * m
}

#[cfg(test)]
mod tests {
    use super::super::tests::{in_place, nod_first, nod_tracker};
    use super::*;
    use crate::geometry::angle_between;
    use nalgebra::Matrix3;

    #[test]
    fn the_lost_flag_needs_lost_after_low_frames_and_clears_only_above_found_above() {
        let cfg = TrackerConfig::default();
        let (below, band, above) = (0.1, 0.3, 0.6);
        assert!(below < cfg.lost_below && band >= cfg.lost_below && band < cfg.found_above);
        assert!(above >= cfg.found_above && cfg.lost_after == 3);
        let run = |cs: &[f64]| {
            let mut s = (0, false);
            cs.iter()
                .map(|&c| {
                    s = lost_state(&cfg, s.0, s.1, c, true);
                    s
                })
                .collect::<Vec<_>>()
        };
        // Not yet lost: a frame in the band starts the count over.
        assert_eq!(
            run(&[below, below, band, below, below]),
            [(1, false), (2, false), (0, false), (1, false), (2, false)]
        );
        // Lost on the third low frame; frames in the band keep it lost (and searched for,
        // the count staying at `lost_after`), and only a frame above `found_above` clears it.
        assert_eq!(
            run(&[below, below, below, band, band, below, above, band]),
            [
                (1, false),
                (2, false),
                (3, true),
                (3, true),
                (3, true),
                (4, true),
                (0, false),
                (0, false)
            ]
        );
        // With `found_above` at `lost_below`, the first frame in the band clears it.
        let old = TrackerConfig {
            found_above: cfg.lost_below,
            ..cfg.clone()
        };
        assert_eq!(lost_state(&old, 3, true, band, true), (0, false));
        // A frame above `found_above` where the target is not recognised keeps it lost; one
        // that is not lost needs no recognising.
        assert_eq!(lost_state(&cfg, 3, true, above, false), (3, true));
        assert_eq!(lost_state(&cfg, 1, false, above, false), (0, false));
    }

    #[test]
    fn a_local_grid_runs_over_centres_then_sizes_then_starts() {
        let p = |cx: f32| Particle {
            cx,
            cy: 10.0,
            a: 4.0,
            b: 2.0,
            ..Particle::default()
        };
        let g = local_grid(&[p(0.0), p(100.0)], 0.5, 1, &[-1.0, 0.0]);
        assert_eq!(g.len(), 2 * 2 * 9);
        // Row by row from the top left, at half size first, then the next start.
        assert_eq!((g[0].cx, g[0].cy, g[0].a, g[0].b), (-0.5, 9.5, 2.0, 1.0));
        assert_eq!((g[1].cx, g[1].cy), (0.0, 9.5));
        assert_eq!((g[3].cx, g[3].cy), (-0.5, 10.0));
        assert_eq!((g[13].cx, g[13].cy, g[13].a), (0.0, 10.0, 4.0));
        assert_eq!((g[18].cx, g[18].a), (99.5, 2.0));
    }

    #[test]
    fn a_reacquired_target_needs_the_colours_and_the_confidence_of_a_found_track() {
        let cfg = TrackerConfig::default();
        let (rho, band) = (cfg.reacquire_rho, 0.5 * (cfg.lost_below + cfg.found_above));
        assert!(band >= cfg.lost_below && band < cfg.found_above);
        assert!(reacquired(&cfg, rho, cfg.found_above));
        assert!(reacquired(&cfg, 1.0, 1.0));
        // Confident enough to keep a track, not to find one.
        assert!(!reacquired(&cfg, 1.0, band));
        // Confident, but not of the target's colours.
        assert!(!reacquired(&cfg, rho - 0.01, 1.0));
        // With `found_above` at `lost_below`, the lower bar.
        let old = TrackerConfig {
            found_above: cfg.lost_below,
            ..cfg.clone()
        };
        assert!(reacquired(&old, rho, band));
    }

    #[test]
    fn the_template_ranks_the_candidates_of_the_targets_colours_by_correlation() {
        let rho = [0.95, 0.85, 0.6, 0.9, 0.81, 0.99];
        let ncc = [0.3, 0.7, 0.9, f32::NAN, 0.5, 0.5];
        // Candidate 2 correlates best but has other colours; 3's correlation is unusable;
        // ties go to the earlier candidate.
        assert_eq!(
            best_by_template(&rho, &ncc, 0.8, 3),
            [(1, 0.7), (4, 0.5), (5, 0.5)]
        );
        assert_eq!(best_by_template(&rho, &ncc, 0.8, 1), [(1, 0.7)]);
        // Nothing of the target's colours, nothing ranked.
        assert!(best_by_template(&rho, &ncc, 0.995, 3).is_empty());
        assert!(best_by_template(&[], &[], 0.0, 3).is_empty());
    }

    #[test]
    fn candidates_are_verified_best_by_colour_first_then_as_the_templates_rank_them() {
        let ranked = [(4, 0.7), (2, 0.5), (9, 0.4)];
        // The best by colour first, then the ranked ones not yet tried.
        assert_eq!(
            verification_order(Some((7, 0.9)), &ranked, 0.8),
            [7, 4, 2, 9]
        );
        assert_eq!(verification_order(Some((2, 0.9)), &ranked, 0.8), [2, 4, 9]);
        // A best by colour under the bar is not tried; the ranked ones still are.
        assert_eq!(verification_order(Some((7, 0.7)), &ranked, 0.8), [4, 2, 9]);
        assert_eq!(verification_order(None, &ranked, 0.8), [4, 2, 9]);
        // Without templates, the best by colour alone.
        assert_eq!(verification_order(Some((7, 0.9)), &[], 0.8), [7]);
        assert!(verification_order(None, &[], 0.8).is_empty());
    }

    #[test]
    fn an_estimate_off_the_first_view_is_reanchored_on_it_in_the_first_pose() {
        let (t, gray, init) = nod_tracker(TrackerConfig::default());
        // On the first frame itself, 4 px right and 3 px up, turned 20° about x and y and
        // rolled 15°: the first view turned so matches the frame poorly there.
        let off = Hypothesis {
            cx: init.cx + 4.0,
            cy: init.cy - 3.0,
            a: init.a * 1.1,
            b: init.b * 1.1,
            rot: Euler::new(0.35, 0.35, 0.26).matrix(),
        };
        let found = t.reanchor(&gray, &off, 1.0).expect("re-anchored");
        let miss = (found.cx - init.cx).hypot(found.cy - init.cy);
        assert!(miss < 1.0, "found {miss:.2} px from the first view");
        assert!(angle_between(&found.rot, &Matrix3::identity()) < 1e-9);
        // The estimate's area, the first ellipse's aspect.
        assert!((found.a * found.b - off.a * off.b).abs() < 1e-3 * off.a * off.b);
        assert!((found.b / found.a - init.b / init.a).abs() < 1e-6);
        // Not when unsure, nor when switched off.
        assert!(t.reanchor(&gray, &off, 0.49).is_none());
        let (t_off, gray_off, _) = nod_tracker(TrackerConfig {
            reanchor: None,
            ..TrackerConfig::default()
        });
        assert!(t_off.reanchor(&gray_off, &off, 1.0).is_none());
        // Started turned, the first view is found at the outline seen at the start, in its
        // pose (not at the object's frontal outline, the model's reference).
        let (first, _) = nod_first();
        let turned = Euler::new(0.2, 0.5, 0.0);
        let t = Tracker::new(
            TrackerConfig::default(),
            &first,
            super::super::Init {
                ellipse: init,
                pose: turned,
            },
        )
        .unwrap();
        assert!((t.reference.b / t.reference.a - init.b / init.a).abs() > 0.01);
        let off = Hypothesis {
            rot: turned.matrix() * Euler::new(0.35, 0.35, 0.26).matrix(),
            ..off
        };
        let found = t.reanchor(&gray, &off, 1.0).expect("re-anchored");
        assert!(angle_between(&found.rot, &turned.matrix()) < 1e-6);
        assert!((found.b / found.a - init.b / init.a).abs() < 1e-6);
    }

    #[test]
    fn an_estimate_turned_away_from_the_first_view_is_turned_back() {
        let (t, gray, init) = nod_tracker(TrackerConfig::default());
        // On the first frame itself, in place, tilted 15° and panned −20° away from the
        // first pose: the first view turned so correlates poorly; turned back, fully.
        let off = in_place(&init, 0.26, -0.35);
        let found = t.repose(&gray, &off, 1.0).expect("turned back");
        let miss = angle_between(&found.rot, &Matrix3::identity()).to_degrees();
        assert!(miss < 2.0, "turned back to {miss:.2}° from the first pose");
        // Place and size are the estimate's.
        assert_eq!(
            (found.cx, found.cy, found.a, found.b),
            (off.cx, off.cy, off.a, off.b)
        );
        // Not when unsure, not when the estimate already explains the first view, and not
        // with the re-anchoring off.
        assert!(t.repose(&gray, &off, 0.49).is_none());
        let on = Hypothesis {
            rot: Matrix3::identity(),
            ..off
        };
        assert!(t.repose(&gray, &on, 1.0).is_none());
        let (t_off, gray_off, _) = nod_tracker(TrackerConfig {
            reanchor: None,
            ..TrackerConfig::default()
        });
        assert!(t_off.repose(&gray_off, &off, 1.0).is_none());
    }

    #[test]
    fn a_turn_back_of_less_than_a_step_is_left_to_the_filter() {
        // A bar the estimate's own correlation misses even a few degrees off the first pose,
        // so that only the rule on the step decides.
        let strict = Reanchor {
            min_ncc: 0.97,
            margin: 0.01,
            ..Reanchor::default()
        };
        let (t, gray, init) = nod_tracker(TrackerConfig {
            reanchor: Some(strict),
            ..TrackerConfig::default()
        });
        let at =
            |rx_deg: f64, ry_deg: f64| in_place(&init, rx_deg.to_radians(), ry_deg.to_radians());
        // 3° off on both axes: the first pose, where the correlation is highest, is less than
        // a step away.
        let near = at(3.0, -3.0);
        let (_, explained) = t.first_view_at(&gray, &near, 1.0).expect("re-anchoring on");
        assert!(
            explained < strict.min_ncc - strict.margin,
            "the test needs the bar missed at 3°: {explained:.3}"
        );
        assert!(t.repose(&gray, &near, 1.0).is_none());
        // 10° off on both axes: two steps away, turned back.
        let found = t.repose(&gray, &at(10.0, -10.0), 1.0).expect("turned back");
        let miss = angle_between(&found.rot, &Matrix3::identity()).to_degrees();
        assert!(miss < 2.0, "turned back to {miss:.2}° from the first pose");
    }

    #[test]
    fn an_estimate_that_explains_the_first_view_is_left_alone() {
        let (t, gray, init) = nod_tracker(TrackerConfig::default());
        let on = in_place(&init, 0.0, 0.0);
        // The first view is found where the estimate is (correlation 1 at the estimate), so
        // nothing beats it by the margin.
        assert!(t.reanchor(&gray, &on, 1.0).is_none());
        // A small turn the first view still correlates with closely is not re-anchored either.
        let near = Hypothesis {
            rot: Euler::new(0.02, -0.02, 0.0).matrix(),
            ..on
        };
        assert!(t.reanchor(&gray, &near, 1.0).is_none());
    }

    #[test]
    fn a_reacquired_target_must_lie_in_the_region_searched() {
        // Candidate 20 x 10 semi-axes at (100, 60): box 40 x 20, margin 18, so the region
        // before clipping is 76 x 56 px, [62, 138] x [32, 88].
        let cand = Ellipse::new(100.0, 60.0, 20.0, 10.0);
        let region = search_region(&cand, 320, 240);
        assert_eq!(
            (region.x, region.y, region.w, region.h),
            (62.0, 32.0, 76.0, 56.0)
        );
        let edge = Ellipse::new(10.0, 60.0, 20.0, 10.0);
        let clipped = search_region(&edge, 320, 240);
        assert_eq!(clipped.x, 0.0);
        let e = Ellipse::new;
        // (placed, candidate searched, its region, expected)
        let cases = [
            (cand, cand, region, true),
            // Moved within the region, and grown to fill it exactly.
            (e(130.0, 40.0, 20.0, 10.0), cand, region, true),
            (e(100.0, 60.0, 38.0, 28.0), cand, region, true),
            // Centre outside it, or larger than it can hold, on either axis.
            (e(140.0, 60.0, 20.0, 10.0), cand, region, false),
            (e(100.0, 30.0, 20.0, 10.0), cand, region, false),
            (e(100.0, 60.0, 38.5, 10.0), cand, region, false),
            (e(100.0, 60.0, 20.0, 28.5), cand, region, false),
            // The car4 case: a huge ellipse centred off the frame.
            (e(-290.0, -198.0, 615.0, 538.0), cand, region, false),
            // Clipping at the frame's edge limits where the centre may be, not the size.
            (e(5.0, 60.0, 38.0, 28.0), edge, clipped, true),
            (e(-1.0, 60.0, 20.0, 10.0), edge, clipped, false),
            // NaN is never inside.
            (e(f64::NAN, 60.0, 20.0, 10.0), cand, region, false),
        ];
        for (placed, searched, region, want) in cases {
            assert_eq!(
                placed_within(&placed, &searched, &region),
                want,
                "{placed:?} in {region:?}"
            );
        }
    }

    #[test]
    fn a_reacquisition_searches_the_whole_frame_at_five_sizes_of_the_initial_ellipse() {
        // 20 x 12 semi-axes in a 100 x 60 frame: steps 3 (6 x 0.5), 4.24, 6, 8.49, 12 px.
        let reference = Ellipse::new(30.0, 20.0, 20.0, 12.0);
        let e = Euler::from_degrees(10.0, -20.0, 5.0);
        let cands = search_grid(&reference, 100, 60, &e);
        let per_axis = |len: f64, step: f64| (len / step).ceil() as usize;
        let mut expected = 0;
        for scale in REACQUIRE_SCALES {
            let (a, b) = (20.0 * scale, 12.0 * scale);
            let step = 0.5 * b;
            let these: Vec<&Particle> = cands
                .iter()
                .filter(|p| (p.a as f64 - a).abs() < 1e-4 && (p.b as f64 - b).abs() < 1e-4)
                .collect();
            assert_eq!(
                these.len(),
                per_axis(100.0, step) * per_axis(60.0, step),
                "{scale}"
            );
            // The grid reaches across the frame, from the corner to within a step of the far
            // sides.
            let max_x = these.iter().map(|p| p.cx).fold(0.0f32, f32::max) as f64;
            let max_y = these.iter().map(|p| p.cy).fold(0.0f32, f32::max) as f64;
            assert!(these.iter().any(|p| p.cx == 0.0 && p.cy == 0.0));
            assert!(
                max_x < 100.0 && max_x >= 100.0 - step - 1e-3,
                "{scale}: {max_x}"
            );
            assert!(
                max_y < 60.0 && max_y >= 60.0 - step - 1e-3,
                "{scale}: {max_y}"
            );
            expected += these.len();
        }
        assert_eq!(cands.len(), expected);
        assert!(
            cands
                .iter()
                .all(|p| p.rx == e.rx as f32 && p.ry == e.ry as f32 && p.rz == e.rz as f32)
        );
        // A tiny reference still steps by at least 2 px.
        let tiny = search_grid(&Ellipse::new(5.0, 5.0, 1.0, 1.0), 10, 10, &e);
        assert_eq!(tiny.len(), 5 * 25);
    }
}
