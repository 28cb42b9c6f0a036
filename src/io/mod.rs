//! The project's file formats (SPEC section 1): pose CSV files ([`pose_csv`]), OTB-style box
//! files ([`boxes`]), the `init.txt` written by `synth` ([`init`]), and files that appear only
//! once complete ([`atomic`]).

pub mod atomic;
pub mod boxes;
pub mod init;
pub mod partial;
pub mod pose_csv;

pub use atomic::AtomicFile;
pub use boxes::read_otb_boxes;
pub use init::{InitFile, read_init, write_init};
pub use partial::{Partial, PartialKind, remove_partial_outputs};
pub use pose_csv::{
    PoseCsvWriter, PoseRecord, format_pose_csv, format_pose_row, pose_csv_header, read_pose_csv,
    write_pose_csv,
};

/// Errors reading or writing the project's file formats.
#[derive(Debug, thiserror::Error)]
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
