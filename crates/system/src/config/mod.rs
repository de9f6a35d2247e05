//! The live system's parameters: every threshold with a default chosen from a principle (the
//! reason is written beside it), all overridable in a YAML config file (`dwslam run --config`).

mod slam;

use ::slam::mapping::culling::CullingConfig;
use geom::PinholeCamera;
use serde::Deserialize;
use std::path::Path;

/// Why a config file was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read the config file {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The YAML is malformed, has an unknown key or a value of the wrong type.
    #[error("config file {path}: {message}")]
    Parse {
        /// The file.
        path: String,
        /// What is wrong (the parser names the line).
        message: String,
    },
    /// A value is out of its range.
    #[error("config: {0}")]
    Invalid(String),
}

/// Every parameter of the live system.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SystemConfig {
    /// Pixel noise σ of the feature measurements (pixels): information `I/σ²` in tracking and
    /// optimisation. One pixel: FAST corners refined to sub-pixel by patch alignment are
    /// located to a fraction of a pixel on sharp images, to about a pixel on the motion-blurred
    /// frames of hand-held cameras.
    pub pixel_noise: f64,
    /// The per-frame tracker.
    pub tracker: TrackerConfig,
    /// When a frame becomes a keyframe and what it adds to the map.
    pub keyframes: KeyframeConfig,
    /// The keyframe pipeline (`slam::mapping`).
    pub mapping: MappingConfig,
    /// Double window optimisation.
    pub optimiser: OptimiserConfig,
    /// Stereo block matching (stereo sensors).
    pub stereo: StereoConfig,
    /// Depth noise coefficient `c` of `σ_z = c·z²` (1/m): place recognition's 3D inlier gate
    /// and the dense model's depth range. `None`: from the sensor — for a depth camera the
    /// Kinect's measured `1.425·10⁻³` (Khoshelham & Elberink 2012: 5.7 mm at 2 m), for stereo
    /// `σ_d/(f·b)` with a disparity noise of σ_d = 0.5 px (sub-pixel block matching).
    pub depth_noise: Option<f64>,
    /// Large-scale loop closure by appearance (thesis §6.4.2).
    pub loops: LoopConfig,
    /// The dense model of `dwslam run --dense-ply` (thesis §6.5.3; its `depth_noise` is the
    /// system's).
    pub dense: DenseModelConfig,
    /// The monocular system (`--sensor mono`, [`crate::mono`]).
    pub mono: MonoConfig,
}

/// Parameters of the monocular system ([`crate::mono`]): the image-side corner tracks and the
/// exploration they feed (`slam::exploration`).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MonoConfig {
    /// Corner tracks kept alive (300): new corners are selected where the tracks are sparse
    /// whenever fewer remain. Twice the features the exploration keeps (`max_features`), so a
    /// keyframe has candidates for new features wherever the map thins out.
    pub tracks: usize,
    /// A new corner needs this many pixels to the nearest live track (10 px: a LK window's
    /// half-size and a little more, so two tracks never follow the same texture).
    pub track_spacing: f64,
    /// FAST threshold of the corner selection (the stereo/RGB-D front-end's 20).
    pub fast_threshold: u8,
    /// Minimum quadtree cell of the selection, pixels (the front-end's 8).
    pub min_cell: f32,
    /// A track survives a frame only if LK back from it returns within this many pixels (1 px:
    /// a forward-backward error beyond a corner's own localisation error is a drift or an
    /// occlusion).
    pub max_forward_backward: f32,
    /// Pyramid levels of the tracking (4, as the front-end: ±40 px of motion at the finest
    /// level with LK's ±3 px per level).
    pub levels: usize,
    /// The finest pyramid levels on which a track's warp is affine rather than a translation
    /// (`vision::lk::LkParams::affine_levels`; 0: translation everywhere, the default so far).
    /// A translation-only window lags a patch that grows — every point of a forward drive —
    /// by up to 0.8 px on KITTI's road (`vision_bench lkroad`), a radial error the estimate
    /// turns into scale drift; affine levels follow the growth (bench/README.md, "The affine
    /// tracker"). Each affine level costs about as much as the whole translation tracker.
    pub lk_affine_levels: usize,
    /// Features (map points and filters) the exploration keeps (300, as many as the corner
    /// tracks: ≈ one per 32×32 px at 640×480, the density of the stereo system's 300 new points
    /// per keyframe). The thesis's §3.4.3 density for its simulated exploration, 150, left a
    /// live camera too few map points where some leave the view at once (measured on eleven
    /// monocular sequences: bench/README.md, "The defaults' measurements").
    pub max_features: usize,
    /// A new feature needs a feature-free box of this half-size, pixels (12).
    pub feature_spacing: f64,
    /// Seed of the order in which a keyframe's tracks are tried as new features (0). A
    /// monocular estimate is chaotic — which tracks become points changes the map's scale
    /// drift, and a drive's ATE moves by tens of per cent with it — so a default is compared
    /// over several seeds (`bench/live/mono_configs.sh`, `SEEDS`), not on one run.
    pub seed: u64,
    /// Keyframes the keyframe BA optimises: the new one, the one before it and those sharing
    /// most points with it (10, the thesis's window, §5.4).
    pub window: usize,
    /// A keyframe when the camera moved this fraction of the median scene depth from the last
    /// one (0.05: a 3° parallax at the median depth, enough to triangulate new features), or,
    /// with `keyframe_parallax`, when the tracked points' median parallax exceeds this many
    /// radians.
    pub keyframe_distance: f64,
    /// Measure a keyframe's baseline by the parallax of the tracked points (the median angle
    /// between their rays from the keyframe and from the frame,
    /// `slam::exploration::KeyframeBaseline::Parallax`) instead of by the distance over the
    /// scene depth. Off: it makes a driving camera's keyframes by what new points need, a third
    /// as many (KITTI 04: 55 instead of 150, ORB-SLAM3 73; the rendered town 288 instead of
    /// 844) and the monocular frame twice as fast by the median, but with this front-end's
    /// 100–140 map points per frame on a drive the sparser windows drift more: Sim(3) ATE
    /// after the run KITTI 04 74.5 against 138 cm, but KITTI 06 snippet 8.9 against 4.0 cm,
    /// 7-Scenes 4.7 against 3.8 cm, the town 214 / 171 against 53 / 28 cm (seeds 1, 2), the
    /// courtyard 9.0 against 2.6 cm (no loop closed), room 0.94 against 0.73 cm; at 0.03 rad
    /// no better (bench/README.md, "Keyframes by parallax"). The medians over five `seed`s
    /// agree (KITTI 04 81 against 145 cm, KITTI 06 8.9 against 4.2, 7-Scenes 4.9 against 4.3,
    /// the courtyard's loop never closed; bench/README.md, "Monocular defaults over five
    /// seeds").
    pub keyframe_parallax: bool,
    /// A feature started in a keyframe also takes in its corner track's first measurement
    /// since the keyframe before (`slam::exploration::ExplorationConfig::feature_history`):
    /// its filter starts with the parallax the track gathered before the keyframe (issue 42's
    /// "new points made early enough on fast forward motion"). Off: it helps the drives and
    /// costs the rooms. Medians of six `seed`s, Sim(3) ATE live / after the run, cm, against
    /// off: KITTI 04 92.3 / 93.2 against 110.9 / 111.2, KITTI 06 snippet 3.53 / 2.61 against
    /// 3.97 / 3.13, courtyard 8.42 / 7.08 against 9.27 / 7.57; but 7-Scenes 4.22 / 4.09
    /// against 4.04 / 3.91, the rendered room 1.41 / 1.38 against 0.74, the building 81.6 /
    /// 12.4 against 63.0 / 16.0, the town (three seeds) 256 / 144 against 136 / 52. With
    /// `keyframe_parallax` it does not bring the KITTI 06 snippet back (7.49 / 7.75 cm with 12
    /// keyframes; bench/README.md, "A feature's history").
    pub feature_history: bool,
    /// The bootstrap waits for the parallax at which a typical point's relative depth error
    /// is at most this (0.1: `θ ≥ √2·σ/(f·ε)`, 1.5° at f = 525 px, σ = 1 px).
    pub bootstrap_depth_error: f64,
    /// A feature's filter becomes a map point once its inverse depth is known to this relative
    /// standard deviation (`slam::exploration::feature_init`, `σ_q ≤ κ·q`; 0.1, the bootstrap's
    /// depth error: a point enters the window BA known as well as the map's first points).
    /// 0.05 was tried over three seeds (bench/README.md, twenty-eighth session; medians,
    /// Sim(3) ATE live / after): better live on the first town (172 / 79 against 305 / 77 cm),
    /// worse on KITTI 04 (174 against 144 cm) and the third town (366 / 181 against 248 / 163).
    pub feature_depth_error: f64,
    /// The bootstrap measures the tracks' noise on its two frames (the inliers' epipolar or
    /// homography residuals) and asks for the parallax that noise needs, not `pixel_noise`'s:
    /// the estimate is taken no lower than this many pixels (0.25: a corner followed by
    /// sub-pixel optical flow is located to about a quarter pixel on real images — the tracks
    /// of 7-Scenes' first frames measure 0.10–0.28 px, KITTI's 0.25–0.41 px — and a residual
    /// below it is more likely noise the fit absorbed than a better track).
    pub bootstrap_min_sigma: f64,
    /// Give up a bootstrap after this many frames and start again from the current one (30:
    /// a second at 30 Hz; a camera that has not moved enough by then is better started anew
    /// from what it sees now).
    pub max_bootstrap_frames: usize,
    /// The camera is lost after this many frames in a row in which the corner tracks could not
    /// be followed (10, a third of a second at 30 Hz: a black frame or a short glitch is waited
    /// out against the last good frame; after longer, the camera has moved too far for LK
    /// from there). A refused frame whose place the map has is relocalised there at once.
    pub max_refused: usize,
    /// A frame in which fewer than this fraction of the previous frame's tracks survive is
    /// refused (0.2: between two frames of a moving camera most corners stay in view and LK
    /// follows them; losing four fifths at once is a broken frame — black, corrupt,
    /// textureless — or a jump); the tracks wait for the next frame in the last good one.
    pub min_surviving_fraction: f64,
    /// New corners are selected when fewer than this fraction of `tracks` live (0.9: the
    /// selection costs a FAST pass over the image, a few milliseconds, so it runs every few
    /// frames rather than in every one, and the tracks stay within 10 % of their number).
    pub replenish_fraction: f64,
    /// Search the map points of nearby keyframes that no track measures, at the pose predicted
    /// for the frame (thesis §6.2.5: tracking against the points of the reference's
    /// neighbourhood, so a revisit measures the old map instead of triangulating it anew).
    pub refind: bool,
    /// Check each frame's measurement of every map point followed by a corner track against
    /// the point's template from its anchor keyframe (`crate::search::relocate`): the
    /// measurement moves to where the template aligns, and a track that drifted off its
    /// point or jumped to another corner stops measuring it. Optical flow drifts a little with
    /// every frame; a point measured for hundreds of frames (a camera browsing a mapped place)
    /// would otherwise be measured where its track has wandered to. A track the template
    /// cannot judge (its alignment does not settle: `crate::search::Relocated::Unaligned`) is
    /// kept on probation: it loses its point only if the frame's pose does not explain it
    /// (`slam::exploration::MonoExplorer::suspect`; `refuse_unaligned` refuses it instead).
    pub verify_tracks: bool,
    /// `verify_tracks` only where the template's predicted scale in the frame is within this
    /// factor of its anchor's (√2 ≈ 1.41: half an octave, the scales one pyramid level's
    /// template stands for, as PTAM picks the level); elsewhere the track's measurement
    /// stands. `None`: everywhere (the default so far). Driving forward brings every point
    /// nearer, and a template taken far away and magnified no longer shows the point's detail:
    /// on KITTI 04 the check then drops and moves the tracks that carry the parallax
    /// (bench/README.md, "The affine tracker").
    pub verify_within_scale: Option<f64>,
    /// `verify_tracks` also ends the association of a track whose template does not align to
    /// the frame (`crate::search::Relocated::Unaligned`: no evidence either way). `false` (the
    /// default): such a track keeps its point on probation, which it loses only if the pose of
    /// the frame's other measurements does not explain it (`MonoExplorer::suspect`). A fifth
    /// of a drive's checks do not settle; refused, the tracks that carry a drive's parallax
    /// are cut. Measured over three seeds with the same build (bench/README.md, "Tracks the
    /// template cannot judge"), `false` gains on every real sequence (KITTI 04 144 → 82 cm,
    /// KITTI 06 4.29 → 3.81 cm, 7-Scenes 4.81 → 4.03 cm live) and on two rendered towns of
    /// three, holds the room and the courtyard (six seeds) and a camera relocalised after a
    /// loss (`tests/mono_real.rs`), and loses after the run on the second town (81 → 128 cm)
    /// and the building (13.1 → 16.0 cm, six seeds each).
    pub refuse_unaligned: bool,
    /// The keyframes whose points are searched: of the last keyframe's neighbourhood (`N2`,
    /// thesis §6.4.1: the first `mapping.n2` keyframes of a breadth-first search over the
    /// keyframes sharing `mapping.theta` points, consecutive keyframes and accepted loops), the
    /// nearest this many (by camera centre) that look within `tracker.max_view_angle_deg` of the
    /// predicted direction (8: the covisible neighbourhood a stereo keyframe's `N1` has on the
    /// same sequences). A place revisited after a longer path than `N2` reaches is a loop: it
    /// is closed by appearance and the Sim(3) correction, not by searching its points with the
    /// drifted pose.
    pub refind_keyframes: usize,
    /// At most this many points are searched per frame: a bound on time only (each costs a
    /// warped template and a few correlations, ≈ 4 µs, so 500 is ≤ 2 ms), not a choice of
    /// points — the thesis's tracker searches every candidate of the neighbourhood. 500: the
    /// monocular sequences here have at most ~400 candidates in a frame (400 and no bound give
    /// identical runs on all seven; the earlier 200 cut the search in a few frames:
    /// bench/README.md, "The defaults' measurements").
    pub max_refind: usize,
    /// Optimise each keyframe by the monocular double window (thesis §6.2.7; windows and
    /// iterations from `optimiser`, covisibility edges by local registration with
    /// `mapping.theta`) instead of the exploration's sliding window of `window` keyframes.
    /// Off. Over three feature `seed`s it ends the run more accurate than the keyframe BA on
    /// eight of nine sequences by the median (KITTI 04 0.89 against 1.45 m, 7-Scenes 3.9
    /// against 4.5 cm, the room 0.37 against 0.73 cm, the towns' second and third seeds 0.49
    /// and 0.57 against 1.14 and 1.63 m; not the first town, 0.87 against 0.77 m), but live
    /// it is worse on KITTI 06 (5.8 against 4.3 cm), 7-Scenes (5.3 against 4.8 cm) and the
    /// town (one draw 19 m before its loops, a scale jump at a turn), and
    /// the tracking thread waits for its 40–90 ms per keyframe before the next frame reads the
    /// map (bench/README.md, "Monocular defaults over five seeds"; the single runs of seed 0:
    /// twenty-fourth session).
    pub double_window: bool,
    /// How the loops found by appearance correct the map: `sim3` (thesis ch. 5: rotation,
    /// translation and scale drift) or `se3` (rigid, for the thesis's comparison; without
    /// `correct_live` the other correction is written too, `trajectory_final_se3.tum` /
    /// `_sim3`).
    pub loop_correction: LoopCorrection,
    /// Detections in a row that must agree before a loop (or a join of two maps) is accepted
    /// (3: a repetitive place — the same façade, a corridor like another — can pass the
    /// appearance and 3-point checks once or twice, but its successive detections jump between
    /// unrelated old places; a real revisit keeps finding the old trajectory where the
    /// odometry since the last detection says it should be).
    pub loop_consistency: usize,
    /// When two successive detections agree: the second's similarity matches the first's
    /// carried by the odometry on both sides within these.
    pub loop_agreement: LoopAgreement,
    /// A loop detection counts only if at least this fraction of the old place's map points
    /// that its pose predicts visible are found there consistent with one pose (0.1). A
    /// look-alike place — a corridor's repeated doors, a street like another — passes the
    /// appearance check and matches its repeated parts at a consistent wrong pose, but not
    /// the rest of the place: on the rendered building's corridor, 92 such detections found
    /// 1.4–3.6 % of the predicted points (one 11 %), enough of them in a row to be accepted
    /// and wreck the map (10–19 m of ATE); the true loops of the building, courtyard and town
    /// found 13–55 % (the first glimpses of the building's revisit 4–6 %, accepted a few
    /// keyframes later). The count Θ alone (`mapping.theta`) does not scale with the place: a
    /// large place offers Θ chance matches.
    pub loop_min_found_fraction: f64,
    /// If set, a loop may move the current keyframe by at most this fraction of the path
    /// travelled since the old keyframe. Not set by default: a loop is accepted on its
    /// evidence (`loop_consistency` detections in a row that agree, each with the old place's
    /// points found again where it puts them, `mono/loops.rs`), not on a share of the path —
    /// a real drive came back to its first street with 16 % of drift, and a fixed 10 % refused
    /// every detection of that true loop (issue 42).
    pub max_loop_drift: Option<f64>,
    /// Correct the map when a loop is accepted, and go on exploring in the corrected map
    /// (thesis ch. 5, "both ends of the graph attached": the map points of the old place are
    /// found again in the corrected map), as well as once more at the end of the run. The pose
    /// graph is solved in the loop closer's thread on a snapshot of the graph and written into
    /// it by the tracking thread (`mono/loops.rs`, `LiveCorrection`). With it the run writes
    /// only `mono.loop_correction`'s correction (the SE(3) comparison is a run with
    /// `loop_correction: se3`). On by default since its corrections no longer compound (the
    /// pose graph's edges between its vertices, `map_edges`): after the run, rendered building
    /// 11.5 → 9.2 cm deterministic and 22.6 / 36.5 → 9.4 / 9.4 cm threaded, courtyard 7.2 →
    /// 3.4 cm, town seed 1 0.91 → 0.61 m (threaded, 3 runs: 0.74 / 0.81 / 0.53 → 0.41 / 0.52 /
    /// 0.64 m, live 2.8–4.2 → 0.75–2.6 m); town seed 2 0.50 → 0.99 m deterministic, threaded
    /// 0.39 / 0.27 / 0.63 → 0.84 / 0.26 / 0.46 m (bench/README, "Loops corrected while the run
    /// goes on"). The live ATE of a sequence that closes its loop late can rise (courtyard 8.2
    /// → 14.2 cm): frames before the loop stay in the drifted map, those after it are in the
    /// corrected one, and one alignment fits both.
    pub correct_live: bool,
    /// Keyframes outside the keyframe BA's window that measure its points join it as fixed
    /// poses, at most this many (10, as many as the window: those measuring most of the
    /// window's points carry nearly all the old map's hold on them). A revisited place's old
    /// keyframes keep its re-found points, and through them the new keyframes, where the old
    /// map has them: without them the window re-estimates the points from its own keyframes
    /// alone and the scale drifts (bench/README.md, "The defaults' measurements").
    pub fixed_observers: usize,
}

/// How monocular loops correct the map (thesis ch. 5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LoopCorrection {
    /// In Sim(3): rotation, translation and scale drift (thesis eq. 5.17).
    #[default]
    Sim3,
    /// In SE(3): rotation and translation only (the thesis's comparison).
    Se3,
}

/// When two successive loop detections agree (`MonoConfig::loop_agreement`): 5° of rotation,
/// 10 % of scale, and a tenth of the old keyframe's median scene depth of translation (the
/// keyframe criterion's 10 %).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopAgreement {
    /// Degrees of rotation.
    pub rotation_deg: f64,
    /// Relative difference of scale (of the log of the scale ratio).
    pub scale: f64,
    /// Translation, as a fraction of the old keyframe's median scene depth.
    pub translation: f64,
}

impl Default for LoopAgreement {
    fn default() -> Self {
        LoopAgreement {
            rotation_deg: 5.0,
            scale: 0.1,
            translation: 0.1,
        }
    }
}

impl Default for MonoConfig {
    fn default() -> Self {
        MonoConfig {
            tracks: 300,
            track_spacing: 10.0,
            fast_threshold: 20,
            min_cell: 8.0,
            max_forward_backward: 1.0,
            levels: 4,
            lk_affine_levels: 0,
            max_features: 300,
            feature_spacing: 12.0,
            seed: 0,
            window: 10,
            keyframe_distance: 0.05,
            keyframe_parallax: false,
            feature_history: false,
            bootstrap_depth_error: 0.1,
            feature_depth_error: 0.1,
            bootstrap_min_sigma: 0.25,
            max_bootstrap_frames: 30,
            max_refused: 10,
            min_surviving_fraction: 0.2,
            replenish_fraction: 0.9,
            refind: true,
            verify_tracks: true,
            verify_within_scale: None,
            refuse_unaligned: false,
            refind_keyframes: 8,
            max_refind: 500,
            double_window: false,
            loop_correction: LoopCorrection::Sim3,
            loop_consistency: 3,
            loop_agreement: LoopAgreement::default(),
            loop_min_found_fraction: 0.1,
            max_loop_drift: None,
            correct_live: true,
            fixed_observers: 10,
        }
    }
}

/// Large-scale loop closure (thesis §6.4.2; [`crate::loops`]).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopConfig {
    /// Close loops by appearance (true).
    pub enabled: bool,
    /// The vocabulary, a DBoW2 YAML file of dwslam ORB words (`dwslam vocabulary`); `None`:
    /// the default vocabulary, trained on the shared images disjoint from every test sequence
    /// and cached (`system::place_recognition::vocabulary`).
    pub vocabulary: Option<std::path::PathBuf>,
    /// Keyframes within this many edges of the keyframe graph are topologically close and
    /// never joined by an appearance loop (2: the keyframes sharing Θ points with the new one
    /// and theirs — local registration and metric loop closure already join those).
    pub exclusion_hops: usize,
    /// The last this many keyframes before a new one are topologically close to it as well,
    /// whatever the graph says (10: the tracker's chain joins them; in a fast turn consecutive
    /// keyframes share too few points for an edge, and an appearance "loop" between them —
    /// seen on the rendered revisit room, keyframes 2–6 apart — is no revisit and can break
    /// the map; the appearance loops of 7-Scenes join keyframes ≥ 11 apart; the monocular
    /// exploration's window is 10 keyframes).
    pub exclusion_recent: usize,
    /// Keyframes queued for the loop closer's thread at most (16: detection takes ~20 ms,
    /// keyframes come a few per second, so the queue only fills while the loop thread works
    /// for seconds — a live loop correction of a long drive takes up to ~0.8 s). A keyframe
    /// that finds it full waits in the tracking thread, which never blocks on it, and goes to
    /// the loop closer as it makes room: none is left out of the keyframe database (until the
    /// eighteenth session they were dropped, 14 of 870 keyframes on the rendered town); the run
    /// reports how many waited.
    pub queue: usize,
    /// Place recognition's thresholds (its `depth_noise` is the system's).
    pub place_recognition: crate::place_recognition::PlaceRecognitionConfig,
    /// A loop by appearance (stereo and RGB-D) may move its keyframe by at most this fraction
    /// of the path the map joins the two places by (0.05: stereo and RGB-D odometry drift by
    /// 1–2 % of the distance; `slam::mapping::MappingConfig::new` gives the measurements) ...
    pub max_drift_of_path: f64,
    /// ... or by this fraction of the old place's scene depth, if more (0.1: the keyframe
    /// criterion's coverage, within which the two views are one place whatever the path).
    /// Loops needing more join two places that only look alike; each refused loop is named in
    /// the run's warnings. (Monocular loops: 10 % of the path, `mono.rs`.)
    pub max_drift_of_scene_depth: f64,
}

impl Default for LoopConfig {
    fn default() -> Self {
        LoopConfig {
            enabled: true,
            vocabulary: None,
            exclusion_hops: 2,
            exclusion_recent: 10,
            queue: 16,
            place_recognition: Default::default(),
            max_drift_of_path: 0.05,
            max_drift_of_scene_depth: 0.1,
        }
    }
}

impl Default for SystemConfig {
    fn default() -> Self {
        SystemConfig {
            pixel_noise: 1.0,
            tracker: TrackerConfig::default(),
            keyframes: KeyframeConfig::default(),
            mapping: MappingConfig::default(),
            optimiser: OptimiserConfig::default(),
            stereo: StereoConfig::default(),
            depth_noise: None,
            loops: LoopConfig::default(),
            dense: Default::default(),
            mono: MonoConfig::default(),
        }
    }
}

impl SystemConfig {
    /// The depth noise coefficient for `camera` (see [`SystemConfig::depth_noise`]);
    /// `stereo`: depth from block matching.
    pub fn depth_noise_for(&self, camera: &geom::StereoCamera, stereo: bool) -> f64 {
        self.depth_noise.unwrap_or(if stereo {
            0.5 / (camera.pinhole.fx * camera.baseline)
        } else {
            KINECT_DEPTH_NOISE
        })
    }
}

/// Parameters of the per-frame tracker (thesis §6.3).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerConfig {
    /// FAST threshold (grey levels). 12: the Kinect's colour camera and rendered images both
    /// give several hundred corners per 640×480 frame at this level, while sensor noise (σ of
    /// 2–3 grey levels) stays far below it.
    pub fast_threshold: u8,
    /// Pyramid levels of the dense prior.
    pub pyramid_levels: usize,
    /// The dense prior (eq. 6.7) stops at this pyramid level: its job is a prior good to a
    /// couple of pixels for the guided search (which refines to sub-pixel accuracy), and a
    /// level-2 pixel is 4 pixels at full resolution — alignment to a fraction of that is within
    /// the search radius, at 1/16 of level 0's cost (7-Scenes, 1000 frames: the same ATE as
    /// level 1 in a quarter of the time).
    pub dense_finest_level: usize,
    /// Gauss-Newton iterations per level of the dense prior (it converges in a few from the
    /// constant-velocity guess; 10 bound the worst case).
    pub dense_iterations: usize,
    /// Guided-search radius after a good dense prior (pixels; thesis §6.3: 1–3).
    pub search_radius: f64,
    /// Guided-search radius when the prior is weak (dense alignment failed: constant
    /// velocity only).
    pub wide_search_radius: f64,
    /// A patch matches when its normalised cross-correlation with the warped 8×8 template is
    /// at least this. Correlation is invariant to the gain and offset changes of auto-exposure,
    /// and its threshold means the same on sharp and blurred, high- and low-contrast patches:
    /// 0.8 accepts a patch whose texture variance is four times the noise variance of the
    /// difference (on 7-Scenes a zero-mean SSD gate, which depends on contrast, lost a fifth of
    /// the true matches on blurred frames).
    pub min_ncc: f32,
    /// At most this many candidate points are searched per frame, chosen spread over the image
    /// (a pose is over-determined hundreds of times by them; more only costs time).
    pub max_searched: usize,
    /// A candidate is searched only if the angle between its rays from the anchor keyframe
    /// and from the current camera is below this (degrees): beyond it the template, warped for
    /// a fronto-parallel plane, no longer predicts the patch (PTAM's visibility test).
    pub max_view_angle_deg: f64,
    /// Inliers (after motion-only BA) for a good frame. 40: twenty times over-determined.
    /// After a lost frame the next must be good to count as tracked (a weak one stays lost).
    pub min_good: usize,
    /// Inliers below which the frame is lost (it then has no pose). 12: a six-DoF pose
    /// from 3D measurements is over-determined sixfold, with margin for the outliers the χ²
    /// gate lets through.
    pub min_tracked: usize,
    /// Seconds of lost frames (relocalisation tried at each) after which a frame with depth
    /// starts a new map at the motion model's guess, in which tracking goes on until an
    /// appearance loop finds the old map and merges the two (ORB-SLAM3's atlas, which starts
    /// one after 3 s without an IMU). 3 s as there: a camera that comes back to the map
    /// sooner is relocalised at its first frame that shows a mapped place, and keeps a
    /// trajectory without guessed offsets; a camera that does not come back within it (a view
    /// the map never held) goes on in the new map instead of staying lost (bench/README.md,
    /// "The defaults' measurements"). `.inf` never starts one. A monocular camera relocalises
    /// alike (P3P against the keyframes' points) for as long, then bootstraps a new map (at
    /// once where nothing can find it: no vocabulary); 0 starts one at once.
    pub new_map_after: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            fast_threshold: 12,
            pyramid_levels: 4,
            dense_finest_level: 2,
            dense_iterations: 10,
            search_radius: 3.0,
            wide_search_radius: 12.0,
            min_ncc: 0.8,
            max_searched: 400,
            max_view_angle_deg: 35.0,
            min_good: 40,
            min_tracked: 12,
            new_map_after: 3.0,
        }
    }
}

/// When a frame becomes a keyframe (thesis §6.2.6) and what it adds.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeConfig {
    /// A keyframe when the camera moved this fraction of the median scene depth away from
    /// every keyframe of `N1` (the parallax that makes a new view informative: 10 %, about
    /// 6° at the scene) ...
    pub parallax: f64,
    /// ... or rotated this much (degrees) from every keyframe of `N1` (the field of view moves
    /// on and their points leave the image). A keyframe within both thresholds covers the view
    /// and no keyframe is added (`crate::keyframes::keyframe_reason`).
    pub rotation_deg: f64,
    /// ... or fewer of the candidate points than this fraction were found (the map around
    /// the camera is thin).
    pub min_found_fraction: f64,
    /// New points per keyframe: at most this many, equi-distributed by the quadtree
    /// (thesis §3.4.3).
    pub max_new_points: usize,
    /// A new point needs this much room (pixels) from the keyframe's tracked points.
    pub new_point_spacing: f64,
    /// New points only where no point of the keyframe's neighbours (`N1`) lies on the same
    /// surface, found by tracking or not (off: only where the keyframe measures none). On: a
    /// revisited surface keeps its points and the map its size (the rendered room browsed for
    /// 9000 frames: 18.5 k points instead of 91 k, 160 keyframes with `cull` instead of 324);
    /// off by default because the points tracking did not find are not all findable, and the
    /// new ones it would have had are missed: on 7-Scenes 5.2 k points instead of 13.7 k, and
    /// a camera kidnapped or blinded there is found later (bench/README "Bounded maps").
    pub reuse_map_points: bool,
    /// Remove the map points tracking no longer finds (stereo and RGB-D; a binomial test at
    /// 95 % that a point is found in fewer than `min_found_fraction` of the well-tracked frames
    /// that search it: `crate::tracker::Tracker::unfound_points`), when a keyframe is made;
    /// only points no other keyframe measures (those still tie two poses together). Off by
    /// default: on 7-Scenes it helps (ATE 4.65 / 4.48 cm instead of 4.91 / 4.72, 1.8× the
    /// frames per second), on the KITTI snippet it costs (7.29 / 6.61 cm instead of
    /// 6.09 / 5.22: driving forward, the points the corners' scale change hides are not bad
    /// points). For long browsing with `reuse_map_points` (bench/README "Bounded maps").
    pub cull_points: bool,
    /// Cull redundant keyframes (stereo and RGB-D; `slam::mapping::culling`): when a keyframe
    /// is made, its neighbours whose points others measure are removed, so that revisits keep
    /// the map's size bounded (lifelong mapping).
    pub cull: bool,
    /// A keyframe is redundant when this fraction of its points is measured by at least
    /// `cull_other_observers` other keyframes (see `slam::mapping::culling::CullingConfig`
    /// for the defaults' reasons).
    pub cull_kept_fraction: f64,
    /// See `cull_kept_fraction`.
    pub cull_other_observers: usize,
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        let culling = CullingConfig::default();
        KeyframeConfig {
            parallax: 0.1,
            rotation_deg: 10.0,
            min_found_fraction: 0.5,
            max_new_points: 300,
            new_point_spacing: 10.0,
            reuse_map_points: false,
            cull_points: false,
            cull: culling.enabled,
            cull_kept_fraction: culling.kept_fraction,
            cull_other_observers: culling.other_observers,
        }
    }
}

/// The keyframe pipeline's parameters that a user may change (`slam::mapping::MappingConfig`).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MappingConfig {
    /// `Θ`, covisible points for an edge (thesis §6.2.6: 15–30).
    pub theta: usize,
    /// Keyframes of `N2`, searched by metric loop closure.
    pub n2: usize,
    /// Guided-search radius of metric loop closure (pixels; thesis §6.4.1: e.g. 10).
    pub loop_search_radius: f64,
}

impl Default for MappingConfig {
    fn default() -> Self {
        MappingConfig {
            theta: 20,
            n2: 100,
            loop_search_radius: 10.0,
        }
    }
}

/// Double window optimisation (thesis §6.2.3–6.2.4).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OptimiserConfig {
    /// `M1`, keyframes of the inner window.
    pub inner: usize,
    /// `M2`, keyframes of the outer window.
    pub outer: usize,
    /// Levenberg-Marquardt iterations per optimisation (thesis §6.5.1: 3).
    pub iterations: usize,
    /// Levenberg-Marquardt iterations of each of the two optimisations that end a stereo or
    /// RGB-D run, the double window with every keyframe in the outer window (the pose graph of
    /// the whole map), then the bundle adjustment over every keyframe and point, both from the
    /// poses as they are (`slam::dwo::DoubleWindowOptimiser::finishing`; the trajectory after
    /// the run is every frame relative to its keyframe after them); 0: none, the last double
    /// window is the final state. The windows leave the
    /// map locally exact but, where a lap's metric loops pull old keyframes into the inner
    /// window, they move those towards the newer (drifted) view instead of spreading the
    /// correction (rendered courtyard seed 3: first-lap keyframes 1.5–2.5 cm off against 0.5
    /// cm live). 5: bench/README.md, "The defaults' measurements".
    pub final_iterations: usize,
}

impl Default for OptimiserConfig {
    /// The thesis's stereo New College run used 25 / 175 (§6.5.2); the simulated spiral 15 /
    /// 50. 20 / 100 keeps the inner window's bundle adjustment within a few tens of
    /// milliseconds on one core while the outer window reaches the far side of a room.
    fn default() -> Self {
        OptimiserConfig {
            inner: 20,
            outer: 100,
            iterations: 3,
            final_iterations: 5,
        }
    }
}

/// Stereo block matching (thesis §6.3).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StereoConfig {
    /// Largest disparity searched (pixels); `None`: from the camera, `f/6` rounded up to a
    /// multiple of 16 — depths down to six baselines (KITTI's 0.54 m rig: 3.2 m, the nearest
    /// road; EuRoC's 0.11 m: 0.7 m). Nearer points have no depth (they are tracked, not
    /// initialised). On the KITTI snippet 64 disparities (down to 6 m) gave 9.7 cm ATE, 128
    /// gave 6.4 cm.
    pub max_disparity: Option<usize>,
    /// Block radius (the block is `(2r+1)²`).
    pub block_radius: usize,
    /// With `matching: dense`, the pyramid level the block matching runs at (0: full
    /// resolution). The disparity map is
    /// the start of each point's own disparity measurement (`vision::stereo::point_disparity`,
    /// at full resolution) and the depth of the dense prior (level 2 and coarser), so a coarser
    /// map costs little accuracy and saves most of a stereo frame's time: level 1 matches a
    /// quarter of the pixels over half the disparities (KITTI 1226×370: frame 45 → 12 ms;
    /// rendered 640×480: 35 → 74 frames per second, deterministic). 0 by default because full
    /// resolution was the more accurate on every sequence measured (bench/README.md, "The
    /// defaults' measurements"). The points' own measurements are as accurate at either level
    /// (`tests/stereo_rendered.rs`); which corners get one differs.
    pub level: usize,
    /// How the points' disparities are found: `sparse` searches each point's own row of the
    /// right image (`vision::stereo::sparse`; ORB-SLAM3 likewise matches its keypoints only),
    /// `dense` block-matches every pixel at `level` and reads the map at the point. Either way
    /// the measurement is the point's own patch aligned along the row from there. Sparse by
    /// default: the same measurements for a fraction of a frame's time (bench/README.md,
    /// "Sparse stereo"); the dense prior then uses a disparity image matched at
    /// `tracker.dense_finest_level`, and `--dense-ply` block-matches the keyframes alone.
    pub matching: StereoMatching,
    /// Threads block matching runs on, each on a horizontal band of the image (the same
    /// disparities bit for bit: `vision::stereo::StereoMatcher::compute_in_bands`); `None`: the
    /// cores this process may run on (one under `taskset -c N`, as in `bench/live`).
    pub threads: Option<usize>,
}

impl Default for StereoConfig {
    /// Disparities from the camera, 9×9 blocks (`vision::stereo`'s default, checked on
    /// Middlebury), at full resolution.
    fn default() -> Self {
        StereoConfig {
            max_disparity: None,
            block_radius: 4,
            level: 0,
            matching: StereoMatching::Sparse,
            threads: None,
        }
    }
}

/// How stereo finds the points' disparities ([`StereoConfig::matching`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StereoMatching {
    /// Each point searched along its row.
    Sparse,
    /// A disparity image of every pixel.
    Dense,
}

impl StereoConfig {
    /// The threads of block matching ([`StereoConfig::threads`]).
    pub fn threads(&self) -> usize {
        self.threads.unwrap_or_else(|| {
            std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
        })
    }

    /// The largest disparity searched for a camera of focal length `focal` (pixels).
    pub fn max_disparity_for(&self, focal: f64) -> usize {
        self.max_disparity
            .unwrap_or_else(|| ((focal / 6.0 / 16.0).ceil() as usize).max(1) * 16)
    }
}

impl SystemConfig {
    /// Reads a YAML config file: keys it gives override the defaults; an unknown key is an
    /// error naming it.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_yaml(&text).map_err(|e| match e {
            ConfigError::Parse { message, .. } => ConfigError::Parse {
                path: path.display().to_string(),
                message,
            },
            other => other,
        })
    }

    /// Parses YAML text (see [`from_file`](Self::from_file)).
    pub fn from_yaml(text: &str) -> Result<Self, ConfigError> {
        let config: SystemConfig = if text.trim().is_empty() {
            SystemConfig::default()
        } else {
            serde_saphyr::from_str(text).map_err(|e| ConfigError::Parse {
                path: "<text>".into(),
                message: e.to_string(),
            })?
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks the ranges, section by section (each section's own `validate`), and the values
    /// that relate sections; the message names the key.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let invalid = ConfigError::Invalid;
        if !(self.pixel_noise.is_finite() && self.pixel_noise > 0.0) {
            return Err(invalid(format!(
                "pixel_noise must be positive (got {})",
                self.pixel_noise
            )));
        }
        if self
            .depth_noise
            .is_some_and(|c| !(c.is_finite() && c > 0.0))
        {
            return Err(invalid("depth_noise must be positive".into()));
        }
        self.tracker.validate().map_err(invalid)?;
        self.keyframes.validate().map_err(invalid)?;
        self.mapping.validate().map_err(invalid)?;
        self.optimiser.validate().map_err(invalid)?;
        self.stereo.validate().map_err(invalid)?;
        self.loops.validate().map_err(invalid)?;
        self.mono.validate().map_err(invalid)?;
        self.dense.validate().map_err(|e| invalid(e.to_string()))?;
        if self.stereo.level >= self.tracker.pyramid_levels {
            return Err(invalid(format!(
                "stereo.level ({}) must be below tracker.pyramid_levels ({})",
                self.stereo.level, self.tracker.pyramid_levels
            )));
        }
        Ok(())
    }
}

impl TrackerConfig {
    /// Checks the ranges; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        let t = self;
        if t.pyramid_levels == 0 || t.dense_finest_level >= t.pyramid_levels {
            return Err(format!(
                "tracker.dense_finest_level ({}) must be below tracker.pyramid_levels ({})",
                t.dense_finest_level, t.pyramid_levels
            ));
        }
        if !(t.search_radius > 0.0 && t.wide_search_radius >= t.search_radius) {
            return Err(
                "tracker.search_radius must be positive and at most tracker.wide_search_radius"
                    .into(),
            );
        }
        if !(t.min_ncc > 0.0 && t.min_ncc < 1.0) {
            return Err(format!(
                "tracker.min_ncc must lie in (0, 1) (got {})",
                t.min_ncc
            ));
        }
        if t.new_map_after.is_nan() || t.new_map_after < 0.0 {
            return Err(format!(
                "tracker.new_map_after ({}) must be a number of seconds, at least 0 (.inf: never)",
                t.new_map_after
            ));
        }
        if t.min_tracked < 6 || t.min_good < t.min_tracked {
            return Err(format!(
                "tracker.min_tracked must be at least 6 (a pose) and at most tracker.min_good (got {}, {})",
                t.min_tracked, t.min_good
            ));
        }
        Ok(())
    }
}

impl KeyframeConfig {
    /// Checks the ranges; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.parallax > 0.0
            && self.rotation_deg > 0.0
            && (0.0..=1.0).contains(&self.min_found_fraction))
        {
            return Err("keyframes.parallax and rotation_deg must be positive, min_found_fraction in [0, 1]".into());
        }
        if !((0.0..=1.0).contains(&self.cull_kept_fraction) && self.cull_other_observers >= 1) {
            return Err(
                "keyframes.cull_kept_fraction must be in [0, 1], cull_other_observers at least 1"
                    .into(),
            );
        }
        Ok(())
    }

    /// Keyframe culling's parameters.
    pub fn culling(&self) -> CullingConfig {
        CullingConfig {
            enabled: self.cull,
            kept_fraction: self.cull_kept_fraction,
            other_observers: self.cull_other_observers,
        }
    }
}

impl MappingConfig {
    /// Checks the ranges; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if self.theta == 0 {
            return Err("mapping.theta must be at least 1".into());
        }
        Ok(())
    }
}

impl OptimiserConfig {
    /// Checks the ranges; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if self.inner == 0 || self.iterations == 0 {
            return Err("optimiser.inner and optimiser.iterations must be at least 1".into());
        }
        Ok(())
    }
}

impl StereoConfig {
    /// Checks the ranges; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if self.threads == Some(0) {
            return Err("stereo.threads must be at least 1".into());
        }
        if self.max_disparity == Some(0) {
            return Err("stereo.max_disparity must be at least 1".into());
        }
        Ok(())
    }
}

impl LoopConfig {
    /// Checks the ranges; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        for (name, v) in [
            ("loops.max_drift_of_path", self.max_drift_of_path),
            (
                "loops.max_drift_of_scene_depth",
                self.max_drift_of_scene_depth,
            ),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} must be a fraction >= 0 (got {v})"));
            }
        }
        if self.queue == 0 {
            return Err("loops.queue must be at least 1".into());
        }
        self.place_recognition.validate().map_err(|e| e.to_string())
    }
}

impl MonoConfig {
    /// Checks the ranges; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        let m = self;
        if m.lk_affine_levels > m.levels {
            return Err(format!(
                "mono.lk_affine_levels ({}) cannot exceed mono.levels ({})",
                m.lk_affine_levels, m.levels
            ));
        }
        if m.verify_within_scale.is_some_and(|s| s.is_nan() || s < 1.0) {
            return Err("mono.verify_within_scale must be at least 1 (a factor of scale)".into());
        }
        if m.tracks < 8 || m.levels == 0 || m.window < 2 || m.max_features < 8 {
            return Err(
                "mono.tracks and mono.max_features must be at least 8, mono.levels at least 1, mono.window at least 2"
                    .into(),
            );
        }
        if !(m.keyframe_distance > 0.0
            && m.bootstrap_depth_error > 0.0
            && m.feature_depth_error > 0.0
            && m.bootstrap_min_sigma > 0.0
            && m.track_spacing >= 0.0
            && m.feature_spacing >= 0.0
            && m.max_forward_backward > 0.0)
        {
            return Err("mono.keyframe_distance, bootstrap_depth_error, feature_depth_error, bootstrap_min_sigma and max_forward_backward must be positive, the spacings non-negative".into());
        }
        if m.max_bootstrap_frames == 0 || m.max_refused == 0 || m.loop_consistency == 0 {
            return Err(
                "mono.max_bootstrap_frames, mono.max_refused and mono.loop_consistency must be at least 1"
                    .into(),
            );
        }
        let fraction = |x: f64| (0.0..=1.0).contains(&x);
        if !fraction(m.min_surviving_fraction)
            || !fraction(m.replenish_fraction)
            || !fraction(m.loop_min_found_fraction)
        {
            return Err(
                "mono.min_surviving_fraction, mono.replenish_fraction and mono.loop_min_found_fraction must lie in [0, 1]".into(),
            );
        }
        let a = &m.loop_agreement;
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !(positive(a.rotation_deg) && positive(a.scale) && positive(a.translation)) {
            return Err(
                "mono.loop_agreement's rotation_deg, scale and translation must be positive".into(),
            );
        }
        if let Some(d) = m.max_loop_drift
            && !(d.is_finite() && d >= 0.0)
        {
            return Err(format!(
                "mono.max_loop_drift must be a fraction >= 0 (got {d})"
            ));
        }
        Ok(())
    }
}

// The dense model's parameters live here with the others (`crate::dense_model` uses them);
// see that module for the fusion they control.

/// The depth noise of a Kinect-class structured-light sensor, `σ_z = c·z²` with
/// `c = 1.425·10⁻³ /m` (Khoshelham & Elberink 2012; 5.7 mm at 2 m).
pub const KINECT_DEPTH_NOISE: f64 = 1.425e-3;

/// The typical range of an indoor RGB-D recording, metres (7-Scenes and TUM RGB-D scenes lie at
/// 1–3 m).
pub const TYPICAL_DEPTH: f64 = 2.0;

/// Parameters of the fusion (serde: the live system's YAML config overrides them).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenseModelConfig {
    /// Edge length of a voxel, metres. Default `3·σ_z` at the typical depth
    /// (3 × 5.7 mm = 1.7 cm for a Kinect at 2 m): a surface's samples, spread by `±σ_z` along
    /// its normal, then fall into one layer of voxels (a thinner voxel makes a surface several
    /// layers thick, a thicker one blurs detail the sensor resolves).
    pub voxel_size: f64,
    /// Voxels seen from fewer keyframes are discarded (2: the least agreement between
    /// independent views that tells a surface from a one-frame outlier).
    pub min_views: usize,
    /// Pixel stride of the samples; `None`: the stride at which samples at the typical depth
    /// lie half a voxel apart (`⌊f·voxel/(2·z)⌋`, 2 px for a Kinect): every voxel a surface
    /// crosses gets samples, no more than needed.
    pub stride: Option<usize>,
    /// Depth noise coefficient `c` of `σ_z = c·z²`, 1/m ([`KINECT_DEPTH_NOISE`]; a stereo
    /// camera: `σ_d/(f·b)`). Not read from the live system's config file: [`crate::dense_model::fuse`] takes the
    /// system's (`SystemConfig::depth_noise`).
    #[serde(skip)]
    pub depth_noise: f64,
    /// Farthest depth used, metres; `None`: where the noise reaches the voxel size,
    /// `√(voxel/c)` (3.5 m for the defaults): farther samples scatter over several voxels.
    pub max_depth: Option<f64>,
    /// A sample is dropped if its 3×3 neighbourhood's depths spread more than this relative
    /// amount (0.05: a depth edge, where pixels mix both sides; see
    /// `crate::frame::depth_off_edges`).
    pub depth_edge_ratio: f64,
}

impl Default for DenseModelConfig {
    fn default() -> Self {
        DenseModelConfig {
            voxel_size: 3.0 * KINECT_DEPTH_NOISE * TYPICAL_DEPTH * TYPICAL_DEPTH,
            min_views: 2,
            stride: None,
            depth_noise: KINECT_DEPTH_NOISE,
            max_depth: None,
            depth_edge_ratio: 0.05,
        }
    }
}

/// A configuration value out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("dense model config: {0}")]
pub struct DenseModelError(pub String);

impl DenseModelConfig {
    /// Checks the ranges; the message names the field.
    pub fn validate(&self) -> Result<(), DenseModelError> {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !positive(self.voxel_size) {
            return Err(DenseModelError("voxel_size must be positive".into()));
        }
        if self.min_views == 0 {
            return Err(DenseModelError("min_views must be at least 1".into()));
        }
        if self.stride == Some(0) {
            return Err(DenseModelError("stride must be at least 1".into()));
        }
        if !positive(self.depth_noise) || !positive(self.depth_edge_ratio) {
            return Err(DenseModelError(
                "depth_noise and depth_edge_ratio must be positive".into(),
            ));
        }
        if self.max_depth.is_some_and(|d| !positive(d)) {
            return Err(DenseModelError("max_depth must be positive".into()));
        }
        Ok(())
    }

    /// The stride for a camera (see [`DenseModelConfig::stride`]).
    pub fn stride_for(&self, camera: &PinholeCamera) -> usize {
        self.stride.unwrap_or_else(|| {
            let f = 0.5 * (camera.fx + camera.fy);
            ((f * self.voxel_size / (2.0 * TYPICAL_DEPTH)).floor() as usize).max(1)
        })
    }

    /// The farthest depth used (see [`DenseModelConfig::max_depth`]).
    pub fn max_depth(&self) -> f64 {
        self.max_depth
            .unwrap_or_else(|| (self.voxel_size / self.depth_noise).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaml_overrides_defaults_and_refuses_unknown_keys() {
        let c =
            SystemConfig::from_yaml("tracker:\n  search_radius: 2.5\noptimiser:\n  inner: 10\n")
                .unwrap();
        assert_eq!(c.tracker.search_radius, 2.5);
        assert_eq!(c.optimiser.inner, 10);
        assert_eq!(c.optimiser.outer, OptimiserConfig::default().outer);
        assert_eq!(
            SystemConfig::from_yaml("").unwrap(),
            SystemConfig::default()
        );
        let e = SystemConfig::from_yaml("tracker:\n  serch_radius: 2\n").unwrap_err();
        assert!(e.to_string().contains("serch_radius"), "{e}");
        let e = SystemConfig::from_yaml("pixel_noise: -1\n").unwrap_err();
        assert!(e.to_string().contains("pixel_noise"), "{e}");
        let e = SystemConfig::from_yaml("tracker:\n  dense_finest_level: 9\n").unwrap_err();
        assert!(e.to_string().contains("dense_finest_level"), "{e}");
        let e = SystemConfig::from_yaml("tracker:\n  new_map_after: -1\n").unwrap_err();
        assert!(e.to_string().contains("new_map_after"), "{e}");
        let c = SystemConfig::from_yaml("tracker:\n  new_map_after: .inf\n").unwrap();
        assert_eq!(c.tracker.new_map_after, f64::INFINITY);
        let e = SystemConfig::from_yaml("stereo:\n  level: 4\n").unwrap_err();
        assert!(e.to_string().contains("stereo.level"), "{e}");
        let c = SystemConfig::from_yaml("stereo:\n  level: 1\n").unwrap();
        assert_eq!(c.stereo.level, 1);
        let e = SystemConfig::from_yaml("stereo:\n  threads: 0\n").unwrap_err();
        assert!(e.to_string().contains("stereo.threads"), "{e}");
        let c = SystemConfig::from_yaml("stereo:\n  threads: 3\n").unwrap();
        assert_eq!(c.stereo.threads(), 3);
        assert!(SystemConfig::default().stereo.threads() >= 1);
        let c =
            SystemConfig::from_yaml("mono:\n  lk_affine_levels: 2\n  verify_within_scale: 1.41\n")
                .unwrap();
        assert_eq!(
            (c.mono.lk_affine_levels, c.mono.verify_within_scale),
            (2, Some(1.41))
        );
        assert!(!SystemConfig::default().mono.refuse_unaligned);
        let c = SystemConfig::from_yaml("mono:\n  refuse_unaligned: true\n").unwrap();
        assert!(c.mono.refuse_unaligned);
        let e = SystemConfig::from_yaml("mono:\n  lk_affine_levels: 5\n").unwrap_err();
        assert!(e.to_string().contains("lk_affine_levels"), "{e}");
        let e = SystemConfig::from_yaml("mono:\n  verify_within_scale: 0.5\n").unwrap_err();
        assert!(e.to_string().contains("verify_within_scale"), "{e}");
    }

    #[test]
    fn the_monocular_seed_and_promotion_threshold_reach_the_exploration() {
        let exploration = |yaml: &str| {
            SystemConfig::from_yaml(yaml)
                .unwrap()
                .exploration(700.0, 1241, 376)
        };
        assert_eq!(exploration("").seed, 0);
        assert_eq!(exploration("mono:\n  seed: 7\n").seed, 7);
        assert!(SystemConfig::from_yaml("mono:\n  seed: -1\n").is_err());
        // The promotion threshold of the features' filters.
        let kappa = |e: ::slam::exploration::ExplorationConfig| {
            e.feature_init.max_relative_inverse_depth_std
        };
        assert_eq!(kappa(exploration("")), 0.1);
        assert_eq!(
            kappa(exploration("mono:\n  feature_depth_error: 0.05\n")),
            0.05
        );
        assert!(SystemConfig::from_yaml("mono:\n  feature_depth_error: 0\n").is_err());
    }
}
