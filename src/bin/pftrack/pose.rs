//! `pftrack pose`: the rotation between two images (SIFT matches inside an ellipse, the
//! paper's outlier rejection, a rotation solver, the Necker pair completed and its branch
//! picked by parallax against the block-matched centre).

use std::path::PathBuf;

use anyhow::bail;
use clap::Args;
use image::{Rgb, RgbImage};
use nalgebra::Vector2;
use pftrack::features::{
    FeatureError, MatchParams, Sift, SiftParams, keep_slope_length, match_features,
};
use pftrack::frames::GrayF32;
use pftrack::frames::dir::decode_rgb;
use pftrack::geometry::{Ellipse, Euler};
use pftrack::motion::{AbmParams, block_match};
use pftrack::pose::ransac::{affine_consensus, select};
use pftrack::pose::{Rls, SolverKind, essential_rotation, interframe, resolve_by_parallax};

use crate::track::parse_floats;

/// Arguments of `pftrack pose`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct PoseArgs {
    /// The first image.
    pub frame_a: PathBuf,
    /// The second image (same size).
    pub frame_b: PathBuf,
    /// The object's ellipse in the first image, `cx,cy,a,b[,angle_deg]`.
    #[arg(
        long,
        value_name = "CX,CY,A,B[,ANGLE]",
        allow_hyphen_values = true,
        value_parser = crate::values::four_or_five
    )]
    pub ellipse: String,
    /// Solver: sea, optimal, lsm, rls or essential.
    #[arg(long, default_value = "sea", value_parser = crate::values::solver)]
    pub solver: String,
    /// Outlier rejection before the solver: `paper` (the paper's: a match's displacement
    /// within 0.2 rad of the mean direction and 30 % of the mean length), `ransac` (the
    /// largest set one affine map carries to within 2 px, which keeps a turn in the image
    /// plane, whose matches move in every direction and the paper's rule rejects) or `none`.
    #[arg(long, value_enum, default_value_t = Reject::Paper)]
    pub reject: Reject,
    /// Draw the matches as arrows (like the paper's Fig. 1) into this PNG.
    #[arg(long, value_name = "F.png")]
    pub draw: Option<PathBuf>,
}

/// The least spread of the matches across their best-fitting line (RMS, pixels) `pose` solves
/// from: about three times SIFT's error (0.24-0.49 px RMS, `examples/bundle_bias.rs`).
const MIN_SPREAD_ACROSS_PX: f64 = 1.0;

/// Outlier rejection of `pftrack pose`'s matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Reject {
    /// The paper's slope/length rule.
    Paper,
    /// RANSAC on an affine map.
    Ransac,
    /// Every match inside the ellipse.
    None,
}

/// Draws a line with a small arrow head (nearest-pixel steps).
fn arrow(img: &mut RgbImage, a: [f64; 2], b: [f64; 2], c: Rgb<u8>, head: usize) {
    let mut put = |x: f64, y: f64| {
        let (xi, yi) = (x.round() as i64, y.round() as i64);
        if xi >= 0 && yi >= 0 && (xi as u32) < img.width() && (yi as u32) < img.height() {
            img.put_pixel(xi as u32, yi as u32, c);
        }
    };
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let n = dx.abs().max(dy.abs()).ceil().max(1.0) as usize;
    for k in 0..=n {
        let t = k as f64 / n as f64;
        put(a[0] + t * dx, a[1] + t * dy);
    }
    let len = (dx * dx + dy * dy).sqrt();
    if len > 1e-9 {
        let (ux, uy) = (dx / len, dy / len);
        for s in [-1.0, 1.0] {
            let (hx, hy) = (-ux * 0.8 + s * uy * 0.6, -uy * 0.8 - s * ux * 0.6);
            for k in 0..=head {
                put(b[0] + hx * k as f64, b[1] + hy * k as f64);
            }
        }
    }
}

/// What `pose` says of a block solver's fit beyond its rotation, from the matches it used.
#[derive(Debug, Clone, Copy, PartialEq)]
struct BlockFit {
    /// The RMS residual of the completed rotation's block (its translation refitted), where
    /// completion moved the solver's block onto a rotation's (LSM's and RLS's): the solver's
    /// own residual is then that of a map no rotation gives.
    completed_residual: Option<f64>,
    /// The larger singular value of the unconstrained least-squares block: the change of size
    /// the matches show (1 for a turn at a constant distance), which the solvers do not model.
    scale: Option<f64>,
    /// The image motion of the object's centre under the printed rotation's map (the
    /// completed block's, where completion moved it), which the parallax test reads.
    motion: Vector2<f64>,
    /// The standard error of one component of the fitted translation, `residual / √(2n)`
    /// (pixels; the residual is the RMS of the 2D error).
    translation_noise: f64,
    /// SEA's Newton residual where it stopped short of convergence (its block is then its
    /// best iterate, projected onto the valid blocks).
    sea_unconverged: Option<f64>,
    /// The certified minimiser's residual where it fits better than SEA's block: SEA finds a
    /// stationary point of the constrained problem, not always its minimum.
    optimal_better: Option<f64>,
}

impl BlockFit {
    fn of(
        i: &pftrack::pose::InterFrame,
        kind: SolverKind,
        centre: Vector2<f64>,
        p: &[[f64; 2]],
        q: &[[f64; 2]],
    ) -> Self {
        use pftrack::pose::{complete::singular_values, lsm::lsm_block, moments, rms_residual};
        let (up, uq) = select(p, q, &i.block.inliers);
        let m = moments(&up, &uq, 3).ok();
        let r2 = i.pair.a.fixed_view::<2, 2>(0, 0).into_owned();
        let moved = (r2 - i.block.r2).norm() > 1e-9;
        let completed = m.filter(|_| moved).map(|m| {
            let l = m.mean_q - r2 * m.mean_p;
            (
                rms_residual(&r2, &l, &up, &uq, None),
                r2 * centre + l - centre,
            )
        });
        let completed_residual = completed.map(|c| c.0);
        let motion = completed.map_or(i.translation, |c| c.1);
        let scale = m
            .and_then(|m| lsm_block(&m).ok())
            .map(|b| singular_values(&b).0);
        let residual = completed_residual.unwrap_or(i.block.residual);
        let sea_unconverged = match (kind, m) {
            (SolverKind::Sea, Some(m)) => pftrack::pose::Sea::default()
                .solve_moments(&m)
                .ok()
                .filter(|s| !s.converged)
                .map(|s| s.residual_norm),
            _ => None,
        };
        let optimal_better = match kind {
            SolverKind::Sea => pftrack::pose::solver(SolverKind::Optimal)
                .solve(&up, &uq)
                .ok()
                .map(|o| o.residual)
                .filter(|&r| r < residual * (1.0 - 1e-6) - 1e-9),
            _ => None,
        };
        Self {
            completed_residual,
            scale,
            motion,
            translation_noise: residual / (2.0 * up.len().max(1) as f64).sqrt(),
            sea_unconverged,
            optimal_better,
        }
    }
}

/// The least parallax that decides a branch (pixels): on exact or identical images the
/// features' noise is nil, and a rounding error of 1e-14 px had been "over twice" it.
const LEAST_PARALLAX_PX: f64 = 0.01;

/// Whether the parallax `offset` decides the Necker branch of `chosen`: its component along
/// the direction the turn moves the surface in (the rotation's `(r13, r23)`), against twice
/// the features' translation's standard error `noise` (block matching's own error, which
/// nothing here measures, is not counted), and never on less than [`LEAST_PARALLAX_PX`].
fn branch_verdict(chosen: &nalgebra::Matrix3<f64>, offset: Vector2<f64>, noise: f64) -> String {
    let c = Vector2::new(chosen[(0, 2)], chosen[(1, 2)]);
    if c.norm() < 1e-9 {
        return "the turn is in the image plane, which has no mirror to tell apart".to_string();
    }
    let along = c.normalize().dot(&offset).abs();
    if along <= LEAST_PARALLAX_PX {
        format!(
            "{along:.3} px along the turn, under {LEAST_PARALLAX_PX} px: no parallax to speak \
             of, the branch is a guess"
        )
    } else if along > 2.0 * noise {
        format!(
            "{along:.2} px along the turn, over twice the features' noise of about {noise:.2} \
             px: it points to this branch"
        )
    } else {
        format!(
            "{along:.2} px along the turn is within twice the features' noise of about \
             {noise:.2} px: the branch is a guess"
        )
    }
}

/// Runs the command.
pub fn run(a: PoseArgs) -> anyhow::Result<()> {
    let v = parse_floats(&a.ellipse, &[4, 5], "--ellipse")?;
    let e = Ellipse {
        cx: v[0],
        cy: v[1],
        a: v[2],
        b: v[3],
        theta: v.get(4).copied().unwrap_or(0.0).to_radians(),
    };
    if !e.is_valid() {
        bail!("--ellipse: semi-axes must be positive");
    }
    // Opened before the work, so a bad place for the drawing fails at once.
    let draw = match &a.draw {
        Some(d) => {
            crate::paths::not_an_input("--draw", d, &[&a.frame_a, &a.frame_b])?;
            crate::paths::png_name("--draw", d)?;
            Some(pftrack::io::AtomicFile::create(d)?)
        }
        None => None,
    };
    // `None`: the essential-matrix baseline, which is not a block solver.
    // Any case, as `--solver` accepts it (`ESSENTIAL` passed the parser and was then refused).
    let solver = match a.solver.as_str() {
        name if name.eq_ignore_ascii_case("essential") => None,
        name => Some(SolverKind::from_name(name).map_err(|_| {
            anyhow::anyhow!(
                "unknown solver `{name}` (expected sea, optimal, lsm, rls or essential)"
            )
        })?),
    };
    let (ia, ib) = (decode_rgb(&a.frame_a)?, decode_rgb(&a.frame_b)?);
    if ia.dimensions() != ib.dimensions() {
        bail!(
            "the images differ in size: {}x{} and {}x{}",
            ia.width(),
            ia.height(),
            ib.width(),
            ib.height()
        );
    }
    // The rules of a tracker's start: the centre in the image, semi-axes from 2 px to its
    // longer side, an angle within a turn (1e308 px axes were taken).
    pftrack::tracker::Init::frontal(e)
        .check(ia.width(), ia.height())
        .map_err(|err| match err {
            pftrack::tracker::TrackError::BadInit { why, .. } => {
                anyhow::anyhow!("--ellipse: {why}")
            }
            other => other.into(),
        })?;
    // On images too large for the upsampled first octave's scale space, SIFT goes on without
    // that octave (saying so); too large even without it, the error says what to do.
    let (ga, gb) = (GrayF32::from_rgb(&ia), GrayF32::from_rgb(&ib));
    let (w, h) = (ga.width as usize, ga.height as usize);
    let sift = Sift::new(sift_params(w, h)?);
    let fa = sift.detect(&ga, None)?;
    let fb = sift.detect(&gb, None)?;
    let (p, q) = matches_inside(&fa, &fb, &e);
    let inside = p.len();
    let (p, q) = reject(a.reject, p, q);
    // The paper's rule keeps the matches that move alike: a turn in the image plane about
    // the object's centre moves them in every direction, and where it left too few to solve
    // from (none, or three collinear survivors of the synthetic `roll`), the solver's error
    // says what keeps more.
    let kept = p.len();
    // The essential matrix's eight-point solve needs eight matches, the blocks three.
    let need = if solver.is_none() { 8 } else { 3 };
    let hint = |err: anyhow::Error| {
        if a.reject == Reject::Paper && inside >= need && (kept < need || 2 * kept < inside) {
            anyhow::anyhow!(
                "{err}: the paper's outlier rejection kept {kept} of the {inside} matches \
                 inside the ellipse (it rejects matches that move in different directions, as \
                 a turn in the image plane moves them): try `--reject ransac`"
            )
        } else {
            err
        }
    };
    // Matches along a line (a textured strip, an edge) determine no turn about it, however
    // exactly they lie there: refused as the solvers refuse points exactly in line, where
    // their spread across the line is not several times SIFT's error.
    if kept >= need
        && let Some(across) = pftrack::pose::spread_across(&p)
        && across < MIN_SPREAD_ACROSS_PX
    {
        return Err(hint(anyhow::anyhow!(
            "degenerate point configuration: the {kept} matches lie along a line ({across:.2} \
             px across it, RMS; {MIN_SPREAD_ACROSS_PX} px at least): the rotation is not \
             determined"
        )));
    }
    /// What the solver gave.
    enum Solved {
        /// The 2x2 block's solvers, completed to the Necker pair.
        Block(SolverKind, pftrack::pose::InterFrame),
        /// The essential matrix's rotation.
        Essential(pftrack::pose::essential::EssentialPose),
    }
    // Solved before anything is printed: a failure is the one line of its error, not a
    // result line followed by it.
    let w = ia.width() as f64;
    let intrinsics = pftrack::pose::Intrinsics {
        fx: w,
        fy: w,
        cx: (w - 1.0) / 2.0,
        cy: (ia.height() as f64 - 1.0) / 2.0,
    };
    let solved = match solver {
        Some(kind) => {
            let i = interframe(&p, &q, [e.cx, e.cy], kind).map_err(|err| hint(err.into()))?;
            Solved::Block(kind, i)
        }
        None => Solved::Essential(
            essential_rotation(&p, &q, &intrinsics).map_err(|err| hint(err.into()))?,
        ),
    };
    outln!(
        "matches inside the ellipse: {inside}, after outlier rejection: {}",
        p.len()
    )?;
    let show = |name: &str, r: &nalgebra::Matrix3<f64>| {
        let [x, y, z] = Euler::from_matrix(r).to_degrees();
        outln!("{name}: tilt {x:.2} pan {y:.2} roll {z:.2} (degrees)")
    };
    match solved {
        Solved::Block(kind, i) => print_block(&i, kind, &e, &p, &q, &ga, &gb)?,
        Solved::Essential(r) => show("essential (focal = image width assumed)", &r.rotation)?,
    }
    if let Some(file) = draw {
        draw_matches(file, &ib, &e, &p, &q)?;
    }
    Ok(())
}

/// SIFT's settings for images `w` x `h`: the defaults, or without the upsampled first octave
/// (said in a note) where its scale space would pass the budget; an error that says to scale
/// them down where even that would.
fn sift_params(w: usize, h: usize) -> anyhow::Result<SiftParams> {
    let mut params = SiftParams::default();
    if let Err(FeatureError::TooLarge { bytes: with, .. }) = params.check_window(w, h) {
        params.upsample = false;
        let without = params.scale_space_bytes(w, h);
        if let Err(FeatureError::TooLarge { limit, .. }) = params.check_window(w, h) {
            bail!(
                "SIFT on {w}x{h} images needs about {:.1} GB for its scale space even without \
                 the upsampled first octave, more than the {:.1} GB allowed: scale them down",
                without as f64 / 1e9,
                limit as f64 / 1e9
            );
        }
        errln!(
            "pftrack: note: SIFT's upsampled first octave on {w}x{h} images would need about \
             {:.1} GB; detecting without it (about {:.1} GB)",
            with as f64 / 1e9,
            without as f64 / 1e9
        );
    }
    Ok(params)
}

/// The matches (Lowe's ratio test and the mutual check) whose first point lies inside the
/// ellipse `e`: their positions in the first image and in the second.
fn matches_inside(
    fa: &pftrack::features::Features,
    fb: &pftrack::features::Features,
    e: &Ellipse,
) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let mut p = Vec::new();
    let mut q = Vec::new();
    for m in match_features(fa, fb, &MatchParams::default()) {
        let (ka, kb) = (&fa.keypoints[m.query], &fb.keypoints[m.train]);
        if e.contains(ka.x as f64, ka.y as f64) {
            p.push([ka.x as f64, ka.y as f64]);
            q.push([kb.x as f64, kb.y as f64]);
        }
    }
    (p, q)
}

/// The matches `rule` keeps: the paper's slope and length rule, an affine RANSAC (all of
/// them where it finds no consensus), or all.
fn reject(rule: Reject, p: Vec<[f64; 2]>, q: Vec<[f64; 2]>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    match rule {
        Reject::Paper => keep_slope_length(
            &p,
            &q,
            pftrack::features::PAPER_ANGLE_TOL,
            pftrack::features::PAPER_LENGTH_TOL,
        ),
        // Fewer than 3 matches, or points no map fits, are left to the solver's error.
        Reject::Ransac => {
            let r = Rls::default();
            match affine_consensus(&p, &q, r.threshold, r.confidence, r.max_iter, r.seed) {
                Ok(mask) => select(&p, &q, &mask),
                Err(_) => (p, q),
            }
        }
        Reject::None => (p, q),
    }
}

/// Prints a block solver's result: its residual, what SEA's iteration left, the scale the
/// matches show, and the rotation with its Necker mirror, the branch picked by the features'
/// parallax against the object's block-matched centre (`ga` to `gb`).
fn print_block(
    i: &pftrack::pose::InterFrame,
    kind: SolverKind,
    e: &Ellipse,
    p: &[[f64; 2]],
    q: &[[f64; 2]],
    ga: &GrayF32,
    gb: &GrayF32,
) -> anyhow::Result<()> {
    let show = |name: &str, r: &nalgebra::Matrix3<f64>| {
        let [x, y, z] = Euler::from_matrix(r).to_degrees();
        outln!("{name}: tilt {x:.2} pan {y:.2} roll {z:.2} (degrees)")
    };
    let fit = BlockFit::of(i, kind, Vector2::new(e.cx, e.cy), p, q);
    match fit.completed_residual {
        Some(r) => outln!(
            "residual {r:.3} px (of the rotation's block; {:.3} px of the unconstrained \
             block, which no rotation has)",
            i.block.residual
        )?,
        None => outln!("residual {:.3} px", i.block.residual)?,
    }
    if let Some(r) = fit.sea_unconverged {
        outln!(
            "SEA stopped short of convergence (Newton residual {r:.1e}): its block is \
             the best iterate, moved onto a rotation's; `--solver optimal` gives the \
             certified minimiser"
        )?;
    }
    if let Some(r) = fit.optimal_better {
        outln!(
            "SEA's block is a stationary point, not the least-squares minimum: \
             `--solver optimal` fits the same matches to {r:.3} px"
        )?;
    }
    if let Some(s) = fit.scale {
        // Within half a permille the line says no more than its three decimals.
        let effect = if s < 1.0 - 5e-4 {
            format!(
                ", so a shrink ({:.1} % here) reads as a turn",
                100.0 * (1.0 - s)
            )
        } else if s > 1.0 + 5e-4 {
            format!(
                ", so a growth ({:.1} % here) hides part of a turn",
                100.0 * (s - 1.0)
            )
        } else {
            ", as the matches show it".to_string()
        };
        outln!(
            "scale: x{s:.3} by the unconstrained fit (1 for a turn at a constant \
             distance); the solvers hold the size constant{effect}"
        )?;
    }
    // Weak perspective cannot tell a tilt and pan from their mirror (the Necker pair):
    // the branch is the one whose parallax the features show against the object's centre,
    // as the tracker's TPE mode picks it, with the centre's motion from block matching.
    match block_match(ga, gb, e, &AbmParams::for_target(e)) {
        Ok(m) if m.is_fitted() => {
            let offset = fit.motion - Vector2::new(m.translation[0], m.translation[1]);
            let chosen = resolve_by_parallax(&i.pair, offset);
            let mirror = if chosen == i.pair.a {
                i.pair.b
            } else {
                i.pair.a
            };
            show("rotation", &chosen)?;
            show("its Necker mirror", &mirror)?;
            let verdict = branch_verdict(&chosen, offset, fit.translation_noise);
            outln!(
                "branch: the features move {:.2},{:.2} px against the object's \
                 block-matched centre (parallax: the nearer surface leads a turn); {verdict}",
                offset[0],
                offset[1]
            )?;
        }
        _ => {
            show("rotation", &i.pair.a)?;
            show("its Necker mirror", &i.pair.b)?;
            outln!(
                "branch: undecided (block matching found no motion of the object to tell \
             it by); the two differ in the signs of tilt and pan"
            )?;
        }
    }
    Ok(())
}

/// Draws the matches as arrows from their first to their second position on the second
/// image `ib`, over the ellipse `e` given, into `file` (a PNG, committed when whole).
fn draw_matches(
    mut file: pftrack::io::AtomicFile,
    ib: &image::RgbImage,
    e: &Ellipse,
    p: &[[f64; 2]],
    q: &[[f64; 2]],
) -> anyhow::Result<()> {
    // Scaled up as `track --render` scales small frames (160x120 twice), so that arrows of
    // a pixel or two can be seen; the ellipse given is drawn in green beneath them.
    use pftrack::output::{
        capped_scale, default_scale,
        draw::{Rect, draw_ellipse, upscale_nearest, upscaled, upscaled_ellipse},
    };
    let k = capped_scale(ib.width(), ib.height(), default_scale(ib.width()));
    let mut img = upscale_nearest(ib, k);
    let clip = Rect {
        x0: 0,
        y0: 0,
        x1: i64::from(img.width()),
        y1: i64::from(img.height()),
    };
    let shown = upscaled_ellipse(e, k);
    draw_ellipse(
        &mut img,
        &shown,
        f64::from(k),
        Rgb([40, 220, 40]),
        None,
        clip,
    );
    let at = |v: [f64; 2]| [upscaled(v[0], k), upscaled(v[1], k)];
    for (p, q) in p.iter().zip(q) {
        arrow(&mut img, at(*p), at(*q), Rgb([255, 40, 40]), 3 * k as usize);
    }
    pftrack::output::encode_png(&mut file, &img)?;
    let path = file.path().to_path_buf();
    file.commit()?;
    outln!("matches drawn in {}", path.display())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_branch_is_decided_only_by_a_parallax_above_the_noise_and_the_floor() {
        // A pan: the surface moves along x.
        let pan = *nalgebra::Rotation3::from_euler_angles(0.0, 0.2, 0.0).matrix();
        let verdict = |dx: f64, noise: f64| branch_verdict(&pan, Vector2::new(dx, 0.0), noise);
        assert!(verdict(1.0, 0.2).contains("it points to this branch"));
        assert!(verdict(0.3, 0.2).contains("the branch is a guess"));
        // Identical images: no noise and a rounding error's parallax decide nothing.
        assert!(verdict(1e-14, 0.0).contains("the branch is a guess"));
        assert!(verdict(0.005, 0.0).contains("no parallax to speak of"));
        assert!(verdict(0.05, 0.0).contains("it points to this branch"));
        let roll = *nalgebra::Rotation3::from_euler_angles(0.0, 0.0, 0.3).matrix();
        assert!(branch_verdict(&roll, Vector2::new(1.0, 0.0), 0.0).contains("image plane"));
    }
}
