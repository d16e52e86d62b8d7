//! The GPU: adapter choice, device set-up with the adapter's own limits, and the tracer that runs
//! the WGSL kernels (docs/ARCHITECTURE.md, The GPU side).

/// Byte offset and size of a `RoundReadback` member.
macro_rules! member {
    ($field:ident, $ty:ty) => {
        (
            std::mem::offset_of!($crate::gpu::layout::RoundReadback, $field) as u64,
            std::mem::size_of::<$ty>() as u64,
        )
    };
}

mod batch;
pub mod compose;
mod density;
mod faults;
pub mod frame;
mod kernels;
mod lanes;
pub mod layout;
pub mod probe;
pub mod rays;
mod rounds;
pub mod row_table;
pub mod scheduler;
mod shade;
pub mod shade_params;
pub mod shaders;
mod store;
pub mod tracer;
pub mod trusted;

use crate::error::{Error, Result};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A device and queue on the chosen adapter.
pub struct Gpu {
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    pub features: wgpu::Features,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// The first error wgpu reported outside an error scope; checked after every wait.
    errors: Arc<Mutex<Option<String>>>,
    /// Called every few milliseconds while waiting on the GPU (cluster ranks poll MPI there),
    /// with the longest wait allowed before the GPU is taken for hung.
    idle: Mutex<Option<Idle>>,
}

/// Counts of live GPU objects and the bytes of GPU memory they hold (`Gpu::live`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Live {
    pub buffers: isize,
    pub textures: isize,
    pub texture_views: isize,
    pub bind_groups: isize,
    pub pipelines: isize,
    pub shader_modules: isize,
    pub command_encoders: isize,
    pub query_sets: isize,
    pub buffer_bytes: isize,
    pub texture_bytes: isize,
}

/// What to do while waiting on the GPU, and for how long at most.
pub struct Idle {
    pub hook: Box<dyn FnMut() + Send>,
    pub limit: Duration,
}

/// How long each GPU wait sleeps between idle calls.
const IDLE_SLICE: Duration = Duration::from_millis(1);

fn instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    // The GL backend has no compute on many drivers and probes X/EGL noisily; use it only when
    // asked for with WGPU_BACKEND.
    if std::env::var_os("WGPU_BACKEND").is_none() {
        desc.backends = wgpu::Backends::PRIMARY;
    }
    wgpu::Instance::new(desc)
}

/// Every adapter wgpu finds, best first: discrete, integrated, virtual GPUs, then CPU drivers.
pub fn adapters() -> Vec<wgpu::Adapter> {
    let mut list = pollster::block_on(instance().enumerate_adapters(wgpu::Backends::all()));
    list.retain(|a| a.get_downlevel_capabilities().is_webgpu_compliant() || is_compute(a));
    list.sort_by_key(|a| rank(a.get_info().device_type));
    list
}

/// What the kernels need: compute shaders, indirect dispatch, and subgroup operations (the trace
/// kernel sums its statistics with them).
fn is_compute(a: &wgpu::Adapter) -> bool {
    lacks(a).is_empty()
}

/// What of the kernels' needs adapter `a` lacks.
fn lacks(a: &wgpu::Adapter) -> Vec<&'static str> {
    let flags = a.get_downlevel_capabilities().flags;
    let mut out = Vec::new();
    if !flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS) {
        out.push("compute shaders");
    }
    if !flags.contains(wgpu::DownlevelFlags::INDIRECT_EXECUTION) {
        out.push("indirect dispatch");
    }
    if !a.features().contains(wgpu::Features::SUBGROUP) {
        out.push("subgroup operations");
    }
    out
}

/// `name (lacks x, y)` for each adapter in `list`, or "none".
fn describe_needs(list: &[wgpu::Adapter]) -> String {
    if list.is_empty() {
        return "none".into();
    }
    let each: Vec<String> = list
        .iter()
        .map(|a| match lacks(a).as_slice() {
            [] => a.get_info().name,
            l => format!("{} (lacks {})", a.get_info().name, l.join(", ")),
        })
        .collect();
    each.join("; ")
}

fn rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    }
}

impl Gpu {
    /// Opens the best adapter, or the first whose name contains `name` (case-insensitive).
    /// `WGPU_ADAPTER_NAME` works like `name`; `WGPU_BACKEND` limits the backends searched.
    pub fn new(name: Option<&str>) -> Result<Gpu> {
        let env_name = std::env::var("WGPU_ADAPTER_NAME").ok();
        let name = name.or(env_name.as_deref());
        let list = adapters();
        let adapter = match name {
            Some(n) => {
                let want = n.to_lowercase();
                list.into_iter()
                    .find(|a| a.get_info().name.to_lowercase().contains(&want))
                    .ok_or_else(|| {
                        let names: Vec<String> =
                            adapters().iter().map(|a| a.get_info().name).collect();
                        Error::Gpu(format!(
                            "no adapter named like '{n}'; available: {}",
                            if names.is_empty() {
                                "none".into()
                            } else {
                                names.join(", ")
                            }
                        ))
                    })?
            }
            None => match list.iter().position(is_compute) {
                Some(i) => list.into_iter().nth(i).expect("found above"),
                None => {
                    return Err(Error::Gpu(format!(
                        "no GPU adapter with compute shaders, indirect dispatch and subgroup \
                         operations found (install mesa-vulkan-drivers for lavapipe); found: {}",
                        describe_needs(&list)
                    )));
                }
            },
        };
        if !is_compute(&adapter) {
            return Err(Error::Gpu(format!(
                "adapter '{}' lacks {}, which dcrt's kernels need",
                adapter.get_info().name,
                lacks(&adapter).join(", ")
            )));
        }
        let limits = adapter.limits();
        let features =
            (adapter.features() & wgpu::Features::TIMESTAMP_QUERY) | wgpu::Features::SUBGROUP;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("dcrt"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| Error::Gpu(format!("cannot open device: {e}")))?;
        let errors = Arc::new(Mutex::new(None));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let mut slot = sink.lock().unwrap_or_else(|p| p.into_inner());
            if slot.is_none() {
                *slot = Some(e.to_string());
            }
        }));
        Ok(Gpu {
            info: adapter.get_info(),
            limits,
            features,
            device,
            queue,
            errors,
            idle: Mutex::new(None),
        })
    }

    /// Waits for all submitted work; returns the first device error seen, if any.
    pub fn wait(&self) -> Result<()> {
        let mut idle = self.idle.lock().unwrap_or_else(|p| p.into_inner());
        let poll_error = |e| Error::Gpu(format!("device poll: {e}"));
        match idle.as_mut() {
            None => {
                self.device
                    .poll(wgpu::PollType::wait_indefinitely())
                    .map_err(poll_error)?;
            }
            Some(idle) => {
                let start = Instant::now();
                let slice = wgpu::PollType::Wait {
                    submission_index: None,
                    timeout: Some(IDLE_SLICE),
                };
                loop {
                    match self.device.poll(slice.clone()) {
                        Ok(_) => break,
                        Err(wgpu::PollError::Timeout) => (idle.hook)(),
                        Err(e) => return Err(poll_error(e)),
                    }
                    if start.elapsed() > idle.limit {
                        return Err(Error::Timeout {
                            what: "end of the GPU's work".into(),
                            seconds: idle.limit.as_secs_f64(),
                            likely: Some("the GPU hung or is far too slow"),
                        });
                    }
                }
            }
        }
        drop(idle);
        self.check()
    }

    /// The GPU objects alive now (wgpu's counters): what a long session must keep flat.
    pub fn live(&self) -> Live {
        let h = self.device.get_internal_counters().hal;
        Live {
            buffers: h.buffers.read(),
            textures: h.textures.read(),
            texture_views: h.texture_views.read(),
            bind_groups: h.bind_groups.read(),
            pipelines: h.compute_pipelines.read() + h.render_pipelines.read(),
            shader_modules: h.shader_modules.read(),
            command_encoders: h.command_encoders.read(),
            query_sets: h.query_sets.read(),
            buffer_bytes: h.buffer_memory.read(),
            texture_bytes: h.texture_memory.read(),
        }
    }

    /// Installs (or with `None` removes) what runs while this process waits on the GPU.
    pub fn set_idle(&self, idle: Option<Idle>) {
        *self.idle.lock().unwrap_or_else(|p| p.into_inner()) = idle;
    }

    pub fn check(&self) -> Result<()> {
        let slot = self.errors.lock().unwrap_or_else(|p| p.into_inner()).take();
        match slot {
            Some(e) => Err(Error::Gpu(e)),
            None => Ok(()),
        }
    }

    /// A one-line description: name, type, backend, driver.
    pub fn describe(&self) -> String {
        describe(&self.info)
    }

    /// A buffer of at least 16 bytes (wgpu refuses empty bindings).
    pub fn buffer(&self, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(16),
            usage,
            mapped_at_creation: false,
        })
    }

    /// A texture of `size` texels in `format` that kernels read (a read-only
    /// `texture_storage_2d_array`) and the host writes, and its view as an array (a single
    /// layer included).
    pub fn uint_texture_array(
        &self,
        label: &str,
        size: wgpu::Extent3d,
        format: wgpu::TextureFormat,
    ) -> (wgpu::Texture, wgpu::TextureView) {
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        (texture, view)
    }

    /// A buffer holding `contents`.
    pub fn buffer_init(
        &self,
        label: &str,
        contents: &[u8],
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        use wgpu::util::DeviceExt;
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
    }

    /// The largest storage buffer the adapter can bind.
    pub fn storage_limit(&self) -> u64 {
        self.limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size)
    }

    /// Writes one value at the start of `buffer`.
    pub fn write<T: bytemuck::Pod>(&self, buffer: &wgpu::Buffer, value: &T) {
        self.queue
            .write_buffer(buffer, 0, bytemuck::bytes_of(value));
    }

    /// Reads `size` bytes of `buffer` from `offset` (which must allow COPY_SRC).
    pub fn read_buffer(&self, buffer: &wgpu::Buffer, offset: u64, size: u64) -> Result<Vec<u8>> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buffer, offset, &staging, 0, size);
        self.queue.submit([enc.finish()]);
        self.map_read(&staging)
    }

    /// Maps a MAP_READ buffer whose copies were submitted, and returns its contents.
    pub fn map_read(&self, staging: &wgpu::Buffer) -> Result<Vec<u8>> {
        self.map_read_prefix(staging, staging.size())
    }

    /// Like `map_read`, for the first `bytes` bytes only.
    pub fn map_read_prefix(&self, staging: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>> {
        self.with_mapped(staging, bytes, <[u8]>::to_vec)
    }

    /// Maps the first `bytes` bytes of a MAP_READ buffer whose copies were submitted and hands
    /// them to `read` in place: a large read-back (a frame's pixels) is not copied into a fresh
    /// allocation first, whose page faults and copy cost more than the read itself.
    pub fn with_mapped<R>(
        &self,
        staging: &wgpu::Buffer,
        bytes: u64,
        read: impl FnOnce(&[u8]) -> R,
    ) -> Result<R> {
        let slice = staging.slice(..bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|_| Error::Gpu("buffer map callback never ran".into()))?
            .map_err(|e| Error::Gpu(format!("buffer map failed: {e}")))?;
        let out = read(
            &slice
                .get_mapped_range()
                .map_err(|e| Error::Gpu(format!("buffer map failed: {e}")))?,
        );
        staging.unmap();
        Ok(out)
    }
}

pub fn describe(info: &wgpu::AdapterInfo) -> String {
    format!(
        "{} ({:?}, {:?}, {} {})",
        info.name, info.device_type, info.backend, info.driver, info.driver_info
    )
}
