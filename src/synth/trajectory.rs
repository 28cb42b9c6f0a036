//! The scenarios' trajectories: the object's rotation `R_t` (SPEC convention: object points in
//! the frame-0 pose to the current pose, about the object centre, `R_0 = I`) and its centre in
//! camera coordinates, per frame.

use nalgebra::{Matrix3, Rotation3, Unit, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::Scenario;
use crate::geometry::{Euler, rad};

/// Where the object is in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectPose {
    /// `R_t`: rotation from the frame-0 pose to this frame's pose (camera axes, about the
    /// object centre). The object's orientation (object to camera coordinates) is
    /// `R_t · R_obj0`, see [`super::Renderer::reference_orientation`].
    pub rotation: Matrix3<f64>,
    /// The object centre in camera coordinates (metres).
    pub centre: Vector3<f64>,
}

/// Depth of the head at frame 0 (metres): about 50 px tall at 160x120.
pub const HEAD_DEPTH: f64 = 0.7;
/// Depth of the car at frame 0 (metres).
pub const CAR_DEPTH: f64 = 1.1;

/// Smooth 0→1 step between `e0` and `e1` (cubic Hermite).
pub fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A sum of sinusoids that is 0 at frame 0: `Σ A_i (sin(ω_i k + φ_i) - sin φ_i)`; its magnitude
/// never exceeds `2 Σ A_i`.
#[derive(Debug, Clone)]
struct Wander {
    terms: Vec<(f64, f64, f64)>, // amplitude, angular frequency (per frame), phase
}

impl Wander {
    /// A random wander bounded by `bound` in magnitude, periods 180 to 720 frames.
    fn new(rng: &mut StdRng, bound: f64) -> Self {
        let w: Vec<f64> = (0..3).map(|_| rng.random_range(0.3..1.0)).collect();
        let total: f64 = w.iter().sum();
        let terms = w
            .iter()
            .map(|wi| {
                let period: f64 = rng.random_range(180.0..720.0);
                let phase: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                (
                    bound / 2.0 * wi / total,
                    std::f64::consts::TAU / period,
                    phase,
                )
            })
            .collect();
        Self { terms }
    }

    fn at(&self, k: f64) -> f64 {
        self.terms
            .iter()
            .map(|&(a, w, p)| a * ((w * k + p).sin() - p.sin()))
            .sum()
    }
}

/// A scenario's motion over a given number of frames.
#[derive(Debug, Clone)]
pub struct Trajectory {
    scenario: Scenario,
    frames: usize,
    /// rx, ry, rz, x, y, z wanders of `long`.
    wander: Option<[Wander; 6]>,
    /// Car's up axis in camera coordinates (its turning axis).
    car_up: Vector3<f64>,
}

impl Trajectory {
    /// The trajectory of a scenario over `frames` frames; `seed` drives `long`'s random motion;
    /// `orientation0` is the object's frame-0 orientation (the car turns about its own up axis).
    pub fn new(scenario: Scenario, frames: usize, seed: u64, orientation0: &Matrix3<f64>) -> Self {
        let wander = (scenario == Scenario::Long).then(|| {
            let mut rng = StdRng::seed_from_u64(super::texture::hash(seed, &[0x6C6F_6E67]));
            [
                Wander::new(&mut rng, rad(30.0)),
                Wander::new(&mut rng, rad(45.0)),
                Wander::new(&mut rng, rad(25.0)),
                Wander::new(&mut rng, 0.05),
                Wander::new(&mut rng, 0.03),
                Wander::new(&mut rng, 0.1),
            ]
        });
        Self {
            scenario,
            frames,
            wander,
            car_up: orientation0 * Vector3::new(0.0, -1.0, 0.0),
        }
    }

    /// Progress through the sequence, 0 at the first frame and 1 at the last.
    fn progress(&self, k: usize) -> f64 {
        k as f64 / (self.frames.max(2) - 1) as f64
    }

    /// The pose at frame `k`.
    pub fn pose(&self, k: usize) -> ObjectPose {
        let s = self.progress(k);
        let tau = std::f64::consts::TAU;
        let head = |e: Euler, c: Vector3<f64>| ObjectPose {
            rotation: e.matrix(),
            centre: c,
        };
        let z0 = HEAD_DEPTH;
        match self.scenario {
            Scenario::Nod => head(
                Euler::new(rad(35.0) * (tau * s).sin(), 0.0, 0.0),
                Vector3::new(0.0, 0.0, z0),
            ),
            Scenario::Pan => head(
                Euler::new(0.0, rad(60.0) * (tau * s).sin(), 0.0),
                Vector3::new(0.0, 0.0, z0),
            ),
            Scenario::Roll => head(
                Euler::new(0.0, 0.0, rad(45.0) * (tau * s).sin()),
                Vector3::new(0.0, 0.0, z0),
            ),
            Scenario::Combo => {
                // Changing speed: warped time with speed 1 - 0.5 cos(2π s) ∈ [0.5, 1.5].
                let t = s - 0.5 * (tau * s).sin() / tau;
                head(
                    Euler::new(
                        rad(25.0) * (tau * t).sin(),
                        rad(40.0) * (1.5 * tau * t).sin(),
                        rad(20.0) * (2.0 * tau * t).sin(),
                    ),
                    Vector3::new(
                        0.05 * (tau * t).sin(),
                        0.025 * (2.0 * tau * t).sin(),
                        z0 * (1.0 + 0.12 * (0.5 * tau * t).sin()),
                    ),
                )
            }
            Scenario::Depth => head(
                Euler::default(),
                Vector3::new(0.0, 0.0, z0 * (1.0 - 0.4 * (tau * s).sin())),
            ),
            Scenario::Car => {
                let turn = rad(60.0) * smoothstep(0.45, 0.9, s);
                let rotation = Rotation3::from_axis_angle(&Unit::new_normalize(self.car_up), turn)
                    .into_inner();
                ObjectPose {
                    rotation,
                    centre: Vector3::new(-0.18 + 0.3 * s, 0.02 * s, CAR_DEPTH - 0.2 * s),
                }
            }
            Scenario::Long => {
                let k = k as f64;
                let [rx, ry, rz, x, y, z] = self.wander.as_ref().map_or_else(
                    || [0.0; 6],
                    |w| {
                        [
                            w[0].at(k),
                            w[1].at(k),
                            w[2].at(k),
                            w[3].at(k),
                            w[4].at(k),
                            w[5].at(k),
                        ]
                    },
                );
                head(Euler::new(rx, ry, rz), Vector3::new(x, y, z0 + z))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_trajectory_starts_at_identity() {
        for &sc in Scenario::all() {
            let o0 = crate::geometry::rotation::rot_x(0.2);
            let t = Trajectory::new(sc, sc.default_frames(), 5, &o0);
            let p = t.pose(0);
            assert!((p.rotation - Matrix3::identity()).norm() < 1e-12, "{sc:?}");
        }
    }

    #[test]
    fn wander_is_bounded_and_starts_at_zero() {
        let mut rng = StdRng::seed_from_u64(3);
        let w = Wander::new(&mut rng, 1.0);
        assert_eq!(w.at(0.0), 0.0);
        assert!((0..5000).all(|k| w.at(k as f64).abs() <= 1.0));
    }

    #[test]
    fn smoothstep_ends() {
        assert_eq!(smoothstep(0.2, 0.4, 0.1), 0.0);
        assert_eq!(smoothstep(0.2, 0.4, 0.5), 1.0);
        assert!((smoothstep(0.2, 0.4, 0.3) - 0.5).abs() < 1e-12);
    }
}
