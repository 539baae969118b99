//! The error of declaring or assembling a model.

/// Errors raised while declaring or assembling a model.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ModelError {
    /// A block is malformed (bad bounds, wrong parameter sizes, unknown handles).
    #[error("block '{block}': {reason}")]
    InvalidBlock {
        /// Name of the block.
        block: String,
        /// What is wrong.
        reason: String,
    },
    /// A residual block is paired with a variable block of another length.
    #[error(
        "residual block '{residual}' has {residual_size} rows but is paired with variable block '{variable}' of size {variable_size}; a residual block and its paired variable block must have the same length"
    )]
    SizeMismatch {
        /// Residual block name.
        residual: String,
        /// Variable block name.
        variable: String,
        /// Its number of rows.
        residual_size: usize,
        /// The variable block's size.
        variable_size: usize,
    },
    /// Variable blocks without a residual block, or with two.
    #[error("pairing: {0}")]
    Pairing(String),
    /// An invalid sparsity pattern.
    #[error("sparsity pattern: {0}")]
    Pattern(String),
    /// Inconsistent dimensions.
    #[error("dimensions: {0}")]
    Dimension(String),
}
