//! CPU reference implementation of every likelihood stage, the reference the GPU engine is
//! checked against and what the tracker runs without a GPU.
//!
//! One file per stage, each the twin of the WGSL shader of the same name in `shaders/`:
//! [`colour`] (which also holds the contrast term: it reads the same histogram), [`gradient`],
//! [`feature`], [`combine`]. The exact semantics (shared with the
//! GPU) are in `prompts/likelihood-spec.md` and in each file's documentation.
//!
//! [`CpuEngine`] evaluates all particles of a frame: it prepares the per-frame data once per
//! [`LikelihoodEngine::evaluate`] call (histogram bins of every pixel, the integer gradient
//! image, the lifted features; nothing is cached between calls, so evaluating the same frame
//! twice recomputes them, which costs little next to the particles), then evaluates the
//! particles in parallel with rayon. Each particle's result depends only on its own inputs,
//! so the output is bit for bit the same for any number of threads.

pub mod colour;
pub mod combine;
pub mod feature;
pub mod gradient;

use rayon::prelude::*;

use super::{
    COLOUR_LUMA, ColourHistogram, ContrastTable, FrameInput, HIST_BINS, LikelihoodEngine,
    LikelihoodError, LikelihoodParams, Particle, TERM_COLOUR, TERM_CONTRAST, TERM_FEATURE,
    TERM_GRADIENT, TermLogs,
};
use crate::geometry::Ellipse;

/// An ellipse in `f32`, as the likelihood stages see a particle: `theta = theta0 + rz`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EllipseF32 {
    /// Centre x.
    pub cx: f32,
    /// Centre y.
    pub cy: f32,
    /// Semi-axis a.
    pub a: f32,
    /// Semi-axis b.
    pub b: f32,
    /// Orientation (radians).
    pub theta: f32,
}

impl EllipseF32 {
    /// The ellipse of a particle: `theta = theta0 + rz` in `f32`.
    pub fn from_particle(p: &Particle, theta0: f32) -> Self {
        Self {
            cx: p.cx,
            cy: p.cy,
            a: p.a,
            b: p.b,
            theta: theta0 + p.rz,
        }
    }

    /// An `f64` ellipse rounded to `f32`.
    pub fn from_ellipse(e: &Ellipse) -> Self {
        Self {
            cx: e.cx as f32,
            cy: e.cy as f32,
            a: e.a as f32,
            b: e.b as f32,
            theta: e.theta as f32,
        }
    }

    /// Finite parameters and positive semi-axes.
    pub fn is_valid(&self) -> bool {
        [self.cx, self.cy, self.a, self.b, self.theta]
            .iter()
            .all(|v| v.is_finite())
            && self.a > 0.0
            && self.b > 0.0
    }
}

/// Whether a particle is degenerate (`a <= 0`, `b <= 0` or a non-finite component among
/// `cx, cy, a, b, rx, ry, rz`): it gets [`combine::DEGENERATE_LOGS`].
pub fn is_degenerate(p: &Particle) -> bool {
    let finite = [p.cx, p.cy, p.a, p.b, p.rx, p.ry, p.rz]
        .iter()
        .all(|v| v.is_finite());
    !(finite && p.a > 0.0 && p.b > 0.0)
}

impl ColourHistogram {
    /// The normalised colour model of the pixels of `image` inside `ellipse` (the same pixel
    /// set as a particle's histogram, [`colour`]), binned under `colour_bins`
    /// ([`LikelihoodParams::colour_bins`], which the engines must then be given):
    /// `q_k = count_k / total` in `f32`.
    ///
    /// Errors when the ellipse is degenerate or holds no pixel of the frame, or `colour_bins`
    /// is unknown.
    pub fn from_ellipse(
        image: &image::RgbImage,
        ellipse: &Ellipse,
        colour_bins: u32,
    ) -> Result<Self, LikelihoodError> {
        if colour_bins > COLOUR_LUMA {
            return Err(LikelihoodError::Invalid(format!(
                "unknown colour_bins {colour_bins}"
            )));
        }
        let e = EllipseF32::from_ellipse(ellipse);
        if !e.is_valid() {
            return Err(LikelihoodError::Invalid(format!(
                "colour model ellipse is degenerate: {ellipse:?}"
            )));
        }
        let (counts, total) = colour::histogram(image, &e, colour_bins);
        if total == 0 {
            return Err(LikelihoodError::Invalid(format!(
                "colour model ellipse holds no pixel of the {}x{} frame: {ellipse:?}",
                image.width(),
                image.height()
            )));
        }
        Ok(Self(colour::normalise(&counts, total)))
    }

    /// Moves the model a share `rate` of the way towards `other`: `q ← (1 − rate) q + rate p`
    /// (the adaptive colour model of Nummiaro, Koller-Meier and Van Gool, 2003). Both are
    /// normalised, so the result is too; `rate` is clamped to `[0, 1]`.
    pub fn blend_towards(&mut self, other: &ColourHistogram, rate: f32) {
        let r = rate.clamp(0.0, 1.0);
        for (q, p) in self.0.iter_mut().zip(&other.0) {
            *q = (1.0 - r) * *q + r * p;
        }
    }

    /// The Bhattacharyya coefficient `Σ sqrt(p_k q_k)` of two normalised histograms under the
    /// same binning: 1 for equal ones, 0 for ones with no bin in common.
    pub fn similarity(&self, other: &ColourHistogram) -> f64 {
        self.0
            .iter()
            .zip(&other.0)
            .map(|(&p, &q)| (f64::from(p.max(0.0)) * f64::from(q.max(0.0))).sqrt())
            .sum()
    }
}

/// How an engine runs its parallel loops.
#[derive(Debug)]
enum Exec {
    /// rayon's global pool (all threads).
    Global,
    /// The engine's own pool.
    Pool(rayon::ThreadPool),
    /// The calling thread only, no rayon.
    Single,
}

/// The CPU likelihood engine (rayon).
#[derive(Debug)]
pub struct CpuEngine {
    exec: Exec,
    model: Option<colour::Model>,
    contrast: Option<Vec<f32>>,
    bins: colour::BinImage,
    grad: gradient::GradientImage,
    luma: Vec<u32>,
}

impl Default for CpuEngine {
    fn default() -> Self {
        Self::new()
    }
}

/// Most threads [`CpuEngine::with_threads`] starts: a million were still being started after
/// two minutes.
pub const MAX_THREADS: usize = 1024;

impl CpuEngine {
    /// An engine on rayon's global pool (all threads).
    pub fn new() -> Self {
        Self::with_exec(Exec::Global)
    }

    /// An engine on its own pool of `threads` threads; `1` runs on the calling thread alone.
    /// Errors when `threads` is 0 or more than [`MAX_THREADS`], or the pool cannot be
    /// created. This bounds the likelihood pass only: a tracker's other parts (SIFT, block
    /// matching, the template terms) run on the pool its step is called in
    /// ([`crate::tracker::Tracker::step`] says how to bound them all).
    pub fn with_threads(threads: usize) -> Result<Self, LikelihoodError> {
        match threads {
            0 => Err(LikelihoodError::Invalid(
                "the CPU engine needs at least one thread".into(),
            )),
            n if n > MAX_THREADS => Err(LikelihoodError::Invalid(format!(
                "{n} threads for the CPU engine: at most {MAX_THREADS}"
            ))),
            1 => Ok(Self::with_exec(Exec::Single)),
            n => rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map(|p| Self::with_exec(Exec::Pool(p)))
                .map_err(|e| LikelihoodError::Invalid(format!("cannot start {n} threads: {e}"))),
        }
    }

    fn with_exec(exec: Exec) -> Self {
        Self {
            exec,
            model: None,
            contrast: None,
            bins: Default::default(),
            grad: Default::default(),
            luma: Vec::new(),
        }
    }

    /// Number of threads the engine uses.
    pub fn threads(&self) -> usize {
        match &self.exec {
            Exec::Global => rayon::current_num_threads(),
            Exec::Pool(p) => p.current_num_threads(),
            Exec::Single => 1,
        }
    }

    fn evaluate_inner(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
        parallel: bool,
    ) -> Result<(), LikelihoodError> {
        let use_colour = params.terms & TERM_COLOUR != 0;
        let use_gradient = params.terms & TERM_GRADIENT != 0;
        let use_feature = params.terms & TERM_FEATURE != 0 && !frame.features.is_empty();
        let use_contrast = params.terms & TERM_CONTRAST != 0;
        let model = match (&self.model, use_colour) {
            (Some(m), true) => Some(m),
            (None, true) => return Err(LikelihoodError::NoModel),
            _ => None,
        };
        let table = match (&self.contrast, use_contrast) {
            (Some(t), true) => Some(t.as_slice()),
            (None, true) => return Err(LikelihoodError::NoContrastTable),
            _ => None,
        };
        if use_colour || use_contrast {
            self.bins.fill(frame.image, params.colour_bins);
        }
        if use_gradient {
            self.grad.fill(frame.image, &mut self.luma, parallel);
        }
        let feats = use_feature.then(|| {
            feature::FeatureFrame::new(
                frame.features,
                frame.depths,
                &frame.prev,
                frame.theta0,
                params,
            )
        });
        let lines = use_gradient.then(|| gradient::LineTables::new(params));
        let (bins, grad) = (&self.bins, &self.grad);
        let theta0 = frame.theta0;

        let one = |p: &Particle| -> TermLogs {
            if is_degenerate(p) {
                return combine::DEGENERATE_LOGS;
            }
            let e = EllipseF32::from_particle(p, theta0);
            let (mut c, mut k) = (0.0, 0.0);
            if model.is_some() || table.is_some() {
                // One histogram serves both terms.
                let mut counts = [0u32; HIST_BINS];
                let total = colour::histogram_bins(bins, &e, &mut counts);
                if let Some(m) = model {
                    c = colour::log_from_rho(
                        colour::bhattacharyya(&counts, total, m),
                        params.sigma_colour,
                    );
                }
                if let Some(t) = table {
                    k = params.contrast_scale * colour::contrast_sum(&counts, t);
                }
            }
            let g = match &lines {
                Some(lt) => gradient::log_likelihood_ellipse(grad, &e, lt, params),
                None => 0.0,
            };
            let f = match &feats {
                Some(ff) => ff.log_likelihood(p, params.feature_eps),
                None => 0.0,
            };
            combine::combine([c, g, f, k], params)
        };

        out.clear();
        out.resize(particles.len(), TermLogs::default());
        if parallel {
            out.par_iter_mut()
                .zip(particles.par_iter())
                .with_min_len(8)
                .for_each(|(o, p)| *o = one(p));
        } else {
            out.iter_mut().zip(particles).for_each(|(o, p)| *o = one(p));
        }
        Ok(())
    }
}

/// Checks what a frame's evaluation depends on besides the particles: the settings
/// ([`LikelihoodParams::check`]) and the frame's own inputs.
pub fn validate(frame: &FrameInput<'_>, params: &LikelihoodParams) -> Result<(), LikelihoodError> {
    let bad = |what: &str| Err(LikelihoodError::Invalid(what.to_string()));
    params.check()?;
    if !frame.theta0.is_finite() {
        return bad("theta0 is not finite");
    }
    let (w, h) = frame.image.dimensions();
    if w == 0 || h == 0 {
        return bad("the frame has no pixels");
    }
    if params.terms & TERM_FEATURE != 0 && !frame.features.is_empty() {
        if is_degenerate(&frame.prev) {
            return bad("the previous estimate is degenerate");
        }
        // Its area scales every particle's lift, and its depth lifts the features: an area
        // that underflows (semi-axes of 1e-23) or overflows (1e20) scored every particle,
        // the perfect one too, as degenerate.
        let (a, b) = (frame.prev.a, frame.prev.b);
        if !((a * b).is_normal() && ((a * b).sqrt() * params.depth_ratio).is_finite()) {
            return bad("the previous estimate's area a b is too small or too large for f32");
        }
        if frame
            .features
            .iter()
            .any(|f| !(f.p.iter().chain(&f.q).all(|v| v.is_finite())))
        {
            return bad("a feature position is not finite");
        }
        if let Some(d) = frame.depths {
            if d.len() != frame.features.len() {
                return Err(LikelihoodError::Invalid(format!(
                    "{} feature depths for {} features",
                    d.len(),
                    frame.features.len()
                )));
            }
            if !d.iter().all(|z| z.is_finite()) {
                return bad("a feature depth is not finite");
            }
        }
    }
    Ok(())
}

impl LikelihoodEngine for CpuEngine {
    /// On the global pool (from [`CpuEngine::new`]) the engine works on the pool it is called
    /// in; on a pool of its own or the calling thread alone it does not.
    fn runs_on_calling_pool(&self) -> bool {
        matches!(self.exec, Exec::Global)
    }

    fn name(&self) -> String {
        match self.threads() {
            1 => "cpu (1 thread)".to_string(),
            n => format!("cpu ({n} threads)"),
        }
    }

    fn set_colour_model(&mut self, model: &ColourHistogram) -> Result<(), LikelihoodError> {
        self.model = Some(colour::Model::checked(&model.0)?);
        Ok(())
    }

    fn set_contrast_table(&mut self, table: &ContrastTable) -> Result<(), LikelihoodError> {
        table.check()?;
        self.contrast = Some(table.0.clone());
        Ok(())
    }

    fn evaluate(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
    ) -> Result<(), LikelihoodError> {
        validate(frame, params)?;
        match std::mem::replace(&mut self.exec, Exec::Single) {
            Exec::Single => self.evaluate_inner(frame, params, particles, out, false),
            Exec::Global => {
                self.exec = Exec::Global;
                self.evaluate_inner(frame, params, particles, out, true)
            }
            Exec::Pool(pool) => {
                let r = pool.install(|| self.evaluate_inner(frame, params, particles, out, true));
                self.exec = Exec::Pool(pool);
                r
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_engine_on_the_global_pool_works_on_the_calling_pool() {
        assert!(CpuEngine::new().runs_on_calling_pool());
        // One thread: the calling thread alone; two: a pool of the engine's own.
        for n in [1, 2] {
            let e = CpuEngine::with_threads(n).expect("an engine");
            assert!(!e.runs_on_calling_pool(), "with_threads({n})");
        }
    }

    fn hist(pairs: &[(usize, f32)]) -> ColourHistogram {
        let mut q = vec![0.0; crate::likelihood::HIST_BINS];
        for &(k, v) in pairs {
            q[k] = v;
        }
        ColourHistogram(q)
    }

    #[test]
    fn blending_moves_the_model_by_the_rate_and_keeps_it_normalised() {
        let other = hist(&[(3, 0.5), (7, 0.5)]);
        let mut q = hist(&[(0, 1.0)]);
        q.blend_towards(&other, 0.1);
        assert!((q.0[0] - 0.9).abs() < 1e-6);
        assert!((q.0[3] - 0.05).abs() < 1e-6);
        assert!((q.0[7] - 0.05).abs() < 1e-6);
        assert!((q.0.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert!(colour::Model::checked(&q.0).is_ok());
        // Rate 0 keeps the model, rate 1 (or more, clamped) replaces it.
        let before = q.clone();
        q.blend_towards(&other, 0.0);
        assert_eq!(q, before);
        q.blend_towards(&other, 2.0);
        assert_eq!(q, other);
    }

    #[test]
    fn similarity_is_the_bhattacharyya_coefficient() {
        let a = hist(&[(0, 0.25), (1, 0.75)]);
        let b = hist(&[(1, 0.25), (2, 0.75)]);
        let c = hist(&[(5, 1.0)]);
        assert!((a.similarity(&a) - 1.0).abs() < 1e-6);
        // Only bin 1 is shared: sqrt(0.75 * 0.25).
        assert!((a.similarity(&b) - (0.75f64 * 0.25).sqrt()).abs() < 1e-6);
        assert_eq!(a.similarity(&b), b.similarity(&a));
        assert_eq!(a.similarity(&c), 0.0);
    }
}
