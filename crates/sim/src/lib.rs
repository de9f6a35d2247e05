//! `sim`: synthetic worlds, camera trajectories and measurements with perfect data association,
//! seeded and deterministic, and the thesis's simulated experiments.

#![warn(missing_docs)]

pub mod ba_scene;
pub mod dwo;
pub mod preliminary;
pub mod render;
pub mod scale_drift;
pub mod sensor;
pub mod trajectory;
pub mod why_filter;
pub mod world;
