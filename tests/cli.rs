//! Tests of the `pftrack` command line: what each command writes, and how it refuses bad
//! input (one line on standard error, a non-zero exit, no panic, and no output that looks
//! complete when it is not).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use pftrack::geometry::Ellipse;
use pftrack::io::{PoseRecord, read_init, read_pose_csv};
use pftrack::synth::{Renderer, Scenario, SynthConfig};

/// A fresh temporary directory path `name` (not created).
fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pftrack-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn pftrack(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_pftrack"))
        .args(args)
        .output()
        .expect("run pftrack")
}

/// Runs `pftrack args` and checks it succeeded (naming the arguments and the error if not).
fn pftrack_ok(args: &[&str]) -> std::process::Output {
    let out = pftrack(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

#[test]
fn cli_writes_frames_truth_and_init() {
    let dir = tmp_dir("cli");
    let d = dir.to_str().unwrap();
    pftrack_ok(&[
        "synth",
        d,
        "--scenario",
        "nod",
        "--frames",
        "5",
        "--size",
        "80x60",
        "--seed",
        "3",
    ]);
    let frames: Vec<_> = std::fs::read_dir(dir.join("frames")).unwrap().collect();
    assert_eq!(frames.len(), 5);
    let img = image::open(dir.join("frames/00004.png")).unwrap();
    assert_eq!((img.width(), img.height()), (80, 60));
    let truth = read_pose_csv(&dir.join("truth.csv")).unwrap();
    assert_eq!(truth.len(), 5);
    assert_eq!(
        truth.iter().map(|r| r.frame).collect::<Vec<_>>(),
        [0, 1, 2, 3, 4]
    );
    let t0 = truth[0].state;
    assert_eq!((t0.rx, t0.ry, t0.rz), (0.0, 0.0, 0.0));
    assert!(truth[1].state.rx > 0.5, "nods: {:?}", truth[1].state);
    let file = read_init(&dir.join("init.txt")).unwrap();
    // the camera the frames were rendered with
    assert_eq!(file.hfov_deg, Some(pftrack::synth::HFOV_DEG));
    let init = file.ellipse;
    assert!((init.cx - t0.cx).abs() < 1e-5 && (init.a - t0.a).abs() < 1e-5);
    assert!((init.cy - t0.cy).abs() < 1e-5 && (init.b - t0.b).abs() < 1e-5);
    // the same as the library's render of that configuration
    let r = Renderer::new(&SynthConfig {
        scenario: Scenario::Nod,
        frames: 5,
        width: 80,
        height: 60,
        seed: 3,
    })
    .unwrap();
    assert_eq!(img.to_rgb8().as_raw(), r.render_image(4).as_raw());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `pose` says what its rotation rests on: the change of size the matches show, which the
/// solvers do not model (the synthetic `depth` moves the head away without turning it, and a
/// rotation of several degrees came out with nothing to say why); the residual of the
/// rotation's own block where LSM's was not one (it printed the unconstrained fit's, lower than
/// any rotation reaches); and whether the parallax decides the Necker branch (identical
/// frames were called "a guess" just as a clear turn was).
#[test]
fn pose_reports_the_scale_the_residual_of_its_rotation_and_the_branch_evidence() {
    let dir = tmp_dir("pose-scale");
    let d = dir.to_str().unwrap();
    pftrack_ok(&["synth", d, "--scenario", "depth", "--frames", "60"]);
    let truth = read_pose_csv(&dir.join("truth.csv")).unwrap();
    let frame = |i: usize| dir.join(format!("frames/{i:05}.png"));
    let (t, t1) = (truth[35].state, truth[36].state);
    assert!(t1.a < 0.99 * t.a, "the head moves away: {t:?} {t1:?}");
    let ellipse = format!("{},{},{},{}", t.cx, t.cy, t.a, t.b);
    let (f35, f36) = (frame(35), frame(36));
    let pose = |a: &Path, b: &Path, solver: &str, reject: &str| {
        let out = pftrack_ok(&[
            "pose",
            a.to_str().unwrap(),
            b.to_str().unwrap(),
            "--ellipse",
            &ellipse,
            "--solver",
            solver,
            "--reject",
            reject,
        ]);
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    let line = |text: &str, start: &str| {
        text.lines()
            .find(|l| l.starts_with(start))
            .unwrap_or_else(|| panic!("no {start}: {text}"))
            .to_string()
    };
    let text = pose(&f35, &f36, "sea", "paper");
    let scale = line(&text, "scale: x");
    let s: f64 = scale["scale: x".len()..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let truth_scale = (t1.a * t1.b / (t.a * t.b)).sqrt();
    // The features lie on the near surface, which perspective shrinks less than the outline
    // (0.983 against the outline's 0.973 here).
    assert!(
        s < 0.995 && (s - truth_scale).abs() < 0.02,
        "{s} vs {truth_scale}: {scale}"
    );
    assert!(
        scale.contains("a shrink (") && scale.contains(" % here) reads as a turn"),
        "{scale}"
    );
    assert!(!line(&text, "residual").contains("unconstrained"), "{text}");
    // LSM: the rotation's block fits worse than the unconstrained one it came from.
    let text = pose(&f35, &f36, "lsm", "paper");
    let res = line(&text, "residual ");
    let words: Vec<&str> = res.split_whitespace().collect();
    let (own, free): (f64, f64) = (words[1].parse().unwrap(), words[7].parse().unwrap());
    assert!(
        res.contains("of the rotation's block") && own > free,
        "{res}"
    );
    // Frame 35 shrunk to 90 % about its centre (its matches all kept: they move apart, which
    // the paper's rule rejects): SEA settles on a stationary point that is not the
    // least-squares minimum, and says what the certified minimiser reaches.
    let img = image::open(&f35).unwrap().to_rgb8();
    let small = image::imageops::resize(&img, 144, 108, image::imageops::FilterType::Triangle);
    let mut shrunk = img.clone();
    image::imageops::overlay(&mut shrunk, &small, 8, 6);
    let f90 = dir.join("shrunk.png");
    shrunk.save(&f90).unwrap();
    let residual = |text: &str| -> f64 {
        line(text, "residual ")
            .split_whitespace()
            .nth(1)
            .unwrap()
            .parse()
            .unwrap()
    };
    let (sea, optimal) = (
        pose(&f35, &f90, "sea", "none"),
        pose(&f35, &f90, "optimal", "none"),
    );
    let note = line(&sea, "SEA's block is a stationary point");
    let claimed: f64 = note
        .split_whitespace()
        .rev()
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(claimed, residual(&optimal), "{note}\n{optimal}");
    assert!(residual(&sea) > claimed, "{sea}");
    assert!(!optimal.contains("stationary point"), "{optimal}");
    // The same frame twice: no turn out of the image plane, nothing for parallax to decide.
    let text = pose(&f35, &f35, "sea", "paper");
    assert!(
        line(&text, "scale: x1.000").contains("as the matches show it"),
        "{text}"
    );
    assert!(
        line(&text, "branch:").contains("in the image plane"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `pose` prints first the rotation of the Necker pair that the images show: over pairs six
/// frames apart through a nod and a pan, the sign of the tilt (nod) and the pan (pan) agrees
/// with the truth's wherever both turn by more than 2 degrees. It printed the branch whose
/// larger out-of-plane component was positive: the truth's sign on 7 of these 11 nod pairs
/// and 5 of 9 pan pairs.
#[test]
fn pose_prints_the_necker_branch_the_parallax_shows() {
    use pftrack::geometry::Euler;
    for (scenario, axis) in [("nod", 0usize), ("pan", 1)] {
        let dir = tmp_dir(&format!("necker-{scenario}"));
        let d = dir.to_str().unwrap();
        pftrack_ok(&["synth", d, "--scenario", scenario]);
        let truth = read_pose_csv(&dir.join("truth.csv")).unwrap();
        let (mut agree, mut disagree) = (0, 0);
        for k in (0..=160).step_by(10) {
            let (ta, tb) = (truth[k].state, truth[k + 6].state);
            let rel = Euler::new(tb.rx, tb.ry, tb.rz).matrix()
                * Euler::new(ta.rx, ta.ry, ta.rz).matrix().transpose();
            let want = Euler::from_matrix(&rel).to_degrees()[axis];
            let frame = |i: usize| dir.join(format!("frames/{i:05}.png"));
            let (fa, fb) = (frame(k), frame(k + 6));
            let ellipse = format!("{},{},{},{}", ta.cx, ta.cy, ta.a, ta.b);
            let out = pftrack_ok(&[
                "pose",
                fa.to_str().unwrap(),
                fb.to_str().unwrap(),
                "--ellipse",
                &ellipse,
            ]);
            let text = String::from_utf8_lossy(&out.stdout).to_string();
            let line = text
                .lines()
                .find(|l| l.starts_with("rotation: "))
                .unwrap_or_else(|| panic!("{scenario} {k}: {text}"));
            let words: Vec<&str> = line.split_whitespace().collect();
            // "rotation: tilt X pan Y roll Z (degrees)"
            let got: f64 = words[2 + 2 * axis].parse().unwrap();
            if want.abs() > 2.0 && got.abs() > 2.0 {
                if (want > 0.0) == (got > 0.0) {
                    agree += 1;
                } else {
                    disagree += 1;
                    eprintln!(
                        "{scenario} {k}->{}: truth {want:.2}, printed {got:.2}",
                        k + 6
                    );
                }
            }
            assert!(text.contains("branch: "), "{text}");
        }
        assert_eq!(disagree, 0, "{scenario}: {agree} agree");
        assert!(
            agree >= 6,
            "{scenario}: only {agree} pairs turned enough to compare"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// A turn in the image plane moves the matches in every direction, and the paper's outlier
/// rejection keeps too few to solve from: `pose` says so in one line and names
/// `--reject ransac`, which keeps them and reads the roll.
#[test]
fn pose_reads_a_roll_with_ransac_where_the_paper_rule_rejects_it() {
    use pftrack::geometry::Euler;
    let dir = tmp_dir("pose-roll");
    let d = dir.to_str().unwrap();
    pftrack_ok(&["synth", d, "--scenario", "roll", "--frames", "40"]);
    let truth = read_pose_csv(&dir.join("truth.csv")).unwrap();
    for (k, gap) in [(0usize, 8usize), (20, 8), (30, 6)] {
        let (ta, tb) = (truth[k].state, truth[k + gap].state);
        let rel = Euler::new(tb.rx, tb.ry, tb.rz).matrix()
            * Euler::new(ta.rx, ta.ry, ta.rz).matrix().transpose();
        let want = Euler::from_matrix(&rel).to_degrees()[2];
        assert!(want.abs() > 4.0, "{k}: the truth rolls {want}");
        let frame = |i: usize| dir.join(format!("frames/{i:05}.png"));
        let (fa, fb) = (frame(k), frame(k + gap));
        let ellipse = format!(
            "{},{},{},{},{}",
            ta.cx,
            ta.cy,
            ta.a,
            ta.b,
            ta.rz.to_degrees()
        );
        let args = |reject: &'static str| {
            vec![
                "pose".to_string(),
                fa.to_str().unwrap().to_string(),
                fb.to_str().unwrap().to_string(),
                "--ellipse".to_string(),
                ellipse.clone(),
                "--reject".to_string(),
                reject.to_string(),
            ]
        };
        let paper = args("paper");
        let paper: Vec<&str> = paper.iter().map(String::as_str).collect();
        assert_one_line_error(&paper, "try `--reject ransac`", &dir.join("none"));
        let ransac = args("ransac");
        let ransac: Vec<&str> = ransac.iter().map(String::as_str).collect();
        let text = String::from_utf8_lossy(&pftrack_ok(&ransac).stdout).to_string();
        let line = text
            .lines()
            .find(|l| l.starts_with("rotation: "))
            .unwrap_or_else(|| panic!("{k}: {text}"));
        let got: f64 = line.split_whitespace().nth(6).unwrap().parse().unwrap();
        assert!((got - want).abs() < 1.5, "{k}: roll {got}, truth {want}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A fresh temporary directory `name` holding a synthetic sequence of the default scenario
/// (`pftrack synth`), `frames` long at `size`.
fn synth_dir(name: &str, frames: usize, size: &str) -> PathBuf {
    let dir = tmp_dir(name);
    let frames = frames.to_string();
    pftrack_ok(&[
        "synth",
        dir.to_str().unwrap(),
        "--frames",
        &frames,
        "--size",
        size,
    ]);
    dir
}

/// The staging folders `synth` renders frames into inside `frames` (`.pftrack-synth-*`).
fn synth_staging(frames: &Path) -> impl Iterator<Item = PathBuf> {
    std::fs::read_dir(frames)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .starts_with(".pftrack-synth-")
        })
        .map(|e| e.path())
}

/// Runs `pftrack args` and checks it fails with one line naming `needle`, without a panic,
/// leaving no `unwritten` file (the output a complete run would have written).
fn assert_one_line_error(args: &[&str], needle: &str, unwritten: &Path) {
    let out = pftrack(args);
    assert!(!out.status.success(), "{args:?} succeeded");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    assert!(err.contains(needle), "{args:?}: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!unwritten.exists(), "{args:?} left {}", unwritten.display());
    // Nothing printed as a result before the error.
    let printed = String::from_utf8_lossy(&out.stdout);
    assert!(printed.is_empty(), "{args:?} printed {printed}");
}

#[test]
fn cli_bad_input_is_a_one_line_error() {
    let dir = tmp_dir("bad");
    let d = dir.to_str().unwrap();
    let truth = dir.join("truth.csv");
    assert_one_line_error(
        &["synth", d, "--scenario", "spin"],
        "unknown scenario 'spin'",
        &truth,
    );
    assert_one_line_error(
        &["synth", d, "--scenario", "spin"],
        "nod, pan, roll, combo, depth, car, long",
        &truth,
    );
    assert_one_line_error(&["synth", d, "--frames", "0"], "from 1 to 100000", &truth);
    assert_one_line_error(
        &["synth", d, "--frames", "1000000000"],
        "from 1 to 100000",
        &truth,
    );
    for size in ["10x", "0x120", "abc", "160x120x3", "100000x100"] {
        assert_one_line_error(&["synth", d, "--size", size], "size", &truth);
    }
    // a directory that cannot be created: its parent is a file
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("plain-file");
    std::fs::write(&file, "x").unwrap();
    let under = file.join("seq");
    assert_one_line_error(
        &["synth", under.to_str().unwrap(), "--frames", "2"],
        "plain-file",
        &under.join("truth.csv"),
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The lost-state and re-acquisition settings of `track` are checked before anything is
/// tracked: one line naming the setting, a non-zero exit and no pose CSV.
#[test]
fn cli_track_rejects_bad_lost_and_reacquisition_settings() {
    let dir = synth_dir("track-bad", 2, "64x48");
    let d = dir.to_str().unwrap();
    let csv = dir.join("poses.csv");
    let c = csv.to_str().unwrap();
    for (flag, value, needle) in [
        ("--found-above", "0.1", "found_above"),
        ("--found-above", "2", "found_above"),
        ("--trust-above", "1.5", "trust_above"),
        ("--trust-above", "NaN", "trust_above"),
        ("--reacquire-ncc", "1.5", "reacquire_ncc"),
        ("--reacquire-ncc", "NaN", "reacquire_ncc"),
        ("--reanchor-ncc", "1.5", "reanchor min_ncc"),
        ("--reanchor-ncc", "NaN", "reanchor min_ncc"),
    ] {
        let args = ["track", d, "--backend", "cpu", flag, value, "--out", c];
        assert_one_line_error(&args, needle, &csv);
    }
    // The bound a flag is held to is said, not only another setting's name.
    let args = ["track", d, "--found-above", "0.1", "--out", c];
    assert_one_line_error(&args, "between lost_below (0.25", &csv);
    // A settings file's errors are in its own terms: JSON's null, not Rust's None.
    let json = dir.join("settings.json");
    std::fs::write(&json, r#"{"camera_hfov_deg": 500}"#).unwrap();
    let args = ["track", d, "--config", json.to_str().unwrap(), "--out", c];
    assert_one_line_error(&args, "set it to null for weak perspective", &csv);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--sift-upsample-below` reaches the tracker: a size below the target's changes the
/// track, `--sift-always-upsample` leaves a small target's as it is, and a size that is not
/// positive is one clear error.
#[test]
fn cli_track_sift_upsample_size() {
    let dir = synth_dir("track-sift-size", 6, "96x72");
    let d = dir.to_str().unwrap();
    let csv = dir.join("poses.csv");
    let c = csv.to_str().unwrap();
    let mut tracks = Vec::new();
    for extra in [
        &[][..],
        &["--sift-always-upsample"][..],
        &["--sift-upsample-below", "10"][..],
    ] {
        let mut args = vec!["track", d, "--backend", "cpu", "--out", c];
        args.extend_from_slice(extra);
        pftrack_ok(&args);
        tracks.push(std::fs::read(&csv).unwrap());
    }
    assert_eq!(
        tracks[0], tracks[1],
        "a small target keeps the doubled octave"
    );
    assert_ne!(tracks[0], tracks[2], "the doubled octave dropped");
    std::fs::remove_file(&csv).unwrap();
    for value in ["0", "-3", "NaN"] {
        let args = [
            "track",
            d,
            "--backend",
            "cpu",
            "--sift-upsample-below",
            value,
        ];
        assert_one_line_error(
            &[&args[..], &["--out", c]].concat(),
            "sift_upsample_below",
            &csv,
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--refine-init` moves a start drawn a few pixels off the head back onto it, and row 0 of
/// the poses gives the ellipse the track started from.
#[test]
fn cli_track_refine_init() {
    let dir = synth_dir("track-refine", 3, "160x120");
    let d = dir.to_str().unwrap();
    let e = read_init(&dir.join("init.txt")).unwrap().ellipse;
    let high = format!("{},{},{},{}", e.cx, e.cy - 3.0, e.a, e.b);
    let csv = dir.join("poses.csv");
    let c = csv.to_str().unwrap();
    let row0_cy = |extra: &[&str]| -> f64 {
        let mut args = vec!["track", d, "--backend", "cpu", "--init-ellipse", &high];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", c]);
        pftrack_ok(&args);
        read_pose_csv(&csv).unwrap()[0].state.cy
    };
    assert!((row0_cy(&[]) - (e.cy - 3.0)).abs() < 1e-6);
    let refined = row0_cy(&["--refine-init"]);
    assert!((refined - e.cy).abs() < 0.5, "{refined} against {}", e.cy);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A start given by hand that takes in much around the target is said to (once, before the
/// track, naming `--refine-init`); one close to the outline, one from a file and one refined
/// already are not.
#[test]
fn cli_track_says_when_a_start_by_hand_is_loose() {
    let dir = synth_dir("track-loose", 2, "160x120");
    let d = dir.to_str().unwrap();
    let e = read_init(&dir.join("init.txt")).unwrap().ellipse;
    let csv = dir.join("poses.csv");
    let c = csv.to_str().unwrap();
    let stderr = |extra: &[&str]| -> String {
        let mut args = vec!["track", d, "--backend", "cpu", "--out", c];
        args.extend_from_slice(extra);
        String::from_utf8_lossy(&pftrack_ok(&args).stderr).into_owned()
    };
    let note = "pftrack: note: the start takes in much around the target";
    // 1.35 times the head's size: refined, the box and the given one's overlap by about 0.55.
    let loose = format!("{},{},{},{}", e.cx, e.cy, 1.35 * e.a, 1.35 * e.b);
    let said = stderr(&["--init-ellipse", &loose]);
    assert_eq!(said.matches(note).count(), 1, "{said}");
    assert!(said.contains("--refine-init tracks from there"), "{said}");
    let as_box = format!(
        "{},{},{},{}",
        e.cx - 1.35 * e.a,
        e.cy - 1.35 * e.b,
        2.7 * e.a,
        2.7 * e.b
    );
    assert!(stderr(&["--init-box", &as_box]).contains(note));
    // One too small is off the outline, not around the target.
    let small = format!("{},{},{},{}", e.cx, e.cy, 0.75 * e.a, 0.75 * e.b);
    let off = stderr(&["--init-ellipse", &small]);
    assert!(
        off.contains("pftrack: note: the start lies off the target's outline"),
        "{off}"
    );
    // Under a settings file, which refuses --refine-init, the note names its setting.
    let settings = dir.join("settings.json");
    std::fs::write(&settings, "{}").unwrap();
    let s = settings.to_str().unwrap();
    let filed = stderr(&["--init-ellipse", &loose, "--config", s]);
    assert!(filed.contains(note), "{filed}");
    assert!(
        filed.contains(&format!("\"init_refine\": {{}} in {s} tracks from there")),
        "{filed}"
    );
    std::fs::write(&settings, r#"{"init_refine": {}}"#).unwrap();
    for quiet in [
        stderr(&["--init-ellipse", &loose, "--config", s]),
        stderr(&[
            "--init-ellipse",
            &format!("{},{},{},{}", e.cx, e.cy, e.a, e.b),
        ]),
        stderr(&["--init-ellipse", &loose, "--refine-init"]),
        stderr(&[]),
    ] {
        assert!(!quiet.contains(note), "{quiet}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `track` takes the camera from the init file `synth` writes, `--hfov` overrides it and
/// `--weak-perspective` sets it aside; a bad camera line is one clear error and no poses.
#[test]
fn cli_track_takes_the_camera_from_the_init_file() {
    let dir = synth_dir("track-camera", 4, "64x48");
    let d = dir.to_str().unwrap();
    let init = std::fs::read_to_string(dir.join("init.txt")).unwrap();
    assert!(init.lines().any(|l| l == "hfov,50.000000"), "{init}");
    let csv = dir.join("poses.csv");
    let c = csv.to_str().unwrap();
    let mut tracks = Vec::new();
    for (extra, said) in [
        (&[][..], "camera hfov 50°"),
        (&["--hfov", "60"][..], "camera hfov 60°"),
        (&["--weak-perspective"][..], "weak perspective"),
        // The camera belongs to the footage, however the target is initialised.
        (&["--init-box", "20,14,24,20"][..], "camera hfov 50°"),
        (
            &["--init-box", "20,14,24,20", "--weak-perspective"][..],
            "weak perspective",
        ),
    ] {
        let mut args = vec!["track", d, "--backend", "cpu", "--out", c];
        args.extend_from_slice(extra);
        let out = pftrack_ok(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(said), "{args:?}: {err}");
        tracks.push(std::fs::read(&csv).unwrap());
    }
    // A flat model (no depth) through the camera: every lifted feature lies on the disc's
    // plane, and the track is as complete as any other (at 64x48 too few features reach the
    // lift; 96x72 failed at frame 3 when the flat model's lift divided by its zero depth).
    let flat_dir = synth_dir("track-camera-flat", 4, "96x72");
    let fd = flat_dir.to_str().unwrap();
    pftrack_ok(&[
        "track",
        fd,
        "--backend",
        "cpu",
        "--depth-ratio",
        "0",
        "--out",
        c,
    ]);
    let flat = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(flat.lines().count(), 5, "{flat}");
    assert!(!flat.contains("NaN") && !flat.contains("inf"), "{flat}");
    std::fs::remove_dir_all(&flat_dir).unwrap();
    // The camera reaches the tracker: the first three tracks differ, and so do the two
    // started from a box.
    assert!(tracks[0] != tracks[1] && tracks[0] != tracks[2] && tracks[1] != tracks[2]);
    assert!(tracks[3] != tracks[4]);
    let out = pftrack(&["track", d, "--hfov", "60", "--weak-perspective", "--out", c]);
    assert!(!out.status.success());

    // A camera line that is not one.
    std::fs::remove_file(&csv).unwrap();
    let ellipse_line = init.lines().next().unwrap();
    std::fs::write(dir.join("init.txt"), format!("{ellipse_line}\nhfov,200\n")).unwrap();
    assert_one_line_error(&["track", d, "--backend", "cpu", "--out", c], "hfov", &csv);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Negative numbers are values (a box reaching past the left edge, a negative SNR, a depth
/// ratio the tracker then rejects itself), and a usage error is one line like any other.
#[test]
fn cli_takes_negative_values_and_reports_usage_errors_on_one_line() {
    let dir = synth_dir("negative", 2, "64x48");
    let d = dir.to_str().unwrap();
    let csv = dir.join("poses.csv");
    let c = csv.to_str().unwrap();
    for args in [
        &["--init-box", "-4,10,40,30"][..],
        &["--init-pose", "-10,5,-3"][..],
        &["--init-points", "-2,20;20,5;42,20;20,35;5,30"][..],
    ] {
        let mut all = vec!["track", d, "--backend", "cpu", "--out", c];
        all.extend_from_slice(args);
        pftrack_ok(&all);
        std::fs::remove_file(&csv).unwrap();
    }
    let snr = dir.join("snr.csv");
    pftrack_ok(&[
        "pose-noise",
        "--snr",
        "-5,0",
        "--lambda-snr",
        "0",
        "--trials",
        "4",
        "--csv",
        snr.to_str().unwrap(),
    ]);
    let table = std::fs::read_to_string(&snr).unwrap();
    assert!(table.lines().nth(1).unwrap().starts_with("-5"), "{table}");

    let track = |extra: &[&'static str]| {
        let mut v = vec!["track", d, "--backend", "cpu", "--out", c];
        v.extend_from_slice(extra);
        v
    };
    assert_one_line_error(
        &track(&["--depth-ratio", "-1"]),
        "--depth-ratio must lie",
        &csv,
    );
    assert_one_line_error(&track(&["--max-frames", "0"]), "--max-frames", &csv);
    assert_one_line_error(&track(&["--bogus"]), "unexpected argument '--bogus'", &csv);
    assert_one_line_error(
        &track(&["--particles", "many"]),
        "invalid value 'many'",
        &csv,
    );
    assert_one_line_error(&["track", "--out", c], "<INPUT>", &csv);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Exit status 2 for a command line that is malformed or lacks what the command needs, 1 for
/// values out of range and failures at run time (README). A missing start and a malformed
/// `synth --size` used to exit 1.
#[test]
fn cli_usage_errors_exit_2_and_others_1() {
    let dir = tmp_dir("status");
    std::fs::create_dir_all(&dir).unwrap();
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    image::RgbImage::from_pixel(32, 24, image::Rgb([90, 60, 30]))
        .save(frames.join("0.png"))
        .unwrap();
    let f = frames.to_str().unwrap();
    let seq = dir.join("seq");
    let s = seq.to_str().unwrap();
    let otb = dir.join("otb.txt");
    std::fs::write(&otb, "0,0,0,0\n1,1,5,5\n").unwrap();
    let o = otb.to_str().unwrap();
    let cases: [(&[&str], i32, &str); 16] = [
        (&["track", f, "--backend", "cpu"], 2, "no initial ellipse"),
        (&["synth", s, "--size", "80x"], 2, "WIDTHxHEIGHT"),
        // A negative size got clap's "unexpected argument '-8'".
        (&["synth", s, "--size", "-80x60"], 2, "bad size '-80x60'"),
        (&["track", f, "--resize", "-3x4"], 2, "bad size '-3x4'"),
        // As `sift --repeat 0` (it exited 1).
        (&["bench", "--repeats", "0"], 2, "0 is not in 1.."),
        (&["synth", s, "--size", "16x16"], 2, "24..=8192"),
        (&["track", f, "--resize", "32768x32768"], 2, "pixels in all"),
        (&["pose-noise", "--trials", "0"], 1, "--trials"),
        (
            &["pose-noise", "--trials", "18446744073709551615"],
            1,
            "1000000",
        ),
        (
            &["track", f, "--init-ellipse", "16,12,60,8"],
            1,
            "--init-ellipse: invalid start",
        ),
        // The start's error names the option that gave the value refused.
        (
            &[
                "track",
                f,
                "--init-box",
                "8,6,80,8",
                "--init-pose",
                "10,0,0",
            ],
            1,
            "--init-box: invalid start",
        ),
        (
            &[
                "track",
                f,
                "--init-box",
                "8,6,10,8",
                "--init-pose",
                "400,0,0",
            ],
            1,
            "--init-pose: invalid start: initial pose 400",
        ),
        // 1e-300 degrees was taken (and printed in 300 digits).
        (
            &[
                "track",
                f,
                "--init-ellipse",
                "16,12,6,8",
                "--hfov",
                "1e-300",
            ],
            1,
            "--hfov must lie between 0.1 and 179.9 degrees, got 1e-300",
        ),
        (
            &[
                "track",
                f,
                "--init-ellipse",
                "16,12,6,8",
                "--contrast-weight",
                "1e300",
            ],
            1,
            "contrast weight 1e300 is not in [0, 1e6]",
        ),
        // Both were reported as the ellipse derived from them (`cx -2.5, ... a -2.5`).
        (
            &["track", f, "--init-box", "0,0,-5,5"],
            1,
            "--init-box 0,0,-5,5: the width and height must be positive",
        ),
        (
            &["track", f, "--init-truth", o],
            1,
            "the box of frame 0 has no size",
        ),
    ];
    for (args, code, needle) in cases {
        let out = pftrack(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
    assert!(!seq.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `-` is standard output for `sift --out` as for `track -o` (it wrote a file named `-`);
/// `pose-noise --csv` writes two files, so a stream or device is refused (`--csv /dev/null`
/// made `/dev/null_lambda`); an image with no pixels is an error, not "0 keypoints".
#[test]
fn cli_dash_is_standard_output_and_streams_are_refused_where_two_files_go() {
    let dir = synth_dir("dash-sift", 1, "64x48");
    let f0 = dir.join("frames/00000.png");
    let f0 = f0.to_str().unwrap();
    let kps = dir.join("kps.csv");
    pftrack_ok(&["sift", f0, "--out", kps.to_str().unwrap()]);
    let out = pftrack(&["sift", f0, "--out", "-"]);
    assert!(out.status.success());
    assert_eq!(out.stdout, std::fs::read(&kps).unwrap());
    assert!(!Path::new("-").exists());

    for csv in ["-", "/dev/null", "/dev/stdout"] {
        let out = pftrack(&["pose-noise", "--trials", "2", "--snr", "10", "--csv", csv]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{csv}: {err}");
        assert!(err.contains("two files"), "{err}");
    }
    assert!(!Path::new("/dev/null_lambda").exists());
    assert!(!Path::new("/dev/stdout_lambda").exists());

    let empty = dir.join("empty.pgm");
    std::fs::write(&empty, b"P5\n0 0\n255\n").unwrap();
    assert_one_line_error(
        &["sift", empty.to_str().unwrap()],
        "empty image",
        &kps.with_extension("x"),
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `sift` and `pose` check their input before any work: a region off the image, an image that
/// is not one (its cause said once) and an unknown solver are each one line and no output.
#[test]
fn cli_sift_and_pose_reject_bad_input_in_one_line() {
    let dir = synth_dir("sift-pose", 2, "96x72");
    let f0 = dir.join("frames/00000.png");
    let f1 = dir.join("frames/00001.png");
    let (f0, f1) = (f0.to_str().unwrap(), f1.to_str().unwrap());
    let kps = dir.join("kps.csv");
    let k = kps.to_str().unwrap();
    for region in ["-20,-20,10,10", "96,0,10,10", "0,72,5,5"] {
        assert_one_line_error(
            &["sift", f0, "--region", region, "--out", k],
            "lies outside the 96x72 image",
            &kps,
        );
    }
    // A region reaching past the top-left corner is still inside.
    pftrack_ok(&["sift", f0, "--region", "-10,-10,60,50", "--out", k]);
    std::fs::remove_file(&kps).unwrap();

    let junk = dir.join("junk.png");
    std::fs::write(&junk, "not a png").unwrap();
    assert_one_line_error(
        &["sift", junk.to_str().unwrap(), "--out", k],
        "junk.png",
        &kps,
    );
    let err =
        String::from_utf8_lossy(&pftrack(&["sift", junk.to_str().unwrap()]).stderr).to_string();
    assert_eq!(err.matches("signature").count(), 1, "{err}");

    let drawn = dir.join("drawn.png");
    let args = [
        "pose",
        f0,
        f1,
        "--ellipse",
        "48,36,14,18",
        "--solver",
        "foo",
        "--draw",
        drawn.to_str().unwrap(),
    ];
    assert_one_line_error(&args, "sea, optimal, lsm, rls or essential", &drawn);
    // A solver in any case, as the parser takes it: `ESSENTIAL` passed it, then was refused
    // as unknown.
    let solve =
        |name: &str| pftrack(&["pose", f0, f1, "--ellipse", "48,36,14,18", "--solver", name]);
    let (upper, lower) = (solve("ESSENTIAL"), solve("essential"));
    let err = String::from_utf8_lossy(&upper.stderr);
    assert!(!err.contains("unknown solver"), "{err}");
    assert_eq!(
        (upper.status.code(), &upper.stdout),
        (lower.status.code(), &lower.stdout)
    );
    // A drawing that cannot be written is refused before the rotation is computed.
    let folder = dir.join("folder.png");
    std::fs::create_dir(&folder).unwrap();
    let jpg = dir.join("drawn.jpg");
    for (draw, needle) in [
        (&folder, "is a directory"),
        (&jpg, "the image is a PNG; give a .png name"),
    ] {
        let args = [
            "pose",
            f0,
            f1,
            "--ellipse",
            "48,36,14,18",
            "--draw",
            draw.to_str().unwrap(),
        ];
        assert_one_line_error(&args, needle, &jpg);
        assert!(pftrack(&args).stdout.is_empty(), "{draw:?}");
    }
    // The ellipse is held to a tracker start's rules (axes of 1e308 px were taken).
    for (ellipse, needle) in [
        ("48,36,1e308,1e308", "--ellipse: semi-axes 1.000e308"),
        ("48,36,14,18,1e308", "at most 360 either way"),
        (
            "148,36,14,18",
            "centre (148, 36) lies outside the 96x72 frame",
        ),
        ("48,36,1,18", "at least 2 px"),
    ] {
        assert_one_line_error(&["pose", f0, f1, "--ellipse", ellipse], needle, &jpg);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A track that fails part-way (a frame of another size) leaves neither a pose CSV nor the
/// frames it had drawn: nothing that reads as a whole track, and what the render folder held
/// before stays as it was. A folder holding frames no render of pftrack's left is refused
/// before tracking.
#[test]
fn cli_a_failed_track_leaves_no_render() {
    let dir = synth_dir("failed-render", 5, "64x48");
    let d = dir.to_str().unwrap();
    let render = dir.join("render");
    let csv = dir.join("poses.csv");
    let args = [
        "track",
        d,
        "--backend",
        "cpu",
        "--render",
        render.to_str().unwrap(),
        "--out",
        csv.to_str().unwrap(),
    ];
    // Whole, it draws every frame, and nothing else stays in the folder.
    pftrack_ok(&args);
    assert_eq!(
        names(&render),
        [
            ".pftrack-render",
            "00000.png",
            "00001.png",
            "00002.png",
            "00003.png",
            "00004.png"
        ]
    );
    std::fs::remove_dir_all(&render).unwrap();
    std::fs::remove_file(&csv).unwrap();
    std::fs::create_dir(&render).unwrap();
    // Frames of the user's own: refused before anything is tracked or drawn.
    std::fs::write(render.join("00000.png"), b"the user's").unwrap();
    assert_one_line_error(&args, "holds 00000.png but no .pftrack-render", &csv);
    assert_eq!(names(&render), ["00000.png"]);
    // A failed run changes nothing: neither an earlier render's folder (its frame 0 edited
    // since) nor names a render cannot reach (a date is no frame number of five digits).
    std::fs::write(render.join(".pftrack-render"), b"").unwrap();
    std::fs::write(render.join("20240101.png"), b"the user's").unwrap();
    image::RgbImage::new(32, 24)
        .save(dir.join("frames/00003.png"))
        .unwrap();
    assert_one_line_error(&args, "frame 3", &csv);
    assert_eq!(
        names(&render),
        [".pftrack-render", "00000.png", "20240101.png"]
    );
    assert_eq!(
        std::fs::read(render.join("00000.png")).unwrap(),
        b"the user's"
    );
    std::fs::remove_file(render.join(".pftrack-render")).unwrap();
    std::fs::remove_file(render.join("00000.png")).unwrap();
    assert_one_line_error(&args, "frame 3", &csv);
    assert_eq!(names(&render), ["20240101.png"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Checks a track against its synthetic truth, in the input's pixels: a row for every frame,
/// row 0 the start as given, and the centre within `(mean, largest)` pixels of the truth's.
fn assert_started_and_followed(
    rows: &[PoseRecord],
    init: &Ellipse,
    truth: &[PoseRecord],
    (mean_px, max_px): (f64, f64),
    what: &str,
) {
    assert_eq!(rows.len(), truth.len(), "{what}");
    let s = rows[0].state;
    for (x, y) in [
        (s.cx, init.cx),
        (s.cy, init.cy),
        (s.a, init.a),
        (s.b, init.b),
    ] {
        assert!((x - y).abs() < 1e-5, "{what}: row 0 {x} vs start {y}");
    }
    let errors: Vec<f64> = rows
        .iter()
        .zip(truth)
        .map(|(r, t)| (r.state.cx - t.state.cx).hypot(r.state.cy - t.state.cy))
        .collect();
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let max = errors.iter().fold(0.0f64, |m, &e| m.max(e));
    assert!(
        mean < mean_px && max < max_px,
        "{what}: centre error mean {mean}, max {max} px"
    );
}

/// `--resize` tracks on the resized frames but takes the start and writes the poses in the
/// input's own pixels: row 0 is the start as given, and the track stays on the truth, which
/// `synth` wrote in the input's pixels.
#[test]
fn cli_resize_keeps_the_start_and_poses_in_the_input_pixels() {
    let dir = synth_dir("resize", 60, "160x120");
    let d = dir.to_str().unwrap();
    let truth = read_pose_csv(&dir.join("truth.csv")).unwrap();
    let init = read_init(&dir.join("init.txt")).unwrap().ellipse;
    for size in ["80x60", "240x180", "120x120"] {
        let csv = dir.join(format!("poses-{size}.csv"));
        let render = dir.join(format!("render-{size}"));
        pftrack_ok(&[
            "track",
            d,
            "--backend",
            "cpu",
            "--resize",
            size,
            "-o",
            csv.to_str().unwrap(),
            "--render",
            render.to_str().unwrap(),
        ]);
        let rows = read_pose_csv(&csv).unwrap();
        // Measured 2026-12-05: mean 0.8-1.4 px, largest 2.1-4.4 px, over the four sizes.
        assert_started_and_followed(&rows, &init, &truth, (2.0, 6.0), size);
        // Drawn from the resized frames.
        let (w, _) = pftrack::frames::parse_size(size).unwrap();
        let img = image::open(render.join("00000.png")).unwrap();
        let scale = pftrack::output::default_scale(w);
        assert!(img.width() >= w * scale && img.width() < 160 * 4, "{size}");
    }
    // A turned start through a resize that changes the aspect: row 0 is the start as given.
    let csv = dir.join("turned.csv");
    pftrack_ok(&[
        "track",
        d,
        "--backend",
        "cpu",
        "--resize",
        "120x120",
        "--max-frames",
        "2",
        "--init-ellipse",
        "79.5,59.5,18,24,30",
        "-o",
        csv.to_str().unwrap(),
    ]);
    let r0 = read_pose_csv(&csv).unwrap()[0].clone();
    let e = r0.ellipse();
    for (x, y) in [(e.cx, 79.5), (e.cy, 59.5), (e.a, 18.0), (e.b, 24.0)] {
        assert!((x - y).abs() < 1e-5, "turned start: {x} vs {y}");
    }
    assert!(
        (e.theta.to_degrees() - 30.0).abs() < 1e-5,
        "{}",
        e.theta.to_degrees()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Frames longer than 800 px are tracked shrunk toward 640 px (`frames::working_size`) when
/// no `--resize` is given: the line says at which size, the start and the poses stay in the
/// input's pixels, and the track stays on the truth; `--full-size` tracks them as they are,
/// and cannot be given with `--resize`.
#[test]
fn cli_large_frames_are_tracked_at_a_working_size() {
    // The whole scenario in 60 frames: four times the default's motion a frame.
    let dir = synth_dir("working", 60, "1280x960");
    let d = dir.to_str().unwrap();
    let truth = read_pose_csv(&dir.join("truth.csv")).unwrap();
    let init = read_init(&dir.join("init.txt")).unwrap().ellipse;
    let csv = dir.join("poses.csv");
    let render = dir.join("render");
    let (_, err) = track_on_cpu(d, &csv, &["--render", render.to_str().unwrap()]);
    assert!(
        err.contains("tracked 60 frames at 640x480 (shrunk from 1280x960) with cpu")
            && err.contains(
                "note: tracking at 640x480, shrunk from 1280x960 (as accurate, and faster; \
                 --full-size tracks at 1280x960)"
            ),
        "{err}"
    );
    let rows = read_pose_csv(&csv).unwrap();
    // In the input's pixels. Measured 2026-12-07: mean 8.2 px, largest 36 px (the head's
    // semi-axes are 148x198 px); tracked at 1280x960 (--full-size) 23 and 73 px, its
    // motion a frame, in pixels, twice as far for the same search.
    assert_started_and_followed(&rows, &init, &truth, (15.0, 50.0), "working size");
    // Drawn from the frames tracked.
    let img = image::open(render.join("00000.png")).unwrap();
    let scale = pftrack::output::default_scale(640);
    assert!(
        img.width() >= 640 * scale && img.width() < 1280,
        "{}",
        img.width()
    );
    // As they are.
    let (_, err) = track_on_cpu(d, &csv, &["--full-size", "--max-frames", "2"]);
    assert!(err.contains("tracked 2 frames with cpu"), "{err}");
    let rows = read_pose_csv(&csv).unwrap();
    assert!((rows[0].state.a - init.a).abs() < 1e-5);
    // A start too small to shrink for is tracked at full size, without a word.
    let small = ["--max-frames", "2", "--init-ellipse", "640,480,50,60"];
    let (_, err) = track_on_cpu(d, &csv, &small);
    assert!(err.contains("tracked 2 frames with cpu"), "{err}");
    // A start the settings would refuse in the shrunk frames (a semi-axis of 30 px, 16 there,
    // under a file's bound of 20) is tracked at full size rather than refused; with a bound
    // of 12 it is shrunk as far as its 16 px allow.
    let settings = dir.join("min_axis.json");
    let kept = "note: tracking at the input's 1280x960: the settings refuse the start in the \
                frames shrunk to 684x513";
    for (bound, at, note) in [
        (20, "with cpu", true),
        (12, "at 684x513 (shrunk from 1280x960) with cpu", false),
    ] {
        std::fs::write(
            &settings,
            format!(r#"{{"filter": {{"min_axis": {bound}}}}}"#),
        )
        .unwrap();
        let (_, err) = track_on_cpu(
            d,
            &csv,
            &[
                "--max-frames",
                "2",
                "--init-ellipse",
                "640,480,200,30",
                "--config",
                settings.to_str().unwrap(),
            ],
        );
        assert!(
            err.contains(&format!("tracked 2 frames {at}")),
            "{bound}: {err}"
        );
        assert_eq!(err.contains(kept), note, "{bound}: {err}");
    }
    let o = pftrack(&["track", d, "--full-size", "--resize", "320x240"]);
    assert_eq!(o.status.code(), Some(2));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A successful track replaces an earlier, longer render in the same folder: its frames that
/// follow the new track's last are removed (and said so), anything else stays (other names,
/// and a frame after a gap, which no reader of the sequence would reach).
#[test]
fn cli_a_render_replaces_an_earlier_longer_one() {
    let dir = synth_dir("rerender", 5, "64x48");
    let d = dir.to_str().unwrap();
    let render = dir.join("render");
    let r = render.to_str().unwrap();
    let args = ["track", d, "--backend", "cpu", "--render", r, "-o", "-"];
    pftrack_ok(&args);
    assert_eq!(names(&render).len(), 6, "five frames and .pftrack-render");
    for keep in [
        "notes.txt",
        "0001.png",
        "00004.png.bak",
        "000005.png",
        "20240101.png",
        "00009.png",
    ] {
        std::fs::write(render.join(keep), b"the user's").unwrap();
    }
    let out = pftrack_ok(&[&args[..], &["--max-frames", "3"]].concat());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!("removed 2 frames of an earlier render from {r}")),
        "{stderr}"
    );
    assert_eq!(
        names(&render),
        [
            ".pftrack-render",
            "00000.png",
            "000005.png",
            "00001.png",
            "00002.png",
            "00004.png.bak",
            "00009.png",
            "0001.png",
            "20240101.png",
            "notes.txt"
        ]
    );
    // Drawn at the overlay's default scale for a 64 px wide frame.
    let img = image::open(render.join("00002.png")).unwrap();
    let scale = pftrack::output::default_scale(64);
    assert_eq!(scale, 4);
    assert!(img.width() >= 64 * scale, "{}", img.width());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The names in a folder, sorted, hidden ones included.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// Frames `00000.png` up to `n` in `dir` (a sequence's or a render's).
fn numbered_frames(dir: &Path, n: usize) -> Vec<image::RgbImage> {
    (0..n)
        .map(|k| {
            image::open(dir.join(format!("{k:05}.png")))
                .unwrap()
                .to_rgb8()
        })
        .collect()
}

/// Runs `pftrack args` with standard output sent to `stdout`.
fn pftrack_to(args: &[&str], stdout: Stdio) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_pftrack"))
        .args(args)
        .stdout(stdout)
        .stderr(Stdio::piped())
        .output()
        .expect("run pftrack")
}

/// `--out /dev/stdout` with standard output appended to a file (`>> log`) appends the CSV
/// there, as the shell means, instead of renaming a new file over the log.
#[cfg(target_os = "linux")]
#[test]
fn cli_out_to_standard_output_appends_to_the_file_behind_it() {
    let dir = synth_dir("append-stdout", 1, "64x48");
    let f0 = dir.join("frames/00000.png");
    let f0 = f0.to_str().unwrap();
    let kps = dir.join("kps.csv");
    pftrack_ok(&["sift", f0, "--out", kps.to_str().unwrap()]);
    let log = dir.join("log.csv");
    std::fs::write(&log, "before\n").unwrap();
    let append = std::fs::OpenOptions::new().append(true).open(&log).unwrap();
    let out = pftrack_to(&["sift", f0, "--out", "/dev/stdout"], Stdio::from(append));
    assert!(out.status.success(), "{out:?}");
    let mut want = b"before\n".to_vec();
    want.extend(std::fs::read(&kps).unwrap());
    let got = std::fs::read(&log).unwrap();
    assert!(
        got == want,
        "the log holds {} bytes, starting {:?}; want {} starting 'before'",
        got.len(),
        String::from_utf8_lossy(&got[..got.len().min(20)]),
        want.len()
    );
    let mut left = names(&dir);
    left.retain(|n| n.starts_with('.'));
    assert!(left.is_empty(), "{left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A track that fails part way (a frame of another size) writes nothing to `--out
/// /dev/stdout`, as it leaves no file: the rows before the failure, redirected into a file,
/// would look like a whole pose CSV.
#[cfg(target_os = "linux")]
#[test]
fn cli_a_failed_track_writes_nothing_to_standard_output() {
    let dir = synth_dir("failed-stdout", 4, "64x48");
    image::RgbImage::new(32, 24)
        .save(dir.join("frames/00003.png"))
        .unwrap();
    let log = dir.join("log.csv");
    let into = std::fs::File::create(&log).unwrap();
    let out = pftrack_to(
        &[
            "track",
            dir.to_str().unwrap(),
            "--backend",
            "cpu",
            "--out",
            "/dev/stdout",
        ],
        Stdio::from(into),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("reading frame 3"), "{err}");
    assert_eq!(std::fs::read_to_string(&log).unwrap(), "");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--stream` writes the same pose CSV as a whole run, but row by row as the frames are
/// tracked: read through a pipe, the first rows arrive while the input is still coming. A run
/// that fails part-way has written the rows before the failure and says which, exiting
/// non-zero; `--out FILE` is refused beside it.
#[test]
fn cli_stream_writes_each_row_as_its_frame_is_tracked() {
    use std::io::{BufRead, Write};
    let dir = synth_dir("stream", 6, "64x48");
    let seq = dir.to_str().unwrap();
    let whole = pftrack_ok(&["track", seq, "--backend", "cpu"]);
    let streamed = pftrack_ok(&["track", seq, "--backend", "cpu", "--stream"]);
    assert_eq!(streamed.stdout, whole.stdout);
    assert_eq!(String::from_utf8_lossy(&whole.stdout).lines().count(), 7);

    // Live: frames fed one at a time through standard input as y4m (4:4:4, the frames'
    // RGB converted as the parser reads it back, near enough for a track). The row of frame
    // 1 must come out before frame 2 is sent.
    let frames = numbered_frames(&dir.join("frames"), 6);
    let y4m_frame = |img: &image::RgbImage| {
        let (w, h) = img.dimensions();
        let mut planes = vec![0u8; 3 * (w * h) as usize];
        for (i, p) in img.pixels().enumerate() {
            let [r, g, b] = p.0.map(f64::from);
            let y = 16.0 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0;
            let cb = 128.0 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0;
            let cr = 128.0 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0;
            let n = (w * h) as usize;
            planes[i] = y.round() as u8;
            planes[n + i] = cb.round() as u8;
            planes[2 * n + i] = cr.round() as u8;
        }
        let mut out = b"FRAME\n".to_vec();
        out.extend(planes);
        out
    };
    let init = std::fs::read_to_string(dir.join("init.txt")).unwrap();
    let ellipse = init.lines().next().unwrap().to_string();
    let mut child = Command::new(env!("CARGO_BIN_EXE_pftrack"))
        .args([
            "track",
            "-",
            "--init-ellipse",
            &ellipse,
            "--backend",
            "cpu",
            "--stream",
        ])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let stdout = child.stdout.take().unwrap();
    // Lines as they come, through a thread, so that a row held back fails in time rather than
    // hanging the test.
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout).lines() {
            if tx.send(line.unwrap()).is_err() {
                break;
            }
        }
    });
    let next_line = |what: &str| {
        rx.recv_timeout(std::time::Duration::from_secs(60))
            .unwrap_or_else(|e| panic!("{what}: no line came ({e})"))
    };
    stdin
        .write_all(b"YUV4MPEG2 W64 H48 F25:1 Ip A1:1 C444\n")
        .unwrap();
    for (k, img) in frames.iter().enumerate() {
        stdin.write_all(&y4m_frame(img)).unwrap();
        stdin.flush().unwrap();
        if k == 0 {
            let header = next_line("the header");
            assert!(header.starts_with("frame,cx,cy"), "{header}");
        }
        // The frame's row, before the next frame exists.
        let row = next_line(&format!(
            "the row of frame {k}, the next frame not yet sent"
        ));
        assert!(row.starts_with(&format!("{k},")), "frame {k}: {row:?}");
    }
    drop(stdin);
    reader.join().unwrap();
    assert!(rx.try_recv().is_err(), "a row after the last frame's");
    assert!(child.wait().unwrap().success());

    // A frame of another size fails the track at frame 3, after the rows of frames 0-2.
    image::RgbImage::new(32, 24)
        .save(dir.join("frames/00003.png"))
        .unwrap();
    let out = pftrack(&["track", seq, "--backend", "cpu", "--stream"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert_eq!(
        err.lines().filter(|l| l.contains("error")).count(),
        1,
        "{err}"
    );
    assert!(
        err.contains("after the pose rows of frames 0 to 2") && err.contains("reading frame 3"),
        "{err}"
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let whole = String::from_utf8_lossy(&whole.stdout);
    assert_eq!(
        text.lines().collect::<Vec<_>>(),
        whole.lines().take(4).collect::<Vec<_>>()
    );

    let csv = dir.join("poses.csv");
    let out = pftrack(&["track", seq, "--stream", "--out", csv.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("--stream") && err.contains("--out"), "{err}");
    assert!(!csv.exists());

    // Standard output that takes nothing fails on the header, which is said as such: the
    // message had said "after the header" of a header never written.
    if let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") {
        let out = Command::new(env!("CARGO_BIN_EXE_pftrack"))
            .args(["track", seq, "--backend", "cpu", "--stream"])
            .stdout(full)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("before the pose CSV's header"), "{err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--render-video` writes the frames `--render` draws as one video, the same frames (read
/// back through ffmpeg, within the codec's loss); a failed run leaves none, partial or whole;
/// names that clash with the inputs or the render are refused.
#[test]
fn cli_render_video_writes_the_rendered_frames_or_nothing() {
    if !pftrack::frames::FfmpegTools::default().available() {
        eprintln!("skip: ffmpeg not on PATH");
        return;
    }
    let dir = synth_dir("render-video", 5, "65x49");
    let seq = dir.to_str().unwrap();
    let (render, video) = (dir.join("render"), dir.join("track.mkv"));
    let out = pftrack_ok(&[
        "track",
        seq,
        "--backend",
        "cpu",
        "--render",
        render.to_str().unwrap(),
        "--render-video",
        video.to_str().unwrap(),
        "--render-fps",
        "10",
        "-o",
        dir.join("poses.csv").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("video in"), "{err}");
    let drawn = numbered_frames(&render, 5);
    let (w, h) = drawn[0].dimensions();
    let mut read =
        pftrack::frames::open(&video, &pftrack::frames::SourceOptions { resize: None }).unwrap();
    assert_eq!(read.size(), (w + w % 2, h + h % 2));
    let mut n = 0;
    for (k, frame) in read.by_ref().enumerate() {
        let frame = frame.unwrap();
        // Mean absolute difference over the drawn part: the codec's loss only.
        let mut sum = 0u64;
        for (x, y, p) in drawn[k].enumerate_pixels() {
            let q = frame.get_pixel(x, y);
            sum += (0..3).map(|c| p[c].abs_diff(q[c]) as u64).sum::<u64>();
        }
        let mad = sum as f64 / (3 * w * h) as f64;
        assert!(mad < 6.0, "frame {k}: mean difference {mad}");
        n += 1;
    }
    assert_eq!(n, 5);
    let hidden: Vec<String> = names(&dir)
        .into_iter()
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");

    // A frame of another size fails the run at frame 3: no video, partial or whole.
    std::fs::remove_file(&video).unwrap();
    image::RgbImage::new(32, 24)
        .save(dir.join("frames/00003.png"))
        .unwrap();
    let out = pftrack(&[
        "track",
        seq,
        "--backend",
        "cpu",
        "--render-video",
        video.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let left: Vec<String> = names(&dir)
        .into_iter()
        .filter(|n| n.contains("track.mkv") || n.starts_with(".pftrack-video"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    // With the frame mended, an ffmpeg that fails only as the video ends (one that says so
    // and exits 0, as ffmpeg 5.1 does on a full disk) fails the run with neither the video
    // nor the poses; the real one writes both.
    image::open(dir.join("frames/00002.png"))
        .unwrap()
        .save(dir.join("frames/00003.png"))
        .unwrap();
    let csv = dir.join("poses-after.csv");
    let args = [
        "track",
        seq,
        "--backend",
        "cpu",
        "--render-video",
        video.to_str().unwrap(),
        "--out",
        csv.to_str().unwrap(),
    ];
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let bin = tmp_dir("render-video-fake-ffmpeg");
        std::fs::create_dir_all(&bin).unwrap();
        std::fs::write(
            bin.join("ffmpeg"),
            "#!/bin/sh\nfor a; do out=$a; done\ncat > /dev/null\nprintf x > \"${out#file:}\"\n\
             echo 'Error writing trailer: No space left on device' >&2\nexit 0\n",
        )
        .unwrap();
        std::fs::set_permissions(bin.join("ffmpeg"), std::fs::Permissions::from_mode(0o755))
            .unwrap();
        let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap());
        let with_fake = |args: &[&str]| {
            Command::new(env!("CARGO_BIN_EXE_pftrack"))
                .args(args)
                .env("PATH", &path)
                .output()
                .unwrap()
        };
        let out = with_fake(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("No space left on device"), "{err}");
        assert!(!csv.exists() && !video.exists());
        let staged: Vec<String> = names(&dir)
            .into_iter()
            .filter(|n| n.starts_with(".pftrack-video"))
            .collect();
        assert!(staged.is_empty(), "{staged:?}");
        // Streamed, the rows went out before the video failed, and the error says which.
        let out = with_fake(&[&args[..6], &["--stream"]].concat());
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(
            err.contains("after the pose rows of frames 0 to 4"),
            "{err}"
        );
        assert_eq!(String::from_utf8_lossy(&out.stdout).lines().count(), 6);
        std::fs::remove_dir_all(&bin).unwrap();
    }
    let out = pftrack(&args);
    assert!(out.status.success(), "{out:?}");
    assert!(csv.exists() && video.exists());

    // Clashes, refused before anything is tracked: among them the poses through a link to
    // the video's name, not yet written (the video would be renamed over the poses).
    #[cfg(unix)]
    {
        let link = dir.join("link.csv");
        std::os::unix::fs::symlink("later.mkv", &link).unwrap();
        let later = dir.join("later.mkv");
        let out = pftrack(&[
            "track",
            seq,
            "--backend",
            "cpu",
            "-o",
            link.to_str().unwrap(),
            "--render-video",
            later.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("both name"), "{err}");
        assert!(!later.exists());
        std::fs::remove_file(&link).unwrap();
    }
    let init = dir.join("init.txt");
    for (args, needle) in [
        (
            vec!["--render-video", init.to_str().unwrap()],
            "is an input",
        ),
        (
            vec![
                "--render-video",
                render.to_str().unwrap(),
                "--render",
                render.to_str().unwrap(),
            ],
            "both name",
        ),
        (vec!["--render-video", "x.png"], "container"),
        (
            vec!["--render-video", "x.mkv", "--out", "x.mkv"],
            "both name",
        ),
        (vec!["--render-video", "-"], "not to standard output"),
        (
            vec!["--render-video", "x.gif", "--render-fps", "60"],
            "at most 50 frames a second",
        ),
        (vec!["--render-video", "o%d.tif"], "container"),
        (vec!["--render-video", "/dev/stdout"], "descriptors"),
        (vec!["--render-video", "nowhere/x.mp4"], "no folder"),
        (vec!["--render-fps", "10"], "--render-video"),
        (
            vec!["--render-video", "x.mp4", "--render-fps", "0"],
            "--render-fps 0: a frame rate",
        ),
    ] {
        let mut all = vec!["track", seq, "--backend", "cpu"];
        all.extend(args);
        let out = pftrack(&all);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains(needle),
            "{all:?}: {err}"
        );
        assert_eq!(err.lines().count(), 1, "{err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A warning naming a folder whose name holds a newline stays on one line, as an error does:
/// each line on standard error is one message.
#[cfg(unix)]
#[test]
fn cli_a_warning_is_one_line_whatever_the_file_names() {
    let seq = synth_dir("warn-name", 3, "64x48");
    let odd = seq.join("odd\nname");
    std::fs::create_dir(&odd).unwrap();
    for (from, to) in [(0, 0), (1, 1), (2, 5)] {
        std::fs::copy(
            seq.join(format!("frames/{from:05}.png")),
            odd.join(format!("{to:05}.png")),
        )
        .unwrap();
    }
    let init = seq.join("init.txt");
    let out = pftrack_ok(&[
        "track",
        odd.to_str().unwrap(),
        "--init-file",
        init.to_str().unwrap(),
        "--backend",
        "cpu",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = err.lines().collect();
    assert!(
        lines
            .iter()
            .any(|l| l.contains("warning") && l.contains("odd\\nname")),
        "{err}"
    );
    assert!(
        lines.iter().all(|l| l.starts_with("pftrack: ")),
        "a message went over two lines: {err}"
    );
    std::fs::remove_dir_all(&seq).unwrap();
}

/// Standard output that cannot be written (a full disk: `/dev/full`) is a one-line error
/// with a non-zero exit, for a command that prints a table and for one that prints its CSV,
/// not the panic of `println!`.
#[cfg(unix)]
#[test]
fn cli_a_full_standard_output_is_an_error() {
    let full = Path::new("/dev/full");
    if !full.exists() {
        let _ = std::io::Write::write_all(&mut std::io::stderr(), b"SKIPPED: no /dev/full\n");
        return;
    }
    let dir = synth_dir("full", 3, "64x48");
    let truth = dir.join("truth.csv");
    let d = dir.to_str().unwrap();
    let t = truth.to_str().unwrap();
    for args in [
        vec!["eval", t, t],
        vec!["track", d, "--backend", "cpu", "--particles", "20"],
        // clap's help and version printing ended with 0 and nothing said.
        vec!["--help"],
        vec!["track", "--help"],
        vec!["--version"],
    ] {
        let sink = std::fs::OpenOptions::new().write(true).open(full).unwrap();
        let out = pftrack_to(&args, Stdio::from(sink));
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err.trim_end().lines().last().unwrap_or_default();
        assert!(
            last.starts_with("pftrack: error: writing to standard output"),
            "{args:?}: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Starts `cmd` with the interrupt signals at their default actions whatever the test's own
/// (a test run in the background of a script inherits SIGINT ignored), and SIGHUP ignored
/// when `nohup`.
#[cfg(unix)]
fn spawn_with_default_signals(cmd: &mut Command, nohup: bool) -> std::process::Child {
    use std::os::unix::process::CommandExt as _;
    // SAFETY: between fork and exec only async-signal-safe calls (signal(2)).
    unsafe {
        cmd.pre_exec(move || {
            for s in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
                libc::signal(s, libc::SIG_DFL);
            }
            if nohup {
                libc::signal(libc::SIGHUP, libc::SIG_IGN);
            }
            Ok(())
        });
    }
    cmd.spawn().expect("run pftrack")
}

#[cfg(unix)]
/// Waits (a minute at most) until `rendered` says a frame is drawn.
fn wait_for_a_frame(rendered: impl Fn() -> bool) {
    let t0 = std::time::Instant::now();
    while !rendered() {
        assert!(t0.elapsed().as_secs() < 60, "no frame rendered");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// Sends `signal` to `child`.
#[cfg(unix)]
fn send(child: &std::process::Child, signal: i32) {
    // SAFETY: kill(2) on the child's own pid.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, signal) }, 0);
}

/// An interrupt (SIGINT, SIGTERM) mid-run removes what the run had in progress: the pose
/// CSV's partial file and the render's staging folder, and the render folder the run made;
/// the command says so in one line and ends by the signal. A signal ignored from the start
/// (SIGHUP under `nohup`) stays ignored. The frames come from a Y4M stream on standard input
/// that stalls after three frames, so the signal lands mid-track. The command starts with
/// the signals' default actions whatever the test's own (a test run in the background of a
/// script inherits SIGINT ignored).
#[cfg(unix)]
#[test]
fn cli_an_interrupted_track_leaves_nothing_behind() {
    use std::io::Write as _;
    use std::os::unix::process::ExitStatusExt as _;
    let dir = tmp_dir("interrupt");
    std::fs::create_dir_all(&dir).unwrap();
    let (w, h) = (64usize, 48usize);
    let mut stream = format!("YUV4MPEG2 W{w} H{h} F25:1 Ip A1:1 C444\n").into_bytes();
    for k in 0..3 {
        stream.extend_from_slice(b"FRAME\n");
        // A textured grey frame, moving a pixel a frame.
        stream.extend((0..w * h).map(|i| (((i % w + k) * 37 + (i / w) * 11) % 251) as u8));
        stream.extend(std::iter::repeat_n(128u8, 2 * w * h));
    }
    let ffmpeg = pftrack::frames::FfmpegTools::default().available();
    // (signal sent first, SIGHUP ignored from the start, the signal that ends the run)
    for (first, nohup, ends) in [
        (libc::SIGINT, false, libc::SIGINT),
        (libc::SIGTERM, false, libc::SIGTERM),
        (libc::SIGHUP, true, libc::SIGTERM),
    ] {
        let csv = dir.join("poses.csv");
        let render = dir.join("render");
        let video = dir.join("track.mkv");
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_pftrack"));
        cmd.args([
            "track",
            "-",
            "--init-ellipse",
            "32,24,12,15",
            "--backend",
            "cpu",
        ])
        .args([
            "-o",
            csv.to_str().unwrap(),
            "--render",
            render.to_str().unwrap(),
        ])
        // The video too, where ffmpeg is at hand to write it.
        .args(
            ffmpeg
                .then_some(["--render-video", video.to_str().unwrap()])
                .into_iter()
                .flatten(),
        )
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
        let mut child = spawn_with_default_signals(&mut cmd, nohup);
        let mut stdin = child.stdin.take().unwrap();
        stdin.write_all(&stream).unwrap();
        stdin.flush().unwrap();
        // Wait for the third frame's rendering: the track is under way, waiting for frame 4.
        let staged = || {
            std::fs::read_dir(&render)
                .into_iter()
                .flatten()
                .flatten()
                .filter_map(|e| std::fs::read_dir(e.path()).ok())
                .map(|d| d.flatten().filter(|f| f.file_name() == "00002.png").count())
                .sum::<usize>()
        };
        wait_for_a_frame(|| staged() > 0);
        let names_then = names(&dir);
        let partial_csv = |names: &[String]| {
            names
                .iter()
                .any(|n| n.starts_with(".poses.csv.") && n.ends_with(".partial"))
        };
        assert!(partial_csv(&names_then), "{names_then:?}");
        assert!(
            !ffmpeg
                || names_then
                    .iter()
                    .any(|n| n.starts_with(".pftrack-video-") && n.ends_with(".partial")),
            "{names_then:?}"
        );
        send(&child, first);
        if nohup {
            // Ignored: still running, its partial files in place.
            std::thread::sleep(std::time::Duration::from_millis(300));
            assert!(
                child.try_wait().unwrap().is_none(),
                "SIGHUP ended a nohup run"
            );
            assert!(partial_csv(&names(&dir)));
            send(&child, ends);
        }
        let out = child.wait_with_output().unwrap();
        drop(stdin);
        // Ended by the signal itself, as a shell expects of an interrupted command (so a loop
        // over files stops).
        assert_eq!(out.status.signal(), Some(ends), "{first}: {out:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.ends_with("pftrack: interrupted\n"), "{first}: {err}");
        assert!(out.stdout.is_empty());
        // Nothing of the run stays: no CSV or video, partial or whole, and no render folder.
        assert!(names(&dir).is_empty(), "{first}: {:?}", names(&dir));
        // Nor its ffmpeg, which the interrupt stops (it runs in a process group of its own, so
        // only the program's clean-up can).
        if let Some(staged) = names_then.iter().find(|n| n.starts_with(".pftrack-video-")) {
            let running: Vec<String> = std::fs::read_dir("/proc")
                .unwrap()
                .flatten()
                .filter_map(|e| std::fs::read(e.path().join("cmdline")).ok())
                .map(|c| String::from_utf8_lossy(&c).replace('\0', " "))
                .filter(|c| c.contains(staged.as_str()))
                .collect();
            assert!(running.is_empty(), "{first}: still running: {running:?}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An interrupted `synth` leaves an earlier sequence in its folder whole (it used to delete
/// its truth and init file and mix new frames with the old), and a new folder, with the
/// parents it made, not at all.
#[cfg(unix)]
#[test]
fn cli_an_interrupted_synth_leaves_the_folder_as_it_was() {
    use std::os::unix::process::ExitStatusExt as _;
    let dir = tmp_dir("interrupt-synth");
    std::fs::create_dir_all(&dir).unwrap();
    let seq = dir.join("seq");
    let s = seq.to_str().unwrap();
    pftrack_ok(&[
        "synth",
        s,
        "--scenario",
        "nod",
        "--frames",
        "5",
        "--size",
        "64x48",
    ]);
    let truth = std::fs::read(seq.join("truth.csv")).unwrap();
    let frames_before = names(&seq.join("frames"));
    let fresh = dir.join("fresh/a/b");
    for (into, existed) in [(&seq, true), (&fresh, false)] {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_pftrack"));
        cmd.args(["synth", into.to_str().unwrap(), "--scenario", "long"])
            .args(["--frames", "2400", "--size", "320x240"])
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        let child = spawn_with_default_signals(&mut cmd, false);
        // Wait for frames in the staging folder: the render is under way.
        let frames = into.join("frames");
        let rendering = || {
            synth_staging(&frames)
                .filter_map(|d| std::fs::read_dir(d).ok())
                .map(|d| d.count())
                .sum::<usize>()
                > 0
        };
        wait_for_a_frame(rendering);
        send(&child, libc::SIGINT);
        let out = child.wait_with_output().unwrap();
        assert_eq!(out.status.signal(), Some(libc::SIGINT), "{out:?}");
        if existed {
            assert_eq!(std::fs::read(seq.join("truth.csv")).unwrap(), truth);
            assert!(seq.join("init.txt").exists());
            assert_eq!(names(&frames), frames_before, "old frames only, no staging");
        } else {
            // Its parents too, made by the render.
            assert!(!dir.join("fresh").exists(), "{:?}", names(&dir));
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An interrupted `demo` leaves its folder as it was: the sequence and the poses move in
/// together, so an earlier run's poses never end up beside a new sequence (the sequence used
/// to be put in place before the track began).
#[cfg(unix)]
#[test]
fn cli_an_interrupted_demo_leaves_the_earlier_run_whole() {
    use std::os::unix::process::ExitStatusExt as _;
    let dir = tmp_dir("interrupt-demo");
    let d = dir.to_str().unwrap();
    let demo = |scenario: &str, frames: &str| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_pftrack"));
        cmd.args([
            "demo",
            "--out",
            d,
            "--backend",
            "cpu",
            "--scenario",
            scenario,
        ])
        .args(["--frames", frames])
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
        cmd
    };
    assert!(demo("pan", "5").status().unwrap().success());
    let poses = std::fs::read(dir.join("poses.csv")).unwrap();
    let truth = std::fs::read(dir.join("sequence/truth.csv")).unwrap();
    let frames_before = names(&dir.join("sequence/frames"));
    let child = spawn_with_default_signals(&mut demo("nod", "600"), false);
    // Once the last frame is rendered into the staging folder the track is under way.
    let frames = dir.join("sequence/frames");
    let rendered = || synth_staging(&frames).any(|d| d.join("00599.png").exists());
    wait_for_a_frame(rendered);
    std::thread::sleep(std::time::Duration::from_millis(100));
    send(&child, libc::SIGTERM);
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.signal(), Some(libc::SIGTERM), "{out:?}");
    assert_eq!(std::fs::read(dir.join("poses.csv")).unwrap(), poses);
    assert_eq!(
        std::fs::read(dir.join("sequence/truth.csv")).unwrap(),
        truth
    );
    assert_eq!(names(&frames), frames_before, "old frames only, no staging");
    assert_eq!(names(&dir), ["poses.csv", "sequence"]);
    // Run to the end, the sequence and its poses are the new run's.
    assert!(demo("nod", "8").status().unwrap().success());
    let rows = |p: &Path| std::fs::read_to_string(p).unwrap().lines().count();
    assert_eq!(rows(&dir.join("poses.csv")), 9);
    assert_eq!(rows(&dir.join("sequence/truth.csv")), 9);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A reader that stops reading (`| head -1`) ends the command quietly: exit 0, nothing on
/// standard error. (Whether the command had written before the pipe closed or not, the
/// outcome is the same.)
#[test]
fn cli_a_closed_pipe_ends_the_command_quietly() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_pftrack"))
        .args([
            "pose-noise",
            "--trials",
            "50",
            "--snr",
            "10",
            "--lambda-snr",
            "10",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run pftrack");
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{out:?}");
    assert!(
        out.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The same for an output file that is the pipe (`--out /dev/stdout`): SIFT's CSV of a
    // frame is larger than a pipe's buffer, so the write meets the closed pipe.
    #[cfg(unix)]
    {
        let dir = synth_dir("pipe-out", 1, "160x120");
        let frame = dir.join("frames/00000.png");
        let mut child = Command::new(env!("CARGO_BIN_EXE_pftrack"))
            .args(["sift", frame.to_str().unwrap(), "--out", "/dev/stdout"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("run pftrack");
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        assert!(out.status.success(), "{out:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("error"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// `--out` names a folder: refused at once by name, with no partial file left beside it;
/// `--out` names a link: the file it links to gets the poses and the link stays a link.
#[test]
fn cli_out_refuses_a_folder_and_writes_through_a_link() {
    let dir = synth_dir("out-kinds", 3, "64x48");
    let d = dir.to_str().unwrap();
    let out_dir = dir.join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let before = names(&dir);
    let args = ["track", d, "--backend", "cpu", "--particles", "20", "--out"];
    let mut a = args.to_vec();
    a.push(out_dir.to_str().unwrap());
    assert_one_line_error(&a, "is a directory", &out_dir.join("x"));
    assert_eq!(names(&dir), before);
    #[cfg(unix)]
    {
        let real = dir.join("real.csv");
        std::fs::write(&real, "old\n").unwrap();
        let link = dir.join("link.csv");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        let mut a = args.to_vec();
        a.push(link.to_str().unwrap());
        pftrack_ok(&a);
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(read_pose_csv(&real).unwrap().len(), 3);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `pose-noise` opens its outputs before it runs: a CSV whose `_lambda` twin cannot be
/// written, or a plot named like the CSV, fails at once and leaves no file at all.
#[test]
fn cli_pose_noise_writes_all_its_outputs_or_none() {
    let dir = tmp_dir("pose-noise-out");
    std::fs::create_dir_all(dir.join("f_lambda.csv")).unwrap();
    let csv = dir.join("f.csv");
    let c = csv.to_str().unwrap();
    let quick = [
        "pose-noise",
        "--trials",
        "5",
        "--snr",
        "10",
        "--lambda-snr",
        "10",
    ];
    let mut a = quick.to_vec();
    a.extend(["--csv", c]);
    assert_one_line_error(&a, "f_lambda.csv: is a directory", &csv);
    let mut a = quick.to_vec();
    a.extend(["--csv", c, "--plot", c]);
    assert_one_line_error(&a, ".png", &csv);
    let plot = dir.join("f_lambda.png");
    let png = dir.join("f.png");
    let mut a = quick.to_vec();
    a.extend([
        "--csv",
        png.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert_one_line_error(&a, "named for two outputs", &png);
    // The same file spelled otherwise: the CSV and the plot shared one partial file, and the
    // run failed after putting a mix of both in place under that name.
    let leaf = dir.file_name().unwrap().to_str().unwrap();
    let other = dir.join("..").join(leaf).join("f.png");
    let mut a = quick.to_vec();
    a.extend([
        "--csv",
        png.to_str().unwrap(),
        "--plot",
        other.to_str().unwrap(),
    ]);
    assert_one_line_error(&a, "named for two outputs", &png);
    assert_eq!(names(&dir), ["f_lambda.csv"]);
    // All of them, when all can be written.
    let ok = tmp_dir("pose-noise-ok");
    std::fs::create_dir_all(&ok).unwrap();
    let mut a = quick.to_vec();
    let (c, p) = (ok.join("g.csv"), ok.join("g.png"));
    a.extend(["--csv", c.to_str().unwrap(), "--plot", p.to_str().unwrap()]);
    pftrack_ok(&a);
    assert_eq!(names(&ok), ["g.csv", "g.png", "g_lambda.csv"]);
    assert_eq!(image::open(&p).unwrap().width(), 1400);
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::remove_dir_all(&ok).unwrap();
}

/// A one-frame sequence is a whole track: the initial row, a summary that counts one frame,
/// and its rendering.
#[test]
fn cli_tracks_a_one_frame_sequence() {
    let dir = synth_dir("one-frame", 1, "64x48");
    let d = dir.to_str().unwrap();
    let csv = dir.join("poses.csv");
    let render = dir.join("render");
    let out = pftrack_ok(&[
        "track",
        d,
        "--backend",
        "cpu",
        "--out",
        csv.to_str().unwrap(),
        "--render",
        render.to_str().unwrap(),
    ]);
    let rows = read_pose_csv(&csv).unwrap();
    assert_eq!(rows.len(), 1);
    let init = read_init(&dir.join("init.txt")).unwrap().ellipse;
    let s = rows[0].state;
    assert_eq!((s.cx, s.cy, s.a, s.b), (init.cx, init.cy, init.a, init.b));
    assert_eq!((s.rx, s.ry, s.rz), (0.0, 0.0, 0.0));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("tracked 1 frame with"), "{stderr}");
    assert_eq!(names(&render), [".pftrack-render", "00000.png"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `bench --step` times the whole tracker step: a row per particle count with a positive
/// time and its frames per second, for one thread (and all, where there are more).
#[test]
fn cli_bench_step_times_the_whole_step() {
    let out = pftrack_ok(&[
        "bench",
        "--step",
        "--particles",
        "20,40",
        "--size",
        "64x48",
        "--repeats",
        "1",
        "--backend",
        "cpu",
    ]);
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        text.contains("whole tracker step: `nod` at 64x48"),
        "{text}"
    );
    for n in ["20", "40"] {
        let row = text
            .lines()
            .find(|l| l.split_whitespace().next() == Some(n))
            .unwrap_or_else(|| panic!("no row for {n}: {text}"));
        // "N  ms (fps/s)" per column
        let cells: Vec<&str> = row.split_whitespace().skip(1).collect();
        assert!(!cells.is_empty() && cells.len().is_multiple_of(2), "{row}");
        for pair in cells.chunks(2) {
            let ms: f64 = pair[0].parse().unwrap();
            let fps: f64 = pair[1]
                .trim_start_matches('(')
                .trim_end_matches("/s)")
                .parse()
                .unwrap();
            assert!(ms > 0.0 && fps > 0.0, "{row}");
            assert!((ms * fps / 1000.0 - 1.0).abs() < 0.05, "{row}");
        }
    }
}

/// A change of light over the whole frame is undone, and `track` says on how many frames;
/// with `--no-exposure` the frames are taken as they come and nothing is said.
#[test]
fn cli_track_reports_the_frames_brought_back_to_the_starts_light() {
    let dir = synth_dir("relit", 8, "96x72");
    // Half the light from the sixth frame on (frames 5, 6 and 7 of 0-7).
    for k in 5..8 {
        let path = dir.join("frames").join(format!("{k:05}.png"));
        let mut img = image::open(&path).unwrap().to_rgb8();
        for p in img.pixels_mut() {
            p.0 = p.0.map(|v| v / 2);
        }
        img.save(&path).unwrap();
    }
    let d = dir.to_str().unwrap();
    let out = pftrack_ok(&["track", d, "--backend", "cpu"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("pftrack: 3 frames were in other light over the whole frame"),
        "{err}"
    );
    let out = pftrack_ok(&["track", d, "--backend", "cpu", "--no-exposure"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("other light"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A setting the tracker refuses is reported by the flag that set it, with the flag that
/// turns the part off, not by the library's field and its `None`.
#[test]
fn cli_track_settings_errors_name_the_flag() {
    let dir = synth_dir("flags", 2, "64x48");
    let d = dir.to_str().unwrap();
    let csv = dir.join("poses.csv");
    let c = csv.to_str().unwrap();
    for (flag, off) in [
        ("--colour-rate=-1", "--colour-rate 0"),
        ("--aspect-slack=0.5", "--no-aspect-bound"),
        ("--size-hold=0.5", "--no-size-hold"),
        ("--reacquire-ncc=2", "--no-template-reacquire"),
        ("--reanchor-ncc=2", "--no-reanchor"),
        ("--sift-upsample-below=-1", "--sift-always-upsample"),
        ("--contrast-weight=-1", "--contrast-weight 0"),
        ("--fit-centre-sigma=-1", "--no-fit-centre-prior"),
        ("--found-above=2", "found_above 2"),
        ("--trust-above=2", "trust_above 2"),
        ("--exposure-jump=0", "--no-exposure"),
    ] {
        let name = flag.split('=').next().unwrap();
        let args = ["track", d, "--backend", "cpu", flag, "--out", c];
        assert_one_line_error(&args, &format!("error: {name}: "), &csv);
        let err = String::from_utf8_lossy(&pftrack(&args).stderr).to_string();
        assert!(err.contains(off), "{flag}: {err}");
        assert!(
            !err.contains("None") && !err.contains("Some("),
            "{flag}: {err}"
        );
    }
    // A setting of a part another flag turns off would do nothing: refused, not ignored.
    for (pair, needle) in [
        (
            ["--template-weight=0", "--template-rate=0.5"],
            "--template-rate 0.5 has no effect",
        ),
        (
            ["--colour-rate=0", "--colour-max-ring=0.3"],
            "--colour-max-ring 0.3 has no effect",
        ),
        (
            ["--no-fit-prior", "--no-fit-centre-prior"],
            "cannot be used with",
        ),
    ] {
        let mut args = vec!["track", d, "--backend", "cpu"];
        args.extend(pair);
        args.extend(["--out", c]);
        assert_one_line_error(&args, needle, &csv);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The demo's poses are the track `pftrack track` gives of the demo's own sequence with the
/// same seed: the demo starts from the init file as written (it had started from the
/// unrounded ellipse, and the chaotic track parted from `track`'s).
#[test]
fn cli_demo_poses_are_the_track_of_its_sequence() {
    // A name a shell would split or expand, to check the command it prints.
    let top = tmp_dir("demo-track");
    let dir = top.join("it's a $demo");
    let d = dir.to_str().unwrap();
    let common = ["--backend", "cpu", "--seed", "3"];
    let mut args = vec!["demo", "--out", d, "--frames", "40"];
    args.extend(common);
    let shown = String::from_utf8(pftrack_ok(&args).stdout).unwrap();
    let poses = std::fs::read(dir.join("poses.csv")).unwrap();
    // The command it gives to watch the track, run by a shell as pasted, writes the same
    // poses, and the video.
    let watch = shown
        .lines()
        .find_map(|l| l.strip_prefix("to watch it: pftrack "))
        .unwrap_or_else(|| panic!("no command to watch it in:\n{shown}"));
    if pftrack::frames::FfmpegTools::default().available() {
        let out = Command::new("sh")
            .arg("-c")
            .arg(format!("\"$PFTRACK\" {watch}"))
            .env("PFTRACK", env!("CARGO_BIN_EXE_pftrack"))
            .output()
            .unwrap();
        assert!(out.status.success(), "{watch}: {out:?}");
        assert!(std::fs::read(dir.join("poses.csv")).unwrap() == poses);
        assert!(dir.join("track.mp4").is_file());
    }
    let csv = dir.join("again.csv");
    let seq = dir.join("sequence");
    let mut args = vec![
        "track",
        seq.to_str().unwrap(),
        "--out",
        csv.to_str().unwrap(),
    ];
    args.extend(common);
    pftrack_ok(&args);
    assert!(
        std::fs::read(dir.join("poses.csv")).unwrap() == std::fs::read(&csv).unwrap(),
        "the demo's poses differ from the track of its sequence"
    );
    std::fs::remove_dir_all(&top).unwrap();
}

/// `demo` checks its arguments before it renders anything: a bad one leaves no folder.
#[test]
fn cli_demo_checks_before_rendering() {
    let dir = tmp_dir("demo-checks");
    let out = dir.join("demo");
    let o = out.to_str().unwrap();
    for (bad, needle) in [
        (["--particles", "0"], "--particles"),
        (["--backend", "foo"], "--backend"),
        (["--frames", "0"], "frames"),
        (["--scenario", "spin"], "spin"),
    ] {
        let mut a = vec!["demo", "--out", o];
        a.extend(bad);
        assert_one_line_error(&a, needle, &out);
    }
    // A file given as the output folder is refused by name, and left as it was.
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("file");
    std::fs::write(&file, b"the user's").unwrap();
    let f = file.to_str().unwrap();
    assert_one_line_error(
        &["demo", "--out", f],
        &format!("--out {f}: not a folder"),
        &out,
    );
    assert_eq!(std::fs::read(&file).unwrap(), b"the user's");
    // A folder where the poses go is refused before the sequence is rendered (the whole
    // render used to run first).
    std::fs::create_dir_all(out.join("poses.csv")).unwrap();
    let e = pftrack(&["demo", "--out", o]);
    assert_eq!(e.status.code(), Some(1));
    let err = String::from_utf8_lossy(&e.stderr);
    assert!(
        err.contains("poses.csv is a folder") && err.lines().count() == 1,
        "{err}"
    );
    let mut left: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    left.sort();
    assert_eq!(left, ["poses.csv"], "nothing rendered");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--init-truth` on a pose CSV starts from its frame 0 row's pose as well as its ellipse,
/// unless `--init-pose` says otherwise; a start beyond the frame or a turn, or a CSV with no
/// row for frame 0, is refused.
#[test]
fn cli_init_truth_starts_from_the_first_rows_pose() {
    let dir = synth_dir("init-truth", 2, "64x48");
    let d = dir.to_str().unwrap();
    let truth = dir.join("truth.csv");
    let mut rows = read_pose_csv(&truth).unwrap();
    rows[0].state.rx = 20f64.to_radians();
    let turned = dir.join("turned.csv");
    pftrack::io::write_pose_csv(&turned, &rows, false).unwrap();
    let t = turned.to_str().unwrap();
    let csv = dir.join("poses.csv");
    let c = csv.to_str().unwrap();
    let first_rx = |extra: &[&str]| {
        let mut a = vec![
            "track",
            d,
            "--backend",
            "cpu",
            "--init-truth",
            t,
            "--out",
            c,
        ];
        a.extend(extra);
        pftrack_ok(&a);
        read_pose_csv(&csv).unwrap()[0].state.rx.to_degrees()
    };
    assert!((first_rx(&[]) - 20.0).abs() < 1e-4);
    assert!(first_rx(&["--init-pose", "0,0,0"]).abs() < 1e-9);
    std::fs::remove_file(&csv).unwrap();
    for (bad, needle) in [
        (["--init-pose", "1000,0,0"], "at most 360"),
        (["--init-ellipse", "32,24,100,10"], "at most 64 px"),
        (["--init-ellipse", "32,24,10,10,-1e30"], "at most 360"),
    ] {
        let mut a = vec!["track", d, "--backend", "cpu", "--out", c];
        a.extend(bad);
        assert_one_line_error(&a, needle, &csv);
    }
    // Rows that begin after frame 0 hold no start for it.
    let late = dir.join("late.csv");
    pftrack::io::write_pose_csv(&late, &rows[1..], false).unwrap();
    assert_one_line_error(
        &[
            "track",
            d,
            "--init-truth",
            late.to_str().unwrap(),
            "--out",
            c,
        ],
        "no row for frame 0, the frame tracking starts on (its one row is of frame 1)",
        &csv,
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An input of the wrong kind is named for what it is: a folder given as an image, a device
/// given as a video.
#[test]
fn cli_inputs_of_the_wrong_kind_are_named() {
    let dir = synth_dir("kinds", 2, "64x48");
    let d = dir.to_str().unwrap();
    let none = dir.join("none.csv");
    assert_one_line_error(&["sift", d], "is a directory, not an image", &none);
    let frame = dir.join("frames/00000.png");
    let f = frame.to_str().unwrap();
    assert_one_line_error(
        &["pose", d, f, "--ellipse", "32,24,8,10"],
        "is a directory, not an image",
        &none,
    );
    #[cfg(unix)]
    assert_one_line_error(
        &["track", "/dev/null", "--init-ellipse", "5,5,3,3"],
        "not a video file",
        &none,
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The outputs of a track never overwrite what it reads, however they are spelled or
/// linked: a frame (through a link), the init file, the truth it starts from; nor does
/// `sift --out` overwrite its image.
#[test]
fn cli_outputs_never_overwrite_what_is_read() {
    let dir = synth_dir("overwrite", 3, "64x48");
    let d = dir.to_str().unwrap();
    let frame = dir.join("frames/00000.png");
    let init = dir.join("init.txt");
    let truth = dir.join("truth.csv");
    let keep: Vec<Vec<u8>> = [&frame, &init, &truth]
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    let track = |extra: &[&str], out: &Path| {
        let mut a = vec!["track", d, "--backend", "cpu", "--particles", "20", "--out"];
        a.push(out.to_str().unwrap());
        a.extend(extra);
        pftrack(&a)
    };
    let mut refused = vec![
        track(&[], &init),
        track(&[], &dir.join("./frames/../init.txt")),
        track(&["--init-truth", truth.to_str().unwrap()], &truth),
        // Not read by the track, but what it is scored against.
        track(&[], &truth),
    ];
    // The same path for the poses and the rendered frames.
    let both = dir.join("both");
    let same = track(&["--render", both.to_str().unwrap()], &both);
    assert!(!same.status.success());
    let err = String::from_utf8_lossy(&same.stderr);
    assert!(err.contains("--out and --render both name"), "{err}");
    assert!(!both.exists());
    #[cfg(unix)]
    {
        let link = dir.join("link.csv");
        std::os::unix::fs::symlink(&frame, &link).unwrap();
        refused.push(track(&[], &link));
    }
    let f = frame.to_str().unwrap();
    refused.push(pftrack(&["sift", f, "--out", f]));
    for out in refused {
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.lines().count() == 1
                && (err.contains("overwritten") || err.contains("read as a frame")),
            "{err}"
        );
    }
    for (p, bytes) in [&frame, &init, &truth].iter().zip(&keep) {
        assert_eq!(&std::fs::read(p).unwrap(), bytes, "{}", p.display());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A render whose frames cannot all be moved in (a folder stands where frame 2 goes) fails
/// before anything is moved or the poses are written; a render folder the failed run made
/// is removed.
#[test]
fn cli_a_render_that_cannot_be_moved_in_changes_nothing() {
    let dir = synth_dir("render-blocked", 3, "64x48");
    let d = dir.to_str().unwrap();
    let render = dir.join("render");
    std::fs::create_dir_all(render.join("00002.png")).unwrap();
    // As an earlier render left it, with a frame edited since.
    std::fs::write(render.join(".pftrack-render"), b"").unwrap();
    std::fs::write(render.join("00000.png"), b"the user's").unwrap();
    let csv = dir.join("poses.csv");
    let r = render.to_str().unwrap();
    let args = [
        "track",
        d,
        "--backend",
        "cpu",
        "--render",
        r,
        "--out",
        csv.to_str().unwrap(),
    ];
    assert_one_line_error(&args, "00002.png is a folder", &csv);
    assert_eq!(
        names(&render),
        [".pftrack-render", "00000.png", "00002.png"]
    );
    assert_eq!(
        std::fs::read(render.join("00000.png")).unwrap(),
        b"the user's"
    );
    // A folder where the mark would go is refused before tracking.
    let marked = dir.join("marked");
    std::fs::create_dir_all(marked.join(".pftrack-render")).unwrap();
    let m = marked.to_str().unwrap();
    let args_m = ["track", d, "--backend", "cpu", "--render", m];
    assert_one_line_error(&args_m, ".pftrack-render is not a file", &csv);
    assert_eq!(names(&marked), [".pftrack-render"]);
    // A render folder made by a run that fails is gone with it.
    let fresh = dir.join("fresh/render");
    std::fs::write(dir.join("frames/00002.png"), b"not a png").unwrap();
    let args = [
        "track",
        d,
        "--backend",
        "cpu",
        "--render",
        fresh.to_str().unwrap(),
    ];
    assert_one_line_error(&args, "00002.png", &csv);
    assert!(!fresh.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The pose CSV keeps the ellipse's orientation (`theta`, `theta0 + rz`): a start turned 30
/// degrees is row 0's theta, and a track started from that row (`--init-truth`), with a
/// roll given as well, starts from the same ellipse.
#[test]
fn cli_the_pose_csv_keeps_the_ellipse_orientation() {
    let dir = synth_dir("theta", 3, "64x48");
    let d = dir.to_str().unwrap();
    let first = dir.join("first.csv");
    let again = dir.join("again.csv");
    let track = |extra: &[&str], out: &Path| {
        let mut a = vec!["track", d, "--backend", "cpu", "--particles", "20", "-o"];
        a.push(out.to_str().unwrap());
        a.extend(extra);
        pftrack_ok(&a);
        read_pose_csv(out).unwrap()
    };
    let rows = track(
        &["--init-ellipse", "32,24,9,12,30", "--init-pose", "0,0,10"],
        &first,
    );
    let r0 = &rows[0];
    assert!((r0.theta.unwrap().to_degrees() - 30.0).abs() < 1e-6);
    assert!((r0.state.rz.to_degrees() - 10.0).abs() < 1e-6);
    let rows = track(&["--init-truth", first.to_str().unwrap()], &again);
    assert_eq!(rows[0].ellipse(), r0.ellipse());
    assert_eq!(rows[0].state, r0.state);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--out -` is standard output, as `-` is standard input for the input: no file named `-`.
#[test]
fn cli_out_dash_is_standard_output() {
    let dir = synth_dir("dash", 2, "64x48");
    let out = Command::new(env!("CARGO_BIN_EXE_pftrack"))
        .args([
            "track",
            ".",
            "--backend",
            "cpu",
            "--particles",
            "20",
            "--out",
            "-",
        ])
        .current_dir(&dir)
        .output()
        .expect("run pftrack");
    assert!(out.status.success(), "{out:?}");
    let csv = String::from_utf8_lossy(&out.stdout);
    assert!(
        csv.starts_with("frame,cx,cy,a,b,rx,ry,rz,score,lost,theta\n"),
        "{csv}"
    );
    assert_eq!(csv.lines().count(), 3);
    assert!(!dir.join("-").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs `pftrack track SEQ --backend cpu -o OUT EXTRA...`, checks that it succeeded, and
/// returns the poses written and what it said on standard error.
fn track_on_cpu(seq: &str, out: &Path, extra: &[&str]) -> (Vec<u8>, String) {
    let o = out.to_str().unwrap();
    let mut args = vec!["track", seq, "--backend", "cpu", "-o", o];
    args.extend_from_slice(extra);
    let said = pftrack_ok(&args).stderr;
    (
        std::fs::read(out).unwrap(),
        String::from_utf8_lossy(&said).into_owned(),
    )
}

/// `track --relief-sigma S` learns the object's relief over the keyframes' adjustments: on a
/// turning box the track differs from the default's, and is the one the settings file that
/// says the same gives; a σ out of its range is refused, and so is the flag beside
/// `--no-bundle`.
#[test]
fn cli_track_learns_the_relief_on_request() {
    let dir = tmp_dir("relief");
    let seq = dir.join("seq");
    let s = seq.to_str().unwrap();
    // The car turns from 45 % of the frames on: enough views for adjustments by the end.
    pftrack_ok(&["synth", s, "--scenario", "car", "--frames", "80"]);
    let run = |extra: &[&str], name: &str| track_on_cpu(s, &dir.join(name), extra);
    let (plain, plain_said) = run(&[], "plain.csv");
    let (learnt, said) = run(&["--relief-sigma", "1"], "learnt.csv");
    assert_ne!(plain, learnt);
    // The factor learnt is said: the box is flatter than the ellipsoid it is lifted on.
    let k: f64 = said
        .lines()
        .find_map(|l| l.strip_prefix("pftrack: relief learnt: "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no relief said: {said}"));
    assert!(k > 0.2 && k < 0.9, "relief {k}: {said}");
    assert!(!plain_said.contains("relief learnt"), "{plain_said}");
    let file = dir.join("relief.json");
    std::fs::write(&file, r#"{"bundle": {"params": {"relief_sigma": 1.0}}}"#).unwrap();
    let (from_file, _) = run(&["--config", file.to_str().unwrap()], "file.csv");
    assert_eq!(learnt, from_file);
    let unwritten = dir.join("none.csv");
    let u = unwritten.to_str().unwrap();
    for bad in ["0", "-1", "inf", "NaN", "1e-200", "1e200"] {
        assert_one_line_error(
            &["track", s, "--relief-sigma", bad, "-o", u],
            "--relief-sigma must lie from 0.001 to 1000",
            &unwritten,
        );
    }
    let out = pftrack(&["track", s, "--relief-sigma", "1", "--no-bundle", "-o", u]);
    assert_eq!(out.status.code(), Some(2));
    assert!(!unwritten.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `track --still-share S` proposes a share of the particles around the previous estimate:
/// the track differs from the default's (which `--still-share 0` gives exactly), is the one
/// the settings file that says the same gives, and a share outside [0, 1) is refused.
#[test]
fn cli_track_proposes_a_share_around_the_previous_estimate_on_request() {
    let dir = tmp_dir("still");
    let seq = dir.join("seq");
    let s = seq.to_str().unwrap();
    pftrack_ok(&["synth", s, "--scenario", "pan", "--frames", "12"]);
    let run = |extra: &[&str], name: &str| track_on_cpu(s, &dir.join(name), extra).0;
    let plain = run(&[], "plain.csv");
    assert_eq!(plain, run(&["--still-share", "0"], "zero.csv"));
    let still = run(&["--still-share", "0.2"], "still.csv");
    assert_ne!(plain, still);
    let file = dir.join("still.json");
    std::fs::write(&file, r#"{"filter": {"still_share": 0.2}}"#).unwrap();
    assert_eq!(
        still,
        run(&["--config", file.to_str().unwrap()], "file.csv")
    );
    let unwritten = dir.join("none.csv");
    let u = unwritten.to_str().unwrap();
    for bad in ["1", "-0.1", "inf", "NaN"] {
        assert_one_line_error(
            &["track", s, "--still-share", bad, "-o", u],
            "--still-share must lie in [0, 1)",
            &unwritten,
        );
    }
    let bad_file = dir.join("bad.json");
    std::fs::write(&bad_file, r#"{"filter": {"still_share": 1.5}}"#).unwrap();
    let out = pftrack(&["track", s, "--config", bad_file.to_str().unwrap(), "-o", u]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("still_share 1.5"), "{err}");
    assert!(!unwritten.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `track --config FILE` takes the tracker's settings from JSON: the same track as the flags
/// that say the same, a misspelt or out-of-range setting refused naming the file, and no
/// tuning flag beside it.
#[test]
fn cli_track_takes_its_settings_from_a_json_file() {
    let dir = tmp_dir("config");
    let seq = dir.join("seq");
    let s = seq.to_str().unwrap();
    pftrack_ok(&["synth", s, "--scenario", "roll", "--frames", "6"]);
    let file = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p.to_str().unwrap().to_string()
    };
    let csv = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let settings = file(
        "a.json",
        r#"{"seed": 3, "filter": {"particles": 60}, "bundle": null, "coast_rate": null}"#,
    );
    let (from_file, from_flags) = (csv("file.csv"), csv("flags.csv"));
    pftrack_ok(&[
        "track",
        s,
        "--backend",
        "cpu",
        "--config",
        &settings,
        "-o",
        &from_file,
    ]);
    pftrack_ok(&[
        "track",
        s,
        "--backend",
        "cpu",
        "--seed",
        "3",
        "--particles",
        "60",
        "--no-bundle",
        "--no-coast",
        "-o",
        &from_flags,
    ]);
    assert_eq!(
        std::fs::read(&from_file).unwrap(),
        std::fs::read(&from_flags).unwrap()
    );
    // A different seed from the file does change the track (the file is read).
    let other = file(
        "b.json",
        r#"{"seed": 4, "mode": "tpe", "filter": {"particles": 60}}"#,
    );
    let out = pftrack_ok(&[
        "track",
        s,
        "--backend",
        "cpu",
        "--config",
        &other,
        "-o",
        &from_file,
    ]);
    // The summary names the file's mode (it named the flag's default, sea).
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(said.contains("(tpe, camera hfov 50°)"), "{said}");
    assert_ne!(
        std::fs::read(&from_file).unwrap(),
        std::fs::read(&from_flags).unwrap()
    );
    let unwritten = dir.join("none.csv");
    let u = unwritten.to_str().unwrap();
    let misspelt = file("c.json", r#"{"sead": 3}"#);
    assert_one_line_error(
        &["track", s, "--config", &misspelt, "-o", u],
        "unknown field `sead`",
        &unwritten,
    );
    let bad = file("d.json", r#"{"filter": {"particles": 0}}"#);
    assert_one_line_error(
        &["track", s, "--config", &bad, "-o", u],
        "particles 0 must lie in 1..=",
        &unwritten,
    );
    // A key given twice is refused, not read as its last value (which hid the first's 0).
    let twice = file(
        "e.json",
        r#"{"filter": {"particles": 0, "particles": 300}}"#,
    );
    assert_one_line_error(
        &["track", s, "--config", &twice, "-o", u],
        "`particles` is given twice in one object at line 1 column",
        &unwritten,
    );
    let out = pftrack(&["track", s, "--config", &settings, "--seed", "2", "-o", u]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot be used with '--seed"));
    // `pftrack settings` prints every setting at its default: as a file, the flags' track.
    let all = pftrack_ok(&["settings"]);
    let all = file("all.json", &String::from_utf8(all.stdout).unwrap());
    let plain = csv("plain.csv");
    pftrack_ok(&[
        "track",
        s,
        "--backend",
        "cpu",
        "--config",
        &all,
        "-o",
        &from_file,
    ]);
    pftrack_ok(&["track", s, "--backend", "cpu", "-o", &plain]);
    assert_eq!(
        std::fs::read(&from_file).unwrap(),
        std::fs::read(&plain).unwrap()
    );
    // The file is an input: the poses cannot overwrite it.
    assert_one_line_error(
        &["track", s, "--config", &settings, "-o", &settings],
        "is an input",
        &unwritten,
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `track` warns, before tracking, that a y4m's frames are interlaced and its pixels 12:11,
/// naming the `--resize` that squares them; given that resize, only the fields are left to say.
#[test]
fn track_warns_of_interlaced_frames_and_non_square_pixels() {
    let d = tmp_dir("layout");
    std::fs::create_dir_all(&d).unwrap();
    let y4m = d.join("fields.y4m");
    let mut bytes = b"YUV4MPEG2 W64 H48 F25:1 It A12:11 Cmono\n".to_vec();
    for k in 0..3i32 {
        bytes.extend_from_slice(b"FRAME\n");
        for y in 0..48i32 {
            for x in 0..64i32 {
                let r2 = (x - 30 - k).pow(2) + (y - 24).pow(2);
                let texture = 16 + ((x * 7 + y * 13) % 50) as u8;
                bytes.push(if r2 < 100 { 200 - texture / 2 } else { texture });
            }
        }
    }
    std::fs::write(&y4m, bytes).unwrap();
    let (input, out) = (y4m.to_str().unwrap(), d.join("poses.csv"));
    let args = [
        "track",
        input,
        "--backend",
        "cpu",
        "--init-ellipse",
        "30,24,10,10",
        "--out",
        out.to_str().unwrap(),
    ];
    let o = pftrack_ok(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    let warnings: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("pftrack: warning: "))
        .collect();
    assert_eq!(warnings.len(), 2, "{err}");
    assert!(warnings[0].contains("interlaced, top field first"), "{err}");
    assert!(warnings[1].contains("--resize 70x48"), "{err}");
    assert_eq!(
        std::fs::read_to_string(&out).unwrap().lines().count(),
        4,
        "a header and three frames"
    );

    // A bad start is the only line printed: the warnings come once the start is good.
    let mut bad = args.to_vec();
    bad[5] = "999,24,10,10";
    let o = pftrack(&bad);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("invalid start"), "{err}");

    let mut resized = args.to_vec();
    resized.extend(["--resize", "70x48"]);
    let o = pftrack_ok(&resized);
    let err = String::from_utf8_lossy(&o.stderr);
    let warnings: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("pftrack: warning: "))
        .collect();
    assert_eq!(warnings.len(), 1, "{err}");
    assert!(warnings[0].contains("interlaced"), "{err}");
    std::fs::remove_dir_all(&d).unwrap();
}

/// `sift` on an image whose scale space, with the upsampled first octave, would pass the 2 GB
/// budget refuses it in one line that names this command's flags (the library's advice
/// reworded), before allocating; a small `--region` of the same image runs.
#[test]
fn sift_on_too_large_an_image_names_its_flags() {
    let d = tmp_dir("sift-large");
    std::fs::create_dir_all(&d).unwrap();
    // 3600x2600 doubled: about 2.2 GB of scale space at the default three scales an octave.
    let big = d.join("big.png");
    image::GrayImage::from_pixel(3600, 2600, image::Luma([90]))
        .save(&big)
        .unwrap();
    let b = big.to_str().unwrap();
    let out = pftrack(&["sift", b]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("3600x2600 window with the upsampled first octave")
            && err.contains("use --no-upsample or --region"),
        "{err}"
    );
    assert!(!err.contains("detect without"), "{err}");
    let ok = pftrack_ok(&["sift", b, "--region", "100,100,200,150"]);
    assert!(String::from_utf8_lossy(&ok.stdout).contains("keypoints"));
    std::fs::remove_dir_all(&d).unwrap();
}

/// The `&str`s of `args`.
fn refs(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
}

/// A `synth` folder whose `init.txt` is gone still reads its `frames` folder, the start given
/// by a flag; and `--render -` is refused, since frames cannot go to standard output as the
/// poses can (`--out -`), rather than made into a folder called `-`.
#[test]
fn cli_track_reads_a_synth_folder_without_its_init_and_refuses_render_to_stdout() {
    let dir = synth_dir("no-init", 3, "64x48");
    std::fs::remove_file(dir.join("init.txt")).unwrap();
    let d = dir.to_str().unwrap();
    let track = |extra: &[&str]| -> Vec<String> {
        let mut a = vec!["track", d, "--init-box", "20,14,24,20", "--backend", "cpu"];
        a.extend(extra);
        a.into_iter().map(String::from).collect()
    };
    let out = pftrack_ok(&refs(&track(&["--out", "-"])));
    let rows = String::from_utf8_lossy(&out.stdout).lines().count();
    assert_eq!(rows, 1 + 3);
    let csv = dir.join("poses.csv");
    let args = track(&["--render", "-", "--out", csv.to_str().unwrap()]);
    assert_one_line_error(&refs(&args), "--render -", &csv);
    assert!(!Path::new("-").exists());
    // Its ground truth is guarded as it was with the init file there.
    let truth = dir.join("truth.csv");
    let before = std::fs::read(&truth).unwrap();
    let out = pftrack(&refs(&track(&["--out", truth.to_str().unwrap()])));
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("ground truth"));
    assert_eq!(std::fs::read(&truth).unwrap(), before);
    // So is it when its `frames` folder is read, with a start from a flag or from the
    // sequence's `init.txt` (a copy made here, as `synth` writes it): the truth had been
    // replaced by the track's poses.
    let frames = dir.join("frames");
    let f = frames.to_str().unwrap();
    let t = truth.to_str().unwrap();
    let init = dir.join("init.txt");
    std::fs::write(&init, "32,24,10,8\n").unwrap();
    for start in [
        ["--init-box", "20,14,24,20"],
        ["--init-file", init.to_str().unwrap()],
    ] {
        let args = [
            "track",
            f,
            start[0],
            start[1],
            "--backend",
            "cpu",
            "--out",
            t,
        ];
        let out = pftrack(&args);
        assert!(!out.status.success(), "{args:?}");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("ground truth"),
            "{args:?}"
        );
        assert_eq!(std::fs::read(&truth).unwrap(), before);
    }
    // Named as the folder read from inside it, `.`.
    let out = Command::new(env!("CARGO_BIN_EXE_pftrack"))
        .current_dir(&frames)
        .args([
            "track",
            ".",
            "--init-box",
            "20,14,24,20",
            "--backend",
            "cpu",
        ])
        .args(["--out", "../truth.csv"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("ground truth"));
    assert_eq!(std::fs::read(&truth).unwrap(), before);
    // Where there is no truth beside them, a `frames` folder and an `init.txt` are any
    // others: the file is written.
    std::fs::remove_file(&truth).unwrap();
    pftrack_ok(&[
        "track",
        f,
        "--init-file",
        init.to_str().unwrap(),
        "--backend",
        "cpu",
        "--out",
        t,
    ]);
    assert_eq!(read_pose_csv(&truth).unwrap().len(), 3);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An object too large for the frame's height (its size follows the width) is rendered whole
/// in the truth, and `synth` says that it reaches past the frame; one that fits is rendered
/// without a word.
#[test]
fn synth_warns_where_the_object_reaches_past_the_frame() {
    for (size, warned) in [("320x96", true), ("160x120", false)] {
        let dir = tmp_dir(&format!("synth-wide-{size}"));
        let out = pftrack_ok(&[
            "synth",
            dir.to_str().unwrap(),
            "--scenario",
            "nod",
            "--frames",
            "1",
            "--size",
            size,
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.contains("reaches past the"), warned, "{size}: {err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// Matches along a textured strip (keypoints nearly in a line) determine no turn about it:
/// `pose` refuses them as degenerate with every solver, where the solvers' own test (points
/// exactly in line) let them through and SEA printed a tilt of tens of degrees.
#[test]
fn pose_refuses_matches_along_a_line() {
    let dir = tmp_dir("pose-strip");
    std::fs::create_dir_all(&dir).unwrap();
    let strip = |shift: u32| {
        pftrack::image::RgbImage::from_fn(160, 120, |x, y| {
            let (sx, sy) = (x.wrapping_sub(shift), y);
            // Blocks of 3 px along the strip, dark or light by a hash of their index, every
            // third a pixel lower: keypoints nearly, not exactly, in line.
            let top = 58 + u32::from(sx / 3 % 3 == 0);
            if (50..110).contains(&sx) && (top..top + 3).contains(&sy) {
                let h = (sx / 3).wrapping_mul(2_654_435_761) >> 29;
                let v = if h % 2 == 0 { 30 } else { 230 };
                pftrack::image::Rgb([v, (h * 31) as u8, 255 - v])
            } else {
                pftrack::image::Rgb([128, 128, 128])
            }
        })
    };
    let (a, b) = (dir.join("a.png"), dir.join("b.png"));
    strip(0).save(&a).unwrap();
    strip(2).save(&b).unwrap();
    for solver in ["sea", "optimal", "lsm", "rls", "essential"] {
        let out = pftrack(&[
            "pose",
            a.to_str().unwrap(),
            b.to_str().unwrap(),
            "--ellipse",
            "80,59.5,40,30",
            "--reject",
            "none",
            "--solver",
            solver,
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        // Too few keypoints on the strip would be refused for that instead: the test would
        // then not test the line.
        assert!(
            !out.status.success() && err.contains("lie along a line"),
            "{solver}: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `pose --draw` draws at `track --render`'s scale (160x120 twice), the ellipse given in green
/// and the matches as red arrows from where they were to where they went.
#[test]
fn pose_draws_the_ellipse_and_the_matches_at_the_renders_scale() {
    let dir = synth_dir("pose-draw", 6, "160x120");
    let frame = |k: usize| dir.join(format!("frames/{k:05}.png"));
    let drawn = dir.join("drawn.png");
    // Frames 0 and 5 posed with the ellipse and options given; the drawing.
    let draw = |ellipse: &str, options: &[&str]| {
        let (a, b) = (frame(0), frame(5));
        let mut args = vec!["pose", a.to_str().unwrap(), b.to_str().unwrap()];
        args.extend(["--ellipse", ellipse]);
        args.extend(options);
        args.extend(["--draw", drawn.to_str().unwrap()]);
        pftrack_ok(&args);
        pftrack::image::open(&drawn).unwrap().to_rgb8()
    };
    let img = draw("79.5,59.5,18.5,24.7", &[]);
    assert_eq!(img.dimensions(), (320, 240));
    let count = |c: [u8; 3]| img.pixels().filter(|p| p.0 == c).count();
    // The ellipse's outline, two pixels wide, about 2 pi sqrt((a^2 + b^2) / 2) long at twice
    // the size: some 270 px of it, twice.
    assert!(count([40, 220, 40]) > 300, "{}", count([40, 220, 40]));
    // The green outline passes through the top of the ellipse, (79.5, 34.8) scaled.
    let top = (2.0 * 79.5 + 0.5) as u32;
    assert!(
        (65..72).any(|y| img.get_pixel(top, y).0 == [40, 220, 40]),
        "no outline at the top"
    );
    assert!(count([255, 40, 40]) > 20, "{}", count([255, 40, 40]));
    // The ellipse's angle is drawn: a long thin one upright (90 degrees) reaches above the
    // frame's middle by its long semi-axis, not by its short one.
    let img = draw("79.5,59.5,40,8,90", &["--reject", "none"]);
    let green_rows: Vec<u32> = (0..240)
        .filter(|&y| (0..320).any(|x| img.get_pixel(x, y).0 == [40, 220, 40]))
        .collect();
    let (top, bottom) = (green_rows[0], green_rows[green_rows.len() - 1]);
    // Upright: 2 * (59.5 - 40) + 0.5 = 39.5 at the top, 199.5 at the bottom.
    assert!(
        (37..=42).contains(&top) && (197..=202).contains(&bottom),
        "{top}..{bottom}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `track --start-frame N` tracks from frame N of the input: the same poses as the input cut
/// to begin there (the same frames, byte for byte), in rows that keep the input's numbers, on
/// standard output as with `--out`; its start is frame N's (`--init-truth` reads that row or
/// box; a synthetic folder's own init, frame 0's, is refused), the render is numbered from
/// `00000.png`, a start past the end is an error, and `eval --segment` scores the frames
/// from the track's first on.
#[test]
fn cli_start_frame_tracks_from_the_middle_of_the_input() {
    let dir = synth_dir("start-frame", 12, "64x48");
    let d = dir.to_str().unwrap();
    let truth = dir.join("truth.csv");
    let t = truth.to_str().unwrap();
    // Frames 5-11 alone, numbered from 0, with their truth.
    let cut = dir.join("cut");
    std::fs::create_dir(&cut).unwrap();
    for k in 5..12 {
        std::fs::copy(
            dir.join("frames").join(format!("{k:05}.png")),
            cut.join(format!("{:05}.png", k - 5)),
        )
        .unwrap();
    }
    let rows = read_pose_csv(&truth).unwrap();
    let cut_rows: Vec<_> = rows[5..]
        .iter()
        .map(|r| pftrack::io::PoseRecord {
            frame: r.frame - 5,
            ..r.clone()
        })
        .collect();
    let cut_truth = dir.join("cut-truth.csv");
    pftrack::io::write_pose_csv(&cut_truth, &cut_rows, false).unwrap();
    let (a, b) = (dir.join("a.csv"), dir.join("b.csv"));
    let render = dir.join("render");
    pftrack_ok(&[
        "track",
        d,
        "--start-frame",
        "5",
        "--init-truth",
        t,
        "--backend",
        "cpu",
        "--out",
        a.to_str().unwrap(),
        "--render",
        render.to_str().unwrap(),
    ]);
    pftrack_ok(&[
        "track",
        cut.to_str().unwrap(),
        "--init-truth",
        cut_truth.to_str().unwrap(),
        "--hfov",
        "50",
        "--backend",
        "cpu",
        "--out",
        b.to_str().unwrap(),
    ]);
    let (from_five, alone) = (read_pose_csv(&a).unwrap(), read_pose_csv(&b).unwrap());
    assert_eq!(from_five.len(), 7);
    for (k, (x, y)) in from_five.iter().zip(&alone).enumerate() {
        assert_eq!(x.frame, k + 5);
        assert_eq!(
            pftrack::io::PoseRecord {
                frame: k,
                ..x.clone()
            },
            *y
        );
    }
    // The start is frame 5's, pose included.
    assert!((from_five[0].state.rx - rows[5].state.rx).abs() < 1e-9);
    let mut drawn = names(&render);
    drawn.retain(|n| !n.starts_with('.'));
    let expected: Vec<String> = (0..7).map(|k| format!("{k:05}.png")).collect();
    assert_eq!(drawn, expected);
    // Standard output, streamed or not, holds the same rows.
    for extra in [None, Some("--stream")] {
        let mut args = vec!["track", d, "--start-frame", "5", "--init-truth", t];
        args.extend(["--backend", "cpu"]);
        args.extend(extra);
        let out = pftrack_ok(&args);
        assert_eq!(
            String::from_utf8_lossy(&out.stdout),
            std::fs::read_to_string(&a).unwrap()
        );
    }
    // `eval --segment` scores frames 5-11 alone; without it frames 0-4 are missing.
    let seg = pftrack_ok(&["eval", "--segment", t, a.to_str().unwrap(), "--json"]);
    let seg: serde_json::Value = serde_json::from_slice(&seg.stdout).unwrap();
    assert_eq!(seg["scored_from"], 5);
    assert_eq!(seg["truth_frames"], 7);
    assert_eq!(seg["missing"], 0);
    let whole = pftrack_ok(&["eval", t, a.to_str().unwrap(), "--json"]);
    let whole: serde_json::Value = serde_json::from_slice(&whole.stdout).unwrap();
    assert_eq!(whole["missing"], 5);
    assert_eq!(whole["angle_rmse_deg"], seg["angle_rmse_deg"]);

    // An OTB file's box of the start frame (its fourth line, frame 3), and one of no size.
    let boxes = dir.join("boxes.txt");
    let mut lines: Vec<String> = (0..12).map(|k| format!("{},20,12,10", 20 + k)).collect();
    lines[4] = "0,0,0,0".into();
    std::fs::write(&boxes, lines.join("\n")).unwrap();
    let bx = boxes.to_str().unwrap();
    let out = pftrack_ok(&["track", d, "--start-frame", "3", "--init-truth", bx]);
    let first = String::from_utf8_lossy(&out.stdout)
        .lines()
        .nth(1)
        .unwrap()
        .to_string();
    // OTB's 1-based 23,20 is 21.5,18.5 in the README's pixels: the centre 6 and 5 px on.
    assert!(
        first.starts_with("3,27.500000,23.500000,6.000000,5.000000,"),
        "{first}"
    );
    let c = dir.join("c.csv");
    let cc = c.to_str().unwrap();
    let own_init = dir.join("init.txt").to_str().unwrap().to_string();
    for (args, needle) in [
        (
            vec!["--start-frame", "4", "--init-truth", bx],
            "the box of frame 4 has no size (0 x 0): the target is not in the frame tracking \
             starts on",
        ),
        (
            vec!["--start-frame", "5"],
            "init.txt gives the start of frame 0; give the start of frame 5",
        ),
        (
            vec!["--start-frame", "5", "--init-file", &own_init],
            "init.txt gives the start of frame 0; give the start of frame 5",
        ),
        (
            vec!["--start-frame", "12", "--init-ellipse", "32,24,8,8"],
            "--start-frame 12: the input has only 12 frames (frames 0 to 11)",
        ),
        (
            vec!["--start-frame", "12", "--init-truth", t],
            "no row for frame 12, the frame tracking starts on (its 12 rows run from frame 0 to 11)",
        ),
        (vec!["--start-frame", "-1", "--init-truth", t], "-1"),
    ] {
        let mut all = vec!["track", d, "--backend", "cpu", "--out", cc];
        all.extend(args);
        assert_one_line_error(&all, needle, &c);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A video started late is passed over inside ffmpeg, which writes nothing meanwhile: a
/// signal sent to pftrack alone (`kill PID`) ends that decode too, where the closed pipe
/// would not have reached it until its first frame.
#[cfg(unix)]
#[test]
fn cli_a_signal_while_a_video_is_passed_over_ends_its_decode() {
    if !pftrack::frames::FfmpegTools::default().available() {
        eprintln!("skip: ffmpeg not on PATH");
        return;
    }
    let dir = tmp_dir("skip-signal");
    std::fs::create_dir_all(&dir).unwrap();
    let video = dir.join("long.mp4");
    let made = Command::new("ffmpeg")
        .args(["-v", "error", "-nostdin", "-y", "-f", "lavfi", "-i"])
        .arg("testsrc=size=320x240:rate=25")
        .args(["-frames:v", "4000", "-c:v", "mpeg4", "-q:v", "10"])
        .arg(&video)
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_pftrack"));
    cmd.args(["track", video.to_str().unwrap(), "--start-frame", "3999"])
        .args(["--init-ellipse", "160,120,30,30", "--backend", "cpu"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let child = spawn_with_default_signals(&mut cmd, false);
    // The decode passing over the frames: a child of pftrack's with the select filter.
    let decode = || -> Option<u32> {
        std::fs::read_dir("/proc").ok()?.flatten().find_map(|e| {
            let pid: u32 = e.file_name().to_str()?.parse().ok()?;
            let stat = std::fs::read_to_string(e.path().join("stat")).ok()?;
            let ppid: u32 = stat
                .rsplit(')')
                .next()?
                .split_whitespace()
                .nth(1)?
                .parse()
                .ok()?;
            let cmdline = std::fs::read(e.path().join("cmdline")).ok()?;
            (ppid == child.id() && String::from_utf8_lossy(&cmdline).contains("select=gte"))
                .then_some(pid)
        })
    };
    let t0 = std::time::Instant::now();
    let pid = loop {
        if let Some(pid) = decode() {
            break pid;
        }
        assert!(t0.elapsed().as_secs() < 60, "no decode started");
        std::thread::sleep(std::time::Duration::from_millis(5));
    };
    send(&child, libc::SIGTERM);
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("pftrack: interrupted"), "{err}");
    // Killed and reaped by pftrack: no such process left, running or a zombie.
    std::thread::sleep(std::time::Duration::from_millis(100));
    let left = std::fs::read_to_string(format!("/proc/{pid}/cmdline")).unwrap_or_default();
    assert!(
        !left.contains("select=gte"),
        "the decode {pid} is still running"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `track` ends by saying how its own signals went: the mean confidence, and the frames it
/// flagged lost as runs of the input's frame numbers (so a user sees where to look without
/// reading the CSV). On a turning head it never loses the target; on frames of one flat grey
/// it flags the frames from its start on, numbered as the input numbers them.
#[test]
fn cli_track_says_its_mean_confidence_and_where_it_was_lost() {
    let dir = tmp_dir("signals");
    let seq = dir.join("seq");
    let s = seq.to_str().unwrap();
    pftrack_ok(&["synth", s, "--scenario", "nod", "--frames", "8"]);
    let (poses, said) = track_on_cpu(s, &dir.join("nod.csv"), &[]);
    let rows = read_pose_csv(&dir.join("nod.csv")).unwrap();
    assert!(
        rows.iter().all(|r| r.lost == Some(false)),
        "{}",
        String::from_utf8_lossy(&poses)
    );
    let mean = rows.iter().map(|r| r.score.unwrap()).sum::<f64>() / rows.len() as f64;
    let lines: Vec<&str> = said.lines().collect();
    let at = lines
        .iter()
        .position(|l| l.starts_with("pftrack: tracked 8 frames"))
        .unwrap_or_else(|| panic!("{said}"));
    assert_eq!(
        lines[at + 1],
        format!("pftrack: mean confidence {mean:.2}; never flagged lost")
    );
    // Flat grey frames, tracked from frame 2 of 12.
    let flat = dir.join("flat");
    std::fs::create_dir_all(&flat).unwrap();
    for k in 0..12 {
        image::RgbImage::from_pixel(64, 48, image::Rgb([128, 128, 128]))
            .save(flat.join(format!("{k:03}.png")))
            .unwrap();
    }
    let out = dir.join("flat.csv");
    let start = ["--init-box", "20,12,24,24", "--start-frame", "2"];
    let (_, said) = track_on_cpu(flat.to_str().unwrap(), &out, &start);
    let rows = read_pose_csv(&out).unwrap();
    let lost: Vec<usize> = rows
        .iter()
        .filter(|r| r.lost == Some(true))
        .map(|r| r.frame)
        .collect();
    assert!(!lost.is_empty() && lost.last() == Some(&11), "{lost:?}");
    // One run to the end, as the rows flag it.
    assert!(lost.windows(2).all(|w| w[1] == w[0] + 1), "{lost:?}");
    let line = said
        .lines()
        .find(|l| l.starts_with("pftrack: mean confidence "))
        .unwrap_or_else(|| panic!("{said}"));
    assert!(
        line.ends_with(&format!(
            "; flagged lost on {} frames: {}-11",
            lost.len(),
            lost[0]
        )),
        "{line}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
