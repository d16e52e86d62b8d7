//! Every kernel parses and validates with naga.

use dcrt::gpu::shaders;

#[test]
fn every_kernel_validates_with_naga() {
    for store in shaders::Store::ALL {
        for (name, _) in shaders::KERNELS {
            if let Err(e) = shaders::validate(name, store) {
                panic!("kernel {name} ({store:?}) does not validate:\n{e}");
            }
        }
    }
}

#[test]
fn validation_catches_a_broken_shader() {
    // The check above must be able to fail: a type error in WGSL is reported.
    let src = format!("{}\nfn broken() -> u32 {{ return 1.5; }}", shaders::COMMON);
    let module = naga::front::wgsl::parse_str(&src);
    assert!(module.is_err(), "naga accepted a float returned as u32");
}
