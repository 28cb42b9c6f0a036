//! The outputs this process has in progress: partial files ([`super::AtomicFile`]) and staging
//! folders, registered while they exist so that an interrupted run can remove them
//! ([`remove_partial_outputs`]) before it exits.
//!
//! Unwinding and `Drop` already remove a partial output on every error; a signal (Ctrl-C,
//! `kill`) ends a process without either. A program that wants no stray `.NAME.partial` left by
//! an interrupt calls [`remove_partial_outputs`] from its signal handler and then exits, as the
//! `pftrack` command line does.
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

/// Removes every partial output of this process (files, then staging folders, then the
/// folders created for them if empty, newest first) and returns how many it removed; meant for a signal
/// handler that ends the process next. The registry stays locked until the process ends, so
/// no output is created or committed after this returns, and any thread that tries waits for
/// ever: call it only on the way out, then end the process (never return to normal work).
pub fn remove_partial_outputs() -> usize {
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
