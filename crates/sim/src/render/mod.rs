//! Rendered image sequences with exact ground truth.
//!
//! The renderer turns textured worlds built in code into photometrically realistic images —
//! pinhole mono, rectified stereo, RGB-D — along seeded camera trajectories, so that the live
//! system can be tested on long loopy runs whose every pose, depth and disparity is known
//! exactly.
//!
//! * [`scene`]: worlds made of textured planar rectangles, with baked lighting and a sky;
//! * [`texture`], [`procedural`]: layered, seeded, band-limited procedural materials;
//! * [`cache`]: the materials' mip-mapped texture tiles, generated on first use;
//! * [`camera`]: render cameras (pinhole, optional radial-tangential distortion);
//! * [`raycast`]: the ray caster (exact ray–plane depth, edge supersampling, trilinear
//!   texture filtering);
//! * [`sensor`]: mono / stereo / RGB-D sensors with noise, exposure changes, motion blur,
//!   Kinect-like depth noise and holes;
//! * [`worlds`]: the room, the building loop and the courtyard;
//! * [`paths`]: their trajectories (hand-held browsing, a walk around the loop, laps);
//! * [`sequence`]: a scene, a trajectory and a sensor together, frame by frame.

pub mod cache;
pub mod camera;
mod error;
pub mod paths;
pub mod procedural;
pub mod quality;
pub mod raycast;
pub mod scene;
pub mod sensor;
pub mod sequence;
pub mod texture;
pub mod worlds;

pub use camera::RenderCamera;
pub use error::RenderError;
pub use raycast::{Pixel, ViewOptions};
pub use scene::Scene;
pub use sensor::{FrameImages, SensorKind, SensorModel};
pub use sequence::{DEFAULT_REVISIT_JITTER, Frame, SceneKind, Sequence, SequenceConfig, capture};

use cache::TextureCache;
use camera::RayTable;
use lie::Se3;

/// Default size of the texture-tile cache (bytes): enough for every tile a 640×480 view of any
/// of the worlds touches several times over, small beside a machine's memory.
pub const DEFAULT_CACHE_BYTES: usize = 384 << 20;

/// A scene with its texture cache and the ray table of the last camera: renders views.
pub struct Renderer {
    scene: Scene,
    cache: TextureCache,
    rays: Option<(RenderCamera, RayTable)>,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("scene", &self.scene.name)
            .field("quads", &self.scene.quads.len())
            .field("cache", &self.cache)
            .finish()
    }
}

impl Renderer {
    /// A renderer of `scene` with a tile cache of [`DEFAULT_CACHE_BYTES`].
    pub fn new(scene: Scene) -> Self {
        Self::with_cache_budget(scene, DEFAULT_CACHE_BYTES)
    }

    /// A renderer whose tile cache holds about `bytes` (tiles unused in the last frame are
    /// evicted beyond that; images do not depend on it).
    pub fn with_cache_budget(scene: Scene, bytes: usize) -> Self {
        let cache = TextureCache::new(&scene, bytes);
        Renderer {
            scene,
            cache,
            rays: None,
        }
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The texture cache (for statistics).
    pub fn cache(&self) -> &TextureCache {
        &self.cache
    }

    /// Renders the view of `camera` at `camera_from_world`: radiance, depth and incidence per
    /// pixel, row-major.
    pub fn render(
        &mut self,
        camera: &RenderCamera,
        camera_from_world: &Se3,
        opts: &ViewOptions,
    ) -> Result<Vec<Pixel>, RenderError> {
        if self.rays.as_ref().is_none_or(|(c, _)| c != camera) {
            self.rays = Some((*camera, RayTable::new(camera)?));
        }
        let (_, rays) = self.rays.as_ref().expect("set above");
        Ok(raycast::render_view(
            &self.scene,
            &self.cache,
            rays,
            camera_from_world,
            opts,
        ))
    }

    /// Ends a frame of the sequence (lets the cache evict tiles the frame did not use).
    pub fn end_frame(&mut self) {
        self.cache.end_frame();
    }
}
