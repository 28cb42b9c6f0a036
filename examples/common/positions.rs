//! The `--positions sift|exact` option of the examples that compare SIFT's matches with the
//! true images of the points they match.

/// Whether `value` of `--positions` asks for the exact images (`exact`) rather than SIFT's
/// own positions (`sift`).
pub fn exact_positions(value: &str) -> Result<bool, String> {
    match value {
        "sift" => Ok(false),
        "exact" => Ok(true),
        other => Err(format!("--positions sift|exact, not '{other}'")),
    }
}
