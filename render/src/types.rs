//! The public data types: what callers hand the renderer (meshes, textures, configuration,
//! camera, lighting) and what it hands back (handles, frames, adapter summaries, errors).

use crate::math::{cross, normalised, rigid_inverse, sub, transform_point};

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
        "invalid pixel region: columns {}..{}, rows {}..{}: regions must be non-empty, sorted by column, column-disjoint and within the {width} x {height} image",
        region.columns.0, region.columns.1, region.rows.0, region.rows.1
    )]
    Region { region: Region, width: u32, height: u32 },
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

/// A mesh uploaded with [`Renderer::add_mesh`](crate::Renderer::add_mesh).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MeshId(pub(crate) usize);
/// A texture uploaded with [`Renderer::add_texture`](crate::Renderer::add_texture).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TextureId(pub(crate) usize);
/// An instance placed with [`Renderer::add_instance`](crate::Renderer::add_instance).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct InstanceHandle(pub(crate) usize);

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

    pub(crate) fn validate(&self) -> Result<(), RenderError> {
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
    /// The pixel regions rendered (sorted by column, column-disjoint); `None`: the whole
    /// frame. Outside them the images are zero (black, no instance, no class) and the
    /// depth infinite (see [`Renderer::render_regions_into`](crate::Renderer::render_regions_into)).
    pub regions: Option<Vec<Region>>,
}

/// A rectangle of pixels: columns `columns.0..columns.1`, rows `rows.0..rows.1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Region {
    pub columns: (u32, u32),
    pub rows: (u32, u32),
}

impl Region {
    /// The whole of a `width` x `height` image.
    pub fn whole(width: u32, height: u32) -> Region {
        Region { columns: (0, width), rows: (0, height) }
    }

    /// Whether pixel (u, v) lies in it.
    pub fn contains(&self, u: u32, v: u32) -> bool {
        (self.columns.0..self.columns.1).contains(&u) && (self.rows.0..self.rows.1).contains(&v)
    }

    /// Whether it lies within a `width` x `height` image (an empty one may).
    pub fn fits(&self, width: u32, height: u32) -> bool {
        self.columns.0 <= self.columns.1
            && self.columns.1 <= width
            && self.rows.0 <= self.rows.1
            && self.rows.1 <= height
    }

    /// Its number of pixels.
    pub fn area(&self) -> u64 {
        self.columns.1.saturating_sub(self.columns.0) as u64 * self.rows.1.saturating_sub(self.rows.0) as u64
    }
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
