//! Adaptive block matching (SPEC section 3): the 2D translation and scale change of the target
//! between frame `t − 1` and frame `t`.
//!
//! 1. The previous target region (an ellipse in frame `t − 1`) is tiled with square blocks of
//!    [`AbmParams::block_size`] on a grid anchored at the region's bounding box; a block is
//!    kept when its centre lies inside the ellipse, and clipped to the frame.
//! 2. Each block is matched by the sum of absolute differences (SAD, on 8-bit quantised luma)
//!    at every integer displacement within ±[`AbmParams::search_radius`] in frame `t`
//!    (positions that leave the frame are skipped).
//! 3. A block is rejected when its texture is flat (mean absolute deviation below
//!    [`AbmParams::min_texture`]), its best SAD per pixel exceeds [`AbmParams::max_sad`], or
//!    the match is ambiguous (the best SAD is not below [`AbmParams::ambiguity_ratio`] times
//!    the best SAD outside the 3x3 neighbourhood of the best displacement). A rejected block
//!    is split into four and each quarter whose centre is inside the ellipse is retried, down
//!    to [`AbmParams::min_block`].
//! 4. Matched blocks whose displacement disagrees with the median displacement by more than a
//!    similarity motion could explain are outliers. The inliers, placed at their matched
//!    positions in frame `t`, form the mask ([`AbmResult::mask`]).
//! 5. The mask's boundary is represented by the centres of its boundary blocks (blocks
//!    touching a pixel the region's blocks do not cover). An ellipse is fitted by least
//!    squares ([`fit_ellipse`]) to these centres at their matched positions and, for
//!    reference, at their original positions. The difference of the two centres is the
//!    translation and the square root of the area ratio the (isotropic) scale change; the new
//!    ellipse is the region moved and scaled by them (orientation kept). Where the fitted
//!    centre `f` is not the region's `r` (a region clipped by the frame's edge, a mask with
//!    blocks missing), a true similarity of scale `s` moves `r` by `(s − 1)(r − f)` more than
//!    `f`; moving it so (2026-12-06, a throwaway build) put a clipped region's centre 0.45 px
//!    from the truth on average instead of 1.0 px under a 8-20 % scale change, but the scale
//!    read on a turning box is not a similarity's, and the synthetic `car`'s pan went from 9.1
//!    to 10.6 degrees (two seeds of twelve 6.5-6.8 degrees worse): the fitted centre's own
//!    shift does not carry the scale's error, and stays.
//!
//! Why block centres and not the pixel outline of the union of blocks: blocks move rigidly, so
//! under a scale change `s` the outline of the union grows by `s·r + h` instead of `s·(r + h)`
//! (`h` half a block) and underestimates the scale. Centres move exactly with the motion, and
//! fitting the same set of blocks before and after makes the estimate exact for any
//! translation and similarity (the direct fit commutes with similarities) whatever the shape
//! of the block set.
//!
//! Displacements are whole pixels. Refining each block's to a fraction of a pixel
//! (equiangular line fitting of the SADs about the best displacement, with the neighbours'
//! SADs taken over the same pixel pairs so that whole-pixel shifts stay exact) measured a
//! smooth texture's shifts of 0.1-3.8 px to within 0.05 px, but made the tracker worse
//! (2026-12-05, `scripts/eval_seeds.sh synth`, per-axis RMSE summed over the six scenarios:
//! 43.5 -> 44.8, `pan` about y 2.31 -> 2.85, `combo` 2.66 / 2.91 / 2.30 -> 2.99 / 2.98 /
//! 2.41; with the refined translation in the proposal and the whole-pixel one for the
//! keyframe fits' centre prior, 44.3). The translation is where the keyframe fits' centre is
//! held ([`crate::tracker::TrackerConfig::fit_centre_sigma`]): a head turning in place
//! slides its texture by a fraction of a pixel a frame, which the refined blocks follow and
//! the whole-pixel ones round to the head's true, unmoved centre. Holding the fits to the
//! previous centre (no shift at all) or to the estimate's last step gave 44.9 and 45.6.
//!
//! When the fit is degenerate (too few boundary blocks, collinear centres) or implausible
//! (scale change beyond [`AbmParams::max_scale_change`], centre far from the median block
//! displacement), the result falls back to the median block displacement with scale 1 and
//! says why in [`AbmResult::fallback`].

use super::MotionError;
use super::fit::fit_ellipse;
use crate::frames::GrayF32;
use crate::geometry::Ellipse;

/// Parameters of [`block_match`].
///
/// The defaults suit a target about 40 px across (the paper's Girl head at 128x96):
/// 8-px blocks split down to 4 px, a ±10 px search. [`AbmParams::for_target`] scales the
/// block sizes and the search radius with the target's size; the intensity thresholds
/// (`max_sad`, `min_texture`, `ambiguity_ratio`) are per pixel and do not depend on it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AbmParams {
    /// Side of the initial blocks (pixels).
    pub block_size: u32,
    /// Smallest block side a split may produce (pixels, ≥ 2).
    pub min_block: u32,
    /// Largest displacement searched along each axis (pixels).
    pub search_radius: u32,
    /// Largest accepted mean absolute difference per pixel, luma in `[0, 1]`
    /// (0.08 ≈ 20 grey levels: tolerates JPEG noise and small deformation).
    pub max_sad: f32,
    /// Smallest mean absolute deviation of a block's luma from its mean for it to be matched
    /// at all (0.012 ≈ 3 grey levels); flatter blocks cannot be located.
    pub min_texture: f32,
    /// The best SAD must be at most this fraction of the best SAD outside the 3x3
    /// neighbourhood of the best displacement (0.8).
    pub ambiguity_ratio: f32,
    /// Largest plausible scale change per frame (1.3: the fit is rejected outside
    /// `[1/1.3, 1.3]`).
    pub max_scale_change: f64,
    /// Largest plausible distance (pixels, plus a quarter of the region's mean semi-axis)
    /// between the fitted centre's translation and the median block displacement (2.0).
    pub max_centre_disagreement: f64,
    /// Fewest boundary blocks for the ellipse fit (≥ 5; 6 by default).
    pub min_fit_blocks: usize,
}

impl Default for AbmParams {
    fn default() -> Self {
        Self {
            block_size: 8,
            min_block: 4,
            search_radius: 10,
            max_sad: 0.08,
            min_texture: 0.012,
            ambiguity_ratio: 0.8,
            max_scale_change: 1.3,
            max_centre_disagreement: 2.0,
            min_fit_blocks: 6,
        }
    }
}

impl AbmParams {
    /// The defaults scaled to the target `region` ([`AbmParams::scaled_to`]): block `8k`
    /// (even, 4..=32), smallest block `max(4, block/4)` (when that is below the block),
    /// search radius `10k` (4..=48), with `k` the target's mean diameter `a + b` over 40 px.
    pub fn for_target(region: &Ellipse) -> Self {
        Self::default().scaled_to(region)
    }

    /// These settings, whose sizes are for a target 40 px across, scaled to the target
    /// `region` by `k`, its mean diameter `a + b` over 40 px (1 for a degenerate region): the
    /// block side `block_size · k` rounded to an even number and kept from
    /// `max(min_block, block_size / 2)` to `4 · block_size`; the smallest block a quarter of
    /// that, but not below `min_block` nor above the block; the search radius
    /// `search_radius · k` kept from 2/5 to 24/5 of `search_radius` (at least 1); every size
    /// at most 256. The thresholds are per pixel and carried over as they are. The defaults
    /// give blocks of 4-32 px, split down to 4 px, and a search of ±4-48 px.
    pub fn scaled_to(&self, region: &Ellipse) -> Self {
        let d = region.a.abs() + region.b.abs();
        let k = if d.is_finite() && d > 0.0 {
            d / 40.0
        } else {
            1.0
        };
        // Every bound is kept `lo <= hi` whatever the settings, so that settings `check`
        // refuses scale without a panic too (`check` then names what is wrong).
        let lo = self.min_block.max(self.block_size / 2);
        let hi = self.block_size.saturating_mul(4).clamp(lo, 256.max(lo));
        let half = (f64::from(self.block_size) * k / 2.0).round() as u32;
        let block = half.saturating_mul(2).clamp(lo, hi);
        let r = self.search_radius;
        let r_hi = (r.saturating_mul(24) / 5).clamp(1, 256);
        let r_lo = (r.saturating_mul(2) / 5).clamp(1, r_hi);
        let radius = ((f64::from(r) * k).round() as u32).clamp(r_lo, r_hi);
        Self {
            block_size: block,
            min_block: (block / 4).max(self.min_block).min(block),
            search_radius: radius,
            ..*self
        }
    }

    /// Checks the settings, as [`block_match`] does: `2 <= min_block <= block_size <= 256`,
    /// a search radius of at most 256, finite thresholds with `ambiguity_ratio` in `(0, 1]`,
    /// `max_scale_change >= 1` and `max_centre_disagreement >= 0`, and at least 5 blocks for
    /// the ellipse fit.
    pub fn check(&self) -> Result<(), MotionError> {
        if self.min_block < 2 || self.block_size < self.min_block {
            return Err(MotionError::InvalidParams(
                "need 2 <= min_block <= block_size",
            ));
        }
        if self.block_size > 256 || self.search_radius > 256 {
            return Err(MotionError::InvalidParams(
                "block_size and search_radius must be at most 256",
            ));
        }
        let ok = self.max_sad.is_finite()
            && self.min_texture.is_finite()
            && self.ambiguity_ratio > 0.0
            && self.ambiguity_ratio <= 1.0
            && self.max_scale_change >= 1.0
            && self.max_scale_change.is_finite()
            && self.max_centre_disagreement >= 0.0
            && self.max_centre_disagreement.is_finite();
        if !ok {
            return Err(MotionError::InvalidParams(
                "thresholds must be finite, ambiguity_ratio in (0, 1], max_scale_change >= 1",
            ));
        }
        if self.min_fit_blocks < 5 {
            return Err(MotionError::InvalidParams(
                "min_fit_blocks must be at least 5",
            ));
        }
        Ok(())
    }
}

/// What became of one block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockStatus {
    /// Matched and consistent with the other blocks: part of the mask.
    Matched,
    /// Too little texture to be located.
    Flat,
    /// The best SAD per pixel exceeds the threshold.
    Poor,
    /// The best match is not clearly better than the second best.
    Ambiguous,
    /// No displacement within the search radius keeps the block inside the frame.
    NoRoom,
    /// Matched, but its displacement disagrees with the other blocks.
    Outlier,
}

/// One block (a leaf of the splitting) and its match.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlockMatch {
    /// Left column of the block in frame `t − 1`.
    pub x: i32,
    /// Top row of the block in frame `t − 1`.
    pub y: i32,
    /// Width (pixels; less than the block size where clipped by the frame).
    pub w: u32,
    /// Height (pixels).
    pub h: u32,
    /// Best displacement found (pixels; meaningful unless the status is `Flat` or `NoRoom`).
    pub dx: i32,
    /// Best displacement found, y.
    pub dy: i32,
    /// Best mean absolute difference per pixel (luma in `[0, 1]`; infinite when unmatched).
    pub sad: f32,
    /// Outcome.
    pub status: BlockStatus,
    /// Whether the block lies on the boundary of the region's blocks (used by the fit).
    pub boundary: bool,
}

impl BlockMatch {
    /// Centre of the block in frame `t − 1` (pixel-centre coordinates).
    pub fn centre(&self) -> [f64; 2] {
        [
            self.x as f64 + (self.w as f64 - 1.0) / 2.0,
            self.y as f64 + (self.h as f64 - 1.0) / 2.0,
        ]
    }
}

/// Why [`block_match`] fell back to the median displacement (scale 1) instead of the fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fallback {
    /// No block matched: the translation is zero, the scale 1.
    NoMatchedBlocks,
    /// Fewer boundary blocks matched than [`AbmParams::min_fit_blocks`].
    TooFewBoundaryBlocks,
    /// The ellipse fit failed (collinear or coincident block centres).
    DegenerateFit,
    /// The fitted scale change exceeds [`AbmParams::max_scale_change`].
    ImplausibleScale,
    /// The fitted translation is far from the median block displacement.
    CentreFarOff,
}

/// The motion of the target between two frames.
#[derive(Debug, Clone, PartialEq)]
pub struct AbmResult {
    /// The target region in frame `t`.
    pub ellipse: Ellipse,
    /// Translation of the centre (pixels).
    pub translation: [f64; 2],
    /// Isotropic scale change (new size / old size).
    pub scale: f64,
    /// Every leaf block with its match.
    pub blocks: Vec<BlockMatch>,
    /// Fraction of the region's block area that matched (inliers), in `[0, 1]`.
    pub matched_fraction: f64,
    /// Component-wise median displacement of the matched blocks (zero when none matched).
    pub median_displacement: [f64; 2],
    /// `Some(reason)` when the result is the median displacement with scale 1 rather than
    /// the ellipse fit of the mask.
    pub fallback: Option<Fallback>,
}

impl AbmResult {
    /// Whether the translation and scale come from the ellipse fit of the mask.
    pub fn is_fitted(&self) -> bool {
        self.fallback.is_none()
    }

    /// The mask in frame `t`: the matched blocks at their matched positions, rasterised into
    /// a `width × height` row-major array (1 inside, 0 outside).
    pub fn mask(&self, width: u32, height: u32) -> Vec<u8> {
        let (wi, hi) = (width as i64, height as i64);
        let mut m = vec![0u8; width as usize * height as usize];
        for b in self
            .blocks
            .iter()
            .filter(|b| b.status == BlockStatus::Matched)
        {
            let x0 = (b.x as i64 + b.dx as i64).max(0);
            let y0 = (b.y as i64 + b.dy as i64).max(0);
            let x1 = (b.x as i64 + b.dx as i64 + b.w as i64).min(wi);
            let y1 = (b.y as i64 + b.dy as i64 + b.h as i64).min(hi);
            for y in y0..y1 {
                for x in x0..x1 {
                    m[(y * wi + x) as usize] = 1;
                }
            }
        }
        m
    }
}

/// An 8-bit copy of a rectangular window of a grey image.
struct Window {
    x0: i64,
    y0: i64,
    w: i64,
    h: i64,
    data: Vec<u8>,
    /// Summed-area table, `(w + 1) × (h + 1)`: `sat[(y + 1)(w + 1) + x + 1]` is the sum of
    /// the pixels above and left of `(x, y)` inclusive, modulo 2^32. A window of more than
    /// 16.8 million bright pixels passes 2^32, but the sums taken from it are of blocks (at
    /// most 256 x 256 x 255, under 2^24), which modular arithmetic gives exactly.
    sat: Vec<u32>,
}

impl Window {
    /// The window `[x0, x1) × [y0, y1)` clipped to the image, quantised to 8 bits.
    fn new(img: &GrayF32, x0: i64, y0: i64, x1: i64, y1: i64) -> Self {
        let x0 = x0.clamp(0, img.width as i64);
        let y0 = y0.clamp(0, img.height as i64);
        let x1 = x1.clamp(x0, img.width as i64);
        let y1 = y1.clamp(y0, img.height as i64);
        let (w, h) = (x1 - x0, y1 - y0);
        let mut data = Vec::with_capacity((w * h) as usize);
        for y in y0..y1 {
            let row = &img.data
                [(y * img.width as i64 + x0) as usize..(y * img.width as i64 + x1) as usize];
            data.extend(row.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8));
        }
        let sw = (w + 1) as usize;
        let mut sat = vec![0u32; sw * (h + 1) as usize];
        for y in 0..h as usize {
            let mut run = 0u32;
            for x in 0..w as usize {
                run = run.wrapping_add(data[y * w as usize + x] as u32);
                sat[(y + 1) * sw + x + 1] = sat[y * sw + x + 1].wrapping_add(run);
            }
        }
        Self {
            x0,
            y0,
            w,
            h,
            data,
            sat,
        }
    }

    /// Sum of the pixels of the rectangle `x, y, w, h` (image coordinates, inside), exact
    /// when under 2^32 (the table wraps; see [`Window::sat`]).
    fn box_sum(&self, x: i64, y: i64, w: i64, h: i64) -> u32 {
        let sw = self.w + 1;
        let (x, y) = (x - self.x0, y - self.y0);
        let i = |xx: i64, yy: i64| self.sat[(yy * sw + xx) as usize];
        i(x + w, y + h)
            .wrapping_add(i(x, y))
            .wrapping_sub(i(x, y + h))
            .wrapping_sub(i(x + w, y))
    }

    /// Whether the rectangle `x, y, w, h` (image coordinates) lies inside the window.
    #[cfg(test)]
    fn holds(&self, x: i64, y: i64, w: i64, h: i64) -> bool {
        x >= self.x0 && y >= self.y0 && x + w <= self.x0 + self.w && y + h <= self.y0 + self.h
    }

    /// Offset of image pixel `(x, y)` in `data` (must be inside).
    fn offset(&self, x: i64, y: i64) -> usize {
        ((y - self.y0) * self.w + (x - self.x0)) as usize
    }
}

/// SAD of two rows of length `W` (`W > 0`, checked by the caller) or of the common length
/// (`W = 0`). The fixed-width form compiles to `psadbw` on x86-64 (SSE2).
#[inline(always)]
fn row_sad<const W: usize>(a: &[u8], b: &[u8]) -> u32 {
    if W > 0
        && let (Some(a), Some(b)) = (a.first_chunk::<W>(), b.first_chunk::<W>())
    {
        // max − min on bytes, then a widening sum.
        let mut d = [0u8; W];
        for ((d, &p), &q) in d.iter_mut().zip(a).zip(b) {
            *d = p.max(q) - p.min(q);
        }
        return d.iter().map(|&v| v as u32).sum();
    }
    a.iter().zip(b).map(|(&p, &q)| p.abs_diff(q) as u32).sum()
}

/// SAD of a contiguous `w × h` block against the window at offset `off`, row by row; stops
/// as soon as the partial sum exceeds `bound` and returns it (a value `> bound`, a lower
/// bound of the full SAD), so the result is exact whenever it is `<= bound`.
#[inline(always)]
fn sad<const W: usize>(
    block: &[u8],
    w: usize,
    h: usize,
    win: &[u8],
    off: usize,
    stride: usize,
    bound: u32,
) -> u32 {
    let mut s = 0u32;
    for r in 0..h {
        let o = off + r * stride;
        s += row_sad::<W>(&block[r * w..r * w + w], &win[o..o + w]);
        if s > bound {
            return s;
        }
    }
    s
}

/// Mean absolute deviation from the mean, in 8-bit units.
fn texture(block: &[u8]) -> f32 {
    let n = block.len().max(1) as f32;
    let mean = block.iter().map(|&v| v as u32).sum::<u32>() as f32 / n;
    block.iter().map(|&v| (v as f32 - mean).abs()).sum::<f32>() / n
}

/// A block to be matched.
#[derive(Clone, Copy)]
struct Cell {
    x: i64,
    y: i64,
    w: i64,
    h: i64,
}

/// Reusable buffers of [`match_cell`].
#[derive(Default)]
struct Scratch {
    block: Vec<u8>,
    /// Per displacement: the exact SAD, or a lower bound of it where pass 1 stopped early.
    lower: Vec<u32>,
}

/// Matches one cell; returns (dx, dy, sad per pixel in [0,1], status) with status one of
/// Matched, Flat, Poor, Ambiguous, NoRoom.
///
/// Gives exactly the result of an exhaustive search, with early termination (successive
/// elimination by block sums, then SAD row by row against the bound):
/// pass 1 finds the best displacement (ties to the smaller `|dx| + |dy|`, then raster
/// order), starting from `hint` (the previous block's displacement) so the bound is tight
/// early, and records for every displacement its SAD or the lower bound where it stopped.
/// Unless the best is already poor or perfect, pass 2 looks outside the 3x3 neighbourhood of
/// the best for a displacement whose SAD is below `best / ambiguity_ratio`, re-examining only
/// those whose recorded lower bound does not already exclude it, and stops at the first.
fn match_cell(
    c: &Cell,
    prev: &Window,
    cur: &Window,
    p: &AbmParams,
    scratch: &mut Scratch,
    hint: (i64, i64),
) -> (i32, i32, f32, BlockStatus) {
    match c.w {
        4 => match_cell_w::<4>(c, prev, cur, p, scratch, hint),
        8 => match_cell_w::<8>(c, prev, cur, p, scratch, hint),
        16 => match_cell_w::<16>(c, prev, cur, p, scratch, hint),
        32 => match_cell_w::<32>(c, prev, cur, p, scratch, hint),
        _ => match_cell_w::<0>(c, prev, cur, p, scratch, hint),
    }
}

/// [`match_cell`] for blocks `W` pixels wide (`W = 0`: any width).
fn match_cell_w<const W: usize>(
    c: &Cell,
    prev: &Window,
    cur: &Window,
    p: &AbmParams,
    scratch: &mut Scratch,
    hint: (i64, i64),
) -> (i32, i32, f32, BlockStatus) {
    let (w, h) = (c.w as usize, c.h as usize);
    let buf = &mut scratch.block;
    buf.clear();
    for r in 0..c.h {
        let o = prev.offset(c.x, c.y + r);
        buf.extend_from_slice(&prev.data[o..o + w]);
    }
    let npx = (w * h) as f32;
    if texture(buf) < p.min_texture * 255.0 {
        return (0, 0, f32::INFINITY, BlockStatus::Flat);
    }
    let buf: &[u8] = buf;
    let r = p.search_radius as i64;
    let stride = cur.w as usize;
    // Displacements that keep the block inside the window (= the frame, clipped).
    let dxl = (-r).max(cur.x0 - c.x);
    let dxh = r.min(cur.x0 + cur.w - c.w - c.x);
    let dyl = (-r).max(cur.y0 - c.y);
    let dyh = r.min(cur.y0 + cur.h - c.h - c.y);
    if dxl > dxh || dyl > dyh {
        return (0, 0, f32::INFINITY, BlockStatus::NoRoom);
    }
    let nx = (dxh - dxl + 1) as usize;
    let data = &cur.data[..];
    let at = |dx: i64, dy: i64| cur.offset(c.x + dx, c.y + dy);
    let lower = &mut scratch.lower;
    lower.clear();
    lower.resize(nx * (dyh - dyl + 1) as usize, 0);
    // Pass 1: the best displacement. Order key: (SAD, |dx| + |dy|, dy, dx).
    let key = |s: u32, dx: i64, dy: i64| (s, dx.abs() + dy.abs(), dy, dx);
    let mut best = (u32::MAX, i64::MAX, 0i64, 0i64);
    if (dxl..=dxh).contains(&hint.0) && (dyl..=dyh).contains(&hint.1) {
        let s = sad::<W>(buf, w, h, data, at(hint.0, hint.1), stride, u32::MAX);
        best = key(s, hint.0, hint.1);
    }
    // Successive elimination: |Σ block − Σ window| ≤ SAD, from the summed-area table, rules
    // out most displacements without touching their pixels.
    let block_sum = buf.iter().map(|&v| v as u32).sum::<u32>();
    for (j, dy) in (dyl..=dyh).enumerate() {
        let row = at(dxl, dy);
        let lrow = &mut lower[j * nx..(j + 1) * nx];
        for (i, dx) in (dxl..=dxh).enumerate() {
            let lb = block_sum.abs_diff(cur.box_sum(c.x + dx, c.y + dy, c.w, c.h));
            if lb > best.0 {
                lrow[i] = lb;
                continue;
            }
            let s = sad::<W>(buf, w, h, data, row + i, stride, best.0);
            lrow[i] = s;
            if s <= best.0 {
                let k = key(s, dx, dy);
                if k < best {
                    best = k;
                }
            }
        }
    }
    let (bdx, bdy) = (best.3, best.2);
    let per_px = best.0 as f32 / (255.0 * npx);
    if per_px > p.max_sad {
        return (bdx as i32, bdy as i32, per_px, BlockStatus::Poor);
    }
    // Pass 2: is some displacement outside the best's neighbourhood nearly as good?
    // Ambiguous iff best > ratio · second, i.e. second < best / ratio.
    if best.0 > 0 {
        let limit = best.0 as f32 / p.ambiguity_ratio;
        let bound = limit.min(u32::MAX as f32 / 2.0) as u32 + 1;
        let qualifies = |s: u32| best.0 as f32 > p.ambiguity_ratio * s as f32;
        for (j, dy) in (dyl..=dyh).enumerate() {
            let row = at(dxl, dy);
            for (i, dx) in (dxl..=dxh).enumerate() {
                if (dx - bdx).abs() <= 1 && (dy - bdy).abs() <= 1 {
                    continue;
                }
                // The recorded value is exact or a lower bound: only an exact value, or a
                // bound that does not rule the displacement out, needs a look.
                let l = lower[j * nx + i];
                if !qualifies(l) {
                    continue;
                }
                let s = sad::<W>(buf, w, h, data, row + i, stride, bound);
                if qualifies(s) {
                    return (bdx as i32, bdy as i32, per_px, BlockStatus::Ambiguous);
                }
            }
        }
    }
    (bdx as i32, bdy as i32, per_px, BlockStatus::Matched)
}

/// Component-wise median of displacements (average of the two middle values when even).
fn median2(v: &[[f64; 2]]) -> [f64; 2] {
    let med = |mut xs: Vec<f64>| -> f64 {
        if xs.is_empty() {
            return 0.0;
        }
        xs.sort_by(f64::total_cmp);
        let n = xs.len();
        if n % 2 == 1 {
            xs[n / 2]
        } else {
            0.5 * (xs[n / 2 - 1] + xs[n / 2])
        }
    };
    [
        med(v.iter().map(|d| d[0]).collect()),
        med(v.iter().map(|d| d[1]).collect()),
    ]
}

/// Adaptive block matching of the region `region` (an ellipse in `prev`) into `cur`; see
/// the module docs for the method.
///
/// Errors: frames of different or zero size ([`MotionError::FrameSize`]), an invalid region
/// ([`MotionError::InvalidRegion`]) or parameters ([`MotionError::InvalidParams`]), and a
/// region with no block inside the frame ([`MotionError::RegionOutside`]). A region partly
/// outside the frame is matched with its blocks clipped to the frame. A region inside the
/// frame that holds no block (smaller than [`AbmParams::min_block`], or too thin) is
/// [`MotionError::RegionTooSmall`]. A textureless region is
/// not an error: the result has a low [`AbmResult::matched_fraction`] and a
/// [`AbmResult::fallback`].
pub fn block_match(
    prev: &GrayF32,
    cur: &GrayF32,
    region: &Ellipse,
    params: &AbmParams,
) -> Result<AbmResult, MotionError> {
    params.check()?;
    if prev.width != cur.width
        || prev.height != cur.height
        || prev.width == 0
        || prev.height == 0
        || prev.data.len() != prev.width as usize * prev.height as usize
        || cur.data.len() != cur.width as usize * cur.height as usize
    {
        return Err(MotionError::FrameSize(
            prev.width,
            prev.height,
            cur.width,
            cur.height,
        ));
    }
    if !region.is_valid() {
        return Err(MotionError::InvalidRegion);
    }
    let grid = Grid::new(region, params, prev.width, prev.height)?;
    let mut blocks = grid.match_blocks(prev, cur, region, params);
    let median = reject_outliers(&mut blocks, region, params);
    mark_boundary(&mut blocks, &grid);
    Ok(fit_motion(blocks, median, region, params))
}

/// The region's first blocks: a grid of `block_size` cells anchored at the region's
/// (unclipped) bounding box, those whose centre lies inside the ellipse, clipped to the frame;
/// and the extent of the pixels the region may cover.
struct Grid {
    /// The first blocks, last to be matched first (a stack).
    cells: Vec<Cell>,
    /// Pixel indices whose centres may lie inside the ellipse: `ix0..ix1`, `iy0..iy1`.
    ix0: i64,
    iy0: i64,
    ix1: i64,
    iy1: i64,
    /// The grid's anchor.
    gx0: i64,
    gy0: i64,
    /// The cells' side.
    bs: i64,
}

impl Grid {
    /// The grid of `region` in a frame `width` x `height`: [`MotionError::RegionOutside`]
    /// where no block lies in the frame, [`MotionError::RegionTooSmall`] where none fits a
    /// region inside it.
    fn new(
        region: &Ellipse,
        params: &AbmParams,
        width: u32,
        height: u32,
    ) -> Result<Self, MotionError> {
        let (fw, fh) = (i64::from(width), i64::from(height));
        let bb = region.bounding_box();
        // Pixel indices whose centres may lie inside the ellipse; far-away regions are cut
        // off before any allocation (the bounds are clamped into a range around the frame).
        let lim = |v: f64, hi: i64| -> i64 { v.clamp(-1.0, hi as f64 + 1.0) as i64 };
        let ix0 = lim(bb.x.ceil(), fw);
        let iy0 = lim(bb.y.ceil(), fh);
        let ix1 = lim((bb.x + bb.w).floor() + 1.0, fw);
        let iy1 = lim((bb.y + bb.h).floor() + 1.0, fh);
        if ix1 <= 0 || iy1 <= 0 || ix0 >= fw || iy0 >= fh {
            return Err(MotionError::RegionOutside);
        }
        // The grid is anchored at the (unclipped) bounding box so clipping does not shift it.
        let bs = params.block_size as i64;
        let gx0 = bb.x.ceil().max(-1e12) as i64;
        let gy0 = bb.y.ceil().max(-1e12) as i64;
        let first = |g0: i64, lo: i64| -> i64 {
            if g0 >= lo {
                g0
            } else {
                g0 + ((lo - g0) / bs) * bs
            }
        };
        let min_b = params.min_block as i64;
        let mut cells: Vec<Cell> = Vec::new();
        let mut gy = first(gy0, 0);
        while gy < iy1.min(fh) {
            let mut gx = first(gx0, 0);
            while gx < ix1.min(fw) {
                let full = Cell {
                    x: gx,
                    y: gy,
                    w: bs,
                    h: bs,
                };
                // Keep when the full cell's centre is inside the ellipse, then clip to frame.
                if full.inside(region) {
                    let x0 = gx.max(0);
                    let y0 = gy.max(0);
                    let x1 = (gx + bs).min(fw);
                    let y1 = (gy + bs).min(fh);
                    if x1 - x0 >= min_b && y1 - y0 >= min_b {
                        cells.push(Cell {
                            x: x0,
                            y: y0,
                            w: x1 - x0,
                            h: y1 - y0,
                        });
                    }
                }
                gx += bs;
            }
            gy += bs;
        }
        if cells.is_empty() {
            return Err(if region.centre_inside(width, height) {
                MotionError::RegionTooSmall
            } else {
                MotionError::RegionOutside
            });
        }
        cells.reverse(); // process in raster order (a stack pops from the end)
        Ok(Self {
            cells,
            ix0,
            iy0,
            ix1,
            iy1,
            gx0,
            gy0,
            bs,
        })
    }

    /// The top-left corner of the window of `prev` the blocks are cut from.
    fn window_origin(&self) -> (i64, i64) {
        (self.ix0.min(self.gx0.max(0)), self.iy0.min(self.gy0.max(0)))
    }

    /// Matches the grid's blocks into `cur`, in raster order, splitting a block whose match is
    /// poor or ambiguous into four (those of them centred in the region) while they stay at
    /// least `min_block` wide.
    fn match_blocks(
        &self,
        prev: &GrayF32,
        cur: &GrayF32,
        region: &Ellipse,
        params: &AbmParams,
    ) -> Vec<BlockMatch> {
        let (bs, r) = (self.bs, params.search_radius as i64);
        let (wx0, wy0) = self.window_origin();
        let prev_win = Window::new(prev, wx0, wy0, self.ix1 + bs, self.iy1 + bs);
        let cur_win = Window::new(cur, wx0 - r, wy0 - r, self.ix1 + bs + r, self.iy1 + bs + r);
        let min_b = params.min_block as i64;
        let mut stack = self.cells.clone();
        let mut blocks: Vec<BlockMatch> = Vec::new();
        let mut scratch = Scratch::default();
        let mut hint = (0i64, 0i64);
        while let Some(c) = stack.pop() {
            let (dx, dy, s, status) =
                match_cell(&c, &prev_win, &cur_win, params, &mut scratch, hint);
            if status == BlockStatus::Matched {
                hint = (dx as i64, dy as i64);
            }
            let can_split = c.w / 2 >= min_b && c.h / 2 >= min_b;
            if status != BlockStatus::Matched && status != BlockStatus::NoRoom && can_split {
                // Pushed in reverse so they pop in raster order.
                for k in c.quarters().iter().rev().filter(|k| k.inside(region)) {
                    stack.push(*k);
                }
                continue;
            }
            blocks.push(BlockMatch {
                x: c.x as i32,
                y: c.y as i32,
                w: c.w as u32,
                h: c.h as u32,
                dx,
                dy,
                sad: s,
                status,
                boundary: false,
            });
        }
        blocks
    }
}

impl Cell {
    /// Whether the cell's centre lies inside `region`.
    fn inside(&self, region: &Ellipse) -> bool {
        region.contains(
            self.x as f64 + (self.w as f64 - 1.0) / 2.0,
            self.y as f64 + (self.h as f64 - 1.0) / 2.0,
        )
    }

    /// The cell's four quarters, in raster order (the right and bottom ones take an odd
    /// pixel).
    fn quarters(&self) -> [Cell; 4] {
        let (w1, h1) = (self.w / 2, self.h / 2);
        [
            Cell {
                x: self.x,
                y: self.y,
                w: w1,
                h: h1,
            },
            Cell {
                x: self.x + w1,
                y: self.y,
                w: self.w - w1,
                h: h1,
            },
            Cell {
                x: self.x,
                y: self.y + h1,
                w: w1,
                h: self.h - h1,
            },
            Cell {
                x: self.x + w1,
                y: self.y + h1,
                w: self.w - w1,
                h: self.h - h1,
            },
        ]
    }
}

/// Marks as outliers the matched blocks whose displacement is too far from the median for a
/// similarity within [`AbmParams::max_scale_change`] (1.5 px plus the change's share of the
/// block's distance from the centre), and returns the median displacement of those left.
fn reject_outliers(blocks: &mut [BlockMatch], region: &Ellipse, params: &AbmParams) -> [f64; 2] {
    let matched = |blocks: &[BlockMatch]| -> Vec<[f64; 2]> {
        blocks
            .iter()
            .filter(|b| b.status == BlockStatus::Matched)
            .map(|b| [b.dx as f64, b.dy as f64])
            .collect()
    };
    let med0 = median2(&matched(blocks));
    let ds = params.max_scale_change - 1.0;
    for b in blocks
        .iter_mut()
        .filter(|b| b.status == BlockStatus::Matched)
    {
        let [px, py] = b.centre();
        let rad = (px - region.cx).hypot(py - region.cy);
        let dev = (b.dx as f64 - med0[0]).hypot(b.dy as f64 - med0[1]);
        if dev > 1.5 + ds * rad {
            b.status = BlockStatus::Outlier;
        }
    }
    median2(&matched(blocks))
}

/// Flags the boundary blocks: those with a pixel of the 1-px ring around them that no block
/// of the region covers (or that lies outside the frame).
fn mark_boundary(blocks: &mut [BlockMatch], grid: &Grid) {
    let (wx0, wy0) = grid.window_origin();
    let (cx0, cy0) = (wx0 - 1, wy0 - 1);
    let (cw, ch) = (grid.ix1 + grid.bs + 2 - cx0, grid.iy1 + grid.bs + 2 - cy0);
    let mut cover = vec![false; (cw * ch) as usize];
    for b in blocks.iter() {
        for y in b.y as i64..b.y as i64 + b.h as i64 {
            for x in b.x as i64..b.x as i64 + b.w as i64 {
                cover[((y - cy0) * cw + (x - cx0)) as usize] = true;
            }
        }
    }
    let covered = |x: i64, y: i64| -> bool {
        x >= cx0
            && y >= cy0
            && x < cx0 + cw
            && y < cy0 + ch
            && cover[((y - cy0) * cw + (x - cx0)) as usize]
    };
    for b in blocks.iter_mut() {
        let (x0, y0, x1, y1) = (
            b.x as i64 - 1,
            b.y as i64 - 1,
            (b.x + b.w as i32) as i64,
            (b.y + b.h as i32) as i64,
        );
        let ring_open = (x0..=x1).any(|x| !covered(x, y0) || !covered(x, y1))
            || (y0..=y1).any(|y| !covered(x0, y) || !covered(x1, y));
        b.boundary = ring_open;
    }
}

/// The region's motion from its blocks: ellipses fitted to the matched boundary blocks'
/// centres before and after give the translation and the scale, checked for plausibility
/// against `median` (the inliers' median displacement); where that fails, the median
/// translates the region at its size, with the reason ([`Fallback`]).
fn fit_motion(
    blocks: Vec<BlockMatch>,
    median: [f64; 2],
    region: &Ellipse,
    params: &AbmParams,
) -> AbmResult {
    let total_area: f64 = blocks.iter().map(|b| (b.w * b.h) as f64).sum();
    let matched_area: f64 = blocks
        .iter()
        .filter(|b| b.status == BlockStatus::Matched)
        .map(|b| (b.w * b.h) as f64)
        .sum();
    let matched_fraction = if total_area > 0.0 {
        matched_area / total_area
    } else {
        0.0
    };

    let fallback_result = |why: Fallback, blocks: Vec<BlockMatch>| AbmResult {
        ellipse: Ellipse {
            cx: region.cx + median[0],
            cy: region.cy + median[1],
            ..*region
        },
        translation: median,
        scale: 1.0,
        blocks,
        matched_fraction,
        median_displacement: median,
        fallback: Some(why),
    };
    if !blocks.iter().any(|b| b.status == BlockStatus::Matched) {
        return fallback_result(Fallback::NoMatchedBlocks, blocks);
    }
    let (old_pts, new_pts): (Vec<[f64; 2]>, Vec<[f64; 2]>) = blocks
        .iter()
        .filter(|b| b.status == BlockStatus::Matched && b.boundary)
        .map(|b| {
            let [x, y] = b.centre();
            ([x, y], [x + b.dx as f64, y + b.dy as f64])
        })
        .unzip();
    if old_pts.len() < params.min_fit_blocks {
        return fallback_result(Fallback::TooFewBoundaryBlocks, blocks);
    }
    let (fo, fnew) = match (fit_ellipse(&old_pts), fit_ellipse(&new_pts)) {
        (Ok(a), Ok(b)) => (a, b),
        _ => return fallback_result(Fallback::DegenerateFit, blocks),
    };
    let scale = ((fnew.a * fnew.b) / (fo.a * fo.b)).sqrt();
    if !(scale.is_finite()
        && scale <= params.max_scale_change
        && scale >= 1.0 / params.max_scale_change)
    {
        return fallback_result(Fallback::ImplausibleScale, blocks);
    }
    let t = [fnew.cx - fo.cx, fnew.cy - fo.cy];
    let tol = params.max_centre_disagreement + 0.25 * 0.5 * (region.a + region.b);
    if (t[0] - median[0]).hypot(t[1] - median[1]) > tol {
        return fallback_result(Fallback::CentreFarOff, blocks);
    }
    AbmResult {
        ellipse: Ellipse {
            cx: region.cx + t[0],
            cy: region.cy + t[1],
            a: region.a * scale,
            b: region.b * scale,
            theta: region.theta,
        },
        translation: t,
        scale,
        blocks,
        matched_fraction,
        median_displacement: median,
        fallback: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bright window of more than 2^32 / 255 pixels wraps its summed-area table, and the
    /// block sums taken from it are still exact (the table used to overflow: a panic in a
    /// build with overflow checks, as the tests are).
    #[test]
    fn block_sums_are_exact_in_a_window_past_two_to_the_32() {
        let (w, h) = (4200u32, 4200u32);
        let mut img = GrayF32::new(w, h);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = 1.0 - 0.02 * ((i % 7) as f32 / 6.0);
        }
        let win = Window::new(&img, 0, 0, w as i64, h as i64);
        assert!(win.data.iter().map(|&v| u64::from(v)).sum::<u64>() > u64::from(u32::MAX));
        for (x, y, bw, bh) in [(0, 0, 16, 16), (4000, 4100, 64, 48), (4199, 4199, 1, 1)] {
            let direct: u32 = (y..y + bh)
                .flat_map(|yy| (x..x + bw).map(move |xx| (xx, yy)))
                .map(|(xx, yy)| u32::from(win.data[win.offset(xx, yy)]))
                .sum();
            assert_eq!(win.box_sum(x, y, bw, bh), direct, "{x},{y} {bw}x{bh}");
        }
    }

    #[test]
    fn sad_and_texture_basics() {
        let a = [0u8, 10, 20, 30];
        let win = [1u8, 10, 25, 99, 0, 30, 30, 99];
        // 2x2 block against window stride 4 at offset 0: |0-1|+|10-10|+|20-0|+|30-30|
        assert_eq!(sad::<0>(&a, 2, 2, &win, 0, 4, u32::MAX), 21);
        // Early exit: a value above the bound, not necessarily the full sum.
        assert!(sad::<0>(&a, 2, 2, &win, 0, 4, 0) > 0);
        let r8: Vec<u8> = (0..8).collect();
        let r8b: Vec<u8> = (0..8).map(|v| 2 * v).collect();
        assert_eq!(row_sad::<8>(&r8, &r8b), 28);
        assert_eq!(row_sad::<0>(&r8, &r8b), 28);
        let r5: Vec<u8> = (0..5).collect();
        assert_eq!(row_sad::<0>(&r5, &[0; 5]), 10);
        assert_eq!(texture(&[5, 5, 5, 5]), 0.0);
        assert_eq!(texture(&[0, 10]), 5.0);
        assert_eq!(median2(&[[1.0, 4.0], [3.0, 2.0]]), [2.0, 3.0]);
        assert_eq!(median2(&[]), [0.0, 0.0]);
    }

    /// The pruned two-pass search equals an exhaustive one (best, tie-breaks, ambiguity).
    #[test]
    fn pruned_search_equals_exhaustive_search() {
        use rand::rngs::StdRng;
        use rand::{Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(9);
        let mut seen = Vec::new();
        for trial in 0..300 {
            let (fw, fh) = (40u32, 36u32);
            // Coarse values (few levels) make ties and ambiguity common.
            let levels = if trial % 2 == 0 { 3.0 } else { 50.0 };
            let mut img = |_: u32| {
                let mut g = GrayF32::new(fw, fh);
                for v in g.data.iter_mut() {
                    *v = (rng.random_range(0.0..levels) as f32).floor() / levels as f32;
                }
                g
            };
            let prev = img(0);
            let mut cur = img(1);
            if trial % 3 == 0 {
                // A near-copy: a clear match that is not perfect.
                cur = prev.clone();
                for _ in 0..40 {
                    let i = rng.random_range(0..cur.data.len());
                    cur.data[i] = (cur.data[i] + 0.02).min(1.0);
                }
            }
            let p = AbmParams {
                search_radius: 4,
                max_sad: if trial % 4 == 1 { 0.05 } else { 0.6 },
                min_texture: 0.0,
                ambiguity_ratio: 0.9,
                ..AbmParams::default()
            };
            let pw = Window::new(&prev, 0, 0, fw as i64, fh as i64);
            let cw = Window::new(&cur, 0, 0, fw as i64, fh as i64);
            let c = Cell {
                x: (trial % 30) as i64,
                y: (trial % 27) as i64,
                w: 4 + (trial % 3) as i64 * 2,
                h: 4,
            };
            let hint = ((trial % 5) as i64 - 2, (trial % 7) as i64 - 3);
            let mut scratch = Scratch::default();
            let got = match_cell(&c, &pw, &cw, &p, &mut scratch, hint);
            // Exhaustive reference.
            let r = 4i64;
            let mut all = Vec::new();
            for dy in -r..=r {
                for dx in -r..=r {
                    if cw.holds(c.x + dx, c.y + dy, c.w, c.h) {
                        let s: u32 = (0..c.h)
                            .flat_map(|yy| (0..c.w).map(move |xx| (xx, yy)))
                            .map(|(xx, yy)| {
                                let a = pw.data[pw.offset(c.x + xx, c.y + yy)];
                                let b = cw.data[cw.offset(c.x + dx + xx, c.y + dy + yy)];
                                a.abs_diff(b) as u32
                            })
                            .sum();
                        all.push((s, dx.abs() + dy.abs(), dy, dx));
                    }
                }
            }
            let best = *all.iter().min().unwrap();
            let second = all
                .iter()
                .filter(|k| (k.3 - best.3).abs() > 1 || (k.2 - best.2).abs() > 1)
                .map(|k| k.0)
                .min();
            let per_px = best.0 as f32 / (255.0 * (c.w * c.h) as f32);
            let status = if per_px > p.max_sad {
                BlockStatus::Poor
            } else if second.is_some_and(|s2| best.0 as f32 > p.ambiguity_ratio * s2 as f32) {
                BlockStatus::Ambiguous
            } else {
                BlockStatus::Matched
            };
            assert_eq!(
                got,
                (best.3 as i32, best.2 as i32, per_px, status),
                "trial {trial}"
            );
            seen.push(status);
        }
        for st in [
            BlockStatus::Matched,
            BlockStatus::Ambiguous,
            BlockStatus::Poor,
        ] {
            assert!(seen.contains(&st), "{st:?} never exercised");
        }
    }

    #[test]
    fn params_scale_with_target_and_validate() {
        let p = AbmParams::for_target(&Ellipse::new(0.0, 0.0, 20.0, 20.0));
        assert_eq!((p.block_size, p.min_block, p.search_radius), (8, 4, 10));
        let p = AbmParams::for_target(&Ellipse::new(0.0, 0.0, 40.0, 40.0));
        assert_eq!((p.block_size, p.min_block, p.search_radius), (16, 4, 20));
        let p = AbmParams::for_target(&Ellipse::new(0.0, 0.0, 2.0, 2.0));
        assert_eq!((p.block_size, p.min_block, p.search_radius), (4, 4, 4));
        assert!(AbmParams::default().check().is_ok());
        let bad = AbmParams {
            min_block: 16,
            ..AbmParams::default()
        };
        assert!(bad.check().is_err());
    }

    #[test]
    fn given_settings_scale_their_sizes_and_keep_their_thresholds() {
        let d = AbmParams::default();
        for r in [1.0, 7.0, 20.0, 33.0, 40.0, 500.0] {
            let e = Ellipse::new(0.0, 0.0, r, r);
            assert_eq!(d.scaled_to(&e), AbmParams::for_target(&e));
        }
        let base = AbmParams {
            block_size: 12,
            min_block: 6,
            search_radius: 5,
            max_sad: 0.2,
            min_fit_blocks: 9,
            ..d
        };
        // Twice the 40 px reference: block 24 (its quarter 6, the floor), radius 10.
        let p = base.scaled_to(&Ellipse::new(0.0, 0.0, 40.0, 40.0));
        assert_eq!((p.block_size, p.min_block, p.search_radius), (24, 6, 10));
        assert_eq!((p.max_sad, p.min_fit_blocks), (0.2, 9));
        // Tiny and huge targets stay within the bounds of `check`.
        let widest = AbmParams {
            block_size: 256,
            min_block: 2,
            search_radius: 256,
            ..d
        };
        for b in [base, widest, d] {
            for r in [0.5, 1e4, 1e12, f64::NAN] {
                let p = b.scaled_to(&Ellipse::new(0.0, 0.0, r, r));
                assert!(p.check().is_ok(), "{b:?} at {r}: {p:?}");
            }
        }
        // Settings `check` refuses still scale (to settings it refuses) without a panic.
        let bad = AbmParams {
            block_size: 1000,
            min_block: 900,
            search_radius: 100_000,
            ..d
        };
        assert!(bad.check().is_err());
        assert!(
            bad.scaled_to(&Ellipse::new(0.0, 0.0, 1e12, 1e12))
                .check()
                .is_err()
        );
    }
}
