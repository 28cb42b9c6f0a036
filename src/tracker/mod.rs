//! The embeddable tracker: [`Tracker::new`] on the first frame, [`Tracker::step`] on each
//! following frame, [`Tracker::reinit`] to start over without rebuilding it.
//!
//! ```no_run
//! use pftrack::geometry::Ellipse;
//! use pftrack::tracker::{Init, Tracker, TrackerConfig};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let first = image::open("frames/00000.png")?.to_rgb8();
//! let init = Init::frontal(Ellipse::new(80.0, 60.0, 20.0, 24.0));
//! let mut tracker = Tracker::new(TrackerConfig::default(), &first, init)?;
//! for k in 1..100 {
//!     let frame = image::open(format!("frames/{k:05}.png"))?.to_rgb8();
//!     let est = tracker.step(&frame)?;
//!     let [tilt, pan, roll] = est.angles_deg();
//!     println!("{k}: centre ({:.1}, {:.1}) tilt {tilt:.1} pan {pan:.1} roll {roll:.1} score {:.2}{}",
//!         est.state.cx, est.state.cy, est.confidence, if est.lost { " LOST" } else { "" });
//! }
//! # Ok(())
//! # }
//! ```
//!
//! Per frame ([`Tracker::step`]): SIFT in the previous ellipse's neighbourhood, matching
//! against the previous frame's features, the paper's slope/length outlier rejection, the
//! inter-frame rotation from Sylvester's equation (both members of its Necker pair),
//! adaptive block matching for the translation, then the particle filter: proposal
//! around `x + Δx`, all particles' likelihoods in one call of the likelihood engine (CPU or
//! GPU) plus the appearance template's correlation (CPU), weights, estimate, resampling. A
//! confidence in `[0, 1]` and a lost flag come with every estimate; a lost target is searched
//! for over the whole frame by colour and taken back where its features fit a keyframe.

mod config;
mod init_refine;
mod keyframe;

pub use config::{
    AnchorRefit, BundleAdjust, ColourUpdate, Contrast, Init, Mode, Reanchor, TemplateTerm,
    TrackerConfig,
};
pub use init_refine::{InitRefine, refine_ellipse};

use nalgebra::{Matrix3, Vector3};

use crate::features::{Features, Sift, keep_slope_length, match_features};
use crate::filter::rotation_mean::{exp_so3, log_so3};
use crate::filter::{AspectRange, Hypothesis, Motion, ParticleFilter, SizeRange};
use crate::frames::GrayF32;
use crate::geometry::{BoxRect, Ellipse, Euler, PoseState, deg};
use crate::likelihood::cpu::colour::rho_from_log;
use crate::likelihood::{
    COLOUR_LUMA, ColourHistogram, ContrastTable, FeaturePair, FrameInput, LikelihoodEngine,
    LikelihoodParams, Particle, TERM_COLOUR, TERM_CONTRAST, TERM_FEATURE, TERM_GRADIENT, TermLogs,
};
use crate::motion::block_match;
use crate::pose::{SolverKind, interframe_consensus};
use keyframe::{FitContext, KeyframePool};

/// Errors of the tracker.
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    /// The initial ellipse is unusable.
    #[error("invalid initial ellipse ({0})")]
    BadInit(String),
    /// A setting of the configuration is out of range.
    #[error("invalid tracker configuration: {0}")]
    BadConfig(String),
    /// A frame's size differs from the first frame's.
    #[error("frame {frame} is {got_w}x{got_h}, the first frame was {want_w}x{want_h}")]
    FrameSize {
        /// Index of the offending frame.
        frame: usize,
        /// Its width.
        got_w: u32,
        /// Its height.
        got_h: u32,
        /// The first frame's width.
        want_w: u32,
        /// The first frame's height.
        want_h: u32,
    },
    /// The likelihood engine failed.
    #[error(transparent)]
    Likelihood(#[from] crate::likelihood::LikelihoodError),
    /// SIFT failed.
    #[error(transparent)]
    Features(#[from] crate::features::FeatureError),
}

/// What the tracker says about one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Frame index (0 for the first frame).
    pub frame: usize,
    /// The state: ellipse centre and semi-axes, rotation (radians) relative to the reference
    /// pose. Angles are continuous from frame to frame (no jumps at ±180°).
    pub state: PoseState,
    /// The ellipse, turned by `theta0 + rz`.
    pub ellipse: Ellipse,
    /// Confidence in `[0, 1]`: colour similarity and contour support of the estimate, lowered
    /// when no features could measure the rotation. On a frame where a lost target is
    /// re-acquired, the found target's own (at least [`TrackerConfig::found_above`]).
    pub confidence: f64,
    /// Whether the target is considered lost: from the [`TrackerConfig::lost_after`]-th
    /// frame in a row below [`TrackerConfig::lost_below`] until a frame reaches
    /// [`TrackerConfig::found_above`] or the target is re-acquired.
    pub lost: bool,
    /// Feature matches used for the rotation this frame (0: colour and gradient only).
    pub matches: usize,
    /// Effective sample size of the filter after weighting.
    pub ess: f64,
}

impl Estimate {
    /// The angles in degrees, `[tilt, pan, roll]`.
    pub fn angles_deg(&self) -> [f64; 3] {
        [deg(self.state.rx), deg(self.state.ry), deg(self.state.rz)]
    }
}

/// Most keyframes held (the first view and those taken as the target turned).
const KEYFRAMES: usize = 12;
/// Keyframes fitted per frame, the nearest to the previous estimate first.
const KEYFRAME_TRIES: usize = 3;
/// Keyframes further than this from the previous estimate (radians, 45°) are not tried: SIFT
/// matches few features across larger turns.
const KEYFRAME_REACH: f64 = std::f64::consts::FRAC_PI_4;

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

/// The joint tracker and pose estimator.
pub struct Tracker {
    cfg: TrackerConfig,
    engine: Box<dyn LikelihoodEngine + Send>,
    sift: Sift,
    /// SIFT without the doubled first octave, for targets of at least
    /// [`TrackerConfig::sift_upsample_below`]; `None` when every target gets `sift`.
    sift_large: Option<Sift>,
    filter: ParticleFilter,
    size: (u32, u32),
    theta0: f64,
    reference: Ellipse,
    frame: usize,
    prev_gray: GrayF32,
    prev_features: Features,
    keyframes: KeyframePool,
    prev: Hypothesis,
    prev_euler: Euler,
    /// The estimate's rotation per frame, smoothed ([`TrackerConfig::coast_rate`]): a
    /// rotation vector about the camera's axes (radians a frame).
    spin: Vector3<f64>,
    low_count: usize,
    lost: bool,
    /// The semi-axes of the last trusted estimate (confidence at least
    /// [`TrackerConfig::found_above`]), which the filter's proposals are held near while the
    /// tracker is unsure ([`TrackerConfig::size_hold`]).
    held_axes: (f64, f64),
    /// The previous frame's confidence (1 after an initialisation).
    prev_confidence: f64,
    particles: Vec<Particle>,
    terms: Vec<TermLogs>,
    first: Estimate,
    /// The colour model the engine holds (it adapts, [`TrackerConfig::colour_update`]).
    colour_model: ColourHistogram,
    /// The contrast term's background histogram (a ring around the target), when the term is
    /// on and the ring held pixels on the initial frame ([`TrackerConfig::contrast`]).
    background: Option<ColourHistogram>,
    /// The appearance template, when the term is on ([`TrackerConfig::template`]).
    template: Option<crate::likelihood::template::Template>,
    /// The particles' correlations with the template this frame.
    correlations: Vec<f32>,
    /// The first view's template and the first frame's estimate, when the anchor is on
    /// ([`TemplateTerm::anchor_weight`]).
    anchor: Option<(
        crate::likelihood::template::Template,
        crate::likelihood::template::FirstView,
    )>,
    /// The particles' correlations with the turned first view this frame.
    anchor_correlations: Vec<f32>,
}

impl std::fmt::Debug for Tracker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tracker")
            .field("engine", &self.engine.name())
            .field("frame", &self.frame)
            .field("size", &self.size)
            .finish_non_exhaustive()
    }
}

/// Checks an initial ellipse against a frame.
fn check_init(init: &Init, w: u32, h: u32) -> Result<(), TrackError> {
    let e = &init.ellipse;
    if !e.is_valid() {
        return Err(TrackError::BadInit(format!(
            "cx {}, cy {}, a {}, b {}: values must be finite and the semi-axes positive",
            e.cx, e.cy, e.a, e.b
        )));
    }
    if e.a < 2.0 || e.b < 2.0 {
        return Err(TrackError::BadInit(format!(
            "semi-axes {:.1} x {:.1} px: at least 2 px each",
            e.a, e.b
        )));
    }
    if !e.centre_inside(w, h) {
        return Err(TrackError::BadInit(format!(
            "centre ({:.1}, {:.1}) lies outside the {w}x{h} frame",
            e.cx, e.cy
        )));
    }
    let p = &init.pose;
    if ![p.rx, p.ry, p.rz].iter().all(|v| v.is_finite()) {
        return Err(TrackError::BadInit(
            "initial pose angles must be finite".into(),
        ));
    }
    Ok(())
}

/// Largest rotation (radians) between two frames' estimates that counts as the target's
/// motion in its smoothed spin ([`TrackerConfig::coast_rate`]): 0.1 (5.7°), several times the
/// fastest synthetic turn (1.6° a frame). A larger step is a jump (a mismatched fit), which
/// the spin ignores.
const SPIN_MAX_STEP: f64 = 0.1;

/// How the estimate moved into a frame, for its smoothed spin ([`smoothed_spin`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Moved {
    /// Tracked, with the rotation measured (a keyframe fit, a fit against the previous
    /// frame, or the rotation between the two frames): the step is the target's motion.
    Tracked,
    /// Tracked with nothing measuring the rotation: the step is the spin's own proposal and
    /// the filter's noise, so the spin keeps its last measured value instead of feeding on
    /// itself.
    Unmeasured,
    /// Reset to where the target was found again (re-anchored, re-posed, re-acquired): the
    /// step corrects the estimate and says nothing of the target's motion.
    Reset,
    /// Lost: no motion is known.
    Lost,
}

/// The estimate's smoothed rotation per frame after a frame whose estimate turned by `step`
/// (a rotation vector) from the previous one: moved by `rate` of the way towards `step` when
/// the frame was tracked and its rotation measured; unchanged when the estimate was reset or
/// the step exceeds [`SPIN_MAX_STEP`] (a correction or a jump, not the target's motion), or
/// when nothing measured the rotation (a gap is bridged at the last measured turn, and a
/// target without texture, never measured, is never turned on by its own noise); at rest
/// when lost.
fn smoothed_spin(
    spin: &Vector3<f64>,
    step: &Vector3<f64>,
    rate: f64,
    moved: Moved,
) -> Vector3<f64> {
    match moved {
        Moved::Lost => Vector3::zeros(),
        Moved::Reset | Moved::Unmeasured => *spin,
        Moved::Tracked if step.norm().is_nan() || step.norm() > SPIN_MAX_STEP => *spin,
        Moved::Tracked => spin + (step - spin) * rate,
    }
}

/// The keyframe fits' motion prior from the configuration (its mean is each fit's start):
/// the filter's rotation walk, [`TrackerConfig::fit_pixel_sigma`] and
/// [`TrackerConfig::fit_centre_sigma`]; `None` without a pixel σ.
fn fit_prior(cfg: &TrackerConfig) -> Option<crate::pose::prior::MotionPrior> {
    cfg.fit_pixel_sigma
        .map(|px| crate::pose::prior::MotionPrior {
            mean: Matrix3::identity(),
            sigma: cfg.filter.dynamics.rotation,
            pixel_sigma: px,
            centre_sigma: cfg.fit_centre_sigma,
        })
}

/// Checks the settings the tracker itself uses (the filter, SIFT and the likelihood check
/// theirs): the feature weight, the keyframe fits' motion prior by the rule of the fit
/// itself ([`crate::pose::prior::MotionPrior::check`]), and each optional part's own
/// `check` (anchor refit, colour update, contrast, inter-frame consensus, template) and
/// widening factors (size hold, aspect slack).
fn check_config(cfg: &TrackerConfig) -> Result<(), TrackError> {
    if !(cfg.feature_weight.is_finite() && cfg.feature_weight >= 0.0) {
        return Err(TrackError::BadConfig(format!(
            "feature_weight {} must be finite and at least 0 (0 leaves the rotation to the \
             motion alone)",
            cfg.feature_weight
        )));
    }
    if let Some(prior) = fit_prior(cfg) {
        prior.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "fit_pixel_sigma {} with the filter's rotation walk {:?} and fit_centre_sigma \
                 {:?}: {e}; set fit_pixel_sigma to None to fit without the prior, \
                 fit_centre_sigma to None to leave the centre free",
                prior.pixel_sigma, cfg.filter.dynamics.rotation, cfg.fit_centre_sigma
            ))
        })?;
    }
    if let Some(rate) = cfg.coast_rate
        && !(rate > 0.0 && rate <= 1.0)
    {
        return Err(TrackError::BadConfig(format!(
            "coast_rate {rate} must lie in (0, 1]; set it to None to hold the rotation still \
             where nothing measured it"
        )));
    }
    if let Some(r) = &cfg.init_refine {
        r.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "{e}; set init_refine to None to keep the given ellipse"
            ))
        })?;
    }
    if let Some(d) = cfg.sift_upsample_below
        && !(d.is_finite() && d > 0.0)
    {
        return Err(TrackError::BadConfig(format!(
            "sift_upsample_below {d} must be a positive size in pixels; set it to None to \
             keep the SIFT settings for every target size"
        )));
    }
    if let Some(b) = &cfg.bundle {
        b.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "{e}; set bundle to None to fit every keyframe on its ellipsoid alone"
            ))
        })?;
    }
    if let Some(r) = &cfg.anchor_refit {
        r.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "{e}; set anchor_refit to None to measure against the nearest views alone"
            ))
        })?;
    }
    if let Some(u) = &cfg.colour_update {
        u.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "{e}; set colour_update to None for a fixed colour model"
            ))
        })?;
    }
    if let Some(c) = &cfg.contrast {
        c.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "{e}; set contrast to None for the paper's three terms alone"
            ))
        })?;
    }
    if let Some(c) = &cfg.interframe_consensus {
        c.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "{e}; set interframe_consensus to None to estimate the rotation from any 3 matches"
            ))
        })?;
    }
    if let Some(r) = &cfg.reanchor {
        r.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "{e}; set reanchor to None to leave the estimate to the filter"
            ))
        })?;
    }
    if let Some(t) = &cfg.template {
        t.check().map_err(|e| {
            TrackError::BadConfig(format!(
                "{e}; set template to None to weigh the particles without a template"
            ))
        })?;
    }
    if !(0.0..=1.0).contains(&cfg.lost_below) || !(cfg.lost_below..=1.0).contains(&cfg.found_above)
    {
        return Err(TrackError::BadConfig(format!(
            "lost_below {} and found_above {} must satisfy 0 <= lost_below <= found_above <= 1",
            cfg.lost_below, cfg.found_above
        )));
    }
    if let Some(n) = cfg.reacquire_ncc
        && !(-1.0..=1.0).contains(&n)
    {
        return Err(TrackError::BadConfig(format!(
            "reacquire_ncc {n} is not in [-1, 1]; set it to None to recognise a re-acquired \
             target by its features alone"
        )));
    }
    check_factor(
        "size_hold",
        cfg.size_hold,
        "leave the ellipse's size free while the target is uncertain",
    )?;
    check_factor(
        "aspect_slack",
        cfg.aspect_slack,
        "leave the ellipse's aspect free",
    )?;
    Ok(())
}

/// A widening factor of the configuration, `name`, must be finite and at least 1; the
/// error says what setting it to `None` does instead (`none_does`).
fn check_factor(name: &str, k: Option<f64>, none_does: &str) -> Result<(), TrackError> {
    match k {
        Some(k) if !(k.is_finite() && k >= 1.0) => Err(TrackError::BadConfig(format!(
            "{name} {k} is not a finite factor of at least 1; set {name} to None to {none_does}"
        ))),
        _ => Ok(()),
    }
}

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

/// The aspects `a / b` the object model of a track starting in `init` can show, widened by
/// `slack` ([`TrackerConfig::aspect_slack`]); `None` without slack or for a degenerate model.
fn aspect_range(init: &Ellipse, depth_ratio: f64, slack: Option<f64>) -> Option<AspectRange> {
    let k = slack?;
    let (lo, hi) = crate::pose::prior::Ellipsoid::facing(init, depth_ratio).outline_aspect_range();
    AspectRange::new(lo / k, hi * k)
}

/// Spacing (degrees) of the tilts and pans [`Tracker::repose`] tries first.
const REPOSE_STEP_DEG: f32 = 5.0;
/// How far (degrees) from the estimate's tilt and pan [`Tracker::repose`] looks.
const REPOSE_REACH_DEG: f32 = 30.0;

/// The search region of SIFT around an ellipse: its bounding box grown by half its larger
/// semi-axis plus 8 px (the largest inter-frame motion followed), clipped to the frame.
fn search_region(e: &Ellipse, w: u32, h: u32) -> BoxRect {
    let bb = e.bounding_box();
    let m = search_margin(e);
    let x0 = (bb.x - m).max(0.0);
    let y0 = (bb.y - m).max(0.0);
    let x1 = (bb.x + bb.w + m).min(w as f64);
    let y1 = (bb.y + bb.h + m).min(h as f64);
    BoxRect::new(x0, y0, (x1 - x0).max(0.0), (y1 - y0).max(0.0))
}

/// The margin of [`search_region`] around an ellipse's bounding box.
fn search_margin(e: &Ellipse) -> f64 {
    0.5 * e.a.max(e.b) + 8.0
}

impl Tracker {
    /// A tracker on the CPU likelihood engine (all cores).
    pub fn new(
        cfg: TrackerConfig,
        first_frame: &image::RgbImage,
        init: Init,
    ) -> crate::Result<Self> {
        let engine = Box::new(crate::likelihood::cpu::CpuEngine::new());
        Self::with_engine(cfg, engine, first_frame, init)
    }

    /// A tracker on a given likelihood engine (e.g. the GPU engine from
    /// [`crate::likelihood::create_engine`]).
    pub fn with_engine(
        cfg: TrackerConfig,
        engine: Box<dyn LikelihoodEngine + Send>,
        first_frame: &image::RgbImage,
        init: Init,
    ) -> crate::Result<Self> {
        check_config(&cfg).map_err(track_err)?;
        let mut cfg = cfg;
        if cfg.grey_luma && is_grey(first_frame) {
            cfg.likelihood.colour_bins = COLOUR_LUMA;
        }
        let sift = Sift::new(cfg.sift.clone());
        let sift_large = (cfg.sift.upsample && cfg.sift_upsample_below.is_some()).then(|| {
            Sift::new(crate::features::SiftParams {
                upsample: false,
                ..cfg.sift.clone()
            })
        });
        let filter = ParticleFilter::new(
            cfg.filter,
            cfg.seed,
            &Hypothesis::from_state(&PoseState::default()),
        );
        let mut t = Self {
            cfg,
            engine,
            sift,
            sift_large,
            filter,
            size: first_frame.dimensions(),
            theta0: 0.0,
            reference: Ellipse::default(),
            frame: 0,
            prev_gray: GrayF32::default(),
            prev_features: Features::default(),
            keyframes: KeyframePool::new(KEYFRAMES),
            prev: Hypothesis::from_state(&PoseState::default()),
            prev_euler: Euler::default(),
            spin: Vector3::zeros(),
            low_count: 0,
            lost: false,
            held_axes: (1.0, 1.0),
            prev_confidence: 1.0,
            particles: Vec::new(),
            terms: Vec::new(),
            colour_model: ColourHistogram(Vec::new()),
            background: None,
            template: None,
            correlations: Vec::new(),
            anchor: None,
            anchor_correlations: Vec::new(),
            first: Estimate {
                frame: 0,
                state: PoseState::default(),
                ellipse: Ellipse::default(),
                confidence: 1.0,
                lost: false,
                matches: 0,
                ess: 0.0,
            },
        };
        t.reinit(first_frame, init)?;
        Ok(t)
    }

    /// Starts over on `frame` from `init`: a new colour model, new reference features, the
    /// filter reset. The frame becomes frame 0 of what follows only for the model: frame
    /// numbering continues. With [`TrackerConfig::init_refine`] the ellipse is refined on
    /// `frame` first ([`refine_ellipse`]); [`Tracker::initial_estimate`] gives the one used.
    pub fn reinit(&mut self, frame: &image::RgbImage, init: Init) -> crate::Result<()> {
        let (w, h) = frame.dimensions();
        check_init(&init, w, h).map_err(track_err)?;
        let init = match &self.cfg.init_refine {
            Some(r) => Init {
                ellipse: init_refine::refine_ellipse(frame, &init.ellipse, &self.cfg.likelihood, r),
                ..init
            },
            None => init,
        };
        self.size = (w, h);
        self.theta0 = init.ellipse.theta;
        let model =
            ColourHistogram::from_ellipse(frame, &init.ellipse, self.cfg.likelihood.colour_bins)?;
        self.engine.set_colour_model(&model)?;
        self.colour_model = model;
        self.background = None;
        if let Some(c) = self.cfg.contrast {
            let bins = self.cfg.likelihood.colour_bins;
            self.background = ring_histogram(frame, &init.ellipse, &c, bins);
            self.send_contrast_table()?;
        }
        let state = PoseState::from_parts(&init.ellipse, init.pose);
        let hyp = Hypothesis::from_state(&state);
        self.filter.set_frame(w, h);
        self.filter.set_aspect_range(aspect_range(
            &init.ellipse,
            self.cfg.likelihood.depth_ratio as f64,
            self.cfg.aspect_slack,
        ));
        self.filter.reset(&hyp);
        self.prev = hyp;
        self.prev_euler = init.pose;
        self.spin = Vector3::zeros();
        self.prev_gray = GrayF32::from_rgb(frame);
        self.template = self.cfg.template.map(|t| {
            crate::likelihood::template::Template::new(
                &self.prev_gray,
                &hyp.to_particle(),
                self.theta0 as f32,
                t.grid,
            )
        });
        self.anchor = match (&self.template, self.cfg.template) {
            (Some(t), Some(c)) if c.anchor_weight_for(self.camera().is_some()) > 0.0 => Some((
                t.clone(),
                crate::likelihood::template::FirstView {
                    particle: hyp.to_particle(),
                    depth_ratio: self.cfg.likelihood.depth_ratio,
                    camera: self.camera(),
                },
            )),
            _ => None,
        };
        self.anchor_correlations.clear();
        let region = search_region(&init.ellipse, w, h);
        self.prev_features = self
            .sift_for(&init.ellipse)
            .detect(&self.prev_gray, Some(region))?;
        self.reference = init.ellipse;
        let model = self.model(&hyp.rot, &init.ellipse);
        self.keyframes
            .reset(&self.prev_features, &init.ellipse, hyp, model);
        self.low_count = 0;
        self.lost = false;
        self.held_axes = (hyp.a, hyp.b);
        self.prev_confidence = 1.0;
        self.first = Estimate {
            frame: self.frame,
            state,
            ellipse: state.ellipse(self.theta0),
            confidence: 1.0,
            lost: false,
            matches: 0,
            ess: self.filter.params().particles as f64,
        };
        Ok(())
    }

    /// The estimate of the frame the tracker was (re)initialised on.
    pub fn initial_estimate(&self) -> Estimate {
        self.first
    }

    /// The configuration.
    pub fn config(&self) -> &TrackerConfig {
        &self.cfg
    }

    /// The particle filter (its particles, weights and last resampling), read only.
    pub fn filter(&self) -> &ParticleFilter {
        &self.filter
    }

    /// The likelihood engine's name.
    pub fn engine_name(&self) -> String {
        self.engine.name()
    }

    /// The colour model the likelihood engine holds now: the first frame's, moved by
    /// [`TrackerConfig::colour_update`] when the model adapts.
    pub fn colour_model(&self) -> &ColourHistogram {
        &self.colour_model
    }

    /// A one-line notice from the likelihood engine since the last call, taken once: e.g. that
    /// the GPU device was lost and the run goes on on the CPU
    /// ([`crate::likelihood::FallbackEngine`]). Callers should show it to the user.
    pub fn take_engine_notice(&mut self) -> Option<String> {
        self.engine.take_notice()
    }

    /// Tracks the target into the next frame.
    ///
    /// The step runs as one task of rayon's pool: called from outside the pool, the calling
    /// thread hands the whole step over and waits once, instead of once for each of the
    /// step's parallel parts (SIFT's bands, block matching beside SIFT, the particles'
    /// likelihoods, the template terms), each of which would otherwise wake a worker and
    /// put the caller to sleep again. Called from inside the pool it runs in place.
    pub fn step(&mut self, frame: &image::RgbImage) -> crate::Result<Estimate> {
        rayon::scope(|_| self.step_in_pool(frame))
    }

    /// [`Self::step`]'s work, on a thread of rayon's pool.
    fn step_in_pool(&mut self, frame: &image::RgbImage) -> crate::Result<Estimate> {
        let (w, h) = frame.dimensions();
        let index = self.frame + 1;
        self.keyframes.tick(index);
        if (w, h) != self.size {
            return Err(track_err(TrackError::FrameSize {
                frame: index,
                got_w: w,
                got_h: h,
                want_w: self.size.0,
                want_h: self.size.1,
            }));
        }
        let gray = GrayF32::from_rgb(frame);
        let prev_state = self.prev.to_state();
        let prev_ellipse = prev_state.ellipse(self.theta0);

        // Features: SIFT around the previous ellipse, matched to the previous frame's.
        // SIFT around the previous ellipse and block matching for the translation do
        // not depend on each other: on two cores they run side by side.
        let region = search_region(&prev_ellipse, w, h);
        let abm = crate::motion::AbmParams::for_target(&prev_ellipse);
        let sift = self.sift_for(&prev_ellipse);
        let (features, abm_result) = rayon::join(
            || sift.detect(&gray, Some(region)),
            || block_match(&self.prev_gray, &gray, &prev_ellipse, &abm),
        );
        let features = features?;

        // Rotation candidates from Sylvester's equation: against the keyframe when it still
        // matches (both members of the Necker pair, and "no change"), else between successive
        // frames.
        let solver = match self.cfg.mode {
            Mode::Sea | Mode::Tpe => SolverKind::Sea,
            Mode::Optimal => SolverKind::Optimal,
            Mode::Rls => SolverKind::Rls,
        };
        let use_key = self.cfg.mode != Mode::Tpe;
        // The matches with the previous frame and the rotation between the two frames.
        let (prev_features, matching) = (&self.prev_features, &self.cfg.matching);
        let consensus = self.cfg.interframe_consensus.as_ref();
        let between_frames = || {
            let pairs = correspondences(prev_features, matching, &prev_ellipse, &features);
            let inter = if pairs.len() >= 3 {
                let (p, q) = FeaturePair::split(&pairs);
                let centre = [prev_state.cx, prev_state.cy];
                interframe_consensus(&p, &q, centre, solver, consensus).ok()
            } else {
                None
            };
            (pairs, inter)
        };
        // Against the keyframes: the ellipsoid depth-prior fit from the previous pose, moved as
        // block matching says. It does not need the matches with the previous frame, so on two
        // cores both run side by side; when block matching failed, the features' median
        // motion stands in for it and the keyframe fit waits for the matches.
        let camera = self.camera();
        let keyframes = &self.keyframes;
        let against_keys = |ctx: &FitContext<'_>| {
            use_key
                .then(|| keyframes.best_fit(&features, ctx, KEYFRAME_TRIES, KEYFRAME_REACH))
                .flatten()
        };
        let (dx, dy, scale, ctx, ((pairs, inter), key_fit)) = match abm_result {
            Ok(r) => {
                let (dx, dy) = (r.translation[0], r.translation[1]);
                let ctx =
                    self.fit_context(&self.prev, nalgebra::Vector2::new(dx, dy), camera.as_ref());
                let both = rayon::join(between_frames, || against_keys(&ctx));
                (dx, dy, r.scale, ctx, both)
            }
            Err(_) => {
                let (pairs, inter) = between_frames();
                let (dx, dy) = median_displacement(&pairs);
                let mut ctx =
                    self.fit_context(&self.prev, nalgebra::Vector2::new(dx, dy), camera.as_ref());
                // The features' own displacement follows the texture, turn included: the
                // centre is held only to block matching's prediction of the region.
                if let Some(p) = &mut ctx.prior {
                    p.centre_sigma = None;
                }
                let key_fit = against_keys(&ctx);
                (dx, dy, 1.0, ctx, ((pairs, inter), key_fit))
            }
        };
        // Without a usable keyframe fit, the same model between the previous frame and this one.
        let mut inter_pairs = pairs.clone();
        let mut prior_prev = None;
        if key_fit.is_none() && pairs.len() >= self.cfg.min_fit_inliers && use_key {
            let model = self.model(&self.prev.rot, &prev_ellipse);
            if let Some((f, inl)) =
                keyframe::accepted_fit(&pairs, &model, &ctx, &Matrix3::identity(), 1.0)
            {
                inter_pairs = inl;
                prior_prev = Some(f);
            }
        }
        // The keyframe's depths adjusted with its views, this one included: the adjusted pose
        // of this view replaces the fit's.
        let mut key_fit = key_fit;
        if let (Some(k), Some(b)) = (key_fit.as_mut(), &self.cfg.bundle)
            && !self.lost
            && let Some(v) = self.keyframes.observe(k, camera.as_ref(), b)
        {
            k.fit.rot = v.rot;
            k.fit.scale = v.scale;
            k.fit.centre = v.centre;
        }
        let (lik_pairs, lik_prev) = match &key_fit {
            Some(k) => (&k.pairs, k.key),
            None => (&inter_pairs, self.prev),
        };
        let key_inter = key_fit.is_some() || prior_prev.is_some();
        let mut lp = self.cfg.likelihood;
        let (dx, dy, scale, rotations) = match (&key_fit, &prior_prev, &inter, self.cfg.mode) {
            (_, _, _, Mode::Tpe) => (dx, dy, scale, vec![(1.0, Matrix3::identity())]),
            (Some(k), _, _, _) => {
                let at = k.placed();
                (
                    at.cx - self.prev.cx,
                    at.cy - self.prev.cy,
                    k.fit.scale / k.prev_scale,
                    vec![(1.0, at.rot * self.prev.rot.transpose())],
                )
            }
            (None, Some(f), _, _) => (
                f.centre.x - self.prev.cx,
                f.centre.y - self.prev.cy,
                f.scale,
                vec![(1.0, f.rot)],
            ),
            (None, None, Some(i), _) => (dx, dy, scale, vec![(0.5, i.pair.a), (0.5, i.pair.b)]),
            // Nothing measured the rotation: the turn carries on as it went.
            (None, None, None, _) => (dx, dy, scale, vec![(1.0, exp_so3(&self.spin))]),
        };
        let motion = Motion {
            dx,
            dy,
            scale: if self.cfg.motion_scale { scale } else { 1.0 },
            rotations,
        };
        if self.cfg.mode == Mode::Tpe || lik_pairs.is_empty() {
            lp.terms &= !TERM_FEATURE;
        }
        // The contrast term as a share of the previous estimate's area.
        self.enable_contrast(&mut lp, prev_state.a * prev_state.b);

        // The filter step.
        let spread = if self.lost { 3.0 } else { 1.0 };
        let unsure = holds_size(&self.cfg, self.lost, self.prev_confidence);
        self.filter.set_size_range(
            self.cfg
                .size_hold
                .filter(|_| unsure)
                .and_then(|k| SizeRange::around(self.held_axes.0, self.held_axes.1, k)),
        );
        self.filter.propose(&motion, spread);
        self.filter.particles_f32(&mut self.particles);
        let depths = self.feature_depths(lik_pairs, &lik_prev);
        let input = FrameInput {
            image: frame,
            features: lik_pairs,
            depths: depths.as_deref(),
            prev: lik_prev.to_particle(),
            theta0: self.theta0 as f32,
        };
        self.engine
            .evaluate(&input, &lp, &self.particles, &mut self.terms)?;
        self.correlate_template(&gray);
        let totals = self.weighted_totals(&lp);
        let info = self.filter.update(&totals);
        let mut est = self.filter.estimate();

        // TPE: the rotation from the features of the tracked region, after tracking.
        if self.cfg.mode == Mode::Tpe
            && let Some(i) = &inter
        {
            let centre_motion =
                nalgebra::Vector2::new(est.cx - prev_state.cx, est.cy - prev_state.cy);
            let delta = crate::pose::resolve_by_parallax(&i.pair, i.translation - centre_motion);
            self.filter.rotate_all(&delta);
            est = self.filter.estimate();
        }

        // Confidence from the weighted colour similarity and contour support.
        let weights = crate::filter::resample::normalise_log_weights(
            &totals.iter().map(|&t| t as f64).collect::<Vec<_>>(),
        );
        let rotation_measured = inter.is_some() || key_inter;
        let mut confidence = self.confidence(&lp, &weights, rotation_measured);
        // Whether the estimate was moved by a reset rather than tracked (for the spin).
        let mut jumped = false;
        // Loop closure on appearance: the first view found again beside the estimate, and
        // clearly better there than the estimate's own pose and place explain it. Its pose
        // counts as measured only when the first view had the features to show a turn: a
        // target without texture correlates with its first view at any pose.
        if !self.lost
            && let Some(found) = self.reanchor(&gray, &est, confidence)
        {
            let textured = self.keyframes.anchor_features() >= self.cfg.min_fit_inliers;
            let (_, c) = self.own_confidence(&input, lp, &found, textured)?;
            if c >= self.cfg.lost_below {
                self.filter.reset(&found);
                est = found;
                confidence = c;
                jumped = true;
            }
        }
        // Loop closure on the pose: the first view, turned, explained clearly better by
        // another tilt and pan at the estimate's place.
        else if !self.lost
            && let Some(found) = self.repose(&gray, &est, confidence)
        {
            self.filter.reset(&found);
            est = found;
            jumped = true;
        }
        (self.low_count, self.lost) = lost_state(&self.cfg, self.low_count, self.lost, confidence);
        if self.low_count >= self.cfg.lost_after
            && let Some((found, c)) = self.reacquire(frame, &gray, &est)?
        {
            self.filter.reset(&found);
            est = found;
            confidence = c;
            self.low_count = 0;
            self.lost = false;
            jumped = true;
        }

        if !self.lost {
            self.adapt_template(&gray, &est, confidence);
            let model_moved = self.adapt_colour(frame, &est, confidence)?;
            let ring_moved = self.adapt_background(frame, &est, confidence);
            if model_moved || ring_moved {
                self.send_contrast_table()?;
            }
        }

        // Angles continuous with the previous output.
        let euler = continuous_euler(&est.rot, &self.prev_euler);
        let state = PoseState {
            cx: est.cx,
            cy: est.cy,
            a: est.a,
            b: est.b,
            rx: euler.rx,
            ry: euler.ry,
            rz: euler.rz,
        };
        if !holds_size(&self.cfg, self.lost, confidence) {
            self.held_axes = (est.a, est.b);
        }
        self.prev_confidence = confidence;
        self.spin = self.cfg.coast_rate.map_or_else(Vector3::zeros, |rate| {
            let step = log_so3(&(est.rot * self.prev.rot.transpose()));
            let moved = match (self.lost, jumped, rotation_measured) {
                (true, _, _) => Moved::Lost,
                (false, true, _) => Moved::Reset,
                (false, false, false) => Moved::Unmeasured,
                (false, false, true) => Moved::Tracked,
            };
            smoothed_spin(&self.spin, &step, rate, moved)
        });
        self.prev = est;
        self.prev_euler = euler;
        self.prev_gray = gray;
        // A new keyframe when the pool's views have drifted out of reach of the matcher, taken
        // only on a confident frame: a view taken off the target would recognise the background.
        let due = use_key
            && self.keyframes.record(
                key_fit.as_ref(),
                self.cfg.min_fit_inliers,
                self.cfg.keyframe_refresh_percent,
            );
        if due && !self.unsure() {
            let e = state.ellipse(self.theta0);
            let model = self.model(&est.rot, &e);
            self.keyframes.add(&features, &e, est, model);
        }
        self.prev_features = features;
        self.frame = index;
        Ok(Estimate {
            frame: index,
            state,
            ellipse: state.ellipse(self.theta0),
            confidence,
            lost: self.lost,
            matches: pairs.len(),
            ess: info.ess,
        })
    }

    /// The particles' correlations with the template into `self.correlations`, for
    /// [`Self::weighted_totals`]; left empty when the term is off.
    fn correlate_template(&mut self, gray: &GrayF32) {
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
    fn adapt_template(&mut self, gray: &GrayF32, est: &Hypothesis, confidence: f64) {
        let (Some(cfg), Some(t)) = (self.cfg.template, self.template.as_mut()) else {
            return;
        };
        let rate = cfg.rate;
        if confidence >= cfg.min_confidence && rate > 0.0 {
            t.blend_towards(gray, &est.to_particle(), self.theta0 as f32, rate as f32);
        }
    }

    /// The SIFT detector for a target the size of `e`: without the doubled first octave from
    /// [`TrackerConfig::sift_upsample_below`] on.
    fn sift_for(&self, e: &Ellipse) -> &Sift {
        match (&self.sift_large, self.cfg.sift_upsample_below) {
            (Some(large), Some(min)) if 2.0 * (e.a * e.b).sqrt() >= min => large,
            _ => &self.sift,
        }
    }

    /// Whether the tracker is unsure of the target: lost, or its confidence below
    /// [`TrackerConfig::lost_below`] on the last frame.
    fn unsure(&self) -> bool {
        self.lost || self.low_count > 0
    }

    /// Turns the contrast term on in `lp` when it is configured and has a background, as the
    /// mean log-odds over an ellipse of semi-axes product `ab` ([`Contrast::weight`]).
    fn enable_contrast(&self, lp: &mut LikelihoodParams, ab: f64) {
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
    fn send_contrast_table(&mut self) -> crate::Result<()> {
        if let (Some(c), Some(bg)) = (self.cfg.contrast, &self.background) {
            let table = ContrastTable::from_histograms(&self.colour_model, bg, c.limit as f32)?;
            self.engine.set_contrast_table(&table)?;
        }
        Ok(())
    }

    /// After a frame with at least [`Contrast::min_confidence`], moves the contrast term's
    /// background towards the ring around the estimate `est`
    /// ([`Contrast::background_rate`]). Returns whether it moved; the caller then sends the
    /// new table ([`Self::send_contrast_table`]).
    fn adapt_background(
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
        let Some(seen) = ring_histogram(frame, &e, &c, self.cfg.likelihood.colour_bins) else {
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
    fn adapt_colour(
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
        let bins = self.cfg.likelihood.colour_bins;
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

    /// The keyframe fits' settings from the configuration, for a fit from `prev` moved by
    /// `shift` seen through `camera` ([`Tracker::camera`]): matching, the acceptance
    /// thresholds, the largest step and the motion prior.
    fn fit_context<'a>(
        &'a self,
        prev: &'a Hypothesis,
        shift: nalgebra::Vector2<f64>,
        camera: Option<&'a crate::pose::prior::Pinhole>,
    ) -> FitContext<'a> {
        FitContext {
            prev,
            shift,
            camera,
            matching: &self.cfg.matching,
            min_inliers: self.cfg.min_fit_inliers,
            max_residual: self.cfg.max_fit_residual,
            max_step: self.cfg.max_rotation_step,
            prior: fit_prior(&self.cfg),
            anchor_refit: self.cfg.anchor_refit,
        }
    }

    /// The camera of the keyframe fits, `None` for weak perspective.
    fn camera(&self) -> Option<crate::pose::prior::Pinhole> {
        self.cfg
            .camera_hfov_deg
            .and_then(|h| crate::pose::prior::Pinhole::from_hfov(self.size.0, self.size.1, h))
    }

    /// The depths the feature term lifts the matches `pairs` of the view `view` with: on the
    /// object model turned to the view's estimated pose ([`Tracker::model`]) when the camera
    /// is known; `None` (the ellipsoid facing the camera) without one.
    ///
    /// The facing ellipsoid is deeper than the turned one where the object has turned about
    /// x or y (about 17 % on the synthetic head panned 60°), which under-reads the turn; under
    /// weak perspective that makes up for the over-reading of a near object's turn, so without
    /// a camera it stays. With the camera (`scripts/eval_seeds.sh synth -- --hfov 50`,
    /// scenario seeds 0-11, 2026-12-04) the turned model brought the pan's RMSE about y from
    /// 3.13° to 2.75° (filter seed 0), and with the anchor weight of
    /// [`TemplateTerm::anchor_weight_camera`], the pan and `combo` summed over their axes
    /// from 13.3° to 13.1° (filter seed 0) and from 15.1° to 13.5° (each scenario's seed).
    fn feature_depths(&self, pairs: &[FeaturePair], view: &Hypothesis) -> Option<Vec<f32>> {
        self.camera()?;
        let model = self.model(&view.rot, &view.to_state().ellipse(self.theta0));
        let points: Vec<[f64; 2]> = pairs
            .iter()
            .map(|f| [f.p[0] as f64, f.p[1] as f64])
            .collect();
        Some(
            crate::pose::prior::lift(&points, &model, None)
                .iter()
                .map(|x| x.z as f32)
                .collect(),
        )
    }

    /// The object model in a view with estimated rotation `rot` and ellipse `view`: the first
    /// frame's ellipse, as deep as the likelihood's depth ratio says, turned by `rot`.
    fn model(&self, rot: &Matrix3<f64>, view: &Ellipse) -> crate::pose::prior::Ellipsoid {
        crate::pose::prior::Ellipsoid::posed(
            &self.reference,
            self.cfg.likelihood.depth_ratio as f64,
            rot,
            view,
        )
    }

    /// Each particle's log-likelihood: the enabled terms of the last evaluation, the feature
    /// term weighted by [`TrackerConfig::feature_weight`], plus the template term
    /// ([`TemplateTerm::weight`] times the particle's correlation, when the term is on) and
    /// the turned first view's ([`TemplateTerm::anchor_weight_for`]).
    fn weighted_totals(&self, lp: &LikelihoodParams) -> Vec<f32> {
        let wf = self.cfg.feature_weight as f32;
        let wt = self.cfg.template.map_or(0.0, |t| t.weight as f32);
        let camera_known = self.camera().is_some();
        let (wa, ta) = self.cfg.template.map_or((0.0, 0.0), |t| {
            (
                t.anchor_weight_for(camera_known) as f32,
                t.anchor_threshold as f32,
            )
        });
        self.terms
            .iter()
            .enumerate()
            .map(|(i, t)| {
                if t.total <= crate::likelihood::DEGENERATE {
                    return t.total;
                }
                let mut s = 0.0;
                if lp.terms & TERM_COLOUR != 0 {
                    s += t.colour;
                }
                if lp.terms & TERM_GRADIENT != 0 {
                    s += t.gradient;
                }
                if lp.terms & TERM_FEATURE != 0 {
                    s += wf * t.feature;
                }
                if lp.terms & TERM_CONTRAST != 0 {
                    s += t.contrast;
                }
                if let Some(c) = self.correlations.get(i) {
                    s += wt * c;
                }
                if let Some(c) = self.anchor_correlations.get(i) {
                    s += wa * (c - ta).max(0.0);
                }
                s
            })
            .collect()
    }

    /// Confidence in `[0, 1]`: the weighted colour similarity ρ̄ (recovered from the colour
    /// term, `ρ = 1 + 2σc² ln p_colour`) mapped from [0.5, 1] to [0, 1], times the weighted
    /// share of normal lines with contour support, square-rooted (a geometric mean); times 0.8
    /// when no features measured the rotation.
    fn confidence(&self, lp: &LikelihoodParams, w: &[f64], rotation_measured: bool) -> f64 {
        let mut colour = 1.0;
        if lp.terms & TERM_COLOUR != 0 {
            let rho: f64 = self
                .terms
                .iter()
                .zip(w)
                .map(|(t, w)| w * rho_from_log(t.colour, lp.sigma_colour))
                .sum();
            colour = ((rho - 0.5) / 0.5).clamp(0.0, 1.0);
        }
        let mut edges = 1.0;
        if lp.terms & TERM_GRADIENT != 0 && lp.num_lines > 0 {
            // Every line's edge on the contour: the term's largest value.
            let k = f64::from(crate::likelihood::cpu::gradient::clutter_gain(lp));
            let full = lp.num_lines as f64 * (1.0 + k).ln();
            let g: f64 = self
                .terms
                .iter()
                .zip(w)
                .map(|(t, w)| w * t.gradient as f64)
                .sum();
            edges = (g / full).clamp(0.0, 1.0);
        }
        let c = (colour * edges).sqrt();
        if rotation_measured { c } else { 0.8 * c }
    }

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
    fn reanchor(&self, gray: &GrayF32, est: &Hypothesis, confidence: f64) -> Option<Hypothesis> {
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
        let (area, aspect) = (est.a * est.b, self.reference.a / self.reference.b);
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
    fn repose(&self, gray: &GrayF32, est: &Hypothesis, confidence: f64) -> Option<Hypothesis> {
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
        let turn = (q.rx - p.rx).abs().max((q.ry - p.ry).abs()).to_degrees();
        if turn < REPOSE_STEP_DEG {
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

    /// The colour similarity and confidence of one hypothesis on this frame's `input`, as
    /// the frame reports it: from the colour and contour terms of `lp` alone, discounted as
    /// [`Self::confidence`] does unless `rotation_measured`.
    fn own_confidence(
        &mut self,
        input: &FrameInput<'_>,
        mut lp: LikelihoodParams,
        h: &Hypothesis,
        rotation_measured: bool,
    ) -> crate::Result<(f64, f64)> {
        let mut shown = self.cfg.likelihood;
        shown.terms &= TERM_COLOUR | TERM_GRADIENT;
        lp.terms = TERM_COLOUR | shown.terms;
        self.engine
            .evaluate(input, &lp, &[h.to_particle()], &mut self.terms)?;
        let rho = self
            .terms
            .first()
            .map_or(0.0, |t| rho_from_log(t.colour, lp.sigma_colour));
        Ok((rho, self.confidence(&shown, &[1.0], rotation_measured)))
    }

    /// Looks for the target over the whole frame: by colour first, ellipses at
    /// [`REACQUIRE_SCALES`] times the initial ellipse's size on a grid of half a semi-axis,
    /// all evaluated in one engine call and ranked by the colour term plus, when it is on,
    /// the contrast term (which prefers the size holding the target's colours and no more);
    /// the best one, when its colour similarity reaches [`TrackerConfig::reacquire_rho`], is
    /// then verified by its features, which must fit one of the keyframes (any pose).
    /// With [`TrackerConfig::reacquire_ncc`], the candidate of the target's colours that
    /// correlates best with its templates ([`Self::template_correlations`]) is taken instead
    /// when it reaches that correlation, and is recognised by it even when its features fit
    /// no keyframe.
    /// Returns the target as the fit places it (or as the template found it), with its own
    /// confidence, when it lies where it was searched ([`placed_within`]), passes the
    /// candidate's colour test and is as confident as a found track ([`reacquired`]).
    ///
    /// The sizes come from the initial ellipse, not from the track: a track is declared lost
    /// only after its estimate has drifted for a while, and by then its size is no guide (on
    /// OTB girl the last estimate above the lost threshold was 2 x 2 px on a 13 x 17 px head,
    /// on car4 96 x 104 px on a 34 x 26 px car).
    fn reacquire(
        &mut self,
        frame: &image::RgbImage,
        gray: &GrayF32,
        est: &Hypothesis,
    ) -> crate::Result<Option<(Hypothesis, f64)>> {
        let (w, h) = self.size;
        let cands = search_grid(&self.reference, w, h, &Euler::from_matrix(&est.rot));
        let mut lp = self.cfg.likelihood;
        lp.terms = TERM_COLOUR;
        // The contrast sum over the same area for every size, the initial ellipse's.
        self.enable_contrast(&mut lp, self.reference.a * self.reference.b);
        let input = FrameInput {
            image: frame,
            features: &[],
            depths: None,
            prev: self.prev.to_particle(),
            theta0: self.theta0 as f32,
        };
        let mut out = Vec::new();
        self.engine.evaluate(&input, &lp, &cands, &mut out)?;
        let rhos: Vec<f64> = out
            .iter()
            .map(|t| rho_from_log(t.colour, lp.sigma_colour))
            .collect();
        let best = out
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total.total_cmp(&b.1.total))
            .map(|(i, _)| (i, rhos[i]));
        // Among the candidates of the target's colours, the one its template recognises best,
        // each of the best few placed first to the template on a finer grid (the search's
        // grid, half a semi-axis, is too coarse for a sharp texture to correlate).
        // (The correlations are computed only when the template may recognise a candidate.)
        let recognised = self.cfg.reacquire_ncc.and_then(|min_ncc| {
            let ncc = self.template_correlations(gray, &cands)?;
            best_by_template(&rhos, &ncc, self.cfg.reacquire_rho, TEMPLATE_REFINED)
                .into_iter()
                .filter_map(|(i, _)| self.refine_by_template(gray, &cands[i]))
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .filter(|&(_, n)| f64::from(n) >= min_ncc)
        });
        let chosen = match (recognised, best) {
            (Some((p, _)), _) => p,
            (None, Some((i, rho))) if rho >= self.cfg.reacquire_rho => cands[i],
            _ => return Ok(None),
        };
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
        let features = self.sift_for(&e).detect(gray, Some(region))?;
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
        let Some(placed) = fit
            .map(|k| k.placed())
            .or(recognised.is_some().then_some(found))
        else {
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
        // own (its features measured the rotation), not the lost track's; one evaluation
        // gives the colour test and the confidence.
        let (rho, c) = self.own_confidence(&input, lp, &placed, true)?;
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

/// Whether the ellipse's size is held ([`TrackerConfig::size_hold`]) on the frame after one
/// of confidence `c` that left the tracker `lost` or not: while the target is lost, or after
/// a frame the tracker did not trust (below [`TrackerConfig::found_above`]). The size a
/// frame that is not held ends with becomes the one later frames are held near. Why
/// `found_above` and not [`TrackerConfig::lost_below`]: see [`TrackerConfig::size_hold`].
fn holds_size(cfg: &TrackerConfig, lost: bool, c: f64) -> bool {
    lost || c < cfg.found_above
}

/// The tracker's lost state after a frame of confidence `c`, from `low` (consecutive frames
/// below [`TrackerConfig::lost_below`], or more while lost) and `lost`: a frame below
/// `lost_below` counts one more; a lost target stays lost, and `low` where it was, until a
/// frame reaches [`TrackerConfig::found_above`]; otherwise the count starts over. The
/// target is declared lost once `low` reaches [`TrackerConfig::lost_after`] (the caller
/// then searches for it).
fn lost_state(cfg: &TrackerConfig, low: usize, lost: bool, c: f64) -> (usize, bool) {
    if c < cfg.lost_below {
        let low = low.saturating_add(1);
        (low, lost || low >= cfg.lost_after)
    } else if lost && c < cfg.found_above {
        (low, true)
    } else {
        (0, false)
    }
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

/// Whether every pixel of `frame` is grey (`R = G = B`): grayscale footage read as RGB.
fn is_grey(frame: &image::RgbImage) -> bool {
    frame
        .as_raw()
        .chunks_exact(3)
        .all(|p| p[0] == p[1] && p[1] == p[2])
}

fn track_err(e: TrackError) -> crate::Error {
    crate::Error::Track(e)
}

/// Matched features between the previous frame's (`prev`, those inside `prev_ellipse`) and
/// this one's (`cur`), after the paper's slope/length outlier rejection.
fn correspondences(
    prev: &Features,
    matching: &crate::features::MatchParams,
    prev_ellipse: &Ellipse,
    cur: &Features,
) -> Vec<FeaturePair> {
    let matches = match_features(prev, cur, matching);
    let mut p = Vec::new();
    let mut q = Vec::new();
    for m in &matches {
        let a = &prev.keypoints[m.query];
        let b = &cur.keypoints[m.train];
        if prev_ellipse.contains(a.x as f64, a.y as f64) {
            p.push([a.x as f64, a.y as f64]);
            q.push([b.x as f64, b.y as f64]);
        }
    }
    if p.len() < 3 {
        return Vec::new();
    }
    let (p, q) = keep_slope_length(&p, &q, 0.2, 0.3);
    p.iter()
        .zip(&q)
        .map(|(p, q)| FeaturePair {
            p: [p[0] as f32, p[1] as f32],
            q: [q[0] as f32, q[1] as f32],
        })
        .collect()
}

/// The median displacement of matched features, (0, 0) without any.
fn median_displacement(pairs: &[FeaturePair]) -> (f64, f64) {
    if pairs.is_empty() {
        return (0.0, 0.0);
    }
    let med = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let dx = med(pairs.iter().map(|f| (f.q[0] - f.p[0]) as f64).collect());
    let dy = med(pairs.iter().map(|f| (f.q[1] - f.p[1]) as f64).collect());
    (dx, dy)
}

/// The Euler angles of `r` closest to `prev`: of the two triples that give the same rotation,
/// `(rx, ry, rz)` and `(rx + π, π − ry, rz + π)`, each angle unwrapped to within π of the
/// previous one, the one nearest `prev`. Keeps output angles continuous through ±180°.
pub fn continuous_euler(r: &Matrix3<f64>, prev: &Euler) -> Euler {
    use std::f64::consts::PI;
    let e = Euler::from_matrix(r);
    let unwrap = |a: f64, p: f64| p + crate::geometry::wrap_pi(a - p);
    let cands = [
        Euler::new(e.rx, e.ry, e.rz),
        Euler::new(e.rx + PI, PI - e.ry, e.rz + PI),
    ];
    let mut best = cands[0];
    let mut best_d = f64::INFINITY;
    for c in cands {
        let u = Euler::new(
            unwrap(c.rx, prev.rx),
            unwrap(c.ry, prev.ry),
            unwrap(c.rz, prev.rz),
        );
        let d = (u.rx - prev.rx).powi(2) + (u.ry - prev.ry).powi(2) + (u.rz - prev.rz).powi(2);
        if d < best_d {
            best_d = d;
            best = u;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::angle_between;

    #[test]
    fn continuous_euler_passes_through_180_without_jumps() {
        let mut prev = Euler::default();
        for k in 0..=72 {
            let truth = Euler::new(0.1, (k as f64 * 5.0).to_radians(), -0.05);
            let e = continuous_euler(&truth.matrix(), &prev);
            assert!(angle_between(&e.matrix(), &truth.matrix()) < 1e-9);
            assert!((e.ry - truth.ry).abs() < 1e-9, "k {k}: {e:?}");
            prev = e;
        }
    }

    #[test]
    fn the_aspect_range_is_the_model_outlines_widened_by_the_slack() {
        // Semi-axes 18 and 24, as deep as sqrt(18 · 24) = 20.78 (depth ratio 1): the
        // outlines' aspect runs from 18/24 to 24/18.
        let e = Ellipse::new(50.0, 40.0, 18.0, 24.0);
        let r = aspect_range(&e, 1.0, Some(1.0)).unwrap();
        assert!((r.lo() - 0.75).abs() < 1e-12 && (r.hi() - 4.0 / 3.0).abs() < 1e-12);
        // A flat object (depth ratio 0.25, 5.196 deep) can turn edge-on: a wider range.
        let flat = aspect_range(&e, 0.25, Some(1.0)).unwrap();
        let d = 0.25 * (18.0f64 * 24.0).sqrt();
        assert!((flat.lo() - d / 24.0).abs() < 1e-12 && (flat.hi() - 24.0 / d).abs() < 1e-12);
        // The slack widens it by its factor on both sides; no slack, no range.
        let wide = aspect_range(&e, 1.0, Some(1.5)).unwrap();
        assert!((wide.lo() - 0.5).abs() < 1e-12 && (wide.hi() - 2.0).abs() < 1e-12);
        assert!(aspect_range(&e, 1.0, None).is_none());
    }

    #[test]
    fn the_size_is_held_after_an_untrusted_frame_or_while_lost() {
        let cfg = TrackerConfig::default();
        let band = 0.5 * (cfg.lost_below + cfg.found_above);
        assert!(band >= cfg.lost_below && band < cfg.found_above);
        // Below the lost bar and in the band between the two bars: held.
        assert!(holds_size(&cfg, false, 0.5 * cfg.lost_below));
        assert!(holds_size(&cfg, false, band));
        // A trusted frame frees it, unless the target is still lost.
        assert!(!holds_size(&cfg, false, cfg.found_above));
        assert!(!holds_size(&cfg, false, 1.0));
        assert!(holds_size(&cfg, true, 1.0));
        // With `found_above` at `lost_below`, the hold starts below the lost bar.
        let low = TrackerConfig {
            found_above: cfg.lost_below,
            ..cfg.clone()
        };
        assert!(!holds_size(&low, false, band));
        assert!(holds_size(&low, false, 0.5 * cfg.lost_below));
    }

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
                    s = lost_state(&cfg, s.0, s.1, c);
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
        assert_eq!(lost_state(&old, 3, true, band), (0, false));
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
    fn found_above_and_reacquire_ncc_are_checked() {
        let bad = [
            TrackerConfig {
                found_above: 0.2,
                ..TrackerConfig::default()
            },
            TrackerConfig {
                found_above: 1.5,
                ..TrackerConfig::default()
            },
            TrackerConfig {
                reacquire_ncc: Some(f64::NAN),
                ..TrackerConfig::default()
            },
            TrackerConfig {
                reacquire_ncc: Some(1.1),
                ..TrackerConfig::default()
            },
        ];
        for cfg in bad {
            assert!(
                matches!(check_config(&cfg), Err(TrackError::BadConfig(_))),
                "{cfg:?}"
            );
        }
        assert!(check_config(&TrackerConfig::default()).is_ok());
    }

    #[test]
    fn a_refined_start_is_the_one_the_tracker_uses() {
        let bad = TrackerConfig {
            init_refine: Some(InitRefine {
                ring: 0.5,
                ..Default::default()
            }),
            ..TrackerConfig::default()
        };
        assert!(matches!(check_config(&bad), Err(TrackError::BadConfig(_))));
        let (first, truth) = nod_first();
        let high = Ellipse {
            cy: truth.cy - 3.0,
            ..truth
        };
        let cfg = TrackerConfig {
            init_refine: Some(InitRefine::default()),
            ..TrackerConfig::default()
        };
        let mut t = Tracker::new(cfg, &first, Init::frontal(high)).unwrap();
        let used = t.initial_estimate().ellipse;
        assert!(
            (used.cy - truth.cy).abs() < 0.5,
            "{used:?} against {truth:?}"
        );
        // Again on reinit, from a start off the other way.
        let left = Ellipse {
            cx: truth.cx - 3.0,
            ..truth
        };
        t.reinit(&first, Init::frontal(left)).unwrap();
        let used = t.initial_estimate().ellipse;
        assert!(
            (used.cx - truth.cx).abs() < 0.5,
            "{used:?} against {truth:?}"
        );
        // Off by default: the given ellipse as it is.
        let (t, _, _) = nod_tracker(TrackerConfig::default());
        assert_eq!(t.initial_estimate().ellipse, truth);
    }

    #[test]
    fn large_targets_get_sift_without_the_doubled_octave() {
        for bad in [0.0, -5.0, f64::NAN, f64::INFINITY] {
            let cfg = TrackerConfig {
                sift_upsample_below: Some(bad),
                ..TrackerConfig::default()
            };
            assert!(matches!(check_config(&cfg), Err(TrackError::BadConfig(_))));
        }
        let (t, gray, init) = nod_tracker(TrackerConfig::default());
        // The nod's head at 160x120 is about 43 px across: the doubled octave.
        assert!(2.0 * (init.a * init.b).sqrt() < 120.0);
        assert!(t.sift_for(&init).params().upsample);
        let wide = Ellipse {
            a: 3.0 * init.a,
            b: 3.0 * init.b,
            ..init
        };
        assert!(2.0 * (wide.a * wide.b).sqrt() >= 120.0);
        assert!(!t.sift_for(&wide).params().upsample);
        // Both detectors find the frame's features; the plain one fewer, at coarser scales.
        let region = search_region(&init, gray.width, gray.height);
        let fine = t.sift_for(&init).detect(&gray, Some(region)).unwrap();
        let coarse = t.sift_for(&wide).detect(&gray, Some(region)).unwrap();
        assert!(!coarse.is_empty() && coarse.len() < fine.len());
        // Off, or with the doubled octave off in the SIFT settings, one detector serves all.
        for cfg in [
            TrackerConfig {
                sift_upsample_below: None,
                ..TrackerConfig::default()
            },
            TrackerConfig {
                sift: crate::features::SiftParams {
                    upsample: false,
                    ..Default::default()
                },
                ..TrackerConfig::default()
            },
        ] {
            let want = cfg.sift.upsample;
            let (t, _, _) = nod_tracker(cfg);
            assert!(t.sift_large.is_none());
            assert_eq!(t.sift_for(&wide).params().upsample, want);
        }
    }

    /// The first frame of the synthetic `nod` and its true ellipse.
    fn nod_first() -> (image::RgbImage, Ellipse) {
        let r = crate::synth::Renderer::new(&crate::synth::SynthConfig::new(
            crate::synth::Scenario::Nod,
        ))
        .unwrap();
        (r.render(0).0, r.init_ellipse())
    }

    /// A tracker on the first frame of the synthetic `nod`, with that frame's grey image
    /// and the initial ellipse.
    fn nod_tracker(cfg: TrackerConfig) -> (Tracker, GrayF32, Ellipse) {
        let (first, init) = nod_first();
        let t = Tracker::new(cfg, &first, Init::frontal(init)).unwrap();
        (t, GrayF32::from_rgb(&first), init)
    }

    #[test]
    fn the_feature_term_lifts_onto_the_turned_model_only_with_a_camera() {
        let (weak, _, init) = nod_tracker(TrackerConfig::default());
        let pairs: Vec<FeaturePair> = [(0.0, 0.0), (0.5, -0.3), (-0.6, 0.4), (0.2, 0.8)]
            .iter()
            .map(|&(u, v)| {
                let p = [(init.cx + u * init.a) as f32, (init.cy + v * init.b) as f32];
                FeaturePair { p, q: p }
            })
            .collect();
        let front = in_place(&init, 0.0, 0.0);
        assert!(weak.feature_depths(&pairs, &front).is_none());
        let cfg = TrackerConfig {
            camera_hfov_deg: Some(50.0),
            ..TrackerConfig::default()
        };
        let (cam, _, _) = nod_tracker(cfg);
        let facing = |view: &Hypothesis| -> Vec<f32> {
            pairs
                .iter()
                .map(|f| {
                    crate::likelihood::cpu::feature::lift(
                        f.p,
                        &view.to_particle(),
                        cam.theta0 as f32,
                        cam.cfg.likelihood.depth_ratio,
                    )[2]
                })
                .collect()
        };
        // In the first pose the turned model is the facing one.
        let got = cam.feature_depths(&pairs, &front).unwrap();
        for (g, w) in got.iter().zip(facing(&front)) {
            assert!((g - w).abs() < 1e-3, "{g} against {w}");
        }
        // Panned 60°, the turned head is shallower under the ellipse's centre than the
        // ellipsoid facing the camera with that outline (about 17 % on this head).
        let panned = in_place(&init, 0.0, 60f64.to_radians());
        let got = cam.feature_depths(&pairs, &panned).unwrap();
        let want = facing(&panned);
        assert!(
            got[0] < 0.0 && got[0] > 0.95 * want[0],
            "{} against {}",
            got[0],
            want[0]
        );
        assert!(got.iter().zip(&want).any(|(g, w)| (g - w).abs() > 0.5));
    }

    /// The estimate at the first ellipse, tilted by `rx` and panned by `ry` (radians).
    fn in_place(init: &Ellipse, rx: f64, ry: f64) -> Hypothesis {
        Hypothesis::from_state(&PoseState::from_parts(init, Euler::new(rx, ry, 0.0)))
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
    fn the_spin_follows_a_steady_turn_and_ignores_resets_and_jumps() {
        let step = Vector3::new(0.0, 0.02, 0.0);
        let mut spin = Vector3::zeros();
        for _ in 0..30 {
            spin = smoothed_spin(&spin, &step, 1.0 / 3.0, Moved::Tracked);
        }
        assert!((spin - step).norm() < 1e-6, "{spin:?}");
        // One frame's step moves it a third of the way.
        let first = smoothed_spin(&Vector3::zeros(), &step, 1.0 / 3.0, Moved::Tracked);
        assert!((first.y - 0.02 / 3.0).abs() < 1e-12);
        // A reset's correction and a jump beyond the bound are not motion; a lost frame
        // knows none.
        let big = Vector3::new(0.3, 0.0, 0.0);
        assert_eq!(smoothed_spin(&spin, &big, 1.0 / 3.0, Moved::Reset), spin);
        assert_eq!(smoothed_spin(&spin, &big, 1.0 / 3.0, Moved::Tracked), spin);
        let nan = Vector3::new(f64::NAN, 0.0, 0.0);
        assert_eq!(smoothed_spin(&spin, &nan, 1.0 / 3.0, Moved::Tracked), spin);
        assert_eq!(
            smoothed_spin(&spin, &step, 1.0 / 3.0, Moved::Lost),
            Vector3::zeros()
        );
        // Unmeasured frames keep the last measured spin, whatever their own step (the spin's
        // proposal plus the filter's noise): it does not feed on itself.
        assert_eq!(
            smoothed_spin(&spin, &big, 1.0 / 3.0, Moved::Unmeasured),
            spin
        );
        assert_eq!(
            smoothed_spin(&Vector3::zeros(), &step, 1.0 / 3.0, Moved::Unmeasured),
            Vector3::zeros()
        );
        // At rate 1 the spin is the last step.
        let s = smoothed_spin(&spin, &(step * 2.0), 1.0, Moved::Tracked);
        assert!((s - step * 2.0).norm() < 1e-15);
    }

    #[test]
    fn coast_rate_is_checked() {
        for rate in [0.0, -0.1, 1.5, f64::NAN] {
            let cfg = TrackerConfig {
                coast_rate: Some(rate),
                ..TrackerConfig::default()
            };
            assert!(
                matches!(check_config(&cfg), Err(TrackError::BadConfig(_))),
                "{rate}"
            );
        }
        for rate in [Some(1.0), Some(0.01), None] {
            let cfg = TrackerConfig {
                coast_rate: rate,
                ..TrackerConfig::default()
            };
            assert!(check_config(&cfg).is_ok(), "{rate:?}");
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
                matches!(check_config(&cfg), Err(TrackError::BadConfig(_))),
                "{r:?}"
            );
        }
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

    #[test]
    fn search_region_is_clipped() {
        let r = search_region(&Ellipse::new(5.0, 5.0, 10.0, 10.0), 100, 80);
        assert_eq!((r.x, r.y), (0.0, 0.0));
        assert!(r.w <= 100.0 && r.h <= 80.0);
    }

    #[test]
    fn init_checks() {
        let ok = Init::frontal(Ellipse::new(50.0, 40.0, 10.0, 12.0));
        assert!(check_init(&ok, 100, 80).is_ok());
        let outside = Init::frontal(Ellipse::new(150.0, 40.0, 10.0, 12.0));
        assert!(check_init(&outside, 100, 80).is_err());
        let zero = Init::frontal(Ellipse::new(50.0, 40.0, 0.0, 12.0));
        assert!(check_init(&zero, 100, 80).is_err());
        let nan = Init::frontal(Ellipse::new(f64::NAN, 40.0, 10.0, 12.0));
        assert!(check_init(&nan, 100, 80).is_err());
    }
}
