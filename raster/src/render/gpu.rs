//! The wgpu forward rasterizer for serving. Projection and tile binning run on the CPU (the
//! same code as the CPU renderer, so both agree on which Gaussians each tile sees and in what
//! order); the compositing, which is where the time goes, runs in a compute shader
//! (`composite.wgsl`), one workgroup per tile. Headless: any adapter wgpu finds (a real GPU,
//! or Mesa's lavapipe on machines without one). The shader is specialized per channel count
//! (the per-pixel accumulator is a fixed-size array) and pipelines are cached.

use std::collections::HashMap;
use std::sync::Mutex;

use inssplat_proto::Camera;
use wgpu::util::DeviceExt;

use super::project::View;
use super::{AlphaCutoff, Image, RenderError, Splats, prepare, validate};

const SHADER: &str = include_str!("composite.wgsl");

/// A wgpu device with the compositing pipelines; create once, render many times.
pub struct GpuRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: wgpu::AdapterInfo,
    pipelines: Mutex<HashMap<usize, wgpu::ComputePipeline>>,
}

impl std::fmt::Debug for GpuRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuRenderer").field("adapter", &self.adapter.name).finish()
    }
}

fn gpu_err(e: impl std::fmt::Display) -> RenderError {
    RenderError::Gpu(e.to_string())
}

/// A storage buffer needs at least one element.
fn padded<T: bytemuck::Pod + Default>(data: &[T]) -> Vec<T> {
    if data.is_empty() { vec![T::default()] } else { data.to_vec() }
}

impl GpuRenderer {
    /// Opens the first adapter wgpu finds (high performance preferred).
    /// [`RenderError::NoAdapter`] when there is none.
    pub fn new() -> Result<Self, RenderError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|_| RenderError::NoAdapter)?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("inssplat-raster"),
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(gpu_err)?;
        Ok(Self {
            device,
            queue,
            adapter: adapter.get_info(),
            pipelines: Mutex::new(HashMap::new()),
        })
    }

    /// Name and backend of the adapter in use (e.g. "llvmpipe (LLVM 19.1.7, 256 bits)", Vulkan).
    pub fn adapter(&self) -> String {
        format!("{} ({:?})", self.adapter.name, self.adapter.backend)
    }

    /// Whether the adapter is a CPU implementation (lavapipe/llvmpipe), where the CPU
    /// rasterizer is usually faster: serving code can use it to choose.
    pub fn is_software(&self) -> bool {
        self.adapter.device_type == wgpu::DeviceType::Cpu
    }

    fn pipeline(&self, channels: usize) -> wgpu::ComputePipeline {
        let mut cache = self.pipelines.lock().unwrap_or_else(|e| e.into_inner());
        cache
            .entry(channels)
            .or_insert_with(|| {
                let source = SHADER
                    .replace("{{CHANNELS}}", &channels.to_string())
                    .replace("{{ACC}}", &channels.max(1).to_string());
                let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("composite.wgsl"),
                    source: wgpu::ShaderSource::Wgsl(source.into()),
                });
                self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some("composite"),
                    layout: None,
                    module: &module,
                    entry_point: Some("main"),
                    compilation_options: Default::default(),
                    cache: None,
                })
            })
            .clone()
    }

    /// Renders like [`super::render`] (hard alpha cutoff), without the backward state.
    pub fn render(
        &self,
        splats: &Splats,
        camera: &Camera,
        background: &[f32],
    ) -> Result<Image, RenderError> {
        let background = validate(splats, camera, background)?;
        let (width, height) = (camera.intrinsics.width, camera.intrinsics.height);
        let c = splats.channels;
        let view = View::new(camera);
        let (_, bins) = prepare(splats, &view, AlphaCutoff::Hard, width, height);
        let pixels = width as usize * height as usize;

        let gauss: Vec<[f32; 4]> = bins
            .sorted
            .iter()
            .flat_map(|p| {
                let [a, b, cc] = p.conic;
                [[p.xy[0], p.xy[1], a, b], [cc, p.opacity, p.depth, 0.0]]
            })
            .collect();
        let params = [width, height, bins.tiles_x, pixels as u32];
        let out_bytes = ((c + 2) * pixels * 4) as u64;
        // Too large for one binding on this adapter: an error, so callers fall back to the CPU.
        let limit = self.device.limits().max_storage_buffer_binding_size;
        let largest =
            [gauss.len() * 16, bins.sorted_features.len() * 4, bins.rank_from_isect.len() * 4]
                .into_iter()
                .map(|b| b as u64)
                .chain([out_bytes])
                .max()
                .unwrap_or(0);
        if largest > limit {
            return Err(RenderError::Gpu(format!(
                "a {largest}-byte buffer exceeds the adapter's {limit}-byte binding limit"
            )));
        }
        // Validation errors would otherwise go to wgpu's handler, which panics.
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let storage = |label, contents: &[u8]| {
            self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let params_buf = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("params"),
            contents: bytemuck::cast_slice(&params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let gauss_buf = storage("gauss", bytemuck::cast_slice(&padded(&gauss)));
        let features_buf =
            storage("features", bytemuck::cast_slice(&padded(&bins.sorted_features)));
        let offsets_buf = storage("tile_offsets", bytemuck::cast_slice(&bins.tile_offsets));
        let isect_buf =
            storage("rank_from_isect", bytemuck::cast_slice(&padded(&bins.rank_from_isect)));
        let background_buf = storage("background", bytemuck::cast_slice(&padded(&background)));
        let out_buf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("output"),
            size: out_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: out_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let pipeline = self.pipeline(c);
        let layout = pipeline.get_bind_group_layout(0);
        let buffers = [
            &params_buf,
            &gauss_buf,
            &features_buf,
            &offsets_buf,
            &isect_buf,
            &background_buf,
            &out_buf,
        ];
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("composite"),
            layout: &layout,
            entries: &entries,
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("render") });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("composite"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(bins.tiles_x, bins.tiles_y, 1);
        }
        encoder.copy_buffer_to_buffer(&out_buf, 0, &readback, 0, out_bytes);
        self.queue.submit([encoder.finish()]);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(gpu_err(e));
        }

        let (sender, receiver) = std::sync::mpsc::channel();
        readback.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = sender.send(r);
        });
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(gpu_err)?;
        receiver.recv().map_err(gpu_err)?.map_err(gpu_err)?;
        let out: Vec<f32> = {
            let view = readback.get_mapped_range(..).map_err(gpu_err)?;
            bytemuck::cast_slice(&view).to_vec()
        };
        readback.unmap();
        Ok(Image {
            width,
            height,
            channels: c,
            features: out[..c * pixels].to_vec(),
            depth: out[c * pixels..(c + 1) * pixels].to_vec(),
            alpha: out[(c + 1) * pixels..].to_vec(),
        })
    }
}
