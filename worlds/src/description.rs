//! The world description: what a scene *is*, as stored in a TOML file.
//!
//! SI units and REP-103 frames throughout: x forward/east, y left/north, z up; yaw is
//! counter-clockwise about +z, stored in degrees because people edit these files by hand.

use serde::{Deserialize, Serialize};

/// Version of the world file format written by this crate.
pub const WORLD_FORMAT_VERSION: u32 = 1;

/// A whole scene: ground, static objects, walking people and the robot's route.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct World {
    pub format_version: u32,
    /// Free-form name, e.g. the preset that generated it.
    pub name: String,
    /// Seed the world was generated from (provenance only; 0 for hand-written worlds).
    #[serde(default)]
    pub seed: u64,
    pub ground: Ground,
    #[serde(default)]
    pub objects: Vec<StaticObject>,
    #[serde(default)]
    pub people: Vec<Person>,
    pub robot: RobotSpec,
}

/// The flat ground: an axis-aligned rectangle at z = 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ground {
    /// Lower-left corner (x, y) in metres.
    pub min_m: [f64; 2],
    /// Upper-right corner (x, y) in metres.
    pub max_m: [f64; 2],
    pub appearance: Appearance,
}

impl Ground {
    pub fn area_m2(&self) -> f64 {
        (self.max_m[0] - self.min_m[0]) * (self.max_m[1] - self.min_m[1])
    }
}

/// Semantic class of an object; what the scorer counts and the class image stores.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectClass {
    Ground,
    Tree,
    Palm,
    Post,
    Wall,
    Person,
    Checkerboard,
}

impl ObjectClass {
    /// Every class, in class-id order.
    pub const ALL: [ObjectClass; 7] = [
        ObjectClass::Ground,
        ObjectClass::Tree,
        ObjectClass::Palm,
        ObjectClass::Post,
        ObjectClass::Wall,
        ObjectClass::Person,
        ObjectClass::Checkerboard,
    ];

    /// Stable numeric id written into class images (0 is reserved for sky / nothing).
    pub fn id(self) -> u8 {
        match self {
            ObjectClass::Ground => 1,
            ObjectClass::Tree => 2,
            ObjectClass::Palm => 3,
            ObjectClass::Post => 4,
            ObjectClass::Wall => 5,
            ObjectClass::Person => 6,
            ObjectClass::Checkerboard => 7,
        }
    }

    pub fn from_id(id: u8) -> Option<ObjectClass> {
        Self::ALL.into_iter().find(|c| c.id() == id)
    }

    pub fn name(self) -> &'static str {
        match self {
            ObjectClass::Ground => "ground",
            ObjectClass::Tree => "tree",
            ObjectClass::Palm => "palm",
            ObjectClass::Post => "post",
            ObjectClass::Wall => "wall",
            ObjectClass::Person => "person",
            ObjectClass::Checkerboard => "checkerboard",
        }
    }

    pub fn from_name(name: &str) -> Option<ObjectClass> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }
}

/// A planar pose on the ground.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pose2 {
    pub x: f64,
    pub y: f64,
    #[serde(default)]
    pub yaw_deg: f64,
}

impl Pose2 {
    pub fn yaw_rad(&self) -> f64 {
        self.yaw_deg.to_radians()
    }
}

/// A static object: tree, palm, post, wall, ... with its shape and look.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StaticObject {
    /// Unique instance id, 1..=65535 (0 means "nothing" in instance images).
    pub id: u16,
    pub class: ObjectClass,
    pub pose: Pose2,
    pub shape: Shape,
    pub appearance: Appearance,
    /// Optional user glTF/.glb mesh replacing the procedural one for rendering; the
    /// shape still gives the collider. Relative paths are relative to the world file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
}

/// Shape parameters; the collider and the procedural mesh are built from these.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// A tree: cylindrical trunk under an ellipsoidal canopy.
    Trunk {
        radius_m: f64,
        height_m: f64,
        canopy_radius_m: f64,
        canopy_height_m: f64,
    },
    /// A palm: slightly tapering ringed trunk with a crown of fronds.
    Palm {
        radius_m: f64,
        height_m: f64,
        crown_radius_m: f64,
    },
    /// A painted post: a plain cylinder.
    Post { radius_m: f64, height_m: f64 },
    /// A wall: a box centred on the pose, `length_m` along the pose's x axis.
    Wall {
        length_m: f64,
        thickness_m: f64,
        height_m: f64,
    },
    /// A flat board standing upright (calibration target); `size_m` = (width, height),
    /// lower edge at `bottom_m` above the ground, facing the pose's +x axis.
    Board {
        width_m: f64,
        height_m: f64,
        bottom_m: f64,
        squares: [u32; 2],
    },
}

impl Shape {
    pub fn kind(&self) -> &'static str {
        match self {
            Shape::Trunk { .. } => "trunk",
            Shape::Palm { .. } => "palm",
            Shape::Post { .. } => "post",
            Shape::Wall { .. } => "wall",
            Shape::Board { .. } => "board",
        }
    }

    /// The footprint on the ground used for overlap and clearance checks.
    pub fn footprint(&self, pose: &Pose2) -> Footprint {
        match *self {
            Shape::Trunk { radius_m, .. } | Shape::Palm { radius_m, .. } | Shape::Post { radius_m, .. } => {
                Footprint::Circle { centre: [pose.x, pose.y], radius: radius_m }
            }
            Shape::Wall { length_m, thickness_m, .. } => Footprint::Rect {
                centre: [pose.x, pose.y],
                half_extents: [length_m / 2.0, thickness_m / 2.0],
                yaw: pose.yaw_rad(),
            },
            Shape::Board { width_m, .. } => Footprint::Rect {
                centre: [pose.x, pose.y],
                half_extents: [0.01, width_m / 2.0],
                yaw: pose.yaw_rad(),
            },
        }
    }

    /// Height of the top of the object above the ground.
    pub fn top_m(&self) -> f64 {
        match *self {
            Shape::Trunk { height_m, canopy_height_m, .. } => height_m + canopy_height_m * 0.5,
            Shape::Palm { height_m, .. } => height_m,
            Shape::Post { height_m, .. } => height_m,
            Shape::Wall { height_m, .. } => height_m,
            Shape::Board { height_m, bottom_m, .. } => bottom_m + height_m,
        }
    }
}

/// A 2-D region on the ground an object occupies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Footprint {
    Circle { centre: [f64; 2], radius: f64 },
    /// Oriented rectangle: half extents along its own x and y axes, rotated by `yaw` (rad).
    Rect { centre: [f64; 2], half_extents: [f64; 2], yaw: f64 },
}

impl Footprint {
    /// Euclidean distance from a point to the footprint (0 inside).
    pub fn distance_to_point(&self, p: [f64; 2]) -> f64 {
        match *self {
            Footprint::Circle { centre, radius } => (dist(centre, p) - radius).max(0.0),
            Footprint::Rect { centre, half_extents, yaw } => {
                let (s, c) = yaw.sin_cos();
                let d = [p[0] - centre[0], p[1] - centre[1]];
                let local = [c * d[0] + s * d[1], -s * d[0] + c * d[1]];
                let qx = (local[0].abs() - half_extents[0]).max(0.0);
                let qy = (local[1].abs() - half_extents[1]).max(0.0);
                (qx * qx + qy * qy).sqrt()
            }
        }
    }

    /// Distance from a line segment to the footprint (0 if they touch).
    pub fn distance_to_segment(&self, a: [f64; 2], b: [f64; 2]) -> f64 {
        match *self {
            Footprint::Circle { centre, radius } => (point_segment_distance(centre, a, b) - radius).max(0.0),
            Footprint::Rect { .. } => {
                // Sample finely along the segment: exact enough for clearance checks at
                // centimetre scale and far simpler than a segment-box distance.
                let len = dist(a, b);
                let n = ((len / 0.02).ceil() as usize).max(1);
                (0..=n)
                    .map(|i| {
                        let t = i as f64 / n as f64;
                        self.distance_to_point([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])])
                    })
                    .fold(f64::INFINITY, f64::min)
            }
        }
    }

    /// Gap between two footprints (0 if they overlap or touch).
    pub fn gap(&self, other: &Footprint) -> f64 {
        match (*self, *other) {
            (Footprint::Circle { centre: a, radius: ra }, Footprint::Circle { centre: b, radius: rb }) => {
                (dist(a, b) - ra - rb).max(0.0)
            }
            (Footprint::Circle { centre, radius }, rect @ Footprint::Rect { .. })
            | (rect @ Footprint::Rect { .. }, Footprint::Circle { centre, radius }) => {
                (rect.distance_to_point(centre) - radius).max(0.0)
            }
            (r1 @ Footprint::Rect { .. }, r2 @ Footprint::Rect { .. }) => {
                // Two rectangles are disjoint iff no corner/edge of one is inside the other:
                // the minimum over the edges of one to the other is the gap.
                let c1 = r1.corners();
                let c2 = r2.corners();
                let mut best = f64::INFINITY;
                for i in 0..4 {
                    best = best.min(r2.distance_to_segment(c1[i], c1[(i + 1) % 4]));
                    best = best.min(r1.distance_to_segment(c2[i], c2[(i + 1) % 4]));
                }
                best
            }
        }
    }

    /// Corners of a rectangle footprint (a circle's bounding square for circles).
    pub fn corners(&self) -> [[f64; 2]; 4] {
        let (centre, he, yaw) = match *self {
            Footprint::Circle { centre, radius } => (centre, [radius, radius], 0.0),
            Footprint::Rect { centre, half_extents, yaw } => (centre, half_extents, yaw),
        };
        let (s, c) = f64::sin_cos(yaw);
        let local = [[he[0], he[1]], [-he[0], he[1]], [-he[0], -he[1]], [he[0], -he[1]]];
        local.map(|[x, y]| [centre[0] + c * x - s * y, centre[1] + s * x + c * y])
    }

    /// Axis-aligned bounds (min, max).
    pub fn bounds(&self) -> ([f64; 2], [f64; 2]) {
        let cs = self.corners();
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for c in cs {
            for k in 0..2 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
        }
        (lo, hi)
    }
}

pub(crate) fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// Distance from point `p` to segment `ab`.
pub fn point_segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1]];
    let ap = [p[0] - a[0], p[1] - a[1]];
    let len2 = ab[0] * ab[0] + ab[1] * ab[1];
    let t = if len2 > 0.0 { ((ap[0] * ab[0] + ap[1] * ab[1]) / len2).clamp(0.0, 1.0) } else { 0.0 };
    dist(p, [a[0] + t * ab[0], a[1] + t * ab[1]])
}

/// Surface material: selects the procedural texture generator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Material {
    Bark,
    PalmBark,
    Foliage,
    Paint,
    Brick,
    Concrete,
    Grass,
    Clothes,
    Skin,
    Checker,
}

/// How an object looks: a material, a base colour and a seed for texture variety.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Appearance {
    pub material: Material,
    /// Base colour, linear-ish sRGB in [0, 1].
    pub colour: [f64; 3],
    /// Seed of the procedural texture, so instances of one material differ.
    #[serde(default)]
    pub texture_seed: u64,
}

/// A polyline route on the ground.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Route {
    /// Waypoints (x, y) in metres.
    pub waypoints: Vec<[f64; 2]>,
    /// Whether the route closes back to the first waypoint and repeats.
    #[serde(default)]
    pub looping: bool,
}

impl Route {
    /// Segments of the route, including the closing one for looping routes.
    pub fn segments(&self) -> Vec<([f64; 2], [f64; 2])> {
        let w = &self.waypoints;
        let mut segs: Vec<_> = w.windows(2).map(|p| (p[0], p[1])).collect();
        // A looping route closes back to its start; with two waypoints that is a
        // back-and-forth walk.
        if self.looping && w.len() >= 2 {
            segs.push((w[w.len() - 1], w[0]));
        }
        segs
    }

    /// Length of one traversal in metres.
    pub fn length_m(&self) -> f64 {
        self.segments().iter().map(|(a, b)| dist(*a, *b)).sum()
    }

    /// Point at arc length `s` along one traversal (clamped; wraps for looping routes).
    pub fn point_at(&self, s: f64) -> ([f64; 2], f64) {
        let segs = self.segments();
        if segs.is_empty() {
            return (self.waypoints.first().copied().unwrap_or([0.0, 0.0]), 0.0);
        }
        let total = self.length_m();
        let mut s = if self.looping && total > 0.0 { s.rem_euclid(total) } else { s.clamp(0.0, total) };
        let last = segs.len() - 1;
        for (k, (a, b)) in segs.iter().enumerate() {
            let l = dist(*a, *b);
            if s <= l || k == last {
                let t = if l > 0.0 { (s / l).clamp(0.0, 1.0) } else { 0.0 };
                let heading = (b[1] - a[1]).atan2(b[0] - a[0]);
                return ([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])], heading);
            }
            s -= l;
        }
        unreachable!("segments is non-empty")
    }
}

/// A walking person: a body with two legs following a route.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Person {
    pub id: u16,
    pub route: Route,
    pub speed_mps: f64,
    /// Time at which the person starts walking; before it they stand at the first waypoint.
    #[serde(default)]
    pub start_time_s: f64,
    pub height_m: f64,
    /// Half the lateral distance between the legs.
    pub hip_half_width_m: f64,
    pub leg_radius_m: f64,
    /// Step length (one foot ahead of the other at full stride).
    pub stride_m: f64,
    pub shirt: Appearance,
    pub trousers: Appearance,
}

/// The robot: where it starts and the route its controller follows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    pub start: Pose2,
    pub route: Route,
    /// Number of traversals of the route (a looping route driven twice revisits the park).
    #[serde(default = "one")]
    pub laps: u32,
}

fn one() -> u32 {
    1
}

impl World {
    /// Looks an object up by instance id.
    pub fn object(&self, id: u16) -> Option<&StaticObject> {
        self.objects.iter().find(|o| o.id == id)
    }

    /// The class of any instance id (static object or person); `None` for 0 / unknown.
    pub fn class_of(&self, id: u16) -> Option<ObjectClass> {
        if let Some(o) = self.object(id) {
            return Some(o.class);
        }
        self.people.iter().any(|p| p.id == id).then_some(ObjectClass::Person)
    }

    /// Serialises to TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a World always serialises to TOML")
    }
}
