//! Exposure: a change of light over the whole frame between two frames (a camera's exposure
//! or gain stepping, a light switched on or off), measured as each channel's gain, and
//! undone so that later stages see the light the target's models were taken in.
//!
//! A gain in linear light is a gain in gamma-encoded values too (`(kL)^γ = k^γ L^γ`), so a
//! change of exposure scales each channel's 8-bit values by one factor. The factor between
//! two frames is measured as the median, over the frame's pixels, of a channel's value in the
//! new frame over its value in the old. The median is the robust choice: objects that move,
//! or a camera that pans, change fewer than half of the pixels between two frames, so they
//! move the median little, while a change of light moves every pixel by the same factor.
//!
//! ```
//! use pftrack::frames::exposure::{channel_gains, undo_gain};
//! let bright = image::RgbImage::from_fn(64, 48, |x, y| {
//!     image::Rgb([(40 + x * 2) as u8, (60 + y * 3) as u8, 120])
//! });
//! // The same view with half the light.
//! let dark = image::RgbImage::from_fn(64, 48, |x, y| {
//!     let p = bright.get_pixel(x, y).0;
//!     image::Rgb(p.map(|v| (f64::from(v) * 0.5).round() as u8))
//! });
//! let g = channel_gains(&bright, &dark, 1).expect("enough pixels in range");
//! assert!(g.iter().all(|g| (g - 0.5).abs() < 0.02));
//! // Brought back to the first frame's light.
//! let back = undo_gain(&dark, g);
//! assert!((i32::from(back.get_pixel(10, 10).0[0]) - 60).abs() <= 2);
//! ```

use image::RgbImage;

/// Values at or below this are too dark for a ratio (quantisation dominates).
const DARK: u8 = 12;
/// Values at or above this may be clipped.
const BRIGHT: u8 = 250;
/// The fewest pixels in range, per channel, for a gain to be measured.
const MIN_PIXELS: usize = 64;

/// Each channel's gain from `prev` to `cur` (of the same size): the median over the pixels
/// of `cur / prev`, taken on every `stride`-th pixel in each direction, over the pixels
/// where both values are neither dark nor clipped. `None` where the frames differ in size,
/// `stride` is 0, or a channel has fewer than 64 such pixels or fewer than a quarter of
/// those sampled (too little of the frame to speak for all of it).
pub fn channel_gains(prev: &RgbImage, cur: &RgbImage, stride: u32) -> Option<[f64; 3]> {
    if prev.dimensions() != cur.dimensions() || stride == 0 {
        return None;
    }
    let (w, h) = cur.dimensions();
    let (mut a, mut b) = (Vec::new(), Vec::new());
    sample(prev, [0, 0, w, h], stride, &mut a);
    sample(cur, [0, 0, w, h], stride, &mut b);
    gains_of(&a, &b, &mut Vec::new())
}

/// Every `stride`-th pixel of `frame` in each direction within the box `[x0, y0, x1, y1]`
/// (cut to the frame), row by row, into `out`.
fn sample(frame: &RgbImage, b: [u32; 4], stride: u32, out: &mut Vec<[u8; 3]>) {
    out.clear();
    let (w, h) = frame.dimensions();
    let (x0, y0, x1, y1) = (b[0].min(w), b[1].min(h), b[2].min(w), b[3].min(h));
    if x1 <= x0 || y1 <= y0 || stride == 0 {
        return;
    }
    for y in (y0..y1).step_by(stride as usize) {
        for x in (x0..x1).step_by(stride as usize) {
            out.push(frame.get_pixel(x, y).0);
        }
    }
}

/// The stride that samples about 2000 pixels of a box `w` by `h` (every pixel of a small
/// one).
fn stride_for(w: u32, h: u32) -> u32 {
    ((f64::from(w) * f64::from(h) / 2000.0).sqrt().round() as u32).max(1)
}

/// Whether a frame's samples hold enough pixels in range in every channel to measure a gain
/// from ([`gains_of`]'s rule for one frame: 64 at least, and a quarter of those sampled).
fn in_range_enough(samples: &[[u8; 3]]) -> bool {
    (0..3).all(|ch| {
        let n = samples
            .iter()
            .filter(|p| p[ch] > DARK && p[ch] < BRIGHT)
            .count();
        n >= MIN_PIXELS && n * 4 >= samples.len()
    })
}

/// [`channel_gains`] on two frames' samples taken alike; `ratios` is scratch space.
fn gains_of(prev: &[[u8; 3]], cur: &[[u8; 3]], ratios: &mut Vec<f32>) -> Option<[f64; 3]> {
    if prev.len() != cur.len() {
        return None;
    }
    let in_range = |v: u8| v > DARK && v < BRIGHT;
    let mut gains = [1.0; 3];
    for (ch, g) in gains.iter_mut().enumerate() {
        ratios.clear();
        ratios.extend(
            prev.iter()
                .zip(cur)
                .filter(|(p, c)| in_range(p[ch]) && in_range(c[ch]))
                .map(|(p, c)| f32::from(c[ch]) / f32::from(p[ch])),
        );
        if ratios.len() < MIN_PIXELS || ratios.len() * 4 < prev.len() {
            return None;
        }
        let mid = ratios.len() / 2;
        let (_, m, _) = ratios.select_nth_unstable_by(mid, f32::total_cmp);
        *g = f64::from(*m);
    }
    Some(gains)
}

/// `frame` with each channel divided by its `gain` (rounded, and clipped to 0-255): the
/// view as it would look in the light before the change. Gains that are not positive and
/// finite leave their channel as it is.
pub fn undo_gain(frame: &RgbImage, gain: [f64; 3]) -> RgbImage {
    let mut lut = [[0u8; 256]; 3];
    for (table, g) in lut.iter_mut().zip(gain) {
        let g = if g.is_finite() && g > 0.0 { g } else { 1.0 };
        for (v, out) in table.iter_mut().enumerate() {
            *out = (v as f64 / g).round().clamp(0.0, 255.0) as u8;
        }
    }
    let mut out = frame.clone();
    for p in out.pixels_mut() {
        for ch in 0..3 {
            p.0[ch] = lut[ch][usize::from(p.0[ch])];
        }
    }
    out
}

/// The least change between two frames (as a log gain, about 2 %) that counts towards a
/// change of light: smaller ones are what moving objects, a panning camera and compression
/// make of a frame's median.
const FLOOR: f64 = 0.02;

/// Undoes changes of light over a sequence. Each frame's gain from the one before is
/// measured ([`channel_gains`]); a run of frames whose gain in a channel moves the same way
/// by more than 2 % each is a change of light once the run's total passes `1 + jump` (or
/// `1 / (1 + jump)`): a light switched in one frame, or a camera's exposure ramping over a
/// few. The runs' gains accumulate, and every frame is handed on with the accumulated gain
/// undone ([`undo_gain`]), but never more of it than the light has changed since the start
/// with every change counted, the small ones too, and what is undone only ever shrinks
/// towards that: light that comes back too slowly to be taken (an exposure recovering over
/// seconds after a jump) is followed back, and a change taken wrongly fades as it is
/// measured back. Everything else is left alone: moving objects, a panning camera, flicker
/// and compression move a frame's median by a few percent, back and forth (on the project's
/// four real sequences no run of such changes passes 7.8 %), and a slow change of light is
/// left to the models that adapt. More than half of the frame changing at once (a large
/// object, a pan onto a brighter scene, a cut) reads as a change of light to the frame's
/// median; the target's box, given, must read it too ([`Compensator::next`]). While a change
/// is undone, each frame is also measured directly against the reference light, the last
/// frame handed on as it was, measured, with no change under way: light back where it was
/// there is undone no more, whatever the changes counted one by one add up to (a strobe's
/// flashes, or a cut away and back, leave nothing behind). A frame too dark or too bright to
/// measure is passed over: the next one is measured against the last that could be (or,
/// where that one could not be, replaces it).
#[derive(Debug, Clone)]
pub struct Compensator {
    jump: f64,
    /// The gain undone: the runs' gains taken, multiplied, held within what was measured.
    gain: [f64; 3],
    /// Each channel's current run: its total log gain, whether it has been taken as a
    /// change of light (its later frames are then taken as they come), and its total log gain
    /// over the target's region.
    run: [(f64, bool, f64); 3],
    /// Each channel's log gain from the start's frame, every measured change counted.
    total: [f64; 3],
    /// The previous frame (empty before the first), and scratch space for the two frames'
    /// samples ([`sample`]) and their ratios.
    prev: RgbImage,
    samples: (Vec<[u8; 3]>, Vec<[u8; 3]>),
    /// The previous frame's samples over the whole frame ([`Compensator::sample_whole`]) and
    /// the current frame's: each frame is sampled once, for its gain, whether it can be
    /// measured at all, the reference light, and as the next frame's previous.
    whole: (Vec<[u8; 3]>, Vec<[u8; 3]>),
    ratios: Vec<f32>,
    /// The reference light: the last frame handed on as it was, measured against the one
    /// before, with no change under way, sampled over the whole frame; its size,
    /// and `total` then: what a frame in other light is measured against directly, to see
    /// the light come back ([`Compensator::next`]).
    reference: (Vec<[u8; 3]>, (u32, u32), [f64; 3]),
}

impl Compensator {
    /// A compensator that takes a run of changes totalling more than `jump` (a share: 0.15
    /// is 15 %) as a change of light. It starts at unit gain, with no previous frame.
    pub fn new(jump: f64) -> Self {
        Self {
            jump,
            gain: [1.0; 3],
            run: [(0.0, false, 0.0); 3],
            total: [0.0; 3],
            prev: RgbImage::new(0, 0),
            samples: (Vec::new(), Vec::new()),
            whole: (Vec::new(), Vec::new()),
            ratios: Vec::new(),
            reference: (Vec::new(), (0, 0), [0.0; 3]),
        }
    }

    /// Starts over from `frame`: its light is the reference (unit gain).
    pub fn reset(&mut self, frame: &RgbImage) {
        self.gain = [1.0; 3];
        self.run = [(0.0, false, 0.0); 3];
        self.total = [0.0; 3];
        Self::sample_whole(frame, &mut self.whole.1);
        self.keep(frame);
        self.take_reference(frame.dimensions());
    }

    /// Samples `frame` over the whole of it ([`sample`], about 2000 pixels) into `out`.
    fn sample_whole(frame: &RgbImage, out: &mut Vec<[u8; 3]>) {
        let (w, h) = frame.dimensions();
        sample(frame, [0, 0, w, h], stride_for(w, h), out);
    }

    /// Takes the current frame (of `size`, sampled in `whole.1`), handed on as it is, as the
    /// reference light.
    fn take_reference(&mut self, size: (u32, u32)) {
        let (samples, at, total) = &mut self.reference;
        samples.clone_from(&self.whole.1);
        *at = size;
        *total = self.total;
    }

    /// Whether the current frame (of `size`, sampled in `whole.1`) is in the reference's
    /// light: its gain from the reference frame, measured directly, within the floor of 1 in
    /// every channel.
    fn in_reference_light(&mut self, size: (u32, u32)) -> bool {
        let (samples, at, _) = &self.reference;
        if *at != size || samples.is_empty() {
            return false;
        }
        gains_of(samples, &self.whole.1, &mut self.ratios)
            .is_some_and(|g| g.iter().all(|g| g.ln().abs() <= FLOOR))
    }

    /// Keeps `frame` as the previous one, reusing the buffer, with its samples over the whole
    /// frame (taken into `whole.1` before).
    fn keep(&mut self, frame: &RgbImage) {
        if self.prev.dimensions() == frame.dimensions() {
            self.prev.copy_from_slice(frame);
        } else {
            self.prev = frame.clone();
        }
        self.whole.0.clone_from(&self.whole.1);
    }

    /// Each channel's gain from the previous frame to `frame` over the box `b`, sampled at
    /// about 2000 pixels ([`gains_of`]); `None` for a frame of another size.
    fn gains_over(&mut self, frame: &RgbImage, b: [u32; 4]) -> Option<[f64; 3]> {
        if self.prev.dimensions() != frame.dimensions() {
            return None;
        }
        let (w, h) = frame.dimensions();
        let b = [b[0].min(w), b[1].min(h), b[2].min(w), b[3].min(h)];
        let stride = stride_for(b[2].saturating_sub(b[0]), b[3].saturating_sub(b[1]));
        let (a, c) = &mut self.samples;
        sample(&self.prev, b, stride, a);
        sample(frame, b, stride, c);
        gains_of(a, c, &mut self.ratios)
    }

    /// The gain undone on the last frame handed on (1 in every channel when none is).
    pub fn gain(&self) -> [f64; 3] {
        self.gain
    }

    /// `frame` (the next in the sequence) in the reference light: measures its gain from the
    /// previous frame, takes it into the accumulated gain where it belongs to a change of
    /// light, and undoes the accumulated gain. Borrowed as it is while the gain is 1.
    ///
    /// `target`, the target's box in the previous frame (`x0, y0, x1, y1` in pixels, cut to
    /// the frame), is a second witness: a run is taken only where the light over the target
    /// changed the same way, by at least half as much, so a background that brightens around
    /// a target that does not (more than half of the frame changing) is not undone on it.
    /// Without a box, or with too few pixels in it to measure, the frame's gain speaks alone.
    pub fn next<'a>(
        &mut self,
        frame: &'a RgbImage,
        target: Option<[u32; 4]>,
    ) -> std::borrow::Cow<'a, RgbImage> {
        let undoing = self.gain != [1.0; 3];
        let size = frame.dimensions();
        // The gain over the whole frame, from the previous frame's samples (`gains_over` of
        // the whole frame, each frame sampled once).
        Self::sample_whole(frame, &mut self.whole.1);
        let measured = (self.prev.dimensions() == size)
            .then(|| gains_of(&self.whole.0, &self.whole.1, &mut self.ratios))
            .flatten();
        let on_target = target.and_then(|b| self.gains_over(frame, b));
        // A frame too dark or too bright to measure (too few pixels in range) is no
        // reference for the next: the change into it and the change out of it would both go
        // unmeasured, and the light coming back after it would never be seen. The next
        // frame is measured against the last one that was measured. A frame that could be
        // measured on its own, where the previous could not (a dark start), takes its place.
        let alone = in_range_enough(&self.whole.1);
        if measured.is_some() || alone || self.prev.dimensions() != size {
            self.keep(frame);
        }
        let bar = (1.0 + self.jump).ln();
        for ch in 0..3 {
            let d = measured.map_or(0.0, |g| g[ch].ln());
            self.total[ch] += d;
            let (total, taken, on) = &mut self.run[ch];
            if d.abs() <= FLOOR {
                (*total, *taken, *on) = (0.0, false, 0.0);
                continue;
            }
            if *total * d < 0.0 {
                (*total, *taken, *on) = (0.0, false, 0.0);
            }
            *total += d;
            *on += on_target.map_or(d, |g| g[ch].ln());
            let witnessed = *on * *total > 0.0 && on.abs() >= 0.5 * total.abs();
            if *taken {
                self.gain[ch] *= d.exp();
            } else if total.abs() > bar && witnessed {
                self.gain[ch] *= total.exp();
                *taken = true;
            }
        }
        // Never more undone than the light has changed since the start, every change
        // counted: what a change taken is held at only shrinks, towards 1, as the light is
        // measured coming back (too slowly for a run), so neither light that returned nor a
        // change taken wrongly and measured back is held against later frames.
        for (g, t) in self.gain.iter_mut().zip(self.total) {
            let l = g.ln();
            let held = if l * t > 0.0 {
                l.signum() * l.abs().min(t.abs())
            } else {
                0.0
            };
            // Within the floor of 1 is the start's light.
            *g = if held.abs() <= FLOOR { 1.0 } else { held.exp() };
        }
        // Light back where it was on the last frame handed on as it was, measured against
        // that frame directly (where a change was being undone, or one is taken): nothing is
        // undone, and the changes counted since are dropped.
        // Counted one by one, the changes into other light and back need not cancel (8-bit
        // values' ratios are biased one way, and a cut to another scene and back measures
        // two different medians), and what they leave would be undone on every later frame.
        if (undoing || self.run.iter().any(|r| r.1)) && self.in_reference_light(size) {
            self.gain = [1.0; 3];
            self.total = self.reference.2;
            self.run = [(0.0, false, 0.0); 3];
        }
        // The reference: a frame handed on as it is, measured against the one before, with no
        // change under way (one still building up to the jump is handed on as it is too, and
        // taken as the reference would snap the change back once it is taken).
        let idle = self.run.iter().all(|r| r.0 == 0.0 && !r.1);
        if self.gain == [1.0; 3] {
            if idle && measured.is_some() {
                self.take_reference(size);
            }
            std::borrow::Cow::Borrowed(frame)
        } else {
            std::borrow::Cow::Owned(undo_gain(frame, self.gain))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn textured(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            let v = |k: u32| (30 + (x * k + y * (k + 3)) % 200) as u8;
            image::Rgb([v(7), v(11), v(13)])
        })
    }

    /// Asserts every channel's gain within 0.02 of `want`.
    #[track_caller]
    fn assert_gain_near(c: &Compensator, want: f64) {
        assert!(
            c.gain().iter().all(|g| (g - want).abs() < 0.02),
            "{:?} against {want}",
            c.gain()
        );
    }

    fn scaled(f: &RgbImage, g: [f64; 3]) -> RgbImage {
        let mut out = f.clone();
        for p in out.pixels_mut() {
            for (v, g) in p.0.iter_mut().zip(g) {
                *v = (f64::from(*v) * g).round().min(255.0) as u8;
            }
        }
        out
    }

    #[test]
    fn the_same_frame_has_unit_gains() {
        let f = textured(80, 60);
        assert_eq!(channel_gains(&f, &f, 2), Some([1.0; 3]));
    }

    #[test]
    fn a_change_of_light_is_measured_per_channel() {
        let f = textured(80, 60);
        let g = [0.5, 0.7, 1.3];
        let got = channel_gains(&f, &scaled(&f, g), 1).expect("measured");
        for ch in 0..3 {
            assert!((got[ch] - g[ch]).abs() < 0.02, "{got:?} vs {g:?}");
        }
    }

    #[test]
    fn a_moving_object_over_less_than_half_the_frame_is_not_a_change_of_light() {
        let f = textured(80, 60);
        let mut g = f.clone();
        // A bright object over a third of the frame.
        for y in 0..60 {
            for x in 0..26 {
                g.put_pixel(x, y, image::Rgb([240, 240, 240]));
            }
        }
        let got = channel_gains(&f, &g, 1).expect("measured");
        assert!(got.iter().all(|v| (v - 1.0).abs() < 1e-6), "{got:?}");
    }

    #[test]
    fn too_few_pixels_in_range_give_no_gain() {
        let black = RgbImage::new(80, 60);
        assert_eq!(channel_gains(&black, &black, 1), None);
        let white = RgbImage::from_pixel(80, 60, image::Rgb([255, 255, 255]));
        assert_eq!(channel_gains(&white, &textured(80, 60), 1), None);
        assert_eq!(channel_gains(&textured(80, 60), &textured(80, 61), 1), None);
        assert_eq!(channel_gains(&textured(80, 60), &textured(80, 60), 0), None);
        // A frame of 7x7 pixels has fewer than 64 to measure.
        assert_eq!(channel_gains(&textured(7, 7), &textured(7, 7), 1), None);
        assert_eq!(
            channel_gains(&RgbImage::new(0, 0), &RgbImage::new(0, 0), 1),
            None
        );
    }

    #[test]
    fn undoing_a_gain_restores_the_frame() {
        let f = textured(80, 60);
        let g = [0.5, 0.8, 1.2];
        let s = scaled(&f, g);
        let back = undo_gain(&s, g);
        for ((a, b), s) in f.pixels().zip(back.pixels()).zip(s.pixels()) {
            for ch in 0..3 {
                // Rounding loses at most a level or two; what the change clipped is lost.
                let d = (i32::from(a.0[ch]) - i32::from(b.0[ch])).abs();
                assert!(d <= 2 || s.0[ch] == 255, "{a:?} {b:?}");
            }
        }
        // Unit and invalid gains leave the frame alone.
        assert_eq!(undo_gain(&f, [1.0; 3]), f);
        assert_eq!(undo_gain(&f, [0.0, f64::NAN, -1.0]), f);
    }

    #[test]
    fn a_sudden_change_of_light_is_undone_until_it_is_reversed() {
        let f = textured(80, 60);
        let mut c = Compensator::new(0.15);
        c.reset(&f);
        // Small changes pass as they are.
        let slight = scaled(&f, [0.99, 0.99, 0.99]);
        assert_eq!(*c.next(&slight, None), slight);
        assert_eq!(c.gain(), [1.0; 3]);
        // Half the light: undone, and still undone on the frames after.
        let dark = scaled(&slight, [0.5, 0.5, 0.5]);
        for _ in 0..3 {
            let out = c.next(&dark, None);
            assert_gain_near(&c, 0.5);
            let diff = out
                .pixels()
                .zip(slight.pixels())
                .map(|(a, b)| (i32::from(a.0[1]) - i32::from(b.0[1])).abs())
                .max();
            assert!(diff.is_some_and(|d| d <= 2), "{diff:?}");
        }
        // The light back: the gain returns to 1, and the frame passes as it is.
        assert_eq!(*c.next(&slight, None), slight);
        assert_eq!(c.gain(), [1.0; 3]);
        // A ramp of 6 % a frame is taken once its run passes 15 %, whole.
        let mut ramp = slight.clone();
        let mut want = 1.0;
        for k in 0..4 {
            ramp = scaled(&ramp, [0.94; 3]);
            want *= 0.94;
            c.next(&ramp, None);
            let g = c.gain()[0];
            if k < 2 {
                assert!((g - 1.0).abs() < 0.03, "frame {k}: {g}");
            } else {
                assert!((g - want).abs() < 0.03, "frame {k}: {g} against {want}");
            }
        }
        // Changes back and forth, each under 15 %, are not taken, however many: at most,
        // what is undone shrinks to the least the light was measured changed (here 10 %
        // less), never more.
        let before = c.gain()[0].ln();
        for k in 0..10 {
            let g = if k % 2 == 0 { 1.1 } else { 1.0 / 1.1 };
            ramp = scaled(&ramp, [g; 3]);
            c.next(&ramp, None);
        }
        let after = c.gain()[0].ln();
        assert!(after <= 0.0 && after >= before, "{before} -> {after}");
        assert!(after - before < 1.1f64.ln() + 0.01, "{before} -> {after}");
        // A reset takes the frame's light as the reference.
        c.reset(&dark);
        assert_eq!(c.gain(), [1.0; 3]);
        assert_eq!(*c.next(&dark, None), dark);
    }

    /// Light halved, then coming back at 1 % a frame (an exposure recovering too slowly for
    /// a run to be taken): what is undone follows it back, and once the light is back the
    /// frames pass as they are.
    #[test]
    fn light_that_comes_back_slowly_is_followed_back() {
        let f = textured(80, 60);
        let mut c = Compensator::new(0.15);
        c.reset(&f);
        let mut light = 0.5;
        c.next(&scaled(&f, [light; 3]), None);
        assert_gain_near(&c, 0.5);
        while light < 1.0 {
            light = (light * 1.01).min(1.0);
            let frame = scaled(&f, [light; 3]);
            c.next(&frame, None);
            let g = c.gain()[1];
            // Within quantisation of the light, or 1 within the floor of it.
            assert!(
                (g - light).abs() < 0.03 || (g == 1.0 && light > 0.97),
                "light {light}: gain {g}"
            );
        }
        assert_eq!(*c.next(&f, None), f);
        assert_eq!(c.gain(), [1.0; 3]);
    }

    /// Light dimmed at 1 % a frame (never taken) and then restored in one frame: the jump is
    /// a change of light, but the light is the start's again, so nothing is undone.
    #[test]
    fn a_jump_back_to_the_starts_light_is_not_undone() {
        let f = textured(80, 60);
        let mut c = Compensator::new(0.15);
        c.reset(&f);
        let mut light = 1.0;
        for _ in 0..70 {
            light *= 0.99;
            c.next(&scaled(&f, [light; 3]), None);
            assert_eq!(c.gain(), [1.0; 3], "light {light}");
        }
        assert_eq!(*c.next(&f, None), f);
        assert_eq!(c.gain(), [1.0; 3]);
    }

    /// More than half of the frame darkening around a target that does not: the frame's
    /// median reads it as a change of light, the target's box does not, and with the box
    /// given nothing is undone; the whole frame darkening is undone with it.
    #[test]
    fn the_targets_box_witnesses_a_change_of_light() {
        let f = textured(80, 60);
        let target = [30, 20, 50, 40];
        let mut around = scaled(&f, [0.5; 3]);
        for y in 20..40 {
            for x in 30..50 {
                around.put_pixel(x, y, *f.get_pixel(x, y));
            }
        }
        let mut c = Compensator::new(0.15);
        c.reset(&f);
        assert_eq!(*c.next(&around, Some(target)), around);
        assert_eq!(c.gain(), [1.0; 3]);
        // Without the box, the frame's median speaks alone.
        c.reset(&f);
        c.next(&around, None);
        assert_gain_near(&c, 0.5);
        // The whole frame: witnessed.
        c.reset(&f);
        c.next(&scaled(&f, [0.5; 3]), Some(target));
        assert_gain_near(&c, 0.5);
        // A box out of the frame, or empty, has nothing to say.
        c.reset(&f);
        c.next(&scaled(&f, [0.5; 3]), Some([200, 200, 300, 300]));
        assert_gain_near(&c, 0.5);
    }

    /// Nearly black, with a little colour noise (not grey): every value under the darkest
    /// measured.
    fn near_black(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([((x + y) % 5) as u8, ((x * 3 + y) % 7) as u8, (y % 4) as u8])
        })
    }

    /// Light halved, then a frame too dark to measure, then light at 70 %: the change out of
    /// the dark frame is measured against the last frame that was measured, so 70 % is undone.
    /// (Measured against the dark frame, it went unmeasured, and the halved light's gain was
    /// held for good.) The start's light after such frames is seen as well.
    #[test]
    fn light_after_a_frame_too_dark_to_measure_is_measured() {
        let f = textured(80, 60);
        let (half, dark) = (scaled(&f, [0.5; 3]), near_black(80, 60));
        let mut c = Compensator::new(0.15);
        c.reset(&f);
        for _ in 0..3 {
            c.next(&half, None);
            assert_gain_near(&c, 0.5);
        }
        assert_eq!(channel_gains(&half, &dark, 1), None);
        for _ in 0..2 {
            c.next(&dark, None);
        }
        c.next(&scaled(&f, [0.7; 3]), None);
        assert_gain_near(&c, 0.7);
        c.next(&dark, None);
        assert_eq!(*c.next(&f, None), f, "{:?}", c.gain());
        assert_eq!(c.gain(), [1.0; 3]);
    }

    /// A start too dark to measure: the first frame that can be measured takes its place, and
    /// a change of light after it is undone (the dark start had stayed the previous frame of
    /// every later one, each pair unmeasurable).
    #[test]
    fn a_start_too_dark_to_measure_gives_way_to_the_first_that_can_be() {
        let f = textured(80, 60);
        let mut c = Compensator::new(0.15);
        c.reset(&near_black(80, 60));
        for _ in 0..2 {
            c.next(&f, None);
            assert_eq!(c.gain(), [1.0; 3]);
        }
        for _ in 0..3 {
            c.next(&scaled(&f, [0.5; 3]), None);
            assert_gain_near(&c, 0.5);
        }
    }

    /// Light changing in two steps, the first under the jump: the frame of the first step is
    /// handed on as it is, but is no reference light, so when the light comes back to it
    /// the change from the start stays undone (it had been snapped back to 1).
    #[test]
    fn a_change_under_way_is_no_reference_light() {
        let f = textured(80, 60);
        let mut c = Compensator::new(0.15);
        c.reset(&f);
        c.next(&scaled(&f, [0.87; 3]), None);
        assert_eq!(c.gain(), [1.0; 3]);
        for _ in 0..2 {
            c.next(&scaled(&f, [0.75; 3]), None);
            assert_gain_near(&c, 0.75);
        }
        for _ in 0..3 {
            c.next(&scaled(&f, [0.87; 3]), None);
            assert_gain_near(&c, 0.87);
        }
    }

    /// `f` with a little noise of its own for `k` (up to a level either way, as a sensor
    /// gives), and its light scaled by `g` with the values cut down to whole levels, as a
    /// camera's do.
    fn noisy(f: &RgbImage, k: u32, g: f64) -> RgbImage {
        let mut out = f.clone();
        for (x, y, p) in out.enumerate_pixels_mut() {
            for (ch, v) in p.0.iter_mut().enumerate() {
                let n = f64::from((x * 7 + y * 11 + k * 13 + ch as u32 * 5) % 3) - 1.0;
                *v = ((f64::from(*v) + n) * g).floor().clamp(0.0, 255.0) as u8;
            }
        }
        out
    }

    /// A strobe on noisy frames of whole levels, then steady light: once the strobe stops,
    /// nothing is undone. Counted frame by frame, each dark frame and the bright one after
    /// it did not cancel (the ratios of whole levels lean one way), and 30 flashes left a
    /// gain of several percent undone on every frame after them. The same after a frame too
    /// dark to measure, handed on as it is: it is no reference light (taken as one, the
    /// strobe's bright frames were never back in it, and left a gain of 26 %).
    #[test]
    fn a_strobe_on_whole_levels_leaves_no_gain_behind() {
        let f = textured(80, 60);
        for dark_first in [false, true] {
            let mut c = Compensator::new(0.15);
            c.reset(&noisy(&f, 0, 1.0));
            if dark_first {
                c.next(&near_black(80, 60), None);
            }
            for k in 1..=60 {
                let g = if k % 2 == 1 { 0.5 } else { 1.0 };
                c.next(&noisy(&f, k, g), None);
                assert_gain_near(&c, g);
            }
            for k in 61..70 {
                c.next(&noisy(&f, k, 1.0), None);
                assert_eq!(c.gain(), [1.0; 3], "dark first {dark_first}, frame {k}");
            }
        }
    }

    /// A cut to another scene for a few frames, then back: the changes measured into the
    /// other scene and out of it are medians of different things and need not cancel, but
    /// the light is the start's again, and nothing is undone.
    #[test]
    fn a_cut_away_and_back_leaves_no_gain_behind() {
        let f = textured(80, 60);
        // A darker scene of other colours, with its own noise on each frame.
        let other = RgbImage::from_fn(80, 60, |x, y| {
            let v = |m: u32| (20 + (x * m * 3 + y * (m + 1) * 5) % 120) as u8;
            image::Rgb([v(5), v(2), v(9)])
        });
        let mut c = Compensator::new(0.15);
        c.reset(&f);
        for k in 1..=4 {
            c.next(&noisy(&other, k, 1.0), None);
        }
        assert_ne!(
            c.gain(),
            [1.0; 3],
            "the cut was not taken as a change of light"
        );
        for k in 5..10 {
            c.next(&noisy(&f, k, 1.0), None);
            assert_eq!(c.gain(), [1.0; 3], "frame {k}");
        }
    }

    /// A strobe (every second frame at half the light) is undone on its dark frames, and once
    /// it stops the frames pass as they are.
    #[test]
    fn a_strobe_is_undone_and_leaves_no_gain() {
        let f = textured(80, 60);
        let dark = scaled(&f, [0.5; 3]);
        let mut c = Compensator::new(0.15);
        c.reset(&f);
        for k in 1..=20 {
            if k % 2 == 1 {
                c.next(&dark, None);
                assert_gain_near(&c, 0.5);
            } else {
                assert_eq!(*c.next(&f, None), f, "{k}: {:?}", c.gain());
            }
        }
        assert_eq!(c.gain(), [1.0; 3]);
    }
}
