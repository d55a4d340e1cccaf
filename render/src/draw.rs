//! Drawing a frame: checking the inputs, the per-frame uniform, and the render pass
//! (instances frustum-culled and drawn near to far, scissored to the requested regions).

use crate::cull::Frustum;
use crate::device::FrameUniform;
use crate::math::{determinant3, mat_mul, normalised, rigid_inverse};
use crate::texture::srgb_to_linear;
use crate::{Camera, Frame, Lighting, Region, RenderError, Renderer};

impl Renderer {
    /// Renders one frame and reads back all images.
    pub fn render(&mut self, camera: &Camera, lighting: &Lighting) -> Result<Frame, RenderError> {
        let mut frame = Frame::default();
        self.render_into(camera, lighting, &mut frame)?;
        Ok(frame)
    }

    /// Like [`Renderer::render`], but reuses `frame`'s allocations (for long runs).
    pub fn render_into(&mut self, camera: &Camera, lighting: &Lighting, frame: &mut Frame) -> Result<(), RenderError> {
        self.render_regions_into(camera, lighting, None, frame)
    }

    /// Renders only the pixel `regions` (sorted by column and column-disjoint; `None`: the
    /// whole image), for consumers that read only part of each frame. The pixels inside
    /// are those of the whole frame (the same draws in the same order, scissored); outside
    /// them the frame is zero. With no regions nothing is drawn at all.
    pub fn render_regions_into(
        &mut self,
        camera: &Camera,
        lighting: &Lighting,
        regions: Option<&[Region]>,
        frame: &mut Frame,
    ) -> Result<(), RenderError> {
        camera.validate()?;
        let spans = match regions {
            None => vec![Region::whole(self.width, self.height)],
            Some(regions) => {
                let mut previous_end = 0;
                for (i, r) in regions.iter().enumerate() {
                    let (start, end) = r.columns;
                    if start >= end
                        || end > self.width
                        || (i > 0 && start < previous_end)
                        || r.rows.0 >= r.rows.1
                        || r.rows.1 > self.height
                    {
                        return Err(RenderError::Region { region: *r, width: self.width, height: self.height });
                    }
                    previous_end = end;
                }
                regions.to_vec()
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
            let whole = spans == [Region::whole(self.width, self.height)];
            for span in &spans {
                // Each region draws what can reach it, in the whole frame's order, so every
                // pixel in it sees the same fragments as in the whole frame.
                let span_frustum = (!whole).then(|| Frustum::of_region(camera, span));
                if !whole {
                    let (x, y) = (span.columns.0, span.rows.0);
                    pass.set_scissor_rect(x, y, span.columns.1 - x, span.rows.1 - y);
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
        self.read_back(encoder, &spans, regions.is_some(), frame)
    }
}

/// The per-frame uniform. The projection maps the optical frame to wgpu clip space
/// (x right, y up, depth 0..1; wgpu flips for GL) so that framebuffer pixel coordinates
/// equal the pinhole (u, v):
/// x_ndc = 2u/W - 1, y_ndc = 1 - 2v/H, depth = f (Z - n) / ((f - n) Z).
pub(crate) fn frame_uniform(c: &Camera, l: &Lighting, width: u32, height: u32) -> FrameUniform {
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
}
