//! The project's file formats (SPEC section 1): pose CSV files ([`pose_csv`]), OTB-style box
//! files ([`boxes`]), the `init.txt` written by `synth` ([`init`]), and files that appear only
//! once complete ([`atomic`]), and the settings' angles in degrees ([`degrees`]).

pub mod atomic;
pub mod boxes;
pub mod degrees;
pub mod init;
pub mod partial;
pub mod pose_csv;

pub use atomic::AtomicFile;
pub use boxes::read_otb_boxes;
pub use init::{InitFile, read_init, write_init};
pub use partial::{MadeDirs, Partial, PartialKind, StagingDir, remove_partial_outputs};
pub use pose_csv::{
    PoseCsvWriter, PoseRecord, format_pose_csv, format_pose_row, pose_csv_header, read_pose_csv,
    write_pose_csv,
};

/// Reads a text file whole, without the UTF-8 byte-order mark some editors put first (it
/// would otherwise cling to the first field: `'\u{feff}39.5' is not a number`).
pub(crate) fn read_text(path: &std::path::Path) -> std::io::Result<String> {
    let mut text = std::fs::read_to_string(path)?;
    if text.starts_with('\u{feff}') {
        text.drain(..'\u{feff}'.len_utf8());
    }
    Ok(text)
}

/// Errors reading or writing the project's file formats.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FormatError {
    /// The file could not be opened, read or written.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: String,
        /// The cause (named so it is shown once, in this message, not again as a source).
        cause: std::io::Error,
    },
    /// The content is malformed.
    #[error("{path}:{line}: {msg}")]
    Parse {
        /// The file.
        path: String,
        /// 1-based line number (0 when not tied to a line).
        line: usize,
        /// What is wrong.
        msg: String,
    },
    /// The file holds no records.
    #[error("{path}: no records")]
    Empty {
        /// The file.
        path: String,
    },
}

impl FormatError {
    pub(crate) fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            cause: source,
        }
    }

    pub(crate) fn parse(path: &std::path::Path, line: usize, msg: impl Into<String>) -> Self {
        Self::Parse {
            path: path.display().to_string(),
            line,
            msg: msg.into(),
        }
    }
}

/// Parses a finite `f64`, or says which field was wrong.
pub(crate) fn parse_f64(s: &str, what: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{what}: '{}' is not a number", s.trim()))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{what}: '{}' is not finite", s.trim()))
    }
}

#[cfg(test)]
mod tests {
    /// A UTF-8 byte-order mark before the first field is read past in every text format
    /// (it was "'\u{feff}39.5' is not a number").
    #[test]
    fn a_byte_order_mark_is_read_past() {
        let dir = std::env::temp_dir().join(format!("pftrack-bom-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, text: &str| {
            let p = dir.join(name);
            std::fs::write(&p, format!("\u{feff}{text}")).unwrap();
            p
        };
        let init = super::read_init(&write("init.txt", "39.5,29.5,9,12\n")).unwrap();
        assert_eq!(init.ellipse.cx, 39.5);
        let poses = super::read_pose_csv(&write(
            "p.csv",
            "frame,cx,cy,a,b,rx,ry,rz\n0,1,2,3,4,0,0,0\n",
        ))
        .unwrap();
        assert_eq!(poses.len(), 1);
        let boxes = super::read_otb_boxes(&write("b.txt", "1,2,30,40\r\n")).unwrap();
        assert_eq!((boxes.len(), boxes[0].w), (1, 30.0));
        assert!(
            crate::eval::load_truth(&write(
                "t.csv",
                "frame,cx,cy,a,b,rx,ry,rz\n0,1,2,3,4,0,0,0\n"
            ))
            .is_ok()
        );
        std::fs::write(dir.join("plain.txt"), "39.5,29.5,9,12\n").unwrap();
        assert_eq!(
            super::read_text(&dir.join("plain.txt")).unwrap(),
            "39.5,29.5,9,12\n"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
