//! Creating a renderer: adapter, device, pipelines and render targets, and what the
//! shader expects of them (target formats, vertex and uniform layouts, the WGSL source).

use std::num::NonZeroU64;
use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};

use crate::readback::Plane;
use crate::{AdapterSummary, RenderError, Renderer, RendererConfig};

/// Matches `VertexIn` in shader.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct Vertex {
    pub(crate) position: [f32; 3],
    pub(crate) normal: [f32; 3],
    pub(crate) uv: [f32; 2],
}

/// Matches `Frame` in shader.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct FrameUniform {
    pub(crate) clip_from_world: [[f32; 4]; 4],
    pub(crate) camera_from_world: [[f32; 4]; 4],
    pub(crate) sun_direction: [f32; 4],
    pub(crate) sun_colour: [f32; 4],
    pub(crate) ambient: [f32; 4],
    pub(crate) params: [f32; 4],
    pub(crate) eye: [f32; 4],
}

/// Matches `Instance` in shader.wgsl (std140: mat3x3 columns padded to 16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct InstanceUniform {
    pub(crate) world_from_model: [[f32; 4]; 4],
    pub(crate) normal_from_model: [[f32; 4]; 3],
    pub(crate) ids: [u32; 4],
}

const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// Instance and class ids leave packed in one target, `instance << 8 | class`: a software
/// rasteriser pays per target and fragment, and one 4-byte target costs less than a 2-byte
/// and a 1-byte one.
const IDS_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
/// Depth leaves as the bits of an f32 in a u32 target: R32Float is not renderable on GLES
/// 3.0 (llvmpipe through wgpu's GL backend), R32Uint is everywhere.
const DEPTH_OUT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
const ZBUFFER_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Targets in shader location order, with bytes per pixel; the depth target last and only
/// when asked for.
fn target_formats(depth: bool) -> Vec<(wgpu::TextureFormat, u32, &'static str)> {
    let mut t = vec![(COLOUR_FORMAT, 4, "colour"), (IDS_FORMAT, 4, "ids")];
    if depth {
        t.push((DEPTH_OUT_FORMAT, 4, "depth"));
    }
    t
}

/// The shader, without its depth output unless `depth`: lines marked `// depth target`.
fn shader_source(depth: bool) -> String {
    let source = include_str!("shader.wgsl");
    if depth {
        source.to_string()
    } else {
        source.lines().filter(|l| !l.ends_with("// depth target")).collect::<Vec<_>>().join("\n")
    }
}

impl Renderer {
    /// Creates a renderer for `width` x `height` frames on the best adapter available (a
    /// GPU if there is one, else a software rasteriser).
    pub fn new(config: &RendererConfig) -> Result<Self, RenderError> {
        let (width, height) = (config.width, config.height);
        if width == 0 || height == 0 {
            return Err(RenderError::Size { width, height, message: "both sides must be at least 1 pixel".into() });
        }
        // `with_env` lets WGPU_BACKEND / WGPU_ADAPTER_NAME choose, e.g. to compare rasterisers.
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle().with_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            ..Default::default()
        }))
        .map_err(|e| RenderError::NoAdapter(e.to_string()))?;
        let ai = adapter.get_info();
        let info = AdapterSummary {
            name: ai.name.clone(),
            backend: format!("{:?}", ai.backend),
            device_type: format!("{:?}", ai.device_type),
            driver: format!("{} {}", ai.driver, ai.driver_info).trim().to_string(),
        };
        let adapter_limits = adapter.limits();
        let max_side = adapter_limits.max_texture_dimension_2d;
        if width > max_side || height > max_side {
            return Err(RenderError::Size {
                width,
                height,
                message: format!("adapter {} allows at most {max_side} pixels a side", info.name),
            });
        }
        let limits =
            wgpu::Limits::downlevel_defaults().using_resolution(adapter_limits.clone()).using_alignment(adapter_limits);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("objslam renderer"),
            required_features: wgpu::Features::empty(),
            required_limits: limits,
            ..Default::default()
        }))
        .map_err(|e| RenderError::Device { adapter: info.to_string(), message: e.to_string() })?;
        let gpu_error = Arc::new(Mutex::new(None));
        let slot = gpu_error.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut s) = slot.lock() {
                s.get_or_insert_with(|| e.to_string());
            }
        }));

        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("objslam shader"),
            source: wgpu::ShaderSource::Wgsl(shader_source(config.depth).into()),
        });
        let uniform_layout = |label, dynamic: bool, size: usize| {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &[wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: dynamic,
                        min_binding_size: NonZeroU64::new(size as u64),
                    },
                    count: None,
                }],
            })
        };
        let frame_layout = uniform_layout("frame", false, size_of::<FrameUniform>());
        let instance_layout = uniform_layout("instance", true, size_of::<InstanceUniform>());
        let texture_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("albedo"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("objslam"),
            bind_group_layouts: &[Some(&frame_layout), Some(&instance_layout), Some(&texture_layout)],
            immediate_size: 0,
        });
        let attributes = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x2];
        let formats = target_formats(config.depth);
        let colour_targets: Vec<Option<wgpu::ColorTargetState>> = formats
            .iter()
            .map(|&(format, _, _)| {
                Some(wgpu::ColorTargetState { format, blend: None, write_mask: wgpu::ColorWrites::ALL })
            })
            .collect();
        // Two pipelines that differ only in culling: meshes that may skip their back faces
        // (see `MeshData::cull_back_faces`) and the rest, drawn from both sides.
        let make_pipeline = |cull_mode: Option<wgpu::Face>, fragment_entry: &str| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("objslam"),
                layout: Some(&layout),
                vertex: wgpu::VertexState {
                    module: &shader,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[Some(wgpu::VertexBufferLayout {
                        array_stride: size_of::<Vertex>() as u64,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &attributes,
                    })],
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    cull_mode,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: ZBUFFER_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                // One sample: an id is never blended with its neighbour's.
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &shader,
                    entry_point: Some(fragment_entry),
                    compilation_options: Default::default(),
                    targets: &colour_targets,
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let pipeline = make_pipeline(None, "fs_main");
        let culling_pipeline = make_pipeline(Some(wgpu::Face::Back), "fs_front");
        let frame_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame"),
            size: size_of::<FrameUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let frame_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame"),
            layout: &frame_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: frame_buffer.as_entire_binding() }],
        });
        // Repeat addressing so bark tiles along trunks. Bilinear within the nearest mip level
        // of CPU-built mipmaps: trilinear costs llvmpipe about 15 % more per frame.
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("albedo"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Nearest,
            ..Default::default()
        });
        let size = wgpu::Extent3d { width, height, depth_or_array_layers: 1 };
        let texture = |format, usage, label| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let targets: Vec<wgpu::Texture> = formats
            .iter()
            .map(|&(format, _, label)| {
                texture(format, wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC, label)
            })
            .collect();
        let target_views = targets.iter().map(|t| t.create_view(&Default::default())).collect();
        let zbuffer = texture(ZBUFFER_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT, "z-buffer")
            .create_view(&Default::default());
        // One buffer holds all four images, each row padded to 256 bytes as copies require.
        let mut planes = Vec::new();
        let mut offset = 0u64;
        for &(_, bytes, _) in &formats {
            let bytes_per_row = (bytes * width).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
            planes.push(Plane { offset, bytes_per_row, bytes_per_pixel: bytes });
            offset += bytes_per_row as u64 * height as u64;
        }
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: offset,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let instance_stride = (size_of::<InstanceUniform>() as u64)
            .next_multiple_of(device.limits().min_uniform_buffer_offset_alignment as u64);
        let renderer = Renderer {
            max_texture_side: device.limits().max_texture_dimension_2d,
            device,
            queue,
            info,
            gpu_error,
            width,
            height,
            pipeline,
            culling_pipeline,
            frame_buffer,
            frame_group,
            instance_layout,
            texture_layout,
            sampler,
            meshes: Vec::new(),
            textures: Vec::new(),
            instances: Vec::new(),
            instance_bytes: Vec::new(),
            instance_stride,
            instance_dirty: None,
            instance_buffer: None,
            draw_order: Vec::new(),
            target_views,
            targets,
            zbuffer,
            readback,
            planes,
        };
        renderer.check_gpu_error()?;
        Ok(renderer)
    }

    /// The adapter in use, to record beside results.
    pub fn adapter_info(&self) -> AdapterSummary {
        self.info.clone()
    }

    /// Frame size (width, height) in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    pub(crate) fn check_gpu_error(&self) -> Result<(), RenderError> {
        match self.gpu_error.lock().map(|mut e| e.take()) {
            Ok(None) => Ok(()),
            Ok(Some(e)) => Err(RenderError::Gpu(e)),
            Err(_) => Err(RenderError::Gpu("error slot poisoned".into())),
        }
    }
}
