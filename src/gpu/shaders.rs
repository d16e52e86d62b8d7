//! WGSL sources. WGSL has no include: each kernel is `common.wgsl`, then the block storage
//! (`store_texture.wgsl` or `store_buffer.wgsl`), then the kernel file.

pub const COMMON: &str = include_str!("../../shaders/common.wgsl");

/// Where the GPU keeps blocks; both give the kernels `fn texel(block, t) -> vec4<u32>`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Store {
    /// An `Rgba32Uint` 2D array texture, one block per row (DESIGN.md section 3).
    #[default]
    Texture,
    /// One storage buffer (bounded by the adapter's storage binding size).
    Buffer,
}

impl Store {
    pub const ALL: [Store; 2] = [Store::Texture, Store::Buffer];

    fn source(self) -> &'static str {
        match self {
            Store::Texture => include_str!("../../shaders/store_texture.wgsl"),
            Store::Buffer => include_str!("../../shaders/store_buffer.wgsl"),
        }
    }
}

/// (name, kernel source without the prelude).
pub const KERNELS: &[(&str, &str)] = &[
    ("raygen", include_str!("../../shaders/raygen.wgsl")),
    ("trace", include_str!("../../shaders/trace.wgsl")),
    ("args", include_str!("../../shaders/args.wgsl")),
    ("shade", include_str!("../../shaders/shade.wgsl")),
    ("spawn", include_str!("../../shaders/spawn.wgsl")),
    ("gather", include_str!("../../shaders/gather.wgsl")),
    ("probe", include_str!("../../shaders/probe.wgsl")),
];

/// The full source of kernel `name`.
pub fn source(name: &str, store: Store) -> String {
    let (_, body) = KERNELS
        .iter()
        .find(|(n, _)| *n == name)
        .unwrap_or_else(|| panic!("no kernel named {name}"));
    format!("{COMMON}\n{}\n{body}", store.source())
}

/// Parses and validates a kernel with naga, as the GPU driver's front end would.
pub fn validate(name: &str, store: Store) -> Result<(), String> {
    let src = source(name, store);
    let module = naga::front::wgsl::parse_str(&src).map_err(|e| e.emit_to_string(&src))?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(&module)
    .map_err(|e| e.emit_to_string(&src))?;
    Ok(())
}
