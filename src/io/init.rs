//! `init.txt`: the initial ellipse of a sequence, one line `cx,cy,a,b` (pixels), optionally a
//! fifth value, the ellipse's orientation in degrees. Written by `pftrack synth`, read by
//! `pftrack track --init-file`.

use std::io::Write;
use std::path::Path;

use super::{AtomicFile, FormatError, parse_f64};
use crate::geometry::{Ellipse, deg, rad};

/// Reads an init file.
pub fn read_init(path: &Path) -> Result<Ellipse, FormatError> {
    let text = std::fs::read_to_string(path).map_err(|e| FormatError::io(path, e))?;
    parse_init(&text, path)
}

/// Parses `cx,cy,a,b[,angle_deg]`; `path` only names the source in errors.
pub fn parse_init(text: &str, path: &Path) -> Result<Ellipse, FormatError> {
    let line = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .ok_or_else(|| FormatError::Empty {
            path: path.display().to_string(),
        })?;
    let f: Vec<&str> = line.split(',').collect();
    if f.len() != 4 && f.len() != 5 {
        return Err(FormatError::parse(
            path,
            1,
            format!("expected cx,cy,a,b[,angle], found '{line}'"),
        ));
    }
    let mut v = [0.0; 5];
    for (k, s) in f.iter().enumerate() {
        v[k] = parse_f64(s, ["cx", "cy", "a", "b", "angle"][k])
            .map_err(|m| FormatError::parse(path, 1, m))?;
    }
    if v[2] <= 0.0 || v[3] <= 0.0 {
        return Err(FormatError::parse(
            path,
            1,
            "semi-axes a and b must be positive",
        ));
    }
    Ok(Ellipse {
        cx: v[0],
        cy: v[1],
        a: v[2],
        b: v[3],
        theta: rad(v[4]),
    })
}

/// Writes an init file (complete or absent, see [`AtomicFile`]).
pub fn write_init(path: &Path, e: &Ellipse) -> Result<(), FormatError> {
    let mut f = AtomicFile::create(path)?;
    let line = if e.theta == 0.0 {
        format!("{:.6},{:.6},{:.6},{:.6}", e.cx, e.cy, e.a, e.b)
    } else {
        format!(
            "{:.6},{:.6},{:.6},{:.6},{:.6}",
            e.cx,
            e.cy,
            e.a,
            e.b,
            deg(e.theta)
        )
    };
    writeln!(f, "{line}").map_err(|err| FormatError::io(path, err))?;
    f.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects() {
        let e = parse_init("64,48,20,25\n", Path::new("i")).unwrap();
        assert_eq!(
            (e.cx, e.cy, e.a, e.b, e.theta),
            (64.0, 48.0, 20.0, 25.0, 0.0)
        );
        let e = parse_init("# comment\n1,2,3,4,90", Path::new("i")).unwrap();
        assert!((e.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        for bad in ["", "1,2,3", "1,2,3,-4", "1,2,3,4,5,6", "a,b,c,d"] {
            assert!(parse_init(bad, Path::new("i")).is_err(), "accepted {bad:?}");
        }
    }
}
