//! A step on rayon's pool with a second thread kept at hand.
//!
//! A step forks a few dozen times (SIFT's blur bands and descriptors, the keyframe fits beside
//! the matches, the particles' likelihoods, the template's correlations), each fork a few tens
//! of microseconds of work, with serial stretches between them. Between forks rayon's idle
//! threads go to sleep, and waking one costs a system call on the forking thread and, on a
//! virtual machine, some 30 µs before the woken thread runs: measured on a 2-vCPU VM, a
//! `join` of two 20 µs halves took 48-60 µs after a serial stretch of 20 µs or more, longer
//! than running both halves in turn, and 22 µs with the second thread kept awake. So for the
//! length of a step, one of the pool's threads waits for work by spinning: it runs whatever
//! the pool has pending (the step's forks, or any other work given to the pool) and checks
//! again, and is back to sleeping the usual way once the step returns.

use std::sync::atomic::{AtomicBool, Ordering};

/// Runs `f` on the current rayon pool (the global one when called from outside any pool) with
/// a second thread of the pool, where it has one, spinning for work until `f` returns. The
/// result is `f`'s; a panic in `f` is passed on once the helper has stopped. On a pool of
/// one thread `f` simply runs there.
pub(super) fn with_helper<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    /// Tells the helper to stop when dropped, so that it stops when `f` panics too (rayon's
    /// `join` waits for both halves before passing a panic on).
    struct Done<'a>(&'a AtomicBool);
    impl Drop for Done<'_> {
        fn drop(&mut self) {
            self.0.store(true, Ordering::Release);
        }
    }
    let done = AtomicBool::new(false);
    let (r, ()) = rayon::join(
        || {
            let _done = Done(&done);
            f()
        },
        || {
            // Run by the forking thread itself only after `f` (nobody stole it): then `done`
            // is already set and this returns at once.
            while !done.load(Ordering::Acquire) {
                if rayon::yield_now() != Some(rayon::Yield::Executed) {
                    std::hint::spin_loop();
                }
            }
        },
    );
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool")
    }

    #[test]
    fn returns_what_the_work_returns_with_its_forks_done_on_any_pool() {
        for threads in [1, 2, 3] {
            let sum = pool(threads).install(|| {
                with_helper(|| {
                    use rayon::prelude::*;
                    // Forks inside, as a step's: all of them run.
                    (0..10_000u64).into_par_iter().map(|i| i * i).sum::<u64>()
                })
            });
            assert_eq!(sum, (0..10_000u64).map(|i| i * i).sum::<u64>(), "{threads}");
        }
    }

    #[test]
    fn a_panic_in_the_work_is_passed_on_and_stops_the_helper() {
        // On a thread of its own, watched: a helper that never stops holds the panic back
        // forever (rayon's join waits for both halves), which fails here instead of hanging.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let p = pool(2);
            for _ in 0..20 {
                let caught = p.install(|| {
                    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        with_helper(|| -> u32 { panic!("the step failed") })
                    }))
                });
                let msg = caught.expect_err("the panic comes back");
                assert_eq!(msg.downcast_ref::<&str>(), Some(&"the step failed"));
            }
            // The pool is free again: the helper stopped.
            let _ = tx.send(p.install(|| with_helper(|| 7)));
        });
        let got = rx.recv_timeout(std::time::Duration::from_secs(120));
        assert_eq!(got, Ok(7), "the panicking work's helper never stopped");
    }
}
