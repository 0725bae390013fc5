//! What can go wrong in the kernel regression: bad shapes, empty or non-finite input, settings
//! out of their domain, and matrices that lost positive definiteness.

use std::fmt;

/// Why an evaluation, a solve or a tuning run could not proceed.
#[derive(Clone, Debug, PartialEq)]
pub enum KrrError {
    /// No training points (n = 0), no features (d = 0) or no inducing points (m = 0).
    Empty(String),
    /// Lengths that do not fit together (e.g. `x.len() != n * d`, `log_s.len() != d`).
    Shape(String),
    /// A NaN or ±∞ in the inputs, the parameters, or a computed quantity.
    NonFinite(String),
    /// A setting out of its domain (e.g. λ ≤ 0, negative jitter).
    Setting(String),
    /// Cholesky met a non-positive (or non-finite) pivot: the matrix is not numerically positive
    /// definite. `what` names the matrix (`"K_mm + jitter I"`, `"H"`, ...); `index` is the row
    /// where it failed and `pivot` the value found there. More jitter (§8) usually cures it.
    NotPositiveDefinite { what: &'static str, index: usize, pivot: f64 },
}

impl fmt::Display for KrrError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            KrrError::Empty(s) => write!(f, "empty input: {s}"),
            KrrError::Shape(s) => write!(f, "shape mismatch: {s}"),
            KrrError::NonFinite(s) => write!(f, "non-finite value: {s}"),
            KrrError::Setting(s) => write!(f, "invalid setting: {s}"),
            KrrError::NotPositiveDefinite { what, index, pivot } => write!(
                f,
                "{what} is not numerically positive definite (Cholesky pivot {index} = {pivot:e}); \
                 increase the jitter"
            ),
        }
    }
}

impl std::error::Error for KrrError {}
