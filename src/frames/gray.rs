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
    pub fn sample(&self, x: f32, y: f32) -> f32 {
        let x0 = x.floor();
        let y0 = y.floor();
        let fx = x - x0;
        let fy = y - y0;
        let (xi, yi) = (x0 as i64, y0 as i64);
        let p00 = self.get_clamped(xi, yi);
        let p10 = self.get_clamped(xi + 1, yi);
        let p01 = self.get_clamped(xi, yi + 1);
        let p11 = self.get_clamped(xi + 1, yi + 1);
        let top = p00 + (p10 - p00) * fx;
        let bot = p01 + (p11 - p01) * fx;
        top + (bot - top) * fy
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
    }
}
