//! The particle filter over `(cx, cy, a, b, rx, ry, rz)` (SPEC section 3; paper eq. 27).
//!
//! Each particle is a [`Hypothesis`]: the ellipse's centre and semi-axes and a rotation
//! matrix (Euler angles are only produced at the boundary, for the likelihood engines and the
//! output). Per frame:
//!
//! 1. [`ParticleFilter::propose`]: `x_k = x_{k-1} + Δx + υ`, `υ ~ N(0, Σ_G)`, with the rotation
//!    part composed on SO(3): `R_k = exp(υ_r) · ΔR_c · R_{k-1}`, where `ΔR_c` is one of the
//!    motion's rotation candidates (the two members of a Necker pair, say), drawn with their
//!    probabilities. The proposal density of each particle is the mixture over the candidates
//!    given its parent.
//! 2. The caller evaluates `ln p(z | x)` for all particles ([`crate::likelihood`]).
//! 3. [`ParticleFilter::update`]: `ln w_k = ln w_{k-1} + ln p(z|x) + ln p(x_k|x_{k-1}) − ln q(x_k)`
//!    with the random-walk dynamics `N(x_{k-1}, Σ_P)`, normalised; the estimate is the weighted
//!    mean (rotations averaged on SO(3)); systematic resampling when the effective sample size
//!    falls below a fraction of N.
//!
//! The SPEC writes `q` as the mixture over all particles, `Σ_i N(x; x_{k-1}^i + Δx, Σ_G)`;
//! here each particle's `q` is that of its own parent (the standard importance weight of a
//! draw from it), which costs N evaluations a frame instead of N². With Σ_P wider than
//! `√2 Σ_G` (the defaults' are 5.3 times wider in the centre, 7.5 in the axes and 1.7-2.5 in
//! the rotation) the ratio `p / q` grows
//! with how far a draw's noise took it, and has no finite variance: with a flat likelihood
//! the weighted particles stand for the random walk about the parents, not for the motion.
//! Leaving the ratio out (the motion then trusted as a measurement with noise Σ_G) was
//! measured on 2026-12-08 and not kept: the synthetic scenarios' summed RMSE went 43.7 ->
//! 45.0, girl's success AUC 0.668 -> 0.661 and car4's 0.800 -> 0.765, one seed of sixteen
//! losing the car (`docs/measurements.md`).

pub mod resample;
pub mod rotation_mean;

use nalgebra::{Matrix3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};

use crate::geometry::{Euler, PoseState};
use crate::likelihood::Particle;
use rotation_mean::{exp_so3, log_so3, weighted_mean};

/// The most particles a filter takes. Each costs the tracker about 400 bytes on the host
/// (the filter's particles, parents and weights, the engines' layout and the per-term
/// results; measured peak resident memory of `pftrack track` with a million particles: 421
/// MB), so this bound is about 2 GB: beyond it a count is a typo more likely than a plan, and
/// is refused with an error instead of failing to allocate. (At ten million, the bound
/// before, the tracker failed to allocate under a 4 GB limit.)
pub const MAX_PARTICLES: usize = 5_000_000;

/// A bound that may be infinite, serialised as a number or, for no bound, `null` (JSON has
/// no infinity).
mod unbounded {
    pub fn serialize<S: serde::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if *v == f64::INFINITY {
            s.serialize_none()
        } else {
            s.serialize_some(v)
        }
    }

    pub fn deserialize<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        let v: Option<f64> = serde::Deserialize::deserialize(d)?;
        Ok(v.unwrap_or(f64::INFINITY))
    }
}

/// Errors of the particle filter.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FilterError {
    /// A setting is out of range; the message names it.
    #[error("invalid filter settings: {0}")]
    BadParams(String),
    /// [`ParticleFilter::update`] was given a number of log-likelihoods other than the
    /// particles'.
    #[error("{got} log-likelihoods for {particles} particles")]
    Length {
        /// Log-likelihoods given.
        got: usize,
        /// Particles held.
        particles: usize,
    },
}

/// One particle: the ellipse centre and semi-axes (pixels) and the rotation relative to the
/// reference pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hypothesis {
    /// Centre x (pixels).
    pub cx: f64,
    /// Centre y (pixels).
    pub cy: f64,
    /// Semi-axis a (pixels).
    pub a: f64,
    /// Semi-axis b (pixels).
    pub b: f64,
    /// Rotation `R = Rx Ry Rz` relative to the reference pose.
    pub rot: Matrix3<f64>,
}

impl Hypothesis {
    /// A hypothesis from a state (angles in radians).
    pub fn from_state(s: &PoseState) -> Self {
        Self {
            cx: s.cx,
            cy: s.cy,
            a: s.a,
            b: s.b,
            rot: s.euler().matrix(),
        }
    }

    /// The state, with Euler angles read from the rotation.
    pub fn to_state(&self) -> PoseState {
        let e = Euler::from_matrix(&self.rot);
        PoseState {
            cx: self.cx,
            cy: self.cy,
            a: self.a,
            b: self.b,
            rx: e.rx,
            ry: e.ry,
            rz: e.rz,
        }
    }

    /// The particle as the likelihood engines see it.
    pub fn to_particle(&self) -> Particle {
        let e = Euler::from_matrix(&self.rot);
        Particle {
            cx: self.cx as f32,
            cy: self.cy as f32,
            a: self.a as f32,
            b: self.b as f32,
            rx: e.rx as f32,
            ry: e.ry as f32,
            rz: e.rz as f32,
            _pad: 0.0,
        }
    }
}

/// Standard deviations of a Gaussian over the state: centre and semi-axes in pixels, the
/// rotation as a rotation vector about the camera axes (radians).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateSigma {
    /// σ of cx and cy (pixels).
    pub centre: f64,
    /// σ of a and b (pixels).
    pub axes: f64,
    /// σ of the rotation vector's x, y, z components (radians; `rotation_deg` in a settings
    /// file, in degrees).
    #[serde(rename = "rotation_deg", with = "crate::io::degrees::three")]
    pub rotation: [f64; 3],
}

/// The largest σ (pixels) of the centre and the axes, [`StateSigma`]'s: a hundred times the
/// longest side a frame may have. Beyond, particles land where `f32` holds no pixel (a σ of
/// 1e300 passed the check and failed the first step as a degenerate estimate); a rotation's
/// σ is at most π, half a turn, past which a Gaussian spreads it over every angle anyway.
pub const MAX_SIGMA_PX: f64 = 3_276_800.0;

impl StateSigma {
    /// Each σ with the name its setting has in messages.
    fn components(&self) -> [(&'static str, f64); 5] {
        let [rx, ry, rz] = self.rotation;
        [
            ("centre", self.centre),
            ("axes", self.axes),
            ("rotation[0]", rx),
            ("rotation[1]", ry),
            ("rotation[2]", rz),
        ]
    }

    /// Checks that every σ is finite and at least 0, the centre's and axes' at most
    /// [`MAX_SIGMA_PX`] and the rotation's at most π; `what` names the set in the error.
    fn check(&self, what: &str) -> Result<(), FilterError> {
        for (name, v) in self.components() {
            let angle = name.starts_with("rotation");
            // An angle is given in degrees too: a settings file holds degrees.
            let shown = if angle {
                format!("{v} rad ({:.4}°)", v.to_degrees())
            } else {
                v.to_string()
            };
            if !(v.is_finite() && v >= 0.0) {
                return Err(FilterError::BadParams(format!(
                    "{what}.{name} {shown} must be finite and at least 0"
                )));
            }
            let (max, max_shown) = if angle {
                (std::f64::consts::PI, "π rad (180°)".to_string())
            } else {
                (MAX_SIGMA_PX, format!("{MAX_SIGMA_PX} px"))
            };
            if v > max {
                return Err(FilterError::BadParams(format!(
                    "{what}.{name} {shown} must be at most {max_shown}"
                )));
            }
        }
        Ok(())
    }

    fn scaled(&self, k: f64) -> Self {
        Self {
            centre: self.centre * k,
            axes: self.axes * k,
            rotation: self.rotation.map(|r| r * k),
        }
    }
}

/// The shares [`FilterParams::still_share`] may take: from 0 (the paper's proposal) to under
/// 1 (some proposals must follow the motion).
pub const STILL_SHARE_RANGE: std::ops::Range<f64> = 0.0..1.0;

/// Settings of the filter.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FilterParams {
    /// Number of particles N (the paper uses 200).
    pub particles: usize,
    /// Σ_G: the proposal's noise around `x_{k-1} + Δx`.
    pub proposal: StateSigma,
    /// Σ_P: the random-walk dynamics `p(x_k | x_{k-1})`.
    pub dynamics: StateSigma,
    /// Resample when the effective sample size falls below this fraction of N, or to 1 (one
    /// particle holds all the weight; with 2 particles and 0.5 the fraction alone never
    /// resamples). 0: never.
    pub resample_below: f64,
    /// Smallest semi-axis a particle may take (pixels); proposals are clamped to it.
    pub min_axis: f64,
    /// Largest semi-axis a particle may take (pixels); proposals are clamped to it and to the
    /// frame set by [`ParticleFilter::set_frame`].
    #[serde(with = "unbounded")]
    pub max_axis: f64,
    /// Share of the proposals drawn with the previous state's centre and semi-axes, with the
    /// same Σ_G, instead of those of `x_{k-1} + Δx` (the rotation candidates as for the
    /// others, so only the translation and scale are held back): a
    /// defensive mixture, so that one wrong motion measurement (block matching fooled by a
    /// shadow, a keyframe fit thrown off by a few features) cannot carry every particle away
    /// from a target that did not move so. The weights take the mixture's density as the
    /// proposal's. 0 (the default): the paper's proposal. 0.2 holds footage at a low frame
    /// rate far better (car4 with every fourth frame: success AUC 0.40 -> 0.55 and 0.44 ->
    /// 0.58 on two blocks of 16 seeds) but reads the synthetic turns a little worse (the
    /// box's pan 9.5 -> 11.4 degrees); see `docs/measurements.md`, under
    /// "FilterParams::still_share".
    pub still_share: f64,
}

impl Default for FilterParams {
    fn default() -> Self {
        Self {
            particles: 200,
            proposal: StateSigma {
                centre: 1.5,
                axes: 0.4,
                rotation: [0.03, 0.03, 0.02],
            },
            // The rotation's random walk allows about 3° per frame on each axis, a fast head
            // turn at 25-30 frames/s: wide enough for the scenarios' fastest turns (about 2°
            // per frame), narrow enough to damp the frame-to-frame noise of the keyframe fits
            // (about 3° with 10-20 matches). At 0.2 rad it let that noise through: the mean
            // per-axis RMSE summed over the six synthetic scenarios was 152° on held-out
            // seeds 3-5, against 92° at 0.05 (with the feature weight at 8).
            dynamics: StateSigma {
                centre: 8.0,
                axes: 3.0,
                rotation: [0.05, 0.05, 0.05],
            },
            resample_below: 0.5,
            min_axis: 2.0,
            max_axis: f64::INFINITY,
            still_share: 0.0,
        }
    }
}

impl FilterParams {
    /// Checks the settings, as [`ParticleFilter::new`] does: from 1 to [`MAX_PARTICLES`]
    /// particles, finite σ of at least 0 ([`FilterParams::proposal`],
    /// [`FilterParams::dynamics`]; a dynamics σ of 0 only where the proposal's is 0 too, the
    /// component then held fixed; the proposal's centre and axes σ above 0 where
    /// `still_share` is), a finite `resample_below` of at least 0 (above 1 the
    /// filter resamples on every update), and semi-axis bounds with
    /// `0 < min_axis <= max_axis` (`max_axis` may be infinite).
    pub fn check(&self) -> Result<(), FilterError> {
        if !(1..=MAX_PARTICLES).contains(&self.particles) {
            return Err(FilterError::BadParams(format!(
                "particles {} must lie in 1..={MAX_PARTICLES}",
                self.particles
            )));
        }
        self.proposal.check("proposal")?;
        self.dynamics.check("dynamics")?;
        // A dynamics σ of 0 would hold the component fixed, so a proposal that moves it would
        // give every moved particle no weight; the weights drop a zero σ's term instead, which
        // reads as no constraint at all (a σ of 1e-9 next to it collapsed the filter to one
        // particle). Refused rather than given either meaning.
        let pairs = self.proposal.components().into_iter();
        for ((name, ps), (_, ds)) in pairs.zip(self.dynamics.components()) {
            if ds == 0.0 && ps > 0.0 {
                return Err(FilterError::BadParams(format!(
                    "dynamics.{name} is 0 where proposal.{name} is {ps}: a component the \
                     proposal moves needs a random walk that allows it (or set both to 0 to \
                     hold it fixed)"
                )));
            }
        }
        let range = STILL_SHARE_RANGE;
        if !range.contains(&self.still_share) {
            return Err(FilterError::BadParams(format!(
                "still_share {} must lie in [{}, {}): the share of proposals drawn around the \
                 previous state instead of where the motion moved it",
                self.still_share, range.start, range.end
            )));
        }
        // The weights need the density of each of the mixture's means where a proposal lands,
        // which a σ of 0 does not give (every mean would read as an exact hit).
        if self.still_share > 0.0 {
            for (name, v) in [
                ("centre", self.proposal.centre),
                ("axes", self.proposal.axes),
            ] {
                if v == 0.0 {
                    return Err(FilterError::BadParams(format!(
                        "proposal.{name} is 0 where still_share is {}: proposals drawn around \
                         two means need a spread about each",
                        self.still_share
                    )));
                }
            }
        }
        if !(self.resample_below.is_finite() && self.resample_below >= 0.0) {
            return Err(FilterError::BadParams(format!(
                "resample_below {} must be finite and at least 0",
                self.resample_below
            )));
        }
        if !(self.min_axis.is_finite() && self.min_axis > 0.0 && self.max_axis >= self.min_axis) {
            let max = if self.max_axis == f64::INFINITY {
                "unbounded".to_string()
            } else {
                self.max_axis.to_string()
            };
            return Err(FilterError::BadParams(format!(
                "min_axis {} and max_axis {max} must satisfy 0 < min_axis <= max_axis (min_axis \
                 finite)",
                self.min_axis
            )));
        }
        Ok(())
    }
}

/// The deterministic part of the motion between two frames, `Δx`.
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    /// Translation of the centre (pixels).
    pub dx: f64,
    /// Translation of the centre (pixels).
    pub dy: f64,
    /// Scale factor of the semi-axes.
    pub scale: f64,
    /// Candidate inter-frame rotations `ΔR` with their probabilities (summing to 1): one
    /// candidate when the rotation is known, the Necker pair when it is ambiguous.
    ///
    /// The tracker proposes the Necker pair at a half each when only the rotation between
    /// successive frames is known. Adding "no turn" as a third candidate (a third each), so
    /// that one wrong inter-frame rotation cannot carry every particle, was measured on
    /// 2026-12-01 in a throwaway build (feature weight 10): the synthetic RMSE summed over
    /// scenarios and axes went 58.7 → 58.1 and 61.8 → 59.8 (filter seeds 0 and 1), girl
    /// stayed (0.525 → 0.527, 0.523 → 0.522 over filter seeds 0-15 and 16-31), and car4 lost
    /// a seed over 0-15 (0.797 → 0.744 ± 0.039; 0.801 → 0.791 over 16-31), so it was not kept.
    pub rotations: Vec<(f64, Matrix3<f64>)>,
}

impl Motion {
    /// No motion: zero translation, scale 1, identity rotation.
    pub fn still() -> Self {
        Self {
            dx: 0.0,
            dy: 0.0,
            scale: 1.0,
            rotations: vec![(1.0, Matrix3::identity())],
        }
    }
}

/// What one update did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateInfo {
    /// Effective sample size after weighting (before any resampling).
    pub ess: f64,
    /// Whether the particles were resampled.
    pub resampled: bool,
}

/// What the last resampling did: the normalised weights it drew from, the comb's offset and
/// the parent index of each new particle. For diagnostics and for tests that compare two runs
/// (the CPU and GPU likelihood engines, say) draw for draw.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Resampling {
    /// The normalised weights before resampling, in particle order.
    pub weights: Vec<f64>,
    /// The comb's offset `u0 ∈ [0, 1)` ([`resample::systematic`]).
    pub u0: f64,
    /// Index of the parent of each new particle.
    pub indices: Vec<usize>,
}

/// The particle filter. Deterministic for a seed.
#[derive(Debug, Clone)]
pub struct ParticleFilter {
    params: FilterParams,
    rng: StdRng,
    particles: Vec<Hypothesis>,
    parents: Vec<Hypothesis>,
    log_w: Vec<f64>,
    /// `ln p(x_k | x_{k-1}) − ln q(x_k)` of each particle from the last proposal.
    log_ratio: Vec<f64>,
    weights: Vec<f64>,
    estimate: Hypothesis,
    /// The last update's resampling, `None` when it did not resample.
    last_resampling: Option<Resampling>,
    /// The frame's size `(w, h)` when known ([`ParticleFilter::set_frame`]).
    frame: Option<(f64, f64)>,
    /// The range of `a / b` proposals are held to, when set
    /// ([`ParticleFilter::set_aspect_range`]).
    aspect: Option<AspectRange>,
    /// The semi-axes proposals are held to, when set ([`ParticleFilter::set_size_range`]).
    size: Option<SizeRange>,
}

/// Bounds on each semi-axis of an ellipse ([`ParticleFilter::set_size_range`]): `a` within
/// `[a0 / k, a0 · k]` and `b` within `[b0 / k, b0 · k]` around a held size `(a0, b0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SizeRange {
    a: (f64, f64),
    b: (f64, f64),
}

impl SizeRange {
    /// The semi-axes within a factor `k` of `(a, b)`; `None` unless both semi-axes are
    /// positive and finite and `k` is a finite factor of at least 1.
    pub fn around(a: f64, b: f64, k: f64) -> Option<Self> {
        let ok = |x: f64| x.is_finite() && x > 0.0;
        (ok(a) && ok(b) && k.is_finite() && k >= 1.0).then_some(Self {
            a: (a / k, a * k),
            b: (b / k, b * k),
        })
    }

    /// The bounds of `a`, `(lo, hi)`.
    pub fn a(&self) -> (f64, f64) {
        self.a
    }

    /// The bounds of `b`, `(lo, hi)`.
    pub fn b(&self) -> (f64, f64) {
        self.b
    }

    /// Semi-axes `(a, b)`, each brought to the nearer of its bounds when outside them.
    pub fn hold(&self, a: f64, b: f64) -> (f64, f64) {
        (a.clamp(self.a.0, self.a.1), b.clamp(self.b.0, self.b.1))
    }
}

/// A range `lo <= a / b <= hi` of an ellipse's aspect ([`ParticleFilter::set_aspect_range`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AspectRange {
    lo: f64,
    hi: f64,
}

impl AspectRange {
    /// The range `[lo, hi]`; `None` unless `0 < lo <= hi` with `lo` finite (`hi` may be
    /// infinite).
    pub fn new(lo: f64, hi: f64) -> Option<Self> {
        (lo > 0.0 && lo.is_finite() && hi >= lo).then_some(Self { lo, hi })
    }

    /// The smallest aspect.
    pub fn lo(&self) -> f64 {
        self.lo
    }

    /// The largest aspect.
    pub fn hi(&self) -> f64 {
        self.hi
    }

    /// Semi-axes `(a, b)` with their aspect brought into the range at the same size
    /// `sqrt(a b)`; unchanged when already inside (or when `a / b` is not positive and
    /// finite).
    pub fn hold(&self, a: f64, b: f64) -> (f64, f64) {
        let r = a / b;
        if !(r.is_finite() && r > 0.0) || (self.lo..=self.hi).contains(&r) {
            return (a, b);
        }
        let k = r.clamp(self.lo, self.hi).sqrt();
        let g = (a * b).sqrt();
        (g * k, g / k)
    }
}

/// `ln N(x; 0, σ²)` up to the constant `-½ ln 2π`; a component with `σ = 0` is deterministic
/// and contributes nothing: held fixed by the proposal, or by the proposal and the dynamics
/// alike ([`FilterParams::check`] refuses a dynamics σ of 0 where the proposal's is not).
fn ln_gauss(x: f64, sigma: f64) -> f64 {
    if sigma > 0.0 {
        -0.5 * (x / sigma).powi(2) - sigma.ln()
    } else {
        0.0
    }
}

/// `ln` density of a state difference under a [`StateSigma`] (constants dropped: they cancel
/// in the normalised weights).
fn ln_density(d: &[f64; 4], w: &Vector3<f64>, s: &StateSigma) -> f64 {
    ln_gauss(d[0], s.centre)
        + ln_gauss(d[1], s.centre)
        + ln_gauss(d[2], s.axes)
        + ln_gauss(d[3], s.axes)
        + ln_gauss(w.x, s.rotation[0])
        + ln_gauss(w.y, s.rotation[1])
        + ln_gauss(w.z, s.rotation[2])
}

/// `ln Σ exp(xᵢ)`, stable.
fn log_sum_exp(xs: &[f64]) -> f64 {
    let m = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        return m;
    }
    m + xs.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

impl ParticleFilter {
    /// N copies of the initial hypothesis with equal weights; a [`FilterError`] when the
    /// settings fail [`FilterParams::check`].
    pub fn new(params: FilterParams, seed: u64, init: &Hypothesis) -> Result<Self, FilterError> {
        params.check()?;
        let n = params.particles;
        Ok(Self {
            params,
            rng: StdRng::seed_from_u64(seed),
            particles: vec![*init; n],
            parents: vec![*init; n],
            log_w: vec![0.0; n],
            log_ratio: vec![0.0; n],
            weights: vec![1.0 / n as f64; n],
            estimate: *init,
            last_resampling: None,
            frame: None,
            aspect: None,
            size: None,
        })
    }

    /// The settings.
    pub fn params(&self) -> &FilterParams {
        &self.params
    }

    /// The current particles.
    pub fn particles(&self) -> &[Hypothesis] {
        &self.particles
    }

    /// The current normalised weights.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Restarts the filter's random draws from `seed`, as [`ParticleFilter::new`] seeds them.
    pub fn reseed(&mut self, seed: u64) {
        self.rng = StdRng::seed_from_u64(seed);
    }

    /// Restarts the filter around a hypothesis: N copies, equal weights.
    pub fn reset(&mut self, h: &Hypothesis) {
        let n = self.particles.len();
        self.particles = vec![*h; n];
        self.parents = vec![*h; n];
        self.log_w = vec![0.0; n];
        self.log_ratio = vec![0.0; n];
        self.weights = vec![1.0 / n as f64; n];
        self.estimate = *h;
        self.last_resampling = None;
    }

    /// The bounds a proposal is held to: `(least centre, greatest cx, greatest cy, least
    /// semi-axis, greatest semi-axis)`, the frame's when [`Self::set_frame`] gave one.
    fn limits(&self) -> (f64, f64, f64, f64, f64) {
        let min_axis = self.params.min_axis;
        let (min_c, max_cx, max_cy, max_axis) = match self.frame {
            Some((w, h)) => (0.0, (w - 1.0).max(0.0), (h - 1.0).max(0.0), w.max(h)),
            None => (
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::INFINITY,
                f64::INFINITY,
            ),
        };
        let max_axis = self.params.max_axis.min(max_axis).max(min_axis);
        (min_c, max_cx, max_cy, min_axis, max_axis)
    }

    /// `h` held to the bounds every proposal is held to (centre on the frame, semi-axes within
    /// [`FilterParams::min_axis`] and the frame's longer side): for a hypothesis placed from
    /// outside the filter (a re-acquisition, a re-anchoring), which [`Self::reset`] takes as
    /// it is.
    pub fn bounded(&self, h: &Hypothesis) -> Hypothesis {
        let (min_c, max_cx, max_cy, min_axis, max_axis) = self.limits();
        Hypothesis {
            cx: h.cx.clamp(min_c, max_cx),
            cy: h.cy.clamp(min_c, max_cy),
            a: h.a.clamp(min_axis, max_axis),
            b: h.b.clamp(min_axis, max_axis),
            rot: h.rot,
        }
    }

    /// Applies a rotation to every particle and to the estimate (`R ← ΔR · R`): the pose step
    /// of a tracker that keeps the rotation out of the filtered state (the paper's TPE).
    pub fn rotate_all(&mut self, delta: &Matrix3<f64>) {
        for p in &mut self.particles {
            p.rot = delta * p.rot;
        }
        self.estimate.rot = delta * self.estimate.rot;
    }

    /// What the last [`ParticleFilter::update`] resampled (`None` when it did not, or after a
    /// reset).
    pub fn last_resampling(&self) -> Option<&Resampling> {
        self.last_resampling.as_ref()
    }

    /// The estimate of the last update: the weighted mean of the particles (rotations averaged
    /// on SO(3)), taken before resampling. Before any update, the initial hypothesis.
    pub fn estimate(&self) -> Hypothesis {
        self.estimate
    }

    fn normal(&mut self) -> f64 {
        StandardNormal.sample(&mut self.rng)
    }

    /// Draws the new particles from the proposal around `x_{k-1} + Δx` (a share
    /// [`FilterParams::still_share`] of them around `x_{k-1}`); `spread` scales Σ_G (1
    /// normally, larger while searching for a lost target).
    pub fn propose(&mut self, motion: &Motion, spread: f64) {
        let sg = self.params.proposal.scaled(spread.max(1e-6));
        let sp = self.params.dynamics;
        // A measurement that is not a finite number carries no motion: a candidate with a NaN
        // (or a share that is not finite) would turn every particle into NaN, which no weight
        // or mean recovers from.
        let usable =
            |(p, r): &&(f64, Matrix3<f64>)| p.is_finite() && r.iter().all(|v| v.is_finite());
        let total_p: f64 = motion
            .rotations
            .iter()
            .filter(usable)
            .map(|(p, _)| p.max(0.0))
            .sum();
        let cands: Vec<(f64, Matrix3<f64>)> = if !(total_p > 0.0 && total_p.is_finite()) {
            vec![(1.0, Matrix3::identity())]
        } else {
            motion
                .rotations
                .iter()
                .filter(usable)
                .map(|(p, r)| (p.max(0.0) / total_p, *r))
                .collect()
        };
        let (dx, dy) = if motion.dx.is_finite() && motion.dy.is_finite() {
            (motion.dx, motion.dy)
        } else {
            (0.0, 0.0)
        };
        let (min_c, max_cx, max_cy, min_axis, max_axis) = self.limits();
        let scale = if motion.scale.is_finite() && motion.scale > 0.0 {
            motion.scale
        } else {
            1.0
        };
        let still = self.params.still_share;
        let mut terms = Vec::with_capacity(2 * cands.len());
        let mut turns = Vec::with_capacity(cands.len());
        std::mem::swap(&mut self.parents, &mut self.particles);
        for i in 0..self.parents.len() {
            let parent = self.parents[i];
            // pick a rotation candidate
            let u: f64 = self.rng.random();
            let mut acc = 0.0;
            let mut c = cands.len() - 1;
            for (k, (p, _)) in cands.iter().enumerate() {
                acc += p;
                if u < acc {
                    c = k;
                    break;
                }
            }
            // Around where the motion moves the parent, or (a share `still` of them) around
            // the parent itself.
            let moved = [
                parent.cx + dx,
                parent.cy + dy,
                parent.a * scale,
                parent.b * scale,
            ];
            let stay = [parent.cx, parent.cy, parent.a, parent.b];
            let stays = still > 0.0 && self.rng.random::<f64>() < still;
            let [mean_cx, mean_cy, mean_a, mean_b] = if stays { stay } else { moved };
            let noise = [self.normal(), self.normal(), self.normal(), self.normal()];
            let wn = Vector3::new(
                self.normal() * sg.rotation[0],
                self.normal() * sg.rotation[1],
                self.normal() * sg.rotation[2],
            );
            let mut x = Hypothesis {
                cx: (mean_cx + noise[0] * sg.centre).clamp(min_c, max_cx),
                cy: (mean_cy + noise[1] * sg.centre).clamp(min_c, max_cy),
                a: (mean_a + noise[2] * sg.axes).clamp(min_axis, max_axis),
                b: (mean_b + noise[3] * sg.axes).clamp(min_axis, max_axis),
                rot: exp_so3(&wn) * cands[c].1 * parent.rot,
            };
            if let Some(range) = &self.size {
                (x.a, x.b) = range.hold(x.a, x.b);
            }
            if let Some(range) = &self.aspect {
                (x.a, x.b) = range.hold(x.a, x.b);
            }
            if self.size.is_some() || self.aspect.is_some() {
                x.a = x.a.clamp(min_axis, max_axis);
                x.b = x.b.clamp(min_axis, max_axis);
            }
            // ln q: the mixture over the rotation candidates (and the moved and the still
            // means) given this parent.
            // The turn from each candidate's mean, the same for both means.
            turns.clear();
            turns.extend(
                cands
                    .iter()
                    .map(|(_, r)| log_so3(&(x.rot * (r * parent.rot).transpose()))),
            );
            terms.clear();
            for (share, m) in [(1.0 - still, moved), (still, stay)] {
                if share <= 0.0 {
                    continue;
                }
                let d = [x.cx - m[0], x.cy - m[1], x.a - m[2], x.b - m[3]];
                for ((p, _), w) in cands.iter().zip(&turns) {
                    terms.push(share.ln() + p.ln() + ln_density(&d, w, &sg));
                }
            }
            let ln_q = log_sum_exp(&terms);
            // ln p(x_k | x_{k-1}): random walk around the parent.
            let dp = [
                x.cx - parent.cx,
                x.cy - parent.cy,
                x.a - parent.a,
                x.b - parent.b,
            ];
            let wp = log_so3(&(x.rot * parent.rot.transpose()));
            let ln_p = ln_density(&dp, &wp, &sp);
            self.log_ratio[i] = ln_p - ln_q;
            self.particles[i] = x;
        }
    }

    /// Keeps proposals on a `w x h` frame: centres within it and semi-axes no longer than its
    /// larger side. No likelihood can tell an ellipse covering the whole frame from a larger
    /// one, nor place one whose centre has left it, so without these bounds a lost target
    /// random-walked without end (on car4, 360x240, a semi-axis reached 2,861 px and the
    /// centre -335 px).
    pub fn set_frame(&mut self, w: u32, h: u32) {
        self.frame = Some((w as f64, h as f64));
    }

    /// Holds the proposals' aspect `a / b` to `range` (`None`: no bound): a proposal outside
    /// it is brought to the nearer end at the same size `sqrt(a b)`, before the semi-axis
    /// bounds. A rigid object's outline cannot take any shape: the tracker sets the range its
    /// object model allows ([`crate::pose::prior::Ellipsoid::outline_aspect_range`]), which
    /// keeps the ellipse from collapsing into a sliver that a few pixels of the right colour
    /// fill. Like the frame and semi-axis bounds, the weight of a moved proposal takes the
    /// proposal density `q` where the proposal lands, which is nearer the proposal's mean than
    /// where it was drawn, so a proposal pushed against the bound weighs a little less than
    /// one drawn inside it. (Taking `q` where it was drawn instead, or giving proposals
    /// outside the range no weight at all, was measured worse: see
    /// [`crate::tracker::TrackerConfig::aspect_slack`].)
    pub fn set_aspect_range(&mut self, range: Option<AspectRange>) {
        self.aspect = range;
    }

    /// The aspect range the proposals are held to ([`Self::set_aspect_range`]).
    pub fn aspect_range(&self) -> Option<AspectRange> {
        self.aspect
    }

    /// Holds the proposals' semi-axes to `range` (`None`: no bound), each brought to the
    /// nearer end of its bounds, before the aspect range ([`Self::set_aspect_range`]) and
    /// the semi-axis bounds. The tracker sets it while it is unsure of the target
    /// ([`crate::tracker::TrackerConfig::size_hold`]): a likelihood that has lost its target
    /// still ranks sizes, and a colour model prefers the smallest ellipse on a few pixels of
    /// the right colour. As with the aspect range, a moved proposal is weighed by the
    /// proposal density where it lands.
    pub fn set_size_range(&mut self, range: Option<SizeRange>) {
        self.size = range;
    }

    /// The particles in the engines' layout.
    pub fn particles_f32(&self, out: &mut Vec<Particle>) {
        out.clear();
        out.extend(self.particles.iter().map(Hypothesis::to_particle));
    }

    /// Weights the proposed particles with their log-likelihoods (one per particle, in
    /// particle order), resampling when the effective sample size is low. Returns what it did.
    /// The estimate ([`ParticleFilter::estimate`]) should be read before the next proposal;
    /// resampling keeps it unchanged in expectation.
    ///
    /// Errors: a number of log-likelihoods other than the particles' ([`FilterError::Length`]),
    /// before anything changes.
    pub fn update(&mut self, log_lik: &[f32]) -> Result<UpdateInfo, FilterError> {
        let n = self.particles.len();
        if log_lik.len() != n {
            return Err(FilterError::Length {
                got: log_lik.len(),
                particles: n,
            });
        }
        for ((w, &l), r) in self.log_w.iter_mut().zip(log_lik).zip(&self.log_ratio) {
            *w += l as f64 + r;
        }
        self.weights = resample::normalise_log_weights(&self.log_w);
        // Keep log-weights bounded: re-base them on the normalised weights.
        for i in 0..n {
            self.log_w[i] = if self.weights[i] > 0.0 {
                self.weights[i].ln()
            } else {
                f64::NEG_INFINITY
            };
        }
        let ess = resample::effective_sample_size(&self.weights);
        // One particle holding all the weight is resampled whatever N: with 2 particles
        // the ESS never falls below 0.5 N = 1, and a particle whose weight had underflowed
        // to 0 was carried, weightless, for the rest of the track.
        let collapsed = n > 1 && self.params.resample_below > 0.0 && ess <= 1.0 + 1e-12;
        let resampled = ess < self.params.resample_below * n as f64 || collapsed;
        self.estimate = self.weighted_estimate();
        self.last_resampling = None;
        if resampled {
            let u0: f64 = self.rng.random();
            let idx = resample::systematic(&self.weights, n, u0);
            self.particles = idx.iter().map(|&i| self.particles[i]).collect();
            self.log_w = vec![0.0; n];
            let weights = std::mem::replace(&mut self.weights, vec![1.0 / n as f64; n]);
            self.last_resampling = Some(Resampling {
                weights,
                u0,
                indices: idx,
            });
        }
        Ok(UpdateInfo { ess, resampled })
    }

    fn weighted_estimate(&self) -> Hypothesis {
        let mut e = Hypothesis {
            cx: 0.0,
            cy: 0.0,
            a: 0.0,
            b: 0.0,
            rot: Matrix3::identity(),
        };
        // Particles of zero weight are left out, not multiplied by 0: a non-finite state
        // would make the whole estimate NaN.
        let mut lo = [f64::INFINITY; 4];
        let mut hi = [f64::NEG_INFINITY; 4];
        for (p, &w) in self.particles.iter().zip(&self.weights) {
            if w == 0.0 {
                continue;
            }
            e.cx += w * p.cx;
            e.cy += w * p.cy;
            e.a += w * p.a;
            e.b += w * p.b;
            for (k, v) in [p.cx, p.cy, p.a, p.b].into_iter().enumerate() {
                lo[k] = lo[k].min(v);
                hi[k] = hi[k].max(v);
            }
        }
        // A mean lies within what it averages; rounding could put it an ulp past the
        // particles' bounds (semi-axes of 2.0000000000000018 on a 2 px frame, which a start
        // from the estimate then failed).
        for (k, v) in [&mut e.cx, &mut e.cy, &mut e.a, &mut e.b]
            .into_iter()
            .enumerate()
        {
            if lo[k] <= hi[k] {
                *v = v.clamp(lo[k], hi[k]);
            }
        }
        let rots: Vec<Matrix3<f64>> = self.particles.iter().map(|p| p.rot).collect();
        e.rot = weighted_mean(&rots, &self.weights);
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{angle_between, rot_x};

    fn init() -> Hypothesis {
        Hypothesis {
            cx: 50.0,
            cy: 40.0,
            a: 20.0,
            b: 25.0,
            rot: Matrix3::identity(),
        }
    }

    /// The estimate's centre and semi-axes lie within the particles' own: four particles of
    /// semi-axis 2 whose weights' products with 2 sum to 2.0000000000000004 give exactly 2.
    #[test]
    fn the_estimate_stays_within_the_particles() {
        let params = FilterParams {
            particles: 4,
            ..FilterParams::default()
        };
        let two = Hypothesis {
            a: 2.0,
            b: 2.0,
            ..init()
        };
        let mut f = ParticleFilter::new(params, 1, &two).unwrap();
        f.particles = vec![two; 4];
        f.weights = vec![
            0.18033978328881142,
            0.01856373348686474,
            0.518107368704161,
            0.282989114520163,
        ];
        let plain: f64 = f.weights.iter().map(|w| w * 2.0).sum();
        assert!(plain > 2.0, "{plain}");
        let e = f.weighted_estimate();
        assert_eq!((e.a, e.b, e.cx, e.cy), (2.0, 2.0, 50.0, 40.0));
    }

    #[test]
    fn settings_out_of_range_are_refused_by_name() {
        let d = FilterParams::default();
        assert!(d.check().is_ok());
        let at_most = FilterParams {
            particles: MAX_PARTICLES,
            ..d
        };
        assert!(at_most.check().is_ok());
        // A σ of 0 holds its component fixed, and above 1 the filter resamples every time.
        let fixed = FilterParams {
            proposal: StateSigma {
                rotation: [0.0; 3],
                ..d.proposal
            },
            resample_below: 2.0,
            ..d
        };
        assert!(fixed.check().is_ok());
        let sigma = |centre: f64, rz: f64| StateSigma {
            centre,
            rotation: [0.05, 0.05, rz],
            ..d.dynamics
        };
        let cases = [
            (FilterParams { particles: 0, ..d }, "particles 0"),
            (
                FilterParams {
                    particles: MAX_PARTICLES + 1,
                    ..d
                },
                "particles",
            ),
            (
                FilterParams {
                    proposal: sigma(f64::NAN, 0.05),
                    ..d
                },
                "proposal.centre NaN",
            ),
            (
                FilterParams {
                    dynamics: sigma(8.0, -0.1),
                    ..d
                },
                "dynamics.rotation[2] -0.1 rad (-5.7296°)",
            ),
            // Finite but absurd: the first step failed, blaming the estimate.
            (
                FilterParams {
                    proposal: sigma(8.0, 4.0),
                    ..d
                },
                "proposal.rotation[2] 4 rad (229.1831°) must be at most π rad (180°)",
            ),
            (
                FilterParams {
                    dynamics: sigma(1e7, 0.05),
                    ..d
                },
                "dynamics.centre 10000000 must be at most",
            ),
            (
                FilterParams {
                    resample_below: f64::NAN,
                    ..d
                },
                "resample_below",
            ),
            // A NaN bound made every proposal's clamp panic.
            (
                FilterParams {
                    min_axis: f64::NAN,
                    ..d
                },
                "min_axis NaN",
            ),
            (FilterParams { min_axis: 0.0, ..d }, "min_axis 0"),
            (
                FilterParams {
                    proposal: StateSigma {
                        axes: 0.0,
                        ..d.proposal
                    },
                    still_share: 0.2,
                    ..d
                },
                "proposal.axes is 0 where still_share is 0.2",
            ),
            (FilterParams { max_axis: 1.0, ..d }, "max_axis 1"),
            (
                FilterParams {
                    max_axis: f64::NAN,
                    ..d
                },
                "max_axis NaN",
            ),
        ];
        for (p, name) in cases {
            let Some(FilterError::BadParams(why)) = ParticleFilter::new(p, 1, &init()).err() else {
                panic!("{p:?} was accepted");
            };
            assert!(why.contains(name), "{why} does not name {name}");
        }
    }

    /// A motion that is not a number moves nothing: a NaN translation is taken as none, and a
    /// candidate rotation holding a NaN is dropped (the others keep their shares), where
    /// either had turned every particle, and so the estimate, into NaN.
    #[test]
    fn a_motion_that_is_not_a_number_moves_nothing() {
        let mut nan_rot = Matrix3::identity();
        nan_rot[(0, 1)] = f64::NAN;
        let turn = rot_x(0.2);
        let motion = |dx: f64, dy: f64, rotations: Vec<(f64, Matrix3<f64>)>| Motion {
            dx,
            dy,
            scale: 1.0,
            rotations,
        };
        let proposed = |m: &Motion| {
            let mut f = ParticleFilter::new(FilterParams::default(), 2, &init()).unwrap();
            f.propose(m, 1.0);
            (f.particles, f.log_ratio)
        };
        // Each as the motion without what is not a number, to the bit (a translation with
        // one such component is no translation).
        for (bad, clean) in [
            (
                motion(f64::NAN, 1.0, vec![(1.0, nan_rot)]),
                motion(0.0, 0.0, vec![]),
            ),
            (
                motion(3.0, 1.0, vec![(0.5, nan_rot), (0.5, turn)]),
                motion(3.0, 1.0, vec![(1.0, turn)]),
            ),
            (
                motion(f64::INFINITY, 1.0, vec![(f64::NAN, turn)]),
                motion(0.0, 0.0, vec![]),
            ),
        ] {
            let (particles, ratios) = proposed(&bad);
            assert!(particles.iter().all(|p| {
                [p.cx, p.cy, p.a, p.b].iter().all(|v| v.is_finite())
                    && p.rot.iter().all(|v| v.is_finite())
            }));
            assert_eq!((particles, ratios), proposed(&clean), "{:?}", bad.dx);
        }
    }

    /// A hypothesis placed from outside is held to the bounds of the proposals.
    #[test]
    fn bounded_holds_a_hypothesis_to_the_frame_and_the_axes() {
        let mut f = ParticleFilter::new(FilterParams::default(), 4, &init()).unwrap();
        let h = Hypothesis {
            cx: -3.0,
            cy: 130.0,
            a: 0.8,
            b: 500.0,
            rot: Matrix3::identity(),
        };
        let min = FilterParams::default().min_axis;
        let free = f.bounded(&h);
        assert_eq!(
            (free.cx, free.cy, free.a, free.b),
            (-3.0, 130.0, min, 500.0)
        );
        f.set_frame(160, 120);
        let b = f.bounded(&h);
        assert_eq!((b.cx, b.cy, b.a, b.b), (0.0, 119.0, min, 160.0));
    }

    /// A likelihood peaked at `t`: what an ideal measurement gives.
    fn loglik(f: &ParticleFilter, t: &Hypothesis) -> Vec<f32> {
        f.particles()
            .iter()
            .map(|p| {
                let d2 = (p.cx - t.cx).powi(2)
                    + (p.cy - t.cy).powi(2)
                    + (p.a - t.a).powi(2)
                    + (p.b - t.b).powi(2);
                let w = log_so3(&(p.rot * t.rot.transpose()));
                (-d2 / 2.0 - w.norm_squared() / (2.0 * 0.02f64.powi(2))) as f32
            })
            .collect()
    }

    #[test]
    fn proposals_stay_on_the_frame_once_it_is_set() {
        // A runaway motion (far off the frame, 50 times larger) must not carry particles off
        // the frame or beyond its size; without a frame they go where the motion says.
        let m = Motion {
            dx: 500.0,
            dy: -300.0,
            scale: 50.0,
            rotations: vec![(1.0, Matrix3::identity())],
        };
        let mut f = ParticleFilter::new(FilterParams::default(), 3, &init()).unwrap();
        f.set_frame(100, 80);
        f.propose(&m, 1.0);
        for p in f.particles() {
            assert!(
                (0.0..=99.0).contains(&p.cx) && (0.0..=79.0).contains(&p.cy),
                "{p:?}"
            );
            assert!(p.a <= 100.0 && p.b <= 100.0, "{p:?}");
        }
        // (All of them with the paper's proposal: none drawn around the previous state.)
        let paper = FilterParams {
            still_share: 0.0,
            ..FilterParams::default()
        };
        let mut free = ParticleFilter::new(paper, 3, &init()).unwrap();
        free.propose(&m, 1.0);
        assert!(free.particles().iter().all(|p| p.cx > 400.0 && p.a > 500.0));
    }

    #[test]
    fn an_aspect_range_is_checked_and_holds_the_size() {
        assert!(AspectRange::new(0.5, 2.0).is_some());
        assert!(AspectRange::new(1.0, f64::INFINITY).is_some());
        for (lo, hi) in [
            (0.0, 2.0),
            (-1.0, 2.0),
            (2.0, 0.5),
            (f64::NAN, 2.0),
            (0.5, f64::NAN),
        ] {
            assert!(AspectRange::new(lo, hi).is_none(), "({lo}, {hi})");
        }
        let r = AspectRange::new(0.5, 2.0).unwrap();
        // Inside: unchanged. Outside: at the nearer end, same sqrt(a b).
        assert_eq!(r.hold(10.0, 12.0), (10.0, 12.0));
        for (a, b, want) in [(40.0, 5.0, 2.0), (3.0, 30.0, 0.5)] {
            let (x, y) = r.hold(a, b);
            assert!((x / y - want).abs() < 1e-12, "{a} {b}: {x} {y}");
            assert!(
                ((x * y).sqrt() - (a * b).sqrt()).abs() < 1e-9,
                "{a} {b}: {x} {y}"
            );
        }
    }

    #[test]
    fn a_size_range_is_checked_and_clamps_each_axis() {
        let r = SizeRange::around(10.0, 20.0, 1.25).unwrap();
        assert_eq!(r.a(), (8.0, 12.5));
        assert_eq!(r.b(), (16.0, 25.0));
        assert_eq!(
            SizeRange::around(10.0, 20.0, 1.0).unwrap().a(),
            (10.0, 10.0)
        );
        for (a, b, k) in [
            (0.0, 20.0, 1.2),
            (10.0, -1.0, 1.2),
            (f64::NAN, 20.0, 1.2),
            (10.0, f64::INFINITY, 1.2),
            (10.0, 20.0, 0.9),
            (10.0, 20.0, f64::NAN),
            (10.0, 20.0, f64::INFINITY),
        ] {
            assert!(SizeRange::around(a, b, k).is_none(), "({a}, {b}, {k})");
        }
        // Inside: unchanged; outside: each axis at its nearer bound, independently.
        assert_eq!(r.hold(9.0, 17.0), (9.0, 17.0));
        assert_eq!(r.hold(2.0, 17.0), (8.0, 17.0));
        assert_eq!(r.hold(9.0, 90.0), (9.0, 25.0));
        assert_eq!(r.hold(100.0, 1.0), (12.5, 16.0));
    }

    /// Filter settings whose proposals walk the semi-axes widely (σ 15 px per step).
    fn wide_axis_walk() -> FilterParams {
        FilterParams {
            proposal: StateSigma {
                centre: 1.0,
                axes: 15.0,
                rotation: [0.01; 3],
            },
            ..FilterParams::default()
        }
    }

    #[test]
    fn proposals_keep_the_size_range_once_it_is_set() {
        // A wide random walk on the semi-axes leaves any size band; with a range none is
        // outside it, and the aspect range still holds inside it.
        let params = wide_axis_walk();
        let still = Motion::still();
        let (a0, b0) = (init().a, init().b);
        let size = SizeRange::around(a0, b0, 1.2).unwrap();
        let aspect = AspectRange::new(0.75, 4.0 / 3.0).unwrap();
        let inside = |p: &Hypothesis| {
            let tol = 1.0 + 1e-9;
            p.a <= a0 * 1.2 * tol
                && p.a >= a0 / 1.2 / tol
                && p.b <= b0 * 1.2 * tol
                && p.b >= b0 / 1.2 / tol
        };
        let mut f = ParticleFilter::new(params, 5, &init()).unwrap();
        f.set_size_range(Some(size));
        f.set_aspect_range(Some(aspect));
        let mut free = ParticleFilter::new(params, 5, &init()).unwrap();
        for _ in 0..3 {
            f.propose(&still, 1.0);
            free.propose(&still, 1.0);
            for p in f.particles() {
                assert!(inside(p), "{p:?}");
                let r = p.a / p.b;
                assert!((0.75 - 1e-12..=4.0 / 3.0 + 1e-12).contains(&r), "{p:?}");
            }
        }
        let outside = free.particles().iter().filter(|p| !inside(p)).count();
        assert!(
            outside > 100,
            "only {outside} of 200 free proposals outside"
        );
        // Clearing the range frees them again.
        f.set_size_range(None);
        f.propose(&still, 1.0);
        assert!(f.particles().iter().any(|p| !inside(p)));
    }

    #[test]
    fn proposals_keep_the_aspect_range_once_it_is_set() {
        // A wide random walk on the semi-axes makes slivers; with a range none is left, and
        // without it some are.
        let params = wide_axis_walk();
        let still = Motion::still();
        let range = AspectRange::new(0.75, 4.0 / 3.0).unwrap();
        let mut f = ParticleFilter::new(params, 5, &init()).unwrap();
        f.set_aspect_range(Some(range));
        let mut free = ParticleFilter::new(params, 5, &init()).unwrap();
        for _ in 0..3 {
            f.propose(&still, 1.0);
            free.propose(&still, 1.0);
        }
        for p in f.particles() {
            let r = p.a / p.b;
            assert!((0.75 - 1e-12..=4.0 / 3.0 + 1e-12).contains(&r), "{p:?}");
        }
        let outside = free
            .particles()
            .iter()
            .filter(|p| !(0.75..=4.0 / 3.0).contains(&(p.a / p.b)))
            .count();
        assert!(outside > 50, "only {outside} of 200 free proposals outside");
        // Clearing the range frees them again.
        f.set_aspect_range(None);
        f.propose(&still, 1.0);
        assert!(
            f.particles()
                .iter()
                .any(|p| !(0.75..=4.0 / 3.0).contains(&(p.a / p.b)))
        );
    }

    #[test]
    fn proposals_that_stay_add_no_lag() {
        // Weighed by the mixture's density, the proposals drawn around the previous state
        // hold the estimate back little more than the random walk's prior does: over 50
        // seeds of 30 steps of (2, -1) px, the mean error is 0.04 px at share 0, 0.06 at 0.2
        // and 0.07 at 0.5, within 0.12 px. Weighed as if drawn around the moved state, they
        // pull it back towards where the target was: 0.19 and 0.39 px.
        for still in [0.0, 0.2, 0.5] {
            let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
            for seed in 0..50 {
                let p = FilterParams {
                    still_share: still,
                    ..FilterParams::default()
                };
                let mut f = ParticleFilter::new(p, seed, &init()).unwrap();
                let mut t = init();
                for _ in 0..30 {
                    t.cx += 2.0;
                    t.cy -= 1.0;
                    let m = Motion {
                        dx: 2.0,
                        dy: -1.0,
                        ..Motion::still()
                    };
                    f.propose(&m, 1.0);
                    let l = loglik(&f, &t);
                    f.update(&l).unwrap();
                    let e = f.estimate();
                    (sx, sy, n) = (sx + e.cx - t.cx, sy + e.cy - t.cy, n + 1.0);
                }
            }
            let (mx, my) = (sx / n, sy / n);
            assert!(mx.abs() < 0.12 && my.abs() < 0.12, "{still}: {mx} {my}");
        }
    }

    #[test]
    fn follows_a_moving_target_with_the_right_motion() {
        // The paper's proposal, every particle around the moved state (with a share around
        // the previous one: `proposals_that_stay_add_no_lag`).
        let paper = FilterParams {
            still_share: 0.0,
            ..FilterParams::default()
        };
        let mut f = ParticleFilter::new(paper, 7, &init()).unwrap();
        let mut t = init();
        let step = rot_x(0.03);
        for _ in 0..30 {
            t.cx += 2.0;
            t.cy -= 1.0;
            t.rot = step * t.rot;
            let m = Motion {
                dx: 2.0,
                dy: -1.0,
                scale: 1.0,
                rotations: vec![(1.0, step)],
            };
            f.propose(&m, 1.0);
            let l = loglik(&f, &t);
            f.update(&l).unwrap();
        }
        let e = f.estimate();
        assert!(
            (e.cx - t.cx).abs() < 0.5 && (e.cy - t.cy).abs() < 0.5,
            "{e:?} vs {t:?}"
        );
        assert!(angle_between(&e.rot, &t.rot) < 0.02);
    }

    #[test]
    fn the_likelihood_picks_the_right_member_of_a_necker_pair() {
        let mut f = ParticleFilter::new(FilterParams::default(), 3, &init()).unwrap();
        let mut t = init();
        let good = rot_x(0.05);
        let mirror = rot_x(-0.05);
        for _ in 0..10 {
            t.rot = good * t.rot;
            let m = Motion {
                dx: 0.0,
                dy: 0.0,
                scale: 1.0,
                rotations: vec![(0.5, mirror), (0.5, good)],
            };
            f.propose(&m, 1.0);
            let l = loglik(&f, &t);
            f.update(&l).unwrap();
        }
        assert!(angle_between(&f.estimate().rot, &t.rot) < 0.02);
    }

    #[test]
    fn deterministic_for_a_seed() {
        let run = |seed| {
            let mut f = ParticleFilter::new(FilterParams::default(), seed, &init()).unwrap();
            let t = Hypothesis { cx: 53.0, ..init() };
            for _ in 0..5 {
                f.propose(&Motion::still(), 1.0);
                let l = loglik(&f, &t);
                f.update(&l).unwrap();
            }
            f.particles().to_vec()
        };
        assert_eq!(run(11), run(11));
        assert_ne!(run(11), run(12));
    }

    #[test]
    fn proposal_ratio_vanishes_when_dynamics_equal_proposal_and_no_motion() {
        let mut p = FilterParams::default();
        p.dynamics = p.proposal;
        let mut f = ParticleFilter::new(p, 5, &init()).unwrap();
        f.propose(&Motion::still(), 1.0);
        assert!(f.log_ratio.iter().all(|r| r.abs() < 1e-9));
        // then the weights are the normalised likelihoods
        let l: Vec<f32> = (0..f.particles().len())
            .map(|i| -(i as f32) * 0.01)
            .collect();
        f.params.resample_below = 0.0;
        f.update(&l).unwrap();
        let w = f.weights();
        assert!((w[0] / w[1] - (0.01f64).exp()).abs() < 1e-4);
    }

    /// `ln N(x; 0, σ)` without its constant, written out apart from the module's helpers.
    fn gauss(x: f64, sigma: f64) -> f64 {
        -0.5 * (x * x) / (sigma * sigma) - sigma.ln()
    }

    /// The rotation vector of `m`, through nalgebra rather than the module's `log_so3`.
    fn rotvec(m: &Matrix3<f64>) -> Vector3<f64> {
        nalgebra::Rotation3::from_matrix_unchecked(*m).scaled_axis()
    }

    #[test]
    fn proposal_ratio_is_the_dynamics_over_the_candidates_mixture() {
        for still in [0.0, 0.25] {
            proposal_ratio_by_hand(still);
        }
    }

    /// ln p(x | parent) - ln q(x | parent, motion) by hand, with a motion that shifts and
    /// scales, two rotation candidates of probability 0.3 and 0.7, proposal and dynamics σ
    /// that differ, spread 1.5 (which scales the proposal's σ), and a share `still` of the
    /// proposals drawn around the parent.
    fn proposal_ratio_by_hand(still: f64) {
        let p = FilterParams {
            particles: 4,
            proposal: StateSigma {
                centre: 2.0,
                axes: 1.0,
                rotation: [0.02, 0.03, 0.04],
            },
            dynamics: StateSigma {
                centre: 3.0,
                axes: 0.5,
                rotation: [0.05, 0.06, 0.07],
            },
            still_share: still,
            ..FilterParams::default()
        };
        let parent = Hypothesis {
            rot: rot_x(0.2),
            ..init()
        };
        let mut f = ParticleFilter::new(p, 3, &parent).unwrap();
        let (r1, r2) = (rot_x(0.05), crate::geometry::rot_y(-0.04));
        let m = Motion {
            dx: 2.0,
            dy: -1.0,
            scale: 1.1,
            rotations: vec![(0.3, r1), (0.7, r2)],
        };
        f.propose(&m, 1.5);
        for (x, &ratio) in f.particles().iter().zip(&f.log_ratio) {
            let g = |s: f64| 1.5 * s;
            // Moved by the motion: centre (52, 39), semi-axes 22 and 27.5; still: the
            // parent's (50, 40), 20 and 25.
            let lin_q = |cx: f64, cy: f64, a: f64, b: f64| {
                gauss(x.cx - cx, g(2.0))
                    + gauss(x.cy - cy, g(2.0))
                    + gauss(x.a - a, g(1.0))
                    + gauss(x.b - b, g(1.0))
            };
            let rot_q = |r: &Matrix3<f64>| {
                let w = rotvec(&(x.rot * (r * parent.rot).transpose()));
                gauss(w.x, g(0.02)) + gauss(w.y, g(0.03)) + gauss(w.z, g(0.04))
            };
            let rot_mix = 0.3 * rot_q(&r1).exp() + 0.7 * rot_q(&r2).exp();
            let ln_q = ((1.0 - still) * lin_q(52.0, 39.0, 22.0, 27.5).exp() * rot_mix
                + still * lin_q(50.0, 40.0, 20.0, 25.0).exp() * rot_mix)
                .ln();
            let w = rotvec(&(x.rot * parent.rot.transpose()));
            let ln_p = gauss(x.cx - 50.0, 3.0)
                + gauss(x.cy - 40.0, 3.0)
                + gauss(x.a - 20.0, 0.5)
                + gauss(x.b - 25.0, 0.5)
                + gauss(w.x, 0.05)
                + gauss(w.y, 0.06)
                + gauss(w.z, 0.07);
            assert!(
                (ratio - (ln_p - ln_q)).abs() < 1e-6 * (1.0 + ratio.abs()),
                "{ratio} against {}",
                ln_p - ln_q
            );
        }
    }

    #[test]
    fn a_share_of_the_proposals_stays_around_the_previous_state() {
        // A motion of 100 px: the proposals drawn around the parent are told apart by
        // where they land. Over 4000 particles the share is within 4 standard deviations of
        // the setting's.
        for still in [0.0, 0.2, 0.5] {
            let p = FilterParams {
                particles: 4000,
                still_share: still,
                ..FilterParams::default()
            };
            let mut f = ParticleFilter::new(p, 11, &init()).unwrap();
            let m = Motion {
                dx: 100.0,
                ..Motion::still()
            };
            f.propose(&m, 1.0);
            let stayed = f.particles().iter().filter(|x| x.cx < 100.0).count() as f64 / 4000.0;
            let sd = (still * (1.0 - still) / 4000.0).sqrt();
            assert!(
                (stayed - still).abs() <= 4.0 * sd + 1e-12,
                "{still}: {stayed}"
            );
            // Where the likelihood is flat, the weights are p / q: a particle that stayed, on
            // a random walk of 8 px, is far likelier a priori than one 100 px away.
            if still > 0.0 {
                let (near, far): (Vec<_>, Vec<_>) = f
                    .particles()
                    .iter()
                    .zip(&f.log_ratio)
                    .partition(|(x, _)| x.cx < 100.0);
                let mean = |v: &[(&Hypothesis, &f64)]| {
                    v.iter().map(|(_, r)| **r).sum::<f64>() / v.len() as f64
                };
                assert!(mean(&near) > mean(&far) + 50.0);
            }
        }
        // Out of [0, 1): refused by name.
        for bad in [-0.1, 1.0, f64::NAN] {
            let p = FilterParams {
                still_share: bad,
                ..FilterParams::default()
            };
            let Some(FilterError::BadParams(why)) = ParticleFilter::new(p, 1, &init()).err() else {
                panic!("still_share {bad} accepted");
            };
            assert!(why.contains("still_share"), "{why}");
        }
    }

    #[test]
    fn weights_accumulate_over_updates_without_resampling() {
        // Without resampling a particle's weight is the product over frames of its likelihood
        // and its proposal ratio (eq. 27): ∝ exp(l1 + l2 + r1 + r2).
        let mut f = ParticleFilter::new(
            FilterParams {
                particles: 3,
                resample_below: 0.0,
                ..FilterParams::default()
            },
            7,
            &init(),
        )
        .unwrap();
        let mut total = [0.0f64; 3];
        for l in [[-1.0f32, -0.5, -2.0], [-0.3, -1.2, -0.1]] {
            f.propose(&Motion::still(), 1.0);
            for (t, (&li, &ri)) in total.iter_mut().zip(l.iter().zip(&f.log_ratio)) {
                *t += li as f64 + ri;
            }
            assert!(!f.update(&l).unwrap().resampled);
        }
        let z: f64 = total.iter().map(|t| t.exp()).sum();
        for (w, t) in f.weights().iter().zip(&total) {
            assert!(
                (w - t.exp() / z).abs() < 1e-9,
                "{w} against {}",
                t.exp() / z
            );
        }
    }

    /// Log-likelihoods of another count than the particles' are refused, before anything
    /// changes (they used to stand in as -inf, or be ignored).
    #[test]
    fn an_update_of_the_wrong_length_is_refused_and_changes_nothing() {
        let mut f = ParticleFilter::new(
            FilterParams {
                particles: 4,
                ..FilterParams::default()
            },
            7,
            &init(),
        )
        .unwrap();
        f.propose(&Motion::still(), 1.0);
        let before = f.weights().to_vec();
        for l in [&[0.0f32; 3][..], &[0.0; 5], &[]] {
            let r = f.update(l);
            assert!(
                matches!(r, Err(FilterError::Length { got, particles: 4 }) if got == l.len()),
                "{r:?}"
            );
            assert_eq!(f.weights(), &before[..]);
        }
        assert!(f.update(&[0.0; 4]).is_ok());
    }

    /// A dynamics σ of 0 where the proposal moves the component is refused; 0 in both holds
    /// it fixed and is accepted.
    #[test]
    fn a_zero_random_walk_under_a_moving_proposal_is_refused() {
        let d = FilterParams::default();
        let bad = FilterParams {
            dynamics: StateSigma {
                rotation: [0.05, 0.0, 0.05],
                ..d.dynamics
            },
            ..d
        };
        let Err(FilterError::BadParams(why)) = bad.check() else {
            panic!("accepted")
        };
        assert!(why.contains("dynamics.rotation[1] is 0"), "{why}");
        let held = FilterParams {
            proposal: StateSigma {
                rotation: [0.03, 0.0, 0.02],
                ..d.proposal
            },
            ..bad
        };
        assert!(held.check().is_ok());
    }

    /// Two particles, at cx 50 and 60, with no proposal ratio.
    fn two_particles() -> ParticleFilter {
        let mut f = ParticleFilter::new(
            FilterParams {
                particles: 2,
                ..FilterParams::default()
            },
            1,
            &init(),
        )
        .unwrap();
        f.particles[1].cx = 60.0;
        f.log_ratio = vec![0.0, 0.0];
        f
    }

    #[test]
    fn weighted_mean_estimate_uses_weights() {
        let mut f = two_particles();
        f.params.resample_below = 0.0;
        f.update(&[0.0, (3.0f32).ln()]).unwrap();
        assert!((f.estimate().cx - (0.25 * 50.0 + 0.75 * 60.0)).abs() < 1e-5);
    }

    /// Two particles resample once one holds all the weight (0.5 N = 1 is an ESS they never
    /// fall below), and 0 still means never.
    #[test]
    fn two_particles_resample_when_one_holds_all_the_weight() {
        let mut f = two_particles();
        let info = f.update(&[0.0, -1.0]).unwrap();
        assert!(!info.resampled && info.ess > 1.0, "{info:?}");
        let info = f.update(&[0.0, f32::NEG_INFINITY]).unwrap();
        assert!(info.resampled, "{info:?}");
        assert!(f.particles().iter().all(|p| p.cx == 50.0));
        f.params.resample_below = 0.0;
        f.particles[1].cx = 60.0;
        let info = f.update(&[0.0, f32::NEG_INFINITY]).unwrap();
        assert!(!info.resampled, "{info:?}");
    }

    #[test]
    fn last_resampling_records_the_draw_it_made() {
        let mut f = ParticleFilter::new(FilterParams::default(), 9, &init()).unwrap();
        f.propose(&Motion::still(), 1.0);
        let before = f.particles().to_vec();
        let t = Hypothesis { cx: 52.0, ..init() };
        let l = loglik(&f, &t);
        f.params.resample_below = 2.0; // always
        let info = f.update(&l).unwrap();
        assert!(info.resampled);
        let r = f.last_resampling().expect("resampled").clone();
        assert_eq!(
            r.indices,
            resample::systematic(&r.weights, before.len(), r.u0)
        );
        assert!((r.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        for (p, &i) in f.particles().iter().zip(&r.indices) {
            assert_eq!(*p, before[i]);
        }
        f.params.resample_below = 0.0; // never
        f.propose(&Motion::still(), 1.0);
        let l = loglik(&f, &t);
        assert!(!f.update(&l).unwrap().resampled);
        assert!(f.last_resampling().is_none());
    }
}
