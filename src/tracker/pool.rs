//! A step on rayon's pool with a second thread kept at hand.
//!
//! A step forks a few dozen times (SIFT's blur bands and descriptors, the keyframe fits beside
//! the matches, the particles' likelihoods, the template's correlations), each fork a few tens
//! of microseconds of work, with serial stretches between them. Between forks rayon's idle
//! threads go to sleep, and waking one costs a system call on the forking thread and, on a
//! virtual machine, some 30 µs before the woken thread runs: measured on a 2-vCPU VM, a
//! `join` of two 20 µs halves took 48-60 µs after a serial stretch of 20 µs or more, longer
//! than running both halves in turn, and 22 µs with the second thread kept awake. So for the
//! length of a step, one of the pool's threads waits for work without sleeping: it runs
//! whatever the pool has pending (the step's forks, or any other work given to the pool), and
//! where there is none it yields its core to any other thread that wants it and checks again.
//! Once the step returns it sleeps the usual way.
//!
//! Yielding, not spinning, keeps the helper from holding a core another process needs: two
//! trackers at once on two cores took 2.0-2.2 s over `nod` with a spinning helper against
//! 1.1-1.3 s without a helper, and as long as without one when it yields. Where the step
//! waits on work done elsewhere (a GPU engine's evaluation, or a CPU engine on a pool of its
//! own) the helper rests, blocked, [`Helper::resting`]: waiting beside a software Vulkan
//! driver took a core from the driver's own threads, a 160x120 step on lavapipe 8 -> 11-16 ms.
//!
//! The helper is never served by the stepping thread itself, which rayon can hand it while
//! the step waits (on a pool of one thread, or waiting for an engine's own pool): there it
//! would wait for a step that cannot go on below it. While it waits the helper may run other
//! work given to the pool (another tracker's step, say), and the step then returns once that
//! work is done, as a rayon `join` does.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Condvar, Mutex, OnceLock, PoisonError};

use crate::likelihood::LikelihoodEngine;

/// The state a step shares with its helper thread: whether the step is done, and whether the
/// helper is to rest (blocked, not polling) for now.
#[derive(Debug, Default)]
pub(super) struct Helper {
    done: AtomicBool,
    rest: AtomicBool,
    /// Guards the helper's wait for `rest` to clear (or `done` to be set).
    lock: Mutex<()>,
    wake: Condvar,
}

impl Helper {
    /// Runs `f` with the helper blocked instead of polling (it runs no pool work meanwhile),
    /// for work that does not run on the step's pool.
    pub(super) fn resting<R>(&self, f: impl FnOnce() -> R) -> R {
        /// Puts the helper back as it was (woken, unless an outer `resting` holds it) when
        /// dropped, so that a panic in `f` does too.
        struct Rested<'a>(&'a Helper, bool);
        impl Drop for Rested<'_> {
            fn drop(&mut self) {
                self.0.set(&self.0.rest, self.1);
            }
        }
        let was = self.rest.swap(true, Ordering::AcqRel);
        let _rested = Rested(self, was);
        f()
    }

    /// Runs `f` on `engine` (its evaluation), with the helper at rest unless the engine works
    /// on the step's pool ([`LikelihoodEngine::runs_on_calling_pool`]).
    pub(super) fn beside<E: LikelihoodEngine + ?Sized, R>(
        &self,
        engine: &mut E,
        f: impl FnOnce(&mut E) -> R,
    ) -> R {
        if engine.runs_on_calling_pool() {
            f(engine)
        } else {
            self.resting(|| f(engine))
        }
    }

    /// Sets `flag` under the lock the helper waits with, then wakes it: a helper about to wait
    /// either sees the new value or is waiting when the wake comes.
    fn set(&self, flag: &AtomicBool, value: bool) {
        {
            let _g = self.lock.lock().unwrap_or_else(PoisonError::into_inner);
            flag.store(value, Ordering::Release);
        }
        self.wake.notify_all();
    }

    /// The helper's loop: runs the pool's pending work, yields its core where there is none,
    /// blocks while told to rest, until the step is done.
    fn serve(&self) {
        while !self.done.load(Ordering::Acquire) {
            if self.rest.load(Ordering::Acquire) {
                let g = self.lock.lock().unwrap_or_else(PoisonError::into_inner);
                let _g = self
                    .wake
                    .wait_while(g, |()| {
                        self.rest.load(Ordering::Acquire) && !self.done.load(Ordering::Acquire)
                    })
                    .unwrap_or_else(PoisonError::into_inner);
            } else if rayon::yield_now() != Some(rayon::Yield::Executed) {
                // Nothing pending: the core goes to any other thread that wants it (another
                // process's; a plain spin held it from them), and comes straight back when
                // none does.
                std::thread::yield_now();
            }
        }
    }
}

/// Runs `f` on the current rayon pool (the global one when called from outside any pool) with
/// a second thread of the pool, where it has one, polling for work until `f` returns, except
/// while `f` has it rest ([`Helper::resting`]). The result is `f`'s; a panic in `f` is passed
/// on once the helper has stopped. On a pool of one thread `f` simply runs there. `helper`
/// must not be in use by another call at the same time.
pub(super) fn with_helper<R: Send>(helper: &Helper, f: impl FnOnce() -> R + Send) -> R {
    /// Tells the helper to stop when dropped, so that it stops when `f` panics too (rayon's
    /// `join` waits for both halves before passing a panic on).
    struct Done<'a>(&'a Helper);
    impl Drop for Done<'_> {
        fn drop(&mut self) {
            self.0.set(&self.0.done, true);
        }
    }
    helper.done.store(false, Ordering::Release);
    helper.rest.store(false, Ordering::Release);
    // The thread that runs `f`. Rayon may hand the helper's half to that very thread while `f`
    // waits, with the helper's half still in its deque: on a pool of one thread, or where work
    // handed to another pool (an engine's own) waits by running the jobs of its thread's
    // deque. Served there, on top of `f`'s stack, the helper would wait for a step that cannot
    // go on until it returns; so there it returns at once, and the step goes on without one.
    let stepper = OnceLock::new();
    let (r, ()) = rayon::join(
        || {
            let _ = stepper.set(std::thread::current().id());
            let _done = Done(helper);
            f()
        },
        || {
            if stepper.get() != Some(&std::thread::current().id()) {
                helper.serve();
            }
        },
    );
    r
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool")
    }

    fn squares(n: u64) -> u64 {
        (0..n).into_par_iter().map(|i| i * i).sum::<u64>()
    }

    /// Runs `f` on a thread of its own and waits at most two minutes for it: a helper that
    /// never stops (or never wakes) holds its step forever, which fails here instead of
    /// hanging the tests.
    fn watched<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(f());
        });
        match rx.recv_timeout(std::time::Duration::from_secs(120)) {
            Ok(r) => r,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                panic!("the step never returned: its helper never stopped")
            }
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                panic!("the watched work panicked (its message is above)")
            }
        }
    }

    #[test]
    fn returns_what_the_work_returns_with_its_forks_done_on_any_pool() {
        let want = (0..10_000u64).map(|i| i * i).sum::<u64>();
        for threads in [1, 2, 3] {
            let got = watched(move || {
                let (p, helper) = (pool(threads), Helper::default());
                // Many steps in a row, each with forks, some of them while the helper rests.
                (0..200)
                    .map(|k| {
                        p.install(|| {
                            with_helper(&helper, || match k % 3 {
                                0 => squares(10_000),
                                1 => helper.resting(|| squares(10_000)),
                                _ => helper.resting(|| 0) + squares(10_000),
                            })
                        })
                    })
                    .collect::<Vec<u64>>()
            });
            assert!(got.iter().all(|&s| s == want), "{threads} threads");
        }
    }

    /// Work handed to another pool, as an engine with a pool of its own does, waits there by
    /// running jobs of its own thread's deque, the helper's among them where no other thread
    /// took it (always on a pool of one thread): run there, on the step's own stack, the
    /// helper served until a step that could not go on was done, and hung.
    #[test]
    fn work_handed_to_another_pool_returns_with_the_helper_resting_or_not() {
        for threads in [1, 2] {
            let got = watched(move || {
                let (p, other, helper) = (pool(threads), pool(2), Helper::default());
                (0..200u64)
                    .map(|k| {
                        p.install(|| {
                            with_helper(&helper, || {
                                let there = || other.install(|| squares(1000 + k));
                                if k % 2 == 0 {
                                    helper.resting(there)
                                } else {
                                    there()
                                }
                            })
                        })
                    })
                    .sum::<u64>()
            });
            let want = (0..200u64).map(|k| (0..1000 + k).map(|i| i * i).sum::<u64>());
            assert_eq!(got, want.sum::<u64>(), "{threads} threads");
        }
    }

    #[test]
    fn a_panic_in_the_work_is_passed_on_and_stops_the_helper_resting_or_not() {
        let got = watched(|| {
            let (p, helper) = (pool(2), Helper::default());
            for k in 0..20 {
                let caught = p.install(|| {
                    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        with_helper(&helper, || -> u32 {
                            if k % 2 == 0 {
                                helper.resting(|| panic!("the step failed"))
                            } else {
                                panic!("the step failed")
                            }
                        })
                    }))
                });
                let msg = caught.expect_err("the panic comes back");
                assert_eq!(msg.downcast_ref::<&str>(), Some(&"the step failed"));
            }
            // The pool is free again: the helper stopped.
            p.install(|| with_helper(&helper, || 7))
        });
        assert_eq!(got, 7);
    }
}
