//! WGSL sources. WGSL has no include: each kernel is `common.wgsl` followed by the kernel file.

pub const COMMON: &str = include_str!("../../shaders/common.wgsl");

/// (name, kernel source without the common prelude).
pub const KERNELS: &[(&str, &str)] = &[
    ("raygen", include_str!("../../shaders/raygen.wgsl")),
    ("trace", include_str!("../../shaders/trace.wgsl")),
    ("args", include_str!("../../shaders/args.wgsl")),
    ("shade", include_str!("../../shaders/shade.wgsl")),
    ("probe", include_str!("../../shaders/probe.wgsl")),
];

/// The full source of kernel `name`.
pub fn source(name: &str) -> String {
    let (_, body) = KERNELS
        .iter()
        .find(|(n, _)| *n == name)
        .unwrap_or_else(|| panic!("no kernel named {name}"));
    format!("{COMMON}\n{body}")
}

/// Parses and validates a kernel with naga, as the GPU driver's front end would.
pub fn validate(name: &str) -> Result<(), String> {
    let src = source(name);
    let module = naga::front::wgsl::parse_str(&src).map_err(|e| e.emit_to_string(&src))?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(&module)
    .map_err(|e| e.emit_to_string(&src))?;
    Ok(())
}
