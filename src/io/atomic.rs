//! Files that appear under their name only once complete: written to `NAME.partial` beside
//! the target and renamed on [`AtomicFile::commit`]; dropped without a commit, the partial
//! file is removed. A crash or an error never leaves a truncated file that looks finished.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::FormatError;

/// A buffered file that becomes visible under its final name only on [`AtomicFile::commit`].
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    partial: PathBuf,
    writer: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Creates `path.partial` for writing.
    pub fn create(path: &Path) -> Result<Self, FormatError> {
        let mut name = path.file_name().unwrap_or_default().to_os_string();
        name.push(".partial");
        let partial = path.with_file_name(name);
        let file = File::create(&partial).map_err(|e| FormatError::io(&partial, e))?;
        Ok(Self {
            target: path.to_path_buf(),
            partial,
            writer: Some(BufWriter::new(file)),
        })
    }

    /// The final path.
    pub fn path(&self) -> &Path {
        &self.target
    }

    /// Flushes, syncs and renames the file to its final name.
    pub fn commit(mut self) -> Result<(), FormatError> {
        if let Some(w) = self.writer.take() {
            let file = w
                .into_inner()
                .map_err(|e| FormatError::io(&self.partial, e.into_error()))?;
            file.sync_all()
                .map_err(|e| FormatError::io(&self.partial, e))?;
        }
        std::fs::rename(&self.partial, &self.target).map_err(|e| FormatError::io(&self.target, e))
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self.writer.as_mut() {
            Some(w) => w.write(buf),
            None => Err(std::io::Error::other("file already committed")),
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        match self.writer.as_mut() {
            Some(w) => w.flush(),
            None => Ok(()),
        }
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.writer.take().is_some() {
            let _ = std::fs::remove_file(&self.partial);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn appears_only_on_commit() {
        let dir = std::env::temp_dir().join(format!("pftrack-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("out.csv");
        {
            let mut f = AtomicFile::create(&p).unwrap();
            writeln!(f, "half").unwrap();
            // dropped without commit
        }
        assert!(!p.exists());
        assert!(!dir.join("out.csv.partial").exists());
        let mut f = AtomicFile::create(&p).unwrap();
        writeln!(f, "whole").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "whole\n");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
