//! The one error type of the core. Every fallible entry point returns [`Result`];
//! no input a user can pass makes the core panic.

/// Everything that can go wrong in the core, with the fields a caller needs to say why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// An input array has no rows where at least one is needed.
    #[error("{argument} is empty: at least {needed} row(s) are needed")]
    Empty {
        /// Name of the offending argument, as the caller knows it.
        argument: &'static str,
        /// How many rows the operation needs.
        needed: usize,
    },
    /// An input holds NaN or infinity.
    #[error("{argument} holds a non-finite value (NaN or infinity) in row {row}")]
    NonFinite {
        /// Name of the offending argument.
        argument: &'static str,
        /// First row (or matrix) with a non-finite entry.
        row: usize,
    },
    /// The number of neighbours asked for cannot be delivered.
    #[error("k = {k} is out of range: it must be between 1 and {max} (the number of candidate points{note})")]
    InvalidK {
        /// Requested neighbour count.
        k: usize,
        /// Largest admissible value.
        max: usize,
        /// Extra explanation, e.g. that a point is not its own neighbour.
        note: &'static str,
    },
    /// A search radius that is not a positive finite number.
    #[error("radius must be a positive finite number, got {radius}")]
    InvalidRadius {
        /// The radius given.
        radius: f64,
    },
    /// More points than the index can address (it stores 32-bit positions).
    #[error("{argument} has {got} rows; at most {max} are supported")]
    TooManyPoints {
        /// Name of the offending argument.
        argument: &'static str,
        /// Rows given.
        got: usize,
        /// Largest supported row count.
        max: usize,
    },
    /// A voxel grid whose data, shape and spacing disagree.
    #[error("a grid of shape {shape:?} and spacing {spacing:?} needs positive finite spacings and as many voxels as the shape says; got {voxels} voxels")]
    GridShape {
        /// Voxels given.
        voxels: usize,
        /// Shape given.
        shape: [usize; 3],
        /// Spacing given.
        spacing: [f64; 3],
    },
    /// A camera that cannot image anything.
    #[error("bad camera: {reason}")]
    BadCamera {
        /// What is wrong.
        reason: &'static str,
    },
    /// Masks that do not match their cameras.
    #[error(
        "mask {camera} is {got_width}x{got_height} pixels but its camera images {width}x{height}"
    )]
    MaskSize {
        /// Index of the camera.
        camera: usize,
        /// Mask width given.
        got_width: usize,
        /// Mask height given.
        got_height: usize,
        /// Camera image width.
        width: usize,
        /// Camera image height.
        height: usize,
    },
    /// An output buffer of the wrong length (a caller's bug, not a user's input).
    #[error("output buffer holds {got} elements where {expected} are needed")]
    OutputSize {
        /// Length needed.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// Two arrays that must agree in their dimension do not.
    #[error("{argument} has {got} columns but the index holds {expected}-D points")]
    DimensionMismatch {
        /// Name of the offending argument.
        argument: &'static str,
        /// Dimension of the index.
        expected: usize,
        /// Dimension given.
        got: usize,
    },
    /// An array whose row count disagrees with the number of points.
    #[error("{argument} has {got} rows but points has {expected}")]
    LengthMismatch {
        /// Name of the offending argument.
        argument: &'static str,
        /// Rows needed (the number of points).
        expected: usize,
        /// Rows given.
        got: usize,
    },
    /// A neighbour index that names no point.
    #[error("neighbors[{row}, {column}] = {index} is not a point index: it must be in 0..{n}")]
    NeighborIndex {
        /// Row (node) of the offending entry.
        row: usize,
        /// Column of the offending entry.
        column: usize,
        /// The index given.
        index: i64,
        /// Number of points.
        n: usize,
    },
    /// A neighbour list that does not contain its own node.
    #[error("neighbors row {node} does not contain the node itself ({node}): each node must be its own neighbour")]
    SelfNotNeighbour {
        /// The node.
        node: usize,
    },
    /// Too few neighbours per node for the approximation asked for.
    #[error("{found} neighbours per node (including the node) are too few: at least {needed} are needed")]
    NotEnoughNeighbours {
        /// Neighbours per node given.
        found: usize,
        /// Least number needed.
        needed: usize,
    },
    /// A support radius that is not a positive finite number.
    #[error("support[{node}] = {value} must be a positive finite number")]
    InvalidSupport {
        /// The node.
        node: usize,
        /// The radius given.
        value: f64,
    },
    /// A node whose moment matrix stays ill-conditioned after enlarging its support: its
    /// neighbours are (nearly) collinear in 2-D or coplanar in 3-D, or too few carry weight.
    #[error("the neighbours of node {node} do not span the space (collinear or coplanar): reciprocal condition number {rcond:.1e} of the moment matrix even with the support enlarged to {support}")]
    IllConditioned {
        /// The node.
        node: usize,
        /// Reciprocal condition number of the equilibrated moment matrix at the last try.
        rcond: f64,
        /// Support radius of the last try.
        support: f64,
    },
    /// A material constant outside its physical range.
    #[error("{argument} = {value} is out of range: it must be {expected}")]
    InvalidMaterial {
        /// Name of the offending argument (`youngs`, `poisson`).
        argument: &'static str,
        /// The value given.
        value: f64,
        /// The admissible range, in words.
        expected: &'static str,
    },
    /// A nodal volume that is not a positive finite number.
    #[error("volumes[{node}] = {value} must be a positive finite number")]
    InvalidVolume {
        /// The node.
        node: usize,
        /// The volume given.
        value: f64,
    },
    /// A square sparse matrix whose size is not a whole number of blocks.
    #[error("{argument} has {size} rows, which is not a multiple of the block size {block}")]
    BlockSize {
        /// Name of the offending argument.
        argument: &'static str,
        /// Rows (and columns) given.
        size: usize,
        /// Block size asked for.
        block: usize,
    },
    /// A sparse matrix whose structure is malformed or not symmetric.
    #[error("{argument} has a bad sparsity pattern in row {row}: {reason}")]
    SparsePattern {
        /// Name of the offending argument.
        argument: &'static str,
        /// First (scalar or block) row where the problem shows.
        row: usize,
        /// What is wrong.
        reason: &'static str,
    },
    /// A matrix whose pattern differs from the one a solver or output was set up for.
    #[error("{argument} does not have the sparsity pattern {expected}")]
    PatternMismatch {
        /// Name of the offending argument.
        argument: &'static str,
        /// Which pattern was expected.
        expected: &'static str,
    },
    /// A vector whose length disagrees with the matrix it goes with.
    #[error("{argument} has length {got} where {expected} are needed (one per matrix row)")]
    VectorLength {
        /// Name of the offending argument.
        argument: &'static str,
        /// Rows of the matrix.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// An index that names no node.
    #[error("{argument}[{position}] = {index} is not a node index: it must be in 0..{n}")]
    NodeIndex {
        /// Name of the offending argument.
        argument: &'static str,
        /// Position (row) of the offending entry.
        position: usize,
        /// The index given.
        index: usize,
        /// Number of nodes.
        n: usize,
    },
    /// A matrix that must be symmetric positive definite is not (numerically).
    #[error("{argument} is not positive definite: {reason} at row {row}")]
    NotPositiveDefinite {
        /// Name of the offending argument.
        argument: &'static str,
        /// Scalar row where it showed.
        row: usize,
        /// How it showed.
        reason: &'static str,
    },
    /// A solver option outside its range.
    #[error("{argument} = {value} is out of range: it must be {expected}")]
    InvalidOption {
        /// Name of the option.
        argument: &'static str,
        /// The value given.
        value: f64,
        /// The admissible range, in words.
        expected: &'static str,
    },
    /// A solve asked of a factorisation that holds no factor.
    #[error("the Cholesky factorisation holds no factor: none was computed since the analysis, or the last factorize failed")]
    NotFactorized,
    /// The sparse factorisation could not run (memory, index overflow).
    #[error("the sparse factorisation failed: {reason}")]
    Factorization {
        /// faer's reason.
        reason: String,
    },
    /// A body model description that cannot be used.
    #[error("bad body model: {reason}")]
    BadModel {
        /// What is wrong.
        reason: String,
    },
    /// A vector of the wrong length.
    #[error("{argument} has {got} entries where {expected} are needed")]
    WrongLength {
        /// Name of the offending argument.
        argument: &'static str,
        /// Entries needed.
        expected: usize,
        /// Entries given.
        got: usize,
    },
    /// A ray with a zero direction.
    #[error("directions row {row} is zero: a ray needs a direction")]
    BadRay {
        /// The row.
        row: usize,
    },
    /// An observation index (frame or part) out of range.
    #[error("{argument}[{row}] = {value} is out of range: it must be in 0..{bound}")]
    IndexOutOfRange {
        /// Name of the offending argument.
        argument: &'static str,
        /// The row.
        row: usize,
        /// The value given.
        value: i64,
        /// Exclusive upper bound.
        bound: usize,
    },
}

/// Result with the core's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Fails with [`Error::NonFinite`] naming the first row of `rows` holding NaN or infinity.
pub fn check_finite<const D: usize>(argument: &'static str, rows: &[[f64; D]]) -> Result<()> {
    use rayon::prelude::*;
    match rows
        .par_iter()
        .position_first(|r| !r.iter().all(|v| v.is_finite()))
    {
        Some(row) => Err(Error::NonFinite { argument, row }),
        None => Ok(()),
    }
}
