//! The embeddable tracker: [`Tracker::new`] on the first frame, [`Tracker::step`] on each
//! following frame, [`Tracker::reinit`] to start over without rebuilding it.
//!
//! ```no_run
//! use pftrack::geometry::Ellipse;
//! use pftrack::image;
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
//!
//! The step's stages are in `step`, in the order the data flows through them; the parts they
//! call on each have their own module: `config` (every setting, with why it has its
//! default), `appearance` (the colour model, the contrast term's background, luma bins for
//! grey footage, the template, and their adaptation), `confidence` (the score each frame
//! reports), `checks` ([`TrackerConfig::check`],
//! [`Init::check`]), `keyframe` (the reference views the rotation is fitted against, and
//! their bundle adjustment), `spin` (the turn carried through frames that measure none),
//! `recovery` (the lost flag, the loop closures on the first view, the re-acquisition),
//! `init_refine` (an optional start moved onto the object's outline) and `pool` (the step on
//! rayon's pool, a second thread kept at hand).

mod appearance;
mod checks;
mod confidence;
mod config;
mod init_refine;
mod keyframe;
mod pool;
mod recovery;
mod spin;
mod step;

pub use checks::MIN_START_AXIS;
pub use config::{
    AnchorRefit, BundleAdjust, ColourUpdate, Contrast, HFOV_RANGE_DEG, Init, MAX_DEPTH_RATIO,
    MAX_WEIGHT, Mode, Reanchor, TemplateTerm, TrackerConfig,
};
pub use init_refine::{InitRefine, refine_ellipse};

use nalgebra::{Matrix3, Vector3};

use crate::features::{Features, Sift, keep_slope_length, match_features};
use crate::filter::rotation_mean::{exp_so3, log_so3};
use crate::filter::{AspectRange, Hypothesis, Motion, ParticleFilter, SizeRange};
use crate::frames::{FrameView, GrayF32};
use crate::geometry::{BoxRect, Ellipse, Euler, PoseState, deg};
use crate::likelihood::{
    COLOUR_LUMA, ColourHistogram, ContrastTable, FeaturePair, FrameInput, LikelihoodEngine,
    LikelihoodParams, Particle, TERM_COLOUR, TERM_CONTRAST, TERM_FEATURE, TERM_GRADIENT, TermLogs,
};
use crate::motion::block_match;
use crate::pose::{SolverKind, interframe_consensus};
use appearance::{GREY_SWITCH_AFTER, is_grey};
use confidence::confidence;
use keyframe::{FitContext, KeyframePool};
use recovery::lost_state;
use spin::{Moved, smoothed_spin};

/// What is wrong with a start ([`TrackError::BadInit`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum InitFault {
    /// A value of the ellipse is not finite, or a semi-axis is not positive.
    NotAnEllipse,
    /// A semi-axis is under [`MIN_START_AXIS`].
    AxesTooSmall,
    /// A semi-axis is over the frame's longer side.
    AxesTooLarge,
    /// The frame is too small to hold any start.
    FrameTooSmall,
    /// The ellipse's angle is more than a turn either way.
    AngleOutOfRange,
    /// The centre lies outside the frame.
    CentreOutside,
    /// An angle of the initial pose is not finite, or more than a turn either way.
    PoseOutOfRange,
    /// A semi-axis lies outside the particle filter's bounds (`filter.min_axis`,
    /// `filter.max_axis`), to which every particle is held.
    OutsideFilterBounds,
}

/// Errors of the tracker's own: its start, configuration and frames. (A likelihood engine's
/// failure comes as [`crate::Error::Likelihood`], SIFT's as [`crate::Error::Features`].)
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TrackError {
    /// The start (its ellipse or pose) is unusable.
    #[error("invalid start: {why}")]
    #[non_exhaustive]
    BadInit {
        /// What is wrong with it, for a program to act on.
        fault: InitFault,
        /// The same for a person: the values and the bounds they broke.
        why: String,
    },
    /// A setting of the configuration is out of range.
    #[error("invalid tracker configuration: {why}")]
    #[non_exhaustive]
    BadConfig {
        /// The setting that holds the refused value: a field of [`TrackerConfig`], or a field
        /// of one of its parts after a dot (`filter.min_axis`, `filter.dynamics.rotation`);
        /// a part's name alone where the part's own check refused it (`sift`, `likelihood`,
        /// `bundle`). Where two settings conflict, the one the message says to set
        /// (`contrast`, for the contrast term's flag without its settings).
        setting: &'static str,
        /// What is wrong with it and what to do instead.
        why: String,
    },
    /// A frame without pixels (0 wide or high), given to start on.
    #[error("the frame to start on is {width}x{height}: it has no pixels")]
    EmptyFrame {
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
    },
    /// A frame's size differs from the frame the tracker was started on (by
    /// [`Tracker::new`] or the last [`Tracker::reinit`]).
    #[error(
        "frame {frame} is {got_w}x{got_h}, the frame the track started on was {want_w}x{want_h}"
    )]
    FrameSize {
        /// Index of the offending frame.
        frame: usize,
        /// Its width.
        got_w: u32,
        /// Its height.
        got_h: u32,
        /// The start frame's width.
        want_w: u32,
        /// The start frame's height.
        want_h: u32,
    },
    /// An earlier step or restart failed part-way (the likelihood engine's error: a GPU fault
    /// its fallback did not absorb), leaving the tracker's state partly advanced: it must be
    /// started again with [`Tracker::reinit`].
    #[error(
        "the tracker failed on frame {frame} ({cause}) and must be started again (reinit) before \
         it steps on"
    )]
    Failed {
        /// The frame whose step or start failed.
        frame: usize,
        /// That failure's message.
        cause: String,
    },
}

/// How the last step weighed its particles ([`Tracker::last_weighing`]): for looking inside
/// the filter (debugging, drawing the particle cloud). Index `i` of each slice is the same
/// particle.
#[derive(Debug, Clone, Copy)]
#[non_exhaustive]
pub struct Weighing<'a> {
    /// The particles as proposed and evaluated, before any resampling: state relative to the
    /// start's reference pose, as the likelihood engines take it.
    pub particles: &'a [Particle],
    /// Each particle's log-likelihood terms (colour, gradient, feature, contrast) from the
    /// likelihood engine, unweighted, under the step's own settings: [`Tracker::likelihood`]'s
    /// with the contrast term added at that frame's scale when it is on, and without the
    /// feature term on a frame without matches.
    pub terms: &'a [TermLogs],
    /// Each particle's log-weight as the filter took it: the enabled terms with the feature
    /// term's weight, plus the template terms ([`TrackerConfig::template`]). The filter adds
    /// the proposal's correction to these ([`ParticleFilter::last_resampling`] holds the
    /// normalised weights when it resampled).
    pub totals: &'a [f32],
}

/// What the tracker says about one frame. Its serde form is the struct's own, angles in
/// radians as the fields hold them (the pose CSV, [`Estimate::to_record`], is the file
/// format in degrees).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Estimate {
    /// The frame's number in the tracker's count: 0 for the frame it was built on, one more
    /// for each frame stepped or restarted on since. Frames it refused (a wrong size) and
    /// the frame of a step that failed are not counted, so where an application skips or
    /// loses frames this is not its stream's index: keep your own beside it.
    pub frame: usize,
    /// The state: ellipse centre and semi-axes, rotation (radians) relative to the reference
    /// pose. Angles are not wrapped at ±180° (a target turning on past 180° reads 190°), but
    /// they jump where the tracker recovers: re-anchored on its first view
    /// ([`TrackerConfig::reanchor`]) the estimate takes the first view's pose (the start's),
    /// re-posed it takes the tilt and pan at which the first view fits, and re-acquired after
    /// being lost the pose of the keyframe its features fit.
    pub state: PoseState,
    /// The ellipse, turned by `theta0 + rz`.
    pub ellipse: Ellipse,
    /// Confidence in `[0, 1]`: colour similarity and contour support of the estimate, lowered
    /// when no features could measure the rotation. On a frame where a lost target is
    /// re-acquired, the found target's own (at least [`TrackerConfig::found_above`]). It is
    /// measured by the colour and gradient terms that are on (`likelihood.terms`): with
    /// neither, it is 1 (0.8 on frames without features), and the target is declared lost
    /// only under a [`TrackerConfig::lost_below`] above 0.8.
    pub confidence: f64,
    /// Whether the target is considered lost: from the [`TrackerConfig::lost_after`]-th
    /// frame in a row below [`TrackerConfig::lost_below`] until a frame reaches
    /// [`TrackerConfig::found_above`] where the target is recognised (by a keyframe fit or
    /// its templates), or the target is re-acquired.
    pub lost: bool,
    /// Feature matches with the previous frame (after the outlier rejection), which the
    /// inter-frame rotation is estimated from; 0 when fewer than 3 matched inside the
    /// previous ellipse, too few to reject outliers among. The keyframe fits and
    /// the feature term use matches of their own, so 0 does not mean the rotation went
    /// unmeasured (the confidence says that: see [`Estimate::confidence`]).
    pub matches: usize,
    /// Effective sample size of the filter after weighting, `1 / Σ wᵢ²` of the normalised
    /// weights: a count of particles, from 1 (one particle holds all the weight) to the
    /// number of particles (equal weights, as at the start).
    pub ess: f64,
}

impl Estimate {
    /// The angles in degrees, `[tilt, pan, roll]`.
    pub fn angles_deg(&self) -> [f64; 3] {
        [deg(self.state.rx), deg(self.state.ry), deg(self.state.rz)]
    }

    /// A start at this estimate, its ellipse as seen and its pose: to start again from where
    /// the track was ([`Tracker::reinit`] after a [`TrackError::Failed`], or on a later frame).
    /// The angles then go on from the estimate's, the reference orientation staying the same,
    /// but for whole turns: an angle (or the ellipse's orientation) past a turn either way,
    /// which [`Init::check`] refuses, is brought within one by taking whole turns off it. That
    /// is the same rotation and the same ellipse, so the track goes on as before; only the
    /// angles read from there on are a multiple of 360 degrees from the old ones.
    pub fn to_init(&self) -> Init {
        let e = self.state.euler();
        Init {
            ellipse: Ellipse {
                theta: within_a_turn(self.ellipse.theta),
                ..self.ellipse
            },
            pose: Euler {
                rx: within_a_turn(e.rx),
                ry: within_a_turn(e.ry),
                rz: within_a_turn(e.rz),
            },
        }
    }

    /// The estimate as a row of the pose CSV ([`crate::io::PoseCsvWriter`]), with its score,
    /// lost flag and ellipse orientation, as `pftrack track` writes it.
    pub fn to_record(&self) -> crate::io::PoseRecord {
        crate::io::PoseRecord {
            frame: self.frame,
            state: self.state,
            score: Some(self.confidence),
            lost: Some(self.lost),
            theta: Some(self.ellipse.theta),
        }
    }
}

/// `angle` (radians) with whole turns taken off until it lies within one turn either way:
/// itself when it does already.
fn within_a_turn(angle: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    angle - (angle / tau).trunc() * tau
}

/// Most keyframes held (the first view and those taken as the target turned).
const KEYFRAMES: usize = 12;
/// Keyframes fitted per frame, the nearest to the previous estimate first.
const KEYFRAME_TRIES: usize = 3;
/// Keyframes further than this from the previous estimate (radians, 45°) are not tried: SIFT
/// matches few features across larger turns.
const KEYFRAME_REACH: f64 = std::f64::consts::FRAC_PI_4;

/// The joint tracker and pose estimator.
pub struct Tracker {
    /// The configuration as given (what [`Tracker::config`] returns).
    cfg: TrackerConfig,
    /// The likelihood settings in use: the configuration's, with luma bins where the frames
    /// are grey ([`TrackerConfig::grey_luma`], [`Tracker::switch_colour_bins`]).
    likelihood: LikelihoodParams,
    engine: Box<dyn LikelihoodEngine + Send>,
    /// What a step shares with the pool thread kept at hand for it ([`pool::with_helper`]).
    helper: std::sync::Arc<pool::Helper>,
    /// The frame and message of a step or restart that failed after changing the state, which
    /// only a successful start clears ([`TrackError::Failed`]).
    failed: Option<(usize, String)>,
    sift: Sift,
    /// SIFT without the doubled first octave: for targets of at least
    /// [`TrackerConfig::sift_upsample_below`], and for a window whose doubled scale space
    /// would pass [`crate::features::SiftParams::max_scale_space_bytes`]; `None` when `sift`
    /// has no doubled octave.
    sift_large: Option<Sift>,
    filter: ParticleFilter,
    size: (u32, u32),
    theta0: f64,
    /// The outline the object shows facing the camera, unrolled: the object model's
    /// ([`crate::pose::prior::Ellipsoid::frontal_outline`] of the start).
    reference: Ellipse,
    /// The start's ellipse as seen, unrolled: the size and aspect the recovery searches and
    /// re-anchors at (the same as `reference` for a start that neither tilts nor pans).
    first_outline: Ellipse,
    frame: usize,
    prev_gray: GrayF32,
    /// Undoes sudden changes of light ([`TrackerConfig::exposure_jump`]); `None` when off.
    exposure: Option<crate::frames::exposure::Compensator>,
    prev_features: Features,
    keyframes: KeyframePool,
    prev: Hypothesis,
    prev_euler: Euler,
    /// The estimate's rotation per frame, smoothed ([`TrackerConfig::coast_rate`]): a
    /// rotation vector about the camera's axes (radians a frame).
    spin: Vector3<f64>,
    low_count: usize,
    lost: bool,
    /// Frames stepped without SIFT, its scale space over budget ([`detect_within_budget`]).
    frames_without_sift: usize,
    /// Frames stepped with a change of light undone ([`TrackerConfig::exposure_jump`]).
    frames_relit: usize,
    /// The last trusted estimate (the start, or a frame of confidence at least
    /// [`TrackerConfig::trust_above`] that left the target found). The filter's proposals
    /// are held near its semi-axes while the tracker is unsure ([`TrackerConfig::size_hold`]),
    /// and a lost target is looked for and recognised in its rotation, not in the estimate's,
    /// which the filter's widened proposals walk about while nothing measures the turn.
    trusted: Hypothesis,
    /// The previous frame's confidence (1 after an initialisation).
    prev_confidence: f64,
    /// The last step's proposed particles, their terms and their total log-weights
    /// ([`Tracker::last_weighing`]); empty after a start.
    particles: Vec<Particle>,
    terms: Vec<TermLogs>,
    totals: Vec<f32>,
    /// The terms of a single hypothesis scored on its own ([`Self::own_confidence`]).
    own_terms: Vec<TermLogs>,
    first: Estimate,
    /// The colour model the engine holds (it adapts, [`TrackerConfig::colour_update`]).
    colour_model: ColourHistogram,
    /// The contrast term's background histogram (a ring around the target), when the term is
    /// on and the ring held pixels on the initial frame ([`TrackerConfig::contrast`]).
    background: Option<ColourHistogram>,
    /// The RGB colour model and background, put aside while the footage is grey
    /// ([`Tracker::switch_colour_bins`]).
    other_appearance: Option<(ColourHistogram, Option<ColourHistogram>)>,
    /// The buffer [`Tracker::step_view`] turns a view's pixels into, kept for the next.
    view_frame: image::RgbImage,
    /// The target's luma appearance on a colour start's frame: what a switch to luma bins
    /// takes while the target is lost, with no place to learn one at.
    luma_start: Option<(ColourHistogram, Option<ColourHistogram>)>,
    /// Frames in a row of the other kind (grey where the colour term counts RGB, colour
    /// where it counts luma), up to [`GREY_SWITCH_AFTER`].
    other_kind_frames: usize,
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

/// The aspects `a / b` the object model of outline `reference` facing the camera can show,
/// widened by `slack` ([`TrackerConfig::aspect_slack`]); `None` without slack or for a
/// degenerate model.
fn aspect_range(reference: &Ellipse, depth_ratio: f64, slack: Option<f64>) -> Option<AspectRange> {
    let k = slack?;
    let (lo, hi) =
        crate::pose::prior::Ellipsoid::facing(reference, depth_ratio).outline_aspect_range();
    AspectRange::new(lo / k, hi * k)
}

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

/// SIFT with `sift` within `region` of `gray`. A window whose scale space would pass
/// [`crate::features::SiftParams::max_scale_space_bytes`] (a large target in a large frame) is
/// searched with `plain`, the same without the doubled first octave, and when even that would
/// pass, the frame goes without features (`None`): colour, contour and template weigh it, as
/// they do a frame without texture, and the track goes on.
fn detect_within_budget(
    sift: &Sift,
    plain: Option<&Sift>,
    gray: &GrayF32,
    region: BoxRect,
) -> Result<Option<crate::features::Features>, crate::features::FeatureError> {
    use crate::features::FeatureError;
    match sift.detect(gray, Some(region)) {
        Err(FeatureError::TooLarge {
            upsampled: true, ..
        }) if plain.is_some() => match plain.map(|p| p.detect(gray, Some(region))) {
            Some(Err(FeatureError::TooLarge { .. })) | None => Ok(None),
            Some(r) => r.map(Some),
        },
        Err(FeatureError::TooLarge { .. }) => Ok(None),
        r => r.map(Some),
    }
}

/// [`TrackError::EmptyFrame`] for a frame to start on without pixels.
fn not_empty(width: u32, height: u32) -> crate::Result<()> {
    if width == 0 || height == 0 {
        return Err(track_err(TrackError::EmptyFrame { width, height }));
    }
    Ok(())
}

/// The margin of [`search_region`] around an ellipse's bounding box.
fn search_margin(e: &Ellipse) -> f64 {
    0.5 * e.a.max(e.b) + 8.0
}

impl std::fmt::Debug for Tracker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tracker")
            .field("engine", &self.engine.name())
            .field("size", &self.size)
            .field("frame", &self.frame)
            .field("lost", &self.lost)
            .field("particles", &self.cfg.filter.particles)
            .finish_non_exhaustive()
    }
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
        cfg.check().map_err(track_err)?;
        // The engine's own bounds (the GPU's buffers), before the filter allocates anything.
        let (w, h) = first_frame.dimensions();
        not_empty(w, h)?;
        engine.check_capacity(cfg.filter.particles, w, h, &cfg.likelihood)?;
        let likelihood = cfg.likelihood;
        let sift = Sift::new(cfg.sift.clone());
        let sift_large = cfg.sift.upsample.then(|| {
            Sift::new(crate::features::SiftParams {
                upsample: false,
                ..cfg.sift.clone()
            })
        });
        let filter = ParticleFilter::new(
            cfg.filter,
            cfg.seed,
            &Hypothesis::from_state(&PoseState::default()),
        )
        .map_err(|e| track_err(TrackError::bad_config("filter", e.to_string())))?;
        let mut t = Self {
            cfg,
            likelihood,
            engine,
            helper: Default::default(),
            sift,
            sift_large,
            filter,
            size: first_frame.dimensions(),
            theta0: 0.0,
            reference: Ellipse::default(),
            first_outline: Ellipse::default(),
            frame: 0,
            prev_gray: GrayF32::default(),
            exposure: None,
            prev_features: Features::default(),
            keyframes: KeyframePool::new(KEYFRAMES),
            prev: Hypothesis::from_state(&PoseState::default()),
            prev_euler: Euler::default(),
            spin: Vector3::zeros(),
            low_count: 0,
            lost: false,
            frames_without_sift: 0,
            frames_relit: 0,
            failed: None,
            trusted: Hypothesis::from_state(&PoseState::default()),
            prev_confidence: 1.0,
            particles: Vec::new(),
            terms: Vec::new(),
            totals: Vec::new(),
            own_terms: Vec::new(),
            colour_model: ColourHistogram(Vec::new()),
            background: None,
            other_appearance: None,
            luma_start: None,
            view_frame: image::RgbImage::new(0, 0),
            other_kind_frames: 0,
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
        t.start(first_frame, init, 0)?;
        Ok(t)
    }

    /// Starts over on `frame`, the next frame of the stream, from `init`: a new colour model,
    /// new reference features and keyframes, the filter reset and its random draws seeded
    /// again from [`TrackerConfig::seed`]. What follows is the track a tracker built on
    /// `frame` with [`Tracker::new`] gives (tested), but for the frame numbers, which go on
    /// counting: `frame` is numbered one after the last frame stepped. With
    /// [`TrackerConfig::init_refine`] the ellipse is refined on `frame` first
    /// ([`refine_ellipse`]); [`Tracker::initial_estimate`] gives the one used. On an error
    /// the frame is not counted. An error in the checks of the frame, the start and the
    /// engine's capacity leaves the tracker as it was; one after them (the likelihood
    /// engine's, setting the new colour model) leaves it to be started again
    /// ([`TrackError::Failed`]). A successful restart clears an earlier failure. `frame` may
    /// be of another size than the earlier frames (a stream that changed resolution): the
    /// frames that follow must then be of its size ([`TrackError::FrameSize`]).
    pub fn reinit(&mut self, frame: &image::RgbImage, init: Init) -> crate::Result<()> {
        self.start(frame, init, self.frame + 1)
    }

    /// The common start of [`Tracker::new`] and [`Tracker::reinit`] on `frame`, numbered
    /// `index`: checks that change nothing, then the start, whose failure is recorded.
    fn start(&mut self, frame: &image::RgbImage, init: Init, index: usize) -> crate::Result<()> {
        let (w, h) = frame.dimensions();
        not_empty(w, h)?;
        init.check_for(&self.cfg, w, h).map_err(track_err)?;
        self.engine
            .check_capacity(self.cfg.filter.particles, w, h, &self.cfg.likelihood)?;
        let likelihood = start_likelihood(&self.cfg, frame);
        let init = match &self.cfg.init_refine {
            Some(r) => refine_within_bounds(&self.cfg, r, frame, &likelihood, init)?,
            None => init,
        };
        let started = self.start_checked(frame, init, likelihood, index);
        self.failed = match &started {
            Ok(()) => None,
            Err(e) => {
                self.clear_weighing();
                Some((index, e.to_string()))
            }
        };
        started
    }

    /// Forgets the last step's weighing ([`Self::last_weighing`] gives `None`).
    fn clear_weighing(&mut self) {
        self.particles.clear();
        self.terms.clear();
        self.totals.clear();
    }

    /// [`Self::start`] once its checks passed: `init` is the start to use, `likelihood` the
    /// settings for its frames.
    fn start_checked(
        &mut self,
        frame: &image::RgbImage,
        init: Init,
        likelihood: LikelihoodParams,
        index: usize,
    ) -> crate::Result<()> {
        let (w, h) = frame.dimensions();
        self.likelihood = likelihood;
        self.size = (w, h);
        // The start's ellipse is the one seen, turned by `theta0 + rz` (SPEC).
        self.theta0 = init.ellipse.theta - init.pose.rz;
        let (model, background) =
            self.appearance_at(frame, &init.ellipse, self.likelihood.colour_bins)?;
        self.engine.set_colour_model(&model)?;
        self.colour_model = model;
        self.background = background;
        self.other_appearance = None;
        self.luma_start = (self.cfg.grey_luma && self.likelihood.colour_bins != COLOUR_LUMA)
            .then(|| self.appearance_at(frame, &init.ellipse, COLOUR_LUMA).ok())
            .flatten();
        self.other_kind_frames = 0;
        self.send_contrast_table()?;
        let state = PoseState::from_parts(&init.ellipse, init.pose);
        let hyp = Hypothesis::from_state(&state);
        // The object model's reference outline: the one the object shows facing the camera,
        // unrolled, since the model is turned by the pose (roll included) on top of it. A
        // start turned in tilt or pan shows it turned.
        self.first_outline = Ellipse {
            theta: self.theta0,
            ..init.ellipse
        };
        self.reference = crate::pose::prior::Ellipsoid::frontal_outline(
            &init.ellipse,
            self.theta0,
            self.likelihood.depth_ratio as f64,
            &hyp.rot,
        );
        self.filter.set_frame(w, h);
        self.filter.set_aspect_range(aspect_range(
            &self.reference,
            self.likelihood.depth_ratio as f64,
            self.cfg.aspect_slack,
        ));
        self.filter.reset(&hyp);
        self.filter.reseed(self.cfg.seed);
        self.prev = hyp;
        self.prev_euler = init.pose;
        self.spin = Vector3::zeros();
        self.prev_gray = GrayF32::from_rgb(frame);
        self.exposure = self.cfg.exposure_jump.map(|j| {
            let mut c = crate::frames::exposure::Compensator::new(j);
            c.reset(frame);
            c
        });
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
                    depth_ratio: self.likelihood.depth_ratio,
                    camera: self.camera(),
                },
            )),
            _ => None,
        };
        self.anchor_correlations.clear();
        self.particles.clear();
        self.terms.clear();
        self.totals.clear();
        let region = search_region(&init.ellipse, w, h);
        self.prev_features = self.detect_features(&init.ellipse, &self.prev_gray, region)?;
        let model = self.model(&hyp.rot, &init.ellipse);
        self.keyframes.tick(index);
        self.keyframes
            .reset(&self.prev_features, &init.ellipse, hyp, model);
        self.low_count = 0;
        self.lost = false;
        self.trusted = hyp;
        self.prev_confidence = 1.0;
        self.frame = index;
        self.first = Estimate {
            frame: index,
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

    /// The size (width, height) every frame handed to [`Tracker::step`] must have: that of
    /// the frame the tracker was last started on ([`TrackError::FrameSize`]).
    pub fn frame_size(&self) -> (u32, u32) {
        self.size
    }

    /// The number of the last frame tracked or started on, from 0 (the number the next
    /// step's [`Estimate::frame`] follows).
    pub fn last_frame(&self) -> usize {
        self.frame
    }

    /// Whether the tracker considers the target lost (the last estimate's
    /// [`Estimate::lost`]): it searches the frame for it each step until found again.
    pub fn is_lost(&self) -> bool {
        self.lost
    }

    /// Whether an earlier step or start failed part-way: every step is refused with
    /// [`TrackError::Failed`] until [`Tracker::reinit`] starts it again.
    pub fn is_failed(&self) -> bool {
        self.failed.is_some()
    }

    /// How many frames [`Tracker::step`] has tracked without SIFT because the scale space
    /// around the target would have passed [`crate::features::SiftParams::max_scale_space_bytes`]
    /// even without the doubled first octave: those frames were weighed by colour, contour and
    /// template alone. With the default budget no frame a source delivers (2^25 pixels at most)
    /// comes to this; a lower budget can.
    pub fn frames_without_sift(&self) -> usize {
        self.frames_without_sift
    }

    /// How many frames [`Tracker::step`] has taken in other light than that of the start
    /// before them, and brought back to it ([`TrackerConfig::exposure_jump`],
    /// [`Tracker::exposure_gain`]).
    pub fn frames_relit(&self) -> usize {
        self.frames_relit
    }

    /// The configuration as it was given: a tracker built from a clone of it tracks as this
    /// one would. What a start changed for its own frames is in [`Tracker::likelihood`].
    pub fn config(&self) -> &TrackerConfig {
        &self.cfg
    }

    /// The factor by which the object's relief differs from its ellipsoid's, as the keyframes'
    /// adjustments found it so far and the fits now lift with it: below 1 for an object
    /// flatter than its model (the synthetic box reads about 0.5), above 1 for a deeper one.
    /// 1 unless the relief is learnt ([`BundleAdjust::params`]'s `relief_sigma`), and until a
    /// keyframe has been adjusted; a start forgets it.
    pub fn relief(&self) -> f64 {
        self.cfg
            .bundle
            .as_ref()
            .map_or(1.0, |b| self.keyframes.relief(b))
    }

    /// The gain per channel (R, G, B) undone on the last frame: the light it was taken in
    /// over the light of the last start, as far as the changes of light taken and the light
    /// measured since tell ([`TrackerConfig::exposure_jump`]). 1 in every channel after a
    /// start, or when the compensation is off.
    pub fn exposure_gain(&self) -> [f64; 3] {
        self.exposure.as_ref().map_or([1.0; 3], |c| c.gain())
    }

    /// The likelihood settings in use: the configuration's, with the luma bins
    /// ([`crate::likelihood::COLOUR_LUMA`]) where the frames are grey, from the start's frame
    /// or from a grey stretch of colour footage on ([`TrackerConfig::grey_luma`]). Each step
    /// starts from these and adds the contrast term at its frame's scale when it is on
    /// ([`TrackerConfig::contrast`]), and leaves out the feature term on a frame without
    /// matches.
    pub fn likelihood(&self) -> &LikelihoodParams {
        &self.likelihood
    }

    /// How the last step weighed its particles: the proposed particles, their likelihood
    /// terms and their log-weights. `None` before the first step after a start. A step that
    /// then reset the filter (re-anchored, re-acquired) reports the particles it weighed
    /// before the reset.
    pub fn last_weighing(&self) -> Option<Weighing<'_>> {
        let n = self.particles.len();
        // (A failed step or start clears all three: none.)
        (n > 0 && self.terms.len() == n && self.totals.len() == n).then_some(Weighing {
            particles: &self.particles,
            terms: &self.terms,
            totals: &self.totals,
        })
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

    /// Puts `engine` in the place of the tracker's likelihood engine and gives back the one
    /// it held, keeping everything else (keyframes, template, the adapted colour model): to go
    /// on on the CPU after the GPU device was lost, say, or to move to another device. The new
    /// engine is given the colour model and contrast table the tracker holds now, so the track
    /// goes on as it would have on the old engine, as far as the two agree (the CPU engine and
    /// another CPU engine: bit for bit).
    ///
    /// Errors, the tracker keeping its engine: the new engine cannot hold the tracker's
    /// particles on its frames ([`LikelihoodEngine::check_capacity`]), or refuses the models.
    /// A tracker stopped by a failure ([`TrackError::Failed`]) stays stopped: replace the
    /// engine, then [`Self::reinit`] (from the last estimate, [`Estimate::to_init`]).
    pub fn replace_engine(
        &mut self,
        mut engine: Box<dyn LikelihoodEngine + Send>,
    ) -> crate::Result<Box<dyn LikelihoodEngine + Send>> {
        let (w, h) = self.size;
        engine.check_capacity(self.cfg.filter.particles, w, h, &self.cfg.likelihood)?;
        engine.set_colour_model(&self.colour_model)?;
        if let Some(table) = self.contrast_table()? {
            engine.set_contrast_table(&table)?;
        }
        Ok(std::mem::replace(&mut self.engine, engine))
    }

    /// A one-line notice from the likelihood engine since the last call, taken once: e.g. that
    /// the GPU device was lost and the run goes on on the CPU
    /// ([`crate::likelihood::FallbackEngine`]). Callers should show it to the user.
    pub fn take_engine_notice(&mut self) -> Option<String> {
        self.engine.take_notice()
    }

    /// [`Self::step`] on a frame in someone else's buffer (a camera's BGR or BGRA rows with
    /// padding, say): its pixels are turned into RGB in a buffer the tracker keeps, which
    /// frames of one size reuse, so no frame allocates. The same estimate as
    /// [`Self::step`] on [`FrameView::to_rgb`]'s image (tested). A view of another size than
    /// the start's is refused and changes nothing, as there.
    pub fn step_view(&mut self, view: &FrameView) -> crate::Result<Estimate> {
        let mut frame = std::mem::replace(&mut self.view_frame, image::RgbImage::new(0, 0));
        view.write_rgb(&mut frame);
        let stepped = self.step(&frame);
        self.view_frame = frame;
        stepped
    }

    /// Tracks the target into the next frame.
    ///
    /// The step runs as one task of rayon's pool: called from outside the pool, the calling
    /// thread hands the whole step over and waits once, instead of once for each of the
    /// step's parallel parts (SIFT's bands, block matching beside SIFT, the particles'
    /// likelihoods, the template terms), each of which would otherwise wake a worker and
    /// put the caller to sleep again. Called from inside the pool it runs in place.
    ///
    /// Threads: every parallel part runs on the rayon pool the step is called in, the global
    /// pool (one thread a core, or `RAYON_NUM_THREADS`) unless the caller installs its own.
    /// To hold a tracker to `n` threads, build a pool and step inside it:
    /// `pool.install(|| tracker.step(&frame))` with `pool` from
    /// `pftrack::rayon::ThreadPoolBuilder::new().num_threads(n).build()`; the output is the same on
    /// any number of threads. [`crate::likelihood::cpu::CpuEngine::with_threads`] bounds only
    /// the likelihood pass. For the length of a step one thread of the pool, where it has more
    /// than one, waits for the step's parallel work without sleeping: it runs any work the
    /// pool has, yields its core to any other thread that wants it, and rests while an engine
    /// that works elsewhere (a GPU) evaluates. Waking a sleeping thread costs more than most of
    /// the step's forks save, some 30 µs on a virtual machine. That thread runs whatever the
    /// pool has queued, so a step called while holding a lock that other jobs of the same pool
    /// wait for (trackers behind mutexes, stepped from a `par_iter` over frames) can deadlock,
    /// and does more often than plain rayon would: step outside such locks, or give the
    /// trackers a pool of their own.
    ///
    /// Errors: a frame of another size than the start's is refused and changes nothing (the
    /// next frame steps as if it had not come). An error after that (the likelihood engine's:
    /// a GPU fault that its CPU fallback, [`crate::likelihood::FallbackEngine`], did not
    /// absorb) leaves the state partly advanced, so every later step returns
    /// [`TrackError::Failed`] until [`Self::reinit`] starts again (from the last estimate, say).
    pub fn step(&mut self, frame: &image::RgbImage) -> crate::Result<Estimate> {
        if let Some((frame, cause)) = &self.failed {
            return Err(track_err(TrackError::Failed {
                frame: *frame,
                cause: cause.clone(),
            }));
        }
        let (w, h) = frame.dimensions();
        let index = self.frame + 1;
        if (w, h) != self.size {
            return Err(track_err(TrackError::FrameSize {
                frame: index,
                got_w: w,
                got_h: h,
                want_w: self.size.0,
                want_h: self.size.1,
            }));
        }
        let helper = std::sync::Arc::clone(&self.helper);
        let stepped = pool::with_helper(&helper, || self.step_in_pool(frame, index));
        if let Err(e) = &stepped {
            self.clear_weighing();
            self.failed = Some((index, e.to_string()));
        }
        stepped
    }

    /// SIFT around a target `e` within `region` of `gray`, within the scale-space budget
    /// ([`detect_within_budget`]).
    fn detect_features(
        &self,
        e: &Ellipse,
        gray: &GrayF32,
        region: BoxRect,
    ) -> Result<crate::features::Features, crate::features::FeatureError> {
        detect_within_budget(self.sift_for(e), self.sift_large.as_ref(), gray, region)
            .map(Option::unwrap_or_default)
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
            prior: self.cfg.fit_prior(),
            anchor_refit: self.cfg.anchor_refit,
            relief: self.relief(),
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

    /// The object model in a view with estimated rotation `rot` and ellipse `view`: the
    /// object's outline facing the camera (the first frame's ellipse, for a start that neither
    /// tilts nor pans), as deep as the likelihood's depth ratio says, turned by `rot`.
    fn model(&self, rot: &Matrix3<f64>, view: &Ellipse) -> crate::pose::prior::Ellipsoid {
        crate::pose::prior::Ellipsoid::posed(
            &self.reference,
            self.likelihood.depth_ratio as f64,
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
}

/// The likelihood settings a start on `frame` takes: grey footage gets luma bins, decided on
/// each start's own frame. The contrast term is the tracker's to turn on, on the frames where
/// it has a background (`enable_contrast`): a start whose ring holds no pixel (a target
/// filling the frame) has none, and the flag left on would have every step ask for a table
/// never made.
fn start_likelihood(cfg: &TrackerConfig, frame: &image::RgbImage) -> LikelihoodParams {
    let mut likelihood = cfg.likelihood;
    likelihood.terms &= !TERM_CONTRAST;
    if cfg.grey_luma && is_grey(frame) {
        likelihood.colour_bins = COLOUR_LUMA;
    }
    likelihood
}

/// `init`, a start already checked against `frame` ([`Init::check_for`]), refined on it with
/// `refine` under `likelihood`; `init` itself where the refinement leaves the start's bounds
/// (a semi-axis under 2 px, the centre off the frame), which is no refinement.
fn refine_within_bounds(
    cfg: &TrackerConfig,
    refine: &InitRefine,
    frame: &image::RgbImage,
    likelihood: &LikelihoodParams,
    init: Init,
) -> crate::Result<Init> {
    let (w, h) = frame.dimensions();
    let refined = Init {
        ellipse: init_refine::refine_ellipse(frame, &init.ellipse, likelihood, refine)
            .map_err(track_err)?,
        ..init
    };
    Ok(if refined.check_for(cfg, w, h).is_ok() {
        refined
    } else {
        init
    })
}

/// The start a tracker would take on `frame` from `init` with [`TrackerConfig::init_refine`]
/// set to `refine` (the rest of `cfg` as given): `init` refined onto the edges and colour
/// boundary nearest it ([`refine_ellipse`], under the likelihood settings the tracker takes
/// on that frame), or `init` itself where the refinement would leave the start's bounds. For
/// a program that shows where a start drawn by hand would move before tracking from it
/// (`pftrack track` says so where the given and the refined ellipses' boxes have an
/// intersection over union under 0.8). Errors: a start [`Init::check_for`] refuses, `refine`
/// settings [`InitRefine::check`] refuses, or likelihood settings the refinement's scoring
/// refuses ([`refine_ellipse`]); the rest of `cfg` is not checked here
/// ([`TrackerConfig::check`] does).
pub fn refined_start(
    cfg: &TrackerConfig,
    refine: &InitRefine,
    frame: &image::RgbImage,
    init: Init,
) -> crate::Result<Init> {
    let (w, h) = frame.dimensions();
    init.check_for(cfg, w, h).map_err(track_err)?;
    refine_within_bounds(cfg, refine, frame, &start_likelihood(cfg, frame), init)
}

/// Whether the ellipse's size is held ([`TrackerConfig::size_hold`]) on the frame after one
/// of confidence `c` that left the tracker `lost` or not: while the target is lost, or after
/// a frame the tracker did not trust (below [`TrackerConfig::trust_above`]). The size a
/// frame that is not held ends with becomes the one later frames are held near. Why a bar
/// above [`TrackerConfig::lost_below`]: see `docs/measurements.md`, under
/// "TrackerConfig::size_hold" and "TrackerConfig::trust_above".
fn holds_size(cfg: &TrackerConfig, lost: bool, c: f64) -> bool {
    lost || c < cfg.trust_above
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
    let (p, q) = keep_slope_length(
        &p,
        &q,
        crate::features::PAPER_ANGLE_TOL,
        crate::features::PAPER_LENGTH_TOL,
    );
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

    /// A start panned 60 degrees, seen 20.1 x 24 px: the object model's reference is the head
    /// facing the camera, 18 x 24, the model at the start shows the outline seen, and the
    /// aspect bound holds the frontal 0.75 (it had been built about the outline seen, from
    /// 0.84: the head turning back was held 12 % too wide).
    #[test]
    fn a_start_turned_in_pan_takes_the_objects_frontal_outline() {
        use crate::synth::{Renderer, Scenario, SynthConfig};
        let r = Renderer::new(&SynthConfig::new(Scenario::Pan)).unwrap();
        let (frame, _) = r.render(0);
        let d = (18.0f64 * 24.0).sqrt();
        let seen = Ellipse::new(80.0, 60.0, (81.0 + 0.75 * d * d).sqrt(), 24.0);
        let pose = Euler::from_degrees(0.0, 60.0, 0.0);
        let t = Tracker::new(
            TrackerConfig::default(),
            &frame,
            Init {
                ellipse: seen,
                pose,
            },
        )
        .unwrap();
        assert!(
            (t.reference.a - 18.0).abs() < 1e-9 && (t.reference.b - 24.0).abs() < 1e-9,
            "{:?}",
            t.reference
        );
        let m = t.model(&pose.matrix(), &seen);
        assert!(
            (m.semi - Vector3::new(18.0, 24.0, d)).abs().max() < 1e-9,
            "{}",
            m.semi
        );
        let lo = t.filter.aspect_range().map(|r| r.lo());
        assert!(lo.is_some_and(|lo| lo <= 0.75 + 1e-12), "{lo:?}");
        // Facing the camera, the same start is its own outline.
        let t = Tracker::new(TrackerConfig::default(), &frame, Init::frontal(seen)).unwrap();
        assert_eq!((t.reference.a, t.reference.b), (seen.a, seen.b));
    }

    /// A start with a roll: the object model at the starting pose has the start's outline
    /// orientation, `theta0 + rz`, not the roll twice.
    #[test]
    fn the_model_at_a_rolled_start_is_turned_as_its_ellipse() {
        use crate::synth::{Renderer, Scenario, SynthConfig};
        let r = Renderer::new(&SynthConfig::new(Scenario::Roll)).unwrap();
        let (frame, _) = r.render(0);
        let ellipse = Ellipse {
            theta: 0.5,
            ..r.init_ellipse()
        };
        let pose = Euler::new(0.0, 0.0, 0.2);
        let t = Tracker::new(TrackerConfig::default(), &frame, Init { ellipse, pose }).unwrap();
        assert!((t.theta0 - 0.3).abs() < 1e-12);
        let m = t.model(&pose.matrix(), &ellipse);
        let want = crate::geometry::rot_z(0.5);
        assert!(
            (m.orientation - want).abs().max() < 1e-12,
            "{}",
            m.orientation
        );
    }

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
        let band = 0.5 * (cfg.lost_below + cfg.trust_above);
        assert!(band >= cfg.lost_below && band < cfg.trust_above);
        // Below the lost bar and in the band between the two bars: held.
        assert!(holds_size(&cfg, false, 0.5 * cfg.lost_below));
        assert!(holds_size(&cfg, false, band));
        // Found but not trusted: a frame between `found_above` and `trust_above` holds it.
        assert!(cfg.found_above < cfg.trust_above);
        assert!(holds_size(&cfg, false, cfg.found_above));
        // A trusted frame frees it, unless the target is still lost.
        assert!(!holds_size(&cfg, false, cfg.trust_above));
        assert!(!holds_size(&cfg, false, 1.0));
        assert!(holds_size(&cfg, true, 1.0));
        // With `trust_above` at `lost_below`, the hold starts below the lost bar.
        let low = TrackerConfig {
            trust_above: cfg.lost_below,
            ..cfg.clone()
        };
        assert!(!holds_size(&low, false, band));
        assert!(holds_size(&low, false, 0.5 * cfg.lost_below));
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
        assert!(matches!(
            bad.check(),
            Err(TrackError::BadConfig {
                setting: "init_refine",
                ..
            })
        ));
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
            assert!(matches!(
                cfg.check(),
                Err(TrackError::BadConfig {
                    setting: "sift_upsample_below",
                    ..
                })
            ));
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
            assert_eq!(t.sift_large.is_some(), want, "kept for windows over budget");
            assert_eq!(t.sift_for(&wide).params().upsample, want);
        }
    }

    #[test]
    fn sift_over_its_budget_degrades_instead_of_failing() {
        use crate::features::SiftParams;
        let (first, e) = nod_first();
        let gray = GrayF32::from_rgb(&first);
        let (w, h) = first.dimensions();
        let region = search_region(&e, w, h);
        let with = |upsample: bool, budget: u64| {
            Sift::new(SiftParams {
                upsample,
                max_scale_space_bytes: budget,
                ..SiftParams::default()
            })
        };
        let plain = with(false, u64::MAX).detect(&gray, Some(region)).unwrap();
        assert!(!plain.is_empty());
        // The doubled window's budget passed, the plain one's not: SIFT without the doubling.
        let window = with(false, 0)
            .params()
            .scale_space_bytes(w as usize, h as usize);
        let (up, down) = (with(true, window), with(false, window));
        let got = detect_within_budget(&up, Some(&down), &gray, region).unwrap();
        assert_eq!(got, Some(plain));
        // Both passed, or no plain twin: no features, and no error.
        let (up, down) = (with(true, 1000), with(false, 1000));
        assert_eq!(
            detect_within_budget(&up, Some(&down), &gray, region).unwrap(),
            None
        );
        assert_eq!(
            detect_within_budget(&up, None, &gray, region).unwrap(),
            None
        );
        // A tracker whose SIFT budget no window meets tracks on colour, contour and template.
        let mut cfg = TrackerConfig::default();
        cfg.sift.max_scale_space_bytes = 1000;
        let (mut t, _, _) = nod_tracker(cfg);
        let r = crate::synth::Renderer::new(&crate::synth::SynthConfig::new(
            crate::synth::Scenario::Nod,
        ))
        .unwrap();
        for k in 1..4 {
            let est = t.step(&r.render(k).0).unwrap();
            assert!(!est.lost, "frame {k}");
        }
        assert_eq!(t.frames_without_sift(), 3);
    }

    /// The first frame of the synthetic `nod` and its true ellipse.
    pub(super) fn nod_first() -> (image::RgbImage, Ellipse) {
        let r = crate::synth::Renderer::new(&crate::synth::SynthConfig::new(
            crate::synth::Scenario::Nod,
        ))
        .unwrap();
        (r.render(0).0, r.init_ellipse())
    }

    /// A tracker on the first frame of the synthetic `nod`, with that frame's grey image
    /// and the initial ellipse.
    pub(super) fn nod_tracker(cfg: TrackerConfig) -> (Tracker, GrayF32, Ellipse) {
        let (first, init) = nod_first();
        let t = Tracker::new(cfg, &first, Init::frontal(init)).unwrap();
        (t, GrayF32::from_rgb(&first), init)
    }

    /// The estimate at the first ellipse, tilted by `rx` and panned by `ry` (radians).
    pub(super) fn in_place(init: &Ellipse, rx: f64, ry: f64) -> Hypothesis {
        Hypothesis::from_state(&PoseState::from_parts(init, Euler::new(rx, ry, 0.0)))
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

    #[test]
    fn search_region_is_clipped() {
        // The bounding box with a margin of half the longer semi-axis plus 8 px (13 px here),
        // cut to the frame at the top left, at the bottom right, and not at all inside.
        let r = search_region(&Ellipse::new(5.0, 5.0, 10.0, 10.0), 100, 80);
        assert_eq!(r, BoxRect::new(0.0, 0.0, 28.0, 28.0));
        let r = search_region(&Ellipse::new(95.0, 75.0, 10.0, 10.0), 100, 80);
        assert_eq!(r, BoxRect::new(72.0, 52.0, 28.0, 28.0));
        let r = search_region(&Ellipse::new(50.0, 40.0, 10.0, 5.0), 100, 80);
        assert_eq!(r, BoxRect::new(27.0, 22.0, 46.0, 36.0));
    }
}
