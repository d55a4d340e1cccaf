//! Every kind of bad world file gets a clear error naming the file, the line or field and
//! the problem — never a panic.

use std::path::{Path, PathBuf};

use worlds::{
    WorldError,
    generate::{ParkParams, park},
};

fn good_text() -> String {
    park(&ParkParams::default(), 11).unwrap().to_toml()
}

fn parse(text: &str) -> Result<worlds::World, WorldError> {
    worlds::parse(text, Path::new("/tmp/objslam-test/bad_world.toml"))
}

fn message(text: &str) -> String {
    let err = parse(text).expect_err("world should be rejected");
    let msg = err.to_string();
    assert!(msg.contains("bad_world.toml"), "error does not name the file: {msg}");
    msg
}

#[test]
fn good_world_parses() {
    parse(&good_text()).unwrap();
}

#[test]
fn syntax_error_names_line() {
    let text = good_text().replacen("[ground]", "[ground", 1);
    let msg = message(&text);
    assert!(msg.contains("line"), "{msg}");
}

#[test]
fn missing_field_is_named() {
    let text = good_text().replacen("speed_mps = ", "not_speed = ", 1);
    let msg = message(&text);
    assert!(msg.contains("speed_mps") || msg.contains("not_speed"), "{msg}");
    assert!(msg.contains("line"), "{msg}");
}

#[test]
fn unknown_class_is_named() {
    let text = good_text().replacen("class = \"post\"", "class = \"lamppost\"", 1);
    let msg = message(&text);
    assert!(msg.contains("lamppost") && msg.contains("line"), "{msg}");
}

#[test]
fn negative_size_is_named() {
    let world = park(&ParkParams::default(), 11).unwrap();
    let mut bad = world.clone();
    let i = bad.objects.iter().position(|o| o.class == worlds::ObjectClass::Tree).unwrap();
    if let worlds::Shape::Trunk { radius_m, .. } = &mut bad.objects[i].shape {
        *radius_m = -0.2;
    }
    let msg = message(&bad.to_toml());
    assert!(msg.contains(&format!("objects[{i}].shape.radius_m")) && msg.contains("positive"), "{msg}");
    let err = parse(&bad.to_toml()).unwrap_err();
    assert!(err.problems()[0].line.is_some(), "no line for {:?}", err.problems());
}

#[test]
fn zero_size_is_named() {
    let mut bad = park(&ParkParams::default(), 11).unwrap();
    let i = bad.objects.iter().position(|o| o.class == worlds::ObjectClass::Wall).unwrap();
    if let worlds::Shape::Wall { height_m, .. } = &mut bad.objects[i].shape {
        *height_m = 0.0;
    }
    let msg = message(&bad.to_toml());
    assert!(msg.contains("height_m") && msg.contains("positive"), "{msg}");
}

/// An object whose pose or size is not a number is that one error: where it stands is
/// unknown, so no overlap or clearance is claimed of it.
#[test]
fn an_object_nowhere_is_one_error_not_a_cascade() {
    let good = good_text();
    let first_x = good.find("x = ").unwrap();
    let end = first_x + good[first_x..].find('\n').unwrap();
    let text = format!("{}x = nan{}", &good[..first_x], &good[end..]);
    let err = parse(&text).unwrap_err();
    let problems: Vec<String> = err.problems().iter().map(|p| p.to_string()).collect();
    assert_eq!(problems.len(), 1, "{problems:#?}");
    assert!(problems[0].contains(".pose") && problems[0].contains("finite"), "{problems:?}");
    let mut bad = park(&ParkParams::default(), 11).unwrap();
    let i = bad.objects.iter().position(|o| o.class == worlds::ObjectClass::Tree).unwrap();
    if let worlds::Shape::Trunk { radius_m, .. } = &mut bad.objects[i].shape {
        *radius_m = f64::INFINITY;
    }
    let err = parse(&bad.to_toml()).unwrap_err();
    assert_eq!(err.problems().len(), 1, "{:#?}", err.problems());
    // So is a robot that starts nowhere.
    let mut bad = park(&ParkParams::default(), 11).unwrap();
    bad.robot.start.x = f64::NAN;
    let err = parse(&bad.to_toml()).unwrap_err();
    assert_eq!(err.problems().len(), 1, "{:#?}", err.problems());
    assert!(err.problems()[0].to_string().contains("robot.start"), "{:#?}", err.problems());
}

#[test]
fn overlapping_objects_are_named() {
    let mut bad = park(&ParkParams::default(), 11).unwrap();
    let trees: Vec<usize> =
        bad.objects.iter().enumerate().filter(|(_, o)| o.class == worlds::ObjectClass::Tree).map(|(i, _)| i).collect();
    let (a, b) = (trees[0], trees[1]);
    bad.objects[b].pose = bad.objects[a].pose;
    let msg = message(&bad.to_toml());
    assert!(msg.contains("overlaps"), "{msg}");
}

#[test]
fn route_through_obstacle_is_named() {
    let mut bad = park(&ParkParams::default(), 11).unwrap();
    let tree = bad.objects.iter().find(|o| o.class == worlds::ObjectClass::Tree).unwrap().pose;
    bad.robot.route.waypoints.insert(1, [tree.x, tree.y]);
    let msg = message(&bad.to_toml());
    assert!(msg.contains("robot.route") && msg.contains("clearance"), "{msg}");
}

#[test]
fn missing_mesh_file_is_named() {
    let mut bad = park(&ParkParams::default(), 11).unwrap();
    bad.objects[0].mesh = Some("meshes/nowhere.glb".into());
    let msg = message(&bad.to_toml());
    assert!(msg.contains("objects[0].mesh") && msg.contains("does not exist"), "{msg}");
}

#[test]
fn mesh_that_is_not_gltf_is_named() {
    let scratch = tempfile::tempdir().unwrap();
    let dir = scratch.path();
    std::fs::write(dir.join("fake.glb"), b"this is not a glTF file").unwrap();
    let mut bad = park(&ParkParams::default(), 11).unwrap();
    bad.objects[0].mesh = Some("fake.glb".into());
    let file: PathBuf = dir.join("world.toml");
    let err = worlds::parse(&bad.to_toml(), &file).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("objects[0].mesh") && msg.contains("not a readable glTF"), "{msg}");
}

#[test]
fn user_glb_mesh_loads() {
    // A world exported as .glb is a valid user mesh for an object.
    let scratch = tempfile::tempdir().unwrap();
    let dir = scratch.path();
    let mut world = park(&ParkParams::default(), 11).unwrap();
    let small = worlds::mesh::object_parts(&world.objects[1]);
    std::fs::write(dir.join("tree.glb"), worlds::gltf_io::parts_to_glb(&small)).unwrap();
    world.objects[1].mesh = Some("tree.glb".into());
    let file = dir.join("world.toml");
    std::fs::write(&file, world.to_toml()).unwrap();
    let loaded = worlds::load(&file).unwrap();
    let mesh = worlds::gltf_io::import_object_mesh(&file, loaded.objects[1].mesh.as_deref().unwrap()).unwrap();
    assert_eq!(mesh.vertex_count(), small.iter().map(|p| p.mesh.vertex_count()).sum::<usize>());
}

#[test]
fn duplicate_ids_are_named() {
    let mut bad = park(&ParkParams::default(), 11).unwrap();
    bad.objects[1].id = bad.objects[0].id;
    let msg = message(&bad.to_toml());
    assert!(msg.contains("already used"), "{msg}");
}

#[test]
fn unreadable_file_is_named() {
    let err = worlds::load(Path::new("/nonexistent/world.toml")).unwrap_err();
    assert!(err.to_string().contains("/nonexistent/world.toml"));
}

#[test]
fn bad_generator_parameters_are_named() {
    let p = ParkParams { tree_radius_m: [0.4, 0.1], ..Default::default() };
    let err = park(&p, 1).unwrap_err();
    assert!(err.to_string().contains("tree_radius_m"), "{err}");
    let crowded = ParkParams { area_m2: 120.0, trees: 400, ..Default::default() };
    assert!(park(&crowded, 1).is_err());
    // A wall range none of which fits the ground is refused; a narrow park keeps the
    // default range, its longer draws cut to the ground.
    let err = park(&ParkParams { wall_length_m: [100.0, 200.0], ..Default::default() }, 1).unwrap_err().to_string();
    assert!(err.contains("wall_length_m") && err.contains("no wall of [100.0, 200.0] m fits"), "{err}");
    park(&ParkParams { area_m2: 200.0, aspect: 1.0, trees: 4, posts: 1, people: 0, ..Default::default() }, 1).unwrap();
    // The loop's size: the message names both settings that make it.
    let err = park(&ParkParams { route_corner_radius_m: 6.5, ..Default::default() }, 1).unwrap_err().to_string();
    assert!(err.contains("route_corner_radius_m") && err.contains("route_margin_m"), "{err}");
    // A post distance of exactly d (as a study varying it sets [d, d]) is met within the
    // millimetre positions are rounded to, whatever d is.
    for d in [0.9, 0.999, 1.0, 1.0000000000001, 1.7000000000000002, 2.3999999999999995] {
        let w = park(&ParkParams { post_distance_m: [d, d], ..Default::default() }, 2006).unwrap();
        for post in w.objects.iter().filter(|o| o.class == worlds::ObjectClass::Post) {
            let gap = w
                .objects
                .iter()
                .filter(|o| o.class == worlds::ObjectClass::Tree)
                .map(|t| ((t.pose.x - post.pose.x).powi(2) + (t.pose.y - post.pose.y).powi(2)).sqrt());
            // Its own tree is d away; another may stand nearer.
            let distances: Vec<f64> = gap.collect();
            assert!(
                distances.iter().any(|g| (g - d).abs() <= 0.001),
                "post {}: no tree {d} m away: {distances:?}",
                post.id
            );
        }
    }
    let err = park(&ParkParams { person_start_time_max_s: -1.0, ..Default::default() }, 1).unwrap_err().to_string();
    assert!(err.contains("person_start_time_max_s") && err.contains("0 or more, got -1"), "{err}");
}

/// A park with one checkerboard placed in a free spot, written as TOML.
fn with_board(extra: &str) -> String {
    let mut text = park(&ParkParams::default(), 11).unwrap().to_toml();
    // The park leaves its corner free of objects and routes.
    let w = park(&ParkParams::default(), 11).unwrap();
    let (x, y) = (w.ground.min_m[0] + 1.0, w.ground.min_m[1] + 1.0);
    text.push_str(&format!(
        "\n[[objects]]\nid = 900\nclass = \"checkerboard\"\npose = {{ x = {x}, y = {y}, yaw_deg = 0.0 }}\n\
         shape = {{ kind = \"board\", width_m = 0.8, height_m = 0.6, bottom_m = 0.3, squares = [8, 6]{extra} }}\n\
         appearance = {{ material = \"checker\", colour = [0.9, 0.9, 0.9] }}\n"
    ));
    text
}

#[test]
fn boards_without_tilt_fields_parse_and_tilted_boards_round_trip() {
    let w = parse(&with_board("")).unwrap();
    let board = w.objects.iter().find(|o| o.id == 900).unwrap();
    assert!(matches!(board.shape, worlds::Shape::Board { tilt_deg: 0.0, roll_deg: 0.0, .. }));
    // Zero tilt is not written, so existing files stay byte for byte the same.
    assert!(!w.to_toml().contains("tilt_deg"));
    let w = parse(&with_board(", tilt_deg = 25.0, roll_deg = -10.0")).unwrap();
    let again = parse(&w.to_toml()).unwrap();
    assert_eq!(w, again);
    assert!(w.to_toml().contains("tilt_deg = 25.0"));
}

#[test]
fn bad_board_tilts_are_named() {
    let msg = message(&with_board(", tilt_deg = 85.0"));
    assert!(msg.contains("shape.tilt_deg") && msg.contains("80"), "{msg}");
    assert!(msg.contains("line"), "{msg}");
    let msg = message(&with_board(", roll_deg = 400.0"));
    assert!(msg.contains("shape.roll_deg"), "{msg}");
    let msg = message(&with_board(", tilt_deg = nan"));
    assert!(msg.contains("shape.tilt_deg"), "{msg}");
    // A board standing on the ground (centre 0.3 m up) turned 45 deg in its plane reaches
    // below the ground (its corners are 0.5 m from its centre): raise it.
    let msg = message(&with_board(", roll_deg = 45.0, bottom_m = 0.0").replace("bottom_m = 0.3, ", ""));
    assert!(msg.contains("shape.roll_deg") && msg.contains("below the ground"), "{msg}");
}

#[test]
fn an_array_longer_than_its_field_is_named_with_its_line() {
    // toml alone would read the first three numbers and drop the fourth.
    let text = good_text();
    let at = text.find("colour = [").expect("a coloured object");
    let end = at + text[at..].find(']').unwrap();
    let bad = format!("{}, 0.5{}", &text[..end], &text[end..]);
    let line = text[..at].matches('\n').count() + 1;
    let msg = message(&bad);
    assert!(msg.contains(&format!("line {line}: ")) && msg.contains("colour: 4 elements, more than it takes"), "{msg}");
}

/// A world whose robot or people leave the ground, whose start leg runs through an object,
/// or whose route cannot be driven as written is refused before anything runs.
#[test]
fn routes_off_the_ground_or_that_cannot_be_driven_are_named() {
    let world = park(&ParkParams::default(), 11).unwrap();
    let check = |edit: &dyn Fn(&mut worlds::World)| {
        let mut w = world.clone();
        edit(&mut w);
        message(&w.to_toml())
    };
    let beyond = world.ground.max_m[0] + 5.0;
    let m = check(&|w| w.robot.route.waypoints[1] = [beyond, 0.0]);
    assert!(m.contains("robot.route.waypoints[1]") && m.contains("lies off the ground"), "{m}");
    let m = check(&|w| (w.robot.start.x, w.robot.start.y) = (beyond, 0.0));
    assert!(m.contains("robot.start") && m.contains("lies off the ground"), "{m}");
    if let Some(p) = world.people.first() {
        let _ = p;
        let m = check(&|w| w.people[0].route.waypoints[0] = [0.0, world.ground.min_m[1] - 40.0]);
        assert!(m.contains("people[0].route.waypoints[0]") && m.contains("lies off the ground"), "{m}");
        // A person wider than the route's usual clearance needs more room.
        let m = check(&|w| w.people[0].leg_radius_m = 5.0);
        assert!(m.contains("people[0].route") && m.contains("clearance"), "{m}");
        // No person runs at 1e6 m/s or stands 100 m tall.
        let m = check(&|w| w.people[0].speed_mps = 1e6);
        assert!(m.contains("people[0].speed_mps") && m.contains("faster than a person runs"), "{m}");
        let m = check(&|w| w.people[0].height_m = 100.0);
        assert!(m.contains("people[0].height_m") && m.contains("taller than a person"), "{m}");
    }
    // A world moved 100 km from the origin: its robot's steps would round away in the
    // physics' f32 (it never moved, and scored a perfect ATE).
    let far = worlds::validate::MAX_COORDINATE_M + 1.0;
    let m = check(&|w| {
        w.ground.min_m[0] += 1e5;
        w.ground.max_m[0] += 1e5;
    });
    let shifted = world.ground.min_m[0] + 1e5;
    assert!(m.contains(&format!("ground: {shifted} m is more than 1000 m from the origin")), "{m}");
    let m = check(&|w| w.objects[0].pose.y = -far);
    assert!(m.contains("objects[0].pose") && m.contains(&format!("-{far} m is more than 1000 m")), "{m}");
    let m = check(&|w| w.robot.start.yaw_deg = 1e12);
    assert!(m.contains("robot.start.yaw_deg") && m.contains("within a turn"), "{m}");
    let m = check(&|w| w.objects[0].pose.yaw_deg = 1e300);
    assert!(m.contains("objects[0].pose.yaw_deg") && m.contains("within a turn"), "{m}");
    let m = check(&|w| {
        w.robot.route.looping = false;
        w.robot.laps = 3;
    });
    assert!(m.contains("robot.laps") && m.contains("does not loop"), "{m}");
    let m = check(&|w| {
        let p = w.robot.route.waypoints[0];
        w.robot.route.waypoints = vec![p, p];
        w.robot.route.looping = false;
    });
    assert!(m.contains("the route has no length"), "{m}");
    // The leg from the start to the first target passes through a tree put on it.
    let m = check(&|w| {
        let tree = w.objects.iter().position(|o| o.class == worlds::ObjectClass::Tree).unwrap();
        let target = if w.robot.route.looping { w.robot.route.waypoints[1] } else { w.robot.route.waypoints[0] };
        let (sx, sy) = (w.robot.start.x, w.robot.start.y);
        w.objects[tree].pose.x = 0.5 * (sx + target[0]);
        w.objects[tree].pose.y = 0.5 * (sy + target[1]);
    });
    assert!(m.contains("the drive from the start"), "{m}");
}

/// Sizes past what a world within 1 km of the origin holds are refused (a typo or another
/// unit; past f32's range an exported mesh would hold infinities), and so are people's
/// parts larger than a person, starts past any run and boards of thousands of squares.
#[test]
fn sizes_beyond_any_world_are_named() {
    let world = park(&ParkParams::default(), 11).unwrap();
    let check = |edit: &dyn Fn(&mut worlds::World)| {
        let mut w = world.clone();
        edit(&mut w);
        message(&w.to_toml())
    };
    let tree = world.objects.iter().position(|o| o.class == worlds::ObjectClass::Tree).unwrap();
    let m = check(&|w| {
        if let worlds::Shape::Trunk { height_m, .. } = &mut w.objects[tree].shape {
            *height_m = 1e39;
        }
    });
    assert!(
        m.contains(&format!("objects[{tree}].shape.height_m: 1e39 m is larger than a world")) && m.contains("2000 m"),
        "{m}"
    );
    // Where the tree stands is unknown at that size: one error, no overlaps claimed.
    assert_eq!(m.matches("\n  - ").count(), 1, "{m}");
    let m = check(&|w| w.people[0].stride_m = 1e30);
    assert!(m.contains("people[0].stride_m: 1e30 m is larger than a person"), "{m}");
    let m = check(&|w| w.people[0].start_time_s = f64::INFINITY);
    assert!(m.contains("people[0].start_time_s: must be finite and >= 0, got inf"), "{m}");
    let m = check(&|w| w.people[0].start_time_s = 1e307);
    assert!(m.contains("people[0].start_time_s: 1e307 s is past any run"), "{m}");
    // A coordinate of 1e300 is written in exponent form, not in 301 digits.
    let m = check(&|w| w.objects[0].pose.x = 1e300);
    assert!(m.contains("objects[0].pose: 1e300 m is more than 1000 m"), "{m}");
    let msg = message(&with_board("").replace("squares = [8, 6]", "squares = [4000000000, 6]"));
    assert!(msg.contains("shape.squares") && msg.contains("at most 100 squares"), "{msg}");
}

/// A board whose roll or bottom is not sound is that error alone: its footprint is unknown,
/// so no overlap or clearance is claimed of it, and a bottom below the ground is not laid
/// on a roll the file does not give.
#[test]
fn a_board_placed_nowhere_is_one_error() {
    let err = parse(&with_board(", roll_deg = nan")).unwrap_err();
    let problems: Vec<String> = err.problems().iter().map(|p| p.to_string()).collect();
    assert_eq!(problems.len(), 1, "{problems:#?}");
    assert!(problems[0].contains("shape.roll_deg"), "{problems:?}");
    let err = parse(&with_board("").replace("bottom_m = 0.3", "bottom_m = -0.3")).unwrap_err();
    let problems: Vec<String> = err.problems().iter().map(|p| p.to_string()).collect();
    assert_eq!(problems.len(), 1, "{problems:#?}");
    assert!(problems[0].contains("shape.bottom_m: must be finite and >= 0, got -0.3"), "{problems:?}");
}

/// A person walking a route of one point, and a ground the robot cannot stand on.
#[test]
fn degenerate_routes_and_grounds_are_named() {
    let world = park(&ParkParams::default(), 11).unwrap();
    let mut w = world.clone();
    let p = w.people[0].route.waypoints[0];
    w.people[0].route.waypoints = vec![p, p];
    let m = message(&w.to_toml());
    assert!(m.contains("people[0].route.waypoints: the route has no length"), "{m}");
    let mut w = world.clone();
    w.ground.max_m = [w.ground.min_m[0] + 0.5, w.ground.max_m[1]];
    let m = message(&w.to_toml());
    assert!(m.contains("ground: a ground of 0.5 x") && m.contains("at least 1 m"), "{m}");
}

/// A table header with a comment after it is still the table the line numbers count.
#[test]
fn lines_are_found_past_commented_headers() {
    let mut w = park(&ParkParams::default(), 11).unwrap();
    let tree = w.objects.iter().position(|o| o.class == worlds::ObjectClass::Tree).unwrap();
    if let worlds::Shape::Trunk { radius_m, .. } = &mut w.objects[tree].shape {
        *radius_m = -0.2;
    }
    let text = w.to_toml().replace("[[objects]]", "[[objects]]  # one of the park's");
    let plain = parse(&w.to_toml()).unwrap_err().problems()[0].line;
    let commented = parse(&text).unwrap_err().problems()[0].line;
    assert!(plain.is_some());
    assert_eq!(commented, plain);
}

/// Generator parameters that would make sizes or times past what a world holds (1e306 m
/// rounds to infinity) are refused by name; the radius named is the one given.
#[test]
fn generator_parameters_past_a_world_are_named() {
    let err = park(&ParkParams { tree_height_m: [1e306, 1e306], ..Default::default() }, 1).unwrap_err().to_string();
    assert!(err.contains("tree_height_m: 1e306 is larger than a world holds"), "{err}");
    let err = park(&ParkParams { person_start_time_max_s: 1e307, ..Default::default() }, 1).unwrap_err().to_string();
    assert!(err.contains("person_start_time_max_s") && err.contains("past any run"), "{err}");
    let err = park(&ParkParams { post_radius_m: [0.1, 1.5], ..Default::default() }, 1).unwrap_err().to_string();
    assert!(err.contains("generator parameter post_radius_m"), "{err}");
}

/// A file that never ends (a device) is refused by its size, not read until memory runs
/// out.
#[test]
fn a_world_file_larger_than_any_world_is_refused() {
    let err = worlds::load(Path::new("/dev/zero")).unwrap_err().to_string();
    assert!(err.contains("/dev/zero") && err.contains("larger than 16 MiB"), "{err}");
}
