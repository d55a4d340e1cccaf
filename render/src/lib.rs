//! # render — a headless wgpu renderer with pixel-exact ground truth
//!
//! Renders textured, lit triangle meshes seen by a pinhole camera into a colour image, an
//! instance-id image, a class-id image and a metric depth image. One render pass writes all
//! four (multiple render targets, no multisampling), so the masks align with the colour
//! image exactly. The crate depends on no other crate of the workspace: callers hand it
//! plain mesh and texture data.
//!
//! Without a GPU, wgpu falls back to Mesa's software rasterisers (GL over EGL with
//! llvmpipe, or Vulkan lavapipe when `mesa-vulkan-drivers` is installed);
//! [`Renderer::adapter_info`] says which adapter was used. `WGPU_BACKEND=gl` or
//! `WGPU_BACKEND=vulkan` picks a backend.
//!
//! ## Conventions
//! - Units: metres; transforms are column-major 4x4 (`m[column][row]`, translation in
//!   `m[3]`).
//! - The world is z-up. The camera's optical frame has z forward, x right, y down.
//! - Pinhole projection: a camera-frame point (X, Y, Z) lands at the continuous pixel
//!   coordinates u = fx X/Z + cx, v = fy Y/Z + cy. Pixel (i, j) (column i, row j, row 0 at
//!   the top) covers [i, i+1) x [j, j+1); its centre is at (i + 0.5, j + 0.5), so the point
//!   falls in pixel (floor(u), floor(v)). An ideal centred camera of width W has cx = W/2.
//! - Depth is the z-depth along the optical axis (not the range along the ray).
//!
//! ## Tests
//! `tests/render.rs` compares a small scene with `tests/golden/*.png` within a tolerance;
//! after an intended change, regenerate them with
//! `OBJSLAM_BLESS=1 cargo test -p render --test render golden`. The tests fail (they do not
//! skip) when no adapter exists.
//!
//! ## Example
//! ```
//! use render::*;
//! let mut r = Renderer::new(&RendererConfig::new(64, 48))?;
//! println!("rendering on {}", r.adapter_info());
//! // A 2 m square facing the camera, 4 m ahead along world x.
//! let square = MeshData {
//!     positions: vec![[4.0, -1.0, -1.0], [4.0, 1.0, -1.0], [4.0, 1.0, 1.0], [4.0, -1.0, 1.0]],
//!     normals: vec![[-1.0, 0.0, 0.0]; 4],
//!     uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
//!     indices: vec![0, 1, 2, 0, 2, 3],
//!     cull_back_faces: false,
//! };
//! let mesh = r.add_mesh(&square)?;
//! let paint = r.add_texture(&TextureData { width: 1, height: 1, rgba: vec![200, 100, 50, 255] })?;
//! r.add_instance(mesh, paint, IDENTITY, 7, 2);
//! let camera = Camera::look_at(50.0, 50.0, 32.0, 24.0, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
//! let frame = r.render(&camera, &Lighting::default())?;
//! assert_eq!(frame.instance_at(32, 24), 7);
//! assert!((frame.depth_at(32, 24) - 4.0).abs() < 1e-3);
//! # Ok::<(), render::RenderError>(())
//! ```

use std::num::NonZeroU64;
use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// Column-major 4x4 identity.
pub const IDENTITY: [[f32; 4]; 4] =
    [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];

/// Errors from the renderer; none of them is raised by a panic.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no graphics adapter available, not even a software rasteriser ({0}); on Debian install libegl-mesa0 and libgl1-mesa-dri (GL/llvmpipe) or mesa-vulkan-drivers (Vulkan/lavapipe)"
    )]
    NoAdapter(String),
    #[error("cannot create a device on adapter {adapter}: {message}")]
    Device { adapter: String, message: String },
    #[error("invalid image size {width}x{height}: {message}")]
    Size { width: u32, height: u32, message: String },
    #[error("invalid mesh: {0}")]
    Mesh(String),
    #[error("invalid texture: {0}")]
    Texture(String),
    #[error("invalid camera: {0}")]
    Camera(String),
    #[error("invalid lighting: {0}")]
    Lighting(String),
    #[error(
        "invalid pixel columns {start}..{end}: spans must be non-empty, sorted, disjoint and within the image's {width} columns"
    )]
    Columns { start: u32, end: u32, width: u32 },
    #[error("instance {instance} refers to mesh {mesh} or texture {texture}, which this renderer does not have")]
    UnknownResource { instance: usize, mesh: usize, texture: usize },
    #[error("GPU error: {0}")]
    Gpu(String),
    #[error("GPU readback failed: {0}")]
    Readback(String),
}

/// A triangle mesh in its model frame: positions (m), normals (need not be unit), texture
/// coordinates (may exceed 1: textures repeat) and triangles (counter-clockwise seen from
/// the side the normals point to, by convention). Unless `cull_back_faces` is set, both
/// sides are drawn, whatever the winding, so open meshes need no caps; a surface seen from
/// the side its normals point away from is lit with them reversed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MeshData {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<u32>,
    /// The mesh is closed wherever it can be seen and every triangle is counter-clockwise
    /// seen from outside, so triangles seen from behind are hidden anyway and may be
    /// skipped. A software rasteriser pays for every fragment it shades: skipping the far
    /// side of trunks saves about a fifth of a park frame. Wrong for open or inconsistently
    /// wound meshes (holes would show), hence off by default.
    pub cull_back_faces: bool,
}

/// An sRGB RGBA8 image, row-major from the top row; uv (0, 0) is its top-left corner.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureData {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

/// Image size of every frame a renderer makes, and whether frames carry depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RendererConfig {
    pub width: u32,
    pub height: u32,
    /// Whether frames carry the depth image. It is a render target of its own, about a
    /// tenth of a software-rendered frame's cost: a consumer that never reads depth (the
    /// online pipeline) goes faster without. Without it, `Frame::depth_m` is empty.
    pub depth: bool,
}

impl RendererConfig {
    /// Frames of `width` x `height` with every image, depth included.
    pub fn new(width: u32, height: u32) -> Self {
        RendererConfig { width, height, depth: true }
    }
}

/// Which adapter renders, so results can say what produced them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AdapterSummary {
    /// E.g. "llvmpipe (LLVM 15.0.6, 256 bits)".
    pub name: String,
    /// "Vulkan", "Gl", "Metal" or "Dx12".
    pub backend: String,
    /// "Cpu" for software rasterisers, else "DiscreteGpu", "IntegratedGpu", ...
    pub device_type: String,
    /// Driver name and version.
    pub driver: String,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}, {}, {})", self.name, self.backend, self.device_type, self.driver)
    }
}

/// A mesh uploaded with [`Renderer::add_mesh`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MeshId(usize);
/// A texture uploaded with [`Renderer::add_texture`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TextureId(usize);
/// An instance placed with [`Renderer::add_instance`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct InstanceHandle(usize);

/// A pinhole camera: intrinsics in pixels and the pose of its optical frame in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// World <- camera optical frame (z forward, x right, y down), rigid, column-major.
    pub world_from_camera: [[f32; 4]; 4],
    /// Nothing nearer than this (m, along z) is drawn.
    pub near_m: f32,
    /// Nothing farther than this (m, along z) is drawn.
    pub far_m: f32,
}

impl Camera {
    /// A camera at `eye` whose optical axis points at `target`, with the image rows level
    /// (x axis horizontal in a z-up world). Near 0.05 m, far 500 m. If the axis is vertical
    /// the image x axis is taken along world -y.
    pub fn look_at(fx: f32, fy: f32, cx: f32, cy: f32, eye: [f32; 3], target: [f32; 3]) -> Self {
        let z = normalised(sub(target, eye)).unwrap_or([1.0, 0.0, 0.0]);
        let x = normalised(cross(z, [0.0, 0.0, 1.0])).unwrap_or([0.0, -1.0, 0.0]);
        let y = cross(z, x);
        let world_from_camera =
            [[x[0], x[1], x[2], 0.0], [y[0], y[1], y[2], 0.0], [z[0], z[1], z[2], 0.0], [eye[0], eye[1], eye[2], 1.0]];
        Camera { fx, fy, cx, cy, world_from_camera, near_m: 0.05, far_m: 500.0 }
    }

    /// Projects a world point with the pinhole model: `Some([u, v, z])` in continuous pixel
    /// coordinates and metres, or `None` behind the camera.
    pub fn project(&self, world: [f32; 3]) -> Option<[f32; 3]> {
        let [x, y, z] = transform_point(&rigid_inverse(&self.world_from_camera), world);
        (z > 0.0).then(|| [self.fx * x / z + self.cx, self.fy * y / z + self.cy, z])
    }

    fn validate(&self) -> Result<(), RenderError> {
        let ok = |v: f32| v.is_finite() && v > 0.0;
        if !(ok(self.fx) && ok(self.fy) && self.cx.is_finite() && self.cy.is_finite()) {
            return Err(RenderError::Camera(format!(
                "focal lengths must be positive and finite (fx {}, fy {}, cx {}, cy {})",
                self.fx, self.fy, self.cx, self.cy
            )));
        }
        if !(ok(self.near_m) && self.far_m.is_finite() && self.far_m > self.near_m) {
            return Err(RenderError::Camera(format!(
                "needs 0 < near_m < far_m < inf, got near {} far {}",
                self.near_m, self.far_m
            )));
        }
        if self.world_from_camera.iter().flatten().any(|v| !v.is_finite()) {
            return Err(RenderError::Camera("world_from_camera has non-finite entries".into()));
        }
        Ok(())
    }
}

/// Sun and sky. Colours are linear RGB intensities except `sky_colour`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lighting {
    /// Direction the sunlight travels, world frame (need not be unit), e.g. [0, 0, -1] at noon.
    pub sun_direction: [f32; 3],
    /// Sun irradiance on a surface facing it (Lambert term).
    pub sun_colour: [f32; 3],
    /// Sky light on an upward surface; 0.4 of it reaches a downward one.
    pub ambient: [f32; 3],
    /// Background where nothing is drawn, sRGB in 0..1; written as is (no exposure).
    pub sky_colour: [f32; 3],
    /// Multiplies the lit colour (1 = as lit).
    pub exposure: f32,
}

impl Default for Lighting {
    /// A clear afternoon.
    fn default() -> Self {
        Lighting {
            sun_direction: [-0.4, -0.3, -0.85],
            sun_colour: [0.85, 0.82, 0.75],
            ambient: [0.45, 0.48, 0.55],
            sky_colour: [0.62, 0.74, 0.88],
            exposure: 1.0,
        }
    }
}

/// One rendered frame. All images are row-major from the top row, `width * height` pixels.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    /// sRGB colour, 3 bytes per pixel.
    pub rgb: Vec<u8>,
    /// Instance id per pixel; 0 where nothing was drawn (so 0 should not be given to objects).
    pub instance: Vec<u16>,
    /// Class id per pixel; 0 where nothing was drawn.
    pub class: Vec<u8>,
    /// Z-depth along the optical axis (m); `f32::INFINITY` where nothing was drawn. Empty
    /// when the renderer was made without depth (`RendererConfig::depth`).
    pub depth_m: Vec<f32>,
    /// The pixel columns rendered (`start..end`, sorted, disjoint); `None`: all of them.
    /// Outside them the images are zero (black, no instance, no class) and the depth
    /// infinite (see [`Renderer::render_columns_into`]).
    pub columns: Option<Vec<(u32, u32)>>,
}

impl Frame {
    /// Instance id at column `u`, row `v`. Panics out of the image, like slice indexing.
    pub fn instance_at(&self, u: u32, v: u32) -> u16 {
        self.instance[self.index(u, v)]
    }

    /// Class id at column `u`, row `v`.
    pub fn class_at(&self, u: u32, v: u32) -> u8 {
        self.class[self.index(u, v)]
    }

    /// Z-depth (m) at column `u`, row `v`. Panics on a frame rendered without depth.
    pub fn depth_at(&self, u: u32, v: u32) -> f32 {
        self.depth_m[self.index(u, v)]
    }

    /// sRGB colour at column `u`, row `v`.
    pub fn rgb_at(&self, u: u32, v: u32) -> [u8; 3] {
        let i = 3 * self.index(u, v);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    fn index(&self, u: u32, v: u32) -> usize {
        assert!(u < self.width && v < self.height, "pixel ({u}, {v}) outside {}x{}", self.width, self.height);
        v as usize * self.width as usize + u as usize
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Vertex {
    position: [f32; 3],
    normal: [f32; 3],
    uv: [f32; 2],
}

/// Matches `Frame` in shader.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct FrameUniform {
    clip_from_world: [[f32; 4]; 4],
    camera_from_world: [[f32; 4]; 4],
    sun_direction: [f32; 4],
    sun_colour: [f32; 4],
    ambient: [f32; 4],
    params: [f32; 4],
    eye: [f32; 4],
}

/// Matches `Instance` in shader.wgsl (std140: mat3x3 columns padded to 16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct InstanceUniform {
    world_from_model: [[f32; 4]; 4],
    normal_from_model: [[f32; 4]; 3],
    ids: [u32; 4],
}

struct Mesh {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
    /// Bounding sphere in the model frame, for frustum culling.
    centre: [f32; 3],
    radius: f32,
    cull_back_faces: bool,
}

struct Instance {
    mesh: MeshId,
    texture: TextureId,
    visible: bool,
    world_from_model: [[f32; 4]; 4],
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

/// Where one target's rows lie in the shared readback buffer.
#[derive(Clone, Copy)]
struct Plane {
    offset: u64,
    bytes_per_row: u32,
    bytes_per_pixel: u32,
}

/// Renders frames of a fixed size. Meshes, textures and instances stay on the GPU; only
/// changed instance transforms and the per-frame camera/lighting are uploaded per frame.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: AdapterSummary,
    /// Errors wgpu reports asynchronously (it would panic by default).
    gpu_error: Arc<Mutex<Option<String>>>,
    width: u32,
    height: u32,
    max_texture_side: u32,
    /// Draws both sides of every triangle.
    pipeline: wgpu::RenderPipeline,
    /// Skips triangles seen from behind (counter-clockwise is the front).
    culling_pipeline: wgpu::RenderPipeline,
    frame_buffer: wgpu::Buffer,
    frame_group: wgpu::BindGroup,
    instance_layout: wgpu::BindGroupLayout,
    texture_layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    meshes: Vec<Mesh>,
    textures: Vec<wgpu::BindGroup>,
    instances: Vec<Instance>,
    /// CPU copy of the per-instance uniforms, `instance_stride` bytes apart.
    instance_bytes: Vec<u8>,
    instance_stride: u64,
    /// Byte range of `instance_bytes` changed since the last upload.
    instance_dirty: Option<(usize, usize)>,
    instance_buffer: Option<(wgpu::Buffer, wgpu::BindGroup)>,
    /// (sort key, instance index) of this frame's draws; kept to reuse its allocation.
    draw_order: Vec<(f32, usize)>,
    target_views: Vec<wgpu::TextureView>,
    targets: Vec<wgpu::Texture>,
    zbuffer: wgpu::TextureView,
    readback: wgpu::Buffer,
    /// Colour, the packed ids and (if rendered) depth.
    planes: Vec<Plane>,
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

    /// Uploads a mesh; it can then be instanced any number of times.
    pub fn add_mesh(&mut self, mesh: &MeshData) -> Result<MeshId, RenderError> {
        let n = mesh.positions.len();
        if n == 0 || mesh.indices.is_empty() || !mesh.indices.len().is_multiple_of(3) {
            return Err(RenderError::Mesh(format!(
                "{n} vertices and {} indices: needs vertices and whole triangles",
                mesh.indices.len()
            )));
        }
        if mesh.normals.len() != n || mesh.uvs.len() != n {
            return Err(RenderError::Mesh(format!(
                "{n} positions but {} normals and {} uvs",
                mesh.normals.len(),
                mesh.uvs.len()
            )));
        }
        if let Some(i) = mesh.indices.iter().find(|&&i| i as usize >= n) {
            return Err(RenderError::Mesh(format!("index {i} out of range for {n} vertices")));
        }
        let finite = |s: &[f32]| s.iter().all(|v| v.is_finite());
        if !(finite(mesh.positions.as_flattened())
            && finite(mesh.normals.as_flattened())
            && finite(mesh.uvs.as_flattened()))
        {
            return Err(RenderError::Mesh("non-finite position, normal or uv".into()));
        }
        let index_count =
            u32::try_from(mesh.indices.len()).map_err(|_| RenderError::Mesh("more than 2^32 indices".into()))?;
        let (centre, radius) = bounding_sphere(&mesh.positions);
        let vertices: Vec<Vertex> =
            (0..n).map(|i| Vertex { position: mesh.positions[i], normal: mesh.normals[i], uv: mesh.uvs[i] }).collect();
        let vertices = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: bytemuck::cast_slice(&vertices),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let indices = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("indices"),
            contents: bytemuck::cast_slice(&mesh.indices),
            usage: wgpu::BufferUsages::INDEX,
        });
        self.check_gpu_error()?;
        self.meshes.push(Mesh {
            vertices,
            indices,
            index_count,
            centre,
            radius,
            cull_back_faces: mesh.cull_back_faces,
        });
        Ok(MeshId(self.meshes.len() - 1))
    }

    /// Uploads an sRGB texture with a full mipmap chain (built here, averaging in linear
    /// light) so distant bark and grass do not shimmer.
    pub fn add_texture(&mut self, t: &TextureData) -> Result<TextureId, RenderError> {
        let expected = t.width as u64 * t.height as u64 * 4;
        if t.width == 0 || t.height == 0 || t.rgba.len() as u64 != expected {
            return Err(RenderError::Texture(format!(
                "{}x{} RGBA needs {expected} bytes, got {}",
                t.width,
                t.height,
                t.rgba.len()
            )));
        }
        if t.width > self.max_texture_side || t.height > self.max_texture_side {
            return Err(RenderError::Texture(format!(
                "{}x{} exceeds the adapter's {} pixels a side",
                t.width, t.height, self.max_texture_side
            )));
        }
        let (data, levels) = mip_chain(t);
        let texture = self.device.create_texture_with_data(
            &self.queue,
            &wgpu::TextureDescriptor {
                label: Some("albedo"),
                size: wgpu::Extent3d { width: t.width, height: t.height, depth_or_array_layers: 1 },
                mip_level_count: levels,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba8UnormSrgb,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            },
            wgpu::util::TextureDataOrder::LayerMajor,
            &data,
        );
        let view = texture.create_view(&Default::default());
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("albedo"),
            layout: &self.texture_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&view) },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::Sampler(&self.sampler) },
            ],
        });
        self.check_gpu_error()?;
        self.textures.push(group);
        Ok(TextureId(self.textures.len() - 1))
    }

    /// Places a visible instance of `mesh` with `texture` at `world_from_model` (column-major;
    /// scaling is allowed), writing `instance_id` and `class_id` into the masks. Ids from
    /// another renderer are reported by [`Renderer::render`].
    pub fn add_instance(
        &mut self,
        mesh: MeshId,
        texture: TextureId,
        world_from_model: [[f32; 4]; 4],
        instance_id: u16,
        class_id: u8,
    ) -> InstanceHandle {
        let k = self.instances.len();
        self.instances.push(Instance { mesh, texture, visible: true, world_from_model });
        self.instance_bytes.resize((k + 1) * self.instance_stride as usize, 0);
        self.write_instance(k, instance_id, class_id);
        // The buffer must grow: rebuild it on the next render.
        self.instance_buffer = None;
        InstanceHandle(k)
    }

    /// Moves an instance (e.g. a walking person). Unknown handles are ignored.
    pub fn set_transform(&mut self, handle: InstanceHandle, world_from_model: [[f32; 4]; 4]) {
        let Some(inst) = self.instances.get_mut(handle.0) else { return };
        inst.world_from_model = world_from_model;
        let at = handle.0 * self.instance_stride as usize;
        let ids: InstanceUniform =
            bytemuck::pod_read_unaligned(&self.instance_bytes[at..at + size_of::<InstanceUniform>()]);
        self.write_instance(handle.0, ids.ids[0] as u16, ids.ids[1] as u8);
    }

    /// Shows or hides an instance without removing it. Unknown handles are ignored.
    pub fn set_visible(&mut self, handle: InstanceHandle, visible: bool) {
        if let Some(inst) = self.instances.get_mut(handle.0) {
            inst.visible = visible;
        }
    }

    fn write_instance(&mut self, k: usize, instance_id: u16, class_id: u8) {
        let m = self.instances[k].world_from_model;
        let n = normal_matrix(&m);
        let uniform = InstanceUniform {
            world_from_model: m,
            normal_from_model: n,
            ids: [instance_id as u32, class_id as u32, 0, 0],
        };
        let at = k * self.instance_stride as usize;
        let end = at + size_of::<InstanceUniform>();
        self.instance_bytes[at..end].copy_from_slice(bytemuck::bytes_of(&uniform));
        self.instance_dirty = Some(match self.instance_dirty {
            Some((a, b)) => (a.min(at), b.max(end)),
            None => (at, end),
        });
    }

    /// Uploads changed instance uniforms, creating the buffer if instances were added.
    fn upload_instances(&mut self) {
        if self.instance_buffer.is_none() {
            let size = (self.instance_bytes.len() as u64).max(self.instance_stride);
            let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("instances"),
                size,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("instances"),
                layout: &self.instance_layout,
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &buffer,
                        offset: 0,
                        size: NonZeroU64::new(size_of::<InstanceUniform>() as u64),
                    }),
                }],
            });
            self.instance_buffer = Some((buffer, group));
            self.instance_dirty = Some((0, self.instance_bytes.len()));
        }
        if let (Some((a, b)), Some((buffer, _))) = (self.instance_dirty.take(), &self.instance_buffer) {
            // write_buffer needs 4-byte multiples; the uniforms are 16-byte aligned.
            if b > a {
                self.queue.write_buffer(buffer, a as u64, &self.instance_bytes[a..b]);
            }
        }
    }

    /// Renders one frame and reads back all images.
    pub fn render(&mut self, camera: &Camera, lighting: &Lighting) -> Result<Frame, RenderError> {
        let mut frame = Frame::default();
        self.render_into(camera, lighting, &mut frame)?;
        Ok(frame)
    }

    /// Like [`Renderer::render`], but reuses `frame`'s allocations (for long runs).
    pub fn render_into(&mut self, camera: &Camera, lighting: &Lighting, frame: &mut Frame) -> Result<(), RenderError> {
        self.render_columns_into(camera, lighting, None, frame)
    }

    /// Renders only the pixel columns in `columns` (`start..end` each; `None`: the whole
    /// image), for consumers that read only part of each frame. The pixels inside are
    /// those of the whole frame (the same draws in the same order, scissored); outside
    /// them the frame is zero. With no columns nothing is drawn at all.
    pub fn render_columns_into(
        &mut self,
        camera: &Camera,
        lighting: &Lighting,
        columns: Option<&[(u32, u32)]>,
        frame: &mut Frame,
    ) -> Result<(), RenderError> {
        camera.validate()?;
        let spans = match columns {
            None => vec![(0, self.width)],
            Some(columns) => {
                let mut previous_end = 0;
                for (i, &(start, end)) in columns.iter().enumerate() {
                    if start >= end || end > self.width || (i > 0 && start < previous_end) {
                        return Err(RenderError::Columns { start, end, width: self.width });
                    }
                    previous_end = end;
                }
                columns.to_vec()
            }
        };
        if lighting
            .sun_direction
            .iter()
            .chain(&lighting.sun_colour)
            .chain(&lighting.ambient)
            .chain(&lighting.sky_colour)
            .chain([&lighting.exposure])
            .any(|v| !v.is_finite())
        {
            return Err(RenderError::Lighting("non-finite direction, colour or exposure".into()));
        }
        for (k, inst) in self.instances.iter().enumerate() {
            if inst.mesh.0 >= self.meshes.len() || inst.texture.0 >= self.textures.len() {
                return Err(RenderError::UnknownResource { instance: k, mesh: inst.mesh.0, texture: inst.texture.0 });
            }
        }
        if spans.is_empty() {
            self.blank(frame);
            return Ok(());
        }
        self.upload_instances();
        let uniform = frame_uniform(camera, lighting, self.width, self.height);
        self.queue.write_buffer(&self.frame_buffer, 0, bytemuck::bytes_of(&uniform));

        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        {
            let sky = lighting.sky_colour.map(|c| srgb_to_linear(c.clamp(0.0, 1.0)) as f64);
            // Depth is cleared to 0 (never a drawn depth: near_m > 0) and read back as infinity.
            let clears = [
                wgpu::Color { r: sky[0], g: sky[1], b: sky[2], a: 1.0 },
                wgpu::Color::TRANSPARENT,
                wgpu::Color::TRANSPARENT,
            ];
            let attachments: Vec<Option<wgpu::RenderPassColorAttachment>> = self
                .target_views
                .iter()
                .zip(clears)
                .map(|(view, clear)| {
                    Some(wgpu::RenderPassColorAttachment {
                        view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations { load: wgpu::LoadOp::Clear(clear), store: wgpu::StoreOp::Store },
                    })
                })
                .collect();
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("scene"),
                color_attachments: &attachments,
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.zbuffer,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(0, &self.frame_group, &[]);
            let frustum = Frustum::new(camera, self.width, self.height);
            // Near to far, so the depth test rejects hidden fragments before they are shaded
            // (software rasterisers pay per shaded fragment).
            self.draw_order.clear();
            for (k, inst) in self.instances.iter().enumerate() {
                let mesh = &self.meshes[inst.mesh.0];
                if let Some(distance) = inst
                    .visible
                    .then(|| frustum.distance_if_visible(&inst.world_from_model, mesh.centre, mesh.radius))
                    .flatten()
                {
                    self.draw_order.push((distance, k));
                }
            }
            self.draw_order.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (_, instance_group) = self.instance_buffer.as_ref().expect("created by upload_instances");
            let mut bound_texture = usize::MAX;
            let mut bound_mesh = usize::MAX;
            let mut culling = None;
            let whole = spans == [(0, self.width)];
            for &(start, end) in &spans {
                // Each span draws what can reach it, in the whole frame's order, so every
                // pixel in it sees the same fragments as in the whole frame.
                let span_frustum = (!whole).then(|| Frustum::of_columns(camera, start, end, self.height));
                if !whole {
                    pass.set_scissor_rect(start, 0, end - start, self.height);
                }
                for &(_, k) in &self.draw_order {
                    let inst = &self.instances[k];
                    let mesh = &self.meshes[inst.mesh.0];
                    if let Some(f) = &span_frustum
                        && f.distance_if_visible(&inst.world_from_model, mesh.centre, mesh.radius).is_none()
                    {
                        continue;
                    }
                    // A mirroring transform turns the winding over: draw such instances whole.
                    let cull = mesh.cull_back_faces && determinant3(&inst.world_from_model) > 0.0;
                    if culling != Some(cull) {
                        pass.set_pipeline(if cull { &self.culling_pipeline } else { &self.pipeline });
                        culling = Some(cull);
                    }
                    pass.set_bind_group(1, instance_group, &[(k as u64 * self.instance_stride) as u32]);
                    if bound_texture != inst.texture.0 {
                        pass.set_bind_group(2, &self.textures[inst.texture.0], &[]);
                        bound_texture = inst.texture.0;
                    }
                    if bound_mesh != inst.mesh.0 {
                        pass.set_vertex_buffer(0, mesh.vertices.slice(..));
                        pass.set_index_buffer(mesh.indices.slice(..), wgpu::IndexFormat::Uint32);
                        bound_mesh = inst.mesh.0;
                    }
                    pass.draw_indexed(0..mesh.index_count, 0, 0..1);
                }
            }
        }
        // Only the rendered columns leave the GPU when they fit the buffer span by span.
        let layout = match (spans != [(0, self.width)]).then(|| self.span_planes(&spans)).flatten() {
            Some(per_span) => spans.iter().copied().zip(per_span).collect(),
            None => vec![((0, self.width), self.planes.clone())],
        };
        for ((start, end), planes) in &layout {
            for (target, plane) in self.targets.iter().zip(planes) {
                encoder.copy_texture_to_buffer(
                    wgpu::TexelCopyTextureInfo {
                        origin: wgpu::Origin3d { x: *start, y: 0, z: 0 },
                        ..target.as_image_copy()
                    },
                    wgpu::TexelCopyBufferInfo {
                        buffer: &self.readback,
                        layout: wgpu::TexelCopyBufferLayout {
                            offset: plane.offset,
                            bytes_per_row: Some(plane.bytes_per_row),
                            rows_per_image: Some(self.height),
                        },
                    },
                    wgpu::Extent3d { width: end - start, height: self.height, depth_or_array_layers: 1 },
                );
            }
        }
        self.queue.submit(Some(encoder.finish()));
        self.check_gpu_error()?;

        let slice = self.readback.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::Wait { submission_index: None, timeout: None })
            .map_err(|e| RenderError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| RenderError::Readback(e.to_string()))?
            .map_err(|e| RenderError::Readback(e.to_string()))?;
        let unpacked = match slice.get_mapped_range() {
            Ok(data) => {
                self.unpack(&data, &layout, frame, if columns.is_some() { Some(&spans) } else { None });
                Ok(())
            }
            Err(e) => Err(RenderError::Readback(e.to_string())),
        };
        // Unmapped even on error, so the next frame can map it again.
        self.readback.unmap();
        unpacked?;
        self.check_gpu_error()
    }

    /// Where each span's rows of each target go in the readback buffer: the spans one after
    /// another, rows padded as copies require; `None` when they would not fit.
    fn span_planes(&self, spans: &[(u32, u32)]) -> Option<Vec<Vec<Plane>>> {
        let mut offset = 0u64;
        let layout = spans
            .iter()
            .map(|&(start, end)| {
                self.planes
                    .iter()
                    .map(|p| {
                        let bytes_per_row =
                            (p.bytes_per_pixel * (end - start)).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
                        let plane = Plane { offset, bytes_per_row, bytes_per_pixel: p.bytes_per_pixel };
                        offset += bytes_per_row as u64 * self.height as u64;
                        plane
                    })
                    .collect()
            })
            .collect();
        (offset <= self.readback.size()).then_some(layout)
    }

    /// Copies the readback buffer, laid out as `layout` says (each copied span's column range
    /// and its targets' rows), into `frame`: all of it, or only the pixel columns `spans`,
    /// the rest zeroed.
    fn unpack(
        &self,
        data: &[u8],
        layout: &[((u32, u32), Vec<Plane>)],
        frame: &mut Frame,
        spans: Option<&[(u32, u32)]>,
    ) {
        let (w, h) = (self.width as usize, self.height as usize);
        self.size_frame(frame);
        let whole = [(0, self.width)];
        let copied = spans.unwrap_or(&whole);
        let empty = if spans.is_some() { gaps(copied, self.width) } else { Vec::new() };
        // Row `y` of columns `a..b` of a target, copied as `plane` from column `first` on.
        let row = |plane: &Plane, first: usize, y: usize, (a, b): (usize, usize)| {
            let start = plane.offset as usize + y * plane.bytes_per_row as usize;
            let bytes = plane.bytes_per_pixel as usize;
            &data[start + bytes * (a - first)..start + bytes * (b - first)]
        };
        for y in 0..h {
            blank_row(frame, y, &empty);
            for &(a, b) in copied {
                let ((first, _), planes) = layout
                    .iter()
                    .find(|((s, e), _)| *s <= a && b <= *e)
                    .expect("every span is copied, alone or in the whole frame");
                let (a, b, first) = (a as usize, b as usize, *first as usize);
                let (i0, i1) = (w * y + a, w * y + b);
                for (d, s) in
                    frame.rgb[3 * i0..3 * i1].chunks_exact_mut(3).zip(row(&planes[0], first, y, (a, b)).chunks_exact(4))
                {
                    d.copy_from_slice(&s[..3]);
                }
                let ids = row(&planes[1], first, y, (a, b)).chunks_exact(4);
                for ((instance, class), s) in frame.instance[i0..i1].iter_mut().zip(&mut frame.class[i0..i1]).zip(ids) {
                    let v = u32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                    *instance = (v >> 8) as u16;
                    *class = (v & 0xff) as u8;
                }
                let Some(depth) = planes.get(2) else { continue };
                for (d, s) in frame.depth_m[i0..i1].iter_mut().zip(row(depth, first, y, (a, b)).chunks_exact(4)) {
                    let z = f32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                    *d = if z > 0.0 { z } else { f32::INFINITY };
                }
            }
        }
        frame.columns = spans.map(<[_]>::to_vec);
    }

    /// Sizes `frame`'s images for this renderer (contents left as they were).
    fn size_frame(&self, frame: &mut Frame) {
        let n = self.width as usize * self.height as usize;
        frame.width = self.width;
        frame.height = self.height;
        frame.rgb.resize(3 * n, 0);
        frame.instance.resize(n, 0);
        frame.class.resize(n, 0);
        frame.depth_m.resize(if self.planes.len() > 2 { n } else { 0 }, 0.0);
    }

    /// `frame` with nothing rendered: every column empty.
    fn blank(&self, frame: &mut Frame) {
        self.size_frame(frame);
        let empty = [(0, self.width as usize)];
        for y in 0..self.height as usize {
            blank_row(frame, y, &empty);
        }
        frame.columns = Some(Vec::new());
    }

    fn check_gpu_error(&self) -> Result<(), RenderError> {
        match self.gpu_error.lock().map(|mut e| e.take()) {
            Ok(None) => Ok(()),
            Ok(Some(e)) => Err(RenderError::Gpu(e)),
            Err(_) => Err(RenderError::Gpu("error slot poisoned".into())),
        }
    }
}

/// The camera's view volume as planes through the optical centre (and near/far), in the
/// camera frame, to skip instances that cannot be seen (software rasterisers pay for them).
struct Frustum {
    camera_from_world: [[f32; 4]; 4],
    /// Unit inward normals of the four side planes, which pass through the origin.
    sides: [[f32; 3]; 4],
    near_m: f32,
    far_m: f32,
}

impl Frustum {
    fn new(c: &Camera, width: u32, height: u32) -> Self {
        Frustum::of_columns(c, 0, width, height)
    }

    /// The view through pixel columns `start..end` only.
    fn of_columns(c: &Camera, start: u32, end: u32, height: u32) -> Self {
        let (u0, u1, h) = (start as f32, end as f32, height as f32);
        // u >= u0: fx X + (cx - u0) Z >= 0; u <= u1: -fx X + (u1 - cx) Z >= 0; likewise for v.
        let sides = [[c.fx, 0.0, c.cx - u0], [-c.fx, 0.0, u1 - c.cx], [0.0, c.fy, c.cy], [0.0, -c.fy, h - c.cy]]
            .map(|n| normalised(n).unwrap_or([0.0, 0.0, 1.0]));
        Frustum { camera_from_world: rigid_inverse(&c.world_from_camera), sides, near_m: c.near_m, far_m: c.far_m }
    }

    /// `None` if the bounding sphere is surely outside the view, else a near-to-far sort
    /// key: the z-distance of its nearest point, or `f32::MAX` for objects around the
    /// camera (ground, walls), which are large and best drawn last, behind the rest.
    fn distance_if_visible(&self, world_from_model: &[[f32; 4]; 4], centre: [f32; 3], radius: f32) -> Option<f32> {
        let scale = (0..3).map(|c| dot3(&world_from_model[c], &world_from_model[c]).sqrt()).fold(0.0f32, f32::max);
        let r = radius * scale;
        let p = transform_point(&self.camera_from_world, transform_point(world_from_model, centre));
        if !(r.is_finite() && p.iter().all(|v| v.is_finite())) {
            return Some(f32::MAX); // let the GPU decide; draw last
        }
        let visible = p[2] > self.near_m - r && p[2] < self.far_m + r && self.sides.iter().all(|n| dot(*n, p) > -r);
        let nearest = p[2] - r;
        visible.then_some(if nearest < self.near_m { f32::MAX } else { nearest })
    }
}

/// The pixel columns of `0..width` outside the sorted disjoint `spans`.
fn gaps(spans: &[(u32, u32)], width: u32) -> Vec<(usize, usize)> {
    let mut out = Vec::with_capacity(spans.len() + 1);
    let mut from = 0;
    for &(a, b) in spans {
        if a > from {
            out.push((from as usize, a as usize));
        }
        from = b;
    }
    if from < width {
        out.push((from as usize, width as usize));
    }
    out
}

/// Zeroes row `y` of `frame` in the pixel columns `empty` (depth: infinity).
fn blank_row(frame: &mut Frame, y: usize, empty: &[(usize, usize)]) {
    let w = frame.width as usize;
    for &(a, b) in empty {
        let (i0, i1) = (w * y + a, w * y + b);
        frame.rgb[3 * i0..3 * i1].fill(0);
        frame.instance[i0..i1].fill(0);
        frame.class[i0..i1].fill(0);
        if !frame.depth_m.is_empty() {
            frame.depth_m[i0..i1].fill(f32::INFINITY);
        }
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn dot3(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn normalised(a: [f32; 3]) -> Option<[f32; 3]> {
    let n = dot(a, a).sqrt();
    (n > 1e-9 && n.is_finite()).then(|| a.map(|v| v / n))
}

/// `m * [p, 1]` for a column-major affine `m`.
fn transform_point(m: &[[f32; 4]; 4], p: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|r| m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r])
}

/// Inverse of a rigid column-major transform: [R^T, -R^T t].
pub fn rigid_inverse(m: &[[f32; 4]; 4]) -> [[f32; 4]; 4] {
    let mut out = IDENTITY;
    for c in 0..3 {
        for r in 0..3 {
            out[c][r] = m[r][c];
        }
        out[3][c] = -dot3(&m[c], &m[3]);
    }
    out
}

/// Determinant of the upper-left 3x3 of a column-major 4x4 matrix.
fn determinant3(m: &[[f32; 4]; 4]) -> f32 {
    dot3(&m[0], &{
        let c = cross([m[1][0], m[1][1], m[1][2]], [m[2][0], m[2][1], m[2][2]]);
        [c[0], c[1], c[2], 0.0]
    })
}

fn mat_mul(a: &[[f32; 4]; 4], b: &[[f32; 4]; 4]) -> [[f32; 4]; 4] {
    std::array::from_fn(|c| std::array::from_fn(|r| (0..4).map(|k| a[k][r] * b[c][k]).sum()))
}

/// Columns of the inverse transpose of `m`'s upper 3x3 (the cofactor matrix, scaled; the
/// shader normalises), padded for std140.
fn normal_matrix(m: &[[f32; 4]; 4]) -> [[f32; 4]; 3] {
    let col = |c: usize| [m[c][0], m[c][1], m[c][2]];
    let (a, b, c) = (col(0), col(1), col(2));
    // For M = [a b c], inverse transpose = [b x c, c x a, a x b] / det.
    let det = dot(a, cross(b, c));
    let s = if det.abs() > 1e-20 { 1.0 / det } else { 1.0 };
    [cross(b, c), cross(c, a), cross(a, b)].map(|v| [v[0] * s, v[1] * s, v[2] * s, 0.0])
}

/// A sphere around all points (centre of the bounding box, max distance).
fn bounding_sphere(points: &[[f32; 3]]) -> ([f32; 3], f32) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let centre = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let radius = points.iter().map(|p| dot(sub(*p, centre), sub(*p, centre))).fold(0.0f32, f32::max).sqrt();
    (centre, radius)
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.0031308 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

/// All mip levels of `t`, level 0 first, each a 2x2 box filter of the previous one in
/// linear light (alpha linearly). Returns the bytes and the level count.
fn mip_chain(t: &TextureData) -> (Vec<u8>, u32) {
    let lut: Vec<f32> = (0..256).map(|i| srgb_to_linear(i as f32 / 255.0)).collect();
    let mut data = t.rgba.clone();
    let (mut w, mut h) = (t.width as usize, t.height as usize);
    let mut level_start = 0;
    let mut levels = 1;
    while w > 1 || h > 1 {
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let mut next = Vec::with_capacity(nw * nh * 4);
        for y in 0..nh {
            for x in 0..nw {
                // Odd sides: the last row/column folds into the last output texel's pair.
                let xs = [(2 * x).min(w - 1), (2 * x + 1).min(w - 1)];
                let ys = [(2 * y).min(h - 1), (2 * y + 1).min(h - 1)];
                let mut sum = [0.0f32; 4];
                for &sy in &ys {
                    for &sx in &xs {
                        let p = &data[level_start + 4 * (sy * w + sx)..][..4];
                        for k in 0..3 {
                            sum[k] += lut[p[k] as usize];
                        }
                        sum[3] += p[3] as f32 / 255.0;
                    }
                }
                for linear in &sum[..3] {
                    next.push((linear_to_srgb(linear / 4.0) * 255.0).round().clamp(0.0, 255.0) as u8);
                }
                next.push((sum[3] / 4.0 * 255.0).round().clamp(0.0, 255.0) as u8);
            }
        }
        level_start = data.len();
        data.extend_from_slice(&next);
        (w, h) = (nw, nh);
        levels += 1;
    }
    (data, levels)
}

/// The per-frame uniform. The projection maps the optical frame to wgpu clip space
/// (x right, y up, depth 0..1; wgpu flips for GL) so that framebuffer pixel coordinates
/// equal the pinhole (u, v):
/// x_ndc = 2u/W - 1, y_ndc = 1 - 2v/H, depth = f (Z - n) / ((f - n) Z).
fn frame_uniform(c: &Camera, l: &Lighting, width: u32, height: u32) -> FrameUniform {
    let (w, h) = (width as f32, height as f32);
    let (n, f) = (c.near_m, c.far_m);
    let clip_from_camera = [
        [2.0 * c.fx / w, 0.0, 0.0, 0.0],
        [0.0, -2.0 * c.fy / h, 0.0, 0.0],
        [2.0 * c.cx / w - 1.0, 1.0 - 2.0 * c.cy / h, f / (f - n), 1.0],
        [0.0, 0.0, -f * n / (f - n), 0.0],
    ];
    let camera_from_world = rigid_inverse(&c.world_from_camera);
    let sun = normalised(l.sun_direction).unwrap_or([0.0, 0.0, -1.0]);
    FrameUniform {
        clip_from_world: mat_mul(&clip_from_camera, &camera_from_world),
        camera_from_world,
        sun_direction: [sun[0], sun[1], sun[2], 0.0],
        sun_colour: [l.sun_colour[0], l.sun_colour[1], l.sun_colour[2], 0.0],
        ambient: [l.ambient[0], l.ambient[1], l.ambient[2], 0.0],
        params: [l.exposure, 0.0, 0.0, 0.0],
        eye: [c.world_from_camera[3][0], c.world_from_camera[3][1], c.world_from_camera[3][2], 1.0],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(yaw: f32, t: [f32; 3]) -> [[f32; 4]; 4] {
        let (s, c) = yaw.sin_cos();
        [[c, s, 0.0, 0.0], [-s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [t[0], t[1], t[2], 1.0]]
    }

    #[test]
    fn renderer_can_move_to_a_simulation_thread() {
        fn send<T: Send>() {}
        send::<Renderer>();
        send::<Frame>();
    }

    #[test]
    fn rigid_inverse_undoes_the_transform() {
        let m = pose(0.7, [1.0, -2.0, 3.0]);
        let p = [0.3, 0.4, -0.5];
        let q = transform_point(&rigid_inverse(&m), transform_point(&m, p));
        assert!((0..3).all(|k| (p[k] - q[k]).abs() < 1e-5), "{q:?}");
        let i = mat_mul(&m, &rigid_inverse(&m));
        assert!((0..4).all(|c| (0..4).all(|r| (i[c][r] - IDENTITY[c][r]).abs() < 1e-6)));
    }

    #[test]
    fn projection_matrix_gives_pinhole_pixels_and_unit_depth_range() {
        let cam = Camera {
            fx: 300.0,
            fy: 310.0,
            cx: 150.0,
            cy: 110.0,
            near_m: 0.1,
            far_m: 100.0,
            ..Camera::look_at(1.0, 1.0, 0.0, 0.0, [1.0, 2.0, 1.5], [6.0, 3.0, 1.0])
        };
        let u = frame_uniform(&cam, &Lighting::default(), 320, 240);
        for p in [[5.0, 3.0, 1.0], [4.0, 2.5, 2.0], [1.2, 9.0, 0.5]] {
            let c = u.clip_from_world;
            let clip: [f32; 4] = std::array::from_fn(|r| c[0][r] * p[0] + c[1][r] * p[1] + c[2][r] * p[2] + c[3][r]);
            let [pu, pv, z] = cam.project(p).unwrap();
            let (x, y) = ((clip[0] / clip[3] + 1.0) * 160.0, (1.0 - clip[1] / clip[3]) * 120.0);
            assert!((x - pu).abs() < 1e-3 && (y - pv).abs() < 1e-3, "({x}, {y}) vs ({pu}, {pv})");
            assert!((clip[3] - z).abs() < 1e-4);
        }
        // Points on the optical axis at near and far map to depth 0 and 1.
        let m = cam.world_from_camera;
        let depth = |d: f32| {
            let p: [f32; 3] = std::array::from_fn(|r| m[3][r] + d * m[2][r]);
            let c = u.clip_from_world;
            let clip: [f32; 4] = std::array::from_fn(|r| c[0][r] * p[0] + c[1][r] * p[1] + c[2][r] * p[2] + c[3][r]);
            clip[2] / clip[3]
        };
        assert!(depth(0.1).abs() < 1e-4 && (depth(100.0) - 1.0).abs() < 1e-4, "{} {}", depth(0.1), depth(100.0));
    }

    #[test]
    fn normal_matrix_keeps_normals_perpendicular_under_scaling() {
        let mut m = IDENTITY;
        m[0][0] = 3.0; // stretch x
        let n = normal_matrix(&m);
        // A surface along x with normal (1, 1, 0)/sqrt2 becomes flatter: normal leans to y.
        let v = [1.0, 1.0, 0.0];
        let out: [f32; 3] = std::array::from_fn(|r| n[0][r] * v[0] + n[1][r] * v[1] + n[2][r] * v[2]);
        // Tangent (1, -1, 0) maps to (3, -1, 0); the normal must stay perpendicular to it.
        assert!((out[0] * 3.0 - out[1]).abs() < 1e-6, "{out:?}");
    }

    #[test]
    fn mip_chain_averages_in_linear_light_down_to_one_texel() {
        let t = TextureData { width: 4, height: 2, rgba: [[0u8, 0, 0, 255], [255, 255, 255, 255]].repeat(4).concat() };
        let (data, levels) = mip_chain(&t);
        assert_eq!(levels, 3); // 4x2, 2x1, 1x1
        assert_eq!(data.len(), 4 * (8 + 2 + 1));
        // Half black, half white in linear light is sRGB 188, not 128.
        let last = &data[data.len() - 4..];
        assert!((last[0] as i32 - 188).abs() <= 1, "{last:?}");
        assert_eq!(last[3], 255);
    }

    #[test]
    fn frustum_rejects_what_is_behind_or_beside_the_camera() {
        let cam = Camera::look_at(50.0, 50.0, 50.0, 50.0, [0.0, 0.0, 1.0], [1.0, 0.0, 1.0]);
        let f = Frustum::new(&cam, 100, 100);
        let at = |x, y| pose(0.0, [x, y, 1.0]);
        let seen = |x, y| f.distance_if_visible(&at(x, y), [0.0; 3], 0.5);
        assert!((seen(5.0, 0.0).unwrap() - 4.5).abs() < 1e-5);
        assert_eq!(seen(-5.0, 0.0), None);
        // 45 degrees half field of view: y = 5 at x = 5 is at the edge; 8 is well outside.
        assert!(seen(5.0, 5.2).is_some());
        assert_eq!(seen(5.0, 8.0), None);
    }
}
