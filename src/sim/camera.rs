//! Pinhole and thin-lens cameras.

use super::geometry::{Ray, concentric_disk};
use glam::Vec3;

/// A perspective camera.
#[derive(Debug, Clone, Copy)]
pub struct Camera {
    position: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    tan_half_fov: f32,
    aspect: f32,
    /// Lens radius; 0 = pinhole.
    pub aperture: f32,
    focus_distance: f32,
}

impl Camera {
    /// A camera at `position` looking at `look_at`, vertical field of view `fov_deg`.
    pub fn new(position: Vec3, look_at: Vec3, up: Vec3, fov_deg: f32, aspect: f32, aperture: f32, focus: f32) -> Self {
        let forward = (look_at - position).normalize();
        let right = forward.cross(up).normalize();
        let up = right.cross(forward);
        Camera {
            position,
            forward,
            right,
            up,
            tan_half_fov: (fov_deg.to_radians() * 0.5).tan(),
            aspect,
            aperture,
            focus_distance: focus,
        }
    }

    /// The ray through film position (`sx`, `sy`) in `[0, 1]²` (y down); `lens` is sampled
    /// only for a thin lens.
    pub fn ray(&self, sx: f32, sy: f32, lens: Option<[f32; 2]>) -> Ray {
        let x = (2.0 * sx - 1.0) * self.tan_half_fov * self.aspect;
        let y = (1.0 - 2.0 * sy) * self.tan_half_fov;
        let dir = (self.forward + x * self.right + y * self.up).normalize();
        match lens {
            Some(u) if self.aperture > 0.0 => {
                let (dx, dy) = concentric_disk(u);
                let origin = self.position + self.aperture * (dx * self.right + dy * self.up);
                let t = self.focus_distance / dir.dot(self.forward);
                let focus = self.position + t * dir;
                Ray::new(origin, (focus - origin).normalize())
            }
            _ => Ray::new(self.position, dir),
        }
    }

    /// Whether rays need a lens sample.
    pub fn is_thin_lens(&self) -> bool {
        self.aperture > 0.0
    }
}
