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
pub use partial::{MadeDirs, Partial, PartialKind, StagingDir, Stopper, remove_partial_outputs};
pub use pose_csv::{
    PoseCsvWriter, PoseRecord, format_pose_csv, format_pose_row, pose_csv_header, read_pose_csv,
    write_pose_csv,
};

/// The largest text file [`read_text`] reads (256 MiB: a pose CSV of about two million
/// frames), so that a path to an endless stream (`/dev/zero`) or a wrong, huge file ends in an
/// error instead of filling the memory.
pub(crate) const MAX_TEXT_BYTES: u64 = 256 << 20;

/// Reads a text file whole, without the UTF-8 byte-order mark some editors put first (it
/// would otherwise cling to the first field: `'\u{feff}39.5' is not a number`). A file over
/// [`MAX_TEXT_BYTES`] is an error.
pub(crate) fn read_text(path: &std::path::Path) -> std::io::Result<String> {
    read_text_limited(path, MAX_TEXT_BYTES)
}

/// [`read_text`] with its bound given.
fn read_text_limited(path: &std::path::Path, limit: u64) -> std::io::Result<String> {
    use std::io::Read;
    let mut text = String::new();
    std::fs::File::open(path)?
        .take(limit + 1)
        .read_to_string(&mut text)?;
    if text.len() as u64 > limit {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "longer than {} MiB, more than a text file of this kind holds",
                limit >> 20
            ),
        ));
    }
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

    /// An endless stream or an outsized file is an error, not a read that fills the memory.
    #[test]
    fn text_is_read_up_to_a_bound() {
        let dir = std::env::temp_dir().join(format!("pftrack-bound-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("t.txt");
        std::fs::write(&p, "x".repeat(1 << 20)).unwrap();
        assert_eq!(
            super::read_text_limited(&p, 1 << 20).unwrap().len(),
            1 << 20
        );
        let e = super::read_text_limited(&p, (1 << 20) - 1).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidData);
        #[cfg(unix)]
        {
            let e = super::read_text_limited(std::path::Path::new("/dev/zero"), 1 << 20);
            assert!(e.unwrap_err().to_string().contains("longer than"));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
