//! The pinhole camera of the scene contract (docs/ARCHITECTURE.md, Cameras and rays), with
//! ParaView's names.

use crate::error::{Error, Result};
use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    #[serde(deserialize_with = "super::strict::f64x3")]
    pub position: [f64; 3],
    #[serde(deserialize_with = "super::strict::f64x3")]
    pub focal_point: [f64; 3],
    #[serde(deserialize_with = "super::strict::f64x3")]
    pub view_up: [f64; 3],
    /// Vertical field of view in degrees.
    pub view_angle: f64,
    /// Parallel (orthographic) projection with this half-height of the view in world units
    /// (ParaView's CameraParallelScale); `None`: perspective.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parallel_scale: Option<f64>,
}

/// The camera reduced to what ray generation needs, in f32 exactly as the GPU gets it. The ray of
/// pixel (x, y) is `normalize(forward + sx * right + sy * up)` from `origin`, with
/// `sx = 2(x+0.5)/w - 1` and `sy = 1 - 2(y+0.5)/h`; `right` and `up` already carry
/// `tan(view_angle/2)` and the aspect. With a parallel projection every ray goes along `forward`
/// from `origin + sx * right + sy * up`, `right` and `up` carrying the parallel scale instead.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraBasis {
    pub origin: [f32; 3],
    pub forward: [f32; 3],
    pub right: [f32; 3],
    pub up: [f32; 3],
    pub width: u32,
    pub height: u32,
    pub parallel: bool,
}

impl Camera {
    pub fn validate(&self) -> Result<()> {
        let all = self
            .position
            .iter()
            .chain(&self.focal_point)
            .chain(&self.view_up)
            .chain(std::iter::once(&self.view_angle));
        // The GPU gets the camera in f32: a value finite in f64 may not be.
        if !all
            .into_iter()
            .all(|v| v.is_finite() && (*v as f32).is_finite())
        {
            return Err(Error::Invalid(
                "camera: every value must be a finite number (in 32-bit floats)".into(),
            ));
        }
        let f = DVec3::from(self.focal_point) - DVec3::from(self.position);
        if f.length() == 0.0 {
            return Err(Error::Invalid(
                "camera: position and focal_point are the same point".into(),
            ));
        }
        let up = DVec3::from(self.view_up);
        if f.normalize().cross(up).length() < 1e-9 {
            return Err(Error::Invalid(
                "camera: view_up is zero or parallel to the view direction".into(),
            ));
        }
        if !(self.view_angle > 0.0 && self.view_angle < 180.0) {
            return Err(Error::Invalid(format!(
                "camera: view_angle must be between 0 and 180 degrees, got {}",
                self.view_angle
            )));
        }
        if let Some(s) = self.parallel_scale
            && !(s > 0.0 && (s as f32).is_finite())
        {
            return Err(Error::Invalid(format!(
                "camera: parallel_scale must be finite and positive, got {s}"
            )));
        }
        Ok(())
    }

    /// Assumes `validate` passed.
    pub fn basis(&self, width: u32, height: u32) -> CameraBasis {
        let f = (DVec3::from(self.focal_point) - DVec3::from(self.position)).normalize();
        let r = f.cross(DVec3::from(self.view_up)).normalize();
        let u = r.cross(f);
        let h = match self.parallel_scale {
            Some(s) => s,
            None => (self.view_angle.to_radians() / 2.0).tan(),
        };
        let a = f64::from(width) / f64::from(height);
        let f32v = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
        CameraBasis {
            origin: f32v(DVec3::from(self.position)),
            forward: f32v(f),
            right: f32v(r * (h * a)),
            up: f32v(u * h),
            width,
            height,
            parallel: self.parallel_scale.is_some(),
        }
    }

    /// The camera at the same place looking the opposite way (the display benchmark's blank
    /// frame: no ray reaches the model in front of the original view).
    pub fn turned_around(&self) -> Camera {
        let (p, f) = (DVec3::from(self.position), DVec3::from(self.focal_point));
        Camera {
            focal_point: (2.0 * p - f).into(),
            ..*self
        }
    }

    /// The same camera turned by `angle` radians about the axis through the focal point along
    /// `view_up`: the orbit used for multi-frame renders.
    /// At angle 0 the camera itself, to the bit (the first frame of an orbit is the camera
    /// given, as `dcrt view` renders it).
    pub fn orbit(&self, angle: f64) -> Camera {
        if angle == 0.0 {
            return *self;
        }
        let c = DVec3::from(self.focal_point);
        let axis = DVec3::from(self.view_up).normalize();
        let rot = glam::DQuat::from_axis_angle(axis, angle);
        let p = c + rot * (DVec3::from(self.position) - c);
        Camera {
            position: p.into(),
            ..*self
        }
    }
}

impl CameraBasis {
    /// Unit direction towards the default key light and the default sun, fixed to the camera.
    pub fn key_light(&self) -> [f32; 3] {
        crate::shading::key_direction(self.right, self.up, self.forward)
    }

    /// Pixel (x, y)'s ray (origin, normalized direction), computed in f64 from the f32 basis: the
    /// reference the GPU's f32 ray generation is compared against, for either projection.
    pub fn pixel_ray(&self, x: u32, y: u32) -> ([f64; 3], [f64; 3]) {
        let v = |a: [f32; 3]| DVec3::new(a[0].into(), a[1].into(), a[2].into());
        if !self.parallel {
            return (v(self.origin).into(), self.dir(x, y));
        }
        let sx = 2.0 * (f64::from(x) + 0.5) / f64::from(self.width) - 1.0;
        let sy = 1.0 - 2.0 * (f64::from(y) + 0.5) / f64::from(self.height);
        let o = v(self.origin) + sx * v(self.right) + sy * v(self.up);
        (o.into(), v(self.forward).normalize().into())
    }

    /// The normalized direction of pixel (x, y)'s ray of a perspective camera, computed in f64
    /// from the f32 basis.
    pub fn dir(&self, x: u32, y: u32) -> [f64; 3] {
        let sx = 2.0 * (f64::from(x) + 0.5) / f64::from(self.width) - 1.0;
        let sy = 1.0 - 2.0 * (f64::from(y) + 0.5) / f64::from(self.height);
        let v = |a: [f32; 3]| DVec3::new(a[0].into(), a[1].into(), a[2].into());
        let d = v(self.forward) + sx * v(self.right) + sy * v(self.up);
        d.normalize().into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera {
            position: [0.0, -5.0, 0.0],
            focal_point: [0.0, 0.0, 0.0],
            view_up: [0.0, 0.0, 1.0],
            view_angle: 90.0,
            parallel_scale: None,
        }
    }

    #[test]
    fn centre_pixel_looks_at_focal_point() {
        let b = cam().basis(3, 3);
        let d = b.dir(1, 1);
        assert!((d[1] - 1.0).abs() < 1e-12 && d[0].abs() < 1e-12 && d[2].abs() < 1e-12);
    }

    #[test]
    fn corners_follow_the_contract() {
        // 90 degrees, square image: the top-left pixel centre of a 2x2 image is at (-0.5, 0.5).
        let b = cam().basis(2, 2);
        let d = b.dir(0, 0);
        let expect = DVec3::new(-0.5, 1.0, 0.5).normalize();
        assert!((DVec3::from(d) - expect).length() < 1e-7, "{d:?}");
        // Wider than tall: x is scaled by the aspect.
        let b = cam().basis(4, 2);
        let d = DVec3::from(b.dir(3, 1));
        let expect = DVec3::new(2.0 * 0.75, 1.0, -0.5).normalize();
        assert!((d - expect).length() < 1e-7, "{d:?}");
    }

    #[test]
    fn bad_cameras_are_refused() {
        let mut c = cam();
        c.focal_point = c.position;
        assert!(c.validate().is_err());
        let mut c = cam();
        c.view_up = [0.0, 1.0, 0.0];
        assert!(c.validate().is_err());
        let mut c = cam();
        c.view_angle = 0.0;
        assert!(c.validate().is_err());
        let mut c = cam();
        c.position[0] = f64::NAN;
        assert!(c.validate().is_err());
    }

    #[test]
    fn orbit_by_nothing_is_the_camera_to_the_bit() {
        // (-2.19 - 2.08) + 2.08 is not -2.19 in f64: turning by 0 must not round the position.
        let c = Camera {
            position: [-2.19, -5.0, 0.0],
            focal_point: [2.08, 0.0, 0.0],
            ..cam()
        };
        assert_eq!(c.orbit(0.0), c);
    }

    #[test]
    fn orbit_keeps_distance() {
        let c = cam().orbit(1.0);
        let d = DVec3::from(c.position).length();
        assert!((d - 5.0).abs() < 1e-12);
    }
}
