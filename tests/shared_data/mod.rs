//! Where the tests find the real footage of `../shared/data` (its README says what is there),
//! and what they do without it: print why and skip, or, under `PFTRACK_REQUIRE_DATA=1` (as in
//! CI, which has the folder), fail. Without that switch a missing or moved folder would turn
//! every real-footage test into a silent pass.

use std::io::Write;
use std::path::PathBuf;

/// Whether missing footage fails the tests (`PFTRACK_REQUIRE_DATA=1`).
pub fn required() -> bool {
    std::env::var("PFTRACK_REQUIRE_DATA").as_deref() == Ok("1")
}

/// `rel` under `../shared/data` beside the checkout (or two levels up, from a worktree one
/// level deeper) when it exists. Otherwise `None`, with the reason printed, or a panic when
/// the footage is [`required`].
pub fn path(rel: &str) -> Option<PathBuf> {
    let root = env!("CARGO_MANIFEST_DIR");
    let found = [
        format!("{root}/../shared/data"),
        format!("{root}/../../shared/data"),
    ]
    .into_iter()
    .map(|d| PathBuf::from(d).join(rel))
    .find(|p| p.exists());
    if found.is_none() {
        let why = format!("../shared/data/{rel} not found beside the checkout");
        assert!(!required(), "PFTRACK_REQUIRE_DATA=1 but {why}");
        let _ = writeln!(std::io::stderr(), "SKIPPED: {why}");
    }
    found
}
