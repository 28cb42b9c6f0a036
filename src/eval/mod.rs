//! Scoring an estimate against ground truth: angle RMSE/MAE, centre error, precision, success AUC.

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Placeholder until the module lands.
    #[error("not implemented yet")]
    Unimplemented,
}
