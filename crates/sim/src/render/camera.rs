//! Render cameras: a pinhole with optional radial-tangential distortion, and the table of
//! per-pixel rays the renderer shoots.

use super::RenderError;
use geom::{CameraModel, DistortedCamera, Distortion, PinholeCamera, RadTan};
use nalgebra::{Vector2, Vector3};

/// Side of the square pixel tiles the renderer bins quads into.
pub(crate) const TILE_PX: usize = 16;

/// A camera to render with: image size, pinhole intrinsics and optional radial-tangential
/// distortion (the forward model `ẑ = K·δ(proj(x))`, see [`geom::DistortedCamera`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderCamera {
    /// Image width (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// Intrinsics `K`.
    pub pinhole: PinholeCamera,
    /// Lens distortion (`None`: an ideal pinhole).
    pub distortion: Option<RadTan>,
}

/// Focal length at 640 pixels of width: the ROS/TUM default `f = 525` px (a 62.8° horizontal
/// field of view, that of the Kinect and of typical VGA machine-vision lenses).
pub const FOCAL_AT_640: f64 = 525.0;

impl RenderCamera {
    /// The default camera for a `width × height` image: `f_x = f_y = 525·width/640`, principal
    /// point at the image centre `((w − 1)/2, (h − 1)/2)` (pixel centres at integers), no
    /// distortion. At 640×480 this is the ROS default `525, 525, 319.5, 239.5`.
    pub fn default_for_size(width: usize, height: usize) -> Self {
        let f = FOCAL_AT_640 * width as f64 / 640.0;
        RenderCamera {
            width,
            height,
            pinhole: PinholeCamera::new(
                f,
                f,
                (width as f64 - 1.0) / 2.0,
                (height as f64 - 1.0) / 2.0,
            ),
            distortion: None,
        }
    }

    /// Projects a camera-frame point to pixels through the full model (distortion included).
    pub fn project(&self, x: &Vector3<f64>) -> Result<Vector2<f64>, geom::CameraError> {
        match self.distortion {
            None => self.pinhole.project(x),
            Some(d) => DistortedCamera::new(self.pinhole, d).project(x),
        }
    }

    /// The normalised ray `(x, y)` (a point `(x, y, 1)` on the ray) through pixel `(u, v)`.
    pub fn ray(&self, u: f64, v: f64) -> Result<Vector2<f64>, geom::CameraError> {
        let m = self.pinhole.normalised_from_pixel(&Vector2::new(u, v));
        match self.distortion {
            None => Ok(m),
            Some(d) => d.undistort(&m),
        }
    }

    pub(crate) fn validate(&self) -> Result<(), RenderError> {
        if self.width < 16 || self.height < 16 || self.width > 8192 || self.height > 8192 {
            return Err(RenderError::InvalidCamera(format!(
                "image size {}×{} outside 16…8192 pixels",
                self.width, self.height
            )));
        }
        let p = &self.pinhole;
        if !(p.fx > 0.0 && p.fy > 0.0 && p.fx.is_finite() && p.fy.is_finite()) {
            return Err(RenderError::InvalidCamera(format!(
                "focal lengths must be positive, got {} and {}",
                p.fx, p.fy
            )));
        }
        if !(p.cx.is_finite() && p.cy.is_finite()) {
            return Err(RenderError::InvalidCamera(
                "non-finite principal point".into(),
            ));
        }
        Ok(())
    }
}

/// The rays of every pixel: the normalised ray `c = (x, y)` through the pixel centre and the
/// Jacobian `J = ∂(x, y)/∂(u, v)` there, so that the ray through the sub-pixel offset `δ` is
/// `c + J·δ` (exact for a pinhole; first order, with an error `O(|δ|²·δ'')` far below a
/// thousandth of a pixel, with distortion). Also, per tile of [`TILE_PX`]² pixels, the bounds
/// of all its rays (pixel footprints included), used to bin quads.
#[derive(Debug, Clone)]
pub(crate) struct RayTable {
    pub width: usize,
    pub height: usize,
    pub centre: Vec<[f64; 2]>,
    pub jacobian: Vec<[f64; 4]>,
    pub tiles: (usize, usize),
    /// Per tile: `[x0, y0, x1, y1]` on the normalised plane.
    pub tile_bounds: Vec<[f64; 4]>,
}

impl RayTable {
    pub fn new(camera: &RenderCamera) -> Result<Self, RenderError> {
        camera.validate()?;
        let (w, h) = (camera.width, camera.height);
        let mut centre = vec![[0.0; 2]; w * h];
        let mut jacobian = vec![[0.0; 4]; w * h];
        let p = &camera.pinhole;
        match camera.distortion {
            None => {
                for v in 0..h {
                    for u in 0..w {
                        centre[v * w + u] = [(u as f64 - p.cx) / p.fx, (v as f64 - p.cy) / p.fy];
                        jacobian[v * w + u] = [1.0 / p.fx, 0.0, 0.0, 1.0 / p.fy];
                    }
                }
            }
            Some(d) => {
                // Undistort every pixel centre; the Jacobian of the undistortion is the inverse
                // of the distortion's at the undistorted point, scaled by K⁻¹.
                for v in 0..h {
                    for u in 0..w {
                        let m_d = p.normalised_from_pixel(&Vector2::new(u as f64, v as f64));
                        let m = d.undistort(&m_d).map_err(|e| {
                            RenderError::InvalidCamera(format!(
                                "distortion {d:?} cannot be inverted at pixel ({u}, {v}): {e}"
                            ))
                        })?;
                        let jd = d.distort_jacobian(&m);
                        let ji = jd.try_inverse().ok_or_else(|| {
                            RenderError::InvalidCamera(format!(
                                "distortion {d:?} is singular at pixel ({u}, {v})"
                            ))
                        })?;
                        centre[v * w + u] = [m.x, m.y];
                        jacobian[v * w + u] = [
                            ji[(0, 0)] / p.fx,
                            ji[(0, 1)] / p.fy,
                            ji[(1, 0)] / p.fx,
                            ji[(1, 1)] / p.fy,
                        ];
                    }
                }
            }
        }
        let tiles = (w.div_ceil(TILE_PX), h.div_ceil(TILE_PX));
        let mut tile_bounds =
            vec![[f64::INFINITY, f64::INFINITY, -f64::INFINITY, -f64::INFINITY]; tiles.0 * tiles.1];
        for v in 0..h {
            for u in 0..w {
                let b = &mut tile_bounds[(v / TILE_PX) * tiles.0 + u / TILE_PX];
                let c = centre[v * w + u];
                let j = jacobian[v * w + u];
                for (du, dv) in [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)] {
                    let x = c[0] + j[0] * du + j[1] * dv;
                    let y = c[1] + j[2] * du + j[3] * dv;
                    b[0] = b[0].min(x);
                    b[1] = b[1].min(y);
                    b[2] = b[2].max(x);
                    b[3] = b[3].max(y);
                }
            }
        }
        // A margin of a thousandth of a pixel against rounding in the bounds tests.
        let m = 1e-3 / p.fx.min(p.fy);
        for b in &mut tile_bounds {
            b[0] -= m;
            b[1] -= m;
            b[2] += m;
            b[3] += m;
        }
        Ok(RayTable {
            width: w,
            height: h,
            centre,
            jacobian,
            tiles,
            tile_bounds,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rays_project_back_to_their_pixels() {
        let mut cam = RenderCamera::default_for_size(64, 48);
        cam.distortion = Some(RadTan::new(-0.28, 0.07, 2e-4, 2e-5));
        let table = RayTable::new(&cam).unwrap();
        for (u, v) in [(0usize, 0usize), (63, 47), (31, 20), (5, 40)] {
            let c = table.centre[v * 64 + u];
            let px = cam.project(&Vector3::new(c[0], c[1], 1.0)).unwrap();
            assert!((px - Vector2::new(u as f64, v as f64)).norm() < 1e-9);
            // The Jacobian predicts the ray of a neighbouring sub-pixel position.
            let j = table.jacobian[v * 64 + u];
            let d = (0.3, -0.2);
            let pred = [
                c[0] + j[0] * d.0 + j[1] * d.1,
                c[1] + j[2] * d.0 + j[3] * d.1,
            ];
            let px = cam.project(&Vector3::new(pred[0], pred[1], 1.0)).unwrap();
            assert!((px - Vector2::new(u as f64 + d.0, v as f64 + d.1)).norm() < 2e-3);
        }
    }

    #[test]
    fn bad_cameras_are_errors() {
        assert!(RayTable::new(&RenderCamera::default_for_size(8, 8)).is_err());
        let mut cam = RenderCamera::default_for_size(64, 48);
        cam.pinhole.fx = -1.0;
        assert!(RayTable::new(&cam).is_err());
        let mut cam = RenderCamera::default_for_size(64, 48);
        // A barrel distortion so strong that the corners fold over.
        cam.distortion = Some(RadTan::new(-3.0, 0.0, 0.0, 0.0));
        assert!(RayTable::new(&cam).is_err());
    }
}
