//! The rendered output frame (like the paper's Fig. 5-7).
//!
//! Layout of the image [`render_overlay`] returns, for an input of `W × H` and a scale `s`:
//!
//! ```text
//! +----------------------+---+
//! |  frame, upscaled     | T |   T: tilt bar (vertical), beside the frame's right edge
//! |  W·s × H·s, with the | I |
//! |  ellipse drawn on it | L |
//! +----------------------+---+
//! |  pan bar (horizontal)|   |   beneath the frame's bottom edge
//! +----------------------+---+
//! | #12  score 0.87  LOST    |   text panel
//! | tilt 12.3 pan -4.0 roll 1.2
//! +--------------------------+
//! ```
//!
//! The angles take one, two or three lines and the text one of three sizes, chosen from the
//! panel's width alone so that the widest text of any frame fits: every frame of a sequence
//! renders at the same size, as a video made of them needs. Both sides are even (the text
//! panel and the right margin take up an odd pixel), as H.264 in 4:2:0 needs.
//!
//! The frame sits at the top-left, untouched except for the ellipse outline; the bars and
//! the text live in margins so they never hide the image. Both bars are centred at 0° with
//! ±90° at their ends and grow in the direction the object's front turns (SPEC section 1,
//! camera looking along +z at a front facing −z): a positive pan (about the y axis) turns
//! the front to the image's left, so the pan bar grows to the left; a positive tilt (about x)
//! turns it down, so the tilt bar grows downwards. The ellipse is green, red and dashed when
//! the tracker says it is lost.

use image::{Rgb, RgbImage};

use super::draw::{
    BarAxis, Rect, draw_bar, draw_ellipse, fill_rect, upscale_nearest, upscaled_ellipse,
};
use super::font::{LINE_H, draw_text, text_size};
use crate::geometry::Ellipse;

/// What to draw on one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Overlay {
    /// Frame number (from 0), printed as `#n`.
    pub frame_index: usize,
    /// The estimated ellipse, in the input frame's pixel coordinates.
    pub ellipse: Ellipse,
    /// `[tilt, pan, roll]` = `[rx, ry, rz]` in degrees.
    pub angles_deg: [f64; 3],
    /// The tracker's confidence in `[0, 1]`.
    pub score: f64,
    /// Whether the tracker considers the target lost.
    pub lost: bool,
}

/// Background of the margins and the text panel.
pub const BACKGROUND: Rgb<u8> = Rgb([22, 22, 26]);
/// Colour of the ellipse while tracking.
pub const ELLIPSE_OK: Rgb<u8> = Rgb([60, 255, 90]);
/// Colour of the (dashed) ellipse when lost.
pub const ELLIPSE_LOST: Rgb<u8> = Rgb([255, 50, 50]);
/// Colour of the pan bar.
pub const PAN_COLOUR: Rgb<u8> = Rgb([255, 170, 0]);
/// Colour of the tilt bar.
pub const TILT_COLOUR: Rgb<u8> = Rgb([0, 200, 255]);
/// Colour of the bars' tracks and ticks.
pub const TRACK_COLOUR: Rgb<u8> = Rgb([130, 130, 140]);
/// Colour of the text.
pub const TEXT_COLOUR: Rgb<u8> = Rgb([235, 235, 235]);

/// A sensible upscaling for an input `width` pixels wide: the smallest integer factor that
/// makes the frame at least 320 px wide, between 1 and 4 (128x96 → 3, 160x120 → 2,
/// 320x240 → 1), so the text stays legible and the ellipse line thin relative to the image.
pub fn default_scale(width: u32) -> u32 {
    if width == 0 {
        return 1;
    }
    320u32.div_ceil(width).clamp(1, 4)
}

/// Where each part of the rendered frame lies (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Total width of the rendered image.
    pub width: u32,
    /// Total height of the rendered image.
    pub height: u32,
    /// The upscaled input frame (top-left).
    pub frame: Rect,
    /// The horizontal pan bar beneath the frame.
    pub pan_bar: Rect,
    /// The vertical tilt bar right of the frame.
    pub tilt_bar: Rect,
    /// The text panel at the bottom.
    pub text: Rect,
    /// Font pixel size of the text.
    pub text_px: u32,
    /// The text lines.
    pub lines: Vec<String>,
}

/// The text of an overlay: the head line `#n  score s  [LOST]` and the three angles as
/// `tilt x`, `pan y`, `roll z`.
fn text_parts(o: &Overlay) -> (String, [String; 3]) {
    let score = if o.score.is_finite() {
        format!("{:.2}", o.score)
    } else {
        "-".to_string()
    };
    let mut head = format!("#{}  score {}", o.frame_index, score);
    if o.lost {
        head.push_str("  LOST");
    }
    let f = |name: &str, v: f64| {
        if v.is_finite() {
            format!("{name} {v:.1}")
        } else {
            format!("{name} -")
        }
    };
    let [tilt, pan, roll] = o.angles_deg;
    (head, [f("tilt", tilt), f("pan", pan), f("roll", roll)])
}

/// How the three angles are spread over the text panel's lines.
#[derive(Debug, Clone, Copy)]
enum AngleLines {
    /// `tilt x pan y roll z`.
    One,
    /// `tilt x pan y`, then `roll z`.
    Two,
    /// One angle per line.
    Three,
}

impl AngleLines {
    fn lines(self, [tilt, pan, roll]: &[String; 3]) -> Vec<String> {
        match self {
            AngleLines::One => vec![format!("{tilt} {pan} {roll}")],
            AngleLines::Two => vec![format!("{tilt} {pan}"), roll.clone()],
            AngleLines::Three => vec![tilt.clone(), pan.clone(), roll.clone()],
        }
    }
}

/// The widest head line the layout makes room for: a frame index of seven digits (ten
/// million frames, 92 hours at 30 frames/s), the score and the lost label.
const WIDEST_HEAD: &str = "#0000000  score 0.00  LOST";
/// The widest angle the layout makes room for (the angles are continuous over frames, so a
/// target that turns round more than once reads beyond ±180).
const WIDEST_ANGLE: f64 = -999.9;

/// The font size and the spread of the angles for a text panel `avail` pixels wide: the
/// first of size 3 on one line of angles, size 2 on one or two, size 1 on one, two or three
/// at which the widest text of any frame fits ([`WIDEST_HEAD`], [`WIDEST_ANGLE`]; size 3 is
/// not split over lines, which would take a third of a small frame's height). It depends on the width alone, so every frame of a
/// sequence renders at one size; text wider still is clipped at the panel's edge.
fn text_fit(avail: i64) -> (u32, AngleLines) {
    let widest = ["tilt", "pan", "roll"].map(|name| format!("{name} {WIDEST_ANGLE:.1}"));
    let fits = |line: &str, px: u32| i64::from(text_size(line, px).0) <= avail;
    let choices = [
        (3, AngleLines::One),
        (2, AngleLines::One),
        (2, AngleLines::Two),
        (1, AngleLines::One),
        (1, AngleLines::Two),
    ];
    choices
        .into_iter()
        .find(|&(px, split)| {
            fits(WIDEST_HEAD, px) && split.lines(&widest).iter().all(|l| fits(l, px))
        })
        .unwrap_or((1, AngleLines::Three))
}

/// Largest side (pixels) of the upscaled frame in an overlay: a larger scale is lowered to
/// fit (160x120 at scale 1000 wanted 64 GB), and a frame already larger renders at scale 1.
pub const MAX_SCALED_SIDE: u32 = 16384;

/// `scale` (0 counts as 1) lowered so that a `w × h` frame scaled by it has no side above
/// [`MAX_SCALED_SIDE`]; at least 1.
pub fn capped_scale(w: u32, h: u32, scale: u32) -> u32 {
    let side = w.max(h).max(1);
    scale.clamp(1, (MAX_SCALED_SIDE / side).max(1))
}

/// The layout of an overlay on a `w × h` input at scale `s` (capped, [`capped_scale`]). The
/// sizes and places depend on `w`, `h` and `s` alone, not on what `o` says; only the text
/// lines do.
pub fn layout(w: u32, h: u32, scale: u32, o: &Overlay) -> Layout {
    let s = i64::from(capped_scale(w, h, scale));
    let (ws, hs) = (w as i64 * s, h as i64 * s);
    let pad = s.max(2);
    let bar = (4 * s).max(6);
    let m = bar + 2 * pad;
    let total_w = ws + m;
    let avail = total_w - 2 * pad;
    let (px, split) = text_fit(avail);
    let (head, angles) = text_parts(o);
    let mut lines = vec![head];
    lines.extend(split.lines(&angles));
    let px = i64::from(px);
    // Even sides, which video encoders in 4:2:0 (H.264's usual) need: the panel takes up the
    // odd pixel.
    let total_w = total_w + (total_w & 1);
    let text_h = lines.len() as i64 * LINE_H as i64 * px + 2 * pad - 2 * px;
    let text_h = text_h + ((hs + m + text_h) & 1);
    let total_h = hs + m + text_h;
    Layout {
        width: total_w as u32,
        height: total_h as u32,
        frame: Rect::new(0, 0, ws, hs),
        pan_bar: Rect::new(0, hs + pad, ws, bar),
        tilt_bar: Rect::new(ws + pad, 0, bar, hs),
        text: Rect::new(0, hs + m, total_w, text_h),
        text_px: px as u32,
        lines,
    }
}

/// Renders one output frame: the input upscaled `scale` times (0 counts as 1, capped by
/// [`capped_scale`]; see [`default_scale`]), the ellipse, the pan and tilt bars and the text
/// (see the module docs for the layout).
pub fn render_overlay(frame: &RgbImage, o: &Overlay, scale: u32) -> RgbImage {
    let s = capped_scale(frame.width(), frame.height(), scale);
    let lay = layout(frame.width(), frame.height(), s, o);
    let mut img = RgbImage::from_pixel(lay.width, lay.height, BACKGROUND);
    let up = upscale_nearest(frame, s);
    for (x, y, p) in up.enumerate_pixels() {
        img.put_pixel(x, y, *p);
    }
    let e = upscaled_ellipse(&o.ellipse, s);
    let width = if s >= 2 { 2.0 } else { 1.0 };
    let (colour, dash) = if o.lost {
        (ELLIPSE_LOST, Some((6.0 * width, 4.0 * width)))
    } else {
        (ELLIPSE_OK, None)
    };
    draw_ellipse(&mut img, &e, width, colour, dash, lay.frame);

    let [tilt, pan, _] = o.angles_deg;
    draw_bar(
        &mut img,
        lay.pan_bar,
        BarAxis::Horizontal,
        -pan / 90.0,
        PAN_COLOUR,
        TRACK_COLOUR,
    );
    draw_bar(
        &mut img,
        lay.tilt_bar,
        BarAxis::Vertical,
        tilt / 90.0,
        TILT_COLOUR,
        TRACK_COLOUR,
    );

    let px = lay.text_px as i64;
    let pad = (s as i64).max(2);
    fill_rect(&mut img, lay.text, BACKGROUND);
    for (i, line) in lay.lines.iter().enumerate() {
        let y = lay.text.y0 + pad + i as i64 * LINE_H as i64 * px;
        if i == 0 && o.lost {
            // "LOST" in the ellipse's lost colour.
            let (head, _) = line.split_at(line.len() - "LOST".len());
            let x = draw_text(&mut img, pad, y, head, TEXT_COLOUR, px as u32);
            draw_text(&mut img, x, y, "LOST", ELLIPSE_LOST, px as u32);
        } else {
            draw_text(&mut img, pad, y, line, TEXT_COLOUR, px as u32);
        }
    }
    img
}
