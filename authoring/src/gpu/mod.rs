//! The wgpu compute device for the per-pixel work of compensation and relighting, and the
//! choice between it and the CPU reference (`--device auto|cpu|gpu`). One device per process,
//! opened on first use; when none can be opened the CPU path is used and the log says so once.
//!
//! `auto` uses a hardware adapter (discrete, integrated or virtual GPU) when there is one and
//! the CPU otherwise: a software Vulkan device (Mesa's lavapipe) emulates a GPU on the same
//! cores, so the CPU path is faster there. `gpu` takes any adapter, lavapipe included (that is
//! how CI runs the GPU path), and fails with a clear error when there is none.

use std::fmt;
use std::str::FromStr;
use std::sync::OnceLock;

use thiserror::Error;
use wgpu::util::DeviceExt;

#[derive(Debug, Error)]
pub enum GpuError {
    #[error(
        "--device gpu was asked for but no GPU adapter could be opened ({0}); install a Vulkan \
         driver (e.g. mesa-vulkan-drivers for lavapipe) or use --device cpu"
    )]
    NoAdapter(String),
    #[error("the GPU could not map a result buffer back ({0})")]
    Readback(String),
    #[error("the work needs a {what} of {need} bytes but the GPU allows at most {max} bytes")]
    TooLarge { what: &'static str, need: u64, max: u64 },
}

/// Where the per-pixel work runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Device {
    /// A hardware GPU when there is one, else the CPU.
    #[default]
    Auto,
    /// The CPU reference path.
    Cpu,
    /// Any wgpu adapter, software (lavapipe) included; an error when none exists.
    Gpu,
}

impl fmt::Display for Device {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Auto => "auto",
            Self::Cpu => "cpu",
            Self::Gpu => "gpu",
        })
    }
}

impl FromStr for Device {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "cpu" => Ok(Self::Cpu),
            "gpu" => Ok(Self::Gpu),
            _ => Err(format!("device {s:?} is not one of auto, cpu, gpu")),
        }
    }
}

/// An opened compute device.
#[derive(Debug)]
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
}

static GPU: OnceLock<Result<Gpu, String>> = OnceLock::new();

fn open() -> Result<Gpu, String> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        ..Default::default()
    }))
    .map_err(|e| e.to_string())?;
    let info = adapter.get_info();
    // Ask for what the adapter offers: frames of 1400x1050 need storage buffers above the
    // portable defaults.
    let limits = adapter.limits();
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("restage compute"),
        required_limits: limits.clone(),
        ..Default::default()
    }))
    .map_err(|e| e.to_string())?;
    Ok(Gpu { device, queue, info, limits })
}

/// The process's GPU, opened on first call; the outcome is logged once.
pub fn shared() -> Result<&'static Gpu, &'static str> {
    GPU.get_or_init(|| {
        let r = open();
        match &r {
            Ok(g) => tracing::info!(
                adapter = %g.info.name,
                kind = ?g.info.device_type,
                backend = ?g.info.backend,
                "GPU compute device opened"
            ),
            Err(e) => tracing::warn!(reason = %e, "no GPU adapter: per-pixel work runs on the CPU"),
        }
        r
    })
    .as_ref()
    .map_err(String::as_str)
}

/// Resolves `device` to a GPU (`Some`) or the CPU path (`None`).
pub fn select(device: Device) -> Result<Option<&'static Gpu>, GpuError> {
    match device {
        Device::Cpu => Ok(None),
        Device::Gpu => shared().map(Some).map_err(|e| GpuError::NoAdapter(e.to_string())),
        Device::Auto => Ok(shared().ok().filter(|g| {
            let hardware = g.info.device_type != wgpu::DeviceType::Cpu;
            if !hardware {
                static SAID: std::sync::Once = std::sync::Once::new();
                SAID.call_once(|| {
                    tracing::info!(
                        adapter = %g.info.name,
                        "only a software GPU adapter: --device auto uses the CPU path (faster on the \
                         same cores); --device gpu uses the adapter"
                    )
                });
            }
            hardware
        })),
    }
}

/// Workgroup size of every kernel (`@workgroup_size(256)` in the shaders).
pub const WORKGROUP: u32 = 256;

impl Gpu {
    /// A storage buffer holding `data`.
    pub fn storage<T: bytemuck::Pod>(
        &self,
        label: &'static str,
        data: &[T],
    ) -> Result<wgpu::Buffer, GpuError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        self.check(label, bytes.len() as u64)?;
        // Zero-length bindings are invalid: give empty inputs one padding word.
        let pad = [0u8; 4];
        let contents = if bytes.is_empty() { &pad[..] } else { bytes };
        Ok(self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        }))
    }

    /// An uninitialised (zeroed by wgpu) storage buffer of `bytes` bytes for results.
    pub fn output(&self, label: &'static str, bytes: u64) -> Result<wgpu::Buffer, GpuError> {
        self.check(label, bytes)?;
        Ok(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(4),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }))
    }

    fn check(&self, what: &'static str, need: u64) -> Result<(), GpuError> {
        let max = self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size);
        if need > max { Err(GpuError::TooLarge { what, need, max }) } else { Ok(()) }
    }

    /// A compute pipeline for `entry` of the WGSL `source`, with its bind-group layout
    /// derived from the shader.
    pub fn pipeline(&self, module: &wgpu::ShaderModule, entry: &str) -> wgpu::ComputePipeline {
        self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        })
    }

    pub fn module(&self, label: &str, source: &str) -> wgpu::ShaderModule {
        self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        })
    }

    /// Binds `(binding, buffer)` pairs to group 0 of `pipeline` (its layout holds only the
    /// bindings the entry point uses).
    pub fn bind(
        &self,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let layout = pipeline.get_bind_group_layout(0);
        let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
            .iter()
            .map(|(i, b)| wgpu::BindGroupEntry { binding: *i, resource: b.as_entire_binding() })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &layout,
            entries: &entries,
        })
    }

    /// Records a dispatch of `threads` invocations (one per item) of `pipeline`. Large counts
    /// use a second grid dimension; shaders index with [`WORKGROUP`] and `num_workgroups`.
    pub fn dispatch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        group: &wgpu::BindGroup,
        threads: u64,
    ) {
        let groups = threads.div_ceil(WORKGROUP as u64).max(1);
        let max = self.limits.max_compute_workgroups_per_dimension.max(1) as u64;
        let x = groups.min(max);
        let y = groups.div_ceil(x);
        let mut pass =
            encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        pass.dispatch_workgroups(x as u32, y as u32, 1);
    }

    /// Copies `buffer` back to the host after everything submitted so far has run.
    pub fn read<T: bytemuck::Pod>(&self, buffer: &wgpu::Buffer, count: usize) -> Result<Vec<T>, GpuError> {
        let bytes = (count * std::mem::size_of::<T>()) as u64;
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, bytes);
        self.queue.submit([encoder.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let view = staging.get_mapped_range(..).map_err(|e| GpuError::Readback(e.to_string()))?;
        let out = bytemuck::cast_slice::<u8, T>(&view).to_vec();
        drop(view);
        staging.unmap();
        Ok(out)
    }
}

/// For tests of the GPU path: the GPU, or `None` when there is none and the environment says
/// that is acceptable (`RESTAGE_NO_GPU_OK=1`). Without that variable a missing adapter fails
/// the test, so CI (which installs lavapipe) cannot skip the comparison silently.
pub fn for_tests() -> Option<&'static Gpu> {
    match shared() {
        Ok(g) => Some(g),
        Err(e) if std::env::var("RESTAGE_NO_GPU_OK").is_ok_and(|v| v == "1") => {
            tracing::warn!(reason = e, "no GPU adapter; GPU comparison skipped (RESTAGE_NO_GPU_OK=1)");
            None
        }
        Err(e) => panic!(
            "no GPU adapter ({e}): install mesa-vulkan-drivers (lavapipe) or set RESTAGE_NO_GPU_OK=1 \
             to skip the GPU comparisons"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_names_parse() {
        assert_eq!("GPU".parse::<Device>().unwrap(), Device::Gpu);
        assert_eq!("cpu".parse::<Device>().unwrap(), Device::Cpu);
        assert!("tpu".parse::<Device>().unwrap_err().contains("auto, cpu, gpu"));
        assert_eq!(select(Device::Cpu).unwrap().map(|g| g.info.name.clone()), None);
    }
}
