//! Why a point has no position in a frame (stored as `u8`; the codes are part of the
//! Python API as `elastocap.tracking.TrackFlag`).

/// Flag of a tracked point (per camera in the 2-D step, per point in 3-D).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Flag {
    /// Tracked: the position is valid.
    Tracked = 0,
    /// No position in the previous frame: not seeded yet (or lost before).
    NotSeeded = 1,
    /// The patch or its search box reaches outside the image.
    ImageBorder = 2,
    /// The best normalised cross-correlation of the box search or the least-squares
    /// match is below the threshold (occlusion, strong change of appearance).
    LowCorrelation = 3,
    /// Matching back from the current frame into the previous one misses the start by
    /// more than the tolerance.
    ForwardBackward = 4,
    /// The view disagrees with the other cameras: its normalised residual in the forward
    /// intersection is a blunder (or its reprojection residual is too large).
    Epipolar = 5,
    /// The 3-D velocity exceeds its threshold.
    Velocity = 6,
    /// The 3-D acceleration exceeds its threshold.
    Acceleration = 7,
    /// The 3-D velocity differs from the local mean of the neighbouring trajectories.
    Nonuniform = 8,
    /// Least-squares matching diverged or the patch has too little texture.
    MatchFailed = 9,
    /// Fewer than two cameras keep the point: no 3-D position.
    FewViews = 10,
}
