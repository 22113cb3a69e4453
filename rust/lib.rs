//! elastocap's core: the heavy kernels of markerless multi-view shape and motion capture.
//!
//! Pure Rust; the Python bindings live in [`python`] behind the `python` feature, which only
//! maturin turns on.
#![warn(missing_docs)]

pub mod body;
pub mod camera;
pub mod carve;
pub mod efg;
pub mod elastic;
pub mod error;
pub mod fit;
pub mod grid_sample;
pub mod intersect;
pub mod linalg;
pub mod lm;
pub mod lsm;
pub mod mesh;
pub mod mls;
pub mod ordered;
pub mod polar;
pub mod raster;
pub mod rigid;
pub mod sdf;
pub mod snake;
pub mod solve;
pub mod spatial_hash;
pub mod track;

#[cfg(feature = "python")]
mod python;

pub use error::{Error, Result};
pub use spatial_hash::SpatialHash;
