//! `vision`: the visual front-end primitives of dwslam (thesis §3.4, §6.3): grey images and
//! pyramids, bilinear sampling, undistortion maps, FAST corners with Shi-Tomasi scores, the
//! equi-distributed quadtree (thesis Alg. 2), patch matching, Lucas-Kanade tracking, TV-L1
//! optical flow, stereo block matching, dense photometric SE(3) alignment (thesis eq. 6.7), ORB
//! features and a bag of binary words.
//!
//! Conventions: image coordinates have their origin at the top-left pixel centre, `u` to the
//! right, `v` down; pixels are `u8` or `f32`, geometry `f64`.

#![warn(missing_docs)]

pub mod bow;
pub mod dense;
pub mod fast;
pub mod image;
pub mod interp;
pub mod lk;
pub mod orb;
pub mod patch;
pub mod pyramid;
pub mod quadtree;
pub mod simd;
pub mod stereo;
pub mod tvl1;
pub mod undistort;

pub use image::{GrayImage, GrayImageF32, Image, ImageError};
