//! Keyframes: reference views the rotation is measured against (drift control beyond the
//! paper, SPEC section 6).
//!
//! Matching against a reference view rather than only against the previous frame lets
//! out-of-plane rotation show as parallax that grows with the angle, where between successive
//! frames it is below the noise (`cos 1° = 0.9998`). The pool keeps several views: the first
//! one, whose pose is known exactly, and those taken as the object turned away from the
//! others. Each frame is fitted against the views nearest the predicted pose and the best fit
//! wins, so a target that turns back is measured against the older, better-anchored views
//! again instead of the error of every view taken in between.

use nalgebra::{Matrix3, Vector2, Vector3};

use crate::features::{Features, MatchParams, match_features};
use crate::filter::Hypothesis;
use crate::geometry::{Ellipse, angle_between};
use crate::likelihood::FeaturePair;
use crate::pose::bundle::{BundleView, refine, relieved};
use crate::pose::prior::{
    Ellipsoid, FitStart, MotionPrior, Pinhole, PriorFit, fit_points, fit_with_depth_prior, lift,
};
use crate::tracker::{AnchorRefit, BundleAdjust};

/// One reference view.
#[derive(Debug, Clone)]
struct Keyframe {
    /// Features of the view inside its ellipse.
    features: Features,
    /// The estimate when the view was taken.
    hyp: Hypothesis,
    /// The object model in this view.
    model: Ellipsoid,
    /// Inlier matches found against it on the first frame after it was taken.
    initial_inliers: Option<usize>,
    /// The frame it was taken in.
    frame: usize,
    /// Later views of it, their poses and what they saw (for the bundle adjustment).
    views: Vec<BundleView>,
    /// Its features' 3D points refined by bundle adjustment; `None`: lifted onto `model`.
    points: Option<Vec<Vector3<f64>>>,
    /// Views added since the last adjustment.
    since_adjusted: usize,
    /// What its last adjustment said of the object's relief ([`KeyframePool::relief`]).
    relief: Evidence,
}

/// Evidence on the object's log-relief `ln k` (its depths against its model's), as a
/// Gaussian in information form: `(1 / σ², ln k / σ²)`, so that pieces add.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Evidence {
    /// `1 / σ²`.
    information: f64,
    /// `ln k / σ²`.
    weighted: f64,
}

impl Evidence {
    fn add(self, o: Self) -> Self {
        Self {
            information: self.information + o.information,
            weighted: self.weighted + o.weighted,
        }
    }

    /// The mean `ln k`, 0 without information.
    fn log(&self) -> f64 {
        if self.information > 0.0 {
            self.weighted / self.information
        } else {
            0.0
        }
    }
}

/// What a fit against a keyframe needs from the tracker.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FitContext<'a> {
    /// The previous frame's estimate (the prediction's starting point).
    pub prev: &'a Hypothesis,
    /// The translation predicted for this frame (block matching).
    pub shift: Vector2<f64>,
    /// The camera, `None` for weak perspective.
    pub camera: Option<&'a Pinhole>,
    /// Feature matching.
    pub matching: &'a MatchParams,
    /// Fewest inliers of an accepted fit.
    pub min_inliers: usize,
    /// Largest RMS residual (pixels) of an accepted fit.
    pub max_residual: f64,
    /// Largest rotation (radians) from the previous estimate an accepted fit may imply.
    pub max_step: f64,
    /// The motion prior; each fit puts its mean at its own start (the previous estimate,
    /// seen from the keyframe). `None` for no prior.
    pub prior: Option<MotionPrior>,
    /// The free fit against the anchor that may replace the best one; `None` for none.
    pub anchor_refit: Option<AnchorRefit>,
    /// The factor the lifted depths' relief is scaled by ([`KeyframePool::relief`]; 1: the
    /// model's own).
    pub relief: f64,
}

/// An accepted fit against one keyframe.
#[derive(Debug, Clone)]
pub(crate) struct KeyFit {
    /// The keyframe's estimate.
    pub key: Hypothesis,
    /// The fit (rotation from the keyframe's pose, scale relative to it, centre).
    pub fit: PriorFit,
    /// The keyframe's scale relative to the previous frame's (`sqrt(ab)` ratio).
    pub prev_scale: f64,
    /// The inlier matches, keyframe → current frame.
    pub pairs: Vec<FeaturePair>,
    /// The keyframe feature of each inlier match.
    query: Vec<usize>,
    /// Which keyframe.
    index: usize,
}

impl KeyFit {
    /// The target as this fit places it in the current frame: the fitted centre, the
    /// keyframe's ellipse scaled by the fit, and the keyframe's rotation carried on by the
    /// fitted one.
    pub fn placed(&self) -> Hypothesis {
        Hypothesis {
            cx: self.fit.centre.x,
            cy: self.fit.centre.y,
            a: self.key.a * self.fit.scale,
            b: self.key.b * self.fit.scale,
            rot: self.fit.rot * self.key.rot,
        }
    }
}

/// Fits the view of `model` to the matches `pairs` (its points → the current frame) from the
/// start `(rot0, scale0)` and the predicted centre `prev + shift`, and keeps the fit only when
/// it is plausible: enough inliers, a small residual, and no more rotation from `rot0` than
/// the tracker follows between two frames. Returns the fit and its inlier matches.
pub(crate) fn accepted_fit(
    pairs: &[FeaturePair],
    model: &Ellipsoid,
    ctx: &FitContext<'_>,
    rot0: &Matrix3<f64>,
    scale0: f64,
) -> Option<(PriorFit, Vec<FeaturePair>)> {
    accepted_fit_on(pairs, None, model, ctx, rot0, scale0).map(|(f, p, _)| (f, p))
}

/// [`accepted_fit`] on the given 3D points of the matches' first positions, when there are
/// some, instead of their lift onto `model`; also returns the inliers' positions in `pairs`.
fn accepted_fit_on(
    pairs: &[FeaturePair],
    points: Option<&[Vector3<f64>]>,
    model: &Ellipsoid,
    ctx: &FitContext<'_>,
    rot0: &Matrix3<f64>,
    scale0: f64,
) -> Option<(PriorFit, Vec<FeaturePair>, Vec<usize>)> {
    let (p, q) = FeaturePair::split(pairs);
    let start = FitStart {
        rot: *rot0,
        scale: scale0,
        centre: Vector2::new(ctx.prev.cx, ctx.prev.cy) + ctx.shift,
    };
    // The prior's mean is the start: the previous estimate, seen from the keyframe.
    let prior = ctx.prior.map(|pr| MotionPrior { mean: *rot0, ..pr });
    let fit = match points {
        Some(x) => fit_points(x, &q, ctx.camera, &start, prior.as_ref()),
        None if ctx.relief != 1.0 && model.is_valid() => {
            let x = relieved(
                &lift(&p, model, ctx.camera),
                ctx.relief,
                ctx.camera,
                &model.centre,
            );
            fit_points(&x, &q, ctx.camera, &start, prior.as_ref())
        }
        None => fit_with_depth_prior(&p, &q, model, ctx.camera, &start, prior.as_ref()),
    }
    .ok()?;
    let which: Vec<usize> = (0..pairs.len()).filter(|&j| fit.inliers[j]).collect();
    let inliers: Vec<FeaturePair> = which.iter().map(|&j| pairs[j]).collect();
    let step = angle_between(&fit.rot, rot0);
    // Written so that a residual or step that is not a number fails the test.
    if inliers.len() < ctx.min_inliers
        || !(fit.residual.is_finite() && fit.residual <= ctx.max_residual)
        || !(step.is_finite() && step <= ctx.max_step)
    {
        return None;
    }
    Some((fit, inliers, which))
}

/// The evidence an adjustment gave on the log-relief of its own: its posterior `r` (relative
/// to its start `log0`) less the prior it was held to, `N(log0, 1 / information0)`; none
/// where the posterior knows no more than that prior.
fn own_evidence(log0: f64, information0: f64, r: crate::pose::bundle::Relief) -> Evidence {
    let information = 1.0 / r.variance - information0;
    if !(information > 0.0 && information.is_finite()) {
        return Evidence::default();
    }
    Evidence {
        information,
        weighted: (log0 + r.log) / r.variance - information0 * log0,
    }
}

/// The pool of keyframes.
#[derive(Debug, Clone, Default)]
pub(crate) struct KeyframePool {
    frames: Vec<Keyframe>,
    capacity: usize,
    /// The frame being tracked (for the keyframes taken and the views recorded).
    now: usize,
    /// The relief evidence of keyframes that gave way to others.
    retired: Evidence,
}

impl KeyframePool {
    /// An empty pool holding at most `capacity` (at least 2: the anchor and one more)
    /// keyframes.
    pub fn new(capacity: usize) -> Self {
        Self {
            frames: Vec::new(),
            // The anchor and at least one keyframe beside it: with room for one alone, a new
            // keyframe replaced the anchor, which is never to be dropped.
            capacity: capacity.max(2),
            now: 0,
            retired: Evidence::default(),
        }
    }

    /// The factor by which the object's relief differs from its model's, as the keyframes'
    /// adjustments found it ([`crate::pose::bundle::BundleParams::relief_sigma`]): each
    /// keyframe's last adjustment and those of keyframes that gave way, pooled with the prior
    /// `ln k ~ N(0, σ²)`. 1 without the setting or before any adjustment. The keyframe fits
    /// scale their lifted depths by it ([`FitContext::relief`]).
    pub fn relief(&self, cfg: &BundleAdjust) -> f64 {
        self.relief_log(cfg, None).0.exp()
    }

    /// The pooled `ln k` and its information, leaving out keyframe `except`'s evidence (the
    /// prior of that keyframe's next adjustment, which gives its evidence anew); `(0, 0)`
    /// without the setting.
    fn relief_log(&self, cfg: &BundleAdjust, except: Option<usize>) -> (f64, f64) {
        let Some(sigma) = cfg.params.relief_sigma else {
            return (0.0, 0.0);
        };
        let prior = Evidence {
            information: 1.0 / (sigma * sigma),
            weighted: 0.0,
        };
        let e = self
            .frames
            .iter()
            .enumerate()
            .filter(|(i, _)| Some(*i) != except)
            .fold(prior.add(self.retired), |e, (_, k)| e.add(k.relief));
        (e.log(), e.information)
    }

    /// Sets the frame being tracked.
    pub fn tick(&mut self, frame: usize) {
        self.now = frame;
    }

    /// Records the view `fit` gave of its keyframe and, every [`BundleAdjust::every`] views
    /// once there are [`BundleAdjust::min_views`] spanning [`BundleAdjust::min_turn`],
    /// adjusts the keyframe's feature depths and its views' poses together
    /// ([`crate::pose::bundle`]). Later fits against the keyframe use the adjusted points.
    /// Returns the adjusted pose of this view when the keyframe was adjusted.
    ///
    /// The anchor is never adjusted: its views span the whole track, and where the target
    /// only moved they read a few degrees of turn the adjustment cannot take back (see
    /// [`crate::tracker::TrackerConfig::bundle`]).
    pub fn observe(
        &mut self,
        fit: &KeyFit,
        camera: Option<&Pinhole>,
        cfg: &BundleAdjust,
    ) -> Option<BundleView> {
        if fit.index == 0 {
            return None;
        }
        let key = self.frames.get_mut(fit.index)?;
        let seen = fit
            .query
            .iter()
            .zip(&fit.pairs)
            .map(|(&j, p)| (j, [f64::from(p.q[0]), f64::from(p.q[1])]))
            .collect();
        key.views.push(BundleView {
            frame: self.now,
            rot: fit.fit.rot,
            scale: fit.fit.scale,
            centre: fit.fit.centre,
            seen,
        });
        if key.views.len() > cfg.max_views.max(2) {
            // Thin out the view closest in rotation to the one before it (never the newest).
            let n = key.views.len();
            let gap = |i: usize| angle_between(&key.views[i].rot, &key.views[i - 1].rot);
            if let Some(drop) = (1..n - 1).min_by(|&a, &b| gap(a).total_cmp(&gap(b))) {
                key.views.remove(drop);
            }
        }
        key.since_adjusted += 1;
        let turn = key
            .views
            .iter()
            .map(|v| angle_between(&v.rot, &Matrix3::identity()))
            .fold(0.0, f64::max);
        if key.views.len() < cfg.min_views || key.since_adjusted < cfg.every || turn < cfg.min_turn
        {
            return None;
        }
        key.since_adjusted = 0;
        let p: Vec<[f64; 2]> = key
            .features
            .keypoints
            .iter()
            .map(|k| [f64::from(k.x), f64::from(k.y)])
            .collect();
        // The relief the other keyframes found is this adjustment's start and prior.
        let (log0, information0) = self.relief_log(cfg, Some(fit.index));
        let key = &mut self.frames[fit.index];
        let mut params = cfg.params;
        let mut x0 = lift(&p, &key.model, camera);
        if params.relief_sigma.is_some() {
            x0 = relieved(&x0, log0.exp(), camera, &key.model.centre);
            params.relief_sigma = Some(information0.sqrt().recip());
        }
        let mut views = key.views.clone();
        let adjusted = refine(
            &x0,
            &key.model.centre,
            key.frame,
            camera,
            &mut views,
            &params,
        )
        .ok()?;
        key.points = Some(adjusted.points);
        key.views = views;
        // Its own evidence: the posterior less the prior it started from. Where the
        // adjustment could not measure the relief, the keyframe's earlier evidence goes too.
        key.relief = adjusted
            .relief
            .map_or(Evidence::default(), |r| own_evidence(log0, information0, r));
        key.views.last().cloned()
    }

    /// Empties the pool and makes `features` (inside `e`, at `hyp`, object `model`) the
    /// anchor view.
    pub fn reset(&mut self, features: &Features, e: &Ellipse, hyp: Hypothesis, model: Ellipsoid) {
        self.frames.clear();
        self.retired = Evidence::default();
        self.frames.push(make(features, e, hyp, model, self.now));
    }

    /// Features of the anchor, the first view (0 before there is one).
    pub fn anchor_features(&self) -> usize {
        self.frames
            .first()
            .map_or(0, |k| k.features.keypoints.len())
    }

    /// Number of keyframes held.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Fits the current features against the keyframes nearest the previous estimate (at most
    /// `tries` of them, all within `reach` radians) and returns the accepted fit with the most
    /// inliers (fewer residual pixels on a tie). With `ctx.anchor_refit`, a free fit against
    /// the anchor (no prior, no bound on the step) that passes its thresholds is returned
    /// instead.
    ///
    /// Most inliers usually means the newest view, the one with the least parallax, where
    /// the rotation prior holds most of an out-of-plane turn back: on `combo` seed 8, while
    /// the head panned 2° a frame, fits against the newest view measured 30-70 % of each
    /// step, and the keyframes taken then inherited the lag (17° of pan by frame 120).
    /// Taking the tried view farthest from the previous estimate instead (measured
    /// 2026-11-25, scenario seeds 0-11 with filter seeds 0, 1 and the scenario's own, and
    /// seeds 12-23) lowered the synthetic per-axis RMSE summed over the six scenarios by
    /// 2.6-5.3° in all four runs (64.5 → 61.9 at filter seed 0), but cost car4 about 0.05
    /// of success AUC in each of three blocks of filter seeds (0.556 → 0.507 over seeds
    /// 0-63); girl was unchanged. Averaging the accepted fits (rotation, centre and size) was
    /// within seed noise on both. So the rule stays. Measured again with the keyframes'
    /// bundle adjustment (2026-12-05, filter seed 0), the farthest view raised the sum from
    /// 43.5 to 45.3 (`car` 4.36 / 8.91 / 4.60 -> 3.69 / 11.2 / 3.95): across a larger turn
    /// the ellipsoid's wrong depths cost the box more of it (see [`crate::pose::prior`]).
    pub fn best_fit(
        &self,
        cur: &Features,
        ctx: &FitContext<'_>,
        tries: usize,
        reach: f64,
    ) -> Option<KeyFit> {
        let mut order: Vec<(f64, usize)> = self
            .frames
            .iter()
            .enumerate()
            .map(|(i, k)| (angle_between(&ctx.prev.rot, &k.hyp.rot), i))
            .filter(|(d, _)| *d <= reach)
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut best: Option<KeyFit> = None;
        // The anchor's matches when it was among the views tried.
        let mut anchor_pairs = None;
        for &(_, i) in order.iter().take(tries) {
            let pairs = self.pairs(i, cur, ctx);
            let f = self.fit_pairs(i, &pairs, ctx);
            if i == 0 {
                anchor_pairs = Some(pairs);
            }
            let Some(f) = f else {
                continue;
            };
            let better = match &best {
                None => true,
                Some(b) => {
                    f.pairs.len() > b.pairs.len()
                        || (f.pairs.len() == b.pairs.len() && f.fit.residual < b.fit.residual)
                }
            };
            if better {
                best = Some(f);
            }
        }
        if let Some(r) = ctx.anchor_refit
            && !self.frames.is_empty()
        {
            // The anchor's pose carries no drift: fitted without the prior, which is centred
            // on the (drifting) previous estimate, and without the step bound.
            let free = FitContext {
                prior: None,
                max_step: std::f64::consts::PI,
                max_residual: r.max_residual,
                min_inliers: r.min_inliers,
                ..*ctx
            };
            let pairs = anchor_pairs.unwrap_or_else(|| self.pairs(0, cur, &free));
            if let Some(f) = self.fit_pairs(0, &pairs, &free) {
                return Some(f);
            }
        }
        best
    }

    /// The matches of keyframe `i` with the current features, keyframe → current frame, with
    /// the keyframe feature of each.
    fn pairs(
        &self,
        i: usize,
        cur: &Features,
        ctx: &FitContext<'_>,
    ) -> (Vec<FeaturePair>, Vec<usize>) {
        let key = &self.frames[i];
        match_features(&key.features, cur, ctx.matching)
            .iter()
            .map(|m| {
                let (a, b) = (&key.features.keypoints[m.query], &cur.keypoints[m.train]);
                (
                    FeaturePair {
                        p: [a.x, a.y],
                        q: [b.x, b.y],
                    },
                    m.query,
                )
            })
            .unzip()
    }

    /// The accepted fit of keyframe `i` to its matches `pairs`, from the previous estimate;
    /// `None` with fewer than `ctx.min_inliers` matches.
    fn fit_pairs(
        &self,
        i: usize,
        (pairs, query): &(Vec<FeaturePair>, Vec<usize>),
        ctx: &FitContext<'_>,
    ) -> Option<KeyFit> {
        if pairs.len() < ctx.min_inliers {
            return None;
        }
        let key = &self.frames[i];
        let rot0: Matrix3<f64> = ctx.prev.rot * key.hyp.rot.transpose();
        let s0 = ((ctx.prev.a * ctx.prev.b) / (key.hyp.a * key.hyp.b)).sqrt();
        let points: Option<Vec<Vector3<f64>>> = key
            .points
            .as_ref()
            .map(|x| query.iter().map(|&j| x[j]).collect());
        let (fit, pairs, which) =
            accepted_fit_on(pairs, points.as_deref(), &key.model, ctx, &rot0, s0)?;
        Some(KeyFit {
            key: key.hyp,
            fit,
            prev_scale: s0,
            pairs,
            query: which.iter().map(|&j| query[j]).collect(),
            index: i,
        })
    }

    /// Records how a frame went: the first fit against a keyframe sets the match count it is
    /// later compared with. Returns whether a new keyframe is due: no accepted fit at all, or
    /// the best one below `refresh_percent` of its keyframe's first count or below
    /// `min_inliers`.
    pub fn record(
        &mut self,
        best: Option<&KeyFit>,
        min_inliers: usize,
        refresh_percent: usize,
    ) -> bool {
        let Some(b) = best else {
            return true;
        };
        let n = b.pairs.len();
        let initial = *self.frames[b.index].initial_inliers.get_or_insert(n);
        n < min_inliers.max(initial * refresh_percent / 100)
    }

    /// Adds a keyframe of the features inside `e`, where there are at least `min_features`
    /// of them (a fit needs that many matches), and says whether it did; when the pool is
    /// full, the non-anchor keyframe nearest the new one in rotation gives way (the anchor,
    /// the first view, is never dropped). A view with fewer features (a blurred frame, or a
    /// frame SIFT skipped) could never be fitted, and would push out the keyframe best placed
    /// for its pose.
    pub fn add(
        &mut self,
        features: &Features,
        e: &Ellipse,
        hyp: Hypothesis,
        model: Ellipsoid,
        min_features: usize,
    ) -> bool {
        let k = make(features, e, hyp, model, self.now);
        if k.features.keypoints.len() < min_features {
            return false;
        }
        if self.frames.len() >= self.capacity {
            let victim = self
                .frames
                .iter()
                .enumerate()
                .skip(1)
                .min_by(|a, b| {
                    angle_between(&a.1.hyp.rot, &hyp.rot)
                        .total_cmp(&angle_between(&b.1.hyp.rot, &hyp.rot))
                })
                .map(|(i, _)| i);
            if let Some(i) = victim {
                self.retired = self.retired.add(self.frames[i].relief);
                self.frames[i] = k;
            }
        } else {
            self.frames.push(k);
        }
        true
    }
}

/// A keyframe from a frame's features, keeping those inside the ellipse.
fn make(
    features: &Features,
    e: &Ellipse,
    hyp: Hypothesis,
    model: Ellipsoid,
    frame: usize,
) -> Keyframe {
    let keep: Vec<usize> = (0..features.keypoints.len())
        .filter(|&i| {
            e.contains(
                features.keypoints[i].x as f64,
                features.keypoints[i].y as f64,
            )
        })
        .collect();
    Keyframe {
        features: Features {
            keypoints: keep.iter().map(|&i| features.keypoints[i]).collect(),
            descriptors: keep.iter().map(|&i| features.descriptors[i]).collect(),
        },
        hyp,
        model,
        initial_inliers: None,
        frame,
        views: Vec::new(),
        points: None,
        since_adjusted: 0,
        relief: Evidence::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::Keypoint;
    use crate::geometry::Euler;

    fn hyp(e: Euler) -> Hypothesis {
        Hypothesis {
            cx: 50.0,
            cy: 40.0,
            a: 10.0,
            b: 12.0,
            rot: e.matrix(),
        }
    }

    fn model() -> Ellipsoid {
        Ellipsoid::facing(&Ellipse::new(50.0, 40.0, 10.0, 12.0), 1.0)
    }

    fn features(n: usize) -> Features {
        Features {
            keypoints: (0..n)
                .map(|i| Keypoint {
                    x: 45.0 + (i % 5) as f32,
                    y: 36.0 + (i / 5) as f32,
                    ..Keypoint::default()
                })
                .collect(),
            descriptors: (0..n).map(|i| [i as u8; 128]).collect(),
        }
    }

    #[test]
    fn the_anchor_survives_a_full_pool_and_the_nearest_view_gives_way() {
        let e = Ellipse::new(50.0, 40.0, 10.0, 12.0);
        let mut pool = KeyframePool::new(3);
        pool.reset(&features(4), &e, hyp(Euler::default()), model());
        pool.add(
            &features(4),
            &e,
            hyp(Euler::from_degrees(20.0, 0.0, 0.0)),
            model(),
            3,
        );
        pool.add(
            &features(4),
            &e,
            hyp(Euler::from_degrees(-20.0, 0.0, 0.0)),
            model(),
            3,
        );
        assert_eq!(pool.len(), 3);
        pool.add(
            &features(4),
            &e,
            hyp(Euler::from_degrees(25.0, 0.0, 0.0)),
            model(),
            3,
        );
        assert_eq!(pool.len(), 3);
        let angles = |pool: &KeyframePool| -> Vec<f64> {
            pool.frames
                .iter()
                .map(|k| Euler::from_matrix(&k.hyp.rot).rx.to_degrees().round())
                .collect()
        };
        assert_eq!(angles(&pool), vec![0.0, 25.0, -20.0]);
        // A view with fewer features than a fit needs is no keyframe, and pushes none out
        // (here 4 features, with 5 needed; none at all, as on a frame SIFT skipped).
        let h = hyp(Euler::from_degrees(24.0, 0.0, 0.0));
        assert!(!pool.add(&features(4), &e, h, model(), 5));
        assert!(!pool.add(&Features::default(), &e, h, model(), 3));
        assert_eq!(angles(&pool), vec![0.0, 25.0, -20.0]);
        // A pool asked to hold one keyframe holds two: the anchor stays.
        let mut pool = KeyframePool::new(1);
        pool.reset(&features(4), &e, hyp(Euler::default()), model());
        for deg in [10.0, 20.0] {
            let h = hyp(Euler::from_degrees(deg, 0.0, 0.0));
            pool.add(&features(4), &e, h, model(), 3);
        }
        let first = Euler::from_matrix(&pool.frames[0].hyp.rot).rx;
        assert_eq!((pool.len(), first), (2, 0.0));
    }

    #[test]
    fn a_keyframe_keeps_only_the_features_inside_its_ellipse() {
        let mut f = features(3);
        f.keypoints[1].x = 0.0;
        let k = make(
            &f,
            &Ellipse::new(50.0, 40.0, 10.0, 12.0),
            hyp(Euler::default()),
            model(),
            0,
        );
        assert_eq!(k.features.keypoints.len(), 2);
        assert_eq!(k.features.descriptors.len(), 2);
        assert_eq!(k.features.descriptors[1], [2u8; 128]);
    }

    #[test]
    fn a_refresh_is_due_without_a_fit_or_when_the_inliers_halve() {
        let e = Ellipse::new(50.0, 40.0, 10.0, 12.0);
        let mut pool = KeyframePool::new(4);
        pool.reset(&features(4), &e, hyp(Euler::default()), model());
        assert!(pool.record(None, 10, 50));
        let fit = |n: usize| KeyFit {
            key: hyp(Euler::default()),
            fit: PriorFit {
                rot: Matrix3::identity(),
                scale: 1.0,
                centre: Vector2::zeros(),
                inliers: vec![true; n],
                residual: 0.5,
            },
            prev_scale: 1.0,
            pairs: vec![FeaturePair::default(); n],
            query: (0..n).collect(),
            index: 0,
        };
        assert!(!pool.record(Some(&fit(30)), 10, 50));
        assert!(!pool.record(Some(&fit(16)), 10, 50));
        assert!(pool.record(Some(&fit(14)), 10, 50));
        // The floor: never fewer than `min_inliers`, whatever the share.
        assert!(!pool.record(Some(&fit(9)), 5, 10));
        assert!(pool.record(Some(&fit(4)), 5, 10));
    }

    /// The anchor's features on a 6 x 5 grid inside its ellipse, and the same features seen
    /// after the object (the anchor's ellipsoid, its relief scaled by `relief`) turned by
    /// `turn`, in place (weak perspective).
    fn anchor_and_turned(turn: &Matrix3<f64>, relief: f64) -> (Features, Features) {
        let m = model();
        let p: Vec<[f64; 2]> = (0..30)
            .map(|i| {
                let (u, v) = ((i % 6) as f64 / 5.0 - 0.5, (i / 6) as f64 / 4.0 - 0.5);
                [50.0 + 12.0 * u, 40.0 + 14.0 * v]
            })
            .collect();
        let q: Vec<[f64; 2]> = crate::pose::prior::lift(&p, &m, None)
            .iter()
            .map(|x| {
                let y = turn * Vector3::new(x.x, x.y, relief * x.z);
                [m.centre.x + y.x, m.centre.y + y.y]
            })
            .collect();
        (features_at(&p, 8), features_at(&q, 8))
    }

    /// A fit from `prev` under weak perspective, held by a motion prior and a 20-degree step
    /// bound, at least 10 inliers within 3 px, no anchor refit, on the model's relief.
    fn context<'a>(prev: &'a Hypothesis, matching: &'a MatchParams) -> FitContext<'a> {
        FitContext {
            prev,
            shift: Vector2::zeros(),
            camera: None,
            matching,
            min_inliers: 10,
            max_residual: 3.0,
            max_step: 20f64.to_radians(),
            prior: Some(MotionPrior {
                mean: Matrix3::identity(),
                sigma: [0.05; 3],
                pixel_sigma: 1.0,
                centre_sigma: None,
            }),
            anchor_refit: None,
            relief: 1.0,
        }
    }

    /// Keypoints at `pts`, the `i`-th with every descriptor entry `step · i`.
    fn features_at(pts: &[[f64; 2]], step: usize) -> Features {
        Features {
            keypoints: pts
                .iter()
                .map(|p| Keypoint {
                    x: p[0] as f32,
                    y: p[1] as f32,
                    ..Keypoint::default()
                })
                .collect(),
            descriptors: (0..pts.len()).map(|i| [(step * i) as u8; 128]).collect(),
        }
    }

    #[test]
    fn the_fits_lift_with_the_relief_they_are_given() {
        // An object half as deep as its model, turned 20 degrees: fitted freely on the model's
        // relief the turn reads short, on half of it exactly.
        let turn = Euler::from_degrees(4.0, 20.0, -3.0).matrix();
        let (anchor, now) = anchor_and_turned(&turn, 0.5);
        let e = Ellipse::new(50.0, 40.0, 10.0, 12.0);
        let mut pool = KeyframePool::new(4);
        pool.reset(&anchor, &e, hyp(Euler::default()), model());
        let prev = hyp(Euler::default());
        let matching = MatchParams::default();
        let error = |relief| {
            // Free: no prior, any step.
            let ctx = FitContext {
                max_step: std::f64::consts::PI,
                prior: None,
                relief,
                ..context(&prev, &matching)
            };
            pool.best_fit(&now, &ctx, 3, 1.0).map_or(180.0, |f| {
                angle_between(&f.placed().rot, &turn).to_degrees()
            })
        };
        let (model_relief, half) = (error(1.0), error(0.5));
        assert!(model_relief > 3.0, "{model_relief}");
        assert!(half < 0.01, "{half} (model's relief: {model_relief})");
    }

    #[test]
    fn a_tight_free_fit_to_the_anchor_overrides_the_prior_and_the_step_bound() {
        // The object turned 25 degrees from the anchor's frontal view while the previous
        // estimate stayed frontal: the prior (centred on that estimate) and the 20-degree
        // step bound keep the truth out of reach; the free anchor fit finds it.
        let turn = Euler::from_degrees(5.0, 25.0, -3.0).matrix();
        let (anchor, now) = anchor_and_turned(&turn, 1.0);
        let e = Ellipse::new(50.0, 40.0, 10.0, 12.0);
        let mut pool = KeyframePool::new(4);
        pool.reset(&anchor, &e, hyp(Euler::default()), model());
        let prev = hyp(Euler::default());
        let matching = MatchParams::default();
        let ctx = |anchor_refit| FitContext {
            anchor_refit,
            ..context(&prev, &matching)
        };
        // Held by the prior, the fit stays near the previous estimate, the turn taken up by
        // translation and scale within a pixel of residual.
        let held = pool.best_fit(&now, &ctx(None), 3, 1.0).map_or(180.0, |f| {
            angle_between(&f.placed().rot, &turn).to_degrees()
        });
        assert!(held > 15.0, "{held}");
        let fit = pool
            .best_fit(&now, &ctx(Some(AnchorRefit::default())), 3, 1.0)
            .expect("the anchor fits");
        assert!(angle_between(&fit.placed().rot, &turn).to_degrees() < 0.01);
        assert_eq!(fit.pairs.len(), 30);
        // Too few inliers for its threshold: no override, the held fit stands.
        let strict = AnchorRefit {
            min_inliers: 31,
            ..AnchorRefit::default()
        };
        let kept = pool
            .best_fit(&now, &ctx(Some(strict)), 3, 1.0)
            .map_or(180.0, |f| {
                angle_between(&f.placed().rot, &turn).to_degrees()
            });
        assert_eq!(kept, held);
    }

    #[test]
    fn a_keyframe_is_adjusted_once_it_has_enough_turned_views_and_the_anchor_never() {
        let cfg = BundleAdjust::default();
        let pool = adjust_half_deep(&cfg);
        assert!(pool.frames[0].views.is_empty() && pool.frames[0].points.is_none());
        assert_eq!(pool.frames[1].views.len(), cfg.min_views);
        assert!(pool.frames[1].points.is_some());
        // Without the relief setting the lift's relief stands.
        assert_eq!(pool.relief(&cfg), 1.0);
    }

    /// With the relief free, the adjustment of the object half as deep as its model finds it
    /// flatter, the pool keeps that when the keyframe gives way, and a reset forgets it.
    #[test]
    fn the_relief_an_adjustment_finds_is_pooled_kept_and_reset() {
        let mut cfg = BundleAdjust::default();
        cfg.params.relief_sigma = Some(1.0);
        let mut pool = adjust_half_deep(&cfg);
        let k = pool.relief(&cfg);
        assert!(k > 0.4 && k < 0.75, "relief {k}");
        let evidence = pool.frames[1].relief;
        assert!(evidence.information > 0.0, "{evidence:?}");
        // Two keyframes turned away fill the pool, and a third in its pose pushes it out
        // (the anchor stays).
        let (feats, e) = (
            pool.frames[1].features.clone(),
            Ellipse::new(80.0, 60.0, 30.0, 24.0),
        );
        for deg in [40.0, 80.0, 0.0] {
            let hyp = Hypothesis {
                rot: Euler::from_degrees(0.0, deg, 0.0).matrix(),
                ..pool.frames[1].hyp
            };
            assert!(pool.add(&feats, &e, hyp, pool.frames[1].model, 3));
        }
        assert!(
            pool.frames
                .iter()
                .skip(1)
                .all(|f| f.relief == Evidence::default())
        );
        assert_eq!(pool.relief(&cfg), k);
        let (hyp, model) = (pool.frames[0].hyp, pool.frames[0].model);
        pool.reset(&feats, &e, hyp, model);
        assert_eq!(pool.relief(&cfg), 1.0);
    }

    /// An adjustment's own evidence and the prior it was held to make up its posterior, and a
    /// posterior that knows no more than its prior gives none.
    #[test]
    fn an_adjustment_s_own_evidence_is_its_posterior_less_its_prior() {
        use crate::pose::bundle::Relief;
        let (log0, information0) = (0.3, 4.0);
        let post = Relief {
            log: -0.1,
            variance: 0.1,
        };
        let own = own_evidence(log0, information0, post);
        let prior = Evidence {
            information: information0,
            weighted: information0 * log0,
        };
        let both = prior.add(own);
        assert!((both.information - 10.0).abs() < 1e-12, "{both:?}");
        assert!((both.log() - 0.2).abs() < 1e-12, "{both:?}");
        // Its own mean lies beyond the posterior's, away from the prior's.
        assert!((own.log() - 0.8 / 6.0).abs() < 1e-12, "{own:?}");
        for variance in [0.25, 0.3, f64::INFINITY] {
            let none = own_evidence(log0, information0, Relief { log: 0.0, variance });
            assert_eq!(none, Evidence::default(), "variance {variance}");
        }
    }

    /// The pool's factor: the prior, the retired evidence and every keyframe's, less the one
    /// left out for its own adjustment; 1 without the setting.
    #[test]
    fn the_pool_adds_the_evidence_of_its_keyframes_and_the_retired() {
        let mut pool = KeyframePool::new(4);
        let feats = features(12);
        let e = Ellipse::new(50.0, 40.0, 10.0, 12.0);
        pool.reset(&feats, &e, hyp(Euler::default()), model());
        assert!(pool.add(&feats, &e, hyp(Euler::default()), model(), 3));
        let ev = |information: f64, log: f64| Evidence {
            information,
            weighted: information * log,
        };
        pool.frames[1].relief = ev(2.0, -0.5);
        pool.retired = ev(1.0, -0.2);
        let mut cfg = BundleAdjust::default();
        assert_eq!(pool.relief(&cfg), 1.0);
        cfg.params.relief_sigma = Some(1.0);
        // Prior (1, 0) + retired (1, -0.2) + keyframe (2, -1.0): 4, mean -0.3.
        let (log, information) = pool.relief_log(&cfg, None);
        assert!((information - 4.0).abs() < 1e-12 && (log + 0.3).abs() < 1e-12);
        assert!((pool.relief(&cfg) - (-0.3f64).exp()).abs() < 1e-12);
        let (log, information) = pool.relief_log(&cfg, Some(1));
        assert!((information - 2.0).abs() < 1e-12 && (log + 0.1).abs() < 1e-12);
    }

    /// A pool whose second keyframe, of an object half as deep as its model, was adjusted
    /// (see the test above).
    fn adjust_half_deep(cfg: &BundleAdjust) -> KeyframePool {
        // A keyframe of an object half as deep as its ellipsoid, seen through a camera while
        // it turns 4 degrees a frame about the vertical; each fit reads half the turn (the
        // shallower object's parallax on the deeper model), as the tracker's fits of the box
        // `car` did.
        let e = Ellipse::new(80.0, 60.0, 30.0, 24.0);
        let cam = Pinhole {
            focal: 100.0,
            principal: Vector2::new(79.5, 59.5),
        };
        let p: Vec<[f64; 2]> = (0..42)
            .map(|i| {
                let (u, v) = ((i % 7) as f64 / 6.0 - 0.5, (i / 7) as f64 / 5.0 - 0.5);
                [80.0 + 40.0 * u + 2.0 * v, 60.0 + 30.0 * v]
            })
            .collect();
        let feats = features_at(&p, 6);
        let m = Ellipsoid::facing(&e, 1.0);
        let key = Hypothesis {
            cx: 80.0,
            cy: 60.0,
            a: 30.0,
            b: 24.0,
            rot: Matrix3::identity(),
        };
        // Each lifted point moved along its ray to half its depth.
        let origin = Vector3::new(
            cam.principal.x - m.centre.x,
            cam.principal.y - m.centre.y,
            -cam.focal,
        );
        let truth: Vec<Vector3<f64>> = crate::pose::prior::lift(&p, &m, Some(&cam))
            .iter()
            .map(|x| origin + (0.5 * x.z - origin.z) / (x.z - origin.z) * (x - origin))
            .collect();
        let mut pool = KeyframePool::new(4);
        pool.reset(&feats, &e, key, m);
        pool.add(&feats, &e, key, m, 3);
        let view = |k: usize, index: usize| {
            let turn = Euler::from_degrees(0.0, 4.0 * k as f64, 0.0).matrix();
            let pairs: Vec<FeaturePair> = truth
                .iter()
                .zip(&p)
                .map(|(x, p)| {
                    let q = crate::pose::prior::view_of(x, &turn, 1.0, &m.centre, Some(&cam));
                    FeaturePair {
                        p: [p[0] as f32, p[1] as f32],
                        q: [q.x as f32, q.y as f32],
                    }
                })
                .collect();
            let fit = PriorFit {
                rot: Euler::from_degrees(0.0, 2.0 * k as f64, 0.0).matrix(),
                scale: 1.0,
                centre: m.centre,
                inliers: vec![true; pairs.len()],
                residual: 0.5,
            };
            let fit = KeyFit {
                key,
                fit,
                prev_scale: 1.0,
                query: (0..pairs.len()).collect(),
                pairs,
                index,
            };
            (fit, turn)
        };
        for k in 1..=cfg.min_views {
            pool.tick(k);
            let (anchor_fit, _) = view(k, 0);
            assert!(pool.observe(&anchor_fit, Some(&cam), cfg).is_none());
            let (fit, turn) = view(k, 1);
            let adjusted = pool.observe(&fit, Some(&cam), cfg);
            if k < cfg.min_views {
                assert!(adjusted.is_none(), "adjusted after {k} views");
                continue;
            }
            let adjusted = adjusted.expect("adjusted at the seventh view");
            let before = angle_between(&fit.fit.rot, &turn).to_degrees();
            let after = angle_between(&adjusted.rot, &turn).to_degrees();
            assert!(after < 0.5 * before, "{before} -> {after}");
        }
        pool
    }
}
