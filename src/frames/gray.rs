//! A single-channel `f32` image: what SIFT, block matching and gradients work on.

use image::RgbImage;

/// A grey image with values in `[0, 1]`, row-major, `data[y * width + x]`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GrayF32 {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixel values, row-major.
    pub data: Vec<f32>,
}

/// Luma of an RGB8 pixel in `[0, 1]` (ITU-R BT.601 weights). One definition for the whole
/// project so the CPU and GPU paths agree.
#[inline]
pub fn luma(r: u8, g: u8, b: u8) -> f32 {
    (0.299 * r as f32 + 0.587 * g as f32 + 0.114 * b as f32) / 255.0
}

impl GrayF32 {
    /// A zero image.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width as usize * height as usize],
        }
    }

    /// The luma of an RGB frame (see [`luma`]).
    pub fn from_rgb(img: &RgbImage) -> Self {
        let data = img.pixels().map(|p| luma(p[0], p[1], p[2])).collect();
        Self {
            width: img.width(),
            height: img.height(),
            data,
        }
    }

    /// Pixel at `(x, y)`, coordinates clamped to the image (edge replication); 0 for an
    /// empty image, or where `data` is shorter than `width * height` (its fields are public).
    #[inline]
    pub fn get_clamped(&self, x: i64, y: i64) -> f32 {
        let x = x.clamp(0, (i64::from(self.width) - 1).max(0)) as usize;
        let y = y.clamp(0, (i64::from(self.height) - 1).max(0)) as usize;
        self.data
            .get(y * self.width as usize + x)
            .copied()
            .unwrap_or(0.0)
    }

    /// Bilinear sample at a sub-pixel position, edge replication outside.
    ///
    /// Inside the image (all four neighbours present) the four pixels are read from one
    /// index without clamping; elsewhere each is clamped. Both give the same value: only the
    /// reads differ. This runs for every template point of every particle, so it avoids
    /// `f32::floor` (a libm call on baseline x86-64) where a truncation is exact.
    #[inline]
    pub fn sample(&self, x: f32, y: f32) -> f32 {
        let (w, h) = (self.width as usize, self.height as usize);
        // `x >= 0` truncates towards zero, which is the floor; NaN fails both tests.
        if x >= 0.0 && y >= 0.0 && x < (w as f32 - 1.0) && y < (h as f32 - 1.0) {
            let (xi, yi) = (x as usize, y as usize);
            let fx = x - xi as f32;
            let fy = y - yi as f32;
            let i = yi * w + xi;
            if let (Some(top), Some(bot)) =
                (self.data.get(i..i + 2), self.data.get(i + w..i + w + 2))
            {
                return lerp_2x2(top[0], top[1], bot[0], bot[1], fx, fy);
            }
        }
        self.sample_clamped(x, y)
    }

    /// [`Self::sample`] at each `(xs[i], ys[i])`, into `out[i]`, for the `i` the shortest of
    /// the three slices holds: the same values bit for bit, eight at a time (AVX2 gathers)
    /// where the CPU has AVX2. Template correlation samples a few hundred points for each of
    /// hundreds of particles a frame, which is where this pays.
    pub fn sample_many(&self, xs: &[f32], ys: &[f32], out: &mut [f32]) {
        let n = out.len().min(xs.len()).min(ys.len());
        let (xs, ys, out) = (&xs[..n], &ys[..n], &mut out[..n]);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
            // calling a function compiled with that target feature.
            unsafe { avx2::sample_many(self, xs, ys, out) };
            return;
        }
        self.sample_many_scalar(xs, ys, out);
    }

    /// [`Self::sample_many`] one point at a time.
    fn sample_many_scalar(&self, xs: &[f32], ys: &[f32], out: &mut [f32]) {
        for ((o, &x), &y) in out.iter_mut().zip(xs).zip(ys) {
            *o = self.sample(x, y);
        }
    }

    /// [`Self::sample`] with every pixel read through [`Self::get_clamped`]: its form at
    /// and beyond the border.
    fn sample_clamped(&self, x: f32, y: f32) -> f32 {
        // Beyond a pixel past the border every neighbour is the edge's: held there, a far or
        // infinite position cannot overflow the integer neighbours (it panicked at 1e19).
        let x = x.clamp(-1.0, self.width as f32);
        let y = y.clamp(-1.0, self.height as f32);
        let (x0, y0) = (x.floor(), y.floor());
        let (xi, yi) = (x0 as i64, y0 as i64);
        lerp_2x2(
            self.get_clamped(xi, yi),
            self.get_clamped(xi + 1, yi),
            self.get_clamped(xi, yi + 1),
            self.get_clamped(xi + 1, yi + 1),
            x - x0,
            y - y0,
        )
    }
}

/// Bilinear interpolation of a 2x2 cell (`p00` top left, `p10` top right, `p01` bottom
/// left) at `(fx, fy)` in `[0, 1)²`: along x first, then y.
#[inline]
fn lerp_2x2(p00: f32, p10: f32, p01: f32, p11: f32, fx: f32, fy: f32) -> f32 {
    let top = p00 + (p10 - p00) * fx;
    let bot = p01 + (p11 - p01) * fx;
    top + (bot - top) * fy
}

/// [`GrayF32::sample_many`] with AVX2.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::GrayF32;
    use std::arch::x86_64::*;

    /// Whether the gathers may serve a `w x h` image of `len` values: at least 2 x 2, all
    /// `w * h` values there, indices within 32-bit lanes, and sides of at most 2^24, every
    /// integer to which is exact in `f32`, so that `x < w - 1` (in `f32`) bounds the column
    /// by `w - 2` (above, `w as f32 - 1.0` rounds up and let the last column's neighbour,
    /// past the end, be read).
    pub(super) fn gathers_fit(w: usize, h: usize, len: usize) -> bool {
        const EXACT: usize = 1 << 24;
        w >= 2
            && h >= 2
            && w <= EXACT
            && h <= EXACT
            && w.checked_mul(h)
                .is_some_and(|n| n <= len && n <= i32::MAX as usize)
    }

    /// Eight points at a time where all eight lie in [`GrayF32::sample`]'s inside region
    /// (`0 <= x < w - 1`, `0 <= y < h - 1`, so all four neighbours exist), gathered and
    /// interpolated with the operations of `lerp_2x2` in its order (no fused multiply-adds:
    /// the values are those of the scalar path bit for bit); any other group of eight, and
    /// the tail, through the scalar path.
    ///
    /// # Safety
    /// The CPU must support AVX2. `xs`, `ys` and `out` must have the same length.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sample_many(img: &GrayF32, xs: &[f32], ys: &[f32], out: &mut [f32]) {
        let (w, h) = (img.width as usize, img.height as usize);
        let n = out.len().min(xs.len()).min(ys.len());
        // The gathers index with 32-bit lanes and read up to pixel (w - 1, h - 1).
        if !gathers_fit(w, h, img.data.len()) {
            img.sample_many_scalar(xs, ys, out);
            return;
        }
        let data = img.data.as_ptr();
        let zero = _mm256_setzero_ps();
        let x_end = _mm256_set1_ps(w as f32 - 1.0);
        let y_end = _mm256_set1_ps(h as f32 - 1.0);
        let wi = _mm256_set1_epi32(w as i32);
        let mut i = 0;
        while i + 8 <= n {
            // SAFETY: i + 8 <= n, the length of all three slices' used part.
            let (x, y) = unsafe {
                (
                    _mm256_loadu_ps(xs.as_ptr().add(i)),
                    _mm256_loadu_ps(ys.as_ptr().add(i)),
                )
            };
            // Ordered comparisons: a NaN lane fails them and takes the scalar path.
            let inside = _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(x, zero),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(y, zero),
                ),
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LT_OQ>(x, x_end),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(y, y_end),
                ),
            );
            if _mm256_movemask_ps(inside) != 0xff {
                img.sample_many_scalar(&xs[i..i + 8], &ys[i..i + 8], &mut out[i..i + 8]);
                i += 8;
                continue;
            }
            // Non-negative: truncation is the floor, as in the scalar path.
            let (xi, yi) = (_mm256_cvttps_epi32(x), _mm256_cvttps_epi32(y));
            let fx = _mm256_sub_ps(x, _mm256_cvtepi32_ps(xi));
            let fy = _mm256_sub_ps(y, _mm256_cvtepi32_ps(yi));
            let idx = _mm256_add_epi32(_mm256_mullo_epi32(yi, wi), xi);
            // SAFETY: every lane has xi <= w - 2 and yi <= h - 2 (the sides are exact in
            // f32, `gathers_fit`), so idx + w + 1 <= w * h - 1, inside `data` (at least
            // w * h long, checked above).
            let (p00, p10, p01, p11) = unsafe {
                (
                    _mm256_i32gather_ps::<4>(data, idx),
                    _mm256_i32gather_ps::<4>(data.add(1), idx),
                    _mm256_i32gather_ps::<4>(data.add(w), idx),
                    _mm256_i32gather_ps::<4>(data.add(w + 1), idx),
                )
            };
            let top = _mm256_add_ps(p00, _mm256_mul_ps(_mm256_sub_ps(p10, p00), fx));
            let bot = _mm256_add_ps(p01, _mm256_mul_ps(_mm256_sub_ps(p11, p01), fx));
            let v = _mm256_add_ps(top, _mm256_mul_ps(_mm256_sub_ps(bot, top), fy));
            // SAFETY: as for the loads.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr().add(i), v) };
            i += 8;
        }
        img.sample_many_scalar(&xs[i..n], &ys[i..n], &mut out[i..n]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luma_extremes_and_sampling() {
        assert_eq!(luma(0, 0, 0), 0.0);
        assert!((luma(255, 255, 255) - 1.0).abs() < 1e-6);
        let mut g = GrayF32::new(2, 2);
        g.data = vec![0.0, 1.0, 2.0, 3.0];
        assert!((g.sample(0.5, 0.5) - 1.5).abs() < 1e-6);
        assert_eq!(g.sample(-3.0, -3.0), 0.0);
        assert_eq!(g.sample(5.0, 5.0), 3.0);
        // An empty image, or data shorter than its size says: zeros, not a panic.
        let empty = GrayF32::default();
        assert_eq!(empty.sample(0.5, 0.5), 0.0);
        assert_eq!(empty.get_clamped(3, -2), 0.0);
        let short = GrayF32 {
            width: 4,
            height: 4,
            data: vec![1.0; 3],
        };
        assert_eq!(short.sample(2.5, 2.5), 0.0);
        let mut out = [9.0; 9];
        short.sample_many(&[2.5; 9], &[2.5; 9], &mut out);
        assert_eq!(out, [0.0; 9]);
    }

    /// Sides past 2^24 are not exact in f32: `w - 1.0` rounds up there, and the inside test
    /// would let a gather read past the data. Such images take the scalar path.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_gathers_serve_only_sides_exact_in_f32() {
        use super::avx2::gathers_fit;
        assert!(gathers_fit(160, 120, 160 * 120));
        assert!(gathers_fit(1 << 24, 2, 1 << 25));
        assert!(!gathers_fit((1 << 24) + 3, 2, ((1 << 24) + 3) * 2));
        assert!(!gathers_fit(8, (1 << 24) + 3, 8 * ((1 << 24) + 3)));
        assert!(((((1u32 << 24) + 3) as f32) - 1.0) > ((1u32 << 24) + 2) as f32);
        assert!(!gathers_fit(4, 4, 15));
        assert!(!gathers_fit(1, 4, 4));
        assert!(!gathers_fit(1 << 16, 1 << 16, 1 << 32));
        assert!(!gathers_fit(usize::MAX, 2, usize::MAX));
    }

    #[test]
    fn the_inside_fast_path_samples_exactly_as_the_clamped_reads_do() {
        let (w, h) = (7u32, 5u32);
        let mut g = GrayF32::new(w, h);
        for (i, v) in g.data.iter_mut().enumerate() {
            *v = ((i * 37 % 23) as f32 / 23.0).sqrt();
        }
        // A grid across the image and a pixel beyond it, with the borders and the last
        // fast-path column and row (just under w - 1, h - 1) included.
        let mut xs: Vec<f32> = (0..=90).map(|k| -1.0 + k as f32 * 0.1).collect();
        let mut ys: Vec<f32> = (0..=70).map(|k| -1.0 + k as f32 * 0.1).collect();
        for v in [
            0.0,
            w as f32 - 1.0,
            w as f32 - 1.0 - f32::EPSILON * 8.0,
            0.999_999,
        ] {
            xs.push(v);
        }
        for v in [
            0.0,
            h as f32 - 1.0,
            h as f32 - 1.0 - f32::EPSILON * 4.0,
            -0.0,
        ] {
            ys.push(v);
        }
        for &x in &xs {
            for &y in &ys {
                let (a, b) = (g.sample(x, y), g.sample_clamped(x, y));
                assert_eq!(a.to_bits(), b.to_bits(), "({x}, {y}): {a} against {b}");
            }
        }
        // Pixel centres give the pixels themselves.
        assert_eq!(g.sample(3.0, 2.0), g.data[2 * w as usize + 3]);
    }

    #[test]
    fn sampling_many_points_gives_each_points_sample_bit_for_bit() {
        let (w, h) = (23u32, 17u32);
        let mut g = GrayF32::new(w, h);
        for (i, v) in g.data.iter_mut().enumerate() {
            *v = ((i * 53 % 31) as f32 / 31.0).powf(1.3);
        }
        // Runs of eight inside, runs that cross the border, points outside, NaN and a tail
        // that is not a whole eight.
        let mut pts: Vec<(f32, f32)> = Vec::new();
        for k in 0..203 {
            let t = k as f32 * 0.618_034;
            let (x, y) = match k / 40 {
                0 => (1.0 + (t * 7.3) % 20.0, 1.0 + (t * 3.1) % 14.0),
                1 => (-2.0 + (t * 5.7) % 27.0, -2.0 + (t * 2.3) % 21.0),
                2 => (w as f32 - 1.0 - (k % 3) as f32 * 1e-6, (t * 1.9) % 16.0),
                3 => (
                    (t * 4.1) % 21.0,
                    if k % 11 == 0 {
                        f32::NAN
                    } else {
                        (t * 2.9) % 15.9
                    },
                ),
                _ => ((t * 6.7) % 21.9, (t * 8.3) % 15.9),
            };
            pts.push((x, y));
        }
        let xs: Vec<f32> = pts.iter().map(|p| p.0).collect();
        let ys: Vec<f32> = pts.iter().map(|p| p.1).collect();
        let mut out = vec![0.0; pts.len()];
        g.sample_many(&xs, &ys, &mut out);
        for (k, (&(x, y), &v)) in pts.iter().zip(&out).enumerate() {
            assert_eq!(
                v.to_bits(),
                g.sample(x, y).to_bits(),
                "point {k} at ({x}, {y})"
            );
        }
        // The shortest slice bounds the points sampled.
        let mut short = vec![-1.0; 5];
        g.sample_many(&xs[..3], &ys, &mut short);
        assert_eq!(&short[..3], &out[..3]);
        assert_eq!(&short[3..], &[-1.0, -1.0]);
    }
}
