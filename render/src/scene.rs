//! What is drawn: uploading meshes and textures, and placing, moving and hiding their
//! instances, whose uniforms are kept on the CPU and uploaded when they change.

use std::num::NonZeroU64;

use wgpu::util::DeviceExt;

use crate::cull::bounding_sphere;
use crate::device::{InstanceUniform, Vertex};
use crate::math::normal_matrix;
use crate::texture::mip_chain;
use crate::{InstanceHandle, MeshData, MeshId, RenderError, Renderer, TextureData, TextureId};

/// A mesh uploaded with [`Renderer::add_mesh`]: its GPU buffers and what culling needs.
pub(crate) struct Mesh {
    pub(crate) vertices: wgpu::Buffer,
    pub(crate) indices: wgpu::Buffer,
    pub(crate) index_count: u32,
    /// Bounding sphere in the model frame, for frustum culling.
    pub(crate) centre: [f32; 3],
    pub(crate) radius: f32,
    pub(crate) cull_back_faces: bool,
}

/// An instance placed with [`Renderer::add_instance`].
pub(crate) struct Instance {
    pub(crate) mesh: MeshId,
    pub(crate) texture: TextureId,
    pub(crate) visible: bool,
    pub(crate) world_from_model: [[f32; 4]; 4],
}

impl Renderer {
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
    pub(crate) fn upload_instances(&mut self) {
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
}
