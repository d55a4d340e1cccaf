//! Validation: a world that loads is one the simulator can run without surprises.

use std::collections::HashMap;
use std::path::Path;

use crate::description::{Footprint, Material, ObjectClass, Shape, WORLD_FORMAT_VERSION, World};
use crate::error::Problem;

/// Tallest person a world may hold (the tallest people measured are about 2.7 m).
pub const MAX_PERSON_HEIGHT_M: f64 = 2.75;
/// Fastest a person may walk (a sprinter's top speed is about 12 m/s).
pub const MAX_PERSON_SPEED_MPS: f64 = 12.0;

/// Instance id reserved for the ground in instance images.
pub const GROUND_INSTANCE_ID: u16 = u16::MAX;

/// Largest board tilt accepted (deg): steeper boards are nearly flat on the ground.
pub const MAX_BOARD_TILT_DEG: f64 = 80.0;

/// Clearance the robot's route keeps from obstacle footprints: half the Pioneer 2-AT's
/// diagonal (0.63 x 0.50 m body) is 0.40 m, plus a margin for path-following error.
pub const ROBOT_ROUTE_CLEARANCE_M: f64 = 0.5;
/// Clearance of people's routes from obstacles (a walking person's half width).
pub const PERSON_ROUTE_CLEARANCE_M: f64 = 0.3;

/// Farthest from the origin (m, in x or y) that the ground and objects may reach. The
/// physics works in f32, whose spacing is at most 61 µm (2^-14 m) within 1,024 m of the
/// origin: under a tenth of the laser's 1 mm range step and about 1% of the 5 mm the robot
/// moves in a 10 ms physics step at its 0.5 m/s cruise. Far beyond, positions round to
/// millimetres, and by 100 km a step rounds away and the robot never moves.
pub const MAX_COORDINATE_M: f64 = 1_000.0;

/// Largest size of an object (m): a world reaches at most [`MAX_COORDINATE_M`] either
/// way from the origin, so nothing in it is longer than its whole width. Larger is a typo
/// or another unit, and past f32's range an exported mesh holds infinities.
pub const MAX_SIZE_M: f64 = 2.0 * MAX_COORDINATE_M;

/// Most squares along a checkerboard's side: a calibration board has about ten; past a
/// hundred its corners, 4 pixels apart at most ranges, could not be found.
pub const MAX_BOARD_SQUARES: u32 = 100;

/// Latest a person may start walking (s): about eleven days, past any run's length; a
/// later start is a typo or another unit (milliseconds).
pub const MAX_START_TIME_S: f64 = 1e6;

/// Shortest side of the ground (m): the Pioneer 2-AT, 0.63 m long, must stand on it.
pub const MIN_GROUND_SIDE_M: f64 = 1.0;

/// Checks a world; `base_dir` resolves relative mesh paths. Returns every problem found.
pub fn validate(world: &World, base_dir: &Path) -> Vec<Problem> {
    let mut out = Vec::new();
    let mut push = |field: String, message: String| out.push(Problem { field, line: None, message });

    if world.format_version != WORLD_FORMAT_VERSION {
        push(
            "format_version".into(),
            format!("unsupported version {} (this build reads {WORLD_FORMAT_VERSION})", world.format_version),
        );
    }
    let g = &world.ground;
    if !(g.max_m[0] > g.min_m[0] && g.max_m[1] > g.min_m[1])
        || !all_finite(&[g.min_m[0], g.min_m[1], g.max_m[0], g.max_m[1]])
    {
        push("ground".into(), "max_m must be greater than min_m in x and y".into());
    } else if (g.max_m[0] - g.min_m[0]).min(g.max_m[1] - g.min_m[1]) < MIN_GROUND_SIDE_M {
        push(
            "ground".into(),
            format!(
                "a ground of {} x {} m: each side must be at least {MIN_GROUND_SIDE_M} m for the robot (0.63 x 0.50 m) to stand on it",
                g.max_m[0] - g.min_m[0],
                g.max_m[1] - g.min_m[1]
            ),
        );
    } else if let Some(c) = [g.min_m[0], g.min_m[1], g.max_m[0], g.max_m[1]].iter().find(|c| c.abs() > MAX_COORDINATE_M)
    {
        push("ground".into(), far_from_origin(*c));
    }
    check_colour(&mut push, "ground.appearance.colour", &g.appearance.colour);

    let mut ids: HashMap<u16, String> = HashMap::new();
    let mut check_id = |push: &mut dyn FnMut(String, String), id: u16, field: String| {
        if id == 0 || id == GROUND_INSTANCE_ID {
            push(field.clone(), format!("id {id} is reserved (0 = nothing, {GROUND_INSTANCE_ID} = ground)"));
        } else if let Some(prev) = ids.insert(id, field.clone()) {
            push(field, format!("id {id} is already used by {prev}"));
        }
    };

    // Where an object stands and how large it is are known only when its pose and sizes
    // are sound: one NaN is its own error, not a cascade of overlaps and clearances.
    let placed = |o: &crate::description::StaticObject| {
        all_finite(&[o.pose.x, o.pose.y, o.pose.yaw_deg])
            && shape_sizes(&o.shape).iter().all(|(_, v)| size_ok(*v))
            && board_placement_ok(&o.shape)
    };
    for (i, o) in world.objects.iter().enumerate() {
        let f = format!("objects[{i}]");
        check_id(&mut push, o.id, format!("{f}.id"));
        if !all_finite(&[o.pose.x, o.pose.y, o.pose.yaw_deg]) {
            push(format!("{f}.pose"), "pose must be finite".into());
        } else if let Some(c) = [o.pose.x, o.pose.y].iter().find(|c| c.abs() > MAX_COORDINATE_M) {
            push(format!("{f}.pose"), far_from_origin(*c));
        } else if o.pose.yaw_deg.abs() > 360.0 {
            // As the robot's: beyond a few turns, degrees lose the heading to rounding.
            push(
                format!("{f}.pose.yaw_deg"),
                format!("must be within a turn (-360 to 360 degrees), got {}", as_written(o.pose.yaw_deg)),
            );
        }
        for (name, v) in shape_sizes(&o.shape) {
            if !(v.is_finite() && v > 0.0) {
                push(format!("{f}.shape.{name}"), format!("must be finite and positive, got {v}"));
            } else if v > MAX_SIZE_M {
                push(format!("{f}.shape.{name}"), too_large(v));
            }
        }
        if let Shape::Board { bottom_m, squares, tilt_deg, roll_deg, .. } = o.shape {
            if !(bottom_m.is_finite() && bottom_m >= 0.0) {
                push(format!("{f}.shape.bottom_m"), format!("must be finite and >= 0, got {bottom_m}"));
            } else if bottom_m > MAX_SIZE_M {
                push(format!("{f}.shape.bottom_m"), too_large(bottom_m));
            }
            if squares[0] < 2 || squares[1] < 2 {
                push(format!("{f}.shape.squares"), "a checkerboard needs at least 2 x 2 squares".into());
            } else if squares[0].max(squares[1]) > MAX_BOARD_SQUARES {
                push(
                    format!("{f}.shape.squares"),
                    format!("{squares:?}: a checkerboard has at most {MAX_BOARD_SQUARES} squares a side"),
                );
            }
            let tilt_ok = tilt_deg.is_finite() && tilt_deg.abs() <= MAX_BOARD_TILT_DEG;
            if !tilt_ok {
                push(
                    format!("{f}.shape.tilt_deg"),
                    format!(
                        "must be within +-{MAX_BOARD_TILT_DEG} deg (a board lying flat cannot stand), got {tilt_deg}"
                    ),
                );
            }
            let roll_ok = roll_deg.is_finite() && roll_deg.abs() <= 180.0;
            if !roll_ok {
                push(format!("{f}.shape.roll_deg"), format!("must be within +-180 deg, got {roll_deg}"));
            }
            let sizes_ok = shape_sizes(&o.shape).iter().all(|(_, v)| size_ok(*v));
            if tilt_ok && roll_ok && sizes_ok && board_placement_ok(&o.shape) {
                let lowest = o.shape.board_frame().expect("a board").lowest_m();
                if lowest < 0.0 {
                    let field = if tilt_deg != 0.0 { "tilt_deg" } else { "roll_deg" };
                    push(
                        format!("{f}.shape.{field}"),
                        format!(
                            "the turned board reaches {:.3} m below the ground; raise bottom_m by at least that much",
                            -lowest
                        ),
                    );
                }
            }
        }
        let expected = expected_shape(o.class);
        if let Some(kind) = expected
            && kind != o.shape.kind()
        {
            push(
                format!("{f}.shape.kind"),
                format!("class {} needs shape kind \"{kind}\", got \"{}\"", o.class.name(), o.shape.kind()),
            );
        }
        if o.class == ObjectClass::Person || o.class == ObjectClass::Ground {
            push(
                format!("{f}.class"),
                format!("class {} is not a static object (people go in [[people]])", o.class.name()),
            );
        }
        if o.class == ObjectClass::Foliage {
            push(
                format!("{f}.class"),
                "class foliage labels canopies in class images; it is not an object class (use tree or palm)".into(),
            );
        }
        check_colour(&mut push, &format!("{f}.appearance.colour"), &o.appearance.colour);
        if let Some(mesh) = &o.mesh
            && let Err(msg) = check_mesh(base_dir, mesh)
        {
            push(format!("{f}.mesh"), msg);
        }
        if !placed(o) {
            continue;
        }
        let (lo, hi) = o.shape.footprint(&o.pose).bounds();
        if lo[0] < g.min_m[0] || lo[1] < g.min_m[1] || hi[0] > g.max_m[0] || hi[1] > g.max_m[1] {
            push(format!("{f}.pose"), "object extends beyond the ground".into());
        }
    }

    // Overlaps between static objects.
    let footprints: Vec<(usize, Footprint)> = world
        .objects
        .iter()
        .enumerate()
        .filter(|(_, o)| placed(o))
        .map(|(i, o)| (i, o.shape.footprint(&o.pose)))
        .collect();
    for (a, (i, fi)) in footprints.iter().enumerate() {
        for (j, fj) in &footprints[a + 1..] {
            let (i, j) = (*i, *j);
            if fi.gap(fj) <= 0.0 {
                push(
                    format!("objects[{j}]"),
                    format!("object {} overlaps object {} (objects[{i}])", world.objects[j].id, world.objects[i].id),
                );
            }
        }
    }

    for (i, p) in world.people.iter().enumerate() {
        let f = format!("people[{i}]");
        check_id(&mut push, p.id, format!("{f}.id"));
        for (name, v) in [
            ("speed_mps", p.speed_mps),
            ("height_m", p.height_m),
            ("hip_half_width_m", p.hip_half_width_m),
            ("leg_radius_m", p.leg_radius_m),
            ("stride_m", p.stride_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                push(format!("{f}.{name}"), format!("must be finite and positive, got {v}"));
            } else if name != "speed_mps" && name != "height_m" && v > MAX_PERSON_HEIGHT_M {
                // No part of a person, nor a step, is larger than the tallest person.
                push(
                    format!("{f}.{name}"),
                    format!("{} m is larger than a person: at most {MAX_PERSON_HEIGHT_M} m", as_written(v)),
                );
            }
        }
        if !(p.start_time_s.is_finite() && p.start_time_s >= 0.0) {
            push(format!("{f}.start_time_s"), format!("must be finite and >= 0, got {}", p.start_time_s));
        } else if p.start_time_s > MAX_START_TIME_S {
            push(
                format!("{f}.start_time_s"),
                format!("{} s is past any run: at most {MAX_START_TIME_S:e} s", as_written(p.start_time_s)),
            );
        }
        if p.height_m.is_finite() && p.height_m < 0.8 {
            push(format!("{f}.height_m"), "a person shorter than 0.8 m has no legs at the laser's height".into());
        }
        // What people are: none runs faster or stands taller (a typo, or another unit).
        if p.height_m.is_finite() && p.height_m > MAX_PERSON_HEIGHT_M {
            push(
                format!("{f}.height_m"),
                format!("{} m is taller than a person: at most {MAX_PERSON_HEIGHT_M} m", as_written(p.height_m)),
            );
        }
        if p.speed_mps.is_finite() && p.speed_mps > MAX_PERSON_SPEED_MPS {
            push(
                format!("{f}.speed_mps"),
                format!(
                    "{} m/s is faster than a person runs: at most {MAX_PERSON_SPEED_MPS} m/s",
                    as_written(p.speed_mps)
                ),
            );
        }
        check_colour(&mut push, &format!("{f}.shirt.colour"), &p.shirt.colour);
        check_colour(&mut push, &format!("{f}.trousers.colour"), &p.trousers.colour);
        // A wide person needs more room than the usual half width.
        let half_width = p.hip_half_width_m + p.leg_radius_m;
        let clearance =
            if half_width.is_finite() { PERSON_ROUTE_CLEARANCE_M.max(half_width) } else { PERSON_ROUTE_CLEARANCE_M };
        check_route(&mut push, &format!("{f}.route"), &p.route, &world.objects, &footprints, clearance);
        check_on_ground(&mut push, &format!("{f}.route.waypoints"), &p.route.waypoints, g);
    }

    let r = &world.robot;
    if !all_finite(&[r.start.x, r.start.y, r.start.yaw_deg]) {
        push("robot.start".into(), "pose must be finite".into());
    } else if r.start.yaw_deg.abs() > 360.0 {
        push(
            "robot.start.yaw_deg".into(),
            format!("must be within a turn (-360 to 360 degrees), got {}", as_written(r.start.yaw_deg)),
        );
    }
    check_on_ground(&mut push, "robot.start", &[[r.start.x, r.start.y]], g);
    if !(1..=crate::MAX_LAPS).contains(&r.laps) {
        push("robot.laps".into(), format!("must be 1 to {}, got {}", crate::MAX_LAPS, r.laps));
    } else if r.laps > 1 && !r.route.looping {
        push(
            "robot.laps".into(),
            format!("{} laps of a route that does not loop: set route.looping = true, or laps = 1", r.laps),
        );
    }
    check_route(&mut push, "robot.route", &r.route, &world.objects, &footprints, ROBOT_ROUTE_CLEARANCE_M);
    check_on_ground(&mut push, "robot.route.waypoints", &r.route.waypoints, g);
    if r.route.waypoints.len() >= 2
        && all_finite(&[r.start.x, r.start.y])
        && r.route.waypoints.iter().all(|w| all_finite(w))
    {
        // The robot drives from its start to the route's first target (the first waypoint,
        // or the second of a looping route, which returns to the first): that leg needs
        // the route's clearance too.
        let first = if r.route.looping { r.route.waypoints[1] } else { r.route.waypoints[0] };
        let start = [r.start.x, r.start.y];
        for (i, fp) in &footprints {
            let d = fp.distance_to_segment(start, first);
            if d < ROBOT_ROUTE_CLEARANCE_M {
                push(
                    "robot.start".into(),
                    format!(
                        "the drive from the start ({:.2}, {:.2}) to the route's first target ({:.2}, {:.2}) passes {d:.2} m from object {} (needs {ROBOT_ROUTE_CLEARANCE_M:.2} m clearance)",
                        start[0], start[1], first[0], first[1], world.objects[*i].id
                    ),
                );
            }
        }
    }
    for (i, fp) in footprints.iter().filter(|_| all_finite(&[r.start.x, r.start.y])) {
        if fp.distance_to_point([r.start.x, r.start.y]) < ROBOT_ROUTE_CLEARANCE_M {
            push("robot.start".into(), format!("robot starts inside or touching object {}", world.objects[*i].id));
        }
    }
    out
}

/// Why a coordinate beyond [`MAX_COORDINATE_M`] is refused, and what to do.
fn far_from_origin(c: f64) -> String {
    format!(
        "{} m is more than {MAX_COORDINATE_M} m from the origin, where the simulator's f32 physics no longer \
         resolves a robot's motion; move the world's coordinates to a local origin",
        as_written(c)
    )
}

/// Why a size beyond [`MAX_SIZE_M`] is refused.
fn too_large(v: f64) -> String {
    format!(
        "{} m is larger than a world within {MAX_COORDINATE_M} m of the origin: at most {MAX_SIZE_M} m",
        as_written(v)
    )
}

/// A number (a length, a time, an angle) as written in a message: in full up to a million,
/// then in exponent form (a typo of 1e300 m would otherwise print as 301 digits).
pub(crate) fn as_written(v: f64) -> String {
    if v.abs() < 1e6 { v.to_string() } else { format!("{v:e}") }
}

/// A size an object may have: finite, positive and at most [`MAX_SIZE_M`].
fn size_ok(v: f64) -> bool {
    v.is_finite() && v > 0.0 && v <= MAX_SIZE_M
}

/// Whether a board's placement (its bottom, tilt and roll) is sound, so that its footprint
/// is known; true for the other shapes.
fn board_placement_ok(shape: &Shape) -> bool {
    match *shape {
        Shape::Board { bottom_m, tilt_deg, roll_deg, .. } => {
            bottom_m.is_finite()
                && (0.0..=MAX_SIZE_M).contains(&bottom_m)
                && tilt_deg.is_finite()
                && tilt_deg.abs() <= MAX_BOARD_TILT_DEG
                && roll_deg.is_finite()
                && roll_deg.abs() <= 180.0
        }
        _ => true,
    }
}

/// Refuses `points` off the ground: nothing stands or drives there.
fn check_on_ground(
    push: &mut dyn FnMut(String, String),
    field: &str,
    points: &[[f64; 2]],
    g: &crate::description::Ground,
) {
    if let Some((k, p)) = points.iter().enumerate().find(|(_, p)| {
        all_finite(&p[..]) && !(p[0] >= g.min_m[0] && p[0] <= g.max_m[0] && p[1] >= g.min_m[1] && p[1] <= g.max_m[1])
    }) {
        let at = if points.len() > 1 { format!("[{k}]") } else { String::new() };
        push(
            format!("{field}{at}"),
            format!(
                "({:.2}, {:.2}) lies off the ground ({:.2}, {:.2}) to ({:.2}, {:.2})",
                p[0], p[1], g.min_m[0], g.min_m[1], g.max_m[0], g.max_m[1]
            ),
        );
    }
}

fn check_route(
    push: &mut dyn FnMut(String, String),
    field: &str,
    route: &crate::description::Route,
    objects: &[crate::description::StaticObject],
    footprints: &[(usize, Footprint)],
    clearance: f64,
) {
    if route.waypoints.len() < 2 {
        push(format!("{field}.waypoints"), "a route needs at least 2 waypoints".into());
        return;
    }
    if route.waypoints.iter().any(|w| !all_finite(w)) {
        push(format!("{field}.waypoints"), "waypoints must be finite".into());
        return;
    }
    if route.length_m() <= 0.0 {
        push(format!("{field}.waypoints"), "the route has no length: its waypoints are all one point".into());
    }
    for (k, (a, b)) in route.segments().iter().enumerate() {
        for (i, fp) in footprints {
            let d = fp.distance_to_segment(*a, *b);
            if d < clearance {
                push(
                    format!("{field}.waypoints[{k}]"),
                    format!(
                        "segment {k} ({:.2}, {:.2}) -> ({:.2}, {:.2}) passes {d:.2} m from object {} (needs {clearance:.2} m clearance)",
                        a[0], a[1], b[0], b[1], objects[*i].id
                    ),
                );
            }
        }
    }
}

fn expected_shape(class: ObjectClass) -> Option<&'static str> {
    match class {
        ObjectClass::Tree => Some("trunk"),
        ObjectClass::Palm => Some("palm"),
        ObjectClass::Post => Some("post"),
        ObjectClass::Wall => Some("wall"),
        ObjectClass::Checkerboard => Some("board"),
        ObjectClass::Ground | ObjectClass::Person | ObjectClass::Foliage => None,
    }
}

fn shape_sizes(shape: &Shape) -> Vec<(&'static str, f64)> {
    match *shape {
        Shape::Trunk { radius_m, height_m, canopy_radius_m, canopy_height_m } => vec![
            ("radius_m", radius_m),
            ("height_m", height_m),
            ("canopy_radius_m", canopy_radius_m),
            ("canopy_height_m", canopy_height_m),
        ],
        Shape::Palm { radius_m, height_m, crown_radius_m } => {
            vec![("radius_m", radius_m), ("height_m", height_m), ("crown_radius_m", crown_radius_m)]
        }
        Shape::Post { radius_m, height_m } => vec![("radius_m", radius_m), ("height_m", height_m)],
        Shape::Wall { length_m, thickness_m, height_m } => {
            vec![("length_m", length_m), ("thickness_m", thickness_m), ("height_m", height_m)]
        }
        Shape::Board { width_m, height_m, .. } => vec![("width_m", width_m), ("height_m", height_m)],
    }
}

fn check_colour(push: &mut dyn FnMut(String, String), field: &str, c: &[f64; 3]) {
    if c.iter().any(|v| !(0.0..=1.0).contains(v)) {
        push(field.into(), format!("colour components must be in [0, 1], got {c:?}"));
    }
}

fn check_mesh(base_dir: &Path, mesh: &str) -> Result<(), String> {
    let path = base_dir.join(mesh);
    if !path.exists() {
        return Err(format!("mesh file {} does not exist", path.display()));
    }
    crate::gltf_io::import_mesh(&path)
        .map(|_| ())
        .map_err(|e| format!("{} is not a readable glTF/.glb mesh: {e}", path.display()))
}

fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Finds the 1-based line where `field` (e.g. `objects[3].shape.radius_m`) is defined in
/// `text`, by locating the n-th `[[objects]]` table and then the key inside it.
pub fn locate_line(text: &str, field: &str) -> Option<usize> {
    let (head, rest) = match field.split_once('[') {
        Some((h, r)) => (h, r),
        None => {
            let key = field.split('.').next()?;
            return text
                .lines()
                .position(|l| {
                    let t = without_comment(l);
                    t == format!("[{key}]") || t.starts_with(&format!("{key} ")) || t.starts_with(&format!("{key}="))
                })
                .map(|i| i + 1);
        }
    };
    if head.contains('.') {
        // Nested arrays (robot.route.waypoints[k]): point at the parent table.
        let table = head.rsplit_once('.').map(|(t, _)| t)?;
        return text.lines().position(|l| without_comment(l) == format!("[{table}]")).map(|i| i + 1);
    }
    let (idx, tail) = rest.split_once(']')?;
    let idx: usize = idx.parse().ok()?;
    let header = format!("[[{head}]]");
    let start = text.lines().enumerate().filter(|(_, l)| without_comment(l) == header).nth(idx)?.0;
    let key = tail.trim_start_matches('.').split('.').next_back().filter(|k| !k.is_empty());
    if let Some(key) = key {
        for (i, l) in text.lines().enumerate().skip(start + 1) {
            let t = without_comment(l);
            if t.starts_with("[[") && !t.starts_with(&format!("[[{head}.")) {
                break;
            }
            if t.starts_with(&format!("{key} "))
                || t.starts_with(&format!("{key}="))
                || t.contains(&format!(" {key} ="))
                || t.contains(&format!("{{ {key} ="))
            {
                return Some(i + 1);
            }
        }
    }
    Some(start + 1)
}

/// A line of TOML trimmed, and a table header without its comment, for matching headers
/// and keys (`[[objects]]  # the big oak` is the header `[[objects]]`; a world's table
/// names hold no `#`). Key lines are matched by their start and keep their comments.
fn without_comment(line: &str) -> &str {
    let t = line.trim();
    if t.starts_with('[') { t.split('#').next().unwrap_or(t).trim_end() } else { t }
}

/// Materials that make sense for each class; used by the generator and by docs.
pub fn default_material(class: ObjectClass) -> Material {
    match class {
        ObjectClass::Tree => Material::Bark,
        ObjectClass::Palm => Material::PalmBark,
        ObjectClass::Post => Material::Paint,
        ObjectClass::Wall => Material::Brick,
        ObjectClass::Person => Material::Clothes,
        ObjectClass::Ground => Material::Grass,
        ObjectClass::Checkerboard => Material::Checker,
        ObjectClass::Foliage => Material::Foliage,
    }
}
