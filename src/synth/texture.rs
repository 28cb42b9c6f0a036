//! Procedural textures (the project ships no third-party images): a solid texture evaluated
//! at object-frame surface points, so it moves rigidly with the object, and a textured,
//! non-uniform background. Everything is a pure function of the seed and the position, through
//! a counter-based hash ([`hash`]): no sequential generator, so pixels may be computed in any
//! order (rayon) and stay byte-identical.

use nalgebra::{Matrix3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// An RGB colour, linear in `[0, 1]` (a little above 1 is allowed before quantisation).
pub type Rgb = [f32; 3];

/// The SplitMix64 finaliser: a bijective, well mixing map of 64-bit words.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Hash of a seed and a few words (cell coordinates, layer numbers, frame and pixel indices).
pub fn hash(seed: u64, parts: &[u64]) -> u64 {
    let mut h = mix64(seed);
    for &p in parts {
        h = mix64(h ^ p);
    }
    h
}

/// A uniform number in `[0, 1)` from the top 53 bits of a hash.
pub fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Approximately standard normal sensor noise for one (seed, frame, pixel, channel): the sum of
/// four uniforms from independent hashes, scaled to unit variance (Irwin–Hall).
pub fn noise(seed: u64, frame: u64, pixel: u64, channel: u64) -> f64 {
    let h = hash(seed ^ 0x006E_6F69_7365, &[frame, pixel, channel]);
    // four 16-bit uniforms from one hash
    let mut s = 0.0;
    for k in 0..4 {
        s += ((h >> (16 * k)) & 0xFFFF) as f64 / 65536.0;
    }
    // variance of the sum of 4 U(0,1) is 4/12
    (s - 2.0) * 3f64.sqrt()
}

fn rgb(r: u8, g: u8, b: u8) -> Rgb {
    [r as f32 / 255.0, g as f32 / 255.0, b as f32 / 255.0]
}

fn scale(c: Rgb, s: f32) -> Rgb {
    [c[0] * s, c[1] * s, c[2] * s]
}

fn lerp(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

fn cell(q: f64) -> u64 {
    q.floor() as i64 as u64
}

/// A rotation matrix from a seeded generator (uniform enough for decorrelating grid layers).
fn random_rotation(rng: &mut StdRng) -> Matrix3<f64> {
    let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let b: f64 = rng.random_range(-1.2..1.2);
    let c: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    crate::geometry::rotation::rot_z(a)
        * crate::geometry::rotation::rot_x(b)
        * crate::geometry::rotation::rot_y(c)
}

/// Which palette family a solid texture draws from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Material {
    /// Skin tones, hair browns and a few accents: a head whose colour distribution differs from
    /// the background's without being separable by colour alone (beige and brown occur in both).
    Head,
    /// Car paint, glass, chrome and rubber.
    Car,
}

/// A multi-scale solid texture: polygonal patches (3D cells cut by the surface), checker patches,
/// sharp-edged blobs and a fine speckle, each layer on its own rotated grid. Rich in corners.
#[derive(Debug, Clone)]
pub struct SolidTexture {
    seed: u64,
    /// Cell size of the coarsest layer (metres).
    size: f64,
    rot: [Matrix3<f64>; 4],
    base: Vec<Rgb>,
    accent: Vec<Rgb>,
}

impl SolidTexture {
    /// A texture for a material, with cells scaled to `size` metres.
    pub fn new(seed: u64, material: Material, size: f64) -> Self {
        let mut rng = StdRng::seed_from_u64(hash(seed, &[0x7465_7874]));
        let rot = [
            random_rotation(&mut rng),
            random_rotation(&mut rng),
            random_rotation(&mut rng),
            random_rotation(&mut rng),
        ];
        let (base, accent) = match material {
            Material::Head => (
                vec![
                    rgb(224, 172, 135),
                    rgb(198, 134, 100),
                    rgb(170, 112, 82),
                    rgb(236, 196, 165),
                    rgb(92, 60, 40),
                    rgb(128, 88, 60),
                    rgb(190, 150, 120),
                ],
                vec![
                    rgb(60, 38, 26),
                    rgb(180, 62, 52),
                    rgb(58, 112, 160),
                    rgb(214, 190, 92),
                    rgb(246, 226, 210),
                    rgb(96, 140, 82),
                ],
            ),
            Material::Car => (
                vec![
                    rgb(170, 30, 36),
                    rgb(196, 52, 40),
                    rgb(140, 24, 40),
                    rgb(210, 90, 60),
                    rgb(120, 130, 140),
                ],
                vec![
                    rgb(30, 34, 40),
                    rgb(200, 205, 210),
                    rgb(70, 110, 150),
                    rgb(235, 220, 120),
                    rgb(15, 15, 15),
                ],
            ),
        };
        Self {
            seed,
            size,
            rot,
            base,
            accent,
        }
    }

    /// The surface colour (albedo) at an object-frame point.
    pub fn albedo(&self, p: &Vector3<f64>) -> Rgb {
        let s = self.seed;
        // Layer 1: polygonal patches of the base palette.
        let q = self.rot[0] * p / self.size;
        let h = hash(s, &[1, cell(q.x), cell(q.y), cell(q.z)]);
        let mut c = self.base[(h % self.base.len() as u64) as usize];
        c = scale(c, 0.82 + 0.36 * unit(h >> 3) as f32);
        // Layer 2: checker patches (2x2x2 blocks of half-size cells) in some regions.
        let q = self.rot[1] * p / (0.5 * self.size);
        let (ix, iy, iz) = (q.x.floor() as i64, q.y.floor() as i64, q.z.floor() as i64);
        let h = hash(
            s,
            &[
                2,
                ix.div_euclid(2) as u64,
                iy.div_euclid(2) as u64,
                iz.div_euclid(2) as u64,
            ],
        );
        if unit(h) < 0.3 {
            // Wrapping: far from the object the floors saturate, and only the parity counts.
            if ix.wrapping_add(iy).wrapping_add(iz).rem_euclid(2) == 1 {
                c = self.accent[((h >> 8) % self.accent.len() as u64) as usize];
            } else {
                c = scale(c, 0.7);
            }
        }
        // Layer 3: sharp-edged blobs, one per cell, at a jittered centre.
        let q = self.rot[2] * p / (0.8 * self.size);
        let h = hash(s, &[3, cell(q.x), cell(q.y), cell(q.z)]);
        if unit(h) < 0.6 {
            let centre = Vector3::new(
                q.x.floor() + 0.25 + 0.5 * unit(hash(h, &[1])),
                q.y.floor() + 0.25 + 0.5 * unit(hash(h, &[2])),
                q.z.floor() + 0.25 + 0.5 * unit(hash(h, &[3])),
            );
            let r = 0.18 + 0.17 * unit(hash(h, &[4]));
            if (q - centre).norm() < r {
                let a = self.accent[((h >> 16) % self.accent.len() as u64) as usize];
                c = lerp(c, a, 0.85);
            }
        }
        // Layer 4: fine speckle.
        let q = self.rot[3] * p / (0.22 * self.size);
        let h = hash(s, &[4, cell(q.x), cell(q.y), cell(q.z)]);
        scale(c, 0.9 + 0.2 * unit(h) as f32)
    }
}

/// A static, textured, non-uniform background: colour gradients, soft blobs, overlapping
/// rectangles (some chequered, some tilted) and a fine cell texture. Defined in coordinates
/// relative to the image width, so it looks the same at every resolution.
#[derive(Debug, Clone)]
pub struct Background {
    seed: u64,
    top: Rgb,
    bottom: Rgb,
    blobs: Vec<Blob>,
    rects: Vec<Rect>,
}

#[derive(Debug, Clone)]
struct Blob {
    x: f64,
    y: f64,
    sigma: f64,
    delta: Rgb,
}

#[derive(Debug, Clone)]
struct Rect {
    x: f64,
    y: f64,
    hw: f64,
    hh: f64,
    cos: f64,
    sin: f64,
    colour: Rgb,
    alpha: f32,
    checker: Option<(f64, Rgb)>,
}

impl Background {
    /// A background for a seed; `aspect` is height / width (one that is not finite and
    /// positive counts as 1, where it panicked on an empty range).
    pub fn new(seed: u64, aspect: f64) -> Self {
        let aspect = if aspect.is_finite() && aspect > 0.0 {
            aspect
        } else {
            1.0
        };
        let mut rng = StdRng::seed_from_u64(hash(seed, &[0x6267]));
        let palette = [
            rgb(90, 100, 120),
            rgb(140, 150, 162),
            rgb(70, 110, 90),
            rgb(184, 164, 140),
            rgb(120, 90, 70),
            rgb(200, 205, 210),
            rgb(60, 60, 72),
            rgb(150, 120, 160),
            rgb(210, 170, 130),
            rgb(40, 70, 110),
        ];
        let pick = |rng: &mut StdRng| palette[rng.random_range(0..palette.len())];
        let top = pick(&mut rng);
        let bottom = pick(&mut rng);
        let blobs = (0..10)
            .map(|_| {
                let d: f32 = rng.random_range(-0.25..0.25);
                Blob {
                    x: rng.random_range(0.0..1.0),
                    y: rng.random_range(0.0..aspect),
                    sigma: rng.random_range(0.05..0.2),
                    delta: [
                        d + rng.random_range(-0.08..0.08),
                        d + rng.random_range(-0.08..0.08),
                        d + rng.random_range(-0.08..0.08),
                    ],
                }
            })
            .collect();
        let rects = (0..34)
            .map(|_| {
                let angle: f64 = if rng.random_bool(0.4) {
                    rng.random_range(-0.5..0.5)
                } else {
                    0.0
                };
                let colour = pick(&mut rng);
                let checker = if rng.random_bool(0.3) {
                    Some((rng.random_range(0.01..0.03), pick(&mut rng)))
                } else {
                    None
                };
                Rect {
                    x: rng.random_range(-0.05..1.05),
                    y: rng.random_range(-0.05..aspect + 0.05),
                    hw: rng.random_range(0.015..0.15),
                    hh: rng.random_range(0.015..0.15),
                    cos: angle.cos(),
                    sin: angle.sin(),
                    colour,
                    alpha: rng.random_range(0.55..0.95),
                    checker,
                }
            })
            .collect();
        Self {
            seed,
            top,
            bottom,
            blobs,
            rects,
        }
    }

    /// Colour at a position in width units (`x` in `[0, 1]` across the image, `y` down).
    pub fn colour(&self, x: f64, y: f64) -> Rgb {
        let mut c = lerp(self.top, self.bottom, (y * 1.3).clamp(0.0, 1.0) as f32);
        let tint = (0.12 * (x - 0.5)) as f32;
        c = [c[0] + tint, c[1], c[2] - tint];
        for b in &self.blobs {
            let d2 = (x - b.x).powi(2) + (y - b.y).powi(2);
            let s2 = b.sigma * b.sigma;
            if d2 > 25.0 * s2 {
                continue; // below 4e-6
            }
            let w = (-d2 / (2.0 * s2)).exp() as f32;
            for (ch, d) in c.iter_mut().zip(b.delta) {
                *ch += w * d;
            }
        }
        for r in &self.rects {
            let dx = x - r.x;
            let dy = y - r.y;
            let lx = r.cos * dx + r.sin * dy;
            let ly = -r.sin * dx + r.cos * dy;
            if lx.abs() <= r.hw && ly.abs() <= r.hh {
                let mut col = r.colour;
                if let Some((period, other)) = r.checker {
                    let i = (lx / period).floor() as i64 + (ly / period).floor() as i64;
                    if i.rem_euclid(2) == 1 {
                        col = other;
                    }
                }
                c = lerp(c, col, r.alpha);
            }
        }
        // Fine cells of slightly varying brightness on a tilted grid.
        let (gx, gy) = (0.8 * x + 0.6 * y, -0.6 * x + 0.8 * y);
        let h = hash(self.seed, &[5, cell(gx / 0.018), cell(gy / 0.018)]);
        scale(c, 0.92 + 0.16 * unit(h) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn far_points_and_odd_aspects_do_not_panic() {
        let t = SolidTexture::new(1, Material::Head, 0.035);
        let far = t.albedo(&Vector3::new(1e300, 1e300, 1e300));
        assert!(far.iter().all(|c| c.is_finite()));
        for aspect in [f64::NAN, 0.0, -1.0, f64::INFINITY] {
            let _ = Background::new(3, aspect);
        }
    }

    #[test]
    fn noise_has_unit_variance_and_zero_mean() {
        let n = 20000;
        let xs: Vec<f64> = (0..n).map(|i| noise(7, 3, i, 1)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(mean.abs() < 0.03, "mean {mean}");
        assert!((var - 1.0).abs() < 0.05, "var {var}");
        // a pure function of its arguments
        assert_eq!(noise(7, 3, 11, 1), noise(7, 3, 11, 1));
        assert_ne!(noise(7, 3, 11, 1), noise(8, 3, 11, 1));
    }

    #[test]
    fn solid_texture_is_a_function_of_position_and_seed() {
        let t = SolidTexture::new(1, Material::Head, 0.035);
        let p = Vector3::new(0.01, 0.02, -0.05);
        assert_eq!(t.albedo(&p), t.albedo(&p));
        // varies over the surface: many distinct colours along a line
        let mut seen = std::collections::HashSet::new();
        for i in 0..200 {
            let q = Vector3::new(-0.08 + i as f64 * 0.0008, 0.01, -0.05);
            let c = t.albedo(&q);
            seen.insert(c.map(|v| (v * 64.0) as i32));
        }
        assert!(seen.len() > 10, "{} colours", seen.len());
        let other = SolidTexture::new(2, Material::Head, 0.035);
        let differs = (0..50).any(|i| {
            let q = Vector3::new(i as f64 * 0.003, 0.0, -0.05);
            t.albedo(&q) != other.albedo(&q)
        });
        assert!(differs);
    }
}
