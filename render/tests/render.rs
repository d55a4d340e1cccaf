//! Renderer tests on whatever adapter wgpu finds (Mesa's software rasteriser in CI):
//! pinhole projection and coverage, mask/colour alignment, texture repeat, instance
//! updates, bad input, and a golden image (`OBJSLAM_BLESS=1` rewrites it).

use render::*;

const BARK: [u8; 3] = [110, 80, 55];
const STONE: [u8; 3] = [150, 150, 140];

/// Fails the test with a clear message when no adapter exists: CI has Mesa, so a missing
/// adapter is a broken environment, not a reason to skip.
fn renderer(width: u32, height: u32) -> Renderer {
    match Renderer::new(&RendererConfig::new(width, height)) {
        Ok(r) => r,
        Err(e) => {
            panic!("cannot create a renderer (install Mesa: libegl-mesa0 libgl1-mesa-dri, or mesa-vulkan-drivers): {e}")
        }
    }
}

/// Vertical cylinder, base at the origin: side with `segments` facets and a top cap.
/// u runs 0..4 around (so textures repeat), v is height in metres.
fn cylinder(radius: f32, height: f32, segments: u32) -> MeshData {
    let mut m = MeshData::default();
    for i in 0..=segments {
        let (s, c) = (std::f32::consts::TAU * i as f32 / segments as f32).sin_cos();
        for z in [0.0, height] {
            m.positions.push([radius * c, radius * s, z]);
            m.normals.push([c, s, 0.0]);
            m.uvs.push([4.0 * i as f32 / segments as f32, -z]);
        }
    }
    for i in 0..segments {
        let (b0, t0, b1, t1) = (2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3);
        m.indices.extend_from_slice(&[b0, b1, t1, b0, t1, t0]);
    }
    let centre = m.positions.len() as u32;
    m.positions.push([0.0, 0.0, height]);
    m.normals.push([0.0, 0.0, 1.0]);
    m.uvs.push([0.5, 0.5]);
    for i in 0..segments {
        let (s, c) = (std::f32::consts::TAU * i as f32 / segments as f32).sin_cos();
        m.positions.push([radius * c, radius * s, height]);
        m.normals.push([0.0, 0.0, 1.0]);
        m.uvs.push([0.5 + 0.5 * c, 0.5 + 0.5 * s]);
    }
    for i in 0..segments {
        m.indices.extend_from_slice(&[centre, centre + 1 + i, centre + 1 + (i + 1) % segments]);
    }
    m
}

/// Axis-aligned box centred on the origin with half sizes `h`, one texture per face.
fn cuboid(h: [f32; 3]) -> MeshData {
    let mut m = MeshData::default();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = m.positions.len() as u32;
            for (da, db) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let mut p = [0.0; 3];
                p[axis] = sign * h[axis];
                p[a] = da * h[a];
                p[b] = db * h[b];
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

/// A flat square on z = 0 with uvs in metres (textures repeat every metre).
fn ground(half: f32) -> MeshData {
    MeshData {
        positions: vec![[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]],
        normals: vec![[0.0, 0.0, 1.0]; 4],
        uvs: vec![[0.0, 0.0], [2.0 * half, 0.0], [2.0 * half, 2.0 * half], [0.0, 2.0 * half]],
        indices: vec![0, 1, 2, 0, 2, 3],
        cull_back_faces: false,
    }
}

/// A 16x16 two-colour checkerboard (4x4 cells).
fn checker(a: [u8; 3], b: [u8; 3]) -> TextureData {
    let mut rgba = Vec::new();
    for y in 0..16 {
        for x in 0..16 {
            let c = if (x / 4 + y / 4) % 2 == 0 { a } else { b };
            rgba.extend_from_slice(&[c[0], c[1], c[2], 255]);
        }
    }
    TextureData { width: 16, height: 16, rgba }
}

fn plain(c: [u8; 3]) -> TextureData {
    TextureData { width: 1, height: 1, rgba: vec![c[0], c[1], c[2], 255] }
}

/// Rotation by `yaw` about z, then translation.
fn pose(yaw: f32, t: [f32; 3]) -> [[f32; 4]; 4] {
    let (s, c) = yaw.sin_cos();
    [[c, s, 0.0, 0.0], [-s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [t[0], t[1], t[2], 1.0]]
}

fn apply(m: &[[f32; 4]; 4], p: [f32; 3], w: f32) -> [f32; 3] {
    std::array::from_fn(|r| m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r] * w)
}

/// The golden scene: ground, two textured cylinders (trees) and a box, seen from 1.2 m up.
struct Scene {
    r: Renderer,
    camera: Camera,
    post: InstanceHandle,
}

fn golden_scene(width: u32, height: u32) -> Scene {
    golden_scene_on(renderer(width, height), false)
}

/// The golden scene on `r` (whose size sets the camera's); `cull` lets the renderer skip
/// back faces of its meshes, which are closed where the camera sees them (cylinders
/// standing on the ground with a top cap, a box, the ground from above).
fn golden_scene_on(mut r: Renderer, cull: bool) -> Scene {
    let (width, height) = r.size();
    let mut add = |m: MeshData| r.add_mesh(&MeshData { cull_back_faces: cull, ..m }).unwrap();
    let (ground_mesh, trunk, post, block) =
        (add(ground(30.0)), add(cylinder(0.3, 4.0, 48)), add(cylinder(0.15, 1.5, 32)), add(cuboid([0.3, 0.3, 0.3])));
    let grass = r.add_texture(&checker([60, 110, 40], [75, 125, 50])).unwrap();
    let bark = r.add_texture(&checker(BARK, [70, 50, 35])).unwrap();
    let stone = r.add_texture(&checker(STONE, [120, 120, 112])).unwrap();
    r.add_instance(ground_mesh, grass, IDENTITY, 1, 1);
    r.add_instance(trunk, bark, pose(0.0, [6.0, 1.0, 0.0]), 11, 2);
    let post = r.add_instance(post, bark, pose(0.0, [3.5, -1.0, 0.0]), 12, 3);
    r.add_instance(block, stone, pose(0.5, [4.5, 0.3, 0.3]), 30, 5);
    let f = width as f32 / 2.0 / 35f32.to_radians().tan();
    let camera = Camera::look_at(f, f, width as f32 / 2.0, height as f32 / 2.0, [0.0, 0.0, 1.2], [6.0, 0.0, 1.0]);
    Scene { r, camera, post }
}

#[test]
fn reports_which_adapter_it_uses() {
    let r = renderer(8, 8);
    let info = r.adapter_info();
    eprintln!("adapter: {info}");
    assert!(!info.name.is_empty() && !info.backend.is_empty() && !info.device_type.is_empty());
}

/// Ray (o + t d) against a box with pose `m` and half sizes `h`: the entry distance.
fn ray_box(o: [f32; 3], d: [f32; 3], m: &[[f32; 4]; 4], h: [f32; 3]) -> Option<f32> {
    // Into the box frame (rigid pose): R^T (o - t).
    let rel = [o[0] - m[3][0], o[1] - m[3][1], o[2] - m[3][2]];
    let lo: [f32; 3] = std::array::from_fn(|c| (0..3).map(|k| m[c][k] * rel[k]).sum());
    let ld: [f32; 3] = std::array::from_fn(|c| (0..3).map(|k| m[c][k] * d[k]).sum());
    let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
    for k in 0..3 {
        let (a, b) = ((-h[k] - lo[k]) / ld[k], (h[k] - lo[k]) / ld[k]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 <= t1).then_some(t0)
}

/// Every pixel whose centre ray surely hits the box shows its id and the ray's z-depth;
/// every pixel whose centre ray surely misses does not. With an off-centre principal
/// point, fx != fy and a rolled camera, a y-flip, a transposed intrinsic or a half-pixel
/// shift all fail this.
#[test]
fn pixel_centre_rays_hit_exactly_the_pixels_of_a_box_with_pinhole_depth() {
    let (w, h) = (200u32, 150u32);
    let mut r = renderer(w, h);
    let half = [0.4, 0.6, 0.5];
    let box_pose = pose(0.4, [5.0, 0.3, 1.1]);
    let mesh = r.add_mesh(&cuboid(half)).unwrap();
    let tex = r.add_texture(&plain(STONE)).unwrap();
    r.add_instance(mesh, tex, box_pose, 4242, 9);
    let mut camera = Camera::look_at(180.0, 165.0, 93.7, 81.2, [0.0, 0.2, 1.0], [5.0, 0.0, 1.3]);
    // Roll the camera by 0.2 rad about its optical axis.
    let (s, c) = 0.2f32.sin_cos();
    let (x, y) = (camera.world_from_camera[0], camera.world_from_camera[1]);
    camera.world_from_camera[0] = std::array::from_fn(|k| c * x[k] + s * y[k]);
    camera.world_from_camera[1] = std::array::from_fn(|k| -s * x[k] + c * y[k]);
    let frame = r.render(&camera, &Lighting::default()).unwrap();

    let m = camera.world_from_camera;
    let eye = [m[3][0], m[3][1], m[3][2]];
    let (mut inside, mut outside) = (0, 0);
    for v in 0..h {
        for u in 0..w {
            let (pu, pv) = (u as f32 + 0.5, v as f32 + 0.5);
            let ray_cam = [(pu - camera.cx) / camera.fx, (pv - camera.cy) / camera.fy, 1.0];
            let d = apply(&m, ray_cam, 0.0);
            let shrunk = ray_box(eye, d, &box_pose, half.map(|x| x - 0.003));
            let grown = ray_box(eye, d, &box_pose, half.map(|x| x + 0.003));
            if shrunk.is_some() {
                let t = ray_box(eye, d, &box_pose, half).expect("inside the shrunk box, so inside the box");
                // The hit point P, projected with the pinhole formula, lands in this pixel.
                let p = [eye[0] + t * d[0], eye[1] + t * d[1], eye[2] + t * d[2]];
                let [pu2, pv2, z] = camera.project(p).unwrap();
                assert_eq!((pu2.floor() as u32, pv2.floor() as u32), (u, v), "P {p:?}");
                assert_eq!(frame.instance_at(u, v), 4242, "pixel ({u}, {v}) should see the box");
                assert_eq!(frame.class_at(u, v), 9);
                let depth = frame.depth_at(u, v);
                assert!((depth - z).abs() < 0.01, "pixel ({u}, {v}): depth {depth} m, pinhole z {z} m");
                inside += 1;
            } else if grown.is_none() {
                assert_eq!(frame.instance_at(u, v), 0, "pixel ({u}, {v}) should see sky");
                assert!(frame.depth_at(u, v).is_infinite());
                outside += 1;
            }
        }
    }
    assert!(inside > 1000 && outside > 1000, "box covers {inside} pixels, sky {outside}");
}

/// A vertical edge at a known fractional column: pixels whose centres lie right of it are
/// covered, the others not (pixel index = floor(u)).
#[test]
fn an_edge_splits_pixels_at_their_centres() {
    let mut r = renderer(64, 48);
    let mesh = r.add_mesh(&cuboid([0.1, 5.0, 5.0])).unwrap();
    let tex = r.add_texture(&plain(STONE)).unwrap();
    let slab = r.add_instance(mesh, tex, IDENTITY, 5, 1);
    // From the origin along +x: u = 32 - 40 y / x, so the slab's +y side is its left edge.
    let camera = Camera::look_at(40.0, 40.0, 32.0, 24.0, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
    for edge_u in [20.3f32, 20.7, 41.45, 41.55] {
        // The silhouette edge is on the near face (x = 9.9) left of centre, else the far one.
        let depth = if edge_u < 32.0 { 9.9 } else { 10.1 };
        let y_edge = (32.0 - edge_u) * depth / 40.0;
        r.set_transform(slab, pose(0.0, [10.0, y_edge - 5.0, 0.0]));
        let f = r.render(&camera, &Lighting::default()).unwrap();
        let first = edge_u.floor() as u32;
        let covered_first = edge_u.fract() < 0.5;
        assert_eq!(f.instance_at(first, 24) == 5, covered_first, "edge at u = {edge_u}: pixel {first}");
        assert_eq!(f.instance_at(first + 1, 24), 5, "edge at u = {edge_u}");
        assert_eq!(f.instance_at(first - 1, 24), 0, "edge at u = {edge_u}");
    }
}

#[test]
fn a_point_on_a_cylinder_lands_on_it_with_its_depth() {
    let Scene { mut r, camera, .. } = golden_scene(320, 240);
    let frame = r.render(&camera, &Lighting::default()).unwrap();
    // Points on the trunk (centre (6, 1), r 0.3) and the post (centre (3.5, -1), r 0.15)
    // facing the camera, at various heights.
    let on = |c: [f32; 2], radius: f32, z: f32| {
        let a = (-c[1]).atan2(-c[0]); // towards the camera at the origin
        [c[0] + radius * a.cos(), c[1] + radius * a.sin(), z]
    };
    for (id, p) in [
        (11u16, on([6.0, 1.0], 0.3, 1.0)),
        (11, on([6.0, 1.0], 0.3, 2.5)),
        (12, on([3.5, -1.0], 0.15, 0.8)),
        (12, on([3.5, -1.0], 0.15, 1.3)),
    ] {
        let [u, v, z] = camera.project(p).unwrap();
        let (pu, pv) = (u.floor() as u32, v.floor() as u32);
        assert_eq!(frame.instance_at(pu, pv), id, "point {p:?} at pixel ({pu}, {pv})");
        let depth = frame.depth_at(pu, pv);
        assert!((depth - z).abs() < 0.01, "point {p:?}: depth {depth} m vs pinhole z {z} m");
    }
}

#[test]
fn masks_depth_and_colour_agree_pixel_for_pixel() {
    let Scene { mut r, camera, .. } = golden_scene(160, 120);
    let light = Lighting::default();
    let frame = r.render(&camera, &light).unwrap();
    assert_eq!(
        (frame.rgb.len(), frame.instance.len(), frame.class.len(), frame.depth_m.len()),
        (160 * 120 * 3, 160 * 120, 160 * 120, 160 * 120)
    );
    let sky = light.sky_colour.map(|c| (c * 255.0).round() as i32);
    let mut counts = std::collections::BTreeMap::new();
    for v in 0..120 {
        for u in 0..160 {
            let rgb = frame.rgb_at(u, v);
            let is_sky_colour = (0..3).all(|k| (rgb[k] as i32 - sky[k]).abs() <= 1);
            let id = frame.instance_at(u, v);
            assert_eq!(id == 0, is_sky_colour, "pixel ({u}, {v}): id {id}, colour {rgb:?}");
            assert_eq!(id == 0, frame.depth_at(u, v).is_infinite(), "pixel ({u}, {v})");
            let class = match id {
                0 => 0,
                1 => 1,
                11 => 2,
                12 => 3,
                30 => 5,
                _ => panic!("unknown id {id} at ({u}, {v})"),
            };
            assert_eq!(frame.class_at(u, v), class, "pixel ({u}, {v})");
            *counts.entry(id).or_insert(0) += 1;
        }
    }
    // Everything is in view.
    assert_eq!(counts.keys().copied().collect::<Vec<_>>(), vec![0, 1, 11, 12, 30], "{counts:?}");
}

#[test]
fn textures_repeat_when_uvs_exceed_one() {
    let mut r = renderer(160, 40);
    // A wall filling the view whose u runs 0..4 across: a red|blue texture must repeat 4 times.
    let wall = MeshData {
        positions: vec![[5.0, 10.0, -10.0], [5.0, -10.0, -10.0], [5.0, -10.0, 10.0], [5.0, 10.0, 10.0]],
        normals: vec![[-1.0, 0.0, 0.0]; 4],
        uvs: vec![[0.0, 0.0], [4.0, 0.0], [4.0, 1.0], [0.0, 1.0]],
        indices: vec![0, 1, 2, 0, 2, 3],
        cull_back_faces: false,
    };
    let mut rgba = Vec::new();
    for x in 0..16 {
        rgba.extend_from_slice(if x < 8 { &[220, 20, 20, 255] } else { &[20, 20, 220, 255] });
    }
    let mesh = r.add_mesh(&wall).unwrap();
    let tex = r.add_texture(&TextureData { width: 16, height: 1, rgba }).unwrap();
    r.add_instance(mesh, tex, IDENTITY, 3, 1);
    // fx chosen so the 20 m wide wall at 5 m spans exactly the 160 px image.
    let camera = Camera::look_at(40.0, 40.0, 80.0, 20.0, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
    let frame = r.render(&camera, &Lighting { sun_direction: [1.0, 0.0, 0.0], ..Lighting::default() }).unwrap();
    let reddish: Vec<bool> = (0..160).map(|u| frame.rgb_at(u, 20)[0] > frame.rgb_at(u, 20)[2]).collect();
    let changes = reddish.windows(2).filter(|w| w[0] != w[1]).count();
    assert!(changes >= 7, "expected 4 red/blue periods across the wall, saw {changes} changes: {reddish:?}");
}

/// Sun-facing faces are brighter, and the lighting does not depend on triangle winding
/// (meshes from elsewhere may wind either way).
#[test]
fn a_face_towards_the_sun_is_brighter_than_one_beside_it_whatever_the_winding() {
    let camera = Camera::look_at(100.0, 100.0, 60.0, 45.0, [-4.0, -4.0, 0.8], [0.0, 0.0, 0.0]);
    // Sunlight travelling along +x lights the -x face fully and grazes the -y face.
    let light = Lighting { sun_direction: [1.0, 0.0, 0.0], ..Lighting::default() };
    let draw = |mesh: &MeshData| {
        let mut r = renderer(120, 90);
        let mesh = r.add_mesh(mesh).unwrap();
        let tex = r.add_texture(&plain(STONE)).unwrap();
        r.add_instance(mesh, tex, IDENTITY, 2, 1);
        r.render(&camera, &light).unwrap()
    };
    let ccw = cuboid([0.5, 0.5, 0.5]);
    let mut cw = ccw.clone();
    cw.indices.chunks_exact_mut(3).for_each(|t| t.swap(1, 2));
    let (frame, reversed) = (draw(&ccw), draw(&cw));
    let at = |p: [f32; 3]| {
        let [u, v, _] = camera.project(p).unwrap();
        assert_eq!(frame.instance_at(u as u32, v as u32), 2);
        frame.rgb_at(u as u32, v as u32).iter().map(|&c| c as u32).sum::<u32>()
    };
    let (lit, shaded) = (at([-0.5, 0.0, 0.0]), at([0.0, -0.5, 0.0]));
    assert!(lit > shaded + 60, "sunlit face {lit}, shaded face {shaded}");
    let worst = frame.rgb.iter().zip(&reversed.rgb).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
    assert!(worst <= 1, "reversing the winding changed a pixel by {worst} levels");
    assert_eq!(frame.instance, reversed.instance);
}

#[test]
fn moving_and_hiding_an_instance_updates_its_pixels() {
    let Scene { mut r, camera, post } = golden_scene(160, 120);
    let count = |f: &Frame| f.instance.iter().filter(|&&i| i == 12).count();
    let before = count(&r.render(&camera, &Lighting::default()).unwrap());
    r.set_transform(post, pose(0.0, [8.0, -1.5, 0.0]));
    let farther = count(&r.render(&camera, &Lighting::default()).unwrap());
    assert!(before > 50 && farther * 2 < before, "post should shrink with distance: {before} -> {farther} pixels");
    r.set_visible(post, false);
    assert_eq!(count(&r.render(&camera, &Lighting::default()).unwrap()), 0);
    r.set_visible(post, true);
    let mut frame = Frame::default();
    r.render_into(&camera, &Lighting::default(), &mut frame).unwrap();
    assert_eq!(count(&frame), farther);
}

#[test]
fn exposure_scales_the_lit_colour_but_not_the_sky() {
    let Scene { mut r, camera, .. } = golden_scene(80, 60);
    let dim = r.render(&camera, &Lighting { exposure: 0.5, ..Lighting::default() }).unwrap();
    let bright = r.render(&camera, &Lighting::default()).unwrap();
    let sum = |f: &Frame, object: bool| -> u64 {
        (0..f.instance.len())
            .filter(|&i| (f.instance[i] != 0) == object)
            .map(|i| f.rgb[3 * i] as u64 + f.rgb[3 * i + 1] as u64)
            .sum()
    };
    assert!(sum(&bright, true) > sum(&dim, true) * 5 / 4);
    assert_eq!(sum(&bright, false), sum(&dim, false));
    assert_eq!(dim.instance, bright.instance);
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    assert!(matches!(Renderer::new(&RendererConfig::new(0, 10)), Err(RenderError::Size { .. })));
    assert!(matches!(Renderer::new(&RendererConfig::new(1_000_000, 10)), Err(RenderError::Size { .. })));
    let mut r = renderer(16, 16);
    let tri = |indices: Vec<u32>| MeshData {
        positions: vec![[0.0; 3]; 3],
        normals: vec![[0.0, 0.0, 1.0]; 3],
        uvs: vec![[0.0; 2]; 3],
        indices,
        cull_back_faces: false,
    };
    assert!(matches!(r.add_mesh(&tri(vec![0, 1, 5])), Err(RenderError::Mesh(_))));
    assert!(matches!(r.add_mesh(&tri(vec![0, 1])), Err(RenderError::Mesh(_))));
    assert!(matches!(r.add_mesh(&MeshData { uvs: vec![], ..tri(vec![0, 1, 2]) }), Err(RenderError::Mesh(_))));
    assert!(matches!(
        r.add_mesh(&MeshData { positions: vec![[f32::NAN; 3]; 3], ..tri(vec![0, 1, 2]) }),
        Err(RenderError::Mesh(_))
    ));
    assert!(matches!(
        r.add_texture(&TextureData { width: 2, height: 2, rgba: vec![0; 3] }),
        Err(RenderError::Texture(_))
    ));
    assert!(matches!(
        r.add_texture(&TextureData { width: 100_000, height: 1, rgba: vec![0; 400_000] }),
        Err(RenderError::Texture(_))
    ));
    let camera = Camera::look_at(10.0, 10.0, 8.0, 8.0, [0.0; 3], [1.0, 0.0, 0.0]);
    assert!(matches!(r.render(&Camera { near_m: 0.0, ..camera }, &Lighting::default()), Err(RenderError::Camera(_))));
    assert!(matches!(r.render(&Camera { fx: f32::NAN, ..camera }, &Lighting::default()), Err(RenderError::Camera(_))));
    assert!(matches!(
        r.render(&camera, &Lighting { exposure: f32::NAN, ..Lighting::default() }),
        Err(RenderError::Lighting(_))
    ));
    // Ids from another renderer are reported, not indexed out of bounds.
    let mut other = renderer(16, 16);
    let mesh = other.add_mesh(&tri(vec![0, 1, 2])).unwrap();
    let tex = other.add_texture(&plain(STONE)).unwrap();
    r.add_instance(mesh, tex, IDENTITY, 1, 1);
    assert!(matches!(r.render(&camera, &Lighting::default()), Err(RenderError::UnknownResource { .. })));
}

/// Compares with the committed golden colour image and instance mask. Software
/// rasterisers differ slightly between versions, so it allows a mean difference of 3 levels
/// per channel on objects, 2 % of pixels far off (edges) and 1 % of mask pixels.
#[test]
fn golden_scene_matches_the_committed_images() {
    let Scene { mut r, camera, .. } = golden_scene(160, 120);
    let frame = r.render(&camera, &Lighting::default()).unwrap();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    let colour_path = dir.join("scene_160x120.png");
    let mask_path = dir.join("scene_160x120_instance.png");
    let colour = image::RgbImage::from_raw(160, 120, frame.rgb.clone()).unwrap();
    let mask = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(160, 120, frame.instance.clone()).unwrap();
    if std::env::var("OBJSLAM_BLESS").is_ok_and(|v| v == "1") {
        std::fs::create_dir_all(&dir).unwrap();
        colour.save(&colour_path).unwrap();
        mask.save(&mask_path).unwrap();
        eprintln!("wrote {} and {} on {}", colour_path.display(), mask_path.display(), r.adapter_info());
        return;
    }
    let hint = "run `OBJSLAM_BLESS=1 cargo test -p render --test render golden` to regenerate after an intended change";
    let golden =
        image::open(&colour_path).unwrap_or_else(|e| panic!("{}: {e}; {hint}", colour_path.display())).to_rgb8();
    let golden_mask =
        image::open(&mask_path).unwrap_or_else(|e| panic!("{}: {e}; {hint}", mask_path.display())).to_luma16();
    assert_eq!(golden.dimensions(), (160, 120));
    // Mean absolute difference per channel over the pixels showing objects (the sky, always
    // exact, would dilute it), and the share of pixels off by more than 16 levels (edges).
    let (mut sum, mut n, mut far_off) = (0.0f64, 0usize, 0usize);
    for (i, (a, b)) in golden.pixels().zip(colour.pixels()).enumerate() {
        let d: Vec<f64> = (0..3).map(|k| (a[k] as f64 - b[k] as f64).abs()).collect();
        if golden_mask.as_raw()[i] != 0 {
            sum += d.iter().sum::<f64>();
            n += 3;
        }
        far_off += d.iter().any(|&x| x > 16.0) as usize;
    }
    let mad = sum / n.max(1) as f64;
    let differing = golden_mask.as_raw().iter().zip(mask.as_raw()).filter(|(a, b)| a != b).count();
    eprintln!(
        "golden: mean abs difference {mad:.3} levels on objects, {far_off} pixels off by > 16 levels, {differing} mask pixels differ"
    );
    assert!(mad < 3.0, "mean absolute difference {mad:.2} levels per channel on objects; {hint}");
    assert!(far_off * 50 < 160 * 120, "{far_off} pixels differ by more than 16 levels; {hint}");
    assert!(differing * 100 < 160 * 120, "{differing} of {} mask pixels differ; {hint}", 160 * 120);
}

#[test]
fn culling_back_faces_of_closed_meshes_changes_no_pixel() {
    let mut two_sided = golden_scene(160, 120);
    let mut culled = golden_scene_on(renderer(160, 120), true);
    let a = two_sided.r.render(&two_sided.camera, &Lighting::default()).unwrap();
    let b = culled.r.render(&culled.camera, &Lighting::default()).unwrap();
    assert_eq!(a.instance, b.instance);
    assert_eq!(a.class, b.class);
    assert_eq!(a.depth_m, b.depth_m);
    assert_eq!(a.rgb, b.rgb);
}

#[test]
fn culling_skips_faces_seen_from_behind_but_not_mirrored_instances() {
    let mut r = renderer(64, 48);
    // A square 4 m ahead, counter-clockwise seen from the camera (its front).
    let square = MeshData {
        positions: vec![[4.0, 1.0, -1.0], [4.0, -1.0, -1.0], [4.0, -1.0, 1.0], [4.0, 1.0, 1.0]],
        normals: vec![[-1.0, 0.0, 0.0]; 4],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        indices: vec![0, 1, 2, 0, 2, 3],
        cull_back_faces: true,
    };
    let mesh = r.add_mesh(&square).unwrap();
    let tex = r.add_texture(&plain(STONE)).unwrap();
    let handle = r.add_instance(mesh, tex, IDENTITY, 9, 1);
    let camera = Camera::look_at(40.0, 40.0, 32.0, 24.0, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
    let seen = |r: &mut Renderer| r.render(&camera, &Lighting::default()).unwrap().instance_at(32, 24) == 9;
    assert!(seen(&mut r), "the front face is drawn");
    // Turned about z through the square's centre: the camera now sees its back.
    r.set_transform(handle, pose(std::f32::consts::PI, [8.0, 0.0, 0.0]));
    assert!(!seen(&mut r), "a back face of a culled mesh is skipped");
    // Mirrored in y (determinant -1): the winding turns over with it, so the face the camera
    // sees is the front, and the instance is drawn from both sides.
    let mut mirror = IDENTITY;
    mirror[1][1] = -1.0;
    r.set_transform(handle, mirror);
    assert!(seen(&mut r), "a mirrored instance is drawn whatever its winding");
}

#[test]
fn a_renderer_without_depth_draws_the_same_colour_and_masks() {
    let mut with = golden_scene(160, 120);
    let mut without = golden_scene_on(
        Renderer::new(&RendererConfig { depth: false, ..RendererConfig::new(160, 120) }).unwrap(),
        false,
    );
    let a = with.r.render(&with.camera, &Lighting::default()).unwrap();
    let b = without.r.render(&without.camera, &Lighting::default()).unwrap();
    assert_eq!(a.depth_m.len(), 160 * 120);
    assert!(b.depth_m.is_empty(), "no depth image was asked for");
    assert_eq!((a.rgb, a.instance, a.class), (b.rgb, b.instance, b.class));
}

#[test]
fn rendering_some_regions_gives_the_whole_frames_pixels_there_and_zero_elsewhere() {
    let mut scene = golden_scene_on(renderer(160, 120), true);
    let light = Lighting::default();
    let whole = scene.r.render(&scene.camera, &light).unwrap();
    assert_eq!(whole.regions, None);
    let r = |c0, c1, r0, r1| Region { columns: (c0, c1), rows: (r0, r1) };
    // Regions through the post (one a single column wide), the block's edge and the
    // trunk's middle, the last at the image's edge, some of the whole height and some of a
    // band of rows; rendered into a frame holding a whole render, which must not show
    // through. Five regions' padded rows do not fit the readback buffer (the whole targets
    // are copied); two do (copied region by region). Each follows a frame from elsewhere
    // under another sky, whose pixels the regions must not keep.
    let many = [r(10, 37, 0, 120), r(60, 61, 30, 31), r(70, 96, 20, 90), r(108, 112, 0, 120), r(150, 160, 100, 120)];
    let mut away = scene.camera;
    away.world_from_camera[3][1] += 0.7;
    let other_sky = Lighting { sky_colour: [0.2, 0.1, 0.5], ..Lighting::default() };
    // Also rendered into one frame after another: each time it holds the last regions'
    // pixels (a frame of another size first), which must not show through either.
    let mut small = golden_scene(32, 24);
    let mut chained = Frame::default();
    small.r.render_regions_into(&small.camera, &light, Some(&[r(3, 20, 2, 20)]), &mut chained).unwrap();
    for spans in [
        &many[..],
        &[r(70, 96, 0, 120), r(108, 112, 40, 75)],
        &[r(10, 37, 0, 120), r(70, 96, 20, 90), r(108, 112, 0, 120)],
    ] {
        let before = scene.r.render(&away, &other_sky).unwrap();
        assert_ne!(before.instance, whole.instance);
        let mut part = whole.clone();
        scene.r.render_regions_into(&scene.camera, &light, Some(spans), &mut part).unwrap();
        assert_eq!(part.regions.as_deref(), Some(spans));
        let mut inside = 0;
        let mut sky = 0;
        for v in 0..120 {
            for u in 0..160 {
                if spans.iter().any(|s| s.contains(u, v)) {
                    let same = (part.rgb_at(u, v), part.instance_at(u, v), part.class_at(u, v), part.depth_at(u, v))
                        == (whole.rgb_at(u, v), whole.instance_at(u, v), whole.class_at(u, v), whole.depth_at(u, v));
                    assert!(same, "pixel ({u}, {v}) differs from the whole frame's with regions {spans:?}");
                    inside += (whole.instance_at(u, v) > 1) as usize;
                    sky += (whole.instance_at(u, v) == 0) as usize;
                } else {
                    assert_eq!(
                        (part.rgb_at(u, v), part.instance_at(u, v), part.class_at(u, v)),
                        ([0; 3], 0, 0),
                        "pixel ({u}, {v}) outside the regions"
                    );
                    assert_eq!(part.depth_at(u, v), f32::INFINITY);
                }
            }
        }
        assert!(inside > 300 && sky > 20, "the regions cross objects ({inside} pixels) and sky ({sky})");
        // A new frame (one allocation, written once) comes out the same.
        let mut new = Frame::default();
        scene.r.render_regions_into(&scene.camera, &light, Some(spans), &mut new).unwrap();
        assert!(new == part, "a new frame differs from a reused one");
        scene.r.render_regions_into(&scene.camera, &light, Some(spans), &mut chained).unwrap();
        assert!(new == chained, "a frame reused from other regions differs from a new one with regions {spans:?}");
    }
    let mut part = whole.clone();
    // No regions: nothing drawn, an empty frame of the right size.
    scene.r.render_regions_into(&scene.camera, &light, Some(&[]), &mut part).unwrap();
    assert_eq!((part.width, part.height, part.regions.as_deref()), (160, 120, Some(&[][..])));
    assert!(part.instance.iter().all(|&i| i == 0) && part.rgb.iter().all(|&c| c == 0));
    let mut new = Frame::default();
    scene.r.render_regions_into(&scene.camera, &light, Some(&[]), &mut new).unwrap();
    assert!(new == part, "a new empty frame differs from a reused one");
}

#[test]
fn regions_out_of_order_overlapping_empty_or_outside_the_image_are_errors() {
    let mut scene = golden_scene(32, 24);
    let mut frame = Frame::default();
    let r = |c0, c1, r0, r1| Region { columns: (c0, c1), rows: (r0, r1) };
    for bad in [
        &[r(5, 5, 0, 24)][..],
        &[r(0, 33, 0, 24)],
        &[r(10, 20, 0, 24), r(15, 25, 0, 24)],
        &[r(10, 20, 0, 24), r(0, 5, 0, 24)],
        &[r(0, 5, 7, 7)],
        &[r(0, 5, 3, 25)],
    ] {
        let e = scene.r.render_regions_into(&scene.camera, &Lighting::default(), Some(bad), &mut frame).unwrap_err();
        assert!(matches!(e, RenderError::Region { .. }), "{bad:?}: {e}");
        assert!(e.to_string().contains("column-disjoint and within the 32 x 24 image"), "{e}");
    }
}
