//! The camera sensor: renders the world from the robot's camera with the `render` crate,
//! people posed at the frame's instant, with exact instance, class and depth images.

use std::sync::{Arc, Mutex};

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, StandardNormal};
use rayon::prelude::*;
use render::{InstanceHandle, Lighting, MeshData, Renderer, RendererConfig, TextureData};
use worlds::World;
use worlds::mesh::{MeshPart, PersonParts, TriMesh, person_parts, static_world_parts};

pub use crate::camera_model::{CameraConfig, Intrinsics, Rigid};
use crate::messages::{PersonState, Pose2D};
use crate::people::leg_pose;

/// Errors of the camera.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("camera settings: {0}")]
    Config(String),
    #[error("renderer: {0}")]
    Render(#[from] render::RenderError),
    #[error("the camera's rendering thread ended unexpectedly")]
    Thread,
}

/// One camera frame: the image and its exactly aligned ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFrame {
    pub t: f64,
    pub intrinsics: Intrinsics,
    /// World <- camera optical frame (ground truth).
    pub world_from_camera: Rigid,
    /// Colour, instance, class and depth images (see `render::Frame`).
    pub image: render::Frame,
}

/// Spent frames handed back for the camera to render into again: a frame is about 1.8 MB,
/// and a reused one needs blanking only where it was last rendered (see
/// `render::Renderer::render_regions_into`), where a new one is filled whole. A consumer
/// that is done with a frame's images gives them here; reuse changes no pixel.
#[derive(Debug, Clone, Default)]
pub struct FramePool(Arc<Mutex<Vec<render::Frame>>>);

impl FramePool {
    /// Frames kept at most: a consumer holds one or two, and frames in flight between the
    /// camera and it are at most a second of them ahead.
    pub const CAPACITY: usize = 4;

    /// Keeps `frame` for a later render (dropped when the pool is full).
    pub fn give(&self, frame: render::Frame) {
        let mut spares = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if spares.len() < Self::CAPACITY {
            spares.push(frame);
        }
    }

    /// A spare frame, or a new (empty) one.
    fn take(&self) -> render::Frame {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).pop().unwrap_or_default()
    }

    /// Whether no frame waits for reuse.
    pub fn is_empty(&self) -> bool {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).is_empty()
    }
}

struct PersonInstances {
    id: u16,
    left: InstanceHandle,
    right: InstanceHandle,
    body: InstanceHandle,
    head: InstanceHandle,
}

/// A camera rendering one world.
pub struct CameraSensor {
    pub config: CameraConfig,
    renderer: Renderer,
    world: World,
    people: Vec<PersonInstances>,
    rng: ChaCha8Rng,
    pub lighting: Lighting,
    frames: FramePool,
}

/// The worlds crate's procedural meshes are closed wherever they can be seen and wound
/// counter-clockwise from outside (two-sided parts carry both windings; its tests check
/// this), so the renderer may skip their back faces.
fn mesh_data(m: &TriMesh) -> MeshData {
    MeshData {
        positions: m.positions.clone(),
        normals: m.normals.clone(),
        uvs: m.uvs.clone(),
        indices: m.indices.clone(),
        cull_back_faces: true,
    }
}

/// A person's parts in the order [`PersonInstances`] names them.
fn person_limbs(p: &PersonParts) -> [&MeshPart; 4] {
    [&p.left_leg, &p.right_leg, &p.body, &p.head]
}

/// Pixels in a run of the noise's own stream (see [`add_pixel_noise`]).
const NOISE_RUN_PIXELS: usize = 32;

/// Adds `normal` noise to every rendered value of `image`: to its regions, or all of it.
/// Each run of [`NOISE_RUN_PIXELS`] pixels of a row draws from a stream of its own of
/// `frame_noise`, whole, so a pixel's noise does not depend on which regions were rendered
/// while the runs no region reaches cost nothing.
fn add_pixel_noise(image: &mut render::Frame, normal: &Normal<f64>, frame_noise: ChaCha8Rng) {
    let render::Frame { width, height, rgb, regions, .. } = image;
    let whole = [render::Region::whole(*width, *height)];
    let regions = regions.as_deref().unwrap_or(&whole);
    let width = *width as usize;
    let runs_per_row = width.div_ceil(NOISE_RUN_PIXELS);
    let mut values = [0.0; 3 * NOISE_RUN_PIXELS];
    for row in 0..*height {
        for run in 0..runs_per_row {
            let (u0, u1) = (run * NOISE_RUN_PIXELS, ((run + 1) * NOISE_RUN_PIXELS).min(width));
            let reached = regions.iter().any(|r| {
                (r.rows.0..r.rows.1).contains(&row) && (r.columns.0 as usize) < u1 && u0 < r.columns.1 as usize
            });
            if !reached {
                continue;
            }
            let mut stream = frame_noise.clone();
            stream.set_stream((row as usize * runs_per_row + run) as u64);
            stream.set_word_pos(0);
            values.iter_mut().for_each(|e| *e = normal.sample(&mut stream));
            for u in u0..u1 {
                if !regions.iter().any(|r| r.contains(u as u32, row)) {
                    continue;
                }
                let i = 3 * (row as usize * width + u);
                for (v, e) in rgb[i..i + 3].iter_mut().zip(&values[3 * (u - u0)..]) {
                    *v = (*v as f64 + e).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
    }
}

fn texture_data(part: &MeshPart) -> TextureData {
    let t = worlds::texture::generate(&part.appearance);
    TextureData { width: t.width, height: t.height, rgba: t.rgba }
}

/// Column-major transform: rotation about z by `yaw`, then about the (rotated) y axis by
/// `pitch`, then translation.
fn transform(t: [f64; 3], yaw: f64, pitch: f64) -> [[f32; 4]; 4] {
    let (sy, cy) = yaw.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    // R = Rz(yaw) * Ry(pitch)
    let r = [[cy * cp, -sy, cy * sp], [sy * cp, cy, sy * sp], [-sp, 0.0, cp]];
    let mut m = [[0.0f32; 4]; 4];
    for c in 0..3 {
        for row in 0..3 {
            m[c][row] = r[row][c] as f32;
        }
    }
    m[3] = [t[0] as f32, t[1] as f32, t[2] as f32, 1.0];
    m
}

impl CameraSensor {
    /// Uploads the world's meshes and textures. `seed` drives image noise and exposure.
    pub fn new(world: &World, config: &CameraConfig, seed: u64) -> Result<Self, CameraError> {
        config.check().map_err(|(field, message)| CameraError::Config(format!("camera.{field}: {message}")))?;
        let parts = static_world_parts(world);
        let people_parts: Vec<_> = world.people.iter().map(person_parts).collect();
        // Starting the graphics device and generating the textures are independent and
        // each takes a noticeable part of a short run's start: do them at once, the
        // textures spread over the pool. Each texture is a pure function of its part.
        let (renderer, (textures, people_textures)) = rayon::join(
            || Renderer::new(&RendererConfig { width: config.width, height: config.height, depth: config.depth_image }),
            || {
                rayon::join(
                    || parts.par_iter().map(texture_data).collect::<Vec<_>>(),
                    || people_parts.par_iter().map(|p| person_limbs(p).map(texture_data)).collect::<Vec<_>>(),
                )
            },
        );
        let mut renderer = renderer?;
        let mut add = |part: &MeshPart, texture: &TextureData| -> Result<InstanceHandle, CameraError> {
            let mesh = renderer.add_mesh(&mesh_data(&part.mesh))?;
            let tex = renderer.add_texture(texture)?;
            Ok(renderer.add_instance(mesh, tex, render::IDENTITY, part.instance_id, part.class.id()))
        };
        for (part, texture) in parts.iter().zip(&textures) {
            add(part, texture)?;
        }
        let mut people = Vec::new();
        for ((p, parts), [tl, tr, tb, th]) in world.people.iter().zip(&people_parts).zip(&people_textures) {
            let [left, right, body, head] = person_limbs(parts);
            people.push(PersonInstances {
                id: p.id,
                left: add(left, tl)?,
                right: add(right, tr)?,
                body: add(body, tb)?,
                head: add(head, th)?,
            });
        }
        Ok(CameraSensor {
            config: config.clone(),
            renderer,
            world: world.clone(),
            people,
            rng: ChaCha8Rng::seed_from_u64(seed),
            lighting: Lighting::default(),
            frames: FramePool::default(),
        })
    }

    /// Where consumers give back frames they are done with (shared: a clone gives to the
    /// same camera).
    pub fn frame_pool(&self) -> FramePool {
        self.frames.clone()
    }

    /// The adapter rendering the images.
    pub fn adapter(&self) -> render::AdapterSummary {
        self.renderer.adapter_info().clone()
    }

    /// Poses the people as in `people` (states from the simulator).
    pub fn pose_people(&mut self, people: &[PersonState]) {
        for s in people {
            let Some(inst) = self.people.iter().find(|p| p.id == s.id) else { continue };
            let Some(p) = self.world.people.iter().find(|p| p.id == s.id) else { continue };
            for (handle, side) in [(inst.left, 1.0), (inst.right, -1.0)] {
                let (hip, swing) = leg_pose(p, s, side);
                // Positive swing moves the foot forward: a rotation of -swing about y.
                self.renderer.set_transform(handle, transform(hip, s.heading, -swing));
            }
            let body = transform([s.x, s.y, 0.0], s.heading, 0.0);
            self.renderer.set_transform(inst.body, body);
            self.renderer.set_transform(inst.head, body);
        }
    }

    /// Renders from an arbitrary camera pose (datasets, calibration).
    pub fn render_from(&mut self, t: f64, world_from_camera: Rigid) -> Result<CameraFrame, CameraError> {
        self.render_regions_from(t, world_from_camera, None)
    }

    /// [`CameraSensor::render_from`] rendering only the pixel `regions` (see
    /// `render::Renderer::render_regions_into`); noise and exposure draw the same random
    /// numbers either way, so the pixels rendered are those of the whole frame.
    pub fn render_regions_from(
        &mut self,
        t: f64,
        world_from_camera: Rigid,
        regions: Option<&[render::Region]>,
    ) -> Result<CameraFrame, CameraError> {
        let k = self.config.intrinsics();
        let camera = render::Camera {
            fx: k.fx as f32,
            fy: k.fy as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            world_from_camera: world_from_camera.to_mat4(),
            near_m: 0.05,
            far_m: 500.0,
        };
        let mut lighting = self.lighting;
        // Both draws are taken whatever the spreads, so that the frames after this one get
        // the same streams when a study varies either spread down to 0 (common random
        // numbers).
        let z: f64 = self.rng.sample(StandardNormal);
        let noise_seed: [u8; 32] = self.rng.random();
        if self.config.exposure_sigma > 0.0 {
            lighting.exposure *= ((1.0 + self.config.exposure_sigma * z) as f32).max(0.1);
        }
        let mut image = self.frames.take();
        self.renderer.render_regions_into(&camera, &lighting, regions, &mut image)?;
        if self.config.noise_sigma > 0.0 {
            let n = Normal::new(0.0, self.config.noise_sigma).expect("finite sigma");
            add_pixel_noise(&mut image, &n, ChaCha8Rng::from_seed(noise_seed));
        }
        Ok(CameraFrame { t, intrinsics: k, world_from_camera, image })
    }

    /// Renders the robot's view at `robot` with `people` posed.
    pub fn capture(&mut self, t: f64, robot: &Pose2D, people: &[PersonState]) -> Result<CameraFrame, CameraError> {
        self.capture_regions(t, robot, people, None)
    }

    /// [`CameraSensor::capture`] rendering only the pixel `regions`.
    pub fn capture_regions(
        &mut self,
        t: f64,
        robot: &Pose2D,
        people: &[PersonState],
        regions: Option<&[render::Region]>,
    ) -> Result<CameraFrame, CameraError> {
        self.pose_people(people);
        let pose = self.config.world_from_camera(robot);
        self.render_regions_from(t, pose, regions)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use render::{Frame, Region};

    /// A grey frame of `width` x `height`, rendered in `regions` (`None`: whole).
    fn grey(width: u32, height: u32, regions: Option<Vec<Region>>) -> Frame {
        let n = (width * height) as usize;
        Frame {
            width,
            height,
            rgb: vec![128; 3 * n],
            instance: vec![0; n],
            class: vec![0; n],
            depth_m: vec![],
            regions,
        }
    }

    #[test]
    fn pixel_noise_is_the_same_wherever_regions_are_rendered_and_only_there() {
        let normal = Normal::new(0.0, 3.0).unwrap();
        let key = ChaCha8Rng::seed_from_u64(7);
        let mut whole = grey(100, 20, None);
        add_pixel_noise(&mut whole, &normal, key.clone());
        // Regions that start and end inside runs of the noise's streams.
        let regions = vec![Region { columns: (5, 40), rows: (3, 9) }, Region { columns: (70, 100), rows: (0, 20) }];
        let mut part = grey(100, 20, Some(regions.clone()));
        add_pixel_noise(&mut part, &normal, key);
        for v in 0..20 {
            for u in 0..100 {
                let i = 3 * (v * 100 + u) as usize;
                let inside = regions.iter().any(|r| r.contains(u, v));
                let want: &[u8] = if inside { &whole.rgb[i..i + 3] } else { &[128; 3] };
                assert_eq!(&part.rgb[i..i + 3], want, "pixel ({u}, {v}), inside a region: {inside}");
            }
        }
    }

    #[test]
    fn pixel_noise_has_its_spread_and_each_run_of_pixels_its_own_numbers() {
        let sigma = 3.0;
        let mut frame = grey(640, 48, None);
        add_pixel_noise(&mut frame, &Normal::new(0.0, sigma).unwrap(), ChaCha8Rng::seed_from_u64(1));
        let e: Vec<f64> = frame.rgb.iter().map(|&v| v as f64 - 128.0).collect();
        let mean = e.iter().sum::<f64>() / e.len() as f64;
        let sd = (e.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / e.len() as f64).sqrt();
        // 92,160 values, rounded to integers (which adds a variance of 1/12).
        let want = (sigma * sigma + 1.0 / 12.0f64).sqrt();
        assert!(mean.abs() < 0.05 && (sd - want).abs() < 0.05, "mean {mean}, sd {sd}, want {want}");
        // No two runs of the streams repeat each other's values.
        let runs: Vec<&[f64]> = e.chunks(3 * NOISE_RUN_PIXELS).collect();
        for (a, ra) in runs.iter().enumerate() {
            for rb in &runs[a + 1..] {
                assert_ne!(ra, rb, "two runs of pixels drew the same noise");
            }
        }
    }
}
