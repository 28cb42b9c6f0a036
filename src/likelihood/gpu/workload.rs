//! A synthetic likelihood workload (frame, target, features, particles) for `pftrack bench`,
//! needing no data files. (`benches/likelihood.rs` builds a scene of its own, with particles
//! spread more tightly about the target, so the two benches' figures are not one series.)

use image::{Rgb, RgbImage};
use rand::{Rng, SeedableRng, rngs::StdRng};

use crate::geometry::Ellipse;
use crate::likelihood::{
    ColourHistogram, FeaturePair, LikelihoodError, LikelihoodParams, Particle,
};

/// One frame's worth of likelihood input.
#[derive(Debug, Clone)]
pub struct Workload {
    /// A textured frame with a bright elliptical target.
    pub image: RgbImage,
    /// The target's ellipse (also the previous estimate).
    pub target: Particle,
    /// Matched features inside the target.
    pub features: Vec<FeaturePair>,
    /// The colour model of the target.
    pub model: ColourHistogram,
    /// Default parameters.
    pub params: LikelihoodParams,
}

/// A `width × height` frame: colour ramps with a noise texture, and a target ellipse of about
/// a quarter of the frame's height (a head at the paper's 128×96), with 40 features on it.
pub fn workload(width: u32, height: u32, seed: u64) -> Result<Workload, LikelihoodError> {
    if width < 8 || height < 8 {
        return Err(LikelihoodError::Invalid(format!(
            "benchmark frame {width}x{height} is too small (at least 8x8)"
        )));
    }
    let mut rng = StdRng::seed_from_u64(seed);
    let target = Particle {
        cx: width as f32 * 0.47,
        cy: height as f32 * 0.52,
        a: height as f32 * 0.16,
        b: height as f32 * 0.21,
        ..Default::default()
    };
    let image = RgbImage::from_fn(width, height, |x, y| {
        let n: u8 = rng.random_range(0..48);
        let dx = (x as f32 - target.cx) / target.a;
        let dy = (y as f32 - target.cy) / target.b;
        if dx * dx + dy * dy <= 1.0 {
            Rgb([190 + n / 2, 130 + n, 90 + n])
        } else {
            Rgb([
                ((x * 160 / width) as u8).wrapping_add(n),
                ((y * 160 / height) as u8).wrapping_add(n),
                (((x / 8 + y / 8) % 2) as u8 * 80).wrapping_add(n),
            ])
        }
    });
    let features = (0..40)
        .map(|_| {
            let p = [
                target.cx + target.a * rng.random_range(-0.7..0.7),
                target.cy + target.b * rng.random_range(-0.7..0.7),
            ];
            FeaturePair {
                p,
                q: [
                    p[0] + 1.0 + rng.random_range(-0.5..0.5),
                    p[1] + rng.random_range(-0.5..0.5),
                ],
            }
        })
        .collect();
    let model = ColourHistogram::from_ellipse(
        &image,
        &Ellipse::new(
            target.cx as f64,
            target.cy as f64,
            target.a as f64,
            target.b as f64,
        ),
        LikelihoodParams::default().colour_bins,
    )?;
    Ok(Workload {
        image,
        target,
        features,
        model,
        params: LikelihoodParams::default(),
    })
}

/// `n` particles scattered around `target` as a filter's proposal would (centre ±20 % of the
/// axes, axes ×0.8..1.2, angles ±0.3 rad).
pub fn particles(target: &Particle, n: usize, seed: u64) -> Vec<Particle> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| Particle {
            cx: target.cx + target.a * rng.random_range(-0.2..0.2),
            cy: target.cy + target.b * rng.random_range(-0.2..0.2),
            a: target.a * rng.random_range(0.8..1.2),
            b: target.b * rng.random_range(0.8..1.2),
            rx: rng.random_range(-0.3..0.3),
            ry: rng.random_range(-0.3..0.3),
            rz: rng.random_range(-0.3..0.3),
            _pad: 0.0,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn workload_is_deterministic_and_its_target_is_inside_the_frame() {
        let a = workload(160, 120, 1).unwrap();
        let b = workload(160, 120, 1).unwrap();
        assert_eq!(a.image, b.image);
        assert_eq!(a.features, b.features);
        assert!(a.target.cx - a.target.a > 0.0 && a.target.cx + a.target.a < 160.0);
        assert!(a.target.cy - a.target.b > 0.0 && a.target.cy + a.target.b < 120.0);
        assert_eq!(particles(&a.target, 50, 3), particles(&a.target, 50, 3));
        assert!(workload(4, 4, 1).is_err());
    }
}
