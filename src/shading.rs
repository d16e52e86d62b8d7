//! Shading modes and their settings, and the parameters the shading kernels read (their CPU
//! mirrors of the sampler, the ray-origin offset and the hemisphere mapping are in `mirror`).
//!
//! Modes: `cast` (primary rays, headlight Lambert), `shadows` (hard shadows from directional and
//! point lights), `ao` (ambient occlusion, N cosine-weighted rays per hit within a distance),
//! `path` (diffuse path tracing under a constant sky and a sun, next-event estimation towards
//! the sun, Russian roulette, a maximum depth).

use crate::error::{Error, Result};

/// Lights a render can take (`MAX_LIGHTS` in `shaders/shared/shading.wgsl`, which the layout
/// test checks).
pub const MAX_LIGHTS: usize = 4;

#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Primary rays only, headlight Lambert shading.
    #[default]
    Cast,
    /// Hard shadows from the scene's lights (a default key light when it has none).
    Shadows,
    /// Ambient occlusion.
    Ao,
    /// Diffuse path tracing with a constant sky and a sun.
    Path,
}

impl Mode {
    pub fn name(self) -> &'static str {
        match self {
            Mode::Cast => "cast",
            Mode::Shadows => "shadows",
            Mode::Ao => "ao",
            Mode::Path => "path",
        }
    }
}

/// How `sample2` draws a pixel's samples (docs/ARCHITECTURE.md, Shading).
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Sampler {
    /// Owen-scrambled Sobol' with a shuffled index per dimension pair: stratified and
    /// decorrelated.
    #[default]
    Sobol,
    /// Independent uniform numbers hashed from (seed, pixel, dimension, index): the unbiased
    /// baseline.
    Independent,
}

impl Sampler {
    pub fn name(self) -> &'static str {
        match self {
            Sampler::Sobol => "sobol",
            Sampler::Independent => "independent",
        }
    }
}

/// A light of the `shadows` mode. Colours scale the light: a surface facing a directional
/// light of colour c receives albedo * c; a point light's colour is that at unit distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// `dir`: the direction the light travels.
    Directional {
        dir: [f32; 3],
        color: [f32; 3],
    },
    Point {
        pos: [f32; 3],
        color: [f32; 3],
    },
}

/// How secondary rays leave a surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Offset {
    /// Past the hit point's rounding error along the normal (pbrt-v4's offset of a hit point
    /// computed from barycentrics with an error bound).
    Bound,
    /// A fixed distance along the normal (the classic epsilon, for comparison).
    Epsilon(f32),
}

pub const DEFAULT_AO_RAYS: u32 = 36;
pub const MAX_AO_RAYS: u32 = 1024;
pub const MAX_SPP: u32 = 1 << 16;
pub const MAX_DEPTH: u32 = 256;
/// The sun and the default key light: from above, behind and left of the camera.
const KEY_LIGHT: [f32; 3] = [-0.4, 1.0, -0.6]; // (right, up, forward) towards the light

/// Everything the shading modes need; `Copy`, so it travels inside the tracer's `Settings`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shading {
    pub mode: Mode,
    /// Samples per pixel of one render.
    pub spp: u32,
    /// The sampler index of the render's first sample: renders of samples `0..a` and `a..a+b`
    /// combine into the render of `0..a+b` (progressive accumulation).
    pub first_sample: u32,
    /// When this render is one part of a progressive one (samples `first_sample..first_sample +
    /// spp` of `Some(n)`): the samples per pixel of the whole, which decides, as `spp` does for a
    /// render of its own, whether primary rays are jittered. The parts' sums, added in sample
    /// order, are then the bits of the whole render's sum. `None`: the render stands alone.
    pub part_of_spp: Option<u32>,
    pub seed: u32,
    pub sampler: Sampler,
    pub ao_rays: u32,
    /// Occluders farther than this do not count (f32::INFINITY: any).
    pub ao_distance: f32,
    /// Path: most bounces after the camera hit.
    pub max_depth: u32,
    /// Path: Russian roulette from this bounce on.
    pub rr_depth: u32,
    /// Path: sky radiance.
    pub sky: [f32; 3],
    /// Path: direction the sunlight travels (`None`: the camera's key light direction).
    pub sun_dir: Option<[f32; 3]>,
    /// Path: sun irradiance (zero: no sun, no next-event rays).
    pub sun: [f32; 3],
    /// Shadows: the lights; with none and `default_light`, a key light tied to the camera.
    pub lights: [Option<Light>; MAX_LIGHTS],
    pub default_light: bool,
    pub ambient: f32,
    pub offset: Offset,
    /// Shadow and occlusion rays stop at the first hit (false: closest hit, for measurement).
    pub any_hit: bool,
    /// Primary rays that miss the model's box skip traversal.
    pub cull: bool,
}

impl Default for Shading {
    fn default() -> Self {
        Shading {
            mode: Mode::Cast,
            spp: 1,
            first_sample: 0,
            part_of_spp: None,
            seed: 0,
            sampler: Sampler::Sobol,
            ao_rays: DEFAULT_AO_RAYS,
            ao_distance: f32::INFINITY,
            max_depth: 8,
            rr_depth: 3,
            sky: [0.6, 0.7, 0.9],
            sun_dir: None,
            sun: [2.5, 2.4, 2.2],
            lights: [None; MAX_LIGHTS],
            default_light: true,
            ambient: 0.1,
            offset: Offset::Bound,
            any_hit: true,
            cull: true,
        }
    }
}

/// The command line's shading options: each replaces the scene's value when given.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Overrides {
    pub mode: Option<Mode>,
    pub spp: Option<u32>,
    pub seed: Option<u32>,
    pub sampler: Option<Sampler>,
    pub ao_rays: Option<u32>,
    pub ao_distance: Option<f32>,
    pub max_depth: Option<u32>,
    /// A fixed ray-origin offset instead of integer ulps.
    pub epsilon: Option<f32>,
    pub closest_hit_shadows: bool,
    pub no_cull: bool,
}

impl Overrides {
    /// `base` with the overrides applied, checked; an error names the flag that is wrong.
    pub fn apply(&self, base: Shading) -> Result<Shading> {
        let bad = |m: String| Err(Error::Invalid(m));
        // Checked here, before `validate`, in its order, so that the message names the flag.
        if let Some(spp) = self.spp
            && !(1..=MAX_SPP).contains(&spp)
        {
            return bad(format!("--spp must be 1..={MAX_SPP}, got {spp}"));
        }
        if let Some(rays) = self.ao_rays
            && !(1..=MAX_AO_RAYS).contains(&rays)
        {
            return bad(format!("--ao-rays must be 1..={MAX_AO_RAYS}, got {rays}"));
        }
        let mut s = base;
        s.mode = self.mode.unwrap_or(s.mode);
        s.spp = self.spp.unwrap_or(s.spp);
        s.seed = self.seed.unwrap_or(s.seed);
        s.sampler = self.sampler.unwrap_or(s.sampler);
        s.ao_rays = self.ao_rays.unwrap_or(s.ao_rays);
        s.ao_distance = self.ao_distance.unwrap_or(s.ao_distance);
        s.max_depth = self.max_depth.unwrap_or(s.max_depth);
        if let Some(e) = self.epsilon {
            s.offset = Offset::Epsilon(e);
        }
        s.any_hit &= !self.closest_hit_shadows;
        s.cull &= !self.no_cull;
        s.validate()?;
        Ok(s)
    }
}

fn finite_nonneg(v: [f32; 3]) -> bool {
    v.iter().all(|c| c.is_finite() && *c >= 0.0)
}

pub fn unit(v: [f32; 3]) -> Option<[f32; 3]> {
    let l = v.iter().map(|c| c * c).sum::<f32>().sqrt();
    (v.iter().all(|c| c.is_finite()) && l > 0.0 && l.is_finite()).then(|| v.map(|c| c / l))
}

impl Shading {
    /// Checks every setting; the error names the one that is wrong.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Invalid(m));
        if !(1..=MAX_SPP).contains(&self.spp) {
            return bad(format!("spp must be 1..={MAX_SPP}, got {}", self.spp));
        }
        if self.first_sample.checked_add(self.spp).is_none() {
            return bad("first sample + spp overflows".into());
        }
        if let Some(n) = self.part_of_spp
            && self.first_sample + self.spp > n
        {
            return bad(format!(
                "samples {}..{} are not a part of a render of {n} samples",
                self.first_sample,
                self.first_sample + self.spp
            ));
        }
        if !(1..=MAX_AO_RAYS).contains(&self.ao_rays) {
            return bad(format!(
                "ao rays must be 1..={MAX_AO_RAYS}, got {}",
                self.ao_rays
            ));
        }
        if self.ao_distance.is_nan() || self.ao_distance <= 0.0 {
            return bad(format!(
                "ao distance must be positive, got {}",
                self.ao_distance
            ));
        }
        if !(1..=MAX_DEPTH).contains(&self.max_depth) {
            return bad(format!(
                "max depth must be 1..={MAX_DEPTH}, got {}",
                self.max_depth
            ));
        }
        if !finite_nonneg(self.sky) {
            return bad(format!(
                "sky must be finite and non-negative, got {:?}",
                self.sky
            ));
        }
        if !finite_nonneg(self.sun) {
            return bad(format!(
                "sun must be finite and non-negative, got {:?}",
                self.sun
            ));
        }
        if let Some(d) = self.sun_dir
            && unit(d).is_none()
        {
            return bad(format!(
                "sun direction must be finite and non-zero, got {d:?}"
            ));
        }
        if !(self.ambient.is_finite() && self.ambient >= 0.0) {
            return bad(format!(
                "ambient must be finite and non-negative, got {}",
                self.ambient
            ));
        }
        if let Offset::Epsilon(e) = self.offset
            && !(e.is_finite() && e >= 0.0)
        {
            return bad(format!("epsilon must be finite and non-negative, got {e}"));
        }
        for (i, l) in self.lights.iter().flatten().enumerate() {
            match *l {
                Light::Directional { dir, color } => {
                    if unit(dir).is_none() {
                        return bad(format!(
                            "light {}: direction must be finite and non-zero, got {dir:?}",
                            i + 1
                        ));
                    }
                    if !finite_nonneg(color) {
                        return bad(format!(
                            "light {}: color must be finite and non-negative, got {color:?}",
                            i + 1
                        ));
                    }
                }
                Light::Point { pos, color } => {
                    if !pos.iter().all(|c| c.is_finite()) {
                        return bad(format!(
                            "light {}: position must be finite, got {pos:?}",
                            i + 1
                        ));
                    }
                    if !finite_nonneg(color) {
                        return bad(format!(
                            "light {}: color must be finite and non-negative, got {color:?}",
                            i + 1
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// Adds a light; errors when all `MAX_LIGHTS` slots are taken.
    pub fn add_light(&mut self, light: Light) -> Result<()> {
        match self.lights.iter_mut().find(|l| l.is_none()) {
            Some(slot) => {
                *slot = Some(light);
                Ok(())
            }
            None => Err(Error::Invalid(format!(
                "at most {MAX_LIGHTS} lights are supported"
            ))),
        }
    }

    /// The lights a render uses: the given ones, or the default key light (shadows mode only),
    /// towards `key_to` (`CameraBasis::key_light`).
    pub fn effective_lights(&self, key_to: [f32; 3]) -> Vec<Light> {
        let given: Vec<Light> = self.lights.iter().flatten().copied().collect();
        if given.is_empty() && self.default_light {
            let to = key_to;
            return vec![Light::Directional {
                dir: to.map(|c| -c),
                color: [0.9, 0.9, 0.9],
            }];
        }
        given
    }

    /// Whether the sun shines (any of its colour above 0).
    pub fn sun_on(&self) -> bool {
        self.sun.iter().any(|&c| c > 0.0)
    }

    /// The number of lights a render uses (`effective_lights`).
    pub fn light_count(&self) -> u32 {
        let given = self.lights.iter().flatten().count() as u32;
        if given == 0 && self.default_light {
            1
        } else {
            given
        }
    }

    /// These settings in the mode with the most secondary rays a pixel (`fan`): what a live
    /// view sizes its batches for, so that a client may switch to any mode.
    pub fn widest_mode(self) -> Shading {
        let mut widest = self;
        for mode in [Mode::Cast, Mode::Shadows, Mode::Ao, Mode::Path] {
            let mut s = self;
            s.mode = mode;
            if s.fan() > widest.fan() {
                widest = s;
            }
        }
        widest
    }

    /// Secondary rays per pixel in one wave (0: no wave).
    pub fn fan(&self) -> u32 {
        match self.mode {
            Mode::Cast => 0,
            Mode::Shadows => self.light_count(),
            Mode::Ao => self.ao_rays,
            Mode::Path => 1 + u32::from(self.sun_on()),
        }
    }

    /// Waves of secondary rays per sample (an upper bound for paths, which may end sooner).
    pub fn waves(&self) -> u32 {
        match self.mode {
            Mode::Cast => 0,
            Mode::Path => self.max_depth,
            _ => u32::from(self.fan() > 0),
        }
    }
}

/// Unit direction towards the key light, from the camera's axes (`CameraBasis::key_light`).
pub fn key_direction(right: [f32; 3], up: [f32; 3], forward: [f32; 3]) -> [f32; 3] {
    let n = |v: [f32; 3]| unit(v).unwrap_or([0.0, 0.0, 1.0]);
    let (r, u, f) = (n(right), n(up), n(forward));
    let v: [f32; 3] =
        std::array::from_fn(|i| KEY_LIGHT[0] * r[i] + KEY_LIGHT[1] * u[i] + KEY_LIGHT[2] * f[i]);
    n(v)
}
