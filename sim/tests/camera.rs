//! The camera against the laser and the ground truth: what the laser hits, carried into the
//! image with the extrinsics (the paper's Phi, Delta) and K, lands on the same object.

use render::Region;
use sim::{SensorEvent, SimConfig, Simulation};

#[test]
fn laser_points_projected_with_extrinsics_land_on_their_objects_pixels() {
    let world = worlds::generate::park(&Default::default(), 2006).unwrap();
    let config = SimConfig { max_duration_s: Some(30.0), ..Default::default() };
    let mut s = Simulation::new(&world, &config, 2).unwrap();
    eprintln!("renderer: {}", s.camera().unwrap().adapter());
    // P_camera = Phi^-1 (P_laser - Delta)
    let camera_from_laser = config.camera.laser_from_camera(&config.laser).inverse();
    let k = config.camera.intrinsics();
    let mut last_frame = None;
    let (mut checked, mut agreed) = (0usize, 0usize);
    let (mut depth_checked, mut depth_agreed) = (0usize, 0usize);
    while let Some(e) = s.next_event() {
        match e {
            // Laser and camera share time stamps at 5 Hz (the laser runs at 10 Hz); at one
            // instant the image comes first.
            SensorEvent::Camera { frame, .. } => last_frame = Some(frame),
            SensorEvent::Laser { scan, beams, .. } => {
                let Some(frame) = &last_frame else { continue };
                if (scan.t - frame.t).abs() > 1e-9 {
                    continue;
                }
                let (ids, ranges) = (&beams.hit_ids, &beams.true_ranges);
                for (i, &id) in ids.iter().enumerate() {
                    if id == 0 || !ranges[i].is_finite() || ranges[i] > 15.0 {
                        continue;
                    }
                    let a = scan.angle_min + scan.angle_increment * i as f64;
                    // Pull the point 2 mm back along the beam so it is in front of the surface.
                    let r = ranges[i] - 0.002;
                    let p_laser = [r * a.cos(), r * a.sin(), 0.0];
                    let p_cam = camera_from_laser.apply(p_laser);
                    let Some(px) = k.project(p_cam) else { continue };
                    let (u, v) = (px[0].floor(), px[1].floor());
                    if u < 0.0 || v < 0.0 || u >= k.width as f64 || v >= k.height as f64 {
                        continue;
                    }
                    let seen = frame.image.instance_at(u as u32, v as u32);
                    checked += 1;
                    if seen == id {
                        agreed += 1;
                    } else {
                        // Only acceptable at an object's silhouette edge.
                        let near_edge =
                            (-1i64..=1).flat_map(|du| (-1i64..=1).map(move |dv| (du, dv))).any(|(du, dv)| {
                                let (uu, vv) = (u as i64 + du, v as i64 + dv);
                                uu >= 0
                                    && vv >= 0
                                    && uu < k.width as i64
                                    && vv < k.height as i64
                                    && frame.image.instance_at(uu as u32, vv as u32) == id
                            });
                        assert!(
                            near_edge,
                            "beam {i} hit {id} at {r:.2} m but pixel ({u}, {v}) shows {seen} at t = {}",
                            frame.t
                        );
                    }
                    // The rendered depth agrees with the laser point's depth, within what one
                    // pixel spans (z / fx) — except at grazing incidence, where a pixel's
                    // footprint covers a range of depths; count those.
                    if seen == id {
                        let d = frame.image.depth_at(u as u32, v as u32) as f64;
                        let tolerance = 0.01 + 2.0 * p_cam[2] / k.fx;
                        depth_checked += 1;
                        if (d - p_cam[2]).abs() < tolerance {
                            depth_agreed += 1;
                        }
                    }
                }
            }
            _ => {}
        }
    }
    assert!(checked > 200, "only {checked} laser points fell in the image");
    assert!(agreed as f64 >= 0.97 * checked as f64, "{agreed} of {checked} agreed");
    assert!(depth_agreed as f64 >= 0.95 * depth_checked as f64, "depth agreed for {depth_agreed} of {depth_checked}");
}

#[test]
fn class_image_follows_the_instance_image() {
    let world = worlds::generate::park(&Default::default(), 2006).unwrap();
    let mut config = SimConfig { max_duration_s: Some(0.5), ..Default::default() };
    config.camera.width = 320;
    config.camera.height = 240;
    let mut s = Simulation::new(&world, &config, 2).unwrap();
    let mut frames = 0;
    while let Some(e) = s.next_event() {
        if let SensorEvent::Camera { frame, .. } = e {
            frames += 1;
            for (i, &id) in frame.image.instance.iter().enumerate() {
                let class = frame.image.class[i];
                let expected = match id {
                    0 => 0,
                    worlds::validate::GROUND_INSTANCE_ID => worlds::ObjectClass::Ground.id(),
                    id => world.class_of(id).expect("instance ids come from the world").id(),
                };
                assert_eq!(class, expected, "pixel {i}: instance {id}");
            }
        }
    }
    assert_eq!(frames, 3);
}

#[test]
fn a_checkerboard_shows_its_squares() {
    use worlds::*;
    let mut world = worlds::generate::park(&Default::default(), 2006).unwrap();
    world.objects.clear();
    world.people.clear();
    // Facing -x, towards a camera at the origin looking along +x.
    world.objects.push(StaticObject::checkerboard(
        500,
        Pose2 { x: 2.5, y: 0.0, yaw_deg: 180.0 },
        Shape::Board { width_m: 0.8, height_m: 0.6, bottom_m: 0.25, squares: [8, 6], tilt_deg: 0.0, roll_deg: 0.0 },
    ));
    let mut config = sim::camera::CameraConfig { mount_pitch_deg: 0.0, ..Default::default() };
    config.enabled = true;
    let mut cam = sim::camera::CameraSensor::new(&world, &config, 1).unwrap();
    let robot = sim::Pose2D { x: 0.0, y: 0.0, theta: 0.0 };
    let frame = cam.capture(0.0, &robot, &[]).unwrap();
    // Walk along the image row through the board's middle (board centre height 0.55 m =
    // the camera's height, so the centre row), counting dark/light changes on the board.
    let v = 240 + 25; // inside a row of squares (a square edge lies on the centre row)
    let mut changes = 0;
    let mut last: Option<bool> = None;
    for u in 0..640 {
        if frame.image.instance_at(u, v) != 500 {
            continue;
        }
        let dark = frame.image.rgb_at(u, v)[0] < 100;
        if let Some(l) = last
            && l != dark
        {
            changes += 1;
        }
        last = Some(dark);
    }
    assert_eq!(changes, 7, "8 squares across give 7 dark/light edges");
}

#[test]
fn masks_and_colour_do_not_depend_on_whether_depth_is_rendered() {
    let world = worlds::generate::park(&Default::default(), 2006).unwrap();
    let frames = |depth_image: bool| -> Vec<render::Frame> {
        let mut config = SimConfig { max_duration_s: Some(20.0), ..Default::default() };
        config.camera.depth_image = depth_image;
        let mut s = Simulation::new(&world, &config, 2).unwrap();
        let mut out = Vec::new();
        while let Some(e) = s.next_event() {
            if let SensorEvent::Camera { frame, .. } = e {
                out.push(frame.image);
            }
        }
        out
    };
    let (with, without) = (frames(true), frames(false));
    assert_eq!(with.len(), without.len());
    assert!(with.len() >= 90, "{} frames", with.len());
    for (k, (a, b)) in with.iter().zip(&without).enumerate() {
        assert!(b.depth_m.is_empty());
        let differ = |x: &[u8], y: &[u8]| x.iter().zip(y).filter(|(p, q)| p != q).count();
        let inst = a.instance.iter().zip(&b.instance).filter(|(p, q)| p != q).count();
        assert_eq!(
            (differ(&a.rgb, &b.rgb), inst, differ(&a.class, &b.class)),
            (0, 0, 0),
            "frame {k}: differing rgb values, instance and class pixels"
        );
    }
}

#[test]
fn rendering_on_the_camera_thread_gives_the_inline_event_stream() {
    let world = worlds::generate::park(&Default::default(), 2006).unwrap();
    let config = SimConfig { max_duration_s: Some(15.0), ..Default::default() };
    let stream = |threaded: bool| -> Vec<String> {
        let mut s = Simulation::new(&world, &config, 5).unwrap();
        if threaded {
            s.render_camera_on_thread().unwrap();
            assert!(s.camera().is_none() && s.camera_adapter().is_some());
        }
        let mut out = Vec::new();
        while let Some(e) = s.next_event() {
            // Each event in full, frames by a hash of their images.
            out.push(match e {
                SensorEvent::Camera { frame, truth } => {
                    let img = &frame.image;
                    let mut h: u64 = 0xcbf29ce484222325;
                    for b in img
                        .rgb
                        .iter()
                        .copied()
                        .chain(img.class.iter().copied())
                        .chain(img.instance.iter().flat_map(|v| v.to_le_bytes()))
                    {
                        h = (h ^ b as u64).wrapping_mul(0x100000001b3);
                    }
                    format!("camera {} {h:x} {truth:?}", frame.t)
                }
                other => format!("{other:?}"),
            });
        }
        assert!(s.camera_error().is_none());
        out
    };
    let (inline, threaded) = (stream(false), stream(true));
    assert!(inline.iter().filter(|e| e.starts_with("camera")).count() >= 70);
    assert_eq!(inline.len(), threaded.len());
    for (k, (a, b)) in inline.iter().zip(&threaded).enumerate() {
        assert!(a == b, "event {k} differs:\n{}\n{}", &a[..a.len().min(300)], &b[..b.len().min(300)]);
    }
}

#[test]
fn a_region_selector_renders_each_frame_where_the_scan_of_its_instant_says() {
    let world = worlds::generate::park(&Default::default(), 2006).unwrap();
    // With image noise and exposure variation, which must draw the same numbers either way.
    let mut config = SimConfig { max_duration_s: Some(4.0), ..Default::default() };
    config.camera.noise_sigma = 2.0;
    config.camera.exposure_sigma = 0.05;
    // Regions from the scan: a rectangle that moves with the number of beams that hit
    // something, and a fixed one of the whole height.
    let select = |scan: &sim::LaserScan, _: &sim::LaserTruth| {
        let hits = scan.ranges.iter().filter(|r| r.is_finite() && **r < scan.range_max).count() as u32;
        vec![
            Region { columns: (hits % 300, hits % 300 + 40), rows: (hits % 200, hits % 200 + 90) },
            Region { columns: (400, 480), rows: (0, 480) },
        ]
    };
    let frames = |regions: bool, threaded: bool| {
        let mut s = Simulation::new(&world, &config, 5).unwrap();
        if regions {
            s.render_camera_regions(Box::new(select));
        }
        if threaded {
            s.render_camera_on_thread().unwrap();
        }
        // Frames of regions are given back as soon as they come, so each renders into the
        // last one's buffers, which must not show through.
        let pool = s.camera_frame_pool().expect("the camera is on");
        let mut out = Vec::new();
        while let Some(e) = s.next_event() {
            match e {
                SensorEvent::Camera { frame, .. } => {
                    if regions {
                        // Inline, each frame takes the one given back before it.
                        assert!(threaded || pool.is_empty(), "a spare frame was left unused");
                        pool.give(frame.image.clone());
                    }
                    out.push((frame, None))
                }
                // The scan of a frame's instant follows it.
                SensorEvent::Laser { scan, beams, .. } => {
                    if let Some(last) = out.last_mut().filter(|(f, chosen)| f.t == scan.t && chosen.is_none()) {
                        last.1 = Some(select(&scan, &beams));
                    }
                }
                _ => {}
            }
        }
        assert!(s.camera_error().is_none());
        out
    };
    let whole = frames(false, false);
    for parts in [frames(true, true), frames(true, false)] {
        assert_eq!(whole.len(), parts.len());
        assert!(parts.len() >= 20);
        for ((w, _), (p, chosen)) in whole.iter().zip(&parts) {
            let t = p.t;
            let (w, p) = (&w.image, &p.image);
            assert_eq!(w.regions, None);
            // The frame at 0 s is made with the simulation, before a selector can be given.
            let spans = if t == 0.0 {
                vec![Region::whole(p.width, p.height)]
            } else {
                chosen.clone().expect("a scan at every frame's instant")
            };
            assert_eq!(p.regions, (t > 0.0).then(|| spans.clone()), "frame at {t} s: the regions of its scan");
            for v in 0..p.height {
                for u in 0..p.width {
                    let inside = spans.iter().any(|r| r.contains(u, v));
                    let expected = if inside { (w.rgb_at(u, v), w.instance_at(u, v)) } else { ([0; 3], 0) };
                    assert_eq!(
                        (p.rgb_at(u, v), p.instance_at(u, v)),
                        expected,
                        "pixel ({u}, {v}), inside the regions: {inside}"
                    );
                }
            }
        }
    }
    // Regions the image does not have stop the camera, not the run.
    let mut s = Simulation::new(&world, &config, 5).unwrap();
    s.render_camera_regions(Box::new(|_, _| vec![Region { columns: (600, 700), rows: (0, 10) }]));
    let mut events = 0;
    while s.next_event().is_some() {
        events += 1;
    }
    assert!(events > 40 && s.camera_error().is_some_and(|e| e.contains("600..700")), "{:?}", s.camera_error());
}

/// A world's `mesh` file is what the camera renders for its object, in the object's class;
/// the shape stays the collider, so the laser sees the same.
#[test]
fn an_objects_mesh_file_is_what_the_camera_renders_and_its_shape_what_the_laser_sees() {
    use worlds::*;
    let dir = std::env::temp_dir().join(format!("objslam-mesh-world-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let look = |material| Appearance { material, colour: [0.4, 0.3, 0.2], texture_seed: 1 };
    let tree = StaticObject {
        id: 7,
        class: ObjectClass::Tree,
        pose: Pose2 { x: 4.0, y: 0.0, yaw_deg: 0.0 },
        shape: Shape::Trunk { radius_m: 0.2, height_m: 2.5, canopy_radius_m: 1.5, canopy_height_m: 2.0 },
        appearance: look(Material::Bark),
        mesh: None,
        mesh_data: Default::default(),
    };
    let world = World {
        format_version: WORLD_FORMAT_VERSION,
        name: "mesh".into(),
        seed: 0,
        ground: Ground { min_m: [-20.0, -20.0], max_m: [20.0, 20.0], appearance: look(Material::Grass) },
        objects: vec![tree.clone()],
        people: vec![],
        robot: RobotSpec {
            start: Pose2 { x: 0.0, y: 0.0, yaw_deg: 0.0 },
            route: Route { waypoints: vec![[0.0, 0.0], [0.0, 3.0]], looping: false },
            laps: 1,
        },
    };
    // The user's mesh: a 1.6 m wide, 1 m high box in the object's frame.
    let block = StaticObject {
        shape: Shape::Wall { length_m: 1.6, thickness_m: 1.6, height_m: 1.0 },
        pose: Pose2 { x: 0.0, y: 0.0, yaw_deg: 0.0 },
        ..tree.clone()
    };
    std::fs::write(dir.join("block.glb"), gltf_io::parts_to_glb(&mesh::object_parts(&block))).unwrap();
    let mut with_mesh = world.clone();
    with_mesh.objects[0].mesh = Some("block.glb".into());
    save(&with_mesh, &dir.join("world.toml")).unwrap();
    let with_mesh = load(&dir.join("world.toml")).unwrap();
    assert_eq!(with_mesh.objects[0].mesh.as_deref(), Some("block.glb"));

    let mut config = SimConfig { max_duration_s: Some(0.3), ..Default::default() };
    config.camera.width = 320;
    config.camera.height = 240;
    // The first frame's pixels of the tree, by class, and the first scan's nearest return.
    let observe = |w: &World| {
        let mut s = Simulation::new(w, &config, 3).unwrap();
        let (mut classes, mut nearest) = (std::collections::BTreeMap::new(), None);
        while let Some(e) = s.next_event() {
            match e {
                SensorEvent::Camera { frame, .. } if classes.is_empty() => {
                    for (i, &id) in frame.image.instance.iter().enumerate() {
                        if id == 7 {
                            *classes.entry(frame.image.class[i]).or_insert(0usize) += 1;
                        }
                    }
                }
                SensorEvent::Laser { beams, .. } if nearest.is_none() => {
                    nearest = beams.true_ranges.iter().copied().filter(|r| r.is_finite()).reduce(f64::min);
                }
                _ => {}
            }
        }
        (classes, nearest.unwrap())
    };
    let (procedural, laser) = observe(&world);
    let (user, laser_with_mesh) = observe(&with_mesh);
    let (tree_class, foliage) = (ObjectClass::Tree.id(), ObjectClass::Foliage.id());
    assert!(procedural.get(&foliage).is_some_and(|n| *n > 0), "{procedural:?}");
    assert_eq!(user.keys().copied().collect::<Vec<_>>(), [tree_class], "{user:?}");
    let (a, b) = (procedural.values().sum::<usize>() as f64, user[&tree_class] as f64);
    assert!((a - b).abs() > 0.2 * a.max(b), "the mesh changed the tree's pixels: {a} and {b}");
    assert_eq!(laser, laser_with_mesh, "the collider is the shape either way");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The exposure's and the pixel noise's draws are taken whatever their spreads, so a
/// spread of 0 leaves the other's stream the same (common random numbers across a study's
/// values): a spread too small to change an image gives the same images as none.
#[test]
fn a_camera_spread_of_zero_leaves_the_other_noise_alone() {
    let world = worlds::generate::park(&Default::default(), 2006).unwrap();
    let images = |exposure_sigma: f64, noise_sigma: f64| {
        let mut config = SimConfig { max_duration_s: Some(0.6), ..Default::default() };
        config.camera.noise_sigma = noise_sigma;
        config.camera.exposure_sigma = exposure_sigma;
        let mut s = Simulation::new(&world, &config, 5).unwrap();
        let mut out = Vec::new();
        while let Some(e) = s.next_event() {
            if let SensorEvent::Camera { frame, .. } = e {
                out.push(frame.image.rgb.clone());
            }
        }
        out
    };
    let no_exposure = images(0.0, 2.0);
    assert!(no_exposure.len() >= 2);
    assert!(images(1e-12, 2.0) == no_exposure, "the pixel noise moved with the exposure's spread");
    let no_noise = images(0.2, 0.0);
    assert!(images(0.2, 1e-12) == no_noise, "the exposures moved with the pixel noise's spread");
}
