//! Point tracking through time (SPEC 7, paper 003 section 3.2): per camera and point, a
//! linear prediction from the last two positions, a search box by normalised
//! cross-correlation around it, temporal least-squares matching (affine + radiometric,
//! [`crate::lsm`]) of the previous frame's patch into the current frame, and a
//! forward-backward check (the match found again from the current frame back into the
//! previous one must land on the start).
//!
//! The template is the previous frame's patch, not the first appearance's: between two
//! frames the affine change of a patch is small, so the Gauss-Newton starts close and
//! converges in a few iterations whatever the deformation or rotation accumulated since
//! the point was seeded (a first-appearance template stops matching once a limb has turned
//! by ~30 degrees). The drift this costs is bounded by the forward-backward check and, in
//! 3-D, by the cross-camera intersection with blunder rejection (done in Python, vectorised:
//! `elastocap.tracking`).
//!
//! Submodules: `ncc` (box search by normalised cross-correlation), `ncc_at` (candidate
//! scoring by it), `ncc_at_decisive` (seeding's candidate scores, exact only where they can
//! decide its test), `ncc_at_estimate` (its cheap estimate and the bilinear fill in blocks), `ncc_batch` (the correlation at candidates across many images in one pass),
//! `weighted_ncc` (the box search with per-pixel template weights), `step` (one frame of
//! every camera, one parallel pass), `step_view` (one view's stages), `flags` (why a point
//! is not tracked), `seed_hull` (the seeding's visual-hull
//! test of ray samples), `seed_depths` (the seeding's depth search along a ray through the hull),
//! `seed_peaks` (the best correlation along a seed's line and the best peak away from it),
//! `zbuffer` (the visibility's test of nearer tracked points on a point's line of sight),
//! `rigid_held_out` (the rigid residuals' leave-one-out fits of each point's neighbours).

mod flags;
mod ncc;
mod ncc_at;
mod ncc_at_decisive;
#[cfg(test)]
mod ncc_at_decisive_tests;
mod ncc_at_estimate;
#[cfg(test)]
mod ncc_at_tests;
mod ncc_batch;
#[cfg(test)]
mod ncc_batch_tests;
mod rigid_held_out;
#[cfg(test)]
mod rigid_held_out_tests;
mod seed_depths;
mod seed_hull;
mod seed_peaks;
mod step;
#[cfg(test)]
mod step_tests;
mod step_view;
#[cfg(test)]
mod tests;
mod weighted_ncc;
#[cfg(test)]
mod weighted_tests;
mod zbuffer;

pub use flags::Flag;
pub use ncc::{box_search_scores, NccBest};
pub use ncc_at::ncc_at;
pub use ncc_at_decisive::ncc_at_decisive;
pub use ncc_batch::ncc_at_cameras;
pub use rigid_held_out::rigid_held_out;
pub use seed_depths::{hull_depths, DepthGrid};
pub use seed_hull::{hull_inside, hull_pixels, line_pixels, HullCamera, HullView, OUTSIDE};
pub use seed_peaks::{line_peak, Away};
pub use step::{track_camera, track_cameras, CameraFrames, CameraStep, TrackOptions};
pub use zbuffer::occluded;
