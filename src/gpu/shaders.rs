//! The WGSL kernels as `build.rs` composed and validated them (docs/ARCHITECTURE.md, Shaders):
//! each kernel's text, its bindings, pipeline constants and workgroup size as naga reflects
//! them, the `Override` enum of every pipeline constant, the kernels' `u32` constants (`wgsl`),
//! and the layout of every WGSL struct (checked against the host structs by the layout tests).

/// Where the GPU keeps blocks; both give the kernels `fn texel(block, t) -> vec4<u32>`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Store {
    /// An `Rgba32Uint` 2D array texture, one block per row (docs/ARCHITECTURE.md, Block store).
    #[default]
    Texture,
    /// One storage buffer (bounded by the adapter's storage binding size).
    Buffer,
}

impl Store {
    pub const ALL: [Store; 2] = [Store::Texture, Store::Buffer];

    /// The shared module `#import store` names for a store that fits one resource (a texture
    /// store in parts uses `store_texture_parts`).
    pub fn module(self) -> &'static str {
        match self {
            Store::Texture => "store_texture",
            Store::Buffer => "store_buffer",
        }
    }
}

/// What a binding holds, as the host must declare it in the bind group layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindingKind {
    Uniform,
    Storage {
        read_only: bool,
    },
    /// `texture_storage_2d_array<F, read>` of a 32-bit unsigned format F: the texel loads of
    /// a read-only storage texture have no mip levels to handle, which a sampled texture's
    /// `textureLoad` does lane by lane on a CPU driver.
    ReadOnlyTexture2dArray {
        format: wgpu::TextureFormat,
    },
}

/// One `@group(g) @binding(b) var name` of a kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BindingInfo {
    pub group: u32,
    pub binding: u32,
    /// The WGSL variable's name: the host binds resources by it.
    pub name: &'static str,
    pub kind: BindingKind,
}

/// A composed kernel for one block store module.
#[derive(Clone, Copy, Debug)]
pub struct KernelInfo {
    /// The kernel's file name without `.wgsl`; its entry point is `main`.
    pub name: &'static str,
    /// The block store module it was composed with (`compose::STORE_MODULES`).
    pub store: &'static str,
    /// The composed WGSL (shared modules first).
    pub source: &'static str,
    /// Sorted by (group, binding).
    pub bindings: &'static [BindingInfo],
    /// The pipeline-overridable constants it declares.
    pub overrides: &'static [Override],
    /// `@workgroup_size` of its entry point.
    pub workgroup_size: [u32; 3],
}

/// The WGSL type of an override: which values the host may give it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OverrideType {
    Bool,
    U32,
}

/// A WGSL struct's size and member offsets, as naga lays it out.
#[derive(Clone, Copy, Debug)]
pub struct StructInfo {
    pub name: &'static str,
    pub size: u32,
    pub members: &'static [(&'static str, u32)],
}

impl StructInfo {
    /// The offset of member `name`; panics when there is none (a test names a member the WGSL
    /// struct lacks).
    pub fn offset(&self, name: &str) -> u32 {
        self.members
            .iter()
            .find(|(m, _)| *m == name)
            .unwrap_or_else(|| panic!("WGSL struct {} has no member {name}", self.name))
            .1
    }
}

include!(concat!(env!("OUT_DIR"), "/shaders.rs"));

/// The kernel `name` composed with block store module `store`.
pub fn kernel(name: &str, store: &str) -> &'static KernelInfo {
    KERNELS
        .iter()
        .find(|k| k.name == name && k.store == store)
        .unwrap_or_else(|| panic!("no kernel named {name} for {store}"))
}

/// The layout of WGSL struct `name`.
pub fn wgsl_struct(name: &str) -> &'static StructInfo {
    STRUCTS
        .iter()
        .find(|s| s.name == name)
        .unwrap_or_else(|| panic!("no WGSL struct named {name}"))
}
