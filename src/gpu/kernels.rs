//! Compute pipelines made from the composed kernels. Bind group layouts come from naga's
//! reflection of each kernel (`shaders::KernelInfo::bindings`), and bind groups are filled by
//! binding name, so no binding list is written by hand (docs/ARCHITECTURE.md, Shaders).

use super::Gpu;
use super::shaders::{self, BindingKind, KernelInfo, Override, OverrideType};
use crate::shading::Mode;
use std::collections::BTreeMap;

/// Values of pipeline-overridable constants, by the typed names `build.rs` generates from the
/// WGSL (a misspelt name does not compile); each kernel gets those it declares.
#[derive(Clone, Debug, Default)]
pub struct Constants(BTreeMap<Override, f64>);

impl Constants {
    /// Sets a `bool` override; naming an override of another type is a host bug: it panics.
    pub fn flag(&mut self, o: Override, on: bool) -> &mut Self {
        self.set(o, OverrideType::Bool, if on { 1.0 } else { 0.0 })
    }

    /// Sets a `u32` override; naming an override of another type is a host bug: it panics.
    pub fn count(&mut self, o: Override, n: u32) -> &mut Self {
        self.set(o, OverrideType::U32, f64::from(n))
    }

    fn set(&mut self, o: Override, ty: OverrideType, v: f64) -> &mut Self {
        assert_eq!(o.ty(), ty, "override {} set as {ty:?}", o.name());
        self.0.insert(o, v);
        self
    }

    /// Those of `kernel`'s overrides that are set, by WGSL name.
    fn for_kernel(&self, kernel: &KernelInfo) -> Vec<(&'static str, f64)> {
        kernel
            .overrides
            .iter()
            .filter_map(|&o| Some((o.name(), *self.0.get(&o)?)))
            .collect()
    }
}

/// One kernel's pipeline and the layouts of the groups it declares.
pub struct Kernel {
    pub info: &'static KernelInfo,
    pipeline: wgpu::ComputePipeline,
    /// Indexed by group; `None` for a group the kernel does not use.
    layouts: Vec<Option<wgpu::BindGroupLayout>>,
}

/// A kernel's bind groups, indexed by group.
pub struct Bound(Vec<Option<wgpu::BindGroup>>);

impl Bound {
    /// No bind groups (a placeholder until the resources exist).
    pub fn empty() -> Bound {
        Bound(Vec::new())
    }
}

/// How many workgroups a dispatch runs.
pub enum Dispatch<'a> {
    /// Enough to give each of this many items an invocation: the count divided by the kernel's
    /// workgroup size (as naga reflects it), rounded up.
    Over(u32),
    /// This many workgroups (a kernel whose one workgroup walks a whole list).
    Groups(u32),
    /// The indirect arguments of a `Counter` (after its count, at byte 4).
    Indirect(&'a wgpu::Buffer),
}

fn layout_entry(b: &shaders::BindingInfo) -> wgpu::BindGroupLayoutEntry {
    let ty = match b.kind {
        BindingKind::Uniform => wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        BindingKind::Storage { read_only } => wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        BindingKind::ReadOnlyTexture2dArray { format } => wgpu::BindingType::StorageTexture {
            access: wgpu::StorageTextureAccess::ReadOnly,
            format,
            view_dimension: wgpu::TextureViewDimension::D2Array,
        },
    };
    wgpu::BindGroupLayoutEntry {
        binding: b.binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty,
        count: None,
    }
}

impl Kernel {
    /// Builds kernel `name` for block store module `store`; of `constants`, it gets those it
    /// declares.
    pub fn new(gpu: &Gpu, name: &str, store: &str, constants: &Constants) -> Kernel {
        let info = shaders::kernel(name, store);
        let groups = info.bindings.iter().map(|b| b.group + 1).max().unwrap_or(0);
        let layouts: Vec<Option<wgpu::BindGroupLayout>> = (0..groups)
            .map(|g| {
                let entries: Vec<_> = info
                    .bindings
                    .iter()
                    .filter(|b| b.group == g)
                    .map(layout_entry)
                    .collect();
                (!entries.is_empty()).then(|| {
                    gpu.device
                        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                            label: Some(name),
                            entries: &entries,
                        })
                })
            })
            .collect();
        let module = super::trusted::shader_module(&gpu.device, name, info.source);
        let refs: Vec<Option<&wgpu::BindGroupLayout>> =
            layouts.iter().map(Option::as_ref).collect();
        let layout = gpu
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(name),
                bind_group_layouts: &refs,
                immediate_size: 0,
            });
        let constants = constants.for_kernel(info);
        let pipeline = gpu
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(name),
                layout: Some(&layout),
                module: &module,
                entry_point: Some("main"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    ..Default::default()
                },
                cache: None,
            });
        Kernel {
            info,
            pipeline,
            layouts,
        }
    }

    /// Bind groups for every group the kernel declares, each binding filled with
    /// `resource(name)`. A name without a resource is a host bug: it panics naming both.
    pub fn bind<'a>(
        &self,
        gpu: &Gpu,
        resource: impl Fn(&str) -> Option<wgpu::BindingResource<'a>>,
    ) -> Bound {
        let groups = self
            .layouts
            .iter()
            .enumerate()
            .map(|(g, layout)| {
                let layout = layout.as_ref()?;
                let entries: Vec<wgpu::BindGroupEntry<'a>> = self
                    .info
                    .bindings
                    .iter()
                    .filter(|b| b.group == g as u32)
                    .map(|b| wgpu::BindGroupEntry {
                        binding: b.binding,
                        resource: resource(b.name).unwrap_or_else(|| {
                            panic!("kernel {}: nothing to bind to {}", self.info.name, b.name)
                        }),
                    })
                    .collect();
                Some(gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some(self.info.name),
                    layout,
                    entries: &entries,
                }))
            })
            .collect();
        Bound(groups)
    }

    /// Records one compute pass of this kernel; `timestamps` writes GPU timestamps around it.
    pub fn dispatch(
        &self,
        enc: &mut wgpu::CommandEncoder,
        bound: &Bound,
        groups: Dispatch<'_>,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: None,
            timestamp_writes: timestamps,
        });
        pass.set_pipeline(&self.pipeline);
        for (g, group) in bound.0.iter().enumerate() {
            if let Some(group) = group {
                pass.set_bind_group(g as u32, group, &[]);
            }
        }
        match groups {
            Dispatch::Over(n) => {
                pass.dispatch_workgroups(n.div_ceil(self.info.workgroup_size[0]), 1, 1)
            }
            Dispatch::Groups(n) => pass.dispatch_workgroups(n, 1, 1),
            Dispatch::Indirect(buf) => pass.dispatch_workgroups_indirect(buf, 4),
        }
    }
}

/// The pipelines of a shading mode: each carries only its mode's code (`MODE` is a pipeline
/// constant), and modes without secondary rays get no spawning first round, spawn or gather pipeline.
pub struct Kernels {
    /// `traverse` built for a batch's first round of primary rays (`FIRST` 1): it makes the
    /// camera rays, and in cast mode writes the pixels of those that end in it.
    pub traverse_first: Kernel,
    /// `traverse` built for a wave's first round (`FIRST` 2): it makes the secondary rays from
    /// the paths. Modes without secondary rays have none.
    pub traverse_spawn: Option<Kernel>,
    /// A path's later waves (`rounds::Gen::Spawned`): lists the live rays' slots.
    pub spawn: Option<Kernel>,
    /// `traverse` built for the first round of a wave `spawn` listed (`FIRST` 3): it makes the
    /// listed rays from their paths.
    pub traverse_listed: Option<Kernel>,
    pub traverse: Kernel,
    /// With a cache, `traverse` built without set-aside slots (`DEFER_SLOTS` 0), for frames that set
    /// nothing aside (`Params::dc_defer` 0): a CPU driver runs the set-aside code of a loop pass
    /// whether or not a ray takes it (2.8% of a 1/8-cache frame's instructions).
    pub traverse_suspending: Option<Kernel>,
    pub args: Kernel,
    /// With a cache, after each round: the listed faults' requesters into the fault list.
    pub requesters: Kernel,
    pub shade: Kernel,
    pub gather: Option<Kernel>,
    /// Colour by data: only models with attribute blocks get it.
    pub albedo: Option<Kernel>,
}

impl Kernels {
    pub fn new(gpu: &Gpu, store: &str, constants: &Constants, mode: Mode, albedo: bool) -> Kernels {
        let mut c = constants.clone();
        c.count(Override::Mode, mode as u32);
        let k = |name| Kernel::new(gpu, name, store, &c);
        let waves = mode != Mode::Cast;
        let defers = c.0.get(&Override::DeferSlots).is_some_and(|&v| v > 0.0);
        let suspending = defers.then(|| {
            let mut c = c.clone();
            c.count(Override::DeferSlots, 0);
            Kernel::new(gpu, "traverse", store, &c)
        });
        let first = |which| {
            let mut c = c.clone();
            c.count(Override::First, which);
            Kernel::new(gpu, "traverse", store, &c)
        };
        Kernels {
            traverse_first: first(1),
            traverse_spawn: waves.then(|| first(2)),
            spawn: waves.then(|| k("spawn")),
            traverse_listed: waves.then(|| first(3)),
            traverse: k("traverse"),
            traverse_suspending: suspending,
            args: k("args"),
            requesters: k("requesters"),
            shade: k("shade"),
            gather: waves.then(|| k("gather")),
            albedo: albedo.then(|| k("albedo")),
        }
    }
}
