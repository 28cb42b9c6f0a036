//! Files that appear under their name only once complete: written to `.NAME.PID-N.partial`
//! beside the target (a name of this write's own, made new: two runs writing one output never
//! share it, and a link already there is not followed) and renamed on [`AtomicFile::commit`];
//! dropped without a commit, or when the commit fails, the partial file is removed. A crash or
//! an error never leaves a truncated file that looks finished, and never a stray partial file
//! beside it.
//!
//! What the target already is decides how it is written:
//! - one of the process's open descriptors (`/dev/stdout`, `/dev/stderr`, `/dev/fd/N`,
//!   `/proc/PID/fd/N`, or a link through one): written to in place and appended to, whatever
//!   it was opened on, so that `-o /dev/stdout >> log` appends to `log` as a shell means it
//!   to, never replacing the file behind the descriptor;
//! - nothing, or a regular file: written beside it and renamed over it, as above;
//! - a symbolic link: the file it points to is written (the link stays a link), by the same
//!   rules;
//! - a directory: refused before anything is written;
//! - anything else (a terminal, a pipe, a device): written to directly, since such a target
//!   cannot be replaced by a rename. A write error there (`/dev/full`) is reported as for any
//!   file.
//!
//! What goes to a target written in place (a descriptor, a pipe, a device) is held in memory
//! until [`AtomicFile::commit`] and written then, all of it: a run that fails part way
//! writes nothing there, as it leaves no file, where a buffer flushed as it filled would have
//! left the rows before the failure looking like a whole output (`-o /dev/stdout > f`).
//!
//! A regular file replaced keeps its permissions; being a new file, it no longer shares
//! the old one's hard links, nor its owner when another user's file is replaced.
//!
//! Every error names the target, never the partial file. The partial file is registered
//! while it exists ([`super::partial`]), so a signal handler can remove it too.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::FormatError;
use super::partial::{Partial, PartialKind};

/// A buffered file that becomes visible under its final name only on [`AtomicFile::commit`].
#[derive(Debug)]
pub struct AtomicFile {
    /// The name the caller gave (for messages).
    target: PathBuf,
    /// Where the data goes on commit: `None` when it is written in place (a stream).
    rename: Option<Rename>,
    /// `None` once committed.
    writer: Option<Sink>,
}

/// Where the bytes go until the commit.
#[derive(Debug)]
enum Sink {
    /// The partial file, buffered.
    Staged(BufWriter<File>),
    /// A target written in place, and everything written to it so far, held for the commit.
    Held { file: File, data: Vec<u8> },
}

impl Sink {
    /// Writes what is held (a target written in place) and flushes: the file, ready for a
    /// sync.
    fn finish(self) -> std::io::Result<File> {
        match self {
            Sink::Staged(w) => w.into_inner().map_err(|e| e.into_error()),
            Sink::Held { mut file, data } => {
                file.write_all(&data)?;
                file.flush()?;
                Ok(file)
            }
        }
    }
}

/// The partial file and the regular file it replaces.
#[derive(Debug)]
struct Rename {
    partial: PathBuf,
    to: PathBuf,
    /// The partial file's registration, for an interrupt to find it.
    registered: Partial,
}

impl AtomicFile {
    /// Writes straight into `file`, opened on `path`: nothing to rename at the commit.
    fn in_place(path: &Path, file: std::fs::File) -> Self {
        Self {
            target: path.to_path_buf(),
            rename: None,
            writer: Some(Sink::Held {
                file,
                data: Vec::new(),
            }),
        }
    }

    /// Opens `path` for writing as the module says: a partial file beside it (or beside the
    /// file it links to), or the target itself when it is a stream or device.
    pub fn create(path: &Path) -> Result<Self, FormatError> {
        let err = |e: std::io::Error| FormatError::io(path, e);
        if path.file_name().is_none() {
            return Err(err(std::io::Error::other("not a file name")));
        }
        // One of the process's descriptors: the file behind it is the caller's, opened by
        // the shell (`> f` or `>> f`), and is written where the descriptor points.
        if through_descriptor(path) {
            let file = std::fs::OpenOptions::new()
                .append(true)
                .open(path)
                .map_err(err)?;
            return Ok(Self::in_place(path, file));
        }
        // What the path names, through its links (the kernel's view: a link in /proc to a
        // pipe names the pipe).
        match std::fs::metadata(path) {
            Ok(m) if m.is_dir() => {
                return Err(err(std::io::Error::new(
                    std::io::ErrorKind::IsADirectory,
                    "is a directory",
                )));
            }
            Ok(m) if !m.is_file() => {
                // A stream or device: no partial file can be renamed over it.
                let file = std::fs::OpenOptions::new()
                    .write(true)
                    .truncate(true)
                    .open(path)
                    .map_err(err)?;
                return Ok(Self::in_place(path, file));
            }
            _ => {}
        }
        // A regular file or nothing yet: the partial file goes beside the file the links end
        // at (a dangling link: the file it would name).
        let resolved = resolve_links(path).map_err(err)?;
        Self::staged(path, partial_path(&resolved), resolved)
    }

    /// Opens a file that will replace `path` itself on commit, written meanwhile to
    /// `partial` (in the same folder): a link at `path` is replaced, not followed, and
    /// nothing is written through it (for a sequence folder's own files, where a stray link
    /// must not send the truth elsewhere).
    pub(crate) fn create_replacing(path: &Path, partial: PathBuf) -> Result<Self, FormatError> {
        Self::staged(path, partial, path.to_path_buf())
    }

    /// Writes to `partial` (registered for an interrupt to remove), renamed onto `to` on
    /// commit; `target` is the name messages give.
    fn staged(target: &Path, partial: PathBuf, to: PathBuf) -> Result<Self, FormatError> {
        // Made new: a file or a link already of that name is an error, never truncated or
        // followed.
        let (registered, file) = Partial::create(&partial, PartialKind::File, || {
            std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&partial)
        })
        .map_err(|e| FormatError::io(target, e))?;
        // A file replaced keeps its permissions (a private file must not come back readable
        // by all), set before anything is written.
        if let Ok(old) = std::fs::symlink_metadata(&to)
            && old.is_file()
        {
            file.set_permissions(old.permissions())
                .map_err(|e| FormatError::io(target, e))?;
        }
        Ok(Self {
            target: target.to_path_buf(),
            rename: Some(Rename {
                partial,
                to,
                registered,
            }),
            writer: Some(Sink::Staged(BufWriter::new(file))),
        })
    }

    /// The final path.
    pub fn path(&self) -> &Path {
        &self.target
    }

    /// Flushes, syncs and renames the file to its final name (a stream is flushed only). On
    /// an error the partial file is removed.
    pub fn commit(mut self) -> Result<(), FormatError> {
        let err = |e: std::io::Error| FormatError::io(&self.target, e);
        let Some(w) = self.writer.take() else {
            return Ok(());
        };
        let file = w.finish();
        let Some(r) = self.rename.take() else {
            return file.map(drop).map_err(err);
        };
        // Synced outside the registry's lock (writers on other threads sync at once); only
        // the rename, or the removal on an error, under it.
        let synced = file.and_then(|file| file.sync_all());
        let result = r.registered.commit(|| {
            let result = synced.and_then(|()| std::fs::rename(&r.partial, &r.to));
            if result.is_err() {
                let _ = std::fs::remove_file(&r.partial);
            }
            result
        });
        result.map_err(err)
    }

    /// Flushes and syncs the file without moving it into place, for a caller that moves it
    /// together with other outputs under one registration's lock ([`Prepared::rename_now`]
    /// inside a [`Partial::commit`]): then an interrupt finds all of them moved or none. On
    /// an error the partial file is removed.
    pub(crate) fn prepare(mut self) -> Result<Prepared, FormatError> {
        let err = |e: std::io::Error| FormatError::io(&self.target, e);
        let rename = self.rename.take();
        let Some(w) = self.writer.take() else {
            return Ok(Prepared {
                target: self.target.clone(),
                rename: None,
                renamed: false,
            });
        };
        let synced = w.finish().and_then(|file| match &rename {
            Some(_) => file.sync_all(),
            None => Ok(()),
        });
        if let Err(e) = synced {
            if let Some(r) = &rename {
                let _ = std::fs::remove_file(&r.partial);
            }
            return Err(err(e));
        }
        Ok(Prepared {
            target: self.target.clone(),
            rename,
            renamed: false,
        })
    }
}

/// A file written and synced, not yet under its name ([`AtomicFile::prepare`]); dropped
/// before [`Prepared::rename_now`], its partial file is removed. Drop it outside any
/// registration's commit: its own registration takes the registry's lock.
#[derive(Debug)]
pub(crate) struct Prepared {
    target: PathBuf,
    /// `None` for a stream written in place.
    rename: Option<Rename>,
    /// Moved into place by [`Prepared::rename_now`].
    renamed: bool,
}

impl Prepared {
    /// Renames the file into place, without taking the registry's lock: for use inside the
    /// commit of the registration that covers the whole move.
    pub(crate) fn rename_now(&mut self) -> Result<(), FormatError> {
        if let Some(r) = &self.rename {
            std::fs::rename(&r.partial, &r.to).map_err(|e| FormatError::io(&self.target, e))?;
        }
        // Nothing left to remove (the registration is forgotten on drop).
        self.renamed = true;
        Ok(())
    }
}

impl Drop for Prepared {
    fn drop(&mut self) {
        if let Some(r) = &self.rename
            && !self.renamed
        {
            let _ = std::fs::remove_file(&r.partial);
        }
    }
}

/// `.NAME.PID-N.partial` beside `path`: hidden, named after what it will become, and after
/// this process and a count of its partial files, so that no other write (another run of the
/// program, another thread) has the same.
fn partial_path(path: &Path) -> PathBuf {
    static COUNT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = COUNT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut name = std::ffi::OsString::from(".");
    name.push(path.file_name().unwrap_or_default());
    name.push(format!(".{}-{n}.partial", std::process::id()));
    path.with_file_name(name)
}

/// Whether `path`, or a link on the way to what it names, is one of the process's open
/// descriptors: `/dev/stdout`, `/dev/stderr`, `/dev/stdin`, an entry of `/dev/fd` or of a
/// `/proc/PID/fd` folder (each hop's folder resolved, so `/dev/fd/1` and relative spellings
/// count too).
pub(crate) fn through_descriptor(path: &Path) -> bool {
    let mut p = path.to_path_buf();
    for _ in 0..40 {
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        if let (Ok(dir), Some(name)) = (std::fs::canonicalize(dir), p.file_name()) {
            let comps: Vec<_> = dir.components().map(|c| c.as_os_str().to_owned()).collect();
            let is = |parts: &[&str]| {
                comps.len() == parts.len() + 1 && comps[1..].iter().zip(parts).all(|(c, p)| c == p)
            };
            let std_name = ["stdout", "stderr", "stdin"].iter().any(|n| name == *n);
            let proc_fd = comps.len() == 4 && comps[1] == "proc" && comps[3] == "fd";
            if (is(&["dev"]) && std_name) || is(&["dev", "fd"]) || proc_fd {
                return true;
            }
        }
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => match std::fs::read_link(&p) {
                Ok(to) => {
                    p = match p.parent() {
                        Some(dir) if to.is_relative() => dir.join(to),
                        _ => to,
                    };
                }
                Err(_) => return false,
            },
            _ => return false,
        }
    }
    false
}

/// `path` with its symbolic links followed, however many (`path` itself when it is none);
/// a link to nothing gives the path it names: where a writer through it puts the file. A
/// loop of links is an error.
pub fn resolve_links(path: &Path) -> std::io::Result<PathBuf> {
    let mut p = path.to_path_buf();
    // The kernel's own bound on a chain of links.
    for _ in 0..40 {
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let to = std::fs::read_link(&p)?;
                p = match p.parent() {
                    Some(dir) if to.is_relative() => dir.join(to),
                    _ => to,
                };
            }
            _ => return Ok(p),
        }
    }
    Err(std::io::Error::other("too many levels of symbolic links"))
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self.writer.as_mut() {
            Some(Sink::Staged(w)) => w.write(buf),
            Some(Sink::Held { data, .. }) => {
                data.extend_from_slice(buf);
                Ok(buf.len())
            }
            None => Err(std::io::Error::other("file already committed")),
        }
    }

    /// Flushes the partial file's buffer; what a target written in place holds stays held
    /// until the commit.
    fn flush(&mut self) -> std::io::Result<()> {
        match self.writer.as_mut() {
            Some(Sink::Staged(w)) => w.flush(),
            Some(Sink::Held { .. }) | None => Ok(()),
        }
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.writer.take().is_some()
            && let Some(r) = &self.rename
        {
            let _ = std::fs::remove_file(&r.partial);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("pftrack-atomic-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn entries(d: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn appears_only_on_commit() {
        let d = dir("commit");
        let p = d.join("out.csv");
        {
            let mut f = AtomicFile::create(&p).unwrap();
            writeln!(f, "half").unwrap();
            let names = entries(&d);
            assert_eq!(names.len(), 1, "{names:?}");
            assert!(
                names[0].starts_with(".out.csv.") && names[0].ends_with(".partial"),
                "{names:?}"
            );
            // dropped without commit
        }
        assert!(entries(&d).is_empty());
        let mut f = AtomicFile::create(&p).unwrap();
        writeln!(f, "whole").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "whole\n");
        assert_eq!(entries(&d), ["out.csv"]);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_replaced_file_keeps_its_permissions() {
        use std::os::unix::fs::PermissionsExt;
        let d = dir("mode");
        let p = d.join("mine.csv");
        std::fs::write(&p, "old\n").unwrap();
        for mode in [0o600, 0o640] {
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode)).unwrap();
            let mut f = AtomicFile::create(&p).unwrap();
            writeln!(f, "new").unwrap();
            f.commit().unwrap();
            let got = std::fs::metadata(&p).unwrap().permissions().mode() & 0o777;
            assert_eq!(got, mode, "{got:o}");
        }
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "new\n");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_directory_is_refused_before_anything_is_written() {
        let d = dir("isdir");
        std::fs::create_dir(d.join("out.csv")).unwrap();
        let e = AtomicFile::create(&d.join("out.csv"))
            .unwrap_err()
            .to_string();
        assert!(e.ends_with("out.csv: is a directory"), "{e}");
        assert_eq!(entries(&d), ["out.csv"]);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn errors_name_the_target_not_the_partial_file() {
        let d = dir("noparent");
        let p = d.join("missing/out.csv");
        let e = AtomicFile::create(&p).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}: ", p.display())), "{e}");
        assert!(!e.contains("partial"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_failed_rename_leaves_no_partial_file() {
        let d = dir("rename");
        let p = d.join("out.csv");
        let mut f = AtomicFile::create(&p).unwrap();
        writeln!(f, "whole").unwrap();
        // A directory appears where the file was to go, after it was opened.
        std::fs::create_dir(&p).unwrap();
        std::fs::write(p.join("keep"), b"x").unwrap();
        let e = f.commit().unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}: ", p.display())), "{e}");
        assert_eq!(entries(&d), ["out.csv"]);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_link_is_written_through_and_stays_a_link() {
        let d = dir("link");
        std::fs::write(d.join("real.csv"), b"old\n").unwrap();
        std::os::unix::fs::symlink("real.csv", d.join("link.csv")).unwrap();
        let mut f = AtomicFile::create(&d.join("link.csv")).unwrap();
        writeln!(f, "new").unwrap();
        f.commit().unwrap();
        assert!(
            std::fs::symlink_metadata(d.join("link.csv"))
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(
            std::fs::read_to_string(d.join("real.csv")).unwrap(),
            "new\n"
        );
        // A dangling link: the file it names is created.
        std::os::unix::fs::symlink("made.csv", d.join("dangling.csv")).unwrap();
        let mut f = AtomicFile::create(&d.join("dangling.csv")).unwrap();
        writeln!(f, "made").unwrap();
        f.commit().unwrap();
        assert_eq!(
            std::fs::read_to_string(d.join("made.csv")).unwrap(),
            "made\n"
        );
        assert_eq!(
            entries(&d),
            ["dangling.csv", "link.csv", "made.csv", "real.csv"]
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn two_writes_of_one_target_do_not_share_a_partial_file() {
        let d = dir("two");
        let p = d.join("out.csv");
        let mut a = AtomicFile::create(&p).unwrap();
        let mut b = AtomicFile::create(&p).unwrap();
        assert_eq!(entries(&d).len(), 2, "{:?}", entries(&d));
        writeln!(a, "a1").unwrap();
        writeln!(b, "b1").unwrap();
        a.flush().unwrap();
        writeln!(b, "b2").unwrap();
        writeln!(a, "a2").unwrap();
        a.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "a1\na2\n");
        b.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "b1\nb2\n");
        assert_eq!(entries(&d), ["out.csv"]);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_descriptor_is_appended_to_not_replaced() {
        use std::os::fd::AsRawFd;
        use std::os::unix::fs::MetadataExt;
        let d = dir("fd");
        let log = d.join("log.csv");
        std::fs::write(&log, "before\n").unwrap();
        let ino = std::fs::metadata(&log).unwrap().ino();
        // As a shell's `3>> log.csv` would hold it.
        let held = std::fs::OpenOptions::new().append(true).open(&log).unwrap();
        let fd = held.as_raw_fd();
        for path in [format!("/dev/fd/{fd}"), format!("/proc/self/fd/{fd}")] {
            assert!(through_descriptor(Path::new(&path)), "{path}");
            let mut f = AtomicFile::create(Path::new(&path)).unwrap();
            writeln!(f, "{path}").unwrap();
            f.commit().unwrap();
        }
        drop(held);
        assert_eq!(
            std::fs::read_to_string(&log).unwrap(),
            format!("before\n/dev/fd/{fd}\n/proc/self/fd/{fd}\n")
        );
        // The same file, not one renamed over it, and nothing left beside it.
        assert_eq!(std::fs::metadata(&log).unwrap().ino(), ino);
        assert_eq!(entries(&d), ["log.csv"]);
        // The standard streams by name, a link to one, and ordinary paths.
        assert!(through_descriptor(Path::new("/dev/stdout")));
        assert!(through_descriptor(Path::new("/dev/stderr")));
        let link = d.join("to-stdout");
        std::os::unix::fs::symlink("/dev/stdout", &link).unwrap();
        assert!(through_descriptor(&link));
        assert!(!through_descriptor(&log));
        assert!(!through_descriptor(&d.join("new.csv")));
        assert!(!through_descriptor(Path::new("/dev/null")));
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// A target written in place (here a file behind one of the process's descriptors) gets
    /// nothing from a write that is dropped uncommitted, however much was written, and all of
    /// it, appended, on the commit.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_stream_gets_nothing_from_a_write_that_fails() {
        use std::os::fd::AsRawFd;
        let d = dir("held");
        let log = d.join("log.csv");
        std::fs::write(&log, "before\n").unwrap();
        let behind = std::fs::OpenOptions::new().append(true).open(&log).unwrap();
        let via = PathBuf::from(format!("/proc/self/fd/{}", behind.as_raw_fd()));
        {
            let mut f = AtomicFile::create(&via).unwrap();
            // More than any write buffer holds.
            for _ in 0..10_000 {
                writeln!(f, "a row of a run that then fails").unwrap();
            }
            f.flush().unwrap();
            assert_eq!(std::fs::read_to_string(&log).unwrap(), "before\n");
        }
        assert_eq!(std::fs::read_to_string(&log).unwrap(), "before\n");
        let mut f = AtomicFile::create(&via).unwrap();
        writeln!(f, "whole").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&log).unwrap(), "before\nwhole\n");
        assert_eq!(entries(&d), ["log.csv"]);
        drop(behind);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_device_is_written_in_place_and_its_errors_reported() {
        // /dev/null takes the data and stays a device.
        let mut f = AtomicFile::create(Path::new("/dev/null")).unwrap();
        writeln!(f, "gone").unwrap();
        f.commit().unwrap();
        let m = std::fs::metadata("/dev/null").unwrap();
        assert!(!m.is_file() && !m.is_dir());
        // /dev/full refuses it, and the error names it.
        if Path::new("/dev/full").exists() {
            let mut f = AtomicFile::create(Path::new("/dev/full")).unwrap();
            let wrote = writeln!(f, "{}", "x".repeat(1 << 16));
            let e = match wrote {
                Err(e) => e.to_string(),
                Ok(()) => f.commit().unwrap_err().to_string(),
            };
            assert!(!e.is_empty());
            assert!(!std::fs::metadata("/dev/full").unwrap().is_file());
        }
    }
}
