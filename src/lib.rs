//! # pftrack
//!
//! Follows a rigid object through video and estimates its 3D rotation (tilt, pan, roll)
//! directly from the 2D frames, with no 3D model and no training: the method of C. Chen and
//! D. Schonfeld, "A Particle Filtering Framework for Joint Video Tracking and Pose Estimation".
//!
//! The modules follow the data flow:
//! [`frames`] → [`features`] → [`pose`] → [`motion`] → [`likelihood`] (cpu | gpu) →
//! [`filter`] → [`tracker`] → [`output`]; [`synth`], [`io`] and [`eval`] make and score
//! ground truth. Conventions (axes, rotation order, CSV formats) live in [`geometry`] and
//! [`io`].
#![warn(missing_docs)]

pub mod error;
pub mod eval;
pub mod features;
pub mod filter;
pub mod frames;
pub mod geometry;
pub mod io;
pub mod likelihood;
pub mod motion;
pub mod output;
pub mod pose;
pub mod synth;
pub mod tracker;

pub use error::{Error, Result};
/// The `glam` crate whose `f32` matrices the CPU likelihood's feature term uses
/// ([`likelihood::cpu::feature::rotation`], column-major), re-exported so that a caller of it
/// uses the same version.
pub use glam;
/// The `image` crate whose `RgbImage` frames the tracker takes, re-exported so that an
/// embedding program uses the same version.
pub use image;
/// The `nalgebra` crate whose matrices the pose API takes and returns (rotation matrices, the
/// 2x2 blocks of the solvers, translations), re-exported so that a caller names them in the
/// same version.
pub use nalgebra;
/// The `rayon` crate whose thread pools run the CPU path, re-exported so that an embedding
/// program sets the threads of a tracker (`ThreadPool::install` around its calls) without a
/// dependency of its own.
pub use rayon;
/// The `wgpu` crate the GPU engine runs on, re-exported so that an application that opens its
/// own device for it ([`likelihood::gpu::GpuDevice::from_wgpu`]) uses the same version.
pub use wgpu;

// The README's library example is compiled as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
struct ReadmeDoctests;
