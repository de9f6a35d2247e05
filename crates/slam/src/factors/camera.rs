//! Cameras that say where a measured point is: the viewing ray of a measurement and, for
//! stereo and RGB-D, its inverse depth from one measurement (thesis eq. 4.23, 6.6).

use super::Projector;
use geom::{PinholeCamera, RgbdCamera, StereoCamera};
use nalgebra::{SVector, Vector2, Vector3};

/// A measurement model whose measurement of a point in its anchor frame gives the point's
/// inverse-depth coordinates `ψ = ((u − c_u)/f_u, (v − c_v)/f_v, q)`, with `q` from the stereo
/// disparity, `q = (u_l − u_r)/(f_u·b)` (thesis eq. 4.23; an RGB-D camera is a virtual stereo
/// camera, §6.5.3), or, for a monocular camera, unknown (eq. 4.26).
pub trait InverseDepthCamera<const N: usize>: Projector<N> + Clone {
    /// Whether one measurement determines depth (stereo, RGB-D) or not (monocular).
    const MEASURES_DEPTH: bool;

    /// The viewing ray `(x/z, y/z, 1)` of a measurement (of its left image for stereo).
    fn ray(&self, z: &SVector<f64, N>) -> Vector3<f64>;

    /// The disparity `u_l − u_r` (pixels) of a stereo or RGB-D measurement; `None` for a
    /// monocular one.
    fn disparity(&self, z: &SVector<f64, N>) -> Option<f64>;

    /// `ψ` of a point measured as `z` in its anchor frame; monocular cameras use
    /// `default_inverse_depth` for `q`. `None` if the disparity is not positive.
    fn inverse_depth_from(
        &self,
        z: &SVector<f64, N>,
        default_inverse_depth: f64,
    ) -> Option<Vector3<f64>>;
}

impl InverseDepthCamera<2> for PinholeCamera {
    const MEASURES_DEPTH: bool = false;

    fn ray(&self, z: &Vector2<f64>) -> Vector3<f64> {
        pinhole_ray(self, z.x, z.y)
    }

    fn disparity(&self, _: &Vector2<f64>) -> Option<f64> {
        None
    }

    fn inverse_depth_from(
        &self,
        z: &Vector2<f64>,
        default_inverse_depth: f64,
    ) -> Option<Vector3<f64>> {
        let m = self.normalised_from_pixel(z);
        Some(Vector3::new(m.x, m.y, default_inverse_depth))
    }
}

impl InverseDepthCamera<3> for StereoCamera {
    const MEASURES_DEPTH: bool = true;

    fn ray(&self, z: &Vector3<f64>) -> Vector3<f64> {
        pinhole_ray(&self.pinhole, z.x, z.y)
    }

    fn disparity(&self, z: &Vector3<f64>) -> Option<f64> {
        Some(z.x - z.z)
    }

    fn inverse_depth_from(&self, z: &Vector3<f64>, _: f64) -> Option<Vector3<f64>> {
        let d = z.x - z.z;
        let q = d / (self.pinhole.fx * self.baseline);
        (d > 0.0 && q.is_finite()).then(|| {
            let r = pinhole_ray(&self.pinhole, z.x, z.y);
            Vector3::new(r.x, r.y, q)
        })
    }
}

impl InverseDepthCamera<3> for RgbdCamera {
    const MEASURES_DEPTH: bool = true;

    fn ray(&self, z: &Vector3<f64>) -> Vector3<f64> {
        self.stereo.ray(z)
    }

    fn disparity(&self, z: &Vector3<f64>) -> Option<f64> {
        self.stereo.disparity(z)
    }

    fn inverse_depth_from(&self, z: &Vector3<f64>, q: f64) -> Option<Vector3<f64>> {
        self.stereo.inverse_depth_from(z, q)
    }
}

/// The ray `((u − c_u)/f_u, (v − c_v)/f_v, 1)` of pixel `(u, v)`.
fn pinhole_ray(c: &PinholeCamera, u: f64, v: f64) -> Vector3<f64> {
    Vector3::new((u - c.cx) / c.fx, (v - c.cy) / c.fy, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stereo_and_rgbd_measurements_give_the_point_back() {
        let pinhole = PinholeCamera::new(500.0, 510.0, 320.0, 240.0);
        let x = Vector3::new(0.3, -0.2, 2.5);
        let stereo = StereoCamera::new(pinhole, 0.1);
        let rgbd = RgbdCamera::new(pinhole, 0.075);
        let z = Projector::<3>::project(&stereo, &x).unwrap().0;
        let psi = stereo.inverse_depth_from(&z, 0.0).unwrap();
        assert!((crate::factors::inverse_depth_to_point(&psi) - x).norm() < 1e-12);
        assert!((stereo.disparity(&z).unwrap() - 500.0 * 0.1 / 2.5).abs() < 1e-12);
        let z = Projector::<3>::project(&rgbd, &x).unwrap().0;
        let psi = rgbd.inverse_depth_from(&z, 0.0).unwrap();
        assert!((crate::factors::inverse_depth_to_point(&psi) - x).norm() < 1e-12);
        // No disparity, no depth.
        assert!(
            stereo
                .inverse_depth_from(&Vector3::new(10.0, 10.0, 10.0), 0.0)
                .is_none()
        );
        assert!(
            stereo
                .inverse_depth_from(&Vector3::new(10.0, 10.0, 12.0), 0.0)
                .is_none()
        );
        // Monocular: the ray with the default inverse depth.
        let z = Projector::<2>::project(&pinhole, &x).unwrap().0;
        let psi = pinhole.inverse_depth_from(&z, 0.25).unwrap();
        assert!((psi.xy() - x.xy() / x.z).norm() < 1e-12 && psi.z == 0.25);
        assert!((pinhole.ray(&z) - x / x.z).norm() < 1e-12);
    }
}
