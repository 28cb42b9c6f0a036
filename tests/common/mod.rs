//! What the GPU test binaries (`tests/gpu.rs`, `tests/gpu_track.rs`) share: opening the GPU
//! engine or skipping with a printed reason, and the gate that limits how many tests hold a
//! device at once and keeps a test that destroys its device apart from the others.

use std::io::Write;
use std::ops::{Deref, DerefMut};
use std::sync::{Condvar, Mutex, PoisonError};

use pftrack::likelihood::gpu::GpuEngine;

/// Prints why a test does nothing (libtest hides `eprintln!` of passing tests).
pub fn skip(reason: &str) {
    let _ = writeln!(std::io::stderr(), "SKIPPED: {reason}");
}

/// Whether a missing adapter fails the tests (`PFTRACK_REQUIRE_GPU=1`, as in CI).
pub fn gpu_required() -> bool {
    std::env::var("PFTRACK_REQUIRE_GPU").as_deref() == Ok("1")
}

/// How many tests of one binary may hold a device at once, and whether one holds its device
/// alone (a test that destroys it).
///
/// Measured on an NVIDIA H200 (Vulkan, driver 580.159.04, 16 cores, 2026-12-04) with
/// `tests/gpu.rs`, before this gate: on four test threads the binary did not finish in 390 s,
/// nor in 45 s in a second run, while its lost-device test destroyed a device beside the
/// other tests' work; it finished in 6 s on one thread, and in 3 s on four threads without that
/// test. With the destroying test alone, four threads finished in 3 s (twice), but sixteen
/// (the default there) still did not finish in 45 s (three runs), so at most [`MAX_DEVICES`]
/// tests hold a device at once. With this gate, on sixteen test threads, `tests/gpu.rs`
/// finished in 2.8-3.5 s and `tests/gpu_track.rs` in 1.5-1.8 s, three runs each, all tests
/// passing (2026-12-04, a later session, the same kind of machine). The cause of the hang
/// (driver or wgpu) was not found. lavapipe never showed either.
const MAX_DEVICES: usize = 4;

struct Slots {
    holders: usize,
    alone: bool,
}

static SLOTS: Mutex<Slots> = Mutex::new(Slots {
    holders: 0,
    alone: false,
});
static FREED: Condvar = Condvar::new();

/// A place among the tests that hold a device; given back on drop.
pub struct Slot {
    alone: bool,
}

impl Slot {
    fn take(alone: bool) -> Self {
        let mut s = SLOTS.lock().unwrap_or_else(PoisonError::into_inner);
        while s.alone || (alone && s.holders > 0) || s.holders >= MAX_DEVICES {
            s = FREED.wait(s).unwrap_or_else(PoisonError::into_inner);
        }
        if alone {
            s.alone = true;
        } else {
            s.holders += 1;
        }
        Self { alone }
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        let mut s = SLOTS.lock().unwrap_or_else(PoisonError::into_inner);
        if self.alone {
            s.alone = false;
        } else {
            s.holders -= 1;
        }
        FREED.notify_all();
    }
}

/// A GPU engine together with its [`Slot`]. The engine is dropped before the slot is given
/// back; it can also be moved out (`held.engine`), the slot then living to the end of the
/// scope.
pub struct Held {
    /// The engine.
    pub engine: GpuEngine,
    _slot: Slot,
}

impl Deref for Held {
    type Target = GpuEngine;
    fn deref(&self) -> &GpuEngine {
        &self.engine
    }
}

impl DerefMut for Held {
    fn deref_mut(&mut self) -> &mut GpuEngine {
        &mut self.engine
    }
}

/// The engine, or `None` (with a printed reason) when there is no adapter and the GPU is not
/// required.
fn open(slot: Slot) -> Option<Held> {
    match GpuEngine::new() {
        Ok(engine) => Some(Held {
            engine,
            _slot: slot,
        }),
        Err(e) => {
            if gpu_required() {
                panic!("PFTRACK_REQUIRE_GPU=1 but no GPU engine: {e}");
            }
            skip(&format!("no GPU engine ({e})"));
            None
        }
    }
}

/// An engine for a test that keeps its device: up to [`MAX_DEVICES`] such tests run at once.
pub fn engine() -> Option<Held> {
    open(Slot::take(false))
}

/// An engine for a test that destroys its device: no other test of the binary holds a device
/// meanwhile.
pub fn engine_alone() -> Option<Held> {
    open(Slot::take(true))
}
