//! SIFT (Lowe 2004) on the CPU: Gaussian scale space, DoG extrema with sub-pixel/scale
//! refinement, contrast and edge rejection, orientation histograms and 128-d descriptors.
//!
//! # Choices
//! - The defaults follow Lowe's paper and OpenCV's `SIFT_create()` (3 layers per octave,
//!   σ = 1.6, contrast threshold 0.04 / 3 on `[0, 1]` images, edge ratio r = 10, an upsampled
//!   first octave assuming the input is blurred by σ = 0.5), so results can be compared with
//!   OpenCV keypoint by keypoint.
//! - **Upsampled first octave, on by default.** At tracker sizes (160x120, a head of 40x40
//!   pixels) most usable structure lives at σ ≈ 1–3 input pixels; without the doubled octave
//!   the smallest detectable scale is 1.6 · 2^(1/3) px and about 3x fewer keypoints are found
//!   on such a head. The extra octave costs ~4x the pixels of the first regular octave; the
//!   tracker restricts detection to the target's region (see [`Sift::detect`]) to pay for it.
//! - The doubled image is aligned exactly with the input's pixel grid: pixel `2x` of the
//!   doubled image *is* input pixel `x` and odd pixels are averages of their neighbours, so a
//!   coordinate `u` in the doubled image is `u / 2` in the input (OpenCV's bilinear resize
//!   has a quarter-pixel shift there that it does not undo). [`UpsampleGrid::OpenCv`]
//!   reproduces OpenCV's default for keypoint-by-keypoint comparisons.
//! - Coordinates follow the SPEC: origin at the centre of the top-left pixel, x right, y down.
//!   `angle` is the dominant gradient direction in radians in `[0, 2π)`, measured from +x
//!   towards +y (clockwise on screen), which is numerically OpenCV's `kp.angle` in degrees.
//!   `scale` is the keypoint's σ in input pixels (OpenCV's `kp.size` is the diameter, 2σ).
//! - Descriptors are 4x4 spatial cells x 8 orientations, trilinear interpolation, a Gaussian
//!   window of half the descriptor width, sampled relative to the sub-pixel keypoint
//!   position, normalised, clamped at 0.2, renormalised and stored as `u8` scaled by 512
//!   (as OpenCV does), so matching runs on exact integer distances.
//! - Blurs are separable with precomputed kernels (radius ⌈4σ⌉-ish, like OpenCV's float
//!   path) and reflect-101 borders; each scale is blurred incrementally from the previous
//!   one; the next octave starts from the scale 2σ of the previous octave, decimated by 2.
//! - Speed: blurs keep blocks of 32 outputs in registers across all taps, extrema are found
//!   a row at a time with branch-free 3x3x3 max/min tests (nothing written but the row's
//!   flags), descriptor samples are limited analytically to the rotated cell grid and
//!   computed a row at a time in one branch-free pass over whole vectors, each sample's 8
//!   shares then added to the histogram as one block (hot loops avoid saturating
//!   float-to-int casts, which block vectorisation), the hot loops are compiled a second time
//!   for AVX2 and picked at run time (bit-identical results: Rust never fuses multiply-adds
//!   on its own), and pyramid buffers come from a per-thread pool so a tracker calling
//!   [`Sift::detect`] every frame reuses them. Restrict detection to the target's region to
//!   pay only for it. The work is spread over rayon's current pool (in the tracker, the
//!   second core joins in once block matching beside SIFT is done): the blurs and the
//!   extremum search of images of 8192 pixels or more by bands of rows (the blurs of one
//!   octave still follow each other), the orientations and descriptors of 16 or more
//!   extrema one extremum at a time. Every pixel and keypoint is computed the same way and
//!   the parts are joined in order, so the output is the same on any number of threads. Run
//!   inside a one-thread pool for a single-threaded detector.

use std::f32::consts::{PI, TAU};

use super::{FeatureError, Features, Keypoint};
use crate::frames::GrayF32;
use crate::geometry::BoxRect;

/// Pixels at the border of each octave where no extremum is searched (as OpenCV).
const IMG_BORDER: usize = 5;
/// Maximum number of refinement steps of an extremum.
const MAX_INTERP_STEPS: usize = 5;
/// Orientation histogram bins.
const ORI_BINS: usize = 36;
/// Orientation window: Gaussian σ as a multiple of the keypoint's σ.
const ORI_SIG_FCTR: f32 = 1.5;
/// Orientation window radius as a multiple of the keypoint's σ.
const ORI_RADIUS: f32 = 3.0 * ORI_SIG_FCTR;
/// Secondary orientation peaks at least this fraction of the highest make extra keypoints.
const ORI_PEAK_RATIO: f32 = 0.8;
/// Descriptor spatial cells per side.
const DESCR_WIDTH: usize = 4;
/// Descriptor orientation bins.
const DESCR_BINS: usize = 8;
/// Width of one descriptor cell as a multiple of the keypoint's σ.
const DESCR_SCL_FCTR: f32 = 3.0;
/// Descriptor elements are clamped at this fraction of the norm.
const DESCR_MAG_THR: f32 = 0.2;
/// Scale of the `u8` descriptor.
const DESCR_INT_FCTR: f32 = 512.0;

/// Length of a descriptor.
pub const DESCRIPTOR_LEN: usize = DESCR_WIDTH * DESCR_WIDTH * DESCR_BINS;

/// How the doubled first octave ([`SiftParams::upsample`]) lies on the input's pixel grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpsampleGrid {
    /// Pixel `2x` of the doubled image is input pixel `x` and a keypoint at `u` in the doubled
    /// image is at `u / 2` in the input: positions are exact (the default).
    #[default]
    Exact,
    /// OpenCV's default (`SIFT_create()` with `enable_precise_upscale = false`): a bilinear
    /// resize with pixel centres at half-integers, so doubled pixel `u` samples the input at
    /// `u / 2 − 1/4`, while keypoints are still reported at `u / 2`, a quarter-pixel shift
    /// OpenCV does not undo. For reproducing OpenCV's keypoints, not for accuracy: on the
    /// project's comparison images this alone moves a fifth to a quarter of OpenCV's own
    /// keypoints by more than the 1.5 px / 1.5x agreement tolerance.
    OpenCv,
}

/// Parameters of [`Sift`]. The defaults are Lowe's and OpenCV's.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SiftParams {
    /// Scales per octave at which extrema are searched (Lowe's s = 3).
    pub n_octave_layers: usize,
    /// Contrast threshold for `[0, 1]` images; a refined extremum is kept when
    /// `|D| > contrast_threshold / n_octave_layers` (0.04).
    pub contrast_threshold: f32,
    /// Edge threshold r: an extremum is kept when `tr(H)² / det(H) < (r + 1)² / r` (10).
    pub edge_threshold: f32,
    /// σ of the first scale of each octave (1.6).
    pub sigma: f32,
    /// Start with the input doubled in size (Lowe's octave −1). Default on: see the module
    /// documentation.
    pub upsample: bool,
    /// How the doubled image lies on the input's pixel grid (exact by default).
    pub upsample_grid: UpsampleGrid,
    /// Blur already present in the input (0.5 pixels, as for a sharp camera image).
    pub input_sigma: f32,
    /// Cap on the number of octaves (`None`: as many as fit, OpenCV's rule).
    pub max_octaves: Option<usize>,
    /// Margin in input pixels added around a detection region (see [`Sift::detect`]) so
    /// blurs and descriptor windows see real image, not a border, near the region's edge.
    pub region_margin: f32,
    /// The most bytes the scale space of one detection may take
    /// ([`SiftParams::scale_space_bytes`]); a larger image or region is refused with
    /// [`FeatureError::TooLarge`] before anything is allocated, instead of failing to
    /// allocate. 2 GB by default: a 24-megapixel photo without the upsampled first octave
    /// (about 1.4 GB), not with it (about 5.6 GB).
    pub max_scale_space_bytes: u64,
}

impl SiftParams {
    /// The bytes of the scale space of a `w x h` detection window: the `2s + 5` Gaussian and
    /// difference images of `f32` per octave (s = [`SiftParams::n_octave_layers`]), the first
    /// octave twice the window's size when [`SiftParams::upsample`] is on, each later octave a
    /// quarter of the one before (4/3 of the first in all, counted as that). The input, the
    /// pool's spare room, the keypoints and the program come on top: measured peak resident
    /// memory of `pftrack sift` on a 2000x1500 image, 762 MB with the upsampled octave and 212
    /// MB without, against 704 and 176 MB here.
    pub fn scale_space_bytes(&self, w: usize, h: usize) -> u64 {
        let k = if self.upsample { 4 } else { 1 };
        let first = (w as u64).saturating_mul(h as u64).saturating_mul(k);
        // Saturating: the settings may be unchecked (`check_window` is public).
        let images = (self.n_octave_layers as u64)
            .saturating_mul(2)
            .saturating_add(5);
        first
            .saturating_mul(images.saturating_mul(4))
            .saturating_mul(4)
            .div_ceil(3)
    }

    /// [`FeatureError::TooLarge`] when the scale space of a `w x h` detection window (the
    /// whole image, or a region with its margin) would exceed
    /// [`SiftParams::max_scale_space_bytes`], as [`Sift::detect`] checks.
    pub fn check_window(&self, w: usize, h: usize) -> Result<(), FeatureError> {
        let bytes = self.scale_space_bytes(w, h);
        if bytes > self.max_scale_space_bytes {
            let plain = SiftParams {
                upsample: false,
                ..self.clone()
            };
            return Err(FeatureError::TooLarge {
                width: w,
                height: h,
                upsampled: self.upsample,
                bytes,
                limit: self.max_scale_space_bytes,
                fits_without_upsampling: self.upsample
                    && plain.scale_space_bytes(w, h) <= self.max_scale_space_bytes,
            });
        }
        Ok(())
    }

    /// Checks the settings, as [`Sift::detect`] does, naming the first one out of range:
    /// 1 to 16 layers per octave, a positive finite `sigma` and `edge_threshold`, a finite
    /// `contrast_threshold`, `input_sigma` and `region_margin` of at least 0, `sigma` and
    /// `input_sigma` at most [`MAX_SIGMA`], and at least one octave when `max_octaves` caps
    /// them.
    pub fn check(&self) -> Result<(), FeatureError> {
        let bad = |what: String| Err(FeatureError::BadParams(what));
        if !(1..=16).contains(&self.n_octave_layers) {
            return bad(format!(
                "n_octave_layers {} must lie in 1..=16",
                self.n_octave_layers
            ));
        }
        for (name, v, zero_ok) in [
            ("sigma", self.sigma, false),
            ("edge_threshold", self.edge_threshold, false),
            ("contrast_threshold", self.contrast_threshold, true),
            ("input_sigma", self.input_sigma, true),
            ("region_margin", self.region_margin, true),
        ] {
            let ok = v.is_finite() && (v > 0.0 || (zero_ok && v == 0.0));
            if !ok {
                let want = if zero_ok { "at least 0" } else { "positive" };
                return bad(format!("{name} {v} must be finite and {want}"));
            }
        }
        for (name, v) in [("sigma", self.sigma), ("input_sigma", self.input_sigma)] {
            if v > MAX_SIGMA {
                return bad(format!("{name} {v} is more than {MAX_SIGMA} pixels"));
            }
        }
        if self.max_octaves == Some(0) {
            return bad("max_octaves Some(0) leaves no octave (None: as many as fit)".into());
        }
        Ok(())
    }
}

/// Largest `sigma` and `input_sigma` [`SiftParams::check`] accepts (pixels): the blur
/// kernels grow with σ (8σ + 1 taps) and the first octave's blur with it; at 1e4 one 48x40
/// image took 37 s, at 1e9 the kernel alone wanted 24 GB. Lowe's is 1.6.
pub const MAX_SIGMA: f32 = 32.0;

impl Default for SiftParams {
    fn default() -> Self {
        Self {
            n_octave_layers: 3,
            contrast_threshold: 0.04,
            edge_threshold: 10.0,
            sigma: 1.6,
            upsample: true,
            upsample_grid: UpsampleGrid::Exact,
            input_sigma: 0.5,
            max_octaves: None,
            region_margin: 16.0,
            max_scale_space_bytes: 2_000_000_000,
        }
    }
}

/// A 1-D symmetric Gaussian kernel: `k[0]` is the centre, `k[i]` the weight at ±i.
#[derive(Debug, Clone)]
struct Kernel {
    half: Vec<f32>,
}

impl Kernel {
    /// Normalised Gaussian of the given σ with OpenCV's float-image size rule
    /// (`ksize = round(8σ + 1) | 1`).
    fn gaussian(sigma: f64) -> Self {
        let ksize = ((sigma * 8.0 + 1.0).round() as usize) | 1;
        let r = ksize / 2;
        let mut half: Vec<f64> = (0..=r)
            .map(|i| (-((i * i) as f64) / (2.0 * sigma * sigma)).exp())
            .collect();
        let sum: f64 = half[0] + 2.0 * half[1..].iter().sum::<f64>();
        for v in &mut half {
            *v /= sum;
        }
        Self {
            half: half.into_iter().map(|v| v as f32).collect(),
        }
    }

    fn radius(&self) -> usize {
        self.half.len() - 1
    }
}

/// A SIFT detector and descriptor extractor with precomputed blur kernels.
#[derive(Debug, Clone)]
pub struct Sift {
    params: SiftParams,
    /// Blur from the (possibly doubled) input to σ of the first scale.
    base_kernel: Kernel,
    /// `layer_kernels[i]` blurs scale `i - 1` to scale `i` (index 0 unused).
    layer_kernels: Vec<Kernel>,
}

/// One octave of the scale space.
struct Octave {
    w: usize,
    h: usize,
    /// `n + 3` Gaussian images.
    gauss: Vec<Vec<f32>>,
    /// `n + 2` differences of Gaussians.
    dog: Vec<Vec<f32>>,
}

thread_local! {
    /// Image buffers kept between calls on this thread, so a tracker calling
    /// [`Sift::detect`] every frame does not fault fresh pages in for its pyramid each time.
    static POOL: std::cell::RefCell<Vec<Vec<f32>>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Most buffers the pool keeps per thread (a pyramid uses about 11 per octave).
const POOL_MAX: usize = 160;

/// A buffer of `len` values from the thread's pool. Its contents are unspecified (stale
/// values from an earlier use): every caller overwrites all of it.
fn take_buf(len: usize) -> Vec<f32> {
    // Best fit: the smallest buffer that holds `len` without wasting more than about its
    // size (a huge buffer would be refilled to capacity on every recycle), else a new one.
    let mut v = POOL.with(|p| {
        let mut p = p.borrow_mut();
        let mut best: Option<(usize, usize)> = None;
        for (i, b) in p.iter().enumerate() {
            let cap = b.capacity();
            if cap >= len && cap <= 2 * len + 4096 && best.is_none_or(|(_, c)| cap < c) {
                best = Some((i, cap));
            }
        }
        best.map(|(i, _)| p.remove(i)).unwrap_or_default()
    });
    v.truncate(len);
    v.resize(len, 0.0);
    v
}

/// Returns a buffer to the thread's pool, at its full capacity so that taking it again for
/// any size up to that never needs to fill it. When the pool is full its oldest buffer makes
/// room, so the pool holds what the latest calls used: a detection returns all its buffers
/// at its end, and the next one (a tracker's next frame, usually of about the same region)
/// takes them again. (Keeping the smaller buffer instead, as it once did, let a pool filled
/// at one region size drop every larger buffer later: a tracker refilled about 5 MB of
/// fresh pages per 160x120 frame once its target had grown.)
fn recycle(mut v: Vec<f32>) {
    POOL.with(|p| {
        let mut p = p.borrow_mut();
        if p.len() >= POOL_MAX {
            p.remove(0);
        }
        v.resize(v.capacity(), 0.0);
        p.push(v);
    });
}

/// Makes a per-row scratch buffer at least `n` long. It never shrinks: rows of a keypoint's
/// window differ in length, and shrinking then growing again would zero-fill the regrown part
/// on every row (a tenth of a tracker's instructions went to that `memset`); every caller
/// overwrites the first `n` values before reading them.
fn grow<T: Copy + Default>(v: &mut Vec<T>, n: usize) {
    if v.len() < n {
        v.resize(n, T::default());
    }
}

/// Scratch buffers of the separable blur.
#[derive(Default)]
struct BlurScratch {
    tmp: Vec<f32>,
    row: Vec<f32>,
    /// Row offsets of the vertical pass.
    offs: Vec<(usize, usize)>,
    /// `row` and `offs` of each band when the blur is spread over threads.
    bands: Vec<BandScratch>,
}

/// A band's `row` and `offs` (see [`BlurScratch`]).
type BandScratch = (Vec<f32>, Vec<(usize, usize)>);

/// A refined extremum, in octave coordinates.
struct Extremum {
    /// Integer position and layer after refinement.
    r: usize,
    c: usize,
    layer: usize,
    /// Sub-pixel offsets.
    xr: f32,
    xc: f32,
    xi: f32,
    /// |D| at the refined position.
    response: f32,
}

impl Sift {
    /// A detector with the given parameters; precomputes the blur kernels.
    /// Settings [`SiftParams::check`] refuses build clamped kernels here and are refused by
    /// [`Sift::detect`].
    pub fn new(params: SiftParams) -> Self {
        let n = params.n_octave_layers.clamp(1, 16);
        let sigma = f64::from(params.sigma.clamp(0.01, MAX_SIGMA));
        let init = f64::from(params.input_sigma.clamp(0.0, MAX_SIGMA));
        let init = if params.upsample { 2.0 * init } else { init };
        let base_sigma = (sigma * sigma - init * init).max(0.01).sqrt();
        let k = 2f64.powf(1.0 / n as f64);
        let mut layer_kernels = vec![Kernel { half: vec![1.0] }];
        for i in 1..n + 3 {
            let prev = k.powi(i as i32 - 1) * sigma;
            let total = prev * k;
            layer_kernels.push(Kernel::gaussian((total * total - prev * prev).sqrt()));
        }
        Self {
            params,
            base_kernel: Kernel::gaussian(base_sigma),
            layer_kernels,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &SiftParams {
        &self.params
    }

    /// Frees the image buffers this thread keeps between [`Sift::detect`] calls (about the
    /// size of one scale-space pyramid: ~16 images the size of the doubled input).
    pub fn release_thread_buffers() {
        POOL.with(|p| p.borrow_mut().clear());
    }

    /// Detects keypoints and computes their descriptors.
    ///
    /// With `region`, only the region (grown by [`SiftParams::region_margin`], clipped to the
    /// image, its corner on a grid of the coarsest octave's stride, at least 8 pixels, so the
    /// octaves sample the same pixels as a full-image run) is processed, and only keypoints
    /// whose centre lies inside `region` are returned, in full-image coordinates. Keypoints
    /// whose windows reach past the margin see a reflected border there, so they can differ
    /// from the full-image run, or be missing from it: the context a keypoint needs grows with
    /// its scale (its extremum test stays 5 octave pixels from the window's edge, its
    /// descriptor reads about 10σ around it), and the blurs of the coarse octaves reflect at
    /// the window's edge tens of pixels in.
    ///
    /// Images too small for one octave give `Ok` with no keypoints, as does a region outside
    /// the image. Errors: pixel data that does not match the size, a pixel in the processed
    /// window that is not finite, a non-finite region or one with a negative size, invalid
    /// parameters.
    pub fn detect(&self, img: &GrayF32, region: Option<BoxRect>) -> Result<Features, FeatureError> {
        self.check_params()?;
        let (w, h) = (img.width as usize, img.height as usize);
        if img.data.len() != w * h {
            return Err(FeatureError::BadImage {
                width: img.width,
                height: img.height,
                len: img.data.len(),
            });
        }
        let mut out = Features::default();
        if w == 0 || h == 0 {
            return Ok(out);
        }
        let Some(region) = region else {
            self.params.check_window(w, h)?;
            finite_pixels(&img.data, w, [0, 0])?;
            self.detect_window(&img.data, w, h, [0, 0], None, &mut out);
            finish(&mut out);
            return Ok(out);
        };
        if ![region.x, region.y, region.w, region.h]
            .iter()
            .all(|v| v.is_finite())
            || region.w < 0.0
            || region.h < 0.0
        {
            return Err(FeatureError::BadRegion(format!(
                "{},{},{},{}",
                region.x, region.y, region.w, region.h
            )));
        }
        let Some([x0, y0, x1, y1]) = self.region_window(w, h, &region) else {
            return Ok(out);
        };
        let (cw, ch) = (x1 - x0, y1 - y0);
        self.params.check_window(cw, ch)?;
        let mut crop = Vec::with_capacity(cw * ch);
        for y in y0..y0 + ch {
            crop.extend_from_slice(&img.data[y * w + x0..y * w + x0 + cw]);
        }
        finite_pixels(&crop, cw, [x0, y0])?;
        // Only keypoints inside the region are described: those of the margin give the
        // region's keypoints their context and are not returned.
        self.detect_window(&crop, cw, ch, [x0, y0], Some(&region), &mut out);
        finish(&mut out);
        Ok(out)
    }

    fn check_params(&self) -> Result<(), FeatureError> {
        self.params.check()
    }

    /// The window `[x0, y0, x1, y1)` of a `w x h` image that [`Self::detect`] processes for
    /// `region` (finite, of size at least 0): the region grown by the margin, clipped to the
    /// image, its top-left corner moved back onto a multiple of the input stride of the
    /// coarsest octave built on the window (at least 8), so that every octave samples the
    /// same input pixels as on the whole image. `None` when nothing of it is in the image.
    fn region_window(&self, w: usize, h: usize, region: &BoxRect) -> Option<[usize; 4]> {
        let margin = f64::from(self.params.region_margin.max(0.0));
        // Clamped to the image before the casts: a region of 1e19 px would saturate an i64
        // and wrap the `+ 1`.
        let (wf, hf) = (w as f64, h as f64);
        let x0 = (region.x - margin).floor().clamp(0.0, wf) as usize;
        let y0 = (region.y - margin).floor().clamp(0.0, hf) as usize;
        let x1 = ((region.x + region.w + margin).ceil() + 1.0).clamp(0.0, wf) as usize;
        let y1 = ((region.y + region.h + margin).ceil() + 1.0).clamp(0.0, hf) as usize;
        if x1 <= x0 || y1 <= y0 {
            return None;
        }
        // Octave k samples every 2^k-th input pixel (2^(k-1)-th after the doubled first
        // octave). Moving the corner back can add an octave, so until the stride settles.
        let mut align = 8;
        loop {
            let (ax, ay) = (x0 - x0 % align, y0 - y0 % align);
            let coarsest = self.octave_count(x1 - ax, y1 - ay).saturating_sub(1);
            let stride = (1usize << coarsest) >> usize::from(self.params.upsample);
            if stride <= align {
                return Some([ax, ay, x1, y1]);
            }
            align = stride;
        }
    }

    /// How many octaves [`Self::build_pyramid`] builds on a `w x h` window: OpenCV's count,
    /// round(log2(min side of the base) − 2), plus one for the doubled octave, capped by
    /// `max_octaves` and stopped before an octave too small to hold an extremum.
    fn octave_count(&self, w: usize, h: usize) -> usize {
        let k = 1 + usize::from(self.params.upsample);
        let (mut bw, mut bh) = (k * w, k * h);
        let min_dim = 2 * IMG_BORDER + 1;
        if bw.min(bh) < min_dim {
            return 0;
        }
        let mut n_oct = ((bw.min(bh) as f64).log2() - 2.0).round().max(1.0) as usize
            + usize::from(self.params.upsample);
        if let Some(m) = self.params.max_octaves {
            n_oct = n_oct.min(m);
        }
        let mut built = 1;
        while built < n_oct {
            (bw, bh) = (bw / 2, bh / 2);
            if bw.min(bh) < min_dim {
                break;
            }
            built += 1;
        }
        built
    }

    /// Runs SIFT on a `w x h` window whose top-left pixel is `origin` in the full image,
    /// appending keypoints in full-image coordinates; with `keep` (full-image coordinates),
    /// only those whose centre lies in it, the others not even described.
    fn detect_window(
        &self,
        data: &[f32],
        w: usize,
        h: usize,
        origin: [usize; 2],
        keep: Option<&BoxRect>,
        out: &mut Features,
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
            // calling a function compiled with that target feature.
            unsafe { self.detect_window_avx2(data, w, h, origin, keep, out) };
            return;
        }
        self.detect_window_impl(data, w, h, origin, keep, out);
    }

    /// [`Self::detect_window_impl`] compiled for AVX2 (8-wide blurs, extrema tests and
    /// descriptor maths). Rust never fuses multiply-adds on its own, so the results are
    /// bit-identical to the baseline build.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn detect_window_avx2(
        &self,
        data: &[f32],
        w: usize,
        h: usize,
        origin: [usize; 2],
        keep: Option<&BoxRect>,
        out: &mut Features,
    ) {
        self.detect_window_impl(data, w, h, origin, keep, out);
    }

    #[inline(always)]
    fn detect_window_impl(
        &self,
        data: &[f32],
        w: usize,
        h: usize,
        origin: [usize; 2],
        keep: Option<&BoxRect>,
        out: &mut Features,
    ) {
        // The blur's scratch image, at the size of the first (largest) octave.
        let base_len = if self.params.upsample {
            4 * w * h
        } else {
            w * h
        };
        let mut scratch = BlurScratch {
            tmp: take_buf(base_len),
            ..BlurScratch::default()
        };
        let octaves = self.build_pyramid(data, w, h, &mut scratch);
        recycle(scratch.tmp);
        let n = self.params.n_octave_layers;
        // Factor from octave 0 coordinates to input coordinates.
        let base_factor = if self.params.upsample { 0.5 } else { 1.0 };
        // Extrema of every octave first (cheap), then orientations and descriptors, which are
        // independent per extremum: on several threads when the pool has them and there are
        // enough, in extremum order either way, so the output does not depend on threads.
        let mut found: Vec<(usize, Extremum)> = Vec::new();
        for (o, oct) in octaves.iter().enumerate() {
            let (w, h) = (oct.w, oct.h);
            // The extrema of each inner layer by bands of rows; the bands' extrema are
            // concatenated in layer and row order, the order of a single pass.
            let bands = parallel_bands(w, h);
            let rows = h.div_ceil(bands);
            if bands <= 1 {
                // Plain loops, not closures, so the code inlines into the AVX2 build.
                let mut scratch = ExtremaScratch::default();
                for layer in 1..=n {
                    self.find_extrema(oct, layer, 0, h, &mut found, o, &mut scratch);
                }
            } else {
                use rayon::prelude::*;
                let parts: Vec<Vec<(usize, Extremum)>> = (1..=n)
                    .flat_map(|layer| (0..bands).map(move |i| (layer, i * rows)))
                    .collect::<Vec<_>>()
                    .into_par_iter()
                    .map(|(layer, r0)| {
                        with_simd(
                            #[inline(always)]
                            || {
                                let mut v = Vec::new();
                                let r1 = (r0 + rows).min(h);
                                let mut scratch = ExtremaScratch::default();
                                self.find_extrema(oct, layer, r0, r1, &mut v, o, &mut scratch);
                                v
                            },
                        )
                    })
                    .collect();
                found.extend(parts.into_iter().flatten());
            }
        }
        let d = Describer {
            sigma: self.params.sigma,
            n,
            octaves: &octaves,
            base_factor,
            first_octave: -i32::from(self.params.upsample),
            ox: origin[0],
            oy: origin[1],
        };
        if let Some(r) = keep {
            found.retain(|f| {
                let (x, y) = d.position(f);
                let (x, y) = (f64::from(x), f64::from(y));
                x >= r.x && x <= r.x + r.w && y >= r.y && y <= r.y + r.h
            });
        }
        let described: Vec<(Keypoint, [u8; DESCRIPTOR_LEN])> =
            if found.len() >= PARALLEL_MIN_EXTREMA && rayon::current_num_threads() > 1 {
                use rayon::prelude::*;
                // `collect` keeps the extrema's order.
                found
                    .par_iter()
                    .map_init(GradScratch::default, |g, f| {
                        let mut v = Vec::with_capacity(1);
                        d.describe_dispatch(f, g, &mut v);
                        v
                    })
                    .flatten_iter()
                    .collect()
            } else {
                let mut grad = GradScratch::default();
                let mut v = Vec::with_capacity(found.len());
                for f in &found {
                    d.describe(f, &mut grad, &mut v);
                }
                v
            };
        for (k, desc) in described {
            out.keypoints.push(k);
            out.descriptors.push(desc);
        }
        for oct in octaves {
            oct.gauss.into_iter().chain(oct.dog).for_each(recycle);
        }
    }

    /// Builds the Gaussian and DoG pyramids of a `w x h` image.
    #[inline(always)]
    fn build_pyramid(
        &self,
        data: &[f32],
        w: usize,
        h: usize,
        scratch: &mut BlurScratch,
    ) -> Vec<Octave> {
        let n = self.params.n_octave_layers;
        let (mut base, bw, bh) = if self.params.upsample {
            match self.params.upsample_grid {
                UpsampleGrid::Exact => upsample2(data, w, h),
                UpsampleGrid::OpenCv => upsample2_quarter_shift(data, w, h),
            }
        } else {
            let mut v = take_buf(w * h);
            v.copy_from_slice(data);
            (v, w, h)
        };
        let min_dim = 2 * IMG_BORDER + 1;
        let n_oct = self.octave_count(w, h);
        if n_oct == 0 {
            recycle(base);
            return Vec::new();
        }
        let mut octaves: Vec<Octave> = Vec::with_capacity(n_oct);
        let mut blurred = take_buf(bw * bh);
        blur(
            &base,
            &mut blurred,
            None,
            bw,
            bh,
            &self.base_kernel,
            scratch,
        );
        recycle(std::mem::replace(&mut base, blurred));
        let (mut ow, mut oh) = (bw, bh);
        for o in 0..n_oct {
            if o > 0 {
                let prev = &octaves[o - 1];
                let (nw, nh) = (prev.w / 2, prev.h / 2);
                if nw.min(nh) < min_dim {
                    break;
                }
                base = downsample2(&prev.gauss[n], prev.w, nw, nh);
                ow = nw;
                oh = nh;
            }
            let mut gauss = Vec::with_capacity(n + 3);
            let mut dog = Vec::with_capacity(n + 2);
            gauss.push(std::mem::take(&mut base));
            for i in 1..n + 3 {
                let mut next = take_buf(ow * oh);
                // Each difference with its blur, band by band, while both scales are still in
                // cache (the first octave's eleven images do not fit in L2) and on the thread
                // that wrote the band.
                let mut d = take_buf(ow * oh);
                blur(
                    &gauss[i - 1],
                    &mut next,
                    Some(&mut d),
                    ow,
                    oh,
                    &self.layer_kernels[i],
                    scratch,
                );
                dog.push(d);
                gauss.push(next);
            }
            octaves.push(Octave {
                w: ow,
                h: oh,
                gauss,
                dog,
            });
        }
        octaves
    }

    /// The refined extrema ([`Self::refine`]) of DoG layer `layer` of octave `o` in rows
    /// `r0..r1`, appended to `out` with the octave number in row order: the candidates of
    /// [`extremum_flags`] with the prefilter threshold (half the final contrast threshold).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn find_extrema(
        &self,
        oct: &Octave,
        layer: usize,
        r0: usize,
        r1: usize,
        out: &mut Vec<(usize, Extremum)>,
        o: usize,
        s: &mut ExtremaScratch,
    ) {
        let (w, h) = (oct.w, oct.h);
        if w <= 2 * IMG_BORDER || h <= 2 * IMG_BORDER {
            return;
        }
        let thr = 0.5 * self.params.contrast_threshold / self.params.n_octave_layers as f32;
        let layers = [
            &oct.dog[layer - 1][..],
            &oct.dog[layer],
            &oct.dog[layer + 1],
        ];
        for r in r0.max(IMG_BORDER)..r1.min(h - IMG_BORDER) {
            let flags = extremum_flags(layers, w, r, thr, s);
            // Candidates are rare: skip 16 flags at a time while they are all zero.
            for (j, ch) in flags.chunks(16).enumerate() {
                if ch.iter().fold(0, |a, &f| a | f) == 0 {
                    continue;
                }
                for (k, _) in ch.iter().enumerate().filter(|(_, f)| **f != 0) {
                    if let Some(e) = self.refine(oct, r, IMG_BORDER + 16 * j + k, layer) {
                        out.push((o, e));
                    }
                }
            }
        }
    }

    /// Sub-pixel/scale refinement by a quadratic fit (up to 5 steps), then contrast and
    /// edge rejection.
    fn refine(&self, oct: &Octave, r0: usize, c0: usize, layer0: usize) -> Option<Extremum> {
        let n = self.params.n_octave_layers;
        let (w, h) = (oct.w, oct.h);
        let (mut r, mut c, mut layer) = (r0 as i64, c0 as i64, layer0 as i64);
        let mut x = [0f32; 3];
        let mut converged = false;
        for _ in 0..MAX_INTERP_STEPS {
            let (g, hm) = derivatives(oct, r as usize, c as usize, layer as usize);
            x = solve3(&hm, &g)?;
            if x.iter().all(|v| v.abs() < 0.5) {
                converged = true;
                break;
            }
            if x.iter().any(|v| v.abs() > (i32::MAX / 3) as f32) {
                return None;
            }
            c += x[0].round() as i64;
            r += x[1].round() as i64;
            layer += x[2].round() as i64;
            let b = IMG_BORDER as i64;
            if layer < 1
                || layer > n as i64
                || c < b
                || c >= w as i64 - b
                || r < b
                || r >= h as i64 - b
            {
                return None;
            }
        }
        if !converged {
            return None;
        }
        let (r, c, layer) = (r as usize, c as usize, layer as usize);
        let (g, hm) = derivatives(oct, r, c, layer);
        let v = oct.dog[layer][r * w + c];
        let contr = v + 0.5 * (g[0] * x[0] + g[1] * x[1] + g[2] * x[2]);
        if contr.abs() * (n as f32) < self.params.contrast_threshold {
            return None;
        }
        let (dxx, dyy, dxy) = (hm[0][0], hm[1][1], hm[0][1]);
        let tr = dxx + dyy;
        let det = dxx * dyy - dxy * dxy;
        let e = self.params.edge_threshold;
        if det <= 0.0 || tr * tr * e >= (e + 1.0) * (e + 1.0) * det {
            return None;
        }
        Some(Extremum {
            r,
            c,
            layer,
            xr: x[1],
            xc: x[0],
            xi: x[2],
            response: contr.abs(),
        })
    }
}

/// Fewest extrema for which orientations and descriptors are spread over rayon's threads (below
/// it, the fork costs more than it saves).
const PARALLEL_MIN_EXTREMA: usize = 16;

/// What the orientations and descriptors of a window's extrema need: the pyramid, and where
/// its coordinates land in the input image.
struct Describer<'a> {
    /// σ of the first scale of each octave, and the layers per octave.
    sigma: f32,
    n: usize,
    octaves: &'a [Octave],
    /// Factor from octave 0 coordinates to the window's.
    base_factor: f32,
    /// Octave number of octave 0 (−1 with the doubled first octave).
    first_octave: i32,
    /// The window's origin in the input image.
    ox: usize,
    oy: usize,
}

impl Describer<'_> {
    /// [`Self::describe`] compiled for AVX2 when the CPU has it, for calls from rayon's
    /// threads (which run outside the AVX2 build of [`Sift::detect_window`]).
    fn describe_dispatch(
        &self,
        f: &(usize, Extremum),
        grad: &mut GradScratch,
        out: &mut Vec<(Keypoint, [u8; DESCRIPTOR_LEN])>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
            // calling a function compiled with that target feature.
            unsafe { self.describe_avx2(f, grad, out) };
            return;
        }
        self.describe(f, grad, out);
    }

    /// [`Self::describe`] compiled for AVX2; bit-identical to the baseline build (no fused
    /// multiply-adds).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn describe_avx2(
        &self,
        f: &(usize, Extremum),
        grad: &mut GradScratch,
        out: &mut Vec<(Keypoint, [u8; DESCRIPTOR_LEN])>,
    ) {
        self.describe(f, grad, out);
    }

    /// Where the keypoints of the refined extremum `f` (octave `f.0`) lie in the input image.
    #[inline(always)]
    fn position(&self, f: &(usize, Extremum)) -> (f32, f32) {
        let (o, e) = f;
        let factor = self.base_factor * (1u32 << o) as f32;
        let xo = e.c as f32 + e.xc;
        let yo = e.r as f32 + e.xr;
        (xo * factor + self.ox as f32, yo * factor + self.oy as f32)
    }

    /// The keypoints of one refined extremum of octave `f.0`: one per dominant orientation,
    /// each with its descriptor, appended to `out`.
    #[inline(always)]
    fn describe(
        &self,
        f: &(usize, Extremum),
        grad: &mut GradScratch,
        out: &mut Vec<(Keypoint, [u8; DESCRIPTOR_LEN])>,
    ) {
        let (o, e) = f;
        let oct = &self.octaves[*o];
        let factor = self.base_factor * (1u32 << o) as f32;
        let sigma_oct = self.sigma * 2f32.powf((e.layer as f32 + e.xi) / self.n as f32);
        let img = &oct.gauss[e.layer];
        let xo = e.c as f32 + e.xc;
        let yo = e.r as f32 + e.xr;
        let mut angles = [0f32; ORI_BINS];
        let na = orientations(img, oct.w, oct.h, e.c, e.r, sigma_oct, &mut angles, grad);
        let (x, y) = self.position(f);
        for &angle in &angles[..na] {
            let desc = descriptor(img, oct.w, oct.h, xo, yo, sigma_oct, angle, grad);
            out.push((
                Keypoint {
                    x,
                    y,
                    scale: sigma_oct * factor,
                    angle,
                    response: e.response,
                    octave: self.first_octave + *o as i32,
                },
                desc,
            ));
        }
    }
}

/// Refuses a window of pixels (`width` a row, at `origin` in the image) holding one that is
/// not finite, naming the first in image coordinates.
fn finite_pixels(window: &[f32], width: usize, origin: [usize; 2]) -> Result<(), FeatureError> {
    match window.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(FeatureError::NonFinitePixel {
            x: origin[0] + i % width.max(1),
            y: origin[1] + i / width.max(1),
            value: window[i],
        }),
    }
}

/// Sorts keypoints (with their descriptors) into a canonical order and removes exact
/// duplicates (two candidates refined to the same point).
fn finish(f: &mut Features) {
    let mut idx: Vec<usize> = (0..f.keypoints.len()).collect();
    let key = |k: &Keypoint| [k.y, k.x, k.scale, k.angle];
    idx.sort_by(|&a, &b| {
        let (ka, kb) = (key(&f.keypoints[a]), key(&f.keypoints[b]));
        ka.iter()
            .zip(&kb)
            .map(|(x, y)| x.total_cmp(y))
            .find(|o| o.is_ne())
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let mut kps = Vec::with_capacity(idx.len());
    let mut descs = Vec::with_capacity(idx.len());
    for i in idx {
        let k = f.keypoints[i];
        if kps.last().is_some_and(|p: &Keypoint| key(p) == key(&k)) {
            continue;
        }
        kps.push(k);
        descs.push(f.descriptors[i]);
    }
    f.keypoints = kps;
    f.descriptors = descs;
}

/// `a > b ? a : b` (compiles to `maxps`).
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// `a < b ? a : b` (compiles to `minps`).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// Scratch of [`extremum_flags`]: one row of column maxima and minima, and the flags.
#[derive(Default)]
struct ExtremaScratch {
    vmax: Vec<f32>,
    vmin: Vec<f32>,
    flags: Vec<u8>,
}

/// Which pixels of row `r` of the middle layer of `layers` (three DoG layers, `w` wide, `r`
/// at least one row from the top and bottom) are extremum candidates, for the columns
/// `IMG_BORDER..w - IMG_BORDER`: above `thr` and `≥` all 26 neighbours in the three layers,
/// or below `-thr` and `≤` all of them.
///
/// The maxima and minima of each column's 9 samples (three rows of three layers) come
/// first, then those of three neighbouring columns: one pass over the 27-neighbourhoods of a
/// row, branch-free and vectorised, with nothing written but the row's flags.
#[inline(always)]
fn extremum_flags<'s>(
    layers: [&[f32]; 3],
    w: usize,
    r: usize,
    thr: f32,
    s: &'s mut ExtremaScratch,
) -> &'s [u8] {
    let len = w.saturating_sub(2 * IMG_BORDER);
    // Columns IMG_BORDER - 1 ..= w - IMG_BORDER: the inner ones and one on each side.
    let vlen = len + 2;
    grow(&mut s.vmax, vlen);
    grow(&mut s.vmin, vlen);
    grow(&mut s.flags, len);
    let (vmax, vmin, flags) = (
        &mut s.vmax[..vlen],
        &mut s.vmin[..vlen],
        &mut s.flags[..len],
    );
    let s0 = r * w + IMG_BORDER - 1;
    let [below, cur, above] = layers;
    // Slices written out one by one: their lengths are then known, and the loop vectorises.
    let (up, mid, down) = (s0 - w, s0, s0 + w);
    let rows = [
        &below[up..up + vlen],
        &below[mid..mid + vlen],
        &below[down..down + vlen],
        &cur[up..up + vlen],
        &cur[mid..mid + vlen],
        &cur[down..down + vlen],
        &above[up..up + vlen],
        &above[mid..mid + vlen],
        &above[down..down + vlen],
    ];
    for k in 0..vlen {
        let (mut m, mut n) = (rows[0][k], rows[0][k]);
        for row in &rows[1..] {
            m = fmax(m, row[k]);
            n = fmin(n, row[k]);
        }
        vmax[k] = m;
        vmin[k] = n;
    }
    let v = &cur[s0 + 1..][..len];
    for k in 0..len {
        let x = v[k];
        let mx = fmax(fmax(vmax[k], vmax[k + 1]), vmax[k + 2]);
        let mn = fmin(fmin(vmin[k], vmin[k + 1]), vmin[k + 2]);
        flags[k] = u8::from(((x > thr) & (x >= mx)) | ((x < -thr) & (x <= mn)));
    }
    flags
}

/// Gradient `(dx, dy, ds)` and Hessian of the DoG at an integer position.
fn derivatives(oct: &Octave, r: usize, c: usize, layer: usize) -> ([f32; 3], [[f32; 3]; 3]) {
    let w = oct.w;
    let i = r * w + c;
    let (p, cu, n) = (&oct.dog[layer - 1], &oct.dog[layer], &oct.dog[layer + 1]);
    let v2 = 2.0 * cu[i];
    let g = [
        (cu[i + 1] - cu[i - 1]) * 0.5,
        (cu[i + w] - cu[i - w]) * 0.5,
        (n[i] - p[i]) * 0.5,
    ];
    let dxx = cu[i + 1] + cu[i - 1] - v2;
    let dyy = cu[i + w] + cu[i - w] - v2;
    let dss = n[i] + p[i] - v2;
    let dxy = (cu[i + w + 1] - cu[i + w - 1] - cu[i - w + 1] + cu[i - w - 1]) * 0.25;
    let dxs = (n[i + 1] - n[i - 1] - p[i + 1] + p[i - 1]) * 0.25;
    let dys = (n[i + w] - n[i - w] - p[i + w] + p[i - w]) * 0.25;
    (g, [[dxx, dxy, dxs], [dxy, dyy, dys], [dxs, dys, dss]])
}

/// Solves `H x = -g` for a symmetric 3x3 `H` (Cramer's rule in f64); `None` if singular.
fn solve3(hm: &[[f32; 3]; 3], g: &[f32; 3]) -> Option<[f32; 3]> {
    let a: [[f64; 3]; 3] = hm.map(|r| r.map(f64::from));
    let b = g.map(|v| -f64::from(v));
    let det3 = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det3(&a);
    if !d.is_finite() || d.abs() < 1e-30 {
        return None;
    }
    let mut x = [0f32; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut m = a;
        for row in 0..3 {
            m[row][k] = b[row];
        }
        *xk = (det3(&m) / d) as f32;
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Reflect-101 border index (`-1 → 1`, `n → n - 2`), for any offset.
#[inline]
fn reflect101(mut i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let n = n as isize;
    loop {
        if i < 0 {
            i = -i;
        } else if i >= n {
            i = 2 * (n - 1) - i;
        } else {
            return i as usize;
        }
    }
}

/// `L` outputs of a symmetric convolution from `x` on: one accumulator per output, all taps
/// in order, so the block stays in registers.
#[inline(always)]
fn conv_block<'a, const L: usize>(
    k: &[f32],
    c: &[f32],
    side: &impl Fn(usize) -> (&'a [f32], &'a [f32]),
    out: &mut [f32],
    x: usize,
) {
    let c = &c[x..x + L];
    let mut acc = [0f32; L];
    for j in 0..L {
        acc[j] = k[0] * c[j];
    }
    for (t, &kt) in k.iter().enumerate().skip(1) {
        let (a, b) = side(t);
        let (a, b) = (&a[x..x + L], &b[x..x + L]);
        for j in 0..L {
            acc[j] += kt * (a[j] + b[j]);
        }
    }
    out[x..x + L].copy_from_slice(&acc);
}

/// One output row of a symmetric convolution with the half kernel `k`: `c` is the centre
/// samples, `side(i)` the samples at `-i` and `+i` (each at least as long as `out`).
/// Summation order per pixel is `k0·c + k1·(a1 + b1) + k2·(a2 + b2) + …`, the same for
/// every block size, so results are bit-identical however the row is cut.
#[inline(always)]
fn conv_row<'a>(
    k: &[f32],
    c: &[f32],
    side: impl Fn(usize) -> (&'a [f32], &'a [f32]),
    out: &mut [f32],
) {
    let n = out.len();
    let mut x = 0;
    while x + 32 <= n {
        conv_block::<32>(k, c, &side, out, x);
        x += 32;
    }
    while x + 8 <= n {
        conv_block::<8>(k, c, &side, out, x);
        x += 8;
    }
    while x < n {
        conv_block::<1>(k, c, &side, out, x);
        x += 1;
    }
}

/// Separable Gaussian blur of a `w x h` image with reflect-101 borders, and with `dog` the
/// difference of the blurred image and `src` (`dst - src`) into it. Images of at least
/// [`PARALLEL_MIN_PIXELS`] are cut into bands of rows spread over rayon's current pool (the
/// horizontal pass, then the vertical one and the difference); every pixel is computed the
/// same way however the rows are split, so the result does not depend on the number of
/// threads.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn blur(
    src: &[f32],
    dst: &mut [f32],
    dog: Option<&mut [f32]>,
    w: usize,
    h: usize,
    k: &Kernel,
    s: &mut BlurScratch,
) {
    let r = k.radius();
    let kh = &k.half[..];
    // Grow only: the caller sizes `tmp` for the largest octave, so it is never refilled.
    if s.tmp.len() < w * h {
        s.tmp.resize(w * h, 0.0);
    }
    let tmp = &mut s.tmp[..w * h];
    let dst = &mut dst[..w * h];
    let bands = parallel_bands(w, h);
    if bands <= 1 {
        blur_rows_h(src, tmp, w, 0, kh, r, &mut s.row);
        blur_rows_v(tmp, dst, w, h, 0, kh, r, &mut s.offs);
        if let Some(d) = dog {
            difference(dst, &src[..w * h], &mut d[..w * h]);
        }
        return;
    }
    use rayon::prelude::*;
    let rows = h.div_ceil(bands);
    if s.bands.len() < bands {
        s.bands.resize_with(bands, Default::default);
    }
    let scratch = &mut s.bands[..bands];
    tmp.par_chunks_mut(rows * w)
        .zip(scratch.par_iter_mut())
        .enumerate()
        .for_each(|(i, (t, (row, _)))| {
            with_simd(
                #[inline(always)]
                || blur_rows_h(src, t, w, i * rows, kh, r, row),
            );
        });
    let tmp = &*tmp;
    // The difference's bands beside the blur's (none without a difference).
    let mut dog_bands: Vec<Option<&mut [f32]>> = match dog {
        Some(d) => d[..w * h].chunks_mut(rows * w).map(Some).collect(),
        None => (0..bands).map(|_| None).collect(),
    };
    dst.par_chunks_mut(rows * w)
        .zip(scratch.par_iter_mut())
        .zip(dog_bands.par_iter_mut())
        .enumerate()
        .for_each(|(i, ((d, (_, offs)), dog))| {
            with_simd(
                #[inline(always)]
                || {
                    blur_rows_v(tmp, d, w, h, i * rows, kh, r, offs);
                    if let Some(g) = dog {
                        difference(d, &src[i * rows * w..][..d.len()], g);
                    }
                },
            );
        });
}

/// `out = b - a`, element by element.
#[inline(always)]
fn difference(b: &[f32], a: &[f32], out: &mut [f32]) {
    for ((d, b), a) in out.iter_mut().zip(b).zip(a) {
        *d = b - a;
    }
}

/// Fewest pixels of an image whose blur, differences of Gaussians and extremum search are
/// spread over rayon's threads (below it, the fork costs more than it saves).
const PARALLEL_MIN_PIXELS: usize = 8192;

/// Most bands an image is cut into for the threads.
const MAX_BANDS: usize = 8;

/// How many bands of rows a `w x h` image's work is cut into: one (no fork) on a one-thread
/// pool or for a small image, else one per thread, each at least 8 rows.
fn parallel_bands(w: usize, h: usize) -> usize {
    if w * h < PARALLEL_MIN_PIXELS {
        return 1;
    }
    rayon::current_num_threads().min(h / 8).clamp(1, MAX_BANDS)
}

/// Runs `f` inside a function compiled for AVX2 when the CPU has it, so that the SIMD loops
/// of work handed to rayon's threads (which run outside the AVX2 build of
/// [`Sift::detect_window`]) are compiled for it too: `f` must be an `#[inline(always)]`
/// closure. Rust never fuses multiply-adds on its own, so the results are bit-identical
/// either way.
#[inline(always)]
fn with_simd<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
        // calling a function compiled with that target feature.
        return unsafe { in_avx2(f) };
    }
    f()
}

/// Calls `f` from a function compiled for AVX2 (see [`with_simd`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn in_avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// The horizontal pass of [`blur`] for the rows `y0..` that `out` holds (whole rows of
/// `w`), from a copy of each row with reflected borders.
#[inline(always)]
fn blur_rows_h(
    src: &[f32],
    out: &mut [f32],
    w: usize,
    y0: usize,
    kh: &[f32],
    r: usize,
    row: &mut Vec<f32>,
) {
    row.resize(w + 2 * r, 0.0);
    for (j, out) in out.chunks_exact_mut(w).enumerate() {
        let y = y0 + j;
        let srow = &src[y * w..(y + 1) * w];
        row[r..r + w].copy_from_slice(srow);
        for i in 1..=r {
            row[r - i] = srow[reflect101(-(i as isize), w)];
            row[r + w - 1 + i] = srow[reflect101((w - 1 + i) as isize, w)];
        }
        let row = &row[..];
        conv_row(kh, &row[r..], |i| (&row[r - i..], &row[r + i..]), out);
    }
}

/// The vertical pass of [`blur`] for the rows `y0..` that `out` holds, from the whole
/// horizontally blurred image `tmp` (`h` rows): rows above and below each output row,
/// reflected at the edges. Rows are done two at a time, each loaded row serving both
/// (see [`conv2_block`]); the sums are those of [`conv_row`] either way.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn blur_rows_v(
    tmp: &[f32],
    out: &mut [f32],
    w: usize,
    h: usize,
    y0: usize,
    kh: &[f32],
    r: usize,
    offs: &mut Vec<(usize, usize)>,
) {
    // Offsets of the rows at -i and +i of row `y` (index 0: the row itself), reflected once
    // per row; one more than the kernel's radius for the two-row blocks.
    let fill_offs = |offs: &mut Vec<(usize, usize)>, y: usize| {
        offs.clear();
        offs.extend((0..=r + 1).map(|i| {
            (
                reflect101(y as isize - i as isize, h) * w,
                reflect101((y + i) as isize, h) * w,
            )
        }));
    };
    let rows = out.len() / w;
    let mut j = 0;
    while j + 2 <= rows {
        fill_offs(offs, y0 + j);
        let (o0, o1) = out[j * w..(j + 2) * w].split_at_mut(w);
        let offs = &offs[..];
        let mut x = 0;
        while x + 16 <= w {
            conv2_block::<16>(kh, tmp, offs, o0, o1, x);
            x += 16;
        }
        while x + 8 <= w {
            conv2_block::<8>(kh, tmp, offs, o0, o1, x);
            x += 8;
        }
        while x < w {
            conv2_block::<1>(kh, tmp, offs, o0, o1, x);
            x += 1;
        }
        j += 2;
    }
    if j < rows {
        let y = y0 + j;
        fill_offs(offs, y);
        let offs = &offs[..];
        conv_row(
            kh,
            &tmp[y * w..(y + 1) * w],
            |i| {
                let (a, b) = offs[i];
                (&tmp[a..a + w], &tmp[b..b + w])
            },
            &mut out[j * w..(j + 1) * w],
        );
    }
}

/// Columns `x..x + L` of two consecutive output rows `y` and `y + 1` of the vertical pass:
/// `offs[i]` holds the offsets of rows `y - i` and `y + i` (reflected), `i = 0..=r + 1`.
/// Row `y + 1 - i` is row `y - (i - 1)` and row `y + 1 + i` is row `y + (i + 1)`, so each
/// tap loads two rows for the two outputs instead of four. Per pixel the sum is
/// `k0·c + k1·(a1 + b1) + …` in tap order, as in [`conv_block`].
#[inline(always)]
fn conv2_block<const L: usize>(
    k: &[f32],
    tmp: &[f32],
    offs: &[(usize, usize)],
    out0: &mut [f32],
    out1: &mut [f32],
    x: usize,
) {
    let row = |o: usize| -> [f32; L] {
        let mut v = [0f32; L];
        v.copy_from_slice(&tmp[o + x..o + x + L]);
        v
    };
    let mut prev_lo = row(offs[0].1);
    let mut prev_hi = row(offs[1].1);
    let mut acc0 = [0f32; L];
    let mut acc1 = [0f32; L];
    for j in 0..L {
        acc0[j] = k[0] * prev_lo[j];
        acc1[j] = k[0] * prev_hi[j];
    }
    for (i, &kt) in k.iter().enumerate().skip(1) {
        let lo = row(offs[i].0);
        let hi_next = row(offs[i + 1].1);
        for j in 0..L {
            acc0[j] += kt * (lo[j] + prev_hi[j]);
            acc1[j] += kt * (prev_lo[j] + hi_next[j]);
        }
        prev_lo = lo;
        prev_hi = hi_next;
    }
    out0[x..x + L].copy_from_slice(&acc0);
    out1[x..x + L].copy_from_slice(&acc1);
}

/// Doubles an image: even pixels are the input's, odd ones the average of their two (or
/// four) neighbours, the last row and column replicate the edge. Pixel `u` of the result
/// is at `u / 2` in the input.
fn upsample2(src: &[f32], w: usize, h: usize) -> (Vec<f32>, usize, usize) {
    let (w2, h2) = (2 * w, 2 * h);
    let mut out = take_buf(w2 * h2);
    // Horizontal doubling of each input row into the even output rows.
    for y in 0..h {
        let s = &src[y * w..(y + 1) * w];
        let o = &mut out[2 * y * w2..(2 * y + 1) * w2];
        for x in 0..w {
            let nx = s[(x + 1).min(w - 1)];
            o[2 * x] = s[x];
            o[2 * x + 1] = 0.5 * (s[x] + nx);
        }
    }
    // Odd rows: average of the even rows around them.
    for y in 0..h {
        let yn = (y + 1).min(h - 1);
        let (head, tail) = out.split_at_mut((2 * y + 1) * w2);
        let a = &head[2 * y * w2..(2 * y + 1) * w2];
        let (odd, rest) = tail.split_at_mut(w2);
        let b: &[f32] = if yn == y { a } else { &rest[..w2] };
        for ((o, p), q) in odd.iter_mut().zip(a).zip(b) {
            *o = 0.5 * (p + q);
        }
    }
    (out, w2, h2)
}

/// Doubles an image as OpenCV's bilinear `resize` does (pixel centres at half-integers):
/// pixel `u` of the result samples the input at `u / 2 − 1/4`, that is `¾·s[k] + ¼·s[k − 1]`
/// for `u = 2k` and `¾·s[k] + ¼·s[k + 1]` for `u = 2k + 1`, along rows and then columns, with
/// replicated edges.
fn upsample2_quarter_shift(src: &[f32], w: usize, h: usize) -> (Vec<f32>, usize, usize) {
    let (w2, h2) = (2 * w, 2 * h);
    let mut rows = take_buf(w2 * h);
    for y in 0..h {
        let s = &src[y * w..(y + 1) * w];
        let o = &mut rows[y * w2..(y + 1) * w2];
        for x in 0..w {
            o[2 * x] = 0.75 * s[x] + 0.25 * s[x.saturating_sub(1)];
            o[2 * x + 1] = 0.75 * s[x] + 0.25 * s[(x + 1).min(w - 1)];
        }
    }
    let mut out = take_buf(w2 * h2);
    for y in 0..h {
        let c = &rows[y * w2..(y + 1) * w2];
        let up = &rows[y.saturating_sub(1) * w2..][..w2];
        let down = &rows[(y + 1).min(h - 1) * w2..][..w2];
        let (even, odd) = out[2 * y * w2..(2 * y + 2) * w2].split_at_mut(w2);
        for x in 0..w2 {
            even[x] = 0.75 * c[x] + 0.25 * up[x];
            odd[x] = 0.75 * c[x] + 0.25 * down[x];
        }
    }
    recycle(rows);
    (out, w2, h2)
}

/// Every other pixel of a `w`-wide image, giving `nw x nh`.
fn downsample2(src: &[f32], w: usize, nw: usize, nh: usize) -> Vec<f32> {
    let mut out = take_buf(nw * nh);
    for (y, o) in out.chunks_exact_mut(nw.max(1)).enumerate() {
        let row = &src[2 * y * w..];
        for (x, v) in o.iter_mut().enumerate() {
            *v = row[2 * x];
        }
    }
    out
}

/// Polynomial arctangent (Abramowitz & Stegun 4.4.49, |error| < 1e-5 rad) as `atan2(y, x)`
/// mapped to `[0, 2π]`; written without branches so loops over it vectorise.
#[inline]
pub(crate) fn fast_atan2(y: f32, x: f32) -> f32 {
    let ax = x.abs();
    let ay = y.abs();
    let mx = ax.max(ay);
    let mn = ax.min(ay);
    let z = mn / (mx + f32::MIN_POSITIVE);
    let z2 = z * z;
    let mut a = z
        * (0.999_866
            + z2 * (-0.330_299_5 + z2 * (0.180_141 + z2 * (-0.085_133 + z2 * 0.020_835_1))));
    a = if ay > ax { PI / 2.0 - a } else { a };
    a = if x < 0.0 { PI - a } else { a };
    if y < 0.0 { TAU - a } else { a }
}

/// Dominant orientations at integer position `(c, r)` of `img`: a 36-bin histogram of
/// gradient directions weighted by magnitude and a Gaussian of σ = 1.5 · `sigma`, smoothed
/// with `[1 4 6 4 1] / 16`; every local peak ≥ 0.8 of the maximum gives an angle (parabolic
/// interpolation). Returns how many angles were written.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn orientations(
    img: &[f32],
    w: usize,
    h: usize,
    c: usize,
    r: usize,
    sigma: f32,
    out: &mut [f32; ORI_BINS],
    s: &mut GradScratch,
) -> usize {
    let radius = (ORI_RADIUS * sigma).round() as isize;
    let sw = ORI_SIG_FCTR * sigma;
    let scale = -1.0 / (2.0 * sw * sw);
    let mut hist = [0f32; ORI_BINS];
    // Window weights for offsets -radius..=radius, and 8 more for the vectors' extra lanes.
    let gw: Vec<f32> = (-radius..=radius + 8)
        .map(|i| ((i * i) as f32 * scale).exp())
        .collect();
    let bins_per_rad = ORI_BINS as f32 / TAU;
    for i in -radius..=radius {
        let y = r as isize + i;
        if y <= 0 || y >= h as isize - 1 {
            continue;
        }
        let y = y as usize;
        let wy = gw[(i + radius) as usize];
        let x_lo = (c as isize - radius).max(1) as usize;
        let x_hi = ((c as isize + radius).min(w as isize - 2)) as usize;
        if x_lo > x_hi {
            continue;
        }
        // Weighted magnitudes and bins of the row in one vectorised pass, then the scatter.
        let n = x_hi - x_lo + 1;
        // Whole vectors of 8 where the image has the room, as in `descriptor` (the window
        // weights `gw` run 8 past the radius for it); the extra samples are not added.
        let m = match n.next_multiple_of(8) {
            m if (y + 1) * w + x_lo + m <= img.len() => m,
            _ => n,
        };
        grow(&mut s.mag, m);
        grow(&mut s.obin, m);
        let left = &img[y * w + x_lo - 1..][..m];
        let right = &img[y * w + x_lo + 1..][..m];
        let up = &img[(y - 1) * w + x_lo..][..m];
        let down = &img[(y + 1) * w + x_lo..][..m];
        let g0 = (x_lo as isize - c as isize + radius) as usize;
        let gwx = &gw[g0..][..m];
        let (mags, bins) = (&mut s.mag[..m], &mut s.obin[..m]);
        for k in 0..m {
            let gx = right[k] - left[k];
            let gy = down[k] - up[k];
            mags[k] = (gx * gx + gy * gy).sqrt() * gwx[k] * wy;
            // Rounded to the nearest bin (the angle is ≥ 0, so truncation of +0.5 rounds).
            bins[k] = whole_to_u32((fast_atan2(gy, gx) * bins_per_rad + 0.5).trunc());
        }
        for (&m, &b) in mags[..n].iter().zip(&bins[..n]) {
            let bin = b as usize;
            let bin = if bin >= ORI_BINS { bin - ORI_BINS } else { bin };
            // `min`: a no-op for finite gradients; keeps a NaN in bounds.
            hist[bin.min(ORI_BINS - 1)] += m;
        }
    }
    // Circular smoothing.
    let n = ORI_BINS;
    let mut sm = [0f32; ORI_BINS];
    for (i, s) in sm.iter_mut().enumerate() {
        let at = |d: isize| hist[(i as isize + d).rem_euclid(n as isize) as usize];
        *s = (at(-2) + at(2)) * (1.0 / 16.0)
            + (at(-1) + at(1)) * (4.0 / 16.0)
            + at(0) * (6.0 / 16.0);
    }
    let max = sm.iter().cloned().fold(0f32, f32::max);
    if max <= 0.0 {
        return 0;
    }
    let thr = max * ORI_PEAK_RATIO;
    let mut count = 0;
    for j in 0..n {
        let l = sm[(j + n - 1) % n];
        let rr = sm[(j + 1) % n];
        let v = sm[j];
        if v > l && v > rr && v >= thr {
            let mut bin = j as f32 + 0.5 * (l - rr) / (l - 2.0 * v + rr);
            if bin < 0.0 {
                bin += n as f32;
            } else if bin >= n as f32 {
                bin -= n as f32;
            }
            let mut a = bin * (TAU / n as f32);
            if a >= TAU - 1e-6 {
                a = 0.0;
            }
            out[count] = a;
            count += 1;
        }
    }
    count
}

/// Scratch of the orientation histogram (`mag`, `obin`, one row) and the descriptor (one
/// row of samples).
#[derive(Default)]
struct GradScratch {
    mag: Vec<f32>,
    obin: Vec<u32>,
    /// Offsets from the keypoint and Gaussian window weights of the descriptor's columns.
    dx: Vec<f32>,
    wx: Vec<f32>,
    /// Anchor of each sample: its lower bins `(r0, c0, o0)` as `(r0 · (d + 1) + c0) · bins
    /// + o0`, spatial bins counted in the grid padded by one cell.
    anchor: Vec<u32>,
    /// Share of each sample's magnitude that goes to the upper orientation bin.
    fo: Vec<f32>,
    /// Weighted magnitude split over the 2x2 spatial cells `(r0, c0), (r0, c0 + 1),
    /// (r0 + 1, c0), (r0 + 1, c0 + 1)`.
    vrc: Vec<[f32; 4]>,
}

/// A whole number `v` in `[0, 2²³)` as an integer, without a (saturating, hence slow and
/// vectorisation-blocking) float-to-int cast: adding 2²³ puts `v` in the mantissa's low bits.
/// Values outside that range (or NaN) give some integer below 2²³, never a panic.
#[inline(always)]
fn whole_to_u32(v: f32) -> u32 {
    (v + 8_388_608.0).to_bits() & 0x7f_ffff
}

/// The interval of `t` where `lo < a + b·t < hi` (open), as `(min, max)`; empty when
/// `min > max`.
#[inline]
fn linear_interval(a: f32, b: f32, lo: f32, hi: f32) -> (f32, f32) {
    if b.abs() < 1e-12 {
        if a > lo && a < hi {
            (f32::NEG_INFINITY, f32::INFINITY)
        } else {
            (1.0, -1.0)
        }
    } else {
        let (t0, t1) = ((lo - a) / b, (hi - a) / b);
        (t0.min(t1), t0.max(t1))
    }
}

/// The 128-d descriptor of a keypoint at sub-pixel `(xo, yo)` of `img` (octave
/// coordinates), σ `sigma` (octave pixels), orientation `angle`.
///
/// Samples are the interior pixels whose rotated position falls inside the 4x4 cell grid
/// grown by one cell (each contributes trilinearly to up to 8 bins); the per-row range of
/// such pixels is computed analytically, so no sample is visited in vain. Per row, one
/// vectorised pass computes every sample's gradient, bins and shares, then a second adds
/// each sample's 8 shares to the histogram as one block (see the anchors below).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn descriptor(
    img: &[f32],
    w: usize,
    h: usize,
    xo: f32,
    yo: f32,
    sigma: f32,
    angle: f32,
    s: &mut GradScratch,
) -> [u8; DESCRIPTOR_LEN] {
    let d = DESCR_WIDTH;
    let nb = DESCR_BINS;
    let df = d as f32;
    let hist_width = DESCR_SCL_FCTR * sigma;
    let diag = ((w * w + h * h) as f32).sqrt();
    let radius = (hist_width * std::f32::consts::SQRT_2 * (df + 1.0) * 0.5)
        .round()
        .min(diag) as isize;
    let (sin_t, cos_t) = angle.sin_cos();
    let (cos_t, sin_t) = (cos_t / hist_width, sin_t / hist_width);
    let ci = xo.round() as isize;
    let ri = yo.round() as isize;
    // Gaussian window, σ = d / 2 cells: separable in the (unrotated) offsets.
    let exp_scale = -1.0 / (0.5 * df * df * hist_width * hist_width);
    let half_d = df / 2.0 - 0.5;
    let x_min = (ci - radius).max(1);
    let x_max = (ci + radius).min(w as isize - 2);
    if x_min > x_max {
        return [0; DESCRIPTOR_LEN];
    }
    // Columns x_min..=x_max, and 8 more for the vectors' extra lanes.
    s.dx.clear();
    s.dx.extend((x_min..=x_max + 8).map(|x| x as f32 - xo));
    s.wx.clear();
    s.wx.extend(s.dx.iter().map(|dx| (dx * dx * exp_scale).exp()));
    // Shrink the open bin interval (-1, d) a hair so rounding never puts a sample outside.
    let (lo, hi) = (-1.0 + 1e-4, df - 1e-4);
    let bins_per_rad = nb as f32 / TAU;
    let nbf = nb as f32;
    // The histogram by anchors: a sample whose lower bins are (r, c, o), in the grid padded
    // by one cell on each side, adds its whole 2x2x2 block of trilinear shares, lanes
    // [do][dr][dc], to anchor (r, c, o) with one 8-lane add instead of eight scattered ones;
    // the anchors are folded into the bins at the end. Lower spatial bins run 0..=d.
    let na = d + 1;
    let mut anchors = [[0f32; 8]; (DESCR_WIDTH + 1) * (DESCR_WIDTH + 1) * DESCR_BINS];
    for y in (ri - radius).max(1)..=(ri + radius).min(h as isize - 2) {
        let dy = y as f32 - yo;
        let (c0, c1) = linear_interval(half_d + dy * sin_t, cos_t, lo, hi);
        let (r0, r1) = linear_interval(half_d + dy * cos_t, -sin_t, lo, hi);
        let dx_lo = c0.max(r0);
        let dx_hi = c1.min(r1);
        if dx_lo > dx_hi {
            continue;
        }
        let xa = ((xo + dx_lo).ceil() as isize).max(x_min);
        let xb = ((xo + dx_hi).floor() as isize).min(x_max);
        if xa > xb {
            continue;
        }
        let wy = (dy * dy * exp_scale).exp();
        let (yu, xa, n) = (y as usize, xa as usize, (xb - xa + 1) as usize);
        // The per-sample pass runs over whole vectors of 8 where the image has the room
        // (past the row's end, into the next row): the extra samples are computed, never
        // added, and the loop needs no scalar tail.
        let m = match n.next_multiple_of(8) {
            m if (yu + 1) * w + xa + m <= img.len() => m,
            _ => n,
        };
        let left = &img[yu * w + xa - 1..][..m];
        let right = &img[yu * w + xa + 1..][..m];
        let up = &img[(yu - 1) * w + xa..][..m];
        let down = &img[(yu + 1) * w + xa..][..m];
        let wxs = &s.wx[xa - x_min as usize..][..m];
        let dxs = &s.dx[xa - x_min as usize..][..m];
        let cb0 = half_d + dy * sin_t;
        let rb0 = half_d + dy * cos_t;
        grow(&mut s.anchor, m);
        grow(&mut s.fo, m);
        grow(&mut s.vrc, m);
        let (anchor, fos, vrc) = (&mut s.anchor[..m], &mut s.fo[..m], &mut s.vrc[..m]);
        for k in 0..m {
            let dx = dxs[k];
            let (gx, gy) = (right[k] - left[k], down[k] - up[k]);
            let mag = (gx * gx + gy * gy).sqrt() * (wy * wxs[k]);
            let o = (fast_atan2(gy, gx) - angle) * bins_per_rad;
            let o = if o < 0.0 { o + nbf } else { o };
            let obin = if o >= nbf { o - nbf } else { o };
            let rb = (rb0 - dx * sin_t).clamp(lo, hi) + 1.0;
            let cb = (cb0 + dx * cos_t).clamp(lo, hi) + 1.0;
            let (r0, c0) = (rb.trunc(), cb.trunc());
            let o0 = obin.trunc().min(nbf - 1.0);
            let (fr, fc) = (rb - r0, cb - c0);
            fos[k] = obin - o0;
            anchor[k] = whole_to_u32((r0 * (df + 1.0) + c0) * nbf + o0);
            let v_r1 = mag * fr;
            let v_r0 = mag - v_r1;
            let (v01, v11) = (v_r0 * fc, v_r1 * fc);
            vrc[k] = [v_r0 - v01, v01, v_r1 - v11, v11];
        }
        // In sample order: each spatial share split between the lower and the upper
        // orientation bin (the first and the last four lanes).
        for k in 0..n {
            // `min`: anchors are within the grid by construction; this keeps a NaN from a
            // broken image from indexing past it.
            let slot = &mut anchors[(anchor[k] as usize).min(na * na * nb - 1)];
            let (v, fo) = (vrc[k], fos[k]);
            let upper = v.map(|vc| vc * fo);
            let (lower_o, upper_o) = slot.split_at_mut(4);
            for ((acc, &vc), &u) in lower_o.iter_mut().zip(&v).zip(&upper) {
                *acc += vc - u;
            }
            for (acc, &u) in upper_o.iter_mut().zip(&upper) {
                *acc += u;
            }
        }
    }
    // Bin (i, j, o) of the inner 4x4 cells gathers lane [do][dr][dc] of anchor
    // (i + 1 - dr, j + 1 - dc, o - do), orientations modulo the bin count.
    let mut v = [0f32; DESCRIPTOR_LEN];
    for i in 0..d {
        for j in 0..d {
            for o in 0..nb {
                // Summed in [dr][dc][do] order.
                v[(i * d + j) * nb + o] = (0..8).fold(0.0, |acc, t| {
                    let (dr, dc, dd) = (t / 4, t / 2 % 2, t % 2);
                    let at = ((i + 1 - dr) * na + j + 1 - dc) * nb + (o + nb - dd) % nb;
                    acc + anchors[at][dd * 4 + dr * 2 + dc]
                });
            }
        }
    }
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    let thr = norm * DESCR_MAG_THR;
    for x in &mut v {
        *x = x.min(thr);
    }
    let norm2 = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    let f = DESCR_INT_FCTR / norm2.max(f32::EPSILON);
    v.map(|x| (x * f + 0.5).min(255.0) as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A region's window starts on the grid of its coarsest octave's stride, which the doc
    /// promises: with a fixed 8-pixel grid, windows 176 px or more across (a fifth halving,
    /// stride 16) started on odd multiples of 8 and their coarsest octave sampled other
    /// pixels than the whole image's.
    #[test]
    fn a_region_window_starts_on_its_coarsest_octaves_grid() {
        let mut widest = 0;
        for upsample in [true, false] {
            let sift = Sift::new(SiftParams {
                upsample,
                ..SiftParams::default()
            });
            for (w, h) in [(160, 120), (640, 480), (1920, 1080), (4000, 3000)] {
                for i in 0..40 {
                    let f = i as f64;
                    let region = BoxRect::new(
                        (f * 37.3) % w as f64,
                        (f * 23.9) % h as f64,
                        5.0 + (f * 71.1) % w as f64,
                        5.0 + (f * 53.7) % h as f64,
                    );
                    let Some([x0, y0, x1, y1]) = sift.region_window(w, h, &region) else {
                        continue;
                    };
                    let coarsest = sift.octave_count(x1 - x0, y1 - y0).saturating_sub(1);
                    let stride = (1usize << coarsest) >> usize::from(upsample);
                    assert!(
                        x0 % stride.max(8) == 0 && y0 % stride.max(8) == 0,
                        "{w}x{h} {region:?}: window from {x0},{y0}, stride {stride}"
                    );
                    // Nothing of the region (grown by the margin, in the image) is cut.
                    let m = f64::from(sift.params.region_margin);
                    assert!(x0 as f64 <= (region.x - m).max(0.0));
                    assert!(y0 as f64 <= (region.y - m).max(0.0));
                    widest = widest.max(stride);
                }
            }
        }
        assert!(widest >= 64, "no window had a coarse octave: {widest}");
    }

    /// A window too large says whether dropping the upsampled first octave would be enough.
    #[test]
    fn a_window_too_large_says_what_would_fit() {
        let p = SiftParams::default();
        let fits = |w, h, p: &SiftParams| match p.check_window(w, h) {
            Err(FeatureError::TooLarge {
                fits_without_upsampling,
                ..
            }) => Some(fits_without_upsampling),
            _ => None,
        };
        assert_eq!(fits(5000, 5000, &p), Some(true));
        assert_eq!(fits(8192, 8192, &p), Some(false));
        let plain = SiftParams {
            upsample: false,
            ..SiftParams::default()
        };
        assert_eq!(fits(8192, 8192, &plain), Some(false));
        assert_eq!(fits(5000, 5000, &plain), None);
        let e = p.check_window(8192, 8192).unwrap_err().to_string();
        assert!(e.ends_with("; detect within a region"), "{e}");
    }

    /// Unchecked settings make the scale-space estimate saturate, not overflow.
    #[test]
    fn the_scale_space_estimate_saturates() {
        let p = SiftParams {
            n_octave_layers: usize::MAX,
            ..SiftParams::default()
        };
        // Saturated at u64::MAX, then 4/3 of it divided down: at least a third of it.
        assert!(p.scale_space_bytes(10, 10) >= u64::MAX / 3);
        assert!(matches!(
            p.check_window(10, 10),
            Err(FeatureError::TooLarge { .. })
        ));
        assert!(SiftParams::default().scale_space_bytes(usize::MAX, usize::MAX) >= u64::MAX / 3);
    }

    #[test]
    fn reflect101_maps_out_of_range() {
        assert_eq!(reflect101(-1, 5), 1);
        assert_eq!(reflect101(-2, 5), 2);
        assert_eq!(reflect101(5, 5), 3);
        assert_eq!(reflect101(6, 5), 2);
        assert_eq!(reflect101(-7, 3), 1);
        assert_eq!(reflect101(9, 1), 0);
        for i in -20..20 {
            assert!(reflect101(i, 2) < 2);
        }
    }

    #[test]
    fn kernel_is_normalised_and_blur_preserves_constants() {
        let k = Kernel::gaussian(1.6);
        let sum = k.half[0] + 2.0 * k.half[1..].iter().sum::<f32>();
        assert!((sum - 1.0).abs() < 1e-6);
        assert_eq!(k.radius(), 7); // round(8 * 1.6 + 1) | 1 = 15 taps
    }

    #[test]
    fn blur_matches_direct_convolution() {
        let (w, h) = (13, 7);
        let src: Vec<f32> = (0..w * h).map(|i| ((i * 37 % 11) as f32) / 11.0).collect();
        let k = Kernel::gaussian(1.2);
        let mut dst = vec![0f32; w * h];
        blur(&src, &mut dst, None, w, h, &k, &mut BlurScratch::default());
        let r = k.radius() as isize;
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0f64;
                for i in -r..=r {
                    for j in -r..=r {
                        let yy = reflect101(y as isize + i, h);
                        let xx = reflect101(x as isize + j, w);
                        acc += f64::from(k.half[i.unsigned_abs()] * k.half[j.unsigned_abs()])
                            * f64::from(src[yy * w + xx]);
                    }
                }
                assert!((acc as f32 - dst[y * w + x]).abs() < 1e-5, "{x},{y}");
            }
        }
    }

    #[test]
    fn upsample_keeps_input_pixels_on_even_positions() {
        let src = vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let (up, w2, h2) = upsample2(&src, 3, 2);
        assert_eq!((w2, h2), (6, 4));
        assert_eq!(up[0], 0.0);
        assert_eq!(up[2], 1.0);
        assert_eq!(up[1], 0.5);
        assert_eq!(up[5], 2.0); // replicated edge
        assert_eq!(up[2 * w2 + 2], 4.0);
        assert_eq!(up[w2 + 1], 0.5 * (0.5 + 3.5));
        assert_eq!(up[3 * w2 + 4], 5.0);
    }

    #[test]
    fn quarter_shift_upsample_samples_a_quarter_pixel_back() {
        // A linear ramp v = 2x + 10y: sampling at (u/2 − 1/4, r/2 − 1/4) gives exactly
        // u − 0.5 + 5r − 2.5 inside; edges replicate the border pixel.
        let (w, h) = (5, 4);
        let src: Vec<f32> = (0..w * h)
            .map(|i| (2 * (i % w) + 10 * (i / w)) as f32)
            .collect();
        let (up, w2, h2) = upsample2_quarter_shift(&src, w, h);
        assert_eq!((w2, h2), (10, 8));
        for r in 1..h2 - 1 {
            for u in 1..w2 - 1 {
                let want = u as f32 - 0.5 + 5.0 * r as f32 - 2.5;
                assert!((up[r * w2 + u] - want).abs() < 1e-4, "{u},{r}");
            }
        }
        // Corner: all four taps clamp to pixel (0, 0).
        assert_eq!(up[0], 0.0);
        // The exact grid keeps input pixel x at 2x instead.
        let (ex, _, _) = upsample2(&src, w, h);
        assert_eq!(ex[2 * w2 + 4], src[w + 2]);
    }

    /// Runs `f` in a rayon pool of `n` threads.
    fn on_threads<R: Send>(n: usize, f: impl FnOnce() -> R + Send) -> R {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(f)
    }

    #[test]
    fn the_two_row_vertical_pass_is_the_one_row_pass_bit_for_bit() {
        // Widths with 16-, 8- and 1-wide column blocks, odd and even row counts, kernels as
        // wide as the image is tall; bands starting at odd rows.
        for (w, h, sigma) in [(37, 11, 0.8), (40, 23, 1.6), (53, 30, 3.1)] {
            let tmp: Vec<f32> = (0..w * h)
                .map(|i| ((i * 53 % 97) as f32) / 97.0 - 0.3)
                .collect();
            let k = Kernel::gaussian(sigma);
            let r = k.radius();
            assert!(r < h);
            let mut want = vec![0f32; w * h];
            for (y, out) in want.chunks_exact_mut(w).enumerate() {
                let row = |i: isize| {
                    let o = reflect101(y as isize + i, h) * w;
                    &tmp[o..o + w]
                };
                conv_row(
                    &k.half,
                    row(0),
                    |i| (row(-(i as isize)), row(i as isize)),
                    out,
                );
            }
            for y0 in [0, 1, 4] {
                let mut got = vec![0f32; (h - y0) * w];
                blur_rows_v(&tmp, &mut got, w, h, y0, &k.half, r, &mut Vec::new());
                assert!(
                    got == want[y0 * w..],
                    "{w}x{h}, sigma {sigma}, from row {y0}"
                );
            }
        }
    }

    #[test]
    fn a_blur_and_its_difference_by_bands_are_those_on_one_thread() {
        // Large enough to be cut into bands, with rows that do not divide evenly.
        let (w, h) = (131, 97);
        assert!(w * h >= PARALLEL_MIN_PIXELS);
        let src: Vec<f32> = (0..w * h)
            .map(|i| ((i * 37 % 101) as f32) / 101.0)
            .collect();
        let k = Kernel::gaussian(2.3);
        let run = |n| {
            on_threads(n, || {
                assert_eq!(parallel_bands(w, h), n);
                let (mut dst, mut dog) = (vec![0f32; w * h], vec![f32::NAN; w * h]);
                blur(
                    &src,
                    &mut dst,
                    Some(&mut dog),
                    w,
                    h,
                    &k,
                    &mut BlurScratch::default(),
                );
                let mut alone = vec![0f32; w * h];
                blur(
                    &src,
                    &mut alone,
                    None,
                    w,
                    h,
                    &k,
                    &mut BlurScratch::default(),
                );
                assert!(alone == dst, "the difference changed the blur on {n} bands");
                (dst, dog)
            })
        };
        let (one, one_dog) = run(1);
        // The difference is the blurred image less the source, on every pixel.
        for ((d, b), a) in one_dog.iter().zip(&one).zip(&src) {
            assert_eq!(d.to_bits(), (b - a).to_bits());
        }
        for n in [2, 3, 5] {
            let (dst, dog) = run(n);
            assert!(dst == one, "{n} bands differ from one");
            assert!(dog == one_dog, "{n} bands' differences differ from one");
        }
    }

    #[test]
    fn extremum_flags_match_a_naive_27_neighbour_test() {
        let mut scratch = ExtremaScratch::default();
        // Small whole values make ties (which count as extrema) and plateaus common; widths
        // around the vector lengths exercise the loops' tails.
        for (w, h, levels) in [(17, 13, 5), (23, 12, 3), (40, 14, 7), (13, 16, 4)] {
            let layer = |l: usize| -> Vec<f32> {
                (0..w * h)
                    .map(|i| ((i * 7919 + l * 104_729) % 97 % levels) as f32 - (levels / 2) as f32)
                    .collect()
            };
            let layers = [layer(0), layer(1), layer(2)];
            let refs = [&layers[0][..], &layers[1], &layers[2]];
            let thr = 0.5;
            let mut candidates = 0;
            for r in IMG_BORDER..h - IMG_BORDER {
                let flags = extremum_flags(refs, w, r, thr, &mut scratch).to_vec();
                assert_eq!(flags.len(), w - 2 * IMG_BORDER);
                for (k, &f) in flags.iter().enumerate() {
                    let c = IMG_BORDER + k;
                    let x = layers[1][r * w + c];
                    let nb =
                        (0..27).map(|i| layers[i / 9][(r + i / 3 % 3 - 1) * w + c + i % 3 - 1]);
                    let is_max = x > thr && nb.clone().all(|v| x >= v);
                    let is_min = x < -thr && nb.clone().all(|v| x <= v);
                    assert_eq!(f != 0, is_max || is_min, "{w}x{h}, row {r}, column {c}");
                    candidates += usize::from(f != 0);
                }
            }
            assert!(
                candidates > 0,
                "{w}x{h}: the case has no candidate to check"
            );
        }
    }

    /// [`descriptor`] written the plain way: every pixel of the window, its rotated cell
    /// coordinates tested one by one, trilinear weights added straight into a padded
    /// histogram in f64, the exact `atan2`.
    fn descriptor_reference(
        img: &[f32],
        (w, h): (usize, usize),
        (xo, yo): (f32, f32),
        sigma: f32,
        angle: f32,
    ) -> [u8; DESCRIPTOR_LEN] {
        let (d, nb) = (DESCR_WIDTH, DESCR_BINS);
        let df = d as f64;
        let hw = f64::from(DESCR_SCL_FCTR * sigma);
        let radius = (hw * std::f64::consts::SQRT_2 * (df + 1.0) * 0.5).round() as isize;
        let (sin_t, cos_t) = f64::from(angle).sin_cos();
        let (ci, ri) = (xo.round() as isize, yo.round() as isize);
        let mut hist = vec![0f64; (d + 2) * (d + 2) * nb];
        for y in (ri - radius).max(1)..=(ri + radius).min(h as isize - 2) {
            for x in (ci - radius).max(1)..=(ci + radius).min(w as isize - 2) {
                let (dx, dy) = (x as f64 - f64::from(xo), y as f64 - f64::from(yo));
                let rbin = (dy * cos_t - dx * sin_t) / hw + df / 2.0 - 0.5;
                let cbin = (dy * sin_t + dx * cos_t) / hw + df / 2.0 - 0.5;
                if !(rbin > -1.0 && rbin < df && cbin > -1.0 && cbin < df) {
                    continue;
                }
                let at = |x: isize, y: isize| f64::from(img[y as usize * w + x as usize]);
                let (gx, gy) = (at(x + 1, y) - at(x - 1, y), at(x, y + 1) - at(x, y - 1));
                let weight = (-(dx * dx + dy * dy) / (0.5 * df * df * hw * hw)).exp();
                let mag = gx.hypot(gy) * weight;
                let tau = std::f64::consts::TAU;
                let ori = (gy.atan2(gx) - f64::from(angle)).rem_euclid(tau) * nb as f64 / tau;
                let (r0, c0, o0) = (rbin.floor(), cbin.floor(), ori.floor());
                let (fr, fc, fo) = (rbin - r0, cbin - c0, ori - o0);
                for (dr, wr) in [(0, 1.0 - fr), (1, fr)] {
                    for (dc, wc) in [(0, 1.0 - fc), (1, fc)] {
                        for (dd, wo) in [(0, 1.0 - fo), (1, fo)] {
                            let r = (r0 as isize + 1 + dr) as usize;
                            let c = (c0 as isize + 1 + dc) as usize;
                            let o = (o0 as usize + dd) % nb;
                            hist[(r * (d + 2) + c) * nb + o] += mag * wr * wc * wo;
                        }
                    }
                }
            }
        }
        let mut v = [0f64; DESCRIPTOR_LEN];
        for i in 0..d {
            for j in 0..d {
                let base = ((i + 1) * (d + 2) + j + 1) * nb;
                v[(i * d + j) * nb..][..nb].copy_from_slice(&hist[base..base + nb]);
            }
        }
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let v = v.map(|x| x.min(norm * f64::from(DESCR_MAG_THR)));
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        v.map(|x| (x * f64::from(DESCR_INT_FCTR) / norm).round().min(255.0) as u8)
    }

    #[test]
    fn descriptor_matches_the_plain_trilinear_histogram() {
        let (w, h) = (72, 64);
        let img: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                0.5 + 0.2 * (0.31 * x + 0.17 * y).sin() * (0.23 * y - 0.11 * x).cos()
                    + 0.1 * (0.07 * x * y / 8.0).sin()
            })
            .collect();
        let mut scratch = GradScratch::default();
        // Orientations on both sides of the wrap at 0 and 2π, off-grid positions, scales
        // whose windows reach past the image edge.
        for (xo, yo, sigma, angle) in [
            (36.3, 31.7, 1.6, 0.0),
            (35.0, 30.0, 2.2, 0.001),
            (30.6, 33.2, 1.9, TAU - 0.001),
            (40.1, 28.9, 2.7, 1.0),
            (20.5, 25.5, 3.3, 4.0),
            (8.2, 9.7, 2.0, 2.5),
        ] {
            let got = descriptor(&img, w, h, xo, yo, sigma, angle, &mut scratch);
            let want = descriptor_reference(&img, (w, h), (xo, yo), sigma, angle);
            let worst = got.iter().zip(&want).map(|(a, b)| a.abs_diff(*b)).max();
            let total: u32 = got
                .iter()
                .zip(&want)
                .map(|(a, b)| u32::from(a.abs_diff(*b)))
                .sum();
            // Equal but for float rounding (f32 against f64, the polynomial arctangent).
            assert!(
                worst <= Some(1) && total <= 8,
                "{xo},{yo} σ {sigma} θ {angle}: {got:?} vs {want:?}"
            );
            assert!(
                want.iter().filter(|&&v| v > 0).count() > 64,
                "a textured window"
            );
        }
    }

    #[test]
    fn fast_atan2_is_accurate() {
        for k in 0..720 {
            let t = k as f32 * TAU / 720.0 + 0.001;
            let (y, x) = (t.sin() * 3.0, t.cos() * 3.0);
            let want = y.atan2(x).rem_euclid(TAU);
            let got = fast_atan2(y, x);
            let diff = (got - want).abs().min(TAU - (got - want).abs());
            assert!(diff < 2e-5, "{t}: {got} vs {want}");
        }
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
    }

    #[test]
    fn whole_to_u32_is_exact_for_whole_numbers() {
        for v in (0..1000).chain([8_388_607]) {
            assert_eq!(whole_to_u32(v as f32), v);
        }
        // Anything else stays below 2^23 (callers clamp it to their range).
        for v in [f32::NAN, -1.0, 1e9, f32::INFINITY] {
            assert!(whole_to_u32(v) < 1 << 23);
        }
    }

    #[test]
    fn a_full_pool_keeps_the_latest_buffer() {
        Sift::release_thread_buffers();
        for _ in 0..POOL_MAX {
            recycle(vec![0.0; 100]);
        }
        recycle(vec![1.0f32; 100_000]);
        // A tracker's next frame asks for about the same size again: it must get that buffer
        // back (its stale values show it), not fresh zeroed pages.
        let again = take_buf(90_000);
        assert_eq!(again.len(), 90_000);
        assert!(again.iter().all(|&x| x == 1.0));
        Sift::release_thread_buffers();
    }

    #[test]
    fn solve3_solves_and_rejects_singular() {
        let h = [[2.0, 0.5, 0.0], [0.5, 3.0, 0.1], [0.0, 0.1, 1.0]];
        let x_true = [0.3f32, -0.2, 0.1];
        let g: [f32; 3] =
            std::array::from_fn(|i| -(0..3).map(|j| h[i][j] * x_true[j]).sum::<f32>());
        let x = solve3(&h, &g).unwrap();
        for i in 0..3 {
            assert!((x[i] - x_true[i]).abs() < 1e-5);
        }
        assert!(solve3(&[[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]], &g).is_none());
    }
}
