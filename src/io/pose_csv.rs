//! Pose CSV: `frame,cx,cy,a,b,rx,ry,rz` then optional extra columns (`score,lost,theta` from
//! the tracker: its confidence, its lost flag and the ellipse's orientation `theta0 + rz`).
//! Header required; `frame` counts from 0; angles in degrees in the file, radians in
//! [`PoseRecord::state`] and [`PoseRecord::theta`].

use std::io::Write;
use std::path::Path;

use super::{AtomicFile, FormatError, parse_f64};
use crate::geometry::{PoseState, deg, rad};

/// The required leading columns of a pose CSV.
pub const POSE_COLUMNS: [&str; 8] = ["frame", "cx", "cy", "a", "b", "rx", "ry", "rz"];

/// One row of a pose CSV.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PoseRecord {
    /// Frame index, from 0.
    pub frame: usize,
    /// The state, angles in radians.
    pub state: PoseState,
    /// The tracker's confidence in `[0, 1]`, when the file has a `score` column.
    pub score: Option<f64>,
    /// Whether the tracker declared the target lost, when the file has a `lost` column.
    pub lost: Option<bool>,
    /// The ellipse's orientation (radians), `theta0 + rz`, when the file has a `theta` column;
    /// without it the orientation is `rz` (`theta0` = 0, as in ground truth from `synth`).
    pub theta: Option<f64>,
}

impl PoseRecord {
    /// The row's ellipse: its orientation from the `theta` column, else `rz`.
    pub fn ellipse(&self) -> crate::geometry::Ellipse {
        let mut e = self.state.ellipse(0.0);
        if let Some(t) = self.theta {
            e.theta = t;
        }
        e
    }
}

/// Reads a pose CSV. Rows must have strictly increasing frame numbers; every value must be a
/// finite number; `a` and `b` positive.
pub fn read_pose_csv(path: &Path) -> Result<Vec<PoseRecord>, FormatError> {
    let text = super::read_text(path).map_err(|e| FormatError::io(path, e))?;
    parse_pose_csv(&text, path)
}

/// Parses the text of a pose CSV; `path` only names the source in errors.
pub fn parse_pose_csv(text: &str, path: &Path) -> Result<Vec<PoseRecord>, FormatError> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().ok_or_else(|| FormatError::Empty {
        path: path.display().to_string(),
    })?;
    let cols: Vec<String> = header
        .split(',')
        .map(|c| c.trim().to_ascii_lowercase())
        .collect();
    if cols.len() < POSE_COLUMNS.len() || cols[..POSE_COLUMNS.len()] != POSE_COLUMNS {
        return Err(FormatError::parse(
            path,
            1,
            format!(
                "header must begin with '{}', found '{}'",
                POSE_COLUMNS.join(","),
                header.trim()
            ),
        ));
    }
    let score_col = cols.iter().position(|c| c == "score");
    let lost_col = cols.iter().position(|c| c == "lost");
    let theta_col = cols.iter().position(|c| c == "theta");
    let mut out: Vec<PoseRecord> = Vec::new();
    for (i, line) in lines {
        let lineno = i + 1;
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != cols.len() {
            return Err(FormatError::parse(
                path,
                lineno,
                format!("expected {} fields, found {}", cols.len(), f.len()),
            ));
        }
        let frame: usize = f[0].parse().map_err(|_| {
            FormatError::parse(
                path,
                lineno,
                format!("frame: '{}' is not a frame number", f[0]),
            )
        })?;
        let mut v = [0.0; 7];
        for (k, slot) in v.iter_mut().enumerate() {
            *slot = parse_f64(f[k + 1], POSE_COLUMNS[k + 1])
                .map_err(|m| FormatError::parse(path, lineno, m))?;
        }
        if v[2] <= 0.0 || v[3] <= 0.0 {
            return Err(FormatError::parse(
                path,
                lineno,
                "semi-axes a and b must be positive",
            ));
        }
        if let Some(last) = out.last()
            && frame <= last.frame
        {
            return Err(FormatError::parse(
                path,
                lineno,
                format!("frame {frame} does not follow frame {}", last.frame),
            ));
        }
        let score = match score_col {
            Some(c) => {
                let score =
                    parse_f64(f[c], "score").map_err(|m| FormatError::parse(path, lineno, m))?;
                // A confidence, as the tracker writes it: out of [0, 1] it is not one, and a
                // mean of such would be reported as a mean confidence.
                if !(0.0..=1.0).contains(&score) {
                    return Err(FormatError::parse(
                        path,
                        lineno,
                        format!("score {score} is not a confidence in [0, 1]"),
                    ));
                }
                Some(score)
            }
            None => None,
        };
        let lost = match lost_col {
            Some(c) => Some(match f[c] {
                "1" | "true" => true,
                "0" | "false" => false,
                other => {
                    return Err(FormatError::parse(
                        path,
                        lineno,
                        format!("lost: '{other}' is not 0 or 1"),
                    ));
                }
            }),
            None => None,
        };
        let theta = match theta_col {
            Some(c) => Some(rad(
                parse_f64(f[c], "theta").map_err(|m| FormatError::parse(path, lineno, m))?
            )),
            None => None,
        };
        let state = PoseState {
            cx: v[0],
            cy: v[1],
            a: v[2],
            b: v[3],
            rx: rad(v[4]),
            ry: rad(v[5]),
            rz: rad(v[6]),
        };
        out.push(PoseRecord {
            frame,
            state,
            score,
            lost,
            theta,
        });
    }
    if out.is_empty() {
        return Err(FormatError::Empty {
            path: path.display().to_string(),
        });
    }
    Ok(out)
}

/// One record as a CSV row (no newline); `with_score` adds the tracker's `score,lost,theta`
/// columns. With [`pose_csv_header`], for writing rows to any stream as they come.
pub fn format_pose_row(r: &PoseRecord, with_score: bool) -> String {
    let s = &r.state;
    let mut row = r.frame.to_string();
    let values = [s.cx, s.cy, s.a, s.b, deg(s.rx), deg(s.ry), deg(s.rz)];
    for v in values {
        push_fixed6(&mut row, v);
    }
    if with_score {
        push_fixed6(&mut row, r.score.unwrap_or(0.0));
        row.push_str(if r.lost.unwrap_or(false) { ",1" } else { ",0" });
        push_fixed6(&mut row, deg(r.theta.unwrap_or(s.rz)));
    }
    row
}

/// Appends `,v` as [`fixed6`] writes it.
fn push_fixed6(row: &mut String, v: f64) {
    row.push(',');
    row.push_str(&fixed6(v));
}

/// `v` with six decimals, as the project's files write numbers; a value that rounds to zero
/// is written `0.000000`, never `-0.000000`.
pub(crate) fn fixed6(v: f64) -> String {
    let text = format!("{v:.6}");
    if text == "-0.000000" {
        "0.000000".to_string()
    } else {
        text
    }
}

/// Writes a pose CSV row by row; the file appears under its name only on
/// [`PoseCsvWriter::finish`] (see [`AtomicFile`]).
#[derive(Debug)]
pub struct PoseCsvWriter {
    file: AtomicFile,
    with_score: bool,
}

impl PoseCsvWriter {
    /// Starts a pose CSV; `with_score` adds the tracker's `score,lost,theta` columns.
    pub fn create(path: &Path, with_score: bool) -> Result<Self, FormatError> {
        let mut file = AtomicFile::create(path)?;
        writeln!(file, "{}", pose_csv_header(with_score)).map_err(|e| FormatError::io(path, e))?;
        Ok(Self { file, with_score })
    }

    /// Appends one record.
    pub fn write(&mut self, r: &PoseRecord) -> Result<(), FormatError> {
        let row = format_pose_row(r, self.with_score);
        writeln!(self.file, "{row}").map_err(|e| FormatError::io(self.file.path(), e))
    }

    /// Completes the file.
    pub fn finish(self) -> Result<(), FormatError> {
        self.file.commit()
    }
}

/// The header line (no newline) of a pose CSV; `with_score` adds the tracker's columns.
pub fn pose_csv_header(with_score: bool) -> String {
    let mut h = POSE_COLUMNS.join(",");
    if with_score {
        h.push_str(",score,lost,theta");
    }
    h
}

/// A whole pose CSV as text, header included (for standard output).
pub fn format_pose_csv(records: &[PoseRecord], with_score: bool) -> String {
    let mut s = pose_csv_header(with_score);
    s.push('\n');
    for r in records {
        s.push_str(&format_pose_row(r, with_score));
        s.push('\n');
    }
    s
}

/// Writes a whole pose CSV at once.
pub fn write_pose_csv(
    path: &Path,
    records: &[PoseRecord],
    with_score: bool,
) -> Result<(), FormatError> {
    let mut w = PoseCsvWriter::create(path, with_score)?;
    for r in records {
        w.write(r)?;
    }
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(frame: usize, rx: f64) -> PoseRecord {
        PoseRecord {
            frame,
            state: PoseState {
                cx: 10.5,
                cy: 20.25,
                a: 5.0,
                b: 6.0,
                rx,
                ry: -0.2,
                rz: 0.05,
            },
            score: Some(0.75),
            lost: Some(frame == 1),
            theta: Some(0.05 + 0.1 * frame as f64),
        }
    }

    #[test]
    fn round_trip_through_a_file() {
        let dir = std::env::temp_dir().join(format!("pftrack-posecsv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("poses.csv");
        let recs = vec![rec(0, 0.1), rec(1, 0.3), rec(5, -1.0)];
        write_pose_csv(&p, &recs, true).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.starts_with("frame,cx,cy,a,b,rx,ry,rz,score,lost,theta\n"));
        assert_eq!(text, format_pose_csv(&recs, true));
        // Row by row to a stream, as an application might write them.
        let mut streamed = Vec::new();
        writeln!(streamed, "{}", pose_csv_header(true)).unwrap();
        for r in &recs {
            writeln!(streamed, "{}", format_pose_row(r, true)).unwrap();
        }
        assert_eq!(String::from_utf8(streamed).unwrap(), text);
        let back = read_pose_csv(&p).unwrap();
        assert_eq!(back.len(), 3);
        for (a, b) in recs.iter().zip(&back) {
            assert_eq!(a.frame, b.frame);
            assert_eq!(a.lost, b.lost);
            assert!((a.theta.unwrap() - b.theta.unwrap()).abs() < 1e-6);
            assert!((a.ellipse().theta - b.ellipse().theta).abs() < 1e-6);
            let (x, y) = (a.state.to_array(), b.state.to_array());
            for k in 0..7 {
                assert!((x[k] - y[k]).abs() < 1e-6, "{k}: {} vs {}", x[k], y[k]);
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn rows_have_six_decimals_and_no_negative_zero() {
        let mut r = rec(2, -1e-9);
        r.state.ry = -0.0;
        r.state.rz = -4e-7f64.to_radians();
        r.state.cx = -0.0000004;
        r.theta = Some(-1e-12);
        assert_eq!(
            format_pose_row(&r, true),
            "2,0.000000,20.250000,5.000000,6.000000,0.000000,0.000000,0.000000,0.750000,0,0.000000"
        );
        // A negative value that rounds to a non-zero one keeps its sign.
        r.state.cx = -0.0000006;
        assert!(format_pose_row(&r, false).starts_with("2,-0.000001,"));
    }

    #[test]
    fn degrees_in_the_file() {
        let recs = parse_pose_csv(
            "frame,cx,cy,a,b,rx,ry,rz\n0,1,2,3,4,90,0,-45\n",
            Path::new("t"),
        )
        .unwrap();
        assert!((recs[0].state.rx - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((recs[0].state.rz + std::f64::consts::FRAC_PI_4).abs() < 1e-12);
        assert_eq!(recs[0].score, None);
    }

    #[test]
    fn malformed_files_are_errors() {
        let p = Path::new("t.csv");
        let bad = [
            "",
            "x,y\n0,1\n",
            "frame,cx,cy,a,b,rx,ry,rz\n",
            "frame,cx,cy,a,b,rx,ry,rz\n0,1,2,3,4,5,6\n",
            "frame,cx,cy,a,b,rx,ry,rz\n0,1,2,3,4,5,6,nan\n",
            "frame,cx,cy,a,b,rx,ry,rz\n0,1,2,0,4,5,6,7\n",
            "frame,cx,cy,a,b,rx,ry,rz\n1,1,2,3,4,5,6,7\n1,1,2,3,4,5,6,7\n",
            "frame,cx,cy,a,b,rx,ry,rz\n-1,1,2,3,4,5,6,7\n",
            "frame,cx,cy,a,b,rx,ry,rz,lost\n0,1,2,3,4,5,6,7,maybe\n",
            "frame,cx,cy,a,b,rx,ry,rz,score\n0,1,2,3,4,5,6,7,5\n",
            "frame,cx,cy,a,b,rx,ry,rz,score\n0,1,2,3,4,5,6,7,-0.01\n",
        ];
        for text in bad {
            assert!(parse_pose_csv(text, p).is_err(), "accepted: {text:?}");
        }
        let edges = "frame,cx,cy,a,b,rx,ry,rz,score\n0,1,2,3,4,5,6,7,0\n1,1,2,3,4,5,6,7,1\n";
        let r = parse_pose_csv(edges, p).unwrap();
        assert_eq!((r[0].score, r[1].score), (Some(0.0), Some(1.0)));
    }
}
