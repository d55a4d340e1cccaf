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

mod cull;
mod device;
mod draw;
mod math;
mod readback;
mod scene;
mod texture;
mod types;

use std::sync::{Arc, Mutex};

pub use math::{IDENTITY, rigid_inverse};
pub use types::{
    AdapterSummary, Camera, Frame, InstanceHandle, Lighting, MeshData, MeshId, Region, RenderError, RendererConfig,
    TextureData, TextureId,
};

use readback::Plane;
use scene::{Instance, Mesh};

// The methods of `Renderer` are split by topic: creation in `device`, meshes, textures and
// instances in `scene`, drawing in `draw`, getting the images back in `readback`.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renderer_can_move_to_a_simulation_thread() {
        fn send<T: Send>() {}
        send::<Renderer>();
        send::<Frame>();
    }
}
