//! Frame rate of a park-like scene at 640x480: ~60 textured 64-segment trunks, ground and a
//! few boxes, including colour, instance and class masks, depth and readback.
//!
//! `cargo bench -p render`; frames per second = 1 / the reported time.

use render::*;

fn main() {
    match Renderer::new(&RendererConfig::new(8, 8)) {
        Ok(r) => eprintln!("adapter: {}", r.adapter_info()),
        Err(e) => panic!("no adapter for the benchmark: {e}"),
    }
    divan::main();
}

fn trunk(radius: f32, height: f32, segments: u32) -> MeshData {
    // Closed where the camera (below the tops) sees it, as the simulator's meshes are.
    let mut m = MeshData { cull_back_faces: true, ..Default::default() };
    for i in 0..=segments {
        let (s, c) = (std::f32::consts::TAU * i as f32 / segments as f32).sin_cos();
        for z in [0.0, height] {
            m.positions.push([radius * c, radius * s, z]);
            m.normals.push([c, s, 0.0]);
            m.uvs.push([4.0 * i as f32 / segments as f32, -z]);
        }
        if i < segments {
            let b = 2 * i;
            m.indices.extend_from_slice(&[b, b + 2, b + 3, b, b + 3, b + 1]);
        }
    }
    m
}

fn cuboid(h: f32) -> MeshData {
    let mut m = MeshData { cull_back_faces: true, ..Default::default() };
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = m.positions.len() as u32;
            for (da, db) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let mut p = [0.0; 3];
                p[axis] = sign * h;
                p[a] = da * h;
                p[b] = db * h;
                let mut n = [0.0; 3];
                n[axis] = sign;
                m.positions.push(p);
                m.normals.push(n);
                m.uvs.push([(da + 1.0) / 2.0, (db + 1.0) / 2.0]);
            }
            // Counter-clockwise seen from outside: reversed on the negative faces.
            if sign > 0.0 {
                m.indices.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
            } else {
                m.indices.extend_from_slice(&[base, base + 2, base + 1, base, base + 3, base + 2]);
            }
        }
    }
    m
}

/// A 64x64 noisy texture (deterministic hash) so sampling is not trivially cached.
fn noisy(base: [u8; 3], seed: u32) -> TextureData {
    let mut rgba = Vec::with_capacity(64 * 64 * 4);
    for i in 0..64 * 64u32 {
        let h = (i ^ seed).wrapping_mul(2654435761) >> 27; // 0..31
        for c in base {
            rgba.push(c.saturating_add(h as u8));
        }
        rgba.push(255);
    }
    TextureData { width: 64, height: 64, rgba }
}

fn translate(x: f32, y: f32, z: f32) -> [[f32; 4]; 4] {
    let mut m = IDENTITY;
    m[3] = [x, y, z, 1.0];
    m
}

fn park() -> (Renderer, Camera, InstanceHandle) {
    let mut r = Renderer::new(&RendererConfig::new(640, 480)).expect("adapter");
    let ground = MeshData {
        positions: vec![[-60.0, -60.0, 0.0], [60.0, -60.0, 0.0], [60.0, 60.0, 0.0], [-60.0, 60.0, 0.0]],
        normals: vec![[0.0, 0.0, 1.0]; 4],
        uvs: vec![[0.0, 0.0], [120.0, 0.0], [120.0, 120.0], [0.0, 120.0]],
        indices: vec![0, 1, 2, 0, 2, 3],
        cull_back_faces: true,
    };
    let ground = r.add_mesh(&ground).unwrap();
    let grass = r.add_texture(&noisy([50, 100, 35], 1)).unwrap();
    r.add_instance(ground, grass, IDENTITY, 1, 1);
    let trunks: Vec<MeshId> = [0.15, 0.25, 0.35].iter().map(|&rad| r.add_mesh(&trunk(rad, 5.0, 64)).unwrap()).collect();
    let barks: Vec<TextureId> = (0..3).map(|k| r.add_texture(&noisy([90, 65, 45], 7 + k)).unwrap()).collect();
    // 60 trees on a jittered grid around the camera, most within 30 m.
    let mut id = 10u16;
    for gx in -5..5 {
        for gy in -3..3 {
            let (x, y) = (gx as f32 * 6.0 + 2.0 * ((gx * 7 + gy * 3) % 5) as f32 / 5.0, gy as f32 * 6.0 + 1.5);
            r.add_instance(trunks[(id % 3) as usize], barks[(id % 3) as usize], translate(x, y, 0.0), id, 2);
            id += 1;
        }
    }
    let block = r.add_mesh(&cuboid(0.5)).unwrap();
    let stone = r.add_texture(&noisy([140, 140, 130], 99)).unwrap();
    let mut walker = None;
    for (k, (x, y)) in [(4.0, -1.0), (8.0, 2.5), (12.0, -4.0), (-6.0, 3.0)].into_iter().enumerate() {
        walker = Some(r.add_instance(block, stone, translate(x, y, 0.5), 500 + k as u16, 5));
    }
    let camera = Camera::look_at(525.0, 525.0, 320.0, 240.0, [-1.0, 0.3, 0.4], [10.0, 0.0, 0.6]);
    (r, camera, walker.expect("boxes added"))
}

/// One frame: render all targets and read them back.
#[divan::bench(sample_count = 50, sample_size = 4)]
fn park_640x480(bencher: divan::Bencher) {
    let (mut r, camera, _) = park();
    let light = Lighting::default();
    let mut frame = Frame::default();
    bencher.bench_local(|| {
        r.render_into(&camera, &light, &mut frame).unwrap();
        divan::black_box(&frame);
    });
}

/// The same with a moving camera and one instance moved per frame (a walking person).
#[divan::bench(sample_count = 50, sample_size = 4)]
fn park_640x480_moving(bencher: divan::Bencher) {
    let (mut r, mut camera, walker) = park();
    let light = Lighting::default();
    let mut frame = Frame::default();
    let mut t = 0.0f32;
    bencher.bench_local(|| {
        t += 0.05;
        camera.world_from_camera[3][0] = -1.0 + t.sin();
        r.set_transform(walker, translate(3.0 + t.cos(), 0.0, 0.0));
        r.render_into(&camera, &light, &mut frame).unwrap();
        divan::black_box(&frame);
    });
}

/// The same scene rendered only in three column spans, a fifth of the image (what
/// `objslam run` draws of a park frame: the columns its segmentation reads).
#[divan::bench(sample_count = 50, sample_size = 4)]
fn park_640x480_columns(bencher: divan::Bencher) {
    let (mut r, camera, _) = park();
    let light = Lighting::default();
    let mut frame = Frame::default();
    let spans = [(100, 145), (300, 345), (500, 545)].map(|columns| Region { columns, rows: (0, 480) });
    bencher.bench_local(|| {
        r.render_regions_into(&camera, &light, Some(&spans), &mut frame).unwrap();
        divan::black_box(&frame);
    });
}

/// The same three column spans cut to the rows a segmentation reads of a cluster some
/// metres off (from the band above the laser down to the laser's rows): about two fifths
/// of their height.
#[divan::bench(sample_count = 50, sample_size = 4)]
fn park_640x480_regions(bencher: divan::Bencher) {
    let (mut r, camera, _) = park();
    let light = Lighting::default();
    let mut frame = Frame::default();
    let spans = [(100, 145), (300, 345), (500, 545)].map(|columns| Region { columns, rows: (60, 260) });
    bencher.bench_local(|| {
        r.render_regions_into(&camera, &light, Some(&spans), &mut frame).unwrap();
        divan::black_box(&frame);
    });
}

/// One pixel of the same scene: what a frame costs whatever is drawn (clearing the targets,
/// submitting, reading back, waiting for the rasteriser).
#[divan::bench(sample_count = 50, sample_size = 4)]
fn park_640x480_one_pixel(bencher: divan::Bencher) {
    let (mut r, camera, _) = park();
    let light = Lighting::default();
    let mut frame = Frame::default();
    let spans = [(0, 1)].map(|columns| Region { columns, rows: (0, 1) });
    bencher.bench_local(|| {
        r.render_regions_into(&camera, &light, Some(&spans), &mut frame).unwrap();
        divan::black_box(&frame);
    });
}
