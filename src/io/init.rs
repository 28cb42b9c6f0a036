//! `init.txt`: the initial ellipse of a sequence, one line `cx,cy,a,b` (pixels), optionally a
//! fifth value, the ellipse's orientation in degrees; optionally a line `hfov,DEG` after it,
//! the horizontal field of view of the camera that took the sequence (degrees), for the
//! tracker's perspective model ([`crate::tracker::TrackerConfig::camera_hfov_deg`]). Blank
//! lines and lines starting with `#` are skipped. Written by `pftrack synth` (with its
//! camera), read by `pftrack track --init-file`.

use std::io::Write;
use std::path::Path;

use super::{AtomicFile, FormatError, parse_f64};
use crate::geometry::{Ellipse, deg, rad};

/// What an init file holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InitFile {
    /// The initial ellipse.
    pub ellipse: Ellipse,
    /// The camera's horizontal field of view (degrees, in `(0, 180)`), when the file gives it.
    pub hfov_deg: Option<f64>,
}

/// Reads an init file.
pub fn read_init(path: &Path) -> Result<InitFile, FormatError> {
    let text = super::read_text(path).map_err(|e| FormatError::io(path, e))?;
    parse_init(&text, path)
}

/// Parses `cx,cy,a,b[,angle_deg]` and an optional `hfov,DEG` line; `path` only names the
/// source in errors.
pub fn parse_init(text: &str, path: &Path) -> Result<InitFile, FormatError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let (n, line) = lines.next().ok_or_else(|| FormatError::Empty {
        path: path.display().to_string(),
    })?;
    let f: Vec<&str> = line.split(',').collect();
    if f.len() != 4 && f.len() != 5 {
        return Err(FormatError::parse(
            path,
            n,
            format!("expected cx,cy,a,b[,angle], found '{line}'"),
        ));
    }
    let mut v = [0.0; 5];
    for (k, s) in f.iter().enumerate() {
        v[k] = parse_f64(s, ["cx", "cy", "a", "b", "angle"][k])
            .map_err(|m| FormatError::parse(path, n, m))?;
    }
    if v[2] <= 0.0 || v[3] <= 0.0 {
        return Err(FormatError::parse(
            path,
            n,
            "semi-axes a and b must be positive",
        ));
    }
    let mut hfov_deg = None;
    for (n, line) in lines {
        let value = match line.split_once(',') {
            Some((key, value)) if key.trim() == "hfov" && hfov_deg.is_none() => value,
            _ => {
                return Err(FormatError::parse(
                    path,
                    n,
                    format!("expected one line hfov,DEG after the ellipse, found '{line}'"),
                ));
            }
        };
        let h = parse_f64(value, "hfov").map_err(|m| FormatError::parse(path, n, m))?;
        let range = crate::tracker::HFOV_RANGE_DEG;
        if !range.contains(&h) {
            return Err(FormatError::parse(
                path,
                n,
                format!(
                    "hfov must lie between {} and {} degrees, found {h}",
                    range.start(),
                    range.end()
                ),
            ));
        }
        hfov_deg = Some(h);
    }
    Ok(InitFile {
        ellipse: Ellipse {
            cx: v[0],
            cy: v[1],
            a: v[2],
            b: v[3],
            theta: rad(v[4]),
        },
        hfov_deg,
    })
}

/// Writes an init file (complete or absent, see [`AtomicFile`]): the ellipse, and the
/// camera's horizontal field of view when given.
pub fn write_init(path: &Path, init: &InitFile) -> Result<(), FormatError> {
    let mut f = AtomicFile::create(path)?;
    f.write_all(format_init(init).as_bytes())
        .map_err(|err| FormatError::io(path, err))?;
    f.commit()
}

/// An init file's text: `cx,cy,a,b[,angle_deg]` with six decimals (the angle only when not
/// 0), then `hfov,DEG` when the camera is given.
pub(crate) fn format_init(init: &InitFile) -> String {
    let e = &init.ellipse;
    let mut values = vec![e.cx, e.cy, e.a, e.b];
    if e.theta != 0.0 {
        values.push(deg(e.theta));
    }
    let text: Vec<String> = values.into_iter().map(super::pose_csv::fixed6).collect();
    let mut out = text.join(",");
    out.push('\n');
    if let Some(h) = init.hfov_deg {
        out.push_str(&format!("hfov,{}\n", super::pose_csv::fixed6(h)));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects() {
        let i = parse_init("64,48,20,25\n", Path::new("i")).unwrap();
        let e = i.ellipse;
        assert_eq!(
            (e.cx, e.cy, e.a, e.b, e.theta),
            (64.0, 48.0, 20.0, 25.0, 0.0)
        );
        assert_eq!(i.hfov_deg, None);
        let e = parse_init("# comment\n1,2,3,4,90", Path::new("i"))
            .unwrap()
            .ellipse;
        assert!((e.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        for bad in ["", "1,2,3", "1,2,3,-4", "1,2,3,4,5,6", "a,b,c,d"] {
            assert!(parse_init(bad, Path::new("i")).is_err(), "accepted {bad:?}");
        }
    }

    #[test]
    fn reads_the_camera_line_and_rejects_bad_ones() {
        let i = parse_init("1,2,3,4\n\n# camera\nhfov, 50\n", Path::new("i")).unwrap();
        assert_eq!(i.hfov_deg, Some(50.0));
        for (bad, what) in [
            ("1,2,3,4\nhfov,0", "between 0.1 and 179.9"),
            ("1,2,3,4\nhfov,180", "between 0.1 and 179.9"),
            ("1,2,3,4\nhfov,0.05", "between 0.1 and 179.9"),
            ("1,2,3,4\nhfov,nan", "hfov"),
            ("1,2,3,4\nhfov,50\nhfov,60", "one line hfov"),
            ("1,2,3,4\nfocal,50", "one line hfov"),
            ("1,2,3,4\n5,6,7,8", "one line hfov"),
        ] {
            let err = parse_init(bad, Path::new("i")).unwrap_err().to_string();
            assert!(err.contains(what), "{bad:?}: {err}");
        }
    }

    #[test]
    fn round_trips_through_a_file() {
        let dir = std::env::temp_dir().join(format!("pftrack-init-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("init.txt");
        for init in [
            InitFile {
                ellipse: Ellipse::new(79.5, 59.5, 18.52, 24.7),
                hfov_deg: Some(50.0),
            },
            InitFile {
                ellipse: Ellipse {
                    theta: rad(30.0),
                    ..Ellipse::new(10.25, 20.5, 3.0, 4.0)
                },
                hfov_deg: None,
            },
        ] {
            write_init(&path, &init).unwrap();
            let back = read_init(&path).unwrap();
            assert_eq!(back.hfov_deg, init.hfov_deg);
            let (a, b) = (back.ellipse, init.ellipse);
            for (x, y) in [
                (a.cx, b.cx),
                (a.cy, b.cy),
                (a.a, b.a),
                (a.b, b.b),
                (a.theta, b.theta),
            ] {
                assert!((x - y).abs() < 1e-6, "{x} != {y}");
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
