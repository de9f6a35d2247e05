//! The keyframe pipeline (thesis §6.2, §6.4): the stages a keyframe goes through on its way into
//! the SLAM graph, callable in order (the synchronous mode of the simulator and the tests) or
//! each from its own thread (the live system).

pub mod registration;

pub use registration::register_locally;
