//! Seeded procedural generators. The `park` preset builds the paper's scene (section 5):
//! about 600 m² with trees, dark look-alike posts close to some trees, palms, a wall of
//! bark-like colour, people whose walks cross the robot's path, and a robot route that
//! loops through the park twice so every tree is re-observed (loop closure).
//!
//! Same seed and parameters give the same world, byte for byte: every draw comes from one
//! `ChaCha8Rng` in a fixed order, and every generated number is rounded to a millimetre
//! (or 1/1000 of a colour level) so the TOML text is stable and round-trips exactly.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::description::*;
use crate::error::WorldError;
use crate::validate::{PERSON_ROUTE_CLEARANCE_M, ROBOT_ROUTE_CLEARANCE_M, as_written};

/// An inclusive range `[min, max]` of a generator parameter.
pub type Range = [f64; 2];

/// Every count and range of the `park` preset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ParkParams {
    /// Ground area in m² (the paper: about 600).
    pub area_m2: f64,
    /// Ground width / depth ratio.
    pub aspect: f64,
    pub trees: usize,
    pub tree_radius_m: Range,
    pub tree_height_m: Range,
    pub canopy_radius_m: Range,
    /// Look-alike posts; each is placed near a different tree when possible.
    pub posts: usize,
    /// Centre-to-centre distance of a post from its tree.
    pub post_distance_m: Range,
    pub post_radius_m: Range,
    pub post_height_m: Range,
    pub palms: usize,
    pub palm_radius_m: Range,
    pub palm_height_m: Range,
    /// Whether to place a wall of bark-like brick along the far side.
    pub wall: bool,
    pub wall_length_m: Range,
    pub wall_height_m: Range,
    pub people: usize,
    pub person_speed_mps: Range,
    pub person_height_m: Range,
    /// Half-length of a person's walk across the robot's route.
    pub person_walk_half_length_m: Range,
    /// Latest start time of a person's walk.
    pub person_start_time_max_s: f64,
    /// Inset of the robot's loop from the ground's edges.
    pub route_margin_m: f64,
    /// Radius of the loop's rounded corners.
    pub route_corner_radius_m: f64,
    /// Times the robot drives the loop.
    pub laps: u32,
    /// Minimum gap between static objects (posts to their tree excepted).
    pub object_gap_m: f64,
    /// Minimum gap between a post and the tree it imitates.
    pub post_tree_gap_m: f64,
    /// Minimum gap between an object and the robot's route.
    pub route_gap_m: f64,
    /// Maximum distance of trees and palms from the route, so they are seen (posts stand
    /// near their tree).
    pub max_route_distance_m: f64,
}

impl Default for ParkParams {
    fn default() -> Self {
        ParkParams {
            area_m2: 600.0,
            aspect: 1.5,
            trees: 12,
            tree_radius_m: [0.1, 0.4],
            tree_height_m: [4.0, 9.0],
            canopy_radius_m: [1.2, 2.5],
            posts: 5,
            post_distance_m: [0.5, 3.0],
            post_radius_m: [0.1, 0.3],
            post_height_m: [1.2, 2.5],
            palms: 2,
            palm_radius_m: [0.15, 0.25],
            palm_height_m: [3.0, 6.0],
            wall: true,
            wall_length_m: [8.0, 14.0],
            wall_height_m: [2.0, 3.0],
            people: 4,
            person_speed_mps: [0.8, 1.4],
            person_height_m: [1.55, 1.9],
            person_walk_half_length_m: [3.0, 6.0],
            person_start_time_max_s: 30.0,
            route_margin_m: 4.0,
            route_corner_radius_m: 2.0,
            laps: 2,
            object_gap_m: 0.8,
            post_tree_gap_m: 0.15,
            route_gap_m: 1.0,
            max_route_distance_m: 4.0,
        }
    }
}

impl ParkParams {
    /// Ground size (width along x, depth along y).
    pub fn ground_size_m(&self) -> [f64; 2] {
        let w = (self.area_m2 * self.aspect).sqrt();
        [w, self.area_m2 / w]
    }

    /// Checks the parameters are usable; names the offending field.
    pub fn check(&self) -> Result<(), WorldError> {
        let bad = |field: &str, message: String| Err(WorldError::Parameter { field: field.into(), message });
        if !(self.area_m2.is_finite() && self.area_m2 >= 100.0) {
            return bad("area_m2", format!("must be at least 100 m², got {}", self.area_m2));
        }
        if !(self.aspect.is_finite() && (0.25..=4.0).contains(&self.aspect)) {
            return bad("aspect", format!("must be in [0.25, 4], got {}", self.aspect));
        }
        // The ground is centred on the origin, and a world may reach no farther from it
        // than the simulator resolves (crate::validate::MAX_COORDINATE_M).
        let [w, d] = self.ground_size_m();
        let limit = crate::validate::MAX_COORDINATE_M;
        if w.max(d) / 2.0 > limit {
            let most = (2.0 * limit).powi(2) / self.aspect.max(1.0 / self.aspect);
            return bad(
                "area_m2",
                format!(
                    "a ground of {w:.0} x {d:.0} m reaches more than {limit} m from the origin, farther than the simulator's f32 physics resolves a robot's motion: at most {most:.0} m² at aspect {}",
                    self.aspect
                ),
            );
        }
        let ranges: [(&str, Range, f64); 13] = [
            ("tree_radius_m", self.tree_radius_m, 0.02),
            ("tree_height_m", self.tree_height_m, 0.5),
            ("canopy_radius_m", self.canopy_radius_m, 0.1),
            ("post_distance_m", self.post_distance_m, 0.1),
            ("post_radius_m", self.post_radius_m, 0.02),
            ("post_height_m", self.post_height_m, 0.5),
            ("palm_radius_m", self.palm_radius_m, 0.02),
            ("palm_height_m", self.palm_height_m, 0.5),
            ("wall_length_m", self.wall_length_m, 0.5),
            ("wall_height_m", self.wall_height_m, 0.5),
            ("person_speed_mps", self.person_speed_mps, 0.1),
            ("person_height_m", self.person_height_m, 0.8),
            ("person_walk_half_length_m", self.person_walk_half_length_m, 0.5),
        ];
        if !(self.person_start_time_max_s.is_finite() && self.person_start_time_max_s >= 0.0) {
            return bad(
                "person_start_time_max_s",
                format!("must be finite and 0 or more, got {}", self.person_start_time_max_s),
            );
        }
        for (field, r, min) in ranges {
            if !(r[0].is_finite() && r[1].is_finite() && r[0] >= min && r[1] >= r[0]) {
                return bad(field, format!("must be a range [min, max] with {min} <= min <= max, got {r:?}"));
            }
            // No size beyond what a world holds (crate::validate::MAX_SIZE_M).
            let most = if field == "person_speed_mps" { f64::INFINITY } else { crate::validate::MAX_SIZE_M };
            if r[1] > most {
                return bad(field, format!("{} is larger than a world holds: at most {most}", as_written(r[1])));
            }
        }
        if self.person_start_time_max_s > crate::validate::MAX_START_TIME_S {
            return bad(
                "person_start_time_max_s",
                format!(
                    "{} s is past any run: at most {:e} s",
                    as_written(self.person_start_time_max_s),
                    crate::validate::MAX_START_TIME_S
                ),
            );
        }
        if self.person_speed_mps[1] > crate::validate::MAX_PERSON_SPEED_MPS {
            return bad(
                "person_speed_mps",
                format!(
                    "people walk at most {} m/s, got {}",
                    crate::validate::MAX_PERSON_SPEED_MPS,
                    as_written(self.person_speed_mps[1])
                ),
            );
        }
        if self.person_height_m[1] > crate::validate::MAX_PERSON_HEIGHT_M {
            return bad(
                "person_height_m",
                format!(
                    "people are at most {} m tall, got {}",
                    crate::validate::MAX_PERSON_HEIGHT_M,
                    as_written(self.person_height_m[1])
                ),
            );
        }
        for (field, r) in [
            ("tree_radius_m", self.tree_radius_m),
            ("post_radius_m", self.post_radius_m),
            ("palm_radius_m", self.palm_radius_m),
        ] {
            if r[1] > 1.0 {
                return bad(field, format!("trunk, post and palm radii must stay under 1 m, got {r:?}"));
            }
        }
        for (field, v) in [
            ("route_margin_m", self.route_margin_m),
            ("route_corner_radius_m", self.route_corner_radius_m),
            ("object_gap_m", self.object_gap_m),
            ("post_tree_gap_m", self.post_tree_gap_m),
            ("route_gap_m", self.route_gap_m),
            ("max_route_distance_m", self.max_route_distance_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, format!("must be finite and positive, got {v}"));
            }
        }
        if self.route_gap_m < ROBOT_ROUTE_CLEARANCE_M {
            return bad("route_gap_m", format!("must be at least the robot's clearance {ROBOT_ROUTE_CLEARANCE_M} m"));
        }
        let [w, d] = self.ground_size_m();
        if 2.0 * self.route_margin_m + 2.0 * self.route_corner_radius_m >= w.min(d) {
            // Either setting may be the one to change: the message names both.
            return bad(
                "route_corner_radius_m",
                format!(
                    "with route_margin_m {} m, the loop's two margins and two corner radii ({:.1} m) do not fit the {w:.1} x {d:.1} m ground's shorter side",
                    self.route_margin_m,
                    2.0 * self.route_margin_m + 2.0 * self.route_corner_radius_m
                ),
            );
        }
        // A drawn length beyond the ground's width less a metre either side is cut to it (a
        // narrow park keeps the default range); a range all of which is longer is refused.
        if self.wall && self.wall_length_m[0] > w - 2.0 {
            return bad(
                "wall_length_m",
                format!(
                    "no wall of {:?} m fits along the {w:.1} m ground with a metre either side: at most {:.1} m",
                    self.wall_length_m,
                    w - 2.0
                ),
            );
        }
        if !(1..=crate::MAX_LAPS).contains(&self.laps) {
            return bad("laps", format!("must be 1 to {}, got {}", crate::MAX_LAPS, self.laps));
        }
        let counts = [("trees", self.trees), ("posts", self.posts), ("palms", self.palms), ("people", self.people)];
        let total = counts.iter().fold(0usize, |sum, (_, n)| sum.saturating_add(*n));
        if total > MAX_OBJECTS {
            // Named by the largest count, the likeliest typo.
            let (field, n) = counts.iter().max_by_key(|(_, n)| *n).unwrap();
            return bad(
                field,
                format!(
                    "{n} makes {total} objects and people in all: trees, posts, palms and people together at most {MAX_OBJECTS}"
                ),
            );
        }
        if self.posts > 0 && self.trees == 0 {
            return bad("posts", "posts are placed near trees: needs at least one tree".into());
        }
        Ok(())
    }
}

const ATTEMPTS: usize = 20_000;

/// Most objects and people a generated park may hold.
pub const MAX_OBJECTS: usize = 2000;

/// How far [`r3`] of both coordinates can move a point: half a millimetre each way.
const ROUNDING_M: f64 = 0.000_5 * std::f64::consts::SQRT_2;

fn r3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

fn sample(rng: &mut ChaCha8Rng, r: Range) -> f64 {
    if r[1] > r[0] { rng.random_range(r[0]..=r[1]) } else { r[0] }
}

fn colour(rng: &mut ChaCha8Rng, lo: [f64; 3], hi: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|k| r3(sample(rng, [lo[k], hi[k]])))
}

/// Generates the `park` world for `seed`.
pub fn park(params: &ParkParams, seed: u64) -> Result<World, WorldError> {
    params.check()?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let [w, d] = params.ground_size_m();
    let (min, max) = ([r3(-w / 2.0), r3(-d / 2.0)], [r3(w / 2.0), r3(d / 2.0)]);

    let route = loop_route(min, max, params.route_margin_m, params.route_corner_radius_m);
    let segs = route.segments();
    let route_distance =
        |p: [f64; 2]| segs.iter().map(|(a, b)| point_segment_distance(p, *a, *b)).fold(f64::INFINITY, f64::min);

    let mut objects: Vec<StaticObject> = Vec::new();
    let mut next_id: u16 = 1;
    let fits = |objects: &[StaticObject], fp: &Footprint, gap: f64, except: Option<u16>| {
        let (lo, hi) = fp.bounds();
        if lo[0] < min[0] + 0.2 || lo[1] < min[1] + 0.2 || hi[0] > max[0] - 0.2 || hi[1] > max[1] - 0.2 {
            return false;
        }
        objects.iter().all(|o| Some(o.id) == except || o.shape.footprint(&o.pose).gap(fp) >= gap)
    };
    let clear_of_route = |fp: &Footprint, gap: f64| segs.iter().all(|(a, b)| fp.distance_to_segment(*a, *b) >= gap);

    // Wall along the far (+y) side, between the loop and the ground's edge.
    if params.wall {
        let length = r3(sample(&mut rng, params.wall_length_m).min(w - 2.0));
        let height = r3(sample(&mut rng, params.wall_height_m));
        let thickness = 0.25;
        let y = r3(max[1] - (params.route_margin_m / 2.0).max(0.5));
        let x = r3(sample(&mut rng, [min[0] + length / 2.0 + 0.5, max[0] - length / 2.0 - 0.5]));
        let pose = Pose2 { x, y, yaw_deg: 0.0 };
        let shape = Shape::Wall { length_m: length, thickness_m: thickness, height_m: height };
        let fp = shape.footprint(&pose);
        if !clear_of_route(&fp, params.route_gap_m) || !fits(&objects, &fp, 0.0, None) {
            return Err(WorldError::Placement { what: "the wall".into(), attempts: 1 });
        }
        objects.push(StaticObject {
            id: next_id,
            class: ObjectClass::Wall,
            pose,
            shape,
            appearance: Appearance {
                material: Material::Brick,
                colour: colour(&mut rng, [0.36, 0.25, 0.18], [0.46, 0.32, 0.24]),
                texture_seed: rng.random_range(0..u32::MAX as u64),
            },
            mesh: None,
            mesh_data: Default::default(),
        });
        next_id += 1;
    }

    // Trees, then palms: anywhere within sight of the route, clear of it and each other.
    let mut place_free = |rng: &mut ChaCha8Rng,
                          objects: &mut Vec<StaticObject>,
                          class: ObjectClass,
                          what: &str|
     -> Result<(), WorldError> {
        for _ in 0..ATTEMPTS {
            let p = [r3(sample(rng, [min[0], max[0]])), r3(sample(rng, [min[1], max[1]]))];
            let (shape, appearance) = match class {
                ObjectClass::Tree => {
                    let radius = r3(sample(rng, params.tree_radius_m));
                    let height = r3(sample(rng, params.tree_height_m));
                    let canopy = r3(sample(rng, params.canopy_radius_m));
                    (
                        Shape::Trunk {
                            radius_m: radius,
                            height_m: height,
                            canopy_radius_m: canopy,
                            canopy_height_m: r3(canopy * 1.4),
                        },
                        Appearance {
                            material: Material::Bark,
                            colour: colour(rng, [0.26, 0.19, 0.13], [0.45, 0.35, 0.26]),
                            texture_seed: rng.random_range(0..u32::MAX as u64),
                        },
                    )
                }
                _ => {
                    let radius = r3(sample(rng, params.palm_radius_m));
                    let height = r3(sample(rng, params.palm_height_m));
                    (
                        Shape::Palm { radius_m: radius, height_m: height, crown_radius_m: r3(height * 0.45) },
                        Appearance {
                            material: Material::PalmBark,
                            colour: colour(rng, [0.45, 0.40, 0.30], [0.58, 0.52, 0.40]),
                            texture_seed: rng.random_range(0..u32::MAX as u64),
                        },
                    )
                }
            };
            let pose = Pose2 { x: p[0], y: p[1], yaw_deg: 0.0 };
            let fp = shape.footprint(&pose);
            let dr = route_distance(p);
            if dr > params.max_route_distance_m
                || !clear_of_route(&fp, params.route_gap_m)
                || !fits(objects, &fp, params.object_gap_m, None)
            {
                continue;
            }
            objects.push(StaticObject {
                id: next_id,
                class,
                pose,
                shape,
                appearance,
                mesh: None,
                mesh_data: Default::default(),
            });
            next_id += 1;
            return Ok(());
        }
        Err(WorldError::Placement { what: what.into(), attempts: ATTEMPTS })
    };
    for i in 0..params.trees {
        place_free(&mut rng, &mut objects, ObjectClass::Tree, &format!("tree {}", i + 1))?;
    }
    for i in 0..params.palms {
        place_free(&mut rng, &mut objects, ObjectClass::Palm, &format!("palm {}", i + 1))?;
    }

    // Posts: each near a tree (a different one while trees last), inside the distance band.
    let tree_ids: Vec<u16> = objects.iter().filter(|o| o.class == ObjectClass::Tree).map(|o| o.id).collect();
    let mut order = tree_ids.clone();
    shuffle(&mut rng, &mut order);
    for k in 0..params.posts {
        let mut placed = false;
        for attempt in 0..ATTEMPTS {
            // Try the assigned tree first; after many failures, any tree.
            let tree_id = if attempt < ATTEMPTS / 2 {
                order[k % order.len()]
            } else {
                tree_ids[rng.random_range(0..tree_ids.len())]
            };
            let tree = objects.iter().find(|o| o.id == tree_id).expect("tree id from this world");
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let dist = sample(&mut rng, params.post_distance_m);
            let p = [r3(tree.pose.x + dist * angle.cos()), r3(tree.pose.y + dist * angle.sin())];
            // Rounding each coordinate to the millimetre moves the post by up to 0.71 mm: a
            // distance within that of the range is in it (a range [d, d] is met, not missed).
            let cd = ((p[0] - tree.pose.x).powi(2) + (p[1] - tree.pose.y).powi(2)).sqrt();
            if cd < params.post_distance_m[0] - ROUNDING_M || cd > params.post_distance_m[1] + ROUNDING_M {
                continue;
            }
            let shape = Shape::Post {
                radius_m: r3(sample(&mut rng, params.post_radius_m)),
                height_m: r3(sample(&mut rng, params.post_height_m)),
            };
            let pose = Pose2 { x: p[0], y: p[1], yaw_deg: 0.0 };
            let fp = shape.footprint(&pose);
            if !clear_of_route(&fp, params.route_gap_m) {
                continue;
            }
            if tree.shape.footprint(&tree.pose).gap(&fp) < params.post_tree_gap_m
                || !fits(&objects, &fp, params.object_gap_m.min(params.post_tree_gap_m), None)
            {
                continue;
            }
            // Keep the usual gap from everything but trees (posts sit close to trees on purpose).
            if !objects
                .iter()
                .filter(|o| o.class != ObjectClass::Tree)
                .all(|o| o.shape.footprint(&o.pose).gap(&fp) >= params.object_gap_m)
            {
                continue;
            }
            let appearance = Appearance {
                material: Material::Paint,
                colour: colour(&mut rng, [0.16, 0.13, 0.10], [0.34, 0.28, 0.22]),
                texture_seed: rng.random_range(0..u32::MAX as u64),
            };
            objects.push(StaticObject {
                id: next_id,
                class: ObjectClass::Post,
                pose,
                shape,
                appearance,
                mesh: None,
                mesh_data: Default::default(),
            });
            next_id += 1;
            placed = true;
            break;
        }
        if !placed {
            return Err(WorldError::Placement { what: format!("post {}", k + 1), attempts: ATTEMPTS });
        }
    }

    // People: walks back and forth across the robot's loop.
    let footprints: Vec<Footprint> = objects.iter().map(|o| o.shape.footprint(&o.pose)).collect();
    let mut people = Vec::new();
    let route_len = route.length_m();
    for k in 0..params.people {
        let mut placed = false;
        for _ in 0..ATTEMPTS {
            let s = rng.random_range(0.0..route_len);
            let (c, heading) = route.point_at(s);
            let half = sample(&mut rng, params.person_walk_half_length_m);
            let skew = rng.random_range(-0.5..0.5);
            let dir = heading + std::f64::consts::FRAC_PI_2 + skew;
            let a = [r3(c[0] + half * dir.cos()), r3(c[1] + half * dir.sin())];
            let b = [r3(c[0] - half * dir.cos()), r3(c[1] - half * dir.sin())];
            let inside =
                |p: [f64; 2]| p[0] > min[0] + 0.5 && p[0] < max[0] - 0.5 && p[1] > min[1] + 0.5 && p[1] < max[1] - 0.5;
            if !inside(a) || !inside(b) {
                continue;
            }
            if footprints.iter().any(|fp| fp.distance_to_segment(a, b) < PERSON_ROUTE_CLEARANCE_M + 0.1) {
                continue;
            }
            let height = r3(sample(&mut rng, params.person_height_m));
            people.push(Person {
                id: next_id,
                route: Route { waypoints: vec![a, b], looping: true },
                speed_mps: r3(sample(&mut rng, params.person_speed_mps)),
                start_time_s: r3(rng.random_range(0.0..=params.person_start_time_max_s)),
                height_m: height,
                hip_half_width_m: r3(height * 0.055),
                leg_radius_m: r3(height * 0.042),
                stride_m: r3(height * 0.40),
                shirt: Appearance {
                    material: Material::Clothes,
                    colour: colour(&mut rng, [0.05, 0.05, 0.05], [0.95, 0.95, 0.95]),
                    texture_seed: rng.random_range(0..u32::MAX as u64),
                },
                trousers: Appearance {
                    material: Material::Clothes,
                    colour: colour(&mut rng, [0.05, 0.05, 0.10], [0.35, 0.35, 0.55]),
                    texture_seed: rng.random_range(0..u32::MAX as u64),
                },
            });
            next_id += 1;
            placed = true;
            break;
        }
        if !placed {
            return Err(WorldError::Placement { what: format!("person {}", k + 1), attempts: ATTEMPTS });
        }
    }

    let start = route.waypoints[0];
    let next = route.waypoints[1];
    let yaw = r3((next[1] - start[1]).atan2(next[0] - start[0]).to_degrees());
    let world = World {
        format_version: WORLD_FORMAT_VERSION,
        name: "park".into(),
        seed,
        ground: Ground {
            min_m: min,
            max_m: max,
            appearance: Appearance { material: Material::Grass, colour: [0.28, 0.42, 0.18], texture_seed: seed },
        },
        objects,
        people,
        robot: RobotSpec { start: Pose2 { x: start[0], y: start[1], yaw_deg: yaw }, route, laps: params.laps },
    };
    // The checks above keep every world valid; one that is not is refused here rather
    // than written for `objslam world check` to refuse later.
    let problems = crate::validate::validate(&world, std::path::Path::new("."));
    if !problems.is_empty() {
        return Err(WorldError::Invalid { file: format!("the generated park of seed {seed}").into(), problems });
    }
    Ok(world)
}

/// A rounded-rectangle loop inset from the ground's edges, counter-clockwise, starting in
/// the middle of the near (-y) side heading +x.
fn loop_route(min: [f64; 2], max: [f64; 2], margin: f64, corner: f64) -> Route {
    let (x0, y0, x1, y1) = (min[0] + margin, min[1] + margin, max[0] - margin, max[1] - margin);
    let mut pts = vec![[r3((x0 + x1) / 2.0), r3(y0)]];
    let corners = [
        ([x1 - corner, y0 + corner], -90.0f64),
        ([x1 - corner, y1 - corner], 0.0),
        ([x0 + corner, y1 - corner], 90.0),
        ([x0 + corner, y0 + corner], 180.0),
    ];
    for (c, a0) in corners {
        for k in 0..=4 {
            let a = (a0 + 90.0 * k as f64 / 4.0).to_radians();
            pts.push([r3(c[0] + corner * a.cos()), r3(c[1] + corner * a.sin())]);
        }
    }
    Route { waypoints: pts, looping: true }
}

/// Fisher-Yates with our own generator (rand's SliceRandom would do, but this keeps the
/// draw order explicit, which the byte-for-byte guarantee depends on).
fn shuffle(rng: &mut ChaCha8Rng, v: &mut [u16]) {
    for i in (1..v.len()).rev() {
        let j = rng.random_range(0..=i);
        v.swap(i, j);
    }
}

/// Names of the available presets.
pub const PRESETS: &[&str] = &["park"];

/// Generates a world by preset name.
pub fn preset(name: &str, params: Option<&ParkParams>, seed: u64) -> Result<World, WorldError> {
    match name {
        "park" => park(params.unwrap_or(&ParkParams::default()), seed),
        other => Err(WorldError::Parameter {
            field: "preset".into(),
            message: format!("unknown preset {other:?}; available: {}", PRESETS.join(", ")),
        }),
    }
}
