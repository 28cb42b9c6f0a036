//! Raster primitives for the overlays: nearest-neighbour upscaling, clipped rectangles, an
//! ellipse outline (solid or dashed) and centred bars.

use image::{Rgb, RgbImage};

use crate::geometry::Ellipse;

/// A pixel rectangle `[x0, x1) × [y0, y1)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Rect {
    /// Left column (inclusive).
    pub x0: i64,
    /// Top row (inclusive).
    pub y0: i64,
    /// Right column (exclusive).
    pub x1: i64,
    /// Bottom row (exclusive).
    pub y1: i64,
}

impl Rect {
    /// A rectangle from its corner and size.
    pub fn new(x: i64, y: i64, w: i64, h: i64) -> Self {
        Self {
            x0: x,
            y0: y,
            x1: x + w,
            y1: y + h,
        }
    }

    /// Whether the pixel `(x, y)` lies inside.
    pub fn contains(&self, x: i64, y: i64) -> bool {
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }

    /// Width in pixels.
    pub fn width(&self) -> i64 {
        self.x1.saturating_sub(self.x0).max(0)
    }

    /// Height in pixels.
    pub fn height(&self) -> i64 {
        self.y1.saturating_sub(self.y0).max(0)
    }

    /// The intersection with the image `img`.
    fn clip_to(&self, img: &RgbImage) -> Rect {
        Rect {
            x0: self.x0.max(0),
            y0: self.y0.max(0),
            x1: self.x1.min(img.width() as i64),
            y1: self.y1.min(img.height() as i64),
        }
    }
}

/// Every pixel repeated `s × s` times (`s = 0` is treated as 1; capped as
/// [`super::overlay::capped_scale`] caps it).
pub fn upscale_nearest(img: &RgbImage, s: u32) -> RgbImage {
    let s = super::overlay::capped_scale(img.width(), img.height(), s);
    RgbImage::from_fn(img.width() * s, img.height() * s, |x, y| {
        *img.get_pixel(x / s, y / s)
    })
}

/// Where an input coordinate lies in an image upscaled `s` times ([`upscale_nearest`]): the
/// centre of input pixel `u` is the centre of its `s × s` block, `(u + 0.5)·s − 0.5`.
pub fn upscaled(v: f64, s: u32) -> f64 {
    (v + 0.5) * f64::from(s) - 0.5
}

/// `e` in an image upscaled `s` times ([`upscaled`] centre, semi-axes `s` times longer).
pub fn upscaled_ellipse(e: &Ellipse, s: u32) -> Ellipse {
    Ellipse {
        cx: upscaled(e.cx, s),
        cy: upscaled(e.cy, s),
        a: e.a * f64::from(s),
        b: e.b * f64::from(s),
        theta: e.theta,
    }
}

/// Fills `r` (clipped to the image) with `colour`.
pub fn fill_rect(img: &mut RgbImage, r: Rect, colour: Rgb<u8>) {
    let r = r.clip_to(img);
    for y in r.y0..r.y1 {
        for x in r.x0..r.x1 {
            img.put_pixel(x as u32, y as u32, colour);
        }
    }
}

/// First-order (Sampson) distance in pixels from `(x, y)` to the contour of `e`, and the
/// parametric angle of the point in the ellipse's own frame. `None` near the centre, where
/// the approximation breaks down (the point is far from the contour there anyway).
pub fn contour_distance(e: &Ellipse, x: f64, y: f64) -> Option<(f64, f64)> {
    contour_point(e, x, y).map(|p| (p.distance, p.angle))
}

/// Where a point stands to an ellipse's contour ([`contour_point`]).
struct ContourPoint {
    /// First-order distance to the contour (pixels).
    distance: f64,
    /// Parametric angle of the point.
    angle: f64,
    /// The larger of the contour's unit normal's components there, `|n_x|` or `|n_y|`: 1
    /// where the contour runs level or upright, `1/√2` at 45 degrees.
    steepest: f64,
}

/// [`contour_distance`], with the normal's larger component.
fn contour_point(e: &Ellipse, x: f64, y: f64) -> Option<ContourPoint> {
    let (s, c) = e.theta.sin_cos();
    let (dx, dy) = (x - e.cx, y - e.cy);
    let u = (c * dx + s * dy) / e.a;
    let v = (-s * dx + c * dy) / e.b;
    let r2 = u * u + v * v;
    if r2 < 0.09 {
        return None;
    }
    let f = r2 - 1.0;
    let gx = 2.0 * (u * c / e.a - v * s / e.b);
    let gy = 2.0 * (u * s / e.a + v * c / e.b);
    let g = gx.hypot(gy);
    if g.is_nan() || g <= 0.0 {
        return None;
    }
    Some(ContourPoint {
        distance: f.abs() / g,
        angle: v.atan2(u),
        steepest: gx.abs().max(gy.abs()) / g,
    })
}

/// Draws the outline of `e` (image coordinates of `img`) as a line `width` pixels wide:
/// every pixel whose centre is within `width / 2` of the contour (by the first-order distance,
/// with a 0.05 px margin for its error), and inside `clip`. A line too thin for that to
/// close it (a pixel wide, where the contour runs nearly level or upright between pixel
/// centres) also takes every pixel whose centre lies within half a pixel of it along the
/// image axis nearest its normal, as a line drawn column by column (or row by row) does, so
/// that it never breaks. With
/// `dash = Some((on, off))` the line is interrupted along the contour (lengths in pixels,
/// measured approximately by the parametric angle times the mean radius).
pub fn draw_ellipse(
    img: &mut RgbImage,
    e: &Ellipse,
    width: f64,
    colour: Rgb<u8>,
    dash: Option<(f64, f64)>,
    clip: Rect,
) {
    if !e.is_valid() {
        return;
    }
    let half = (width / 2.0).max(0.5) - 0.05;
    let bb = e.bounding_box();
    let area = Rect {
        x0: (bb.x - half - 1.0).floor().max(-1.0) as i64,
        y0: (bb.y - half - 1.0).floor().max(-1.0) as i64,
        x1: (bb.x + bb.w + half + 2.0).ceil().min(1e9) as i64,
        y1: (bb.y + bb.h + half + 2.0).ceil().min(1e9) as i64,
    };
    let r = Rect {
        x0: area.x0.max(clip.x0),
        y0: area.y0.max(clip.y0),
        x1: area.x1.min(clip.x1),
        y1: area.y1.min(clip.y1),
    }
    .clip_to(img);
    let mean_r = 0.5 * (e.a + e.b);
    for y in r.y0..r.y1 {
        for x in r.x0..r.x1 {
            let Some(ContourPoint {
                distance: d,
                angle: phi,
                steepest,
            }) = contour_point(e, x as f64, y as f64)
            else {
                continue;
            };
            // Half a pixel along the axis nearest the normal is `steepest / 2` across it.
            if d > half.max(0.5 * steepest) {
                continue;
            }
            if let Some((on, off)) = dash {
                let arc = (phi + std::f64::consts::PI) * mean_r;
                if arc.rem_euclid(on + off) >= on {
                    continue;
                }
            }
            img.put_pixel(x as u32, y as u32, colour);
        }
    }
}

/// Orientation of a [`draw_bar`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BarAxis {
    /// Grows left or right from the middle of its rectangle.
    Horizontal,
    /// Grows up or down from the middle of its rectangle.
    Vertical,
}

/// Draws a bar centred in `r`: a thin track with ticks at the middle, at the halves and at
/// the ends, and a filled bar from the middle over `frac` of the half length (clamped to
/// `[-1, 1]`; positive to the right for a horizontal bar, downwards for a vertical one).
pub fn draw_bar(
    img: &mut RgbImage,
    r: Rect,
    axis: BarAxis,
    frac: f64,
    colour: Rgb<u8>,
    track: Rgb<u8>,
) {
    let frac = if frac.is_finite() {
        frac.clamp(-1.0, 1.0)
    } else {
        0.0
    };
    // Work in (along, across) coordinates.
    let (len, thick) = match axis {
        BarAxis::Horizontal => (r.width(), r.height()),
        BarAxis::Vertical => (r.height(), r.width()),
    };
    if len < 3 || thick < 1 {
        return;
    }
    let put = |img: &mut RgbImage, a0: i64, a1: i64, c0: i64, c1: i64, col: Rgb<u8>| {
        let rr = match axis {
            BarAxis::Horizontal => Rect {
                x0: r.x0.saturating_add(a0),
                x1: r.x0.saturating_add(a1),
                y0: r.y0.saturating_add(c0),
                y1: r.y0.saturating_add(c1),
            },
            BarAxis::Vertical => Rect {
                x0: r.x0.saturating_add(c0),
                x1: r.x0.saturating_add(c1),
                y0: r.y0.saturating_add(a0),
                y1: r.y0.saturating_add(a1),
            },
        };
        fill_rect(img, rr, col);
    };
    let mid = len / 2;
    let half = (len - 1) / 2;
    let tc = thick / 2;
    // Track and ticks.
    put(img, 0, len, tc, tc + 1, track);
    for t in [0, half / 2, half, half + half / 2, 2 * half] {
        let a = mid - half + t;
        let tl = if t == half { thick } else { (thick / 2).max(1) };
        put(img, a, a + 1, tc - tl / 2, tc - tl / 2 + tl, track);
    }
    // The bar.
    let n = (frac.abs() * half as f64).round() as i64;
    if n > 0 {
        let (a0, a1) = if frac > 0.0 {
            (mid + 1, mid + 1 + n)
        } else {
            (mid - n, mid)
        };
        let m = (thick / 6).max(0);
        put(img, a0, a1, m, thick - m, colour);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upscale_and_fill() {
        let mut img = RgbImage::new(2, 1);
        img.put_pixel(1, 0, Rgb([9, 8, 7]));
        let up = upscale_nearest(&img, 3);
        assert_eq!((up.width(), up.height()), (6, 3));
        assert_eq!(*up.get_pixel(3, 2), Rgb([9, 8, 7]));
        assert_eq!(*up.get_pixel(2, 2), Rgb([0, 0, 0]));
        // Input pixel 1's centre is the centre of its block, columns 3-5.
        assert_eq!(upscaled(1.0, 3), 4.0);
        let e = upscaled_ellipse(&Ellipse::new(1.0, 0.0, 2.0, 0.5), 3);
        assert_eq!((e.cx, e.cy, e.a, e.b), (4.0, 1.0, 6.0, 1.5));
        let mut img = RgbImage::new(4, 4);
        fill_rect(&mut img, Rect::new(-2, 2, 4, 10), Rgb([1, 1, 1]));
        assert_eq!(img.pixels().filter(|p| p[0] == 1).count(), 4);
    }

    #[test]
    fn sampson_distance_is_close_to_the_true_distance_near_the_contour() {
        let e = Ellipse {
            cx: 50.0,
            cy: 40.0,
            a: 30.0,
            b: 12.0,
            theta: 0.4,
        };
        for k in 0..40 {
            let phi = k as f64 * 0.157;
            let (px, py) = e.point_at(phi);
            let (nx, ny) = e.normal_at(phi);
            for &d in &[-1.0, -0.5, 0.5, 1.0] {
                let (dd, _) = contour_distance(&e, px + d * nx, py + d * ny).unwrap();
                assert!((dd - f64::abs(d)).abs() < 0.1, "{phi} {d} {dd}");
            }
        }
        assert!(contour_distance(&e, 50.0, 40.0).is_none());
    }
}
