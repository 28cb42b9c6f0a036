//! Particle likelihoods `p(z | x) = p_colour · p_gradient · p_feature` (SPEC section 3), for all
//! particles of a frame at once, behind one interface with two implementations: the CPU
//! reference ([`cpu`]) and the WGSL compute engine ([`gpu`]). A fourth, optional term,
//! `p_contrast` ([`TERM_CONTRAST`], [`ContrastTable`]), is the project's addition: the
//! target's colours against its surroundings, read from the same per-particle histogram.
//! A fifth, the appearance template ([`template`]), is evaluated on the CPU for either engine
//! from the frame's grey image and added by the tracker.
//!
//! The data crossing this interface is flat and `Pod` so the GPU engine uploads it as is.

pub mod cpu;
mod fallback;
pub mod gpu;
pub mod template;

pub use fallback::FallbackEngine;

use bytemuck::{Pod, Zeroable};

/// One particle as the likelihood engines see it: the state `(cx, cy, a, b, rx, ry, rz)` in
/// `f32` (pixels, radians), padded to 32 bytes. Mirrored in WGSL.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Particle {
    /// Centre x (pixels).
    pub cx: f32,
    /// Centre y (pixels).
    pub cy: f32,
    /// Semi-axis a (pixels).
    pub a: f32,
    /// Semi-axis b (pixels).
    pub b: f32,
    /// Tilt (radians).
    pub rx: f32,
    /// Pan (radians).
    pub ry: f32,
    /// Roll (radians).
    pub rz: f32,
    /// Padding to 32 bytes.
    pub _pad: f32,
}

/// The per-particle result: the log of each likelihood term and their sum. Mirrored in WGSL.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct TermLogs {
    /// `ln p_colour`.
    pub colour: f32,
    /// `ln p_gradient`.
    pub gradient: f32,
    /// `ln p_feature`.
    pub feature: f32,
    /// The foreground/background contrast of the ellipse's pixels ([`ContrastTable`]):
    /// `contrast_scale · Σ_pixels L[bin]`.
    pub contrast: f32,
    /// The sum of the enabled terms: the particle's log-likelihood.
    pub total: f32,
}

/// A matched feature: its position in the previous frame `p` and in the current frame `q`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct FeaturePair {
    /// Position in frame t-1 (pixels).
    pub p: [f32; 2],
    /// Position in frame t (pixels).
    pub q: [f32; 2],
}

/// A matched feature as the feature term uses it, prepared once per frame on the host: the
/// previous position lifted to 3D relative to the previous estimate's centre,
/// `x = (p − c_prev, z)` (pixels, `z` negative towards the camera), and the matched position
/// `q` in the current frame. Mirrored in WGSL; both engines read the same lift, so the GPU
/// does per particle only what depends on the particle.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct LiftedFeature {
    /// `X = (p − c_prev, z)`.
    pub x: [f32; 3],
    /// Matched position in the current frame (pixels).
    pub q: [f32; 2],
}

impl FeaturePair {
    /// The pairs' positions as two lists in `f64`, `(p, q)`, the form the pose solvers take.
    pub fn split(pairs: &[FeaturePair]) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        pairs
            .iter()
            .map(|f| {
                (
                    [f.p[0] as f64, f.p[1] as f64],
                    [f.q[0] as f64, f.q[1] as f64],
                )
            })
            .unzip()
    }
}

/// Number of bins of the colour histogram: 8×8×8 RGB.
pub const HIST_BINS: usize = 512;

/// A normalised 8×8×8 RGB histogram, bin `(r >> 5) * 64 + (g >> 5) * 8 + (b >> 5)`.
#[derive(Debug, Clone, PartialEq)]
pub struct ColourHistogram(pub Vec<f32>);

/// Per-bin log-odds of the target against its surroundings, under the same binning as the
/// colour model: `L_k = ln((f_k + ε) / (g_k + ε))` with `f` the target's normalised
/// histogram, `g` the background's (a ring around the target), `ε` =
/// [`ContrastTable::EPSILON`], clamped to `±limit`.
///
/// Summed over the pixels inside an ellipse, `Σ L[bin]` grows while the ellipse takes in
/// pixels that look like the target and shrinks when it takes in background. It gives the
/// colour cue a scale: the Bhattacharyya similarity of the colour term is nearly as high for
/// an ellipse inside the target, or one a little larger on a background of similar colours,
/// as for the right one. This is the object-versus-surroundings colour model of
/// discriminative colour trackers (e.g. Possegger, Mauthner and Bischof, "In defense of
/// color-based model-free tracking", CVPR 2015), evaluated here per particle from the
/// histogram the colour term builds anyway.
///
/// The log-odds carry no prior: a pixel adds to the sum whenever its colour is likelier in
/// the target than in the ring, so an ellipse grows over target-coloured surroundings (on
/// girl, the long hair below the chin). Subtracting the ring's area prior (`ln 2.24` for the
/// tracker's default ring, so that only pixels more likely target than ring add) makes the
/// sum punish area instead: measured 2026-11-25 (filter seeds 0-15), the ellipse shrank to
/// a few pixels and girl fell from 0.536 to 0.135 success AUC, car4 from 0.578 to 0.317
/// (0.172 and 0.352 with half that shift).
#[derive(Debug, Clone, PartialEq)]
pub struct ContrastTable(pub Vec<f32>);

impl ContrastTable {
    /// `ε` of the log-odds: a bin seen in neither histogram scores 0; one seen in only one
    /// of them is bounded by `limit` in any case.
    pub const EPSILON: f32 = 1e-3;

    /// The table of a target histogram `fg` against a background histogram `bg` (both
    /// normalised, [`HIST_BINS`] bins), clamped to `±limit`. Errors on a wrong bin count or
    /// a negative, non-finite or non-positive `limit`.
    pub fn from_histograms(
        fg: &ColourHistogram,
        bg: &ColourHistogram,
        limit: f32,
    ) -> Result<Self, LikelihoodError> {
        if fg.0.len() != HIST_BINS || bg.0.len() != HIST_BINS {
            return Err(LikelihoodError::Invalid(format!(
                "contrast histograms have {} and {} bins, expected {HIST_BINS}",
                fg.0.len(),
                bg.0.len()
            )));
        }
        if !(limit.is_finite() && limit > 0.0) {
            return Err(LikelihoodError::Invalid(format!(
                "contrast limit {limit} is not positive and finite"
            )));
        }
        let eps = Self::EPSILON;
        Ok(Self(
            fg.0.iter()
                .zip(&bg.0)
                .map(|(&f, &g)| {
                    let l = ((f.max(0.0) + eps) / (g.max(0.0) + eps)).ln();
                    if l.is_nan() {
                        0.0
                    } else {
                        l.clamp(-limit, limit)
                    }
                })
                .collect(),
        ))
    }

    /// Checks what both engines need: [`HIST_BINS`] finite entries.
    pub fn check(&self) -> Result<(), LikelihoodError> {
        if self.0.len() != HIST_BINS {
            return Err(LikelihoodError::Invalid(format!(
                "contrast table has {} bins, expected {HIST_BINS}",
                self.0.len()
            )));
        }
        if !self.0.iter().all(|v| v.is_finite()) {
            return Err(LikelihoodError::Invalid(
                "contrast table has a non-finite entry".into(),
            ));
        }
        Ok(())
    }
}

/// What the likelihood of one frame depends on besides the particles.
#[derive(Debug, Clone, Copy)]
pub struct FrameInput<'a> {
    /// The current frame.
    pub image: &'a image::RgbImage,
    /// Matched features between the previous and the current frame.
    pub features: &'a [FeaturePair],
    /// The depth `z` of each feature's lift (pixels, negative towards the camera), one per
    /// feature, from a model of the object in the previous view that the caller holds (the
    /// tracker's ellipsoid turned to the previous estimate's pose when the camera is known,
    /// [`crate::tracker::TrackerConfig::camera_hfov_deg`]); `None` for the ellipsoid facing
    /// the camera of [`LikelihoodParams::depth_ratio`].
    pub depths: Option<&'a [f32]>,
    /// The previous frame's estimate: its centre, semi-axes and rotation. The feature term
    /// lifts `p` to 3D, `X = (p − c_prev, z)` with `z` from [`FrameInput::depths`] or the
    /// ellipsoid prior of [`LikelihoodParams::depth_ratio`], and predicts `q̂ = c_particle + s · (ΔR X)_xy`, with
    /// `ΔR = R_particle · R_prevᵀ` and `s = sqrt(a b / (a_prev b_prev))`.
    pub prev: Particle,
    /// Orientation of the ellipse in the reference pose (radians): a particle's ellipse is
    /// turned by `theta0 + rz`.
    pub theta0: f32,
}

/// Constants of the likelihood model. Mirrored in WGSL (as a uniform).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LikelihoodParams {
    /// σc of the colour term: `ln p_colour = -(1 - ρ) / (2 σc²)`.
    pub sigma_colour: f32,
    /// σz, contour noise of the gradient term (pixels).
    pub sigma_z: f32,
    /// γ, Poisson clutter density of edges along a normal line (per pixel).
    pub clutter_density: f32,
    /// p0, probability that no detected edge on a line is the contour.
    pub p_no_contour: f32,
    /// Threshold on the gradient magnitude for an edge (luma units per pixel).
    pub edge_threshold: f32,
    /// Half length of each normal line (pixels).
    pub line_half_length: f32,
    /// ε of the feature term `p_feature = Σ 1 / (ε + ‖q − q̂‖)` (pixels).
    pub feature_eps: f32,
    /// Depth of the visible surface relative to the ellipse size, for the feature term's
    /// ellipsoid prior: a feature at normalised ellipse position `(u, v)` of the previous
    /// ellipse is lifted to depth `z = -depth_ratio · sqrt(a b) · sqrt(max(0, 1 - u² - v²))`
    /// (towards the camera) before the particle's rotation is applied. This is what lets the
    /// feature term tell a tilt from its mirror (the Necker ambiguity). 0 disables it.
    pub depth_ratio: f32,
    /// Number L of normal lines.
    pub num_lines: u32,
    /// Bit flags of the enabled terms: [`TERM_COLOUR`], [`TERM_GRADIENT`], [`TERM_FEATURE`].
    pub terms: u32,
    /// What the colour histogram's bins count: [`COLOUR_RGB`] (8x8x8 RGB, the paper's) or
    /// [`COLOUR_LUMA`] (64 levels of luma, for grayscale footage, where RGB bins leave only
    /// the 8 on their diagonal).
    pub colour_bins: u32,
    /// The factor of the contrast term ([`TERM_CONTRAST`]): `ln p_contrast = contrast_scale ·
    /// Σ L[bin]` over the pixels inside the ellipse, with `L` the engine's
    /// [`ContrastTable`]. The tracker sets it every frame to its weight divided by the area
    /// of the previous estimate, so that the term is a share of that area: per particle it
    /// is the same sum at every size, which is what lets it prefer the ellipse that holds the
    /// target's pixels and no more. Not serialised (read back, it is the default's): a
    /// tracker's setting would be overwritten on its first frame.
    #[serde(skip)]
    pub contrast_scale: f32,
}

impl LikelihoodParams {
    /// Checks the settings of the enabled terms, as every evaluation does: known term flags
    /// and colour binning, a finite `contrast_scale` (contrast), a positive finite
    /// `sigma_colour` of at least 1e-19 (colour), positive finite `sigma_z` of at least 1e-19 and
    /// `clutter_density` with `p_no_contour` in `(0, 1]`, whose clutter gain neither overflows
    /// nor falls below `f32::EPSILON` (where the term would read 0 on every line), a finite `edge_threshold`,
    /// `line_half_length` in `[0, 4096]` and at most 4096 lines (gradient), and a finite
    /// `feature_eps` of at least 1e-6 with a finite `depth_ratio` of at least 0 (feature).
    pub fn check(&self) -> Result<(), LikelihoodError> {
        let bad = |what: &str| Err(LikelihoodError::Invalid(what.to_string()));
        let pos = |v: f32| v.is_finite() && v > 0.0;
        if self.terms & !TERM_ALL != 0 {
            return bad("unknown bits in the likelihood terms flags");
        }
        if self.terms & TERM_CONTRAST != 0 && !self.contrast_scale.is_finite() {
            return bad("contrast_scale is not finite");
        }
        // The terms divide by 2σ²: below about 1e-19 it is no normal f32 (at 1e-30 the gradient
        // term read 0/0 on a contour, at 1e-20 the colour term -inf on every imperfect match).
        let sq_normal = |v: f32| (2.0 * v * v).is_normal();
        if self.terms & TERM_COLOUR != 0
            && !(pos(self.sigma_colour) && sq_normal(self.sigma_colour))
        {
            return bad("sigma_colour must be finite and at least 1e-19");
        }
        if self.colour_bins > COLOUR_LUMA {
            return bad("colour_bins must be COLOUR_RGB (0) or COLOUR_LUMA (1)");
        }
        if self.terms & TERM_GRADIENT != 0 {
            if !(pos(self.sigma_z) && pos(self.p_no_contour) && pos(self.clutter_density)) {
                return bad(
                    "sigma_z, p_no_contour and clutter_density must be positive and finite",
                );
            }
            if !sq_normal(self.sigma_z) {
                return bad("sigma_z must be at least 1e-19");
            }
            if self.p_no_contour > 1.0 {
                return bad("p_no_contour is a probability: at most 1");
            }
            let gain = cpu::gradient::clutter_gain(self);
            if !gain.is_finite() {
                return bad("1 / (sqrt(2 pi) sigma_z p0 gamma) overflows");
            }
            // Below f32's epsilon `ln(1 + K e^..)` is 0 on every line: no contour term.
            if gain < f32::EPSILON {
                return bad("1 / (sqrt(2 pi) sigma_z p0 gamma) is below f32 precision");
            }
            if !self.edge_threshold.is_finite() {
                return bad("edge_threshold is not finite");
            }
            if !(self.line_half_length >= 0.0 && self.line_half_length <= 4096.0) {
                return bad("line_half_length must be in [0, 4096]");
            }
            if self.num_lines > 4096 {
                return bad("num_lines must be at most 4096");
            }
        }
        if self.terms & TERM_FEATURE != 0 {
            // An exact match weighs 1 / feature_eps: below 1e-6 px one swamps the rest, and a
            // subnormal one made it infinite, scoring the best particle as degenerate.
            if !(pos(self.feature_eps) && self.feature_eps >= 1e-6) {
                return bad("feature_eps must be finite and at least 1e-6");
            }
            if !(self.depth_ratio.is_finite() && self.depth_ratio >= 0.0) {
                return bad("depth_ratio must be finite and non-negative");
            }
        }
        Ok(())
    }
}

/// [`LikelihoodParams::colour_bins`]: bin `(r >> 5) * 64 + (g >> 5) * 8 + (b >> 5)` of 512.
pub const COLOUR_RGB: u32 = 0;
/// [`LikelihoodParams::colour_bins`]: bin `luma >> 2` (64 of the 512 bins used), luma the
/// integer `(77 r + 150 g + 29 b + 128) >> 8`, which is exactly the grey level of a grey pixel.
pub const COLOUR_LUMA: u32 = 1;

/// Flag of the colour term in [`LikelihoodParams::terms`].
pub const TERM_COLOUR: u32 = 1;
/// Flag of the gradient term in [`LikelihoodParams::terms`].
pub const TERM_GRADIENT: u32 = 2;
/// Flag of the feature term in [`LikelihoodParams::terms`].
pub const TERM_FEATURE: u32 = 4;
/// Flag of the contrast term in [`LikelihoodParams::terms`] (needs a [`ContrastTable`] set
/// on the engine). Not in the default terms: it is the tracker's addition to the paper's
/// three ([`crate::tracker::Contrast`]).
pub const TERM_CONTRAST: u32 = 8;
/// Every term flag.
pub const TERM_ALL: u32 = TERM_COLOUR | TERM_GRADIENT | TERM_FEATURE | TERM_CONTRAST;

impl Default for LikelihoodParams {
    /// Starting values, reviewed against the spec's formulas for targets of about 40 px at
    /// 160x120 (about 80 px at 320x240) and measured on the real footage: every 5th frame of
    /// girl (128x96, head about 31x45 px) and car4 (360x240, grayscale, about 107x87 px),
    /// along 24 normal lines of the ground-truth box's inscribed ellipse
    /// (`cargo run --release --example edge_stats -- ../shared/data/girl`).
    ///
    /// - `edge_threshold` 0.05 (luma per pixel: half the luma step across a pixel pair, so a
    ///   step of 0.1 = 25 grey levels): 82 % (girl) / 87 % (car4) of the lines have an edge
    ///   within 4 px of the contour, against 70 % / 77 % at 0.08.
    ///   On the real footage a higher threshold tracks better. The weak edges of texture and
    ///   compression that 0.05 keeps (clutter on girl 0.080 edges per sample, 0.028 at 0.1)
    ///   let a wrong ellipse score like the contour: the term ranks the truth above a wrong
    ///   ellipse (moved by a quarter or half of its semi-axes, or scaled by 0.6 to 1.5, each
    ///   threshold with its own measured p0, γ and σz) in 84 % of the cases on girl at 0.05
    ///   and 89-90 % at 0.1 and 0.12 (car4: 79-82 % at every threshold from 0.03 to 0.15; the
    ///   car's outline is a box, which no ellipse fits well). With `--edge-threshold 0.1` the
    ///   success AUC over seeds 0-11 goes from 0.38 to 0.53 on girl and from 0.18 to 0.25 on
    ///   car4 (car4 measured with the RGB colour bins, before the tracker's luma bins for
    ///   grayscale footage, `TrackerConfig::grey_luma`, raised its default to 0.22). It is not the default because it costs where outlines are clean but faint in
    ///   places, and under dimmer light, whose edges an absolute threshold loses: the
    ///   synthetic scenarios' angle RMSE summed over scenarios and axes rose from 73.4 to 89.3
    ///   degrees (seeds 0-5; `combo` the most, and at 0.12 it broke); a synthetic head on a
    ///   flat background strayed up to 2.8 px instead of 1.4 (`tests/tracker.rs`, the jump
    ///   test), and one dimmed to half its brightness was followed up to 4.0 px off instead
    ///   of 1.9, with a confidence of 0.53 instead of 0.83, its outline mostly below the
    ///   threshold. Weighing the nearest edge by its strength instead (nothing at 0.05, fully
    ///   from 0.1) made the same trade at a lower rate: girl 0.47, car4 0.22, and the synthetic
    ///   sum up by 15-18 % (seeds 0-11, filter seeds 0 and 1), so it was not kept. A threshold
    ///   relative to the frame's own contrast and clutter would be the way to have both; it
    ///   is not built yet.
    /// - `p_no_contour` 0.15: the measured share of lines with no edge within 4 px at that
    ///   threshold (18 % girl, 13 % car4).
    /// - `clutter_density` 0.1 edges per pixel: measured 0.080 (girl) and 0.137 (car4) edges
    ///   per sample besides the contour's.
    /// - `sigma_z` 2 px: the RMS distance of the nearest edge (within 4 px) is 1.9 px (girl)
    ///   and 1.7 px (car4), which includes the misfit of a box's inscribed ellipse to a real
    ///   contour. With these, `K = 1 / (sqrt(2π) σz p0 γ) = 13.3`: a line whose edge sits on
    ///   the contour scores `ln(1 + K) = 2.66`, at 2 px 2.2, at 4 px 1.0, without an edge 0.
    /// - `line_half_length` 8 px: 40 % of a 20 px semi-axis at 160x120 (20 % at 320x240),
    ///   more than the proposal's usual scale and position spread.
    /// - `num_lines` 24 (every 15°): contour points about 5 px apart on a 40 px target, 10 px
    ///   at 320x240, so neighbouring lines see mostly different edges (σz = 2 px).
    /// - `sigma_colour` 0.1: on girl, moving the truth ellipse 4 px drops ρ by 0.024
    ///   (median) and 10 px by about 0.1, that is 1.2 and 5 nats: colour stays comparable to
    ///   one or two normal lines instead of being drowned by the 24 of the gradient term.
    ///   (On grayscale car4 colour barely changes with position, as expected.)
    /// - `feature_eps` 1 px: about the localisation noise of a matched feature at these
    ///   sizes; an exact match counts 1, one off by 1 px counts 1/2.
    /// - `depth_ratio` 1.0: a human head (about 15 cm wide, 23 cm high, 19 cm deep) is as
    ///   deep as the geometric mean of its width and height (19 / sqrt(15 · 23) = 1.02). The
    ///   tracker also fits keyframe rotations with this prior (`pose::prior`), whose angles
    ///   scale inversely with it: at 0.7 the synthetic head's tilts came out about 1.4 times
    ///   too large. A flat target such as a car's rear would want less.
    fn default() -> Self {
        Self {
            sigma_colour: 0.1,
            sigma_z: 2.0,
            clutter_density: 0.1,
            p_no_contour: 0.15,
            edge_threshold: 0.05,
            line_half_length: 8.0,
            feature_eps: 1.0,
            depth_ratio: 1.0,
            num_lines: 24,
            terms: TERM_COLOUR | TERM_GRADIENT | TERM_FEATURE,
            colour_bins: COLOUR_RGB,
            contrast_scale: 0.0,
        }
    }
}

/// Errors of the likelihood engines.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LikelihoodError {
    /// The engine has no colour model yet.
    #[error("no colour model set")]
    NoModel,
    /// The contrast term is enabled but the engine has no contrast table.
    #[error("no contrast table set")]
    NoContrastTable,
    /// Invalid input to an engine: parameters, frame data, colour model or thread count.
    #[error("invalid likelihood input: {0}")]
    Invalid(String),
    /// No Vulkan adapter: the driver (or the loader) is missing.
    #[error(
        "no Vulkan adapter found (install a Vulkan driver, e.g. `apt-get install mesa-vulkan-drivers libvulkan1`, or use the CPU engine, Backend::Cpu)"
    )]
    NoAdapter,
    /// The best Vulkan adapter renders in software on the CPU (e.g. Mesa's lavapipe), so the
    /// automatic choice leaves it for the CPU engine, which is faster.
    #[error(
        "the best Vulkan adapter here, {name}, renders in software, slower than the CPU engine (Backend::Gpu or PFTRACK_ADAPTER uses it)"
    )]
    SoftwareAdapter {
        /// The adapter's description.
        name: String,
    },
    /// The adapter asked for (by `PFTRACK_ADAPTER` or [`create_engine_for`]) is not there.
    #[error(
        "no Vulkan adapter's name contains {wanted:?} (PFTRACK_ADAPTER or the adapter asked for); available: {}",
        adapter_list(available)
    )]
    AdapterNotFound {
        /// The substring asked for.
        wanted: String,
        /// The adapters there are.
        available: Vec<String>,
    },
    /// The GPU device was lost (driver reset, device destroyed); the engine is unusable.
    #[error("GPU device lost ({0}); rerun on the CPU engine (Backend::Cpu)")]
    DeviceLost(String),
    /// The frame does not fit the adapter's buffer limits.
    #[error(
        "frame {width}x{height} needs a {bytes}-byte GPU buffer, beyond the adapter's limit of {limit} bytes (use the CPU engine, Backend::Cpu, or a smaller frame)"
    )]
    FrameTooLarge {
        /// Frame width.
        width: u32,
        /// Frame height.
        height: u32,
        /// Bytes of the largest per-frame buffer.
        bytes: u64,
        /// The adapter's limit.
        limit: u64,
    },
    /// More particles (or particle × line pairs) than the adapter's buffers hold.
    #[error(
        "{n} particles need a {bytes}-byte GPU buffer, beyond the adapter's limit of {limit} bytes (use the CPU engine, Backend::Cpu, or fewer particles)"
    )]
    TooManyParticles {
        /// Number of particles.
        n: usize,
        /// Bytes of the largest per-particle buffer.
        bytes: u64,
        /// The adapter's limit.
        limit: u64,
    },
    /// More matched features than the adapter's buffers hold (only on a device opened with
    /// small limits: the default 128 MiB binding holds millions).
    #[error(
        "{n} matched features need a {bytes}-byte GPU buffer, beyond the adapter's limit of {limit} bytes (use the CPU engine, Backend::Cpu, or fewer features)"
    )]
    TooManyFeatures {
        /// Number of matched features.
        n: usize,
        /// Bytes of the features' buffer.
        bytes: u64,
        /// The adapter's limit.
        limit: u64,
    },
    /// Any other GPU failure (device request, validation, mapping).
    #[error("GPU error: {0}")]
    Gpu(String),
}

/// Which likelihood engine to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Backend {
    /// The GPU when a hardware Vulkan adapter exists (or `PFTRACK_ADAPTER` names one), else
    /// the CPU (with a one-line notice): a software adapter such as lavapipe is slower than the
    /// CPU engine.
    #[default]
    Auto,
    /// The CPU reference engine.
    Cpu,
    /// The GPU engine on the best or the named adapter, software ones too; an error when
    /// there is no Vulkan adapter.
    Gpu,
}

impl std::str::FromStr for Backend {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(Backend::Auto),
            "cpu" => Ok(Backend::Cpu),
            "gpu" => Ok(Backend::Gpu),
            other => Err(format!(
                "unknown backend {other:?} (expected auto, cpu or gpu)"
            )),
        }
    }
}

impl std::fmt::Display for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Backend::Auto => "auto",
            Backend::Cpu => "cpu",
            Backend::Gpu => "gpu",
        })
    }
}

/// The likelihood engine for `backend`, with a one-line notice when `Auto` fell back to the CPU.
///
/// `Auto` opens the GPU engine when a hardware Vulkan adapter exists (or the one
/// `PFTRACK_ADAPTER` names, by a substring of its name, whatever it is) and otherwise returns
/// the CPU engine with a notice saying why: no adapter, or only a software one such as Mesa's
/// lavapipe, which trails the CPU engine ([`LikelihoodError::SoftwareAdapter`]). `Gpu` opens
/// the best or the named adapter, software ones too, and fails when there is none
/// ([`LikelihoodError::NoAdapter`], naming the package to install); `Cpu` is the CPU engine on
/// all threads. The GPU engine comes wrapped in a [`FallbackEngine`]: when its
/// device is lost mid-run it continues on the CPU for the rest of the run and hands the caller
/// a one-line notice through [`LikelihoodEngine::take_notice`] (which the caller should print).
///
/// On a machine without a display, Mesa's Vulkan device-select layer prints
/// "error: XDG_RUNTIME_DIR is invalid or not set" to standard error for every Vulkan instance,
/// which reads as the program's own error. The `pftrack` command line sets `NODEVICE_SELECT=1`
/// first thing in `main`, before any thread exists, which turns the layer off (pftrack picks its
/// adapter itself); a program embedding the library may do the same.
pub fn create_engine(
    backend: Backend,
) -> Result<(Box<dyn LikelihoodEngine + Send>, Option<String>), LikelihoodError> {
    create_engine_for(backend, gpu::named_adapter().as_deref())
}

/// The adapters of an [`LikelihoodError::AdapterNotFound`], or what their absence means.
fn adapter_list(available: &[String]) -> String {
    if available.is_empty() {
        "none (no Vulkan driver is installed)".to_string()
    } else {
        available.join("; ")
    }
}

/// [`create_engine`] with the adapter named by `adapter` (a substring of its name, or `None`
/// for the best one) instead of `PFTRACK_ADAPTER`: for a program that chooses the adapter
/// itself.
pub fn create_engine_for(
    backend: Backend,
    adapter: Option<&str>,
) -> Result<(Box<dyn LikelihoodEngine + Send>, Option<String>), LikelihoodError> {
    let gpu_engine = |device: gpu::GpuDevice| -> Result<Box<dyn LikelihoodEngine + Send>, _> {
        Ok(Box::new(FallbackEngine::new(Box::new(
            gpu::GpuEngine::with_device(device)?,
        ))))
    };
    match backend {
        Backend::Cpu => Ok((Box::new(cpu::CpuEngine::new()), None)),
        Backend::Gpu => Ok((gpu_engine(gpu::GpuDevice::open_matching(adapter)?)?, None)),
        Backend::Auto => match gpu::GpuDevice::open_hardware(adapter).and_then(gpu_engine) {
            Ok(e) => Ok((e, None)),
            // A named adapter that does not exist is the user's mistake: report it.
            Err(e @ LikelihoodError::AdapterNotFound { .. }) => Err(e),
            // Without an adapter the note says what to install, not to use the CPU engine,
            // which it is already on.
            Err(LikelihoodError::NoAdapter) => Ok((
                Box::new(cpu::CpuEngine::new()),
                Some(
                    "note: likelihood on the CPU: no Vulkan adapter found (a GPU engine needs \
                     a Vulkan driver, e.g. `apt-get install mesa-vulkan-drivers libvulkan1`)"
                        .to_string(),
                ),
            )),
            Err(e) => Ok((
                Box::new(cpu::CpuEngine::new()),
                Some(format!("note: likelihood on the CPU ({e})")),
            )),
        },
    }
}

/// An engine that evaluates all particles' likelihoods for a frame.
pub trait LikelihoodEngine {
    /// A short human-readable name (for the GPU, the adapter's).
    fn name(&self) -> String;

    /// Sets the colour model (from the initial frame).
    fn set_colour_model(&mut self, model: &ColourHistogram) -> Result<(), LikelihoodError>;

    /// Sets the table of the contrast term ([`TERM_CONTRAST`]).
    fn set_contrast_table(&mut self, table: &ContrastTable) -> Result<(), LikelihoodError>;

    /// Evaluates every particle on one frame; `out` is resized to `particles.len()`.
    fn evaluate(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
    ) -> Result<(), LikelihoodError>;

    /// [`Self::evaluate`] on any number of particles: in batches of the most the engine's
    /// buffers hold ([`Self::check_capacity`]: all at once on the CPU), the results in
    /// order. The same results as one call where one call fits, each particle's terms being
    /// its own. For a caller whose particle count has no bound, such as a search over a frame.
    fn evaluate_batched(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
    ) -> Result<(), LikelihoodError> {
        let (w, h) = frame.image.dimensions();
        let mut batch = particles.len().max(1);
        loop {
            match self.check_capacity(batch, w, h, params) {
                Ok(()) => break,
                Err(LikelihoodError::TooManyParticles { .. }) if batch > 1 => {
                    batch = batch.div_ceil(2);
                }
                Err(e) => return Err(e),
            }
        }
        if batch >= particles.len() {
            return self.evaluate(frame, params, particles, out);
        }
        out.clear();
        out.reserve(particles.len());
        let mut part = Vec::with_capacity(batch);
        for chunk in particles.chunks(batch) {
            self.evaluate(frame, params, chunk, &mut part)?;
            out.extend_from_slice(&part);
        }
        Ok(())
    }

    /// A one-line notice the engine wants shown to the user since the last call (e.g. that it
    /// switched from a lost GPU to the CPU), taken once. None by default.
    fn take_notice(&mut self) -> Option<String> {
        None
    }

    /// Whether [`Self::evaluate`] does its work on the rayon pool it is called in (the CPU
    /// engine on the global pool), rather than somewhere the caller waits for: a GPU, or a pool
    /// of the engine's own. A tracker keeps a thread of its pool awake for the step's forks
    /// ([`crate::tracker::Tracker::step`]) and lets it rest during an evaluation that does not
    /// run there, where it would only take a core from the work (a software Vulkan driver's
    /// threads). False by default. An engine that answers false must not hand work to the
    /// calling pool and block until it is done (`rayon::spawn`, then a channel's `recv`): with
    /// the helper resting, a pool of two threads then has none left to run it.
    fn runs_on_calling_pool(&self) -> bool {
        false
    }

    /// Whether the engine can evaluate `particles` particles on `width x height` frames with
    /// `params`, checked before anything is allocated: the error its
    /// [`LikelihoodEngine::evaluate`] would give on the first frame, for an engine whose
    /// buffers are bounded (the GPU's, [`LikelihoodError::TooManyParticles`] and
    /// [`LikelihoodError::FrameTooLarge`]). Always `Ok` by default.
    fn check_capacity(
        &self,
        particles: usize,
        width: u32,
        height: u32,
        params: &LikelihoodParams,
    ) -> Result<(), LikelihoodError> {
        let _ = (particles, width, height, params);
        Ok(())
    }
}

/// The log-likelihood given to a degenerate particle (non-positive semi-axes or a non-finite
/// component), by every engine: finite, so weights stay well defined, and far below any real
/// particle's.
pub const DEGENERATE: f32 = -1e30;

#[cfg(test)]
mod backend_tests {
    use super::*;

    #[test]
    fn feature_pairs_split_into_their_two_position_lists() {
        let pairs = [
            FeaturePair {
                p: [1.5, 2.0],
                q: [3.0, -4.25],
            },
            FeaturePair {
                p: [0.1, 0.0],
                q: [7.0, 8.0],
            },
        ];
        let (p, q) = FeaturePair::split(&pairs);
        assert_eq!(p, vec![[1.5, 2.0], [0.1f32 as f64, 0.0]]);
        assert_eq!(q, vec![[3.0, -4.25], [7.0, 8.0]]);
        assert_eq!(FeaturePair::split(&[]), (vec![], vec![]));
    }

    #[test]
    fn backend_parses_case_insensitively_and_rejects_others() {
        assert_eq!("auto".parse::<Backend>(), Ok(Backend::Auto));
        assert_eq!("CPU".parse::<Backend>(), Ok(Backend::Cpu));
        assert_eq!("Gpu".parse::<Backend>(), Ok(Backend::Gpu));
        assert!("vulkan".parse::<Backend>().is_err());
        for b in [Backend::Auto, Backend::Cpu, Backend::Gpu] {
            assert_eq!(b.to_string().parse::<Backend>(), Ok(b));
        }
    }

    #[test]
    fn cpu_backend_gives_the_cpu_engine_without_notice() {
        let (e, notice) = create_engine(Backend::Cpu).unwrap();
        assert!(e.name().starts_with("cpu"));
        assert!(notice.is_none());
    }

    #[test]
    fn no_adapter_error_names_the_fix() {
        let msg = LikelihoodError::NoAdapter.to_string();
        assert!(
            msg.contains("apt-get install mesa-vulkan-drivers libvulkan1"),
            "{msg}"
        );
    }
}
