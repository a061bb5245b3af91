//! The wgpu device the viewer draws and computes with: one adapter, one device and queue, with
//! the adapter's own limits (the defaults cap 2D textures at 8192) and the optional features the
//! shadow shaders and the frame timer use when the adapter has them.

use std::fmt;

/// An adapter with its device and queue, ready for the renderer and the shadow shaders.
/// Cloning shares them (wgpu's handles are reference-counted and usable from any thread: the
/// tile loaders of [`crate::stream`] make textures on their own threads).
#[derive(Clone)]
pub struct Gpu {
    /// The instance the adapter came from (the window's surface is made from it).
    pub instance: wgpu::Instance,
    /// The adapter (a GPU, or a CPU implementation such as Mesa's lavapipe).
    pub adapter: wgpu::Adapter,
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter's name, backend and device type, for logs and reports.
    pub info: wgpu::AdapterInfo,
    /// Whether the device has `TIMESTAMP_QUERY` (GPU frame timings).
    pub timestamps: bool,
}

/// Why no device could be made.
#[derive(Debug)]
pub enum GpuError {
    /// No adapter at all: no GPU driver and no software fallback.
    NoAdapter(String),
    /// An adapter was found but refused the device.
    Device(String),
}

impl fmt::Display for GpuError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            GpuError::NoAdapter(why) => write!(
                f,
                "no GPU adapter ({why}); install a Vulkan driver, or Mesa's software one \
                 (`apt-get install mesa-vulkan-drivers`, lavapipe), or pick a backend with \
                 WGPU_BACKEND=vulkan|gl"
            ),
            GpuError::Device(why) => write!(
                f,
                "the GPU adapter refused a device ({why}); update the driver, or try another \
                 backend with WGPU_BACKEND=vulkan|gl"
            ),
        }
    }
}

impl std::error::Error for GpuError {}

impl Gpu {
    /// A device without a surface (headless frames, validation, tests); the instance's backends
    /// and flags come from the environment (`WGPU_BACKEND`, …). A software adapter is accepted
    /// when there is no other.
    pub fn headless() -> Result<Gpu, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = request_adapter(&instance, None)?;
        Gpu::from_adapter(instance, adapter)
    }

    /// A device whose adapter can present to `surface` (made from `instance`).
    pub fn for_surface(
        instance: wgpu::Instance,
        surface: &wgpu::Surface<'_>,
    ) -> Result<Gpu, GpuError> {
        let adapter = request_adapter(&instance, Some(surface))?;
        Gpu::from_adapter(instance, adapter)
    }

    fn from_adapter(instance: wgpu::Instance, adapter: wgpu::Adapter) -> Result<Gpu, GpuError> {
        let info = adapter.get_info();
        let wanted = wgpu::Features::FLOAT32_FILTERABLE | wgpu::Features::TIMESTAMP_QUERY;
        let features = adapter.features() & wanted;
        let desc = wgpu::DeviceDescriptor {
            label: Some("penumbra-view"),
            required_features: features,
            required_limits: adapter.limits(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc))
            .map_err(|e| GpuError::Device(format!("{} ({:?}): {e}", info.name, info.backend)))?;
        Ok(Gpu {
            instance,
            adapter,
            device,
            queue,
            info,
            timestamps: features.contains(wgpu::Features::TIMESTAMP_QUERY),
        })
    }

    /// One line naming the adapter: name, backend, device type.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }
}

/// A hardware adapter when there is one, else the fallback (software) adapter.
fn request_adapter(
    instance: &wgpu::Instance,
    surface: Option<&wgpu::Surface<'_>>,
) -> Result<wgpu::Adapter, GpuError> {
    let mut why = Vec::new();
    for fallback in [false, true] {
        let options = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: fallback,
            compatible_surface: surface,
            apply_limit_buckets: false,
        };
        match pollster::block_on(instance.request_adapter(&options)) {
            Ok(adapter) => return Ok(adapter),
            Err(e) => why.push(e.to_string()),
        }
    }
    why.dedup();
    Err(GpuError::NoAdapter(why.join("; ")))
}

impl Gpu {
    /// A read-only 2-D texture (`TEXTURE_BINDING`, one mip level) of `w × h` texels of `format`
    /// from `bytes` (row-major), and its default view.
    pub fn texture_view(
        &self,
        label: &str,
        format: wgpu::TextureFormat,
        w: u32,
        h: u32,
        bytes: &[u8],
    ) -> wgpu::TextureView {
        use wgpu::util::DeviceExt;
        self.device
            .create_texture_with_data(
                &self.queue,
                &wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d {
                        width: w,
                        height: h,
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage: wgpu::TextureUsages::TEXTURE_BINDING,
                    view_formats: &[],
                },
                wgpu::util::TextureDataOrder::LayerMajor,
                bytes,
            )
            .create_view(&wgpu::TextureViewDescriptor::default())
    }
}
