//! Frames held in someone else's buffer: a camera's, a decoder's or another library's pixels
//! (RGB, BGR, RGBA, BGRA or grey, rows of any stride), read in place and turned into the
//! tracker's RGB frames, into a buffer that is reused from frame to frame
//! ([`FrameView::write_rgb`], [`crate::tracker::Tracker::step_view`]).
//!
//! ```
//! use pftrack::frames::view::{FrameView, PixelFormat};
//! // A 4x2 BGRA frame whose rows are padded to 20 bytes, as a camera's often are.
//! let mut bgra = vec![0u8; 20 * 2];
//! bgra[..4].copy_from_slice(&[10, 20, 30, 255]); // the first pixel: blue 10, green 20, red 30
//! let view = FrameView::new(&bgra, 4, 2, 20, PixelFormat::Bgra8)?;
//! let rgb = view.to_rgb();
//! assert_eq!(rgb.get_pixel(0, 0).0, [30, 20, 10]);
//! # Ok::<(), pftrack::frames::FrameError>(())
//! ```

use image::RgbImage;

use super::FrameError;

/// How a raw frame's pixels are laid out: 8 bits a channel, channels in the order named.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum PixelFormat {
    /// Red, green, blue.
    Rgb8,
    /// Blue, green, red (OpenCV's order).
    Bgr8,
    /// Red, green, blue, alpha (the alpha is ignored).
    Rgba8,
    /// Blue, green, red, alpha (the alpha is ignored).
    Bgra8,
    /// One grey level, taken as the three equal channels of a grey RGB pixel.
    Gray8,
}

impl PixelFormat {
    /// Bytes of one pixel.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Rgb8 | PixelFormat::Bgr8 => 3,
            PixelFormat::Rgba8 | PixelFormat::Bgra8 => 4,
            PixelFormat::Gray8 => 1,
        }
    }

    /// The RGB of the pixel whose bytes start `px` (at least [`Self::bytes_per_pixel`] long).
    fn rgb(self, px: &[u8]) -> [u8; 3] {
        match self {
            PixelFormat::Rgb8 | PixelFormat::Rgba8 => [px[0], px[1], px[2]],
            PixelFormat::Bgr8 | PixelFormat::Bgra8 => [px[2], px[1], px[0]],
            PixelFormat::Gray8 => [px[0]; 3],
        }
    }
}

/// A frame in a borrowed buffer: `height` rows of `width` pixels, each row starting `stride`
/// bytes after the one before (the last row need not be padded). Checked when made
/// ([`FrameView::new`]), so reading it cannot fail.
#[derive(Debug, Clone, Copy)]
pub struct FrameView<'a> {
    data: &'a [u8],
    width: u32,
    height: u32,
    stride: usize,
    format: PixelFormat,
}

impl<'a> FrameView<'a> {
    /// A view of `data` as a `width` x `height` frame of `format` whose rows are `stride`
    /// bytes apart. [`FrameError::BadView`] where a side is 0, `stride` is shorter than a
    /// row's pixels, or `data` is too short to hold the last row's.
    pub fn new(
        data: &'a [u8],
        width: u32,
        height: u32,
        stride: usize,
        format: PixelFormat,
    ) -> Result<Self, FrameError> {
        let bad = |msg: String| Err(FrameError::BadView { msg });
        if width == 0 || height == 0 {
            return bad(format!("a {width}x{height} frame has no pixels"));
        }
        let row = (width as usize).checked_mul(format.bytes_per_pixel());
        let Some(row) = row.filter(|&r| r <= stride) else {
            return bad(format!(
                "rows {stride} bytes apart are shorter than {width} pixels of {format:?} ({} \
                 bytes each)",
                format.bytes_per_pixel()
            ));
        };
        let needed = stride
            .checked_mul(height as usize - 1)
            .and_then(|v| v.checked_add(row));
        match needed {
            Some(n) if n <= data.len() => Ok(Self {
                data,
                width,
                height,
                stride,
                format,
            }),
            _ => bad(format!(
                "{} bytes hold no {width}x{height} frame of {format:?} with rows {stride} bytes \
                 apart ({} needed)",
                data.len(),
                needed.map_or_else(|| "more than can be addressed".into(), |n| n.to_string())
            )),
        }
    }

    /// A view of rows packed one after the other (`stride` = `width` pixels).
    pub fn packed(
        data: &'a [u8],
        width: u32,
        height: u32,
        format: PixelFormat,
    ) -> Result<Self, FrameError> {
        let stride = (width as usize).saturating_mul(format.bytes_per_pixel());
        Self::new(data, width, height, stride, format)
    }

    /// The frame's width and height in pixels.
    pub fn dimensions(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The pixels' layout.
    pub fn format(&self) -> PixelFormat {
        self.format
    }

    /// Bytes from the start of one row to the start of the next.
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// The frame as RGB into `out`, made the frame's size first where it is not (its buffer
    /// is reused where it is, so a stream of frames of one size allocates once).
    pub fn write_rgb(&self, out: &mut RgbImage) {
        if out.dimensions() != (self.width, self.height)
            || out.as_raw().len() != 3 * self.width as usize * self.height as usize
        {
            *out = RgbImage::new(self.width, self.height);
        }
        let bpp = self.format.bytes_per_pixel();
        let row_len = self.width as usize * bpp;
        for (y, dst) in out.chunks_exact_mut(3 * self.width as usize).enumerate() {
            let start = y * self.stride;
            let src = &self.data[start..start + row_len];
            for (d, s) in dst.chunks_exact_mut(3).zip(src.chunks_exact(bpp)) {
                d.copy_from_slice(&self.format.rgb(s));
            }
        }
    }

    /// The frame as a new RGB image.
    pub fn to_rgb(&self) -> RgbImage {
        let mut out = RgbImage::new(0, 0);
        self.write_rgb(&mut out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An RGB test frame whose every pixel differs in each channel.
    fn frame(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([
                (x * 7 + y) as u8,
                (x + y * 11) as u8,
                (x * 3 + y * 5 + 1) as u8,
            ])
        })
    }

    /// `img` laid out in `format` with rows `pad` bytes longer than their pixels.
    fn laid_out(img: &RgbImage, format: PixelFormat, pad: usize) -> Vec<u8> {
        let mut out = Vec::new();
        for y in 0..img.height() {
            for x in 0..img.width() {
                let [r, g, b] = img.get_pixel(x, y).0;
                match format {
                    PixelFormat::Rgb8 => out.extend([r, g, b]),
                    PixelFormat::Bgr8 => out.extend([b, g, r]),
                    PixelFormat::Rgba8 => out.extend([r, g, b, 7]),
                    PixelFormat::Bgra8 => out.extend([b, g, r, 7]),
                    PixelFormat::Gray8 => out.push(g),
                }
            }
            out.extend(std::iter::repeat_n(0xEE, pad));
        }
        out
    }

    #[test]
    fn every_layout_and_stride_reads_back_the_frame() {
        let img = frame(13, 5);
        for format in [
            PixelFormat::Rgb8,
            PixelFormat::Bgr8,
            PixelFormat::Rgba8,
            PixelFormat::Bgra8,
        ] {
            for pad in [0, 1, 3, 16] {
                let data = laid_out(&img, format, pad);
                let stride = 13 * format.bytes_per_pixel() + pad;
                let view = FrameView::new(&data, 13, 5, stride, format).unwrap();
                assert_eq!(view.to_rgb(), img, "{format:?}, pad {pad}");
                // The last row's padding may be missing.
                let cut = &data[..data.len() - pad];
                let view = FrameView::new(cut, 13, 5, stride, format).unwrap();
                assert_eq!(view.to_rgb(), img, "{format:?}, pad {pad}, last row cut");
            }
        }
        let grey = laid_out(&img, PixelFormat::Gray8, 2);
        let view = FrameView::new(&grey, 13, 5, 15, PixelFormat::Gray8).unwrap();
        let rgb = view.to_rgb();
        for (x, y, p) in rgb.enumerate_pixels() {
            let g = img.get_pixel(x, y).0[1];
            assert_eq!(p.0, [g; 3]);
        }
    }

    #[test]
    fn the_buffer_is_reused_for_frames_of_one_size_and_remade_for_another() {
        let (a, b) = (frame(6, 4), frame(9, 3));
        let mut out = RgbImage::new(6, 4);
        let ptr = out.as_raw().as_ptr();
        let data = laid_out(&a, PixelFormat::Rgb8, 0);
        FrameView::packed(&data, 6, 4, PixelFormat::Rgb8)
            .unwrap()
            .write_rgb(&mut out);
        assert_eq!(out, a);
        assert_eq!(out.as_raw().as_ptr(), ptr);
        let data = laid_out(&b, PixelFormat::Bgr8, 0);
        FrameView::packed(&data, 9, 3, PixelFormat::Bgr8)
            .unwrap()
            .write_rgb(&mut out);
        assert_eq!(out, b);
        // An image over a longer buffer than its pixels is made afresh, not written past.
        let mut long = RgbImage::from_raw(6, 4, vec![0; 3 * 6 * 4 + 5]).unwrap();
        let data = laid_out(&a, PixelFormat::Rgb8, 0);
        FrameView::packed(&data, 6, 4, PixelFormat::Rgb8)
            .unwrap()
            .write_rgb(&mut long);
        assert_eq!(long, a);
    }

    #[test]
    fn buffers_that_hold_no_such_frame_are_refused() {
        let data = vec![0u8; 100];
        let refused =
            |r: Result<FrameView, FrameError>| matches!(r, Err(FrameError::BadView { .. }));
        assert!(refused(FrameView::new(&data, 0, 5, 30, PixelFormat::Rgb8)));
        assert!(refused(FrameView::new(&data, 5, 0, 30, PixelFormat::Rgb8)));
        // Rows shorter than their pixels.
        assert!(refused(FrameView::new(&data, 10, 2, 29, PixelFormat::Rgb8)));
        // 3 rows of 10 RGB pixels 33 bytes apart need 96 bytes; 4 rows need 129.
        assert!(FrameView::new(&data, 10, 3, 33, PixelFormat::Rgb8).is_ok());
        assert!(refused(FrameView::new(&data, 10, 4, 33, PixelFormat::Rgb8)));
        assert!(refused(FrameView::packed(&data, 10, 4, PixelFormat::Rgb8)));
        // Sizes whose byte counts overflow (the first), or reach past any buffer.
        assert!(refused(FrameView::new(
            &data,
            u32::MAX,
            u32::MAX,
            usize::MAX,
            PixelFormat::Bgra8
        )));
        assert!(refused(FrameView::packed(
            &data,
            u32::MAX,
            2,
            PixelFormat::Rgba8
        )));
        let msg = FrameView::new(&data, 10, 4, 33, PixelFormat::Rgb8)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("129 needed"), "{msg}");
    }
}
