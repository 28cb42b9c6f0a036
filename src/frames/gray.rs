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

    /// Pixel at `(x, y)`, coordinates clamped to the image (edge replication).
    #[inline]
    pub fn get_clamped(&self, x: i64, y: i64) -> f32 {
        let x = x.clamp(0, self.width as i64 - 1) as usize;
        let y = y.clamp(0, self.height as i64 - 1) as usize;
        self.data[y * self.width as usize + x]
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

    /// [`Self::sample`] with every pixel read through [`Self::get_clamped`]: its form at
    /// and beyond the border.
    fn sample_clamped(&self, x: f32, y: f32) -> f32 {
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
}
