//! Tests of `pftrack synth`: the geometry of the rendered ground truth, every scenario, the
//! determinism for a seed and the texture's richness in corners (its command line is tested
//! in `tests/cli.rs`).

use std::path::PathBuf;

use nalgebra::{Matrix3, Vector3};
use pftrack::frames::GrayF32;
use pftrack::geometry::{Euler, PoseState, angle_between};
use pftrack::io::read_pose_csv;
use pftrack::synth::{Renderer, Scenario, Shape, SynthConfig, write_sequence};

fn cfg(scenario: Scenario, frames: usize, width: u32, height: u32) -> SynthConfig {
    SynthConfig {
        frames,
        width,
        height,
        ..SynthConfig::new(scenario)
    }
}

fn head_scenarios() -> impl Iterator<Item = Scenario> {
    Scenario::all()
        .iter()
        .copied()
        .filter(|&s| s != Scenario::Car)
}

fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pftrack-synth-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A small deterministic generator for test sampling (no dependency on the renderer's hash).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

// ---------------------------------------------------------------- geometry

#[test]
fn projected_centre_matches_silhouette_centroid() {
    // Perspective moves the centroid of an ellipsoid's outline away from the projection of its
    // centre, by about (r/z)² times the centre's distance from the principal point: under
    // 0.5 px for the head at its working distances. The analytic outline (exact conic) checks
    // the sampled moments at the same time.
    let mut worst: f64 = 0.0;
    for sc in head_scenarios() {
        let r = Renderer::new(&cfg(sc, sc.default_frames().min(240), 160, 120)).unwrap();
        let n = r.frames();
        for k in (0..n).step_by((n / 12).max(1)) {
            let t = r.truth(k);
            let sil = r.silhouette(k);
            let exact = r.analytic_outline(k).unwrap();
            let d_truth = ((sil.centre.x - t.cx).powi(2) + (sil.centre.y - t.cy).powi(2)).sqrt();
            let d_exact = (sil.centre - exact.centre).norm();
            assert!(
                d_truth < 0.5,
                "{sc} frame {k}: centroid {d_truth} px from centre"
            );
            assert!(
                d_exact < 0.05,
                "{sc} frame {k}: sampled vs exact centroid {d_exact}"
            );
            assert!((sil.area - exact.area).abs() / exact.area < 0.01);
            worst = worst.max(d_truth);
        }
    }
    // The offset is real (perspective), not an artefact of computing both the same way.
    assert!(worst > 0.005, "worst {worst}");
}

/// Convex hull (counter-clockwise in image coordinates' maths sense) of points.
fn convex_hull(mut pts: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    pts.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
        (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
    };
    let mut hull: Vec<(f64, f64)> = vec![];
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(f64, f64)>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

/// Area, centroid and covariance of a simple polygon (exact).
fn polygon_moments(poly: &[(f64, f64)]) -> (f64, (f64, f64), [f64; 3]) {
    let (ox, oy) = poly[0];
    let (mut a, mut sx, mut sy, mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..poly.len() {
        let (x0, y0) = (poly[i].0 - ox, poly[i].1 - oy);
        let j = (i + 1) % poly.len();
        let (x1, y1) = (poly[j].0 - ox, poly[j].1 - oy);
        let c = x0 * y1 - x1 * y0;
        a += c / 2.0;
        sx += (x0 + x1) * c / 6.0;
        sy += (y0 + y1) * c / 6.0;
        sxx += (x0 * x0 + x0 * x1 + x1 * x1) * c / 12.0;
        syy += (y0 * y0 + y0 * y1 + y1 * y1) * c / 12.0;
        sxy += (x0 * y1 + 2.0 * x0 * y0 + 2.0 * x1 * y1 + x1 * y0) * c / 24.0;
    }
    let (mx, my) = (sx / a, sy / a);
    (
        a.abs(),
        (ox + mx, oy + my),
        [sxx / a - mx * mx, sxy / a - mx * my, syy / a - my * my],
    )
}

#[test]
fn car_silhouette_matches_its_projected_hull() {
    // The outline of a convex polyhedron is the convex hull of its projected vertices: exact
    // area, centroid and second moments to check the sampled silhouette (and so the truth's
    // a, b) against. A box's outline is not symmetric about its projected centre (its near end
    // looks bigger): the car, about 1 m away, off-axis and turning, shows up to 3.6 px between
    // the truth centre (the projected centre, by definition) and the centroid.
    let r = Renderer::new(&SynthConfig::new(Scenario::Car)).unwrap();
    let Shape::Box { half } = *r.shape() else {
        panic!("the car is a box")
    };
    let mut worst: f64 = 0.0;
    for k in (0..r.frames()).step_by(10) {
        let corners: Vec<(f64, f64)> = (0..8)
            .map(|i| {
                let c = Vector3::new(
                    if i & 1 == 0 { -half.x } else { half.x },
                    if i & 2 == 0 { -half.y } else { half.y },
                    if i & 4 == 0 { -half.z } else { half.z },
                );
                r.project_point(k, &c)
            })
            .collect();
        let hull = convex_hull(corners);
        let (area, (mx, my), cov) = polygon_moments(&hull);
        let sil = r.silhouette(k);
        assert!(
            (sil.area - area).abs() / area < 0.01,
            "frame {k}: {} vs {area}",
            sil.area
        );
        assert!(
            (sil.centre.x - mx).abs() < 0.05 && (sil.centre.y - my).abs() < 0.05,
            "frame {k}"
        );
        let t = r.truth(k);
        let exact = pftrack::synth::Outline {
            centre: nalgebra::Vector2::new(mx, my),
            cov: nalgebra::Matrix2::new(cov[0], cov[1], cov[1], cov[2]),
            area,
        };
        let (a, b) = exact.axes_along(t.rz);
        assert!(
            (t.a - a).abs() / a < 0.01 && (t.b - b).abs() / b < 0.01,
            "frame {k}: {t:?} vs {a} {b}"
        );
        let d = ((mx - t.cx).powi(2) + (my - t.cy).powi(2)).sqrt();
        worst = worst.max(d);
        assert!(d < 4.0, "frame {k}: centre {d} px from the centroid");
    }
    eprintln!("car: centre to centroid at most {worst:.2} px");
    assert!(
        worst > 0.5,
        "a perspective offset is expected, found {worst}"
    );
}

#[test]
fn cast_hit_reprojects_with_the_truth_pose() {
    // Cast the ray through a random image position, take the hit point in object coordinates,
    // move it with the *truth row's* angles (R_t = Euler::matrix), the object's reference
    // orientation and centre, project it: the same position.
    let mut rng = Lcg(11);
    for &sc in Scenario::all() {
        let n = 30;
        let r = Renderer::new(&cfg(sc, n, 160, 120)).unwrap();
        let o0 = r.reference_orientation();
        let mut checked = 0;
        for k in [0, 7, 13, 22, 29] {
            let t: PoseState = r.truth(k);
            let rt = t.euler().matrix();
            let centre = r.pose(k).centre;
            let (cu, cv) = r.camera().project(&centre);
            assert!((cu - t.cx).abs() < 1e-9 && (cv - t.cy).abs() < 1e-9);
            for _ in 0..400 {
                let u = cu + (rng.next() - 0.5) * 3.0 * t.a.max(t.b);
                let v = cv + (rng.next() - 0.5) * 3.0 * t.b.min(t.a);
                if let Some(hit) = r.cast(k, u, v) {
                    assert!(r.shape().on_surface(&hit.point, 1e-9));
                    let p = rt * (o0 * hit.point) + centre;
                    let (pu, pv) = r.camera().project(&p);
                    assert!(
                        (pu - u).abs() < 1e-6 && (pv - v).abs() < 1e-6,
                        "{sc} frame {k}: ({u}, {v}) -> ({pu}, {pv})"
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 200, "{sc}: only {checked} hits");
    }
}

/// Surface points of a shape, spread over it.
fn surface_points(shape: &Shape, n: usize, rng: &mut Lcg) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|_| {
            let z = 2.0 * rng.next() - 1.0;
            let phi = std::f64::consts::TAU * rng.next();
            let s = (1.0 - z * z).sqrt();
            let dir = Vector3::new(s * phi.cos(), s * phi.sin(), z);
            match shape {
                Shape::Ellipsoid { semi } => dir.component_mul(semi),
                Shape::Box { half } => {
                    // push the direction out to the box surface
                    let m = (dir.x.abs() / half.x)
                        .max(dir.y.abs() / half.y)
                        .max(dir.z.abs() / half.z);
                    dir / m
                }
            }
        })
        .collect()
}

#[test]
fn known_surface_points_are_where_the_renderer_puts_them() {
    // A known surface point, moved by a known rotation (the truth) and projected: the renderer's
    // ray through that pixel hits exactly that point whenever the point faces the camera (the
    // shapes are convex), and never a point in front of a back-facing one.
    let mut rng = Lcg(5);
    for &sc in Scenario::all() {
        let r = Renderer::new(&cfg(sc, 24, 160, 120)).unwrap();
        let mut front = 0;
        for k in [0, 5, 11, 17, 23] {
            let t = r.truth(k);
            let m = t.euler().matrix() * r.reference_orientation();
            let centre = r.pose(k).centre;
            for p in surface_points(r.shape(), 300, &mut rng) {
                let pc = m * p + centre;
                let (u, v) = r.camera().project(&pc);
                let hit = r
                    .cast(k, u, v)
                    .expect("a surface point's own ray hits the shape");
                // outward normal in camera coordinates, from the shape's hit at that point
                let facing = match r.shape() {
                    Shape::Ellipsoid { semi } => {
                        let n = m * p.component_div(semi).component_div(semi).normalize();
                        n.dot(&pc.normalize())
                    }
                    Shape::Box { half } => {
                        // the face the point lies on
                        let q = p.component_div(half).abs();
                        let axis = q.imax();
                        let mut n = Vector3::zeros();
                        n[axis] = p[axis].signum();
                        (m * n).dot(&pc.normalize())
                    }
                };
                if facing < -0.05 {
                    assert!(
                        (hit.point - p).norm() < 1e-9,
                        "{sc} frame {k}: {p:?} rendered as {:?}",
                        hit.point
                    );
                    front += 1;
                } else if facing > 0.05 {
                    // back-facing: hidden behind a nearer surface point
                    assert!((hit.point - p).norm() > 1e-6);
                }
            }
        }
        assert!(front > 400, "{sc}: {front} front-facing points");
    }
}

/// Bilinear luma at a position.
fn luma_at(g: &GrayF32, u: f64, v: f64) -> f64 {
    g.sample(u as f32, v as f32) as f64
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let ma = a.iter().sum::<f64>() / n;
    let mb = b.iter().sum::<f64>() / n;
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

#[test]
fn texture_moves_rigidly_with_the_truth_pose() {
    // Sample surface points visible in two frames of a fast pan; the image intensity at their
    // truth-projected positions in frame j follows the intensity at their positions in frame i
    // closely, while the intensity at the *old* positions in frame j does not.
    let r = Renderer::new(&cfg(Scenario::Pan, 40, 320, 240)).unwrap();
    let (i, j) = (1, 3);
    let gi = GrayF32::from_rgb(&r.render_image(i));
    let gj = GrayF32::from_rgb(&r.render_image(j));
    let (ti, tj) = (r.truth(i), r.truth(j));
    let (mi, mj) = (ti.euler().matrix(), tj.euler().matrix());
    let (ci, cj) = (r.pose(i).centre, r.pose(j).centre);
    let mut rng = Lcg(3);
    let (mut a, mut b, mut stale) = (vec![], vec![], vec![]);
    for p in surface_points(r.shape(), 4000, &mut rng) {
        let (pi, pj) = (mi * p + ci, mj * p + cj);
        let (ui, vi) = r.camera().project(&pi);
        let (uj, vj) = r.camera().project(&pj);
        // well inside the silhouette in both frames: the hits in a 1.5 px ring are this surface
        let inside = |k: usize, u: f64, v: f64| {
            [(1.5, 0.0), (-1.5, 0.0), (0.0, 1.5), (0.0, -1.5)]
                .iter()
                .all(|(du, dv)| r.cast(k, u + du, v + dv).is_some())
        };
        let vis =
            |k: usize, u: f64, v: f64| r.cast(k, u, v).is_some_and(|h| (h.point - p).norm() < 1e-9);
        if vis(i, ui, vi) && vis(j, uj, vj) && inside(i, ui, vi) && inside(j, uj, vj) {
            a.push(luma_at(&gi, ui, vi));
            b.push(luma_at(&gj, uj, vj));
            stale.push(luma_at(&gj, ui, vi));
        }
    }
    assert!(a.len() > 300, "{} points", a.len());
    let follow = correlation(&a, &b);
    let still = correlation(&a, &stale);
    eprintln!(
        "{} points: correlation {follow:.3} following the truth, {still:.3} staying",
        a.len()
    );
    assert!(follow > 0.85, "follow {follow}");
    assert!(still < follow - 0.3, "stale {still} vs follow {follow}");
}

#[test]
fn truth_angles_start_at_zero_and_round_trip() {
    for &sc in Scenario::all() {
        let r = Renderer::new(&SynthConfig::new(sc)).unwrap();
        let t0 = r.truth(0);
        assert_eq!((t0.rx, t0.ry, t0.rz), (0.0, 0.0, 0.0), "{sc}");
        let mut prev = Euler::default();
        for k in 0..r.frames() {
            let rt = r.pose(k).rotation;
            let e = Euler::from_matrix(&rt);
            // the truth's angles rebuild the renderer's rotation
            assert!(angle_between(&e.matrix(), &rt) < 1e-9, "{sc} frame {k}");
            // continuous: no wrap jumps between frames
            let jump = (e.rx - prev.rx)
                .abs()
                .max((e.ry - prev.ry).abs())
                .max((e.rz - prev.rz).abs());
            assert!(jump < 0.1, "{sc} frame {k}: jump {jump} rad");
            prev = e;
        }
        // and the truth row carries exactly those angles
        for k in [1, r.frames() / 3, r.frames() - 1] {
            let t = r.truth(k);
            let e = Euler::from_matrix(&r.pose(k).rotation);
            assert!((t.rx - e.rx).abs() < 1e-12 && (t.ry - e.ry).abs() < 1e-12);
            assert!((t.rz - e.rz).abs() < 1e-12);
        }
    }
}

#[test]
fn head_axes_match_the_analytic_outline() {
    // Frame 0 (frontal) and turned frames of combo (rz ≠ 0: a, b measured along the rolled axes).
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let t = r.truth(0);
    let (a, b) = r.analytic_outline(0).unwrap().axes_along(0.0);
    assert!((t.a - a).abs() / a < 0.01, "a {} vs {a}", t.a);
    assert!((t.b - b).abs() / b < 0.01, "b {} vs {b}", t.b);
    // the head is taller than wide, about 37 × 49 px at 160x120
    assert!(t.b > t.a && (30.0..45.0).contains(&(2.0 * t.a)), "{t:?}");
    let init = r.init_ellipse();
    assert_eq!(
        (init.cx, init.cy, init.a, init.b, init.theta),
        (t.cx, t.cy, t.a, t.b, 0.0)
    );

    let r = Renderer::new(&SynthConfig::new(Scenario::Combo)).unwrap();
    for k in [17, 50, 101, 190] {
        let t = r.truth(k);
        assert!(t.rz.abs() > 0.02, "frame {k} has roll");
        let (a, b) = r.analytic_outline(k).unwrap().axes_along(t.rz);
        assert!((t.a - a).abs() / a < 0.02, "frame {k}: a {} vs {a}", t.a);
        assert!((t.b - b).abs() / b < 0.02, "frame {k}: b {} vs {b}", t.b);
    }
}

// ---------------------------------------------------------------- scenarios

fn extremes(r: &Renderer) -> [(f64, f64); 3] {
    let mut out = [(f64::INFINITY, f64::NEG_INFINITY); 3];
    for k in 0..r.frames() {
        let e = Euler::from_matrix(&r.pose(k).rotation).to_degrees();
        for (o, v) in out.iter_mut().zip(e) {
            o.0 = o.0.min(v);
            o.1 = o.1.max(v);
        }
    }
    out
}

#[test]
fn every_scenario_renders() {
    for &sc in Scenario::all() {
        let r = Renderer::new(&cfg(sc, 9, 64, 48)).unwrap();
        for k in [0, 4, 8] {
            let (img, t) = r.render(k);
            assert_eq!(img.dimensions(), (64, 48));
            assert!(t.a > 2.0 && t.b > 2.0, "{sc} frame {k}: {t:?}");
            assert!(
                t.cx > 0.0 && t.cx < 63.0 && t.cy > 0.0 && t.cy < 47.0,
                "{sc} {t:?}"
            );
            // textured: the image is far from flat
            let g = GrayF32::from_rgb(&img);
            let mean = g.data.iter().sum::<f32>() / g.data.len() as f32;
            let var = g.data.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / g.data.len() as f32;
            assert!(var > 0.002, "{sc}: variance {var}");
        }
    }
}

#[test]
fn objects_stay_in_view_over_default_sequences() {
    for &sc in Scenario::all() {
        let r = Renderer::new(&SynthConfig::new(sc)).unwrap();
        let step = if sc == Scenario::Long { 5 } else { 1 };
        for k in (0..r.frames()).step_by(step) {
            assert!(r.image_bounds(k).is_some(), "in front of the camera");
            // exact image extents: the box's projected corners, the ellipsoid's outline
            let [u0, u1, v0, v1] = match r.shape() {
                Shape::Box { half } => {
                    let mut e = [
                        f64::INFINITY,
                        f64::NEG_INFINITY,
                        f64::INFINITY,
                        f64::NEG_INFINITY,
                    ];
                    for i in 0..8 {
                        let c = Vector3::new(
                            if i & 1 == 0 { -half.x } else { half.x },
                            if i & 2 == 0 { -half.y } else { half.y },
                            if i & 4 == 0 { -half.z } else { half.z },
                        );
                        let (u, v) = r.project_point(k, &c);
                        e = [e[0].min(u), e[1].max(u), e[2].min(v), e[3].max(v)];
                    }
                    e
                }
                Shape::Ellipsoid { .. } => {
                    let o = r.analytic_outline(k).unwrap();
                    let (hu, hv) = (2.0 * o.cov[(0, 0)].sqrt(), 2.0 * o.cov[(1, 1)].sqrt());
                    [
                        o.centre.x - hu,
                        o.centre.x + hu,
                        o.centre.y - hv,
                        o.centre.y + hv,
                    ]
                }
            };
            assert!(
                u0 > -0.5 && v0 > -0.5 && u1 < 159.5 && v1 < 119.5,
                "{sc} frame {k}: {u0} {u1} {v0} {v1}"
            );
        }
    }
}

#[test]
fn scenario_amplitudes() {
    let close = |x: f64, want: f64| (x - want).abs() < 1.0;
    let e = extremes(&Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap());
    assert!(close(e[0].0, -35.0) && close(e[0].1, 35.0), "nod {e:?}");
    assert!(e[1].0.abs() < 1e-9 && e[2].1.abs() < 1e-9);
    // also with few frames
    let e = extremes(&Renderer::new(&cfg(Scenario::Nod, 30, 64, 48)).unwrap());
    assert!(close(e[0].0, -35.0) && close(e[0].1, 35.0), "nod/30 {e:?}");

    let e = extremes(&Renderer::new(&SynthConfig::new(Scenario::Pan)).unwrap());
    assert!(close(e[1].0, -60.0) && close(e[1].1, 60.0), "pan {e:?}");
    assert!(e[0].1.abs() < 1e-9 && e[2].1.abs() < 1e-9);

    let e = extremes(&Renderer::new(&SynthConfig::new(Scenario::Roll)).unwrap());
    assert!(close(e[2].0, -45.0) && close(e[2].1, 45.0), "roll {e:?}");

    let e = extremes(&Renderer::new(&SynthConfig::new(Scenario::Combo)).unwrap());
    for (axis, (lo, hi)) in e.iter().enumerate() {
        assert!(*lo < -15.0 && *hi > 15.0, "combo axis {axis}: {lo}..{hi}");
    }

    let e = extremes(&Renderer::new(&SynthConfig::new(Scenario::Long)).unwrap());
    for (axis, (lo, hi)) in e.iter().enumerate() {
        assert!(hi - lo > 10.0, "long axis {axis}: {lo}..{hi}");
    }
}

#[test]
fn combo_changes_speed() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Combo)).unwrap();
    let n = r.frames();
    let speeds: Vec<f64> = (1..n)
        .map(|k| angle_between(&r.pose(k).rotation, &r.pose(k - 1).rotation))
        .collect();
    let max = speeds.iter().cloned().fold(0.0, f64::max);
    let min = speeds.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(max > 3.0 * min.max(1e-6), "{min} .. {max}");
    let c0 = r.pose(0).centre;
    assert!(
        (0..n).any(|k| (r.pose(k).centre - c0).norm() > 0.03),
        "translates"
    );
}

#[test]
fn depth_approaches_and_recedes() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Depth)).unwrap();
    let z: Vec<f64> = (0..r.frames()).map(|k| r.pose(k).centre.z).collect();
    let (zmin, zmax) = (
        z.iter().cloned().fold(f64::INFINITY, f64::min),
        z.iter().cloned().fold(0.0, f64::max),
    );
    let kmin = z.iter().position(|&v| v == zmin).unwrap();
    let kmax = z.iter().position(|&v| v == zmax).unwrap();
    assert!(kmin < kmax, "approaches first");
    assert!(
        zmin < 0.65 * z[0] && zmax > 1.35 * z[0],
        "{zmin} {zmax} {}",
        z[0]
    );
    // the silhouette scales inversely with depth (near, roughly: perspective of a solid)
    let (t0, tn) = (r.truth(0), r.truth(kmin));
    let ratio = tn.b / t0.b;
    assert!(
        (ratio - z[0] / zmin).abs() / (z[0] / zmin) < 0.05,
        "{ratio}"
    );
}

#[test]
fn car_translates_then_turns_sixty_degrees() {
    let r = Renderer::new(&SynthConfig::new(Scenario::Car)).unwrap();
    assert!(matches!(r.shape(), Shape::Box { .. }));
    let n = r.frames();
    let last = r.pose(n - 1).rotation;
    let turned = angle_between(&last, &Matrix3::identity()).to_degrees();
    assert!((turned - 60.0).abs() < 0.5, "turned {turned}°");
    // the turn is about the car's own up axis
    let up = r.reference_orientation() * Vector3::new(0.0, -1.0, 0.0);
    assert!((last * up - up).norm() < 1e-9);
    // first translation only, then the turn
    let mid = n * 2 / 5;
    assert!(angle_between(&r.pose(mid).rotation, &Matrix3::identity()) < 1e-9);
    let shift = r.truth(mid).cx - r.truth(0).cx;
    assert!(shift > 15.0, "moves across the image: {shift} px");
    // the truth row says it too
    let t = r.truth(n - 1);
    assert!(angle_between(&t.euler().matrix(), &Matrix3::identity()).to_degrees() > 59.5);
}

#[test]
fn long_has_at_least_2000_frames() {
    assert!(Scenario::Long.default_frames() >= 2000);
    let c = SynthConfig::new(Scenario::Long);
    assert!(c.frames >= 2000);
    // the last frame renders and is still a sane view
    let r = Renderer::new(&c).unwrap();
    let t = r.truth(c.frames - 1);
    assert!(
        t.a > 10.0 && t.b > 10.0 && (10.0..150.0).contains(&t.cx),
        "{t:?}"
    );
    for &sc in Scenario::all() {
        assert!((120..=240).contains(&sc.default_frames()) || sc == Scenario::Long);
    }
}

#[test]
fn unknown_scenario_lists_valid_names() {
    let e = Scenario::from_name("spin").unwrap_err().to_string();
    for &s in Scenario::all() {
        assert!(e.contains(s.name()), "{e}");
    }
    assert!(Renderer::new(&cfg(Scenario::Nod, 0, 160, 120)).is_err());
    assert!(Renderer::new(&cfg(Scenario::Nod, 5, 0, 120)).is_err());
}

#[test]
fn every_scenario_at_the_smallest_size_gives_a_start_a_tracker_takes() {
    use pftrack::synth::MIN_SIDE;
    use pftrack::tracker::{Init, TrackerConfig};
    let tc = TrackerConfig::default();
    for &sc in Scenario::all() {
        for (w, h) in [
            (MIN_SIDE, MIN_SIDE),
            (MIN_SIDE, 8 * MIN_SIDE),
            (8 * MIN_SIDE, MIN_SIDE),
        ] {
            let r = Renderer::new(&cfg(sc, 3, w, h)).unwrap();
            let init = Init::frontal(r.init_ellipse());
            // At 16 px a side the heads' start was 1.8 px wide and the tracker refused it.
            init.check_for(&tc, w, h)
                .unwrap_or_else(|e| panic!("{sc:?} at {w}x{h}: {e}"));
        }
    }
    assert!(Renderer::new(&cfg(Scenario::Nod, 3, MIN_SIDE - 1, 120)).is_err());
}

#[test]
fn wide_frames_keep_the_whole_outline_in_the_truth() {
    // The field of view is horizontal: at 320x48 the head is as large as at 320x240 and
    // reaches well past the top and bottom. Its truth is the unclipped outline's, the same
    // semi-axes as on the taller frame (a window of one height beyond the borders cut b 7 %).
    for sc in [Scenario::Depth, Scenario::Nod] {
        let wide = Renderer::new(&cfg(sc, 5, 320, 48)).unwrap();
        let tall = Renderer::new(&cfg(sc, 5, 320, 240)).unwrap();
        for k in 0..5 {
            let (tw, tt) = (wide.truth(k), tall.truth(k));
            let (a, b) = wide.analytic_outline(k).unwrap().axes_along(tw.rz);
            assert!(
                (tw.a - a).abs() / a < 0.01,
                "{sc} frame {k}: a {} vs {a}",
                tw.a
            );
            assert!(
                (tw.b - b).abs() / b < 0.01,
                "{sc} frame {k}: b {} vs {b}",
                tw.b
            );
            assert!((tw.a - tt.a).abs() < 0.01 * tt.a && (tw.b - tt.b).abs() < 0.01 * tt.b);
            assert!(
                2.0 * tw.b > 48.0,
                "{sc} frame {k}: the head is taller than the frame"
            );
        }
    }
}

#[test]
fn sizes_are_bounded_by_the_pixels_a_tracker_reads() {
    use pftrack::synth::{MAX_PIXELS, parse_size};
    assert_eq!(MAX_PIXELS, pftrack::frames::y4m::MAX_PIXELS);
    assert_eq!(parse_size("8192x4096").unwrap(), (8192, 4096));
    for big in ["8192x4097", "8192x8192"] {
        let e = parse_size(big).unwrap_err().to_string();
        assert!(e.contains("33554432 pixels"), "{e}");
        let (w, h) = pftrack::frames::parse_wxh(big).unwrap();
        assert!(Renderer::new(&cfg(Scenario::Nod, 1, w, h)).is_err());
    }
}

// ---------------------------------------------------------------- determinism

#[test]
fn same_seed_same_bytes_different_seed_different_texture() {
    let c = cfg(Scenario::Combo, 10, 96, 72);
    let a = Renderer::new(&c).unwrap().render_image(6);
    // a fresh renderer, and a single thread instead of the pool: the same bytes
    let single = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let b = single.install(|| Renderer::new(&c).unwrap().render_image(6));
    assert_eq!(a.as_raw(), b.as_raw());

    let other = SynthConfig { seed: 2, ..c };
    let ro = Renderer::new(&other).unwrap();
    let d = ro.render_image(6);
    let differing = a
        .as_raw()
        .iter()
        .zip(d.as_raw())
        .filter(|(x, y)| x != y)
        .count();
    assert!(differing > a.as_raw().len() / 2, "{differing}");
    // the object's texture itself differs, not only the noise
    let r1 = Renderer::new(&c).unwrap();
    let p = Vector3::new(0.0, 0.0, -0.085);
    let changed = (0..40)
        .filter(|i| {
            let q = p + Vector3::new(-0.04 + 0.002 * *i as f64, 0.01, 0.0);
            r1.albedo(&q) != ro.albedo(&q)
        })
        .count();
    assert!(changed > 20, "{changed}");
}

// ---------------------------------------------------------------- texture richness

/// Harris corners (k = 0.04, 5×5 box window, 3×3 non-maximum suppression) with a response of
/// at least `thresh` (image in [0, 1]).
fn harris_corners(g: &GrayF32, thresh: f32) -> Vec<(usize, usize)> {
    let (w, h) = (g.width as usize, g.height as usize);
    let px = |x: i64, y: i64| g.get_clamped(x, y);
    let mut ixx = vec![0f32; w * h];
    let mut iyy = vec![0f32; w * h];
    let mut ixy = vec![0f32; w * h];
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let gx = (px(x + 1, y - 1) + 2.0 * px(x + 1, y) + px(x + 1, y + 1)
                - px(x - 1, y - 1)
                - 2.0 * px(x - 1, y)
                - px(x - 1, y + 1))
                / 8.0;
            let gy = (px(x - 1, y + 1) + 2.0 * px(x, y + 1) + px(x + 1, y + 1)
                - px(x - 1, y - 1)
                - 2.0 * px(x, y - 1)
                - px(x + 1, y - 1))
                / 8.0;
            let i = y as usize * w + x as usize;
            ixx[i] = gx * gx;
            iyy[i] = gy * gy;
            ixy[i] = gx * gy;
        }
    }
    let mut resp = vec![0f32; w * h];
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            let (mut a, mut b, mut c) = (0.0, 0.0, 0.0);
            for dy in 0..5 {
                for dx in 0..5 {
                    let i = (y + dy - 2) * w + x + dx - 2;
                    a += ixx[i];
                    b += iyy[i];
                    c += ixy[i];
                }
            }
            resp[y * w + x] = a * b - c * c - 0.04 * (a + b) * (a + b);
        }
    }
    let mut out = vec![];
    for y in 3..h - 3 {
        for x in 3..w - 3 {
            let r = resp[y * w + x];
            if r < thresh {
                continue;
            }
            let is_max = (0..3).all(|dy| {
                (0..3).all(|dx| {
                    let q = resp[(y + dy - 1) * w + x + dx - 1];
                    (dx == 1 && dy == 1) || q < r
                })
            });
            if is_max {
                out.push((x, y));
            }
        }
    }
    out
}

#[test]
fn texture_is_rich_in_corners() {
    // At 160x120 the head covers about 37 × 49 px; count strong corners well inside it.
    for (sc, k, want) in [
        (Scenario::Nod, 0, 15),
        (Scenario::Pan, 30, 12),
        (Scenario::Car, 0, 15),
    ] {
        let r = Renderer::new(&SynthConfig::new(sc)).unwrap();
        let (img, t) = r.render(k);
        let g = GrayF32::from_rgb(&img);
        let inner = t.ellipse(0.0);
        let inner = pftrack::geometry::Ellipse {
            a: 0.8 * inner.a,
            b: 0.8 * inner.b,
            ..inner
        };
        let n = harris_corners(&g, 1e-4)
            .iter()
            .filter(|(x, y)| inner.contains(*x as f64, *y as f64))
            .count();
        eprintln!("{sc} frame {k}: {n} corners inside");
        assert!(n >= want, "{sc} frame {k}: {n} corners inside the object");
        // and a flat image has none: the detector can fail
        let flat = GrayF32 {
            width: g.width,
            height: g.height,
            data: vec![0.5; g.data.len()],
        };
        assert!(harris_corners(&flat, 1e-4).is_empty());
    }
}

// ---------------------------------------------------------------- files and CLI

#[test]
fn written_frames_equal_the_in_memory_render() {
    let dir = tmp_dir("lib");
    let c = cfg(Scenario::Roll, 4, 64, 48);
    let s = write_sequence(&c, &dir, false).unwrap();
    // Found again in the folder, as `pftrack track DIR` and an embedder find it.
    let found = pftrack::synth::SequencePaths::find(&dir).unwrap();
    assert_eq!(
        (&found.frames, &found.init, found.truth.as_ref()),
        (&s.frames_dir, &s.init_file, Some(&s.truth))
    );
    assert!(pftrack::synth::SequencePaths::find(&s.frames_dir).is_none());
    let r = Renderer::new(&c).unwrap();
    for k in 0..4 {
        let img = image::open(dir.join("frames").join(format!("{k:05}.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!(img.as_raw(), r.render_image(k).as_raw(), "frame {k}");
    }
    let truth = read_pose_csv(&s.truth).unwrap();
    assert_eq!(truth.len(), 4);
    for (k, rec) in truth.iter().enumerate() {
        let t = r.truth(k).to_array();
        let f = rec.state.to_array();
        for i in 0..7 {
            assert!(
                (t[i] - f[i]).abs() < 1e-5,
                "frame {k} field {i}: {} vs {}",
                t[i],
                f[i]
            );
        }
    }
    // a shorter re-render removes the frames of the longer one, and an interrupted frame's
    // temporary file
    std::fs::write(dir.join("frames/.00003.png.partial"), b"half").unwrap();
    std::fs::write(dir.join("frames/.00004.png.77-0.partial"), b"half").unwrap();
    write_sequence(&cfg(Scenario::Roll, 2, 64, 48), &dir, false).unwrap();
    let mut names: Vec<String> = std::fs::read_dir(dir.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(names, ["00000.png", "00001.png"]);
    assert_eq!(read_pose_csv(&dir.join("truth.csv")).unwrap().len(), 2);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_failed_render_leaves_the_folder_as_it_was() {
    let dir = tmp_dir("fail");
    let c = cfg(Scenario::Pan, 3, 48, 36);
    write_sequence(&c, &dir, false).unwrap();
    assert!(dir.join("truth.csv").exists() && dir.join("init.txt").exists());
    let truth = std::fs::read(dir.join("truth.csv")).unwrap();
    let frame0 = std::fs::read(dir.join("frames/00000.png")).unwrap();
    // Frame 1 cannot be moved in: a non-empty folder stands in its place. Found before
    // anything moves; the old sequence used to lose its truth and init file here (and to an
    // interrupt mid-render), and the new frames written before the failure stayed.
    std::fs::remove_file(dir.join("frames/00001.png")).unwrap();
    std::fs::create_dir_all(dir.join("frames/00001.png/x")).unwrap();
    let c2 = SynthConfig { seed: 7, ..c };
    let err = write_sequence(&c2, &dir, false).unwrap_err().to_string();
    assert!(err.contains("00001.png"), "{err}");
    assert_eq!(std::fs::read(dir.join("truth.csv")).unwrap(), truth);
    assert!(dir.join("init.txt").exists());
    assert_eq!(std::fs::read(dir.join("frames/00000.png")).unwrap(), frame0);
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["frames", "init.txt", "truth.csv"],
        "no staging folder left"
    );
    // A render into a path that is a file is refused.
    let file = dir.join("plain");
    std::fs::write(&file, "x").unwrap();
    assert!(write_sequence(&c, &file, false).is_err());
    assert_eq!(std::fs::read(&file).unwrap(), b"x");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `frames` that is not a folder is refused before anything is rendered (a dangling link
/// used to fail after the whole render, with the old truth already deleted), and a stale
/// frame that is a folder is left alone rather than failing the move half-way.
#[test]
fn a_sequence_folder_in_an_odd_state_is_refused_or_left_alone() {
    let dir = tmp_dir("odd");
    let c = cfg(Scenario::Pan, 3, 48, 36);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("frames"), "not a folder").unwrap();
    let err = write_sequence(&c, &dir, false).unwrap_err().to_string();
    assert!(
        err.contains("frames") && err.contains("not a folder"),
        "{err}"
    );
    std::fs::remove_file(dir.join("frames")).unwrap();
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(dir.join("nowhere"), dir.join("frames")).unwrap();
        let err = write_sequence(&c, &dir, false).unwrap_err().to_string();
        assert!(err.contains("not a folder"), "{err}");
        std::fs::remove_file(dir.join("frames")).unwrap();
    }
    assert!(!dir.join("truth.csv").exists());
    // Frames with neither truth nor init file beside them are not a render's: refused, and
    // left as they were (a render replaced them and removed those past its length).
    std::fs::create_dir_all(dir.join("frames/00005.png")).unwrap();
    std::fs::write(dir.join("frames/00004.png"), "stale").unwrap();
    let err = write_sequence(&c, &dir, false).unwrap_err().to_string();
    assert!(
        err.contains("00004.png") && err.contains("truth.csv") && !err.contains('\n'),
        "{err}"
    );
    assert_eq!(
        std::fs::read(dir.join("frames/00004.png")).unwrap(),
        b"stale"
    );
    // A folder where a longer render's frame 5 was (its init file beside it): the new
    // 3-frame sequence goes in, the regular stale frames go, the folder stays.
    std::fs::write(dir.join("init.txt"), "10,10,5,5\n").unwrap();
    write_sequence(&c, &dir, false).unwrap();
    let mut names: Vec<String> = std::fs::read_dir(dir.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(names, ["00000.png", "00001.png", "00002.png", "00005.png"]);
    assert_eq!(read_pose_csv(&dir.join("truth.csv")).unwrap().len(), 3);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A link named `truth.csv` is replaced by the new truth, not written through (which deleted
/// the link, overwrote its target and left no truth); staging a killed render left an hour
/// ago is removed, a fresh one (another render's, under way) is not.
#[cfg(unix)]
#[test]
fn links_are_replaced_and_abandoned_staging_is_removed() {
    let dir = tmp_dir("links");
    let c = cfg(Scenario::Nod, 3, 48, 36);
    write_sequence(&c, &dir, false).unwrap();
    let elsewhere = dir.with_extension("elsewhere.csv");
    std::fs::write(&elsewhere, "keep me").unwrap();
    std::fs::remove_file(dir.join("truth.csv")).unwrap();
    std::os::unix::fs::symlink(&elsewhere, dir.join("truth.csv")).unwrap();
    let old = dir.join("frames/.pftrack-synth-1-1.partial");
    let fresh = dir.join("frames/.pftrack-synth-2-2.partial");
    for d in [&old, &fresh] {
        std::fs::create_dir_all(d).unwrap();
        std::fs::write(d.join("00000.png"), "x").unwrap();
    }
    let old_file = dir.join(".pftrack-synth-1-1.partial-truth.csv");
    std::fs::write(&old_file, "half").unwrap();
    for p in [&old, &old_file] {
        let touched = std::process::Command::new("touch")
            .args(["-d", "2 hours ago"])
            .arg(p)
            .status()
            .unwrap();
        assert!(touched.success());
    }
    write_sequence(&c, &dir, false).unwrap();
    let meta = std::fs::symlink_metadata(dir.join("truth.csv")).unwrap();
    assert!(meta.is_file(), "the link is replaced by a file");
    assert_eq!(read_pose_csv(&dir.join("truth.csv")).unwrap().len(), 3);
    assert_eq!(std::fs::read_to_string(&elsewhere).unwrap(), "keep me");
    assert!(!old.exists() && !old_file.exists());
    assert!(fresh.exists());
    std::fs::remove_file(&elsewhere).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Normalised 8×8×8 RGB histogram of the listed pixels.
fn histogram(img: &image::RgbImage, pixels: &[(u32, u32)]) -> Vec<f64> {
    let mut h = vec![0.0; 512];
    for &(x, y) in pixels {
        let p = img.get_pixel(x, y).0;
        let bin = (p[0] as usize / 32) * 64 + (p[1] as usize / 32) * 8 + p[2] as usize / 32;
        h[bin] += 1.0;
    }
    let n = pixels.len() as f64;
    h.iter().map(|v| v / n).collect()
}

#[test]
fn head_colours_differ_from_the_background_but_overlap() {
    // The colour term of the likelihood needs a head whose colours differ from the background's
    // (Bhattacharyya coefficient clearly below 1), but not a trivially separable one (a
    // coefficient clearly above 0: skin and hair tones also occur in the background).
    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let img = r.render_image(0);
    let (mut head, mut bg) = (vec![], vec![]);
    for y in 0..img.height() {
        for x in 0..img.width() {
            let (u, v) = (x as f64, y as f64);
            let corners = [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)];
            let hits = corners
                .iter()
                .filter(|(du, dv)| r.cast(0, u + du, v + dv).is_some())
                .count();
            match hits {
                4 => head.push((x, y)),
                0 => bg.push((x, y)),
                _ => {}
            }
        }
    }
    assert!(head.len() > 1000, "{}", head.len());
    let (hh, hb) = (histogram(&img, &head), histogram(&img, &bg));
    let rho: f64 = hh.iter().zip(&hb).map(|(p, q)| (p * q).sqrt()).sum();
    eprintln!("Bhattacharyya coefficient head/background: {rho:.3}");
    assert!(
        rho < 0.8,
        "head colours too close to the background's: {rho}"
    );
    assert!(rho > 0.15, "head trivially separable by colour: {rho}");
}
