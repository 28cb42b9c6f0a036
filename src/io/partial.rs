//! The outputs this process has in progress: partial files ([`super::AtomicFile`]) and staging
//! folders, registered while they exist so that an interrupted run can remove them
//! ([`remove_partial_outputs`]) before it exits, and what writes them on its own (a child
//! process, [`Stopper`]), which it stops first.
//!
//! Unwinding and `Drop` already remove a partial output on every error; a signal (Ctrl-C,
//! `kill`) ends a process without either. A program that wants no stray `.NAME.PID-N.partial` left by
//! an interrupt calls [`remove_partial_outputs`] when a signal arrives and then exits, as the
//! `pftrack` command line does: from a thread that waits for signals (`signal_hook::iterator`,
//! `ctrlc`), never inside an asynchronous signal handler, since it takes a lock, allocates and
//! removes files.
//!
//! Creating a partial output and committing it (the rename into place) happen under the
//! registry's lock, and [`remove_partial_outputs`] keeps the lock, so an interrupt sees every
//! output either still partial (and removes it) or already in place, never one half-created.

use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

/// What an interrupt removes for a registered path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PartialKind {
    /// A partial file.
    File,
    /// A staging folder and everything in it.
    Tree,
    /// A folder this run created, removed only when empty (once the others are gone).
    EmptyDir,
}

#[derive(Debug)]
struct Entry {
    id: u64,
    path: PathBuf,
    kind: PartialKind,
}

#[derive(Debug, Default)]
struct Registry {
    next_id: u64,
    entries: Vec<Entry>,
}

static REGISTRY: Mutex<Registry> = Mutex::new(Registry {
    next_id: 0,
    entries: Vec::new(),
});

/// The registry, whatever a panicking holder left it as (its entries stay valid).
fn registry() -> MutexGuard<'static, Registry> {
    REGISTRY.lock().unwrap_or_else(|e| e.into_inner())
}

/// A registered partial output; dropping it (or [`Partial::commit`]) forgets the path. It
/// removes nothing itself: its owner does, on commit or drop.
#[derive(Debug)]
pub struct Partial {
    id: u64,
}

impl Partial {
    /// Registers `path` and runs `create` (which makes it on disk) under the registry's lock;
    /// when `create` fails nothing stays registered.
    pub fn create<T>(
        path: &Path,
        kind: PartialKind,
        create: impl FnOnce() -> std::io::Result<T>,
    ) -> std::io::Result<(Self, T)> {
        let mut reg = registry();
        let made = create()?;
        let id = reg.next_id;
        reg.next_id += 1;
        reg.entries.push(Entry {
            id,
            path: path.to_path_buf(),
            kind,
        });
        Ok((Self { id }, made))
    }

    /// Runs `commit` (which moves the output into place) under the registry's lock and
    /// forgets the path, whether or not `commit` succeeds.
    pub fn commit<T>(self, commit: impl FnOnce() -> T) -> T {
        let mut reg = registry();
        let out = commit();
        reg.entries.retain(|e| e.id != self.id);
        out
    }
}

impl Drop for Partial {
    fn drop(&mut self) {
        registry().entries.retain(|e| e.id != self.id);
    }
}

/// The folders a run made for its outputs, outermost first, each registered
/// ([`PartialKind::EmptyDir`]) so that an interrupt removes it when nothing else is in it;
/// [`MadeDirs::remove_empty`] does the same after a failure, and [`MadeDirs::keep`] forgets
/// them once the output they hold is complete.
#[derive(Debug, Default)]
pub struct MadeDirs(Vec<(PathBuf, Partial)>);

impl MadeDirs {
    /// Makes `dir` and its missing parents one by one, as `create_dir_all` does, registering
    /// each one this call made (a folder that was there, or that another process makes at
    /// the same moment, is not this run's to remove). A `..` in the path is no folder to make.
    pub fn create_all(&mut self, dir: &Path) -> std::io::Result<()> {
        let mut missing: Vec<&Path> = dir
            .ancestors()
            .filter(|a| !a.as_os_str().is_empty())
            .take_while(|a| std::fs::symlink_metadata(a).is_err())
            .collect();
        missing.reverse();
        for d in missing {
            match Partial::create(d, PartialKind::EmptyDir, || std::fs::create_dir(d)) {
                Ok((p, ())) => self.0.push((d.to_path_buf(), p)),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && d.is_dir() => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Removes the folders made, innermost first, each only when empty.
    pub fn remove_empty(&mut self) {
        for (d, _) in self.0.drain(..).rev() {
            let _ = std::fs::remove_dir(d);
        }
    }

    /// Keeps the folders made: they now hold a complete output.
    pub fn keep(&mut self) {
        self.0.clear();
    }

    /// Whether this run made any folder.
    pub fn any(&self) -> bool {
        !self.0.is_empty()
    }
}

/// A hidden folder an output is built in before it moves into place: made (with the folders
/// it needs, [`MadeDirs`]) inside the folder the output goes to, so that the output moves in
/// by renaming, and registered so that an interrupt removes it. Dropped, it is removed, with
/// the folders made for it that are still empty; [`StagingDir::commit`] runs the move.
#[derive(Debug)]
pub struct StagingDir {
    path: PathBuf,
    /// Taken by [`StagingDir::commit`].
    registered: Option<Partial>,
    made: MadeDirs,
    /// The folder held open and locked while it is in use, so that another run's
    /// [`StagingDir::sweep_stale`] passes it by however long it has been idle.
    _lock: Option<std::fs::File>,
}

impl StagingDir {
    /// Makes `parent` as need be (and its missing parents) and a new folder
    /// `.PREFIX-PID-NANOS.partial` in it, a name no other run (another process with the same
    /// id in another container, say) has.
    pub fn create(parent: &Path, prefix: &str) -> std::io::Result<Self> {
        let mut made = MadeDirs::default();
        made.create_all(parent)?;
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let path = parent.join(format!(".{prefix}-{}-{nanos}.partial", std::process::id()));
        let mut s = Self {
            path,
            registered: None,
            made,
            _lock: None,
        };
        let (registered, ()) =
            Partial::create(&s.path, PartialKind::Tree, || std::fs::create_dir(&s.path))?;
        s.registered = Some(registered);
        // Where a folder cannot be opened or locked (not every system or file system), the
        // sweep's idle time alone protects it.
        s._lock = std::fs::File::open(&s.path)
            .ok()
            .filter(|f| f.try_lock().is_ok());
        Ok(s)
    }

    /// The staging folder.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Removes the staging folders `.PREFIX-*.partial` in `parent` untouched for `idle` or
    /// longer (neither the folder nor any file in it modified) and not in use, and returns how
    /// many it removed. A run killed outright (SIGKILL, out of memory) cannot remove its own,
    /// and each run's has a name of its own, so they stayed for good. A running one is spared:
    /// it holds a lock on its folder ([`std::fs::File::try_lock`]) for as long as it runs,
    /// however long it waits for a frame, and where locks do not work, it adds a file (a
    /// frame) or writes to one (a video growing) more often than any sensible `idle`. Errors
    /// (an unreadable folder, a folder removed meanwhile) are passed over: this is tidying.
    pub fn sweep_stale(parent: &Path, prefix: &str, idle: std::time::Duration) -> usize {
        let Ok(entries) = std::fs::read_dir(parent) else {
            return 0;
        };
        let head = format!(".{prefix}-");
        let mut removed = 0;
        for entry in entries.flatten() {
            let name = entry.file_name();
            let Some(name) = name.to_str() else { continue };
            if !(name.starts_with(&head) && name.ends_with(".partial")) {
                continue;
            }
            let idle_for = |m: std::fs::Metadata| m.modified().ok().and_then(|t| t.elapsed().ok());
            let Some(folder) = entry.metadata().ok().filter(std::fs::Metadata::is_dir) else {
                continue;
            };
            // The least time since the folder or anything in it changed.
            let newest = std::fs::read_dir(entry.path())
                .into_iter()
                .flatten()
                .flatten()
                .filter_map(|f| f.metadata().ok().and_then(idle_for))
                .chain(idle_for(folder))
                .min();
            // In use: its run holds the lock (released when the run ends, however it ends).
            let in_use = std::fs::File::open(entry.path())
                .is_ok_and(|f| matches!(f.try_lock(), Err(std::fs::TryLockError::WouldBlock)));
            let stale = !in_use && newest.is_some_and(|age| age >= idle);
            if stale && std::fs::remove_dir_all(entry.path()).is_ok() {
                removed += 1;
            }
        }
        removed
    }

    /// Runs `move_in` (which moves the output out of the staging folder into place) under the
    /// registry's lock, so that an interrupt finds all of it moved or none, and forgets the
    /// folder; on success the folders made for the output are kept.
    pub fn commit<T, E>(&mut self, move_in: impl FnOnce() -> Result<T, E>) -> Result<T, E> {
        let out = match self.registered.take() {
            Some(r) => r.commit(move_in),
            None => move_in(),
        }?;
        self.made.keep();
        Ok(out)
    }
}

impl Drop for StagingDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
        // Innermost first, and only when empty: a failed run leaves no folder it made.
        self.made.remove_empty();
    }
}

/// Something that writes a partial output on its own, such as a child process (ffmpeg writing
/// a video), registered so that an interrupt stops it before the outputs are removed:
/// [`remove_partial_outputs`] calls `stop` first. Dropping the `Stopper` forgets it.
pub struct Stopper {
    id: u64,
}

/// The registered stops, by id.
type Stops = Vec<(u64, Box<dyn Fn() + Send>)>;

static STOPS: Mutex<(u64, Stops)> = Mutex::new((0, Vec::new()));

fn stops() -> MutexGuard<'static, (u64, Stops)> {
    STOPS.lock().unwrap_or_else(|e| e.into_inner())
}

impl Stopper {
    /// Registers `stop`, which must return soon: kill a child (with a signal it cannot
    /// ignore) and reap it, not ask it to finish.
    pub fn register(stop: impl Fn() + Send + 'static) -> Self {
        let mut s = stops();
        let id = s.0;
        s.0 += 1;
        s.1.push((id, Box::new(stop)));
        Self { id }
    }
}

impl std::fmt::Debug for Stopper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Stopper").field("id", &self.id).finish()
    }
}

impl Drop for Stopper {
    fn drop(&mut self) {
        stops().1.retain(|(id, _)| *id != self.id);
    }
}

/// Removes every partial output of this process (files, then staging folders, then the
/// folders created for them if empty, newest first) and returns how many it removed; meant for
/// a thread that handles a signal by ending the process next (not for an asynchronous signal
/// handler itself: it takes a lock, allocates and removes files). The registry stays locked until the process ends, so
/// no output is created or committed after this returns, and any thread that tries waits for
/// ever: call it only on the way out, then end the process (never return to normal work).
pub fn remove_partial_outputs() -> usize {
    // What writes outputs of its own is stopped first, and stays unable to register more.
    let stopping = stops();
    for (_, stop) in &stopping.1 {
        stop();
    }
    std::mem::forget(stopping);
    let reg = registry();
    let mut removed = 0;
    for kind in [PartialKind::File, PartialKind::Tree, PartialKind::EmptyDir] {
        // Folders newest first: one made inside another is registered after it.
        let entries: Vec<&Entry> = match kind {
            PartialKind::EmptyDir => reg.entries.iter().rev().collect(),
            _ => reg.entries.iter().collect(),
        };
        for e in entries.into_iter().filter(|e| e.kind == kind) {
            let ok = match kind {
                PartialKind::File => std::fs::remove_file(&e.path).is_ok(),
                PartialKind::Tree => std::fs::remove_dir_all(&e.path).is_ok(),
                PartialKind::EmptyDir => std::fs::remove_dir(&e.path).is_ok(),
            };
            removed += usize::from(ok);
        }
    }
    // Held until the process exits: nothing new appears after the clean-up.
    std::mem::forget(reg);
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    fn registered(path: &Path) -> bool {
        registry().entries.iter().any(|e| e.path == path)
    }

    // Setting a folder's modification time through a handle opened on it is Unix's way.
    #[cfg(unix)]
    #[test]
    fn stale_staging_folders_are_swept_and_running_ones_spared() {
        use std::time::{Duration, SystemTime};
        let root = std::env::temp_dir().join(format!("pftrack-sweep-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let two_hours_ago = SystemTime::now() - Duration::from_secs(7200);
        let age = |p: &Path| {
            std::fs::File::open(p)
                .unwrap()
                .set_modified(two_hours_ago)
                .unwrap()
        };
        // A killed run's (old, with a frame in it), a running one's, another prefix's, an old
        // file of the pattern, and the user's own hidden folder.
        let killed = root.join(".pftrack-render-123-456.partial");
        std::fs::create_dir(&killed).unwrap();
        std::fs::write(killed.join("00000.png"), b"x").unwrap();
        age(&killed.join("00000.png"));
        age(&killed);
        let running = root.join(".pftrack-render-124-457.partial");
        std::fs::create_dir(&running).unwrap();
        // A video growing in its folder: the folder old, the file written now.
        let growing = root.join(".pftrack-render-125-458.partial");
        std::fs::create_dir(&growing).unwrap();
        std::fs::write(growing.join("video.mp4"), b"x").unwrap();
        age(&growing);
        let other = root.join(".other-1-2.partial");
        std::fs::create_dir(&other).unwrap();
        age(&other);
        let file = root.join(".pftrack-render-5-6.partial");
        std::fs::write(&file, b"x").unwrap();
        age(&file);
        let mine = root.join(".pftrack-render-notes");
        std::fs::create_dir(&mine).unwrap();
        age(&mine);
        // A run waiting for its first frame: its folder empty and old, but locked.
        let waiting = StagingDir::create(&root, "pftrack-render").unwrap();
        age(waiting.path());
        let idle = Duration::from_secs(3600);
        assert_eq!(StagingDir::sweep_stale(&root, "pftrack-render", idle), 1);
        assert!(waiting.path().exists());
        drop(waiting);
        assert!(!killed.exists());
        assert!(running.exists() && other.exists() && file.exists() && mine.exists());
        assert!(growing.exists());
        assert_eq!(
            StagingDir::sweep_stale(&root.join("none"), "pftrack-render", idle),
            0
        );
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn made_folders_are_registered_one_by_one_and_removed_innermost_first() {
        let root = std::env::temp_dir().join(format!("pftrack-made-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let mut made = MadeDirs::default();
        // `x/..` is not a folder to make (create_dir on it fails with "exists").
        made.create_all(&root.join("x/../a/b/c")).unwrap();
        assert!(root.join("a/b/c").is_dir());
        // Registered as named, through the `..`.
        for d in ["x", "x/../a", "x/../a/b", "x/../a/b/c"] {
            assert!(registered(&root.join(d)), "{d}");
        }
        // Already there: nothing more made.
        let mut again = MadeDirs::default();
        again.create_all(&root.join("a/b")).unwrap();
        assert!(!again.any());
        // A file the user put in `a` keeps `a`; the rest goes.
        std::fs::write(root.join("a/keep.txt"), "x").unwrap();
        made.remove_empty();
        assert!(!root.join("a/b").exists() && !root.join("x").exists());
        assert!(root.join("a/keep.txt").exists());
        assert!(!registered(&root.join("x/../a")));
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn registered_while_alive_and_forgotten_after() {
        let p = std::env::temp_dir().join(format!("pftrack-partial-{}", std::process::id()));
        let (g, ()) = Partial::create(&p, PartialKind::File, || Ok(())).unwrap();
        assert!(registered(&p));
        drop(g);
        assert!(!registered(&p));
        let (g, ()) = Partial::create(&p, PartialKind::File, || Ok(())).unwrap();
        assert_eq!(g.commit(|| 7), 7);
        assert!(!registered(&p));
        // A failed creation registers nothing.
        let e = Partial::create(&p, PartialKind::File, || {
            Err::<(), _>(std::io::Error::other("no"))
        });
        assert!(e.is_err());
        assert!(!registered(&p));
    }
}
