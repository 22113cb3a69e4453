//! What a match is asked for and what it reports: options, start values, per-match status
//! and the output buffers the batch writes into.

/// Why a match ended. Stored as `u8` in the output (the codes are part of the Python API).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Status {
    /// The shift update (and the change of the linear part) fell below the tolerance.
    Converged = 0,
    /// The estimate ran away: moved further than `max_shift` from its start, the affine
    /// map degenerated (scale outside `[1 / max_scale, max_scale]`, or a reflection), the
    /// gain turned non-positive, or a value became non-finite.
    Diverged = 1,
    /// The template patch (with its one-pixel gradient border) or the warped search patch
    /// reaches outside its image.
    LeftImage = 2,
    /// The template patch has too little texture to fix a position: the root mean square
    /// gradient along its weakest direction is below `min_texture`, or the normal
    /// equations are singular.
    LowTexture = 3,
    /// The iteration cap was reached before the shift update fell below the tolerance.
    MaxIterations = 4,
}

impl Status {
    /// Whether the match carries an estimate with a covariance (converged, or stopped at
    /// the iteration cap).
    pub fn has_estimate(self) -> bool {
        matches!(self, Status::Converged | Status::MaxIterations)
    }
}

/// How the search image is resampled between pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interpolation {
    /// Bilinear (SPEC 7): four pixels per sample. It damps and shifts the phase of texture
    /// near the Nyquist frequency, which biases positions by up to a few hundredths of a
    /// pixel on sharp texture.
    Bilinear,
    /// Keys' cubic convolution (a = -1/2): sixteen pixels per sample, flat to a higher
    /// frequency; the patch must stay one more pixel inside the image.
    Bicubic,
}

/// Options of least-squares matching (Gruen 1985), the same for every point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchOptions {
    /// Side of the square template patch, pixels; odd, at least 3.
    pub size: usize,
    /// Gauss-Newton iteration cap per search image.
    pub max_iterations: usize,
    /// Stop when the update of the matched centre is shorter than this, search-image
    /// pixels (SPEC 7: 0.01), and no entry of the affine map's linear part changes by more
    /// than this (search pixels per template pixel).
    pub tolerance: f64,
    /// Diverged when the matched centre moves further than this from its start, pixels.
    pub max_shift: f64,
    /// Diverged when a singular value of the affine map leaves `[1 / max_scale, max_scale]`.
    pub max_scale: f64,
    /// Least root mean square gradient along the template patch's weakest direction, grey
    /// levels per pixel (the square root of the smaller eigenvalue of the mean structure
    /// tensor); below it the match reports [`Status::LowTexture`].
    pub min_texture: f64,
    /// Standard deviation of the distance of the matched centre from its epipolar line,
    /// pixels: 0 makes the line a hard constraint, a positive value a soft one (a weighted
    /// pseudo-observation).
    pub line_sigma: f64,
    /// Iterations that estimate shift, gain and offset only before the affine part is
    /// freed: a start that is off by pixels first finds the centre, which the shape
    /// parameters cannot yet help with.
    pub shift_only_iterations: usize,
    /// Resampling of the template (at sub-pixel points) and the search images.
    pub interpolation: Interpolation,
    /// The covariance with both images' noise (the sandwich: one widened resampling of the
    /// search patch at the final state, about a quarter of a match); false gives
    /// `(G^T G)^-1`, the template taken noise-free, for callers that only use the match's
    /// position (the tracker's forward-backward check).
    pub sandwich: bool,
    /// A richer model for the last iterations of a converged match (off by default):
    /// second-order warp terms and a gain that varies across the patch (`rich`).
    pub extra: ExtraModel,
}

impl Default for MatchOptions {
    fn default() -> Self {
        Self {
            size: 11,
            max_iterations: 30,
            tolerance: 0.01,
            max_shift: 5.0,
            max_scale: 3.0,
            min_texture: 0.0,
            line_sigma: 0.0,
            shift_only_iterations: 1,
            interpolation: Interpolation::Bicubic,
            sandwich: true,
            extra: ExtraModel::default(),
        }
    }
}

/// The warp of the richer model: template offsets `x` (pixels, `xi = x / h` with `h` the
/// patch's half-width) to search pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Warp {
    /// `b + A x`: the affine map alone.
    Affine,
    /// `b + A x / (1 + p1 xi + p2 eta)`: a homography about the centre, two more unknowns
    /// (a compression that varies linearly across the patch).
    Projective,
    /// `b + A x + (q_u . m, q_v . m)`, `m = (xi^2, xi eta, eta^2)`: six more unknowns, the
    /// coefficients in search pixels at the patch's edge.
    Quadratic,
}

/// The richer model of a match (Gauss-Newton with the exact Jacobian, the search patch's
/// own gradients, after the affine match has converged: staged, so the extra unknowns
/// start from a settled centre and shape). The centre stays `b` (every extra term vanishes
/// at the template point), so the matched position keeps its meaning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExtraModel {
    /// Gauss-Newton iterations of the richer model after the affine match converged; 0 =
    /// off (the affine match to the bit).
    pub iterations: usize,
    /// Warp terms beyond the affine map.
    pub warp: Warp,
    /// The gain varies linearly across the patch, `g0 + g_x xi + g_y eta` (two more
    /// unknowns): shading that changes across a curved patch.
    pub gain_gradient: bool,
    /// Standard deviation of a zero-mean prior (Tikhonov) on the extra warp terms, search
    /// pixels of displacement at the patch's edge; 0 = no prior.
    pub warp_sigma: f64,
    /// Standard deviation of a zero-mean prior on the gain's slopes, as a fraction of the
    /// gain across half the patch; 0 = no prior.
    pub gain_sigma: f64,
    /// When the richer model does not converge, report the affine match as it stood (the
    /// match the option-free path returns) instead of the richer model's failure.
    pub fallback: bool,
    /// The Jacobian from the template's gradients (the affine loop's choice: constant
    /// apart from the gain columns, the update composed on the template side) instead of
    /// the search image's at the warped points (exact, forward-additive).
    pub template_jacobian: bool,
    /// The richer stage is skipped where the converged affine match's correlation is at
    /// least this (the affine model already explains the patch: nothing for the extra
    /// terms to take up but noise), and the affine match is reported; infinite = never
    /// skipped.
    pub skip_correlation: f64,
}

impl Default for ExtraModel {
    fn default() -> Self {
        Self {
            iterations: 0,
            warp: Warp::Affine,
            gain_gradient: false,
            warp_sigma: 0.0,
            gain_sigma: 0.0,
            fallback: false,
            template_jacobian: false,
            skip_correlation: f64::INFINITY,
        }
    }
}

/// What the richer stage did for one match (stored as `u8`; the codes are part of the
/// Python API).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Refined {
    /// No richer stage: not asked for, a line constraint, or the affine match did not
    /// converge.
    No = 0,
    /// The richer model ran; its outcome is reported.
    Reported = 1,
    /// The richer model did not converge; the affine match is reported (`fallback`).
    FellBack = 2,
    /// Skipped by `skip_correlation`; the affine match is reported.
    Skipped = 3,
}

/// The richer stage's record of one match: what it did, and the converged affine match it
/// started from (so that a caller wanting both centres needs no second, affine-only match).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stage {
    /// The affine match's centre `(u, v)`, search pixels, where the richer stage was asked
    /// for and the affine match converged (its own outcome, covariance included, would
    /// have been [`Status::Converged`]); NaN elsewhere.
    pub affine: [f64; 2],
    /// What the richer stage did.
    pub refined: Refined,
}

impl Stage {
    /// No richer stage, no affine centre.
    pub const NONE: Self = Self {
        affine: [f64::NAN; 2],
        refined: Refined::No,
    };
}

impl Default for Stage {
    fn default() -> Self {
        Self::NONE
    }
}

/// An image as the matcher reads it: row-major `f32` grey values.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    /// `height * width` grey values, row by row.
    pub data: &'a [f32],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

/// Per-parameter layout of one search image's block of the covariance, in this order.
pub const PARAMETERS: usize = 8;

/// Where the batch writes its results: flat buffers indexed `[point][search image]`.
///
/// `affine` holds the 2x3 map row-major, `[a11, a12, u, a21, a22, v]`: template patch
/// offsets `(dx, dy)` from the template point go to search pixel
/// `(a11 dx + a12 dy + u, a21 dx + a22 dy + v)`, so `(u, v)` is the matched centre.
/// `radiometry` is `[gain, offset]` with `template ≈ offset + gain * search`. The
/// covariance of point `p` is the `8S x 8S` row-major block `covariance[64 S² p ..]`, with
/// search image `s`'s parameters at rows `8s..8s + 8` in the order
/// `[u, v, a11, a12, a21, a22, gain, offset]`.
#[derive(Debug)]
pub struct MatchOutput<'a> {
    /// [`Status`] codes.
    pub status: &'a mut [u8],
    /// Final affine maps.
    pub affine: &'a mut [[f64; 6]],
    /// Final `[gain, offset]`.
    pub radiometry: &'a mut [[f64; 2]],
    /// Standard deviation of unit weight: RMS residual grey level with the redundancy as
    /// the divisor.
    pub sigma0: &'a mut [f64],
    /// Normalised cross-correlation of the template patch and the resampled search patch.
    pub correlation: &'a mut [f64],
    /// Gauss-Newton iterations run.
    pub iterations: &'a mut [u32],
    /// Joint covariances, `8S x 8S` per point.
    pub covariance: &'a mut [f64],
}
