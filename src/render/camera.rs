//! Camera: a pinhole camera with a pixel grid, placed and pointed in the scene frame.
//!
//! In: image size (pixels), the field of view across the image width (or a focal length
//! in pixels), a position (m, scene frame) and a pointing (a target point and an "up"
//! vector, or an explicit rotation). Out: the ray through each pixel centre and the
//! projection of points onto the image plane.
//!
//! Camera frame: x to the right along image rows, y down along columns, z along the
//! boresight; pixel (col, row) covers [col, col+1) × [row, row+1), row 0 at the top. A
//! camera-frame point (x, y, z), z > 0, projects to u = f·x/z + W/2, v = f·y/z + H/2.

use crate::error::{Error, Result};
use crate::scene::camera_size_problem;
use crate::world::Pose;
use glam::{DMat3, DVec3};

/// Dawn Framing Camera (Sierks et al. 2011, Space Sci. Rev. 163, 263): 1024 × 1024 pixels,
/// 5.46° field of view, 150 mm focal length (14 µm pixels, 93.3 µrad per pixel).
pub const DAWN_FC: (usize, usize, f64) = (1024, 1024, 5.46);

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub width: usize,
    pub height: usize,
    /// Focal length in pixels.
    pub focal_px: f64,
    /// Position and orientation: `body_to_scene` takes camera-frame vectors to the scene frame.
    pub pose: Pose,
}

impl Camera {
    /// A camera at the scene origin looking along +z, with the field of view `fov_deg`
    /// across the image width.
    pub fn with_fov(width: usize, height: usize, fov_deg: f64) -> Result<Camera> {
        if let Some(problem) = camera_size_problem(width, height, fov_deg) {
            return Err(Error::Usage(problem));
        }
        Ok(Camera {
            width,
            height,
            focal_px: 0.5 * width as f64 / (0.5 * fov_deg.to_radians()).tan(),
            pose: Pose::IDENTITY,
        })
    }

    /// The Dawn Framing Camera preset ([`DAWN_FC`]).
    pub fn dawn_fc() -> Camera {
        let (w, h, fov) = DAWN_FC;
        Camera::with_fov(w, h, fov).expect("valid preset")
    }

    /// This camera at `position_m` looking at `target_m` (scene frame), with image "up"
    /// (−y) as close to `up` as possible.
    pub fn looking_at(self, position_m: DVec3, target_m: DVec3, up: DVec3) -> Result<Camera> {
        let z = (target_m - position_m).normalize_or_zero();
        let x = z.cross(up).normalize_or_zero();
        if z == DVec3::ZERO || x == DVec3::ZERO || !z.is_finite() || !x.is_finite() {
            return Err(Error::Usage(format!(
                "camera at {position_m} m cannot look at {target_m} m with up {up}: the \
                 target must differ from the position and up must not be parallel to the \
                 line of sight"
            )));
        }
        let y = z.cross(x);
        Ok(Camera {
            pose: Pose {
                body_to_scene: DMat3::from_cols(x, y, z),
                position_m,
            },
            ..self
        })
    }

    /// Centre of the image plane, pixels.
    fn centre(&self) -> (f64, f64) {
        (0.5 * self.width as f64, 0.5 * self.height as f64)
    }

    /// Direction (camera frame, z = 1, not normalised) of the ray through image point (u, v).
    pub fn ray(&self, u: f64, v: f64) -> DVec3 {
        let (cx, cy) = self.centre();
        DVec3::new((u - cx) / self.focal_px, (v - cy) / self.focal_px, 1.0)
    }

    /// Image point (u, v) of camera-frame point `p` (z > 0).
    pub fn project(&self, p: DVec3) -> (f64, f64) {
        let (cx, cy) = self.centre();
        (
            self.focal_px * p.x / p.z + cx,
            self.focal_px * p.y / p.z + cy,
        )
    }

    /// Boresight (unit vector along +z of the camera) in the scene frame.
    pub fn boresight(&self) -> DVec3 {
        self.pose.body_to_scene.z_axis
    }

    /// Full field of view across the width, degrees.
    pub fn fov_deg(&self) -> f64 {
        2.0 * (0.5 * self.width as f64 / self.focal_px)
            .atan()
            .to_degrees()
    }
}
