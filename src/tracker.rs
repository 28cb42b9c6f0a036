//! The embeddable tracker: `Tracker::new`, `step`, `reinit`.
