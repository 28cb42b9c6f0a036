//! SIFT keypoints and descriptors ([`Sift`]), and matching between frames
//! ([`match_features`], then the paper's slope/length outlier rejection
//! [`reject_slope_length`], SPEC section 2). RANSAC lives in `pose`.
//!
//! Everything runs on `[0, 1]` grey images ([`crate::frames::GrayF32`]) in the SPEC's pixel
//! convention: origin at the centre of the top-left pixel, x right, y down (OpenCV's `pt`).

mod matching;
mod sift;

pub use matching::{
    Match, MatchParams, PAPER_ANGLE_TOL, PAPER_LENGTH_TOL, STILL_LENGTH_PX, STILL_RADIUS_PX,
    keep_slope_length, match_features, reject_slope_length,
};
pub use sift::{DESCRIPTOR_LEN, MAX_SIGMA, Sift, SiftParams, UpsampleGrid};

/// A SIFT keypoint, in input-image pixels.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Keypoint {
    /// Column (x right), origin at the centre of the top-left pixel.
    pub x: f32,
    /// Row (y down).
    pub y: f32,
    /// σ of the keypoint's scale in input pixels (OpenCV's `size` is `2 * scale`).
    pub scale: f32,
    /// Dominant gradient orientation in radians, `[0, 2π)`, from +x towards +y (clockwise on
    /// screen); numerically OpenCV's `angle` once converted to degrees.
    pub angle: f32,
    /// |DoG| at the refined extremum (contrast), on the `[0, 1]` intensity scale.
    pub response: f32,
    /// Octave the keypoint was found in: −1 for the doubled first octave, 0 for the input's
    /// resolution, k for a 2^k-fold reduction.
    pub octave: i32,
}

/// Keypoints and their descriptors, `descriptors[i]` belonging to `keypoints[i]`.
///
/// Descriptors are 128 bytes: the normalised, 0.2-clamped, renormalised SIFT vector times
/// 512, rounded and saturated (OpenCV's integer form), so distances are exact integers.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Features {
    /// Keypoints in a canonical order (by y, then x, scale, angle), without duplicates.
    pub keypoints: Vec<Keypoint>,
    /// One descriptor per keypoint.
    pub descriptors: Vec<[u8; DESCRIPTOR_LEN]>,
}

impl Features {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// True when there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }
}

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FeatureError {
    /// The pixel buffer does not match the image size.
    #[error("bad image: {width}x{height} with {len} pixels")]
    BadImage {
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
        /// Pixels present.
        len: usize,
    },
    /// A pixel of the image (within the detection window) that is not finite: NaN or an
    /// infinity, which would spread through the scale space's blurs.
    #[error("pixel ({x}, {y}) of the image is {value}: SIFT needs finite grey levels")]
    NonFinitePixel {
        /// Column of the first such pixel.
        x: usize,
        /// Row of the first such pixel.
        y: usize,
        /// Its value.
        value: f32,
    },
    /// A detection region that is not finite or has a negative size.
    #[error("bad region {0} (want finite x,y,w,h with w, h >= 0)")]
    BadRegion(String),
    /// SIFT parameters out of range ([`SiftParams::check`]).
    #[error("bad SIFT parameters: {0}")]
    BadParams(String),
    /// Matching parameters out of range ([`MatchParams::check`]).
    #[error("bad matching parameters: {0}")]
    BadMatching(String),
    /// The scale space of the detection window would exceed
    /// [`SiftParams::max_scale_space_bytes`].
    #[error(
        "SIFT on a {width}x{height} window{} needs about {} for its scale space, more than the {} allowed (SiftParams::max_scale_space_bytes){}",
        if *upsampled { " with the upsampled first octave" } else { "" },
        size_text(*bytes),
        size_text(*limit),
        if *fits_without_upsampling { "; detect without the upsampled first octave or within a region" } else { "; detect within a region" }
    )]
    TooLarge {
        /// Width of the window (pixels).
        width: usize,
        /// Height of the window (pixels).
        height: usize,
        /// Whether the first octave was to be upsampled.
        upsampled: bool,
        /// The scale space's bytes ([`SiftParams::scale_space_bytes`]).
        bytes: u64,
        /// The limit.
        limit: u64,
        /// Whether the window's scale space without the upsampled first octave would be
        /// within the limit (false when it was not upsampled).
        fits_without_upsampling: bool,
    },
}

/// A size in bytes for people: `5.6 GB`, `176 MB`, `12 kB` or `1000 bytes`.
pub(crate) fn size_text(bytes: u64) -> String {
    // Each unit from where the one below would round to 1000.
    let b = bytes as f64;
    if b >= 999.5e6 {
        format!("{:.1} GB", b / 1e9)
    } else if b >= 999.5e3 {
        format!("{:.0} MB", b / 1e6)
    } else if b >= 999.5 {
        format!("{:.0} kB", b / 1e3)
    } else {
        format!("{bytes} bytes")
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn sizes_are_written_in_the_unit_they_round_to() {
        for (bytes, text) in [
            (999, "999 bytes"),
            (999_499, "999 kB"),
            (999_500, "1 MB"),
            (176_000_000, "176 MB"),
            (999_999_999, "1.0 GB"),
            (5_632_000_000, "5.6 GB"),
        ] {
            assert_eq!(super::size_text(bytes), text);
        }
    }
}
