//! Resizing RGB8 frames, pixel-centre aligned: bilinear where an axis grows, the mean over
//! each output pixel's footprint where it shrinks.
//!
//! Output pixel `x` is centred on the source position `sx = (x + 0.5) · sw / dw − 0.5` (and
//! likewise in y): the centres of the first and last pixels of both images span the same
//! extent of the scene, so the image does not shift by half a pixel.
//! - [`resize_bilinear`] samples there, positions outside `[0, sw − 1]` clamped (edge
//!   replication). It has no anti-aliasing prefilter: shrinking by more than 2 it reads only
//!   two of every `sw / dw` source pixels, and aliases.
//! - [`resize()`] (what a [`crate::frames::FrameSource`] resizes with) averages, along an axis
//!   that shrinks, the source over the output pixel's footprint `[x · sw / dw, (x + 1) · sw /
//!   dw)`, each source pixel weighted by how much of it lies inside (OpenCV's `INTER_AREA`
//!   does the same): every source pixel counts, so fine texture averages out instead of
//!   aliasing into false edges and features. Along an axis that grows or keeps its size it
//!   is bilinear. Halving is the same either way (the footprint is two whole pixels, and
//!   bilinear samples midway between them).

use image::RgbImage;

use crate::geometry::{Ellipse, PoseState};
use crate::io::PoseRecord;

/// Where positions in a frame of one size lie in the same frame resized to another, by the
/// resizes' convention ([`resize()`], [`resize_bilinear`]): `x' = (x + 0.5) · dw / sw − 0.5`,
/// and likewise in y. An ellipse maps to its exact image under the scaling: with the same aspect ratio its
/// semi-axes scale and its orientation stays; otherwise a turned ellipse's axes turn too.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rescale {
    /// The sizes mapped from, as numbers.
    from: (f64, f64),
    /// The sizes mapped to.
    to: (f64, f64),
}

impl Rescale {
    /// The map from a `from` frame (width, height) to the `to` frame; sizes of 0 map as 1.
    pub fn new(from: (u32, u32), to: (u32, u32)) -> Self {
        let side = |v: u32| f64::from(v.max(1));
        Self::between((side(from.0), side(from.1)), (side(to.0), side(to.1)))
    }

    fn between(from: (f64, f64), to: (f64, f64)) -> Self {
        Self { from, to }
    }

    /// The scale along x.
    fn sx(&self) -> f64 {
        self.to.0 / self.from.0
    }

    /// The scale along y.
    fn sy(&self) -> f64 {
        self.to.1 / self.from.1
    }

    /// The map back.
    pub fn inverse(&self) -> Self {
        Self::between(self.to, self.from)
    }

    /// Whether the map leaves every position where it is.
    pub fn is_identity(&self) -> bool {
        self.from == self.to
    }

    /// Where pixel position `(x, y)` lands (exactly where it was along an axis of scale 1).
    /// Computed as `(x + 0.5) · dw / sw − 0.5`, the product first: the frame's edges and the
    /// centres of its first and last pixels land exactly on the other frame's, so a position
    /// inside one frame is inside the other.
    pub fn point(&self, x: f64, y: f64) -> (f64, f64) {
        let map = |v: f64, from: f64, to: f64| {
            if from == to {
                v
            } else {
                (v + 0.5) * to / from - 0.5
            }
        };
        (
            map(x, self.from.0, self.to.0),
            map(y, self.from.1, self.to.1),
        )
    }

    /// The image of the ellipse: its centre mapped, and the ellipse its two semi-axes (now
    /// conjugate semi-diameters) span. `a` stays the semi-axis nearest the image of the old
    /// `a`, and the orientation within a quarter turn of the old one.
    pub fn ellipse(&self, e: &Ellipse) -> Ellipse {
        let (cx, cy) = self.point(e.cx, e.cy);
        let (sx, sy) = (self.sx(), self.sy());
        let (a, b, theta) = if sx == sy {
            (e.a * sx, e.b * sx, e.theta)
        } else {
            self.axes(e.a, e.b, e.theta)
        };
        Ellipse {
            cx,
            cy,
            a,
            b,
            theta,
        }
    }

    /// The semi-axes and orientation of the image of an ellipse of semi-axes `a`, `b` turned
    /// by `theta`.
    fn axes(&self, a: f64, b: f64, theta: f64) -> (f64, f64, f64) {
        let (sx, sy) = (self.sx(), self.sy());
        let (s, c) = theta.sin_cos();
        // The images of the two semi-axes, the columns of S R(θ) diag(a, b).
        let m = nalgebra::Matrix2::new(sx * c * a, -sx * s * b, sy * s * a, sy * c * b);
        let svd = m.svd(true, false);
        let Some(u) = svd.u else {
            return (a * sx, b * sy, theta);
        };
        let (s0, s1) = (svd.singular_values[0], svd.singular_values[1]);
        if (s0 - s1).abs() <= 1e-12 * s0.max(s1) {
            // A circle: any orientation; keep the old one.
            return (s0, s1, theta);
        }
        // `a` is the image axis whose preimage lies nearest the old `a` axis: the component
        // of the image of `a` along each axis, over that axis's length, is the cosine of the
        // preimage's angle to `a` (so the map back chooses the same way).
        let image_a = m.column(0);
        let (d0, d1) = (u.column(0), u.column(1));
        let (len_a, len_b, dir) = if d0.dot(&image_a).abs() / s0 >= d1.dot(&image_a).abs() / s1 {
            (s0, s1, d0)
        } else {
            (s1, s0, d1)
        };
        // The axis has no sign: the orientation nearest the old one, kept within a turn
        // either way as the old one was.
        let pi = std::f64::consts::PI;
        let t = dir[1].atan2(dir[0]);
        let mut t = t + pi * ((theta - t) / pi).round();
        let turn = 2.0 * pi;
        if t > turn {
            t -= pi;
        } else if t < -turn {
            t += pi;
        }
        (len_a, len_b, t)
    }

    /// A pose-CSV row in the other frame: its ellipse (orientation `theta`, else `rz`) as
    /// [`Rescale::ellipse`] maps it, the angles kept; `theta` the mapped orientation when
    /// the row had one.
    pub fn record(&self, r: &PoseRecord) -> PoseRecord {
        let e = self.ellipse(&r.ellipse());
        PoseRecord {
            state: PoseState {
                cx: e.cx,
                cy: e.cy,
                a: e.a,
                b: e.b,
                ..r.state
            },
            theta: r.theta.map(|_| e.theta),
            ..r.clone()
        }
    }
}

/// The longer side [`working_size`] shrinks frames toward.
pub const WORKING_SIDE: u32 = 640;

/// The larger semi-axis, in pixels, [`working_size`] leaves a target at least.
pub const WORKING_SEMI_AXIS: f64 = 64.0;

/// The smaller semi-axis, in pixels, [`working_size`] leaves a target at least.
pub const WORKING_MIN_SEMI_AXIS: f64 = 16.0;

/// The size to track frames of size `frame` at, where a smaller one serves as well: frames
/// longer than [`WORKING_SIDE`] pixels on their longer side, shrunk ([`resize()`]) toward it,
/// as far as the target (`target`) keeps a larger semi-axis of [`WORKING_SEMI_AXIS`] pixels
/// and a smaller one of [`WORKING_MIN_SEMI_AXIS`]; `None` where the frames are tracked as they
/// are: no longer than that, a target no larger, or a shrink of the longer side by a fifth or
/// less (frames up to 800 px long are never shrunk). The frame's proportions are kept exactly
/// where its sides allow it within a step of 64 px and a shrink by more than a fifth
/// (1920x1080 shrinks by multiples of 16x9), else each side is rounded up to whole pixels.
///
/// The tracker's cost grows with the target's area (its colour histograms, block matching and
/// SIFT all cover it), and its accuracy stops growing well below these sizes: on the
/// synthetic scenarios rendered at 1280x960 (heads of semi-axes 148x198 px) and tracked at
/// that size, at 640x480 and at 320x240, the six scenarios' per-axis RMSE summed to 33.9,
/// 31.3 and 29.9 degrees, at 59, 18 and 13 ms a step (see `docs/measurements.md`).
/// The floor on the side keeps a target that later shrinks (a car driving away) at least as
/// many pixels as footage [`WORKING_SIDE`] pixels wide gives it.
pub fn working_size(frame: (u32, u32), target: &Ellipse) -> Option<(u32, u32)> {
    let (w, h) = frame;
    let (a, b) = (target.a.abs(), target.b.abs());
    if w == 0 || h == 0 || !(a.is_finite() && b.is_finite() && a > 0.0 && b > 0.0) {
        return None;
    }
    let k = (f64::from(WORKING_SIDE) / f64::from(w.max(h)))
        .max(WORKING_SEMI_AXIS / a.max(b))
        .max(WORKING_MIN_SEMI_AXIS / a.min(b));
    // Rounded up, so that no bound above is passed.
    let up = |v: f64| (v - 1e-9).ceil().max(1.0) as u32;
    // Shrinking by a fifth or less saves little, and still blurs every pixel a little: the
    // longer side must lose more than a fifth.
    let enough = |(sw, sh): (u32, u32)| 5 * u64::from(sw.max(sh)) < 4 * u64::from(w.max(h));
    let g = gcd(w, h);
    let (p, q) = (w / g, h / g);
    let exact = (p.max(q) <= 64)
        .then(|| {
            let n = up(f64::from(g) * k);
            (n * p, n * q)
        })
        .filter(|&s| enough(s));
    let size = exact.unwrap_or_else(|| (up(f64::from(w) * k), up(f64::from(h) * k)));
    (enough(size) && size.0 <= w && size.1 <= h).then_some(size)
}

/// The greatest common divisor.
fn gcd(mut a: u32, mut b: u32) -> u32 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// One output coordinate's two source taps and the weight of the second, `[0, 1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tap {
    i0: usize,
    i1: usize,
    w1: f32,
}

/// The taps of every output coordinate for a `src → dst` resize along one axis.
fn taps(src: u32, dst: u32) -> Vec<Tap> {
    let scale = src as f64 / dst as f64;
    let last = (src - 1) as f64;
    (0..dst)
        .map(|x| {
            let s = ((x as f64 + 0.5) * scale - 0.5).clamp(0.0, last);
            let i0 = s.floor();
            let w1 = (s - i0) as f32;
            let i0 = i0 as usize;
            let i1 = (i0 + 1).min(src as usize - 1);
            Tap { i0, i1, w1 }
        })
        .collect()
}

/// One output coordinate's source pixels along an axis: the first, and the weight of each
/// from there on (summing to 1).
#[derive(Debug, Clone, PartialEq)]
struct Footprint {
    first: usize,
    weights: Vec<f32>,
}

/// The bilinear footprints of every output coordinate for a `src → dst` resize along one
/// axis: [`taps`]' two, or one where the second is clamped onto the first at the border
/// (it carries no weight there).
fn bilinear_footprints(src: u32, dst: u32) -> Vec<Footprint> {
    taps(src, dst)
        .into_iter()
        .map(|t| Footprint {
            first: t.i0,
            weights: if t.i1 == t.i0 {
                vec![1.0]
            } else {
                vec![1.0 - t.w1, t.w1]
            },
        })
        .collect()
}

/// The footprints of every output coordinate for a `src → dst` resize along one axis: the
/// mean over `[x · src / dst, (x + 1) · src / dst)` where the axis shrinks, else bilinear
/// ([`bilinear_footprints`]).
fn footprints(src: u32, dst: u32) -> Vec<Footprint> {
    if dst >= src {
        return bilinear_footprints(src, dst);
    }
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|x| {
            let lo = x as f64 * scale;
            let hi = ((x + 1) as f64 * scale).min(src as f64);
            let first = lo.floor() as usize;
            let end = (hi.ceil() as usize).clamp(first + 1, src as usize);
            let weights = (first..end)
                .map(|i| {
                    let overlap = (hi.min(i as f64 + 1.0) - lo.max(i as f64)).max(0.0);
                    (overlap / (hi - lo)) as f32
                })
                .collect();
            Footprint { first, weights }
        })
        .collect()
}

/// Resizes `img` to `w × h`, pixel-centre aligned: the mean over each output pixel's
/// footprint along an axis that shrinks, bilinear along one that grows (see the module
/// docs). The same size gives the same image; an empty source or target size gives an empty
/// image of the target size.
pub fn resize(img: &RgbImage, w: u32, h: u32) -> RgbImage {
    resample(img, w, h, footprints)
}

/// Resizes `img` to `w × h` by bilinear interpolation, pixel-centre aligned (see the module
/// docs). An empty source or target size gives an empty image of the target size.
pub fn resize_bilinear(img: &RgbImage, w: u32, h: u32) -> RgbImage {
    resample(img, w, h, bilinear_footprints)
}

/// Resamples `img` to `w × h` separably, each axis by the footprints `along` gives it: along
/// x first, then y, in f32, rounded once at the end. The same size gives the same image (both
/// footprints are then the pixel itself).
fn resample(img: &RgbImage, w: u32, h: u32, along: fn(u32, u32) -> Vec<Footprint>) -> RgbImage {
    let (sw, sh) = img.dimensions();
    if (sw, sh) == (w, h) {
        return img.clone();
    }
    let mut out = RgbImage::new(w, h);
    if sw == 0 || sh == 0 || w == 0 || h == 0 {
        return out;
    }
    let xf = along(sw, w);
    let yf = along(sh, h);
    let src = img.as_raw();
    let (row_len, out_len) = (sw as usize * 3, w as usize * 3);
    // Along x first, in f32, a source row at a time as the output rows read them; the last
    // two kept, since successive output rows share at most the row between their footprints
    // (shrinking) or both of their rows (growing): memory of two output rows, not of the
    // source's height.
    let across = |y: usize, row: &mut [f32]| {
        let s = &src[y * row_len..(y + 1) * row_len];
        for (px, f) in row.chunks_exact_mut(3).zip(&xf) {
            let taps = &s[f.first * 3..(f.first + f.weights.len()) * 3];
            let mut v = [0f32; 3];
            for (p, &wt) in taps.chunks_exact(3).zip(&f.weights) {
                v[0] += f32::from(p[0]) * wt;
                v[1] += f32::from(p[1]) * wt;
                v[2] += f32::from(p[2]) * wt;
            }
            px.copy_from_slice(&v);
        }
    };
    let mut kept: [(usize, Vec<f32>); 2] = [
        (usize::MAX, vec![0f32; out_len]),
        (usize::MAX, vec![0f32; out_len]),
    ];
    // Then along y, a whole row at a time.
    let dst: &mut [u8] = &mut out;
    let mut acc = vec![0f32; out_len];
    for (drow, f) in dst.chunks_exact_mut(out_len).zip(&yf) {
        acc.fill(0.0);
        for (k, &wt) in f.weights.iter().enumerate() {
            let y = f.first + k;
            let slot = match kept.iter().position(|(at, _)| *at == y) {
                Some(i) => i,
                None => {
                    // An empty place first; else, the rows coming in order, the one kept
                    // from further up goes.
                    let i = match (kept[0].0, kept[1].0) {
                        (usize::MAX, _) => 0,
                        (_, usize::MAX) => 1,
                        (a, b) => usize::from(b < a),
                    };
                    across(y, &mut kept[i].1);
                    kept[i].0 = y;
                    i
                }
            };
            for (a, &v) in acc.iter_mut().zip(&kept[slot].1) {
                *a += v * wt;
            }
        }
        for (d, &a) in drow.iter_mut().zip(&acc) {
            *d = (a + 0.5).clamp(0.0, 255.0) as u8;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The map follows the resize itself: in a horizontal ramp whose grey level is the source
    /// column, each resized pixel reads the column its centre maps back to.
    #[test]
    fn rescale_agrees_with_the_resize() {
        let src = RgbImage::from_fn(200, 30, |x, _| image::Rgb([x as u8; 3]));
        let out = resize_bilinear(&src, 50, 10);
        let back = Rescale::new((200, 30), (50, 10)).inverse();
        for x in 1..49 {
            let (sx, _) = back.point(x as f64, 4.0);
            let v = out.get_pixel(x, 4)[0] as f64;
            assert!((v - sx).abs() <= 0.5, "pixel {x}: {v} vs {sx}");
        }
    }

    #[test]
    fn rescale_maps_ellipses_exactly_and_back() {
        let r = Rescale::new((640, 480), (160, 96));
        assert!(!r.is_identity());
        let same = Rescale::new((64, 48), (64, 48));
        assert!(same.is_identity());
        assert_eq!(same.point(0.1, 0.7), (0.1, 0.7));
        assert_eq!(r.point(-0.5, -0.5), (-0.5, -0.5));
        assert_eq!(r.point(639.5, 479.5), (159.5, 95.5));
        let at = |theta: f64| Ellipse {
            cx: 300.25,
            cy: 200.5,
            a: 40.0,
            b: 50.0,
            theta,
        };
        // Axis-aligned: each semi-axis scales along its own image axis.
        let m = r.ellipse(&at(0.0));
        assert!((m.a - 10.0).abs() < 1e-12 && (m.b - 10.0).abs() < 1e-12 && m.theta == 0.0);
        let m = r.ellipse(&at(std::f64::consts::FRAC_PI_2));
        assert!(
            (m.a - 8.0).abs() < 1e-9 && (m.b - 12.5).abs() < 1e-9,
            "{m:?}"
        );
        assert!((m.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        // The same aspect ratio: the orientation stays.
        let u = Rescale::new((640, 480), (320, 240)).ellipse(&at(0.3));
        assert_eq!((u.a, u.b, u.theta), (20.0, 25.0, 0.3));
        // Turned, by every angle from a turn one way to a turn the other (near the axes too):
        // every point of the ellipse maps onto the mapped ellipse, and back again.
        let sweep = (-720..=720).map(|d| f64::from(d).to_radians() / 2.0);
        for theta in sweep.chain([0.3, -1.2, 2.5, 1e-9, -1e-9]) {
            let e = at(theta);
            let m = r.ellipse(&e);
            for k in 0..16 {
                let (x, y) = e.point_at(k as f64 * 0.4);
                let (u, v) = r.point(x, y);
                let (p, q) = m.to_unit(u, v);
                assert!(
                    ((p * p + q * q) - 1.0).abs() < 1e-9,
                    "theta {theta}: {p} {q}"
                );
            }
            assert!((m.theta - theta).abs() <= std::f64::consts::FRAC_PI_2 + 1e-9);
            assert!(
                m.theta.abs() <= std::f64::consts::TAU + 1e-9,
                "{theta}: {}",
                m.theta
            );
            let back = r.inverse().ellipse(&m);
            for (x, y) in [
                (back.cx, e.cx),
                (back.cy, e.cy),
                (back.a, e.a),
                (back.b, e.b),
                (back.theta, e.theta),
            ] {
                assert!((x - y).abs() < 1e-9, "theta {theta}: {x} vs {y}");
            }
        }
        // A pose row: its ellipse (orientation from `theta`) mapped, its angles kept.
        let e = at(0.7);
        let row = PoseRecord {
            frame: 3,
            state: PoseState::from_parts(&e, crate::geometry::Euler::new(0.1, -0.2, 0.3)),
            score: Some(0.5),
            lost: Some(false),
            theta: Some(0.7),
        };
        let t = r.record(&row);
        let m = r.ellipse(&e);
        assert_eq!(
            (t.state.cx, t.state.cy, t.state.a, t.state.b),
            (m.cx, m.cy, m.a, m.b)
        );
        assert_eq!((t.state.rx, t.state.ry, t.state.rz), (0.1, -0.2, 0.3));
        assert_eq!(
            (t.frame, t.score, t.lost, t.theta),
            (3, Some(0.5), Some(false), Some(m.theta))
        );
    }

    /// The frame's edges and its first and last pixels' centres land exactly on the other
    /// frame's, so a start inside one frame is inside the other (1079.5 of 1080 rows had
    /// mapped past 860.5 of 861 when the ratio was taken first).
    #[test]
    fn the_frames_bounds_map_exactly() {
        for n in 1..=2000u32 {
            for m in [
                1,
                2,
                3,
                360,
                602,
                641,
                737,
                861,
                1080,
                1081,
                4320,
                n / 3 + 1,
            ] {
                let r = Rescale::new((n, n), (m, m));
                let (n, m) = (f64::from(n), f64::from(m));
                for (v, want) in [(-0.5, -0.5), (n - 0.5, m - 0.5)] {
                    assert_eq!(r.point(v, v), (want, want), "{n} -> {m}");
                    assert_eq!(r.inverse().point(want, want), (v, v), "{m} -> {n}");
                }
            }
        }
    }

    #[test]
    fn identity_size_is_identity() {
        let img = RgbImage::from_fn(17, 9, |x, y| {
            image::Rgb([(x * 13 + y * 7) as u8, (x * y) as u8, (255 - x * 5) as u8])
        });
        assert_eq!(resize_bilinear(&img, 17, 9), img);
        assert_eq!(resize(&img, 17, 9), img);
        assert_eq!(resize(&img, 0, 4).dimensions(), (0, 4));
    }

    #[test]
    fn constant_stays_constant() {
        let img = RgbImage::from_pixel(31, 23, image::Rgb([12, 200, 77]));
        for (w, h) in [(10, 7), (64, 48), (1, 1), (31, 50)] {
            for r in [resize_bilinear(&img, w, h), resize(&img, w, h)] {
                assert_eq!(r.dimensions(), (w, h));
                assert!(r.pixels().all(|p| p.0 == [12, 200, 77]));
            }
        }
    }

    #[test]
    fn taps_are_centre_aligned() {
        // Halving: output pixel x sits between source pixels 2x and 2x + 1.
        let t = taps(8, 4);
        assert_eq!(
            t[1],
            Tap {
                i0: 2,
                i1: 3,
                w1: 0.5
            }
        );
        // Doubling: output pixel 3 sits at source 1.25; the first clamps to 0.
        let t = taps(4, 8);
        assert_eq!(
            t[3],
            Tap {
                i0: 1,
                i1: 2,
                w1: 0.25
            }
        );
        assert_eq!(
            t[0],
            Tap {
                i0: 0,
                i1: 1,
                w1: 0.0
            }
        );
        assert_eq!(t[7].i0, 3);
    }

    /// A test image whose channels vary with position, differently in each.
    fn textured(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([
                (x * 37 + y * 11) as u8,
                (x * y * 5 + 3) as u8,
                (255 - (x * 7 + y * 29) % 256) as u8,
            ])
        })
    }

    #[test]
    fn resize_is_bilinear_where_growing_keeping_the_size_or_halving() {
        let img = textured(40, 30);
        // Growing, the same size, halving, and growing along one axis while halving the
        // other: bilinear exactly (halving's footprint is the two pixels bilinear averages).
        for (w, h) in [(97, 61), (40, 30), (20, 15), (80, 15), (20, 30), (40, 45)] {
            assert_eq!(resize(&img, w, h), resize_bilinear(&img, w, h), "{w}x{h}");
        }
    }

    #[test]
    fn shrinking_by_a_whole_factor_gives_the_block_means() {
        let img = textured(12, 9);
        let r = resize(&img, 4, 3);
        for (x, y, p) in r.enumerate_pixels() {
            for c in 0..3 {
                let sum: u32 = (0..3)
                    .flat_map(|j| (0..3).map(move |i| (3 * x + i, 3 * y + j)))
                    .map(|(i, j)| u32::from(img.get_pixel(i, j)[c]))
                    .sum();
                let want = f64::from(sum) / 9.0;
                assert!(
                    (f64::from(p[c]) - want).abs() <= 0.5 + 1e-4,
                    "({x}, {y}) channel {c}: {} against the mean {want}",
                    p[c]
                );
            }
        }
    }

    #[test]
    fn shrinking_one_axis_and_growing_the_other() {
        // Columns of a pattern, alike down every row: shrunk by three along x and grown along
        // y, every row holds the means of three columns.
        let img = RgbImage::from_fn(12, 5, |x, _| image::Rgb([(x * 20) as u8, (x * x) as u8, 7]));
        let r = resize(&img, 4, 9);
        for (x, y, p) in r.enumerate_pixels() {
            let mean = |c: usize| {
                (0..3)
                    .map(|i| f64::from(img.get_pixel(3 * x + i, 0)[c]))
                    .sum::<f64>()
                    / 3.0
            };
            for c in 0..3 {
                assert!(
                    (f64::from(p[c]) - mean(c)).abs() <= 0.5 + 1e-4,
                    "({x}, {y}) channel {c}: {} against {}",
                    p[c],
                    mean(c)
                );
            }
        }
    }

    /// Against the footprints' weights applied in f64, pixel by pixel, on texture that varies
    /// down the image too: output rows that share a source row (shrinking by a factor that is
    /// not whole, growing) read the same filtered row.
    #[test]
    fn resize_is_the_footprints_weighted_sum() {
        for ((sw, sh), (w, h)) in [
            ((30, 30), (7, 7)),
            ((5, 1000), (5, 3)),
            ((4, 1), (4, 5)),
            ((40, 30), (13, 45)),
            ((40, 30), (97, 11)),
            ((33, 47), (20, 29)),
        ] {
            let img = textured(sw, sh);
            let r = resize(&img, w, h);
            let (xf, yf) = (footprints(sw, w), footprints(sh, h));
            for (x, y, p) in r.enumerate_pixels() {
                let (fx, fy) = (&xf[x as usize], &yf[y as usize]);
                for c in 0..3 {
                    let mut want = 0.0;
                    for (j, &wy) in fy.weights.iter().enumerate() {
                        for (i, &wx) in fx.weights.iter().enumerate() {
                            let v = img.get_pixel((fx.first + i) as u32, (fy.first + j) as u32)[c];
                            want += f64::from(wy) * f64::from(wx) * f64::from(v);
                        }
                    }
                    assert!(
                        (f64::from(p[c]) - want).abs() <= 0.5 + 1e-3,
                        "{sw}x{sh} -> {w}x{h} ({x}, {y}) channel {c}: {} against {want}",
                        p[c]
                    );
                }
            }
        }
    }

    #[test]
    fn shrinking_averages_texture_that_bilinear_aliases() {
        // One lit column in every four: shrunk by four, every pixel holds a quarter of it,
        // where bilinear reads only the two dark columns between and sees black.
        let img = RgbImage::from_fn(64, 8, |x, _| {
            image::Rgb([if x % 4 == 0 { 255 } else { 0 }; 3])
        });
        let area = resize(&img, 16, 2);
        assert!(
            area.pixels().all(|p| p.0 == [64; 3]),
            "{:?}",
            area.get_pixel(3, 1)
        );
        let bilinear = resize_bilinear(&img, 16, 2);
        assert!(bilinear.pixels().all(|p| p.0 == [0; 3]));
        // By a factor that is not whole, each pixel's share of the light still averages to the
        // image's (the footprints tile the source, every source pixel weighed in once).
        for (w, h) in [(23, 3), (37, 5), (7, 1), (1, 1)] {
            let r = resize(&img, w, h);
            let mean = r.pixels().map(|p| f64::from(p[0])).sum::<f64>() / f64::from(w * h);
            assert!((mean - 63.75).abs() <= 0.5, "{w}x{h}: mean {mean}");
        }
    }

    #[test]
    fn footprints_tile_the_source() {
        for (src, dst) in [
            (10u32, 3u32),
            (640, 213),
            (7, 1),
            (1000, 999),
            (5, 4),
            (3, 3),
            (2, 9),
        ] {
            let f = footprints(src, dst);
            assert_eq!(f.len(), dst as usize);
            // Each footprint's weights sum to 1; shrinking, each source pixel is weighed in
            // dst / src in all.
            let mut total = vec![0f64; src as usize];
            for fp in &f {
                let s: f64 = fp.weights.iter().map(|&w| f64::from(w)).sum();
                assert!((s - 1.0).abs() < 1e-5, "{src} -> {dst}: {fp:?}");
                assert!(fp.first + fp.weights.len() <= src as usize);
                for (k, &w) in fp.weights.iter().enumerate() {
                    total[fp.first + k] += f64::from(w);
                }
            }
            if dst < src {
                let each = f64::from(dst) / f64::from(src);
                assert!(
                    total.iter().all(|t| (t - each).abs() < 1e-5),
                    "{src} -> {dst}"
                );
            }
        }
    }

    #[test]
    fn working_size_shrinks_large_frames_as_far_as_the_target_allows() {
        let target = |a: f64, b: f64| Ellipse {
            cx: 0.0,
            cy: 0.0,
            a,
            b,
            theta: 0.3,
        };
        // Toward 640 px on the longer side, when the target keeps 64 px there.
        assert_eq!(
            working_size((1280, 960), &target(148.0, 198.0)),
            Some((640, 480))
        );
        assert_eq!(
            working_size((1920, 1080), &target(300.0, 200.0)),
            Some((640, 360))
        );
        assert_eq!(
            working_size((1080, 1920), &target(-200.0, 300.0)),
            Some((360, 640))
        );
        // Only as far as the target keeps 64 px: 100 px in 1920x1080 shrinks by 0.64, to the
        // next 16x9 multiple above.
        assert_eq!(
            working_size((1920, 1080), &target(100.0, 80.0)),
            Some((1232, 693))
        );
        // And 16 px across: a long thin target shrinks less.
        assert_eq!(
            working_size((1920, 1080), &target(200.0, 30.0)),
            Some((1024, 576))
        );
        // Proportions that take no small step: each side rounded up.
        assert_eq!(
            working_size((1366, 768), &target(300.0, 200.0)),
            Some((640, 360))
        );
        // Only for a shrink by more than a fifth; where the proportions' step would leave
        // less (896x882 steps by 64x63: 768x756 for an 80 px target), each side rounded up.
        assert_eq!(
            working_size((1920, 1080), &target(81.0, 30.0)),
            Some((1520, 855))
        );
        assert_eq!(
            working_size((801, 600), &target(300.0, 100.0)),
            Some((640, 480))
        );
        assert_eq!(
            working_size((896, 882), &target(90.0, 90.0)),
            Some((640, 630))
        );
        // Not at all: frames no longer than a fifth past 640 px, a target of 80 px or less
        // or 20 px or less across, or none.
        for (frame, t) in [
            ((800, 600), target(300.0, 100.0)),
            ((1920, 1080), target(80.0, 30.0)),
            ((1920, 1080), target(300.0, 20.0)),
            ((896, 882), target(80.0, 80.0)),
            ((832, 637), target(80.0, 80.0)),
            ((640, 480), target(300.0, 200.0)),
            ((480, 640), target(300.0, 200.0)),
            ((799, 600), target(300.0, 200.0)),
            ((1920, 1080), target(64.0, 30.0)),
            ((1920, 1080), target(79.0, 60.0)),
            ((1920, 1080), target(300.0, 5.0)),
            ((1920, 1080), target(300.0, 19.0)),
            ((1920, 1080), target(f64::NAN, 300.0)),
            ((1920, 1080), target(f64::INFINITY, 300.0)),
            ((1920, 1080), target(300.0, 0.0)),
            ((0, 1080), target(300.0, 200.0)),
        ] {
            assert_eq!(working_size(frame, &t), None, "{frame:?} {t:?}");
        }
        // The shrink keeps the target's semi-axes at 64 and 16 px at least, the frame's longer
        // side at 640 px at least, and the proportions within a pixel's rounding.
        let frames = [
            (641u32, 1u32),
            (1000, 999),
            (4000, 3),
            (3840, 2160),
            (7680, 4320),
        ];
        for (w, h) in frames
            .into_iter()
            .chain([(1366, 768), (2048, 858), (65535, 2)])
        {
            for (semi, across) in [65.0, 100.0, 333.3, 5000.0]
                .into_iter()
                .flat_map(|s| [(s, s / 4.0), (s, s / 8.0)])
            {
                let Some((sw, sh)) = working_size((w, h), &target(semi, across)) else {
                    continue;
                };
                let k = f64::from(sw) / f64::from(w);
                assert!(
                    sw.max(sh) >= 640 && semi * k >= 63.99 && across * k >= 15.99,
                    "{w}x{h} {semi}: {sw}x{sh}"
                );
                assert!(
                    (f64::from(sh) - f64::from(h) * k).abs() <= 1.0,
                    "{w}x{h}: {sw}x{sh}"
                );
                assert!(sw <= w && sh <= h && (sw, sh) != (w, h));
            }
        }
    }

    #[test]
    fn linear_ramp_stays_linear() {
        // v = 3 x + 10 along x (constant along y); upscale 60 → 150 and downscale → 40.
        let src = RgbImage::from_fn(60, 5, |x, _| {
            let v = (3 * x + 10) as u8;
            image::Rgb([v, v / 2, 255 - v])
        });
        for dw in [150u32, 40, 97] {
            let r = resize_bilinear(&src, dw, 5);
            let scale = 60.0 / dw as f64;
            for x in 0..dw {
                let sx = (x as f64 + 0.5) * scale - 0.5;
                if !(0.0..=59.0).contains(&sx) {
                    continue; // clamped at the border: edge replication, not the ramp
                }
                let want = 3.0 * sx + 10.0;
                let got = r.get_pixel(x, 2).0;
                assert!(
                    (got[0] as f64 - want).abs() <= 0.5 + 1e-3,
                    "{dw} {x}: {got:?} {want}"
                );
                assert!((got[2] as f64 - (255.0 - want)).abs() <= 0.5 + 1e-3);
            }
        }
    }
}
