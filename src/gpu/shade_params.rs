//! The shading kernels' parameters (`ShadeParams`) from the shading settings and the camera.

use super::layout::{FAR, ShadeParams};
use crate::scene::CameraBasis;
use crate::shading::{Light, Mode, Offset, Shading, unit};

impl ShadeParams {
    /// The kernels' view of `sh` for a camera.
    pub fn new(sh: &Shading, basis: &CameraBasis) -> ShadeParams {
        let v4 = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
        let mut p = ShadeParams {
            sky: v4(sh.sky, 0.0),
            mode: sh.mode as u32,
            fan: sh.fan(),
            ao_rays: sh.ao_rays,
            ao_distance: sh.ao_distance.min(FAR),
            max_depth: sh.max_depth,
            rr_depth: sh.rr_depth,
            ambient: sh.ambient,
            any_hit: if sh.any_hit {
                super::layout::flags::ANY_HIT
            } else {
                0
            },
            ..ShadeParams::default()
        };
        let sun_to = match sh.sun_dir.and_then(unit) {
            Some(d) => d.map(|c| -c),
            None => basis.key_light(),
        };
        p.sun_dir = v4(sun_to, 0.0);
        p.sun = v4(sh.sun, if sh.sun_on() { 1.0 } else { 0.0 });
        (p.offset_mode, p.epsilon) = match sh.offset {
            Offset::Bound => (0, 0.0),
            Offset::Epsilon(e) => (1, e),
        };
        if sh.mode == Mode::Shadows {
            let lights = sh.effective_lights(basis.key_light());
            p.light_count = lights.len() as u32;
            for (slot, l) in p.lights.iter_mut().zip(lights) {
                *slot = match l {
                    Light::Directional { dir, color } => super::layout::Light {
                        pos: v4(unit(dir).unwrap_or([0.0, 0.0, 1.0]).map(|c| -c), 0.0),
                        color: v4(color, 0.0),
                    },
                    Light::Point { pos, color } => super::layout::Light {
                        pos: v4(pos, 1.0),
                        color: v4(color, 0.0),
                    },
                };
            }
        }
        p
    }
}
