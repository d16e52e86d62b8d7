//! The camera as the live view's clients read and write it: ParaView's names (`position`,
//! `focal_point`, `view_up`, `view_angle`, `parallel_projection`, `parallel_scale`), checked as a
//! scene's `[camera]` is (docs/ARCHITECTURE.md, Live view).

use crate::error::{Error, Result};
use crate::scene::Camera;
use glam::DVec3;

/// `GET /camera`'s answer and `POST /camera`'s body.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraJson {
    pub position: [f64; 3],
    pub focal_point: [f64; 3],
    pub view_up: [f64; 3],
    /// Vertical, degrees.
    pub view_angle: f64,
    /// Orthographic projection (ParaView's CameraParallelProjection); needs `parallel_scale`.
    #[serde(default)]
    pub parallel_projection: bool,
    /// Half the view's height in world units (ParaView's CameraParallelScale). Reported for a
    /// perspective camera too, as ParaView does: the half-height at the focal point.
    #[serde(default)]
    pub parallel_scale: Option<f64>,
}

impl CameraJson {
    pub fn of(c: &Camera) -> CameraJson {
        let distance = (DVec3::from(c.focal_point) - DVec3::from(c.position)).length();
        CameraJson {
            position: c.position,
            focal_point: c.focal_point,
            view_up: c.view_up,
            view_angle: c.view_angle,
            parallel_projection: c.parallel_scale.is_some(),
            parallel_scale: Some(
                c.parallel_scale
                    .unwrap_or(distance * (c.view_angle.to_radians() / 2.0).tan()),
            ),
        }
    }

    /// The camera this JSON names, checked; the error says what is wrong.
    pub fn camera(&self) -> Result<Camera> {
        let parallel_scale = match (self.parallel_projection, self.parallel_scale) {
            (true, None) => {
                return Err(Error::Invalid(
                    "camera: parallel_projection needs parallel_scale".into(),
                ));
            }
            (true, s) => s,
            (false, _) => None,
        };
        let c = Camera {
            position: self.position,
            focal_point: self.focal_point,
            view_up: self.view_up,
            view_angle: self.view_angle,
            parallel_scale,
        };
        c.validate()?;
        Ok(c)
    }

    /// Parses and checks a client's JSON text.
    pub fn parse(text: &[u8]) -> Result<Camera> {
        let json: CameraJson = serde_json::from_slice(text)
            .map_err(|e| Error::Invalid(format!("camera: not the camera's JSON: {e}")))?;
        json.camera()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera {
            position: [0.5, -3.0, 1.25],
            focal_point: [0.0, 0.1, 0.0],
            view_up: [0.0, 0.0, 1.0],
            view_angle: 30.0,
            parallel_scale: None,
        }
    }

    #[test]
    fn round_trips_to_the_bit() {
        let text = serde_json::to_vec(&CameraJson::of(&cam())).unwrap();
        assert_eq!(CameraJson::parse(&text).unwrap(), cam());
        let par = Camera {
            parallel_scale: Some(2.5),
            ..cam()
        };
        let text = serde_json::to_vec(&CameraJson::of(&par)).unwrap();
        assert_eq!(CameraJson::parse(&text).unwrap(), par);
    }

    #[test]
    fn bad_json_is_refused_with_what_is_wrong() {
        let e = CameraJson::parse(b"{\"position\": [0, 0]}").unwrap_err();
        assert!(e.to_string().contains("camera"), "{e}");
        let e = CameraJson::parse(b"not json").unwrap_err();
        assert!(e.to_string().contains("JSON"), "{e}");
        let same =
            br#"{"position":[0,0,0],"focal_point":[0,0,0],"view_up":[0,0,1],"view_angle":30}"#;
        let e = CameraJson::parse(same).unwrap_err();
        assert!(e.to_string().contains("same point"), "{e}");
        let par = br#"{"position":[0,0,1],"focal_point":[0,0,0],"view_up":[0,1,0],"view_angle":30,"parallel_projection":true}"#;
        let e = CameraJson::parse(par).unwrap_err();
        assert!(e.to_string().contains("parallel_scale"), "{e}");
    }
}
