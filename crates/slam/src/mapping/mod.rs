//! The keyframe pipeline (thesis §6.2–6.4): the stages a keyframe goes through on its way into
//! the SLAM graph, as a library API that the simulator, the tests and the live system call.
//!
//! A keyframe's data flow, stage by stage ([`Mapper`], one method each; `docs/architecture.md`
//! draws it):
//!
//! 1. **track** ([`Mapper::predict_pose`], [`Mapper::track`]): a constant-velocity guess from
//!    the last two keyframes, in the reference keyframe's metric; the front-end matches the
//!    candidate points of `N1(ref)` ([`crate::tracking::tracking_candidates`]); robust
//!    motion-only BA against them (§6.2.5);
//! 2. **insert** ([`Mapper::insert_keyframe`]): the keyframe with its matched observations,
//!    local registration to every keyframe sharing `Θ` points (§6.2.6), and it becomes the
//!    reference. A pose tracked against a reference that moved meanwhile (an optimisation or a
//!    loop correction in another thread) is rebased onto the moved reference;
//! 3. **appearance loop** ([`Mapper::close_appearance_loop`]): a revisited place recognised
//!    by the front-end, with 3D–3D correspondences, is aligned (SE(3), or Sim(3) for
//!    monocular maps; eq. 5.11–5.14, 6.9) and inserted as a marginalised edge (§6.4.2);
//! 4. **metric loop** ([`Mapper::loop_predictions`], [`Mapper::close_metric_loops`]): the
//!    points of `N2 \ N1` are predicted in the keyframe, the front-end searches for them, and
//!    the matches join the keyframe to old ones (§6.4.1);
//! 5. **new points** ([`Mapper::add_points`]): the measurements left unmatched become points,
//!    from one measurement's disparity (stereo, RGB-D; eq. 6.6) or by two-view triangulation
//!    once a track has enough parallax (monocular);
//! 6. **optimise**: double window optimisation ([`crate::dwo`]).
//!
//! Data association is the front-end's ([`FrontEnd`]): the live system finds matches by
//! guided patch search in images, the simulator from its known world. [`KeyframePipeline`]
//! runs the stages in order in one thread (the synchronous mode: the simulator and the tests
//! drive exactly the code the live system runs); the live system calls the same stages from
//! its threads — tracking and insertion in the tracking thread, the optimiser in its own on a
//! [`SharedGraph`](crate::map::SharedGraph).

pub mod culling;
mod mapper;
mod pipeline;
pub mod registration;

pub use mapper::{
    AppearanceClosure, AppearanceFit, AppearanceMatch, AppearancePlan, Mapper, MappingConfig,
    MappingError, PreparedFrame, TrackedFrame,
};
pub use pipeline::{FrontEnd, KeyframePipeline, KeyframeReport};
pub use registration::register_locally;
