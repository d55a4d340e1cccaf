//! `objslam world import`: a user's mesh joins a world as an object the camera renders,
//! with a collider fitted to it; bad meshes and places are errors naming them.

use std::process::Command;

fn objslam(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_objslam")).args(args).output().expect("objslam runs")
}

#[test]
fn a_mesh_joins_a_world_with_a_collider_fitted_to_it() {
    let dir = std::env::temp_dir().join(format!("objslam-world-import-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let path = |name: &str| dir.join(name).to_string_lossy().into_owned();
    // The park of seed 3, and a post 0.3 m wide and 2 m tall as the user's mesh.
    let world = worlds::generate::preset("park", None, 3).unwrap();
    worlds::save(&world, &dir.join("park.toml")).unwrap();
    let post = worlds::StaticObject {
        id: 1,
        class: worlds::ObjectClass::Post,
        pose: worlds::Pose2 { x: 0.0, y: 0.0, yaw_deg: 0.0 },
        shape: worlds::Shape::Post { radius_m: 0.3, height_m: 2.0 },
        appearance: worlds::import::default_appearance(worlds::ObjectClass::Post),
        mesh: None,
        mesh_data: Default::default(),
    };
    std::fs::write(dir.join("post.glb"), worlds::gltf_io::parts_to_glb(&worlds::mesh::object_parts(&post))).unwrap();
    // A place with a negative x, 3 m clear of the park's objects, its route and its robot.
    let s = world.robot.start;
    let clear = |x: f64, y: f64| {
        let d = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
        let to_segment = |a: [f64; 2], b: [f64; 2]| {
            let (ab, ap) = ([b[0] - a[0], b[1] - a[1]], [x - a[0], y - a[1]]);
            let t = ((ab[0] * ap[0] + ab[1] * ap[1]) / (ab[0] * ab[0] + ab[1] * ab[1]).max(1e-12)).clamp(0.0, 1.0);
            d([x, y], [a[0] + t * ab[0], a[1] + t * ab[1]])
        };
        world.objects.iter().all(|o| d([x, y], [o.pose.x, o.pose.y]) > 3.0)
            && world.robot.route.waypoints.windows(2).all(|w| to_segment(w[0], w[1]) > 3.0)
            && d([x, y], [s.x, s.y]) > 3.0
            && world.ground.min_m[0] + 1.0 < x
            && world.ground.min_m[1] + 1.0 < y
            && y < world.ground.max_m[1] - 1.0
    };
    let (x, y) = (1..20)
        .flat_map(|i| (-20..20).map(move |j| (-0.5 * i as f64, 0.5 * j as f64)))
        .find(|&(x, y)| clear(x, y))
        .expect("a clear place");
    let at = format!("{x},{y}");
    let out = objslam(&[
        "world",
        "import",
        &path("post.glb"),
        "--world",
        &path("park.toml"),
        "--class",
        "post",
        "--at",
        &at,
        "--out",
        &path("with_post.toml"),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let imported = worlds::load(&dir.join("with_post.toml")).unwrap();
    assert_eq!(imported.objects.len(), world.objects.len() + 1);
    let added = imported.objects.last().unwrap();
    assert_eq!(added.mesh.as_deref(), Some("post.glb"), "named relative to the world file");
    assert!(added.mesh_data.0.is_some(), "loading reads the mesh");
    let worlds::Shape::Post { radius_m, height_m } = added.shape else { panic!("{:?}", added.shape) };
    assert!((radius_m - 0.3).abs() < 0.01 && (height_m - 2.0).abs() < 1e-6, "{:?}", added.shape);
    assert!(imported.objects[..world.objects.len()].iter().zip(&world.objects).all(|(a, b)| a == b));

    // Refusals name the problem, and write nothing.
    for (args, expect) in [
        (["--class", "person", "--at", "0,0"].map(String::from), "cannot import a mesh as a person"),
        (["--class", "post", "--at", "3"].map(String::from), "--at takes X,Y"),
        (["--class", "post", "--at", "-1,x"].map(String::from), "--at takes X,Y"),
        (
            ["--class", "post", "--at", &format!("{},{}", s.x, s.y)].map(String::from),
            "robot starts inside or touching object",
        ),
    ] {
        let (mesh, base, refused) = (path("post.glb"), path("park.toml"), path("refused.toml"));
        let mut call = vec!["world", "import", &mesh, "--world", &base];
        call.extend(args.iter().map(String::as_str));
        call.extend(["--out", &refused]);
        let out = objslam(&call);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(expect), "{args:?}: {err}");
        assert!(!dir.join("refused.toml").exists());
    }
    // Written elsewhere, the world still finds the meshes it names.
    std::fs::create_dir_all(dir.join("elsewhere")).unwrap();
    let (x2, y2) = (1..20)
        .flat_map(|i| (-20..20).map(move |j| (-0.5 * i as f64, 0.5 * j as f64)))
        .find(|&(u, v)| clear(u, v) && (u - x).hypot(v - y) > 3.0)
        .expect("a second clear place");
    let out = objslam(&[
        "world",
        "import",
        &path("post.glb"),
        "--world",
        &path("with_post.toml"),
        "--class",
        "post",
        "--at",
        &format!("{x2},{y2}"),
        "--out",
        &path("elsewhere/two.toml"),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let two = worlds::load(&dir.join("elsewhere/two.toml")).unwrap();
    let meshes: Vec<_> = two.objects.iter().filter(|o| o.mesh.is_some()).collect();
    assert_eq!(meshes.len(), 2);
    assert!(meshes.iter().all(|o| o.mesh_data.0.is_some()), "both meshes found from the new file");

    // No command writes over a file it reads: the mesh (as MESH or named by the world) or
    // the generator's parameters.
    let mesh_bytes = std::fs::read(dir.join("post.glb")).unwrap();
    std::fs::write(dir.join("params.toml"), "trees = 5\n").unwrap();
    let (mesh, with_post, params) = (path("post.glb"), path("with_post.toml"), path("params.toml"));
    for (call, expect) in [
        (
            vec!["world", "import", &mesh, "--world", &with_post, "--class", "post", "--at", "0,0", "--out", &mesh],
            "it is the MESH given",
        ),
        (vec!["world", "export", &with_post, "--out", &mesh], "it is the mesh of object"),
        (vec!["world", "plot", &with_post, "--out", &mesh], "it is the mesh of object"),
        (vec!["world", "generate", "--params", &params, "--out", &params], "it is the --params file given"),
    ] {
        let out = objslam(&call);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(expect), "{call:?}: {err}");
    }
    assert_eq!(std::fs::read(dir.join("post.glb")).unwrap(), mesh_bytes, "the mesh is kept");

    // Nor over a buffer file that a JSON glTF mesh names (the .glb's chunks split into a
    // .gltf and its .bin), given as MESH or named by the world.
    let json_len = u32::from_le_bytes(mesh_bytes[12..16].try_into().unwrap()) as usize;
    let mut gltf: serde_json::Value = serde_json::from_slice(&mesh_bytes[20..20 + json_len]).unwrap();
    let bin = &mesh_bytes[20 + json_len + 8..];
    let bin_len = u32::from_le_bytes(mesh_bytes[20 + json_len..24 + json_len].try_into().unwrap()) as usize;
    gltf["buffers"] = serde_json::json!([{"uri": "post.bin", "byteLength": bin_len}]);
    std::fs::write(dir.join("post.gltf"), serde_json::to_vec(&gltf).unwrap()).unwrap();
    std::fs::write(dir.join("post.bin"), &bin[..bin_len]).unwrap();
    let (gltf_mesh, buffer, with_gltf) = (path("post.gltf"), path("post.bin"), path("with_gltf.toml"));
    let place = format!("{x},{y}");
    let base = path("park.toml");
    let out = objslam(&[
        "world", "import", &gltf_mesh, "--world", &base, "--class", "post", "--at", &place, "--out", &with_gltf,
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for (call, expect) in [
        (
            vec!["world", "import", &gltf_mesh, "--world", &base, "--class", "post", "--at", &place, "--out", &buffer],
            "it is the buffer file of MESH given",
        ),
        (
            vec!["world", "import", &mesh, "--world", &with_gltf, "--class", "post", "--at", "0,0", "--out", &buffer],
            "it is the buffer of the mesh of object",
        ),
    ] {
        let out = objslam(&call);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(expect), "{call:?}: {err}");
    }
    assert_eq!(std::fs::read(dir.join("post.bin")).unwrap(), &bin[..bin_len], "the buffer is kept");
    assert_eq!(std::fs::read_to_string(dir.join("params.toml")).unwrap(), "trees = 5\n", "the parameters are kept");

    // A scenario on that world: its run's outputs score as a log (their world.toml finds
    // the meshes), and the scenario its metadata.json records runs the run again from
    // another directory.
    let scenario = "name = \"with_posts\"\n[world]\nfile = \"elsewhere/two.toml\"\n[sim]\nmax_duration_s = 8.0\n";
    std::fs::write(dir.join("with_posts.toml"), scenario).unwrap();
    let run = path("run");
    // 8 s do not finish the route, so the run fails its criteria (exit 1), outputs written.
    let said = |o: &std::process::Output| {
        format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
    };
    let out = objslam(&["run", &path("with_posts.toml"), "--method", "nn", "--out", &run]);
    assert_eq!(out.status.code(), Some(1), "{}", said(&out));
    let est = format!("{run}/trajectory_est.tum");
    let out = objslam(&["score", "--log", &run, "--trajectory", &est, "--out", &path("scored")]);
    assert!(out.status.code().is_some_and(|c| c <= 1), "{}", said(&out));
    assert!(dir.join("scored/metrics.json").is_file(), "{}", said(&out));
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("run/metadata.json")).unwrap()).unwrap();
    let recorded: scenarios::scenario::Scenario =
        serde_json::from_value(meta["configuration"]["scenario"].clone()).unwrap();
    std::fs::create_dir_all(dir.join("rerun")).unwrap();
    std::fs::write(dir.join("rerun/again.toml"), toml::to_string(&recorded).unwrap()).unwrap();
    let again = path("again");
    let out = objslam(&["run", &path("rerun/again.toml"), "--out", &again]);
    assert_eq!(out.status.code(), Some(1), "{}", said(&out));
    let same =
        |f: &str| std::fs::read(dir.join("run").join(f)).unwrap() == std::fs::read(dir.join("again").join(f)).unwrap();
    assert!(same("trajectory_est.tum") && same("landmarks.json"), "the recorded scenario runs the run again");
    let _ = std::fs::remove_dir_all(&dir);
}
