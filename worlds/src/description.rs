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
    /// Leaves: tree canopies and palm crowns in class images. A mesh part's class, never a
    /// world object's (their instance id stays the tree's or palm's).
    Foliage,
}

impl ObjectClass {
    /// Every class, in class-id order.
    pub const ALL: [ObjectClass; 8] = [
        ObjectClass::Ground,
        ObjectClass::Tree,
        ObjectClass::Palm,
        ObjectClass::Post,
        ObjectClass::Wall,
        ObjectClass::Person,
        ObjectClass::Checkerboard,
        ObjectClass::Foliage,
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
            ObjectClass::Foliage => 8,
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
            ObjectClass::Foliage => "foliage",
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
    /// Optional user glTF/.glb mesh replacing the procedural one for rendering, in the
    /// object's frame (z up, origin on the ground at the pose), all of it in the object's
    /// class; the shape still gives the collider, so the laser sees the shape. Relative
    /// paths are relative to the world file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    /// The `mesh` file's triangles, read when the world is loaded ([`crate::parse`]): what
    /// the camera renders for this object.
    #[serde(skip)]
    pub mesh_data: LoadedMesh,
}

/// A user mesh as read from a world's `mesh` file. Worlds compare and print by their
/// description: two objects naming the same file are equal whatever was read.
#[derive(Clone, Default)]
pub struct LoadedMesh(pub Option<std::sync::Arc<crate::mesh::TriMesh>>);

impl PartialEq for LoadedMesh {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for LoadedMesh {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match &self.0 {
            Some(m) => write!(f, "LoadedMesh({} triangles)", m.indices.len() / 3),
            None => write!(f, "LoadedMesh(none)"),
        }
    }
}

impl StaticObject {
    /// A calibration checkerboard (`shape` should be a `Shape::Board`): near-white squares
    /// on the checker material, so detection sees full contrast.
    pub fn checkerboard(id: u16, pose: Pose2, shape: Shape) -> StaticObject {
        StaticObject {
            id,
            class: ObjectClass::Checkerboard,
            pose,
            shape,
            appearance: Appearance { material: Material::Checker, colour: [0.95, 0.95, 0.95], texture_seed: 0 },
            mesh: None,
            mesh_data: Default::default(),
        }
    }
}

/// Shape parameters; the collider and the procedural mesh are built from these.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// A tree: cylindrical trunk under an ellipsoidal canopy.
    Trunk { radius_m: f64, height_m: f64, canopy_radius_m: f64, canopy_height_m: f64 },
    /// A palm: slightly tapering ringed trunk with a crown of fronds.
    Palm { radius_m: f64, height_m: f64, crown_radius_m: f64 },
    /// A painted post: a plain cylinder.
    Post { radius_m: f64, height_m: f64 },
    /// A wall: a box centred on the pose, `length_m` along the pose's x axis.
    Wall { length_m: f64, thickness_m: f64, height_m: f64 },
    /// A flat board (calibration target) [`BOARD_THICKNESS_M`] thick, facing the pose's
    /// +x axis; `squares` = (across, down) checker squares. Untilted it stands upright
    /// with its lower edge `bottom_m` above the ground. It turns about its centre (which
    /// stays `bottom_m + height_m / 2` up): first by `roll_deg` about its face normal
    /// (counter-clockwise as seen from the front), then by `tilt_deg` about its horizontal
    /// width axis (positive turns the face upwards: the top leans back). See
    /// [`BoardFrame`]. A stand reaches from the ground to the board's lowest corner.
    Board {
        width_m: f64,
        height_m: f64,
        bottom_m: f64,
        squares: [u32; 2],
        #[serde(default, skip_serializing_if = "is_zero")]
        tilt_deg: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        roll_deg: f64,
    },
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// Thickness of a board (m); its front face is half of it in front of the board's centre.
pub const BOARD_THICKNESS_M: f64 = 0.02;

/// Where a board is in its object's model frame (origin on the ground at the object's
/// pose, z up): `model = centre_m + rotation * local`, with the board's local axes x = face
/// normal (out of the front face), y = across (the face's left as seen from the front),
/// z = up the board.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoardFrame {
    pub centre_m: [f64; 3],
    /// Model <- board local, row-major.
    pub rotation: [[f64; 3]; 3],
    pub width_m: f64,
    pub height_m: f64,
}

impl BoardFrame {
    pub fn new(width_m: f64, height_m: f64, bottom_m: f64, tilt_deg: f64, roll_deg: f64) -> Self {
        let (st, ct) = tilt_deg.to_radians().sin_cos();
        let (sr, cr) = roll_deg.to_radians().sin_cos();
        // Ry(-tilt) * Rx(roll): the normal (1, 0, 0) goes to (cos t, 0, sin t).
        let ry = [[ct, 0.0, -st], [0.0, 1.0, 0.0], [st, 0.0, ct]];
        let rx = [[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]];
        let rotation = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| ry[i][k] * rx[k][j]).sum()));
        BoardFrame { centre_m: [0.0, 0.0, bottom_m + height_m / 2.0], rotation, width_m, height_m }
    }

    /// A point given in board-local coordinates, in the model frame.
    pub fn apply(&self, local: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        std::array::from_fn(|i| self.centre_m[i] + r[i][0] * local[0] + r[i][1] * local[1] + r[i][2] * local[2])
    }

    /// Unit normal of the front face in the model frame.
    pub fn normal(&self) -> [f64; 3] {
        [self.rotation[0][0], self.rotation[1][0], self.rotation[2][0]]
    }

    /// The eight corners of the board's box in the model frame.
    pub fn box_corners(&self) -> [[f64; 3]; 8] {
        let (hx, hy, hz) = (BOARD_THICKNESS_M / 2.0, self.width_m / 2.0, self.height_m / 2.0);
        std::array::from_fn(|k| {
            let s = |bit: usize| if k & bit != 0 { 1.0 } else { -1.0 };
            self.apply([s(1) * hx, s(2) * hy, s(4) * hz])
        })
    }

    /// Height of the board's lowest point above the ground (negative: below it).
    pub fn lowest_m(&self) -> f64 {
        self.box_corners().iter().map(|c| c[2]).fold(f64::INFINITY, f64::min)
    }

    /// Height of the board's highest point.
    pub fn highest_m(&self) -> f64 {
        self.box_corners().iter().map(|c| c[2]).fold(f64::NEG_INFINITY, f64::max)
    }
}

impl Shape {
    /// The shape in words, for people: its kind and sizes in metres.
    pub fn describe(&self) -> String {
        match *self {
            Shape::Trunk { radius_m, height_m, canopy_radius_m, canopy_height_m } => format!(
                "a trunk of radius {radius_m:.3} m and height {height_m:.2} m under a canopy of radius {canopy_radius_m:.2} m and height {canopy_height_m:.2} m"
            ),
            Shape::Palm { radius_m, height_m, crown_radius_m } => format!(
                "a palm trunk of radius {radius_m:.3} m and height {height_m:.2} m under a crown of radius {crown_radius_m:.2} m"
            ),
            Shape::Post { radius_m, height_m } => {
                format!("a post of radius {radius_m:.3} m and height {height_m:.2} m")
            }
            Shape::Wall { length_m, thickness_m, height_m } => {
                format!("a wall {length_m:.2} m long, {thickness_m:.2} m thick and {height_m:.2} m high")
            }
            Shape::Board { width_m, height_m, .. } => format!("a board {width_m:.2} m wide and {height_m:.2} m high"),
        }
    }

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
            Shape::Board { .. } => {
                // The box's extent on the ground in the model frame, turned by the yaw.
                let corners = self.board_frame().expect("a board").box_corners();
                let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
                for c in corners {
                    for k in 0..2 {
                        lo[k] = lo[k].min(c[k]);
                        hi[k] = hi[k].max(c[k]);
                    }
                }
                let (mx, my) = ((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0);
                let (s, c) = pose.yaw_rad().sin_cos();
                Footprint::Rect {
                    centre: [pose.x + c * mx - s * my, pose.y + s * mx + c * my],
                    half_extents: [(hi[0] - lo[0]) / 2.0, (hi[1] - lo[1]) / 2.0],
                    yaw: pose.yaw_rad(),
                }
            }
        }
    }

    /// Height of the top of the object above the ground.
    pub fn top_m(&self) -> f64 {
        match *self {
            Shape::Trunk { height_m, canopy_height_m, .. } => height_m + canopy_height_m * 0.5,
            Shape::Palm { height_m, .. } => height_m,
            Shape::Post { height_m, .. } => height_m,
            Shape::Wall { height_m, .. } => height_m,
            Shape::Board { .. } => self.board_frame().expect("a board").highest_m(),
        }
    }

    /// A board's placement in its model frame; `None` for other shapes.
    pub fn board_frame(&self) -> Option<BoardFrame> {
        match *self {
            Shape::Board { width_m, height_m, bottom_m, tilt_deg, roll_deg, .. } => {
                Some(BoardFrame::new(width_m, height_m, bottom_m, tilt_deg, roll_deg))
            }
            _ => None,
        }
    }
}

/// A 2-D region on the ground an object occupies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Footprint {
    Circle {
        centre: [f64; 2],
        radius: f64,
    },
    /// Oriented rectangle: half extents along its own x and y axes, rotated by `yaw` (rad).
    Rect {
        centre: [f64; 2],
        half_extents: [f64; 2],
        yaw: f64,
    },
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
            Footprint::Rect { centre, half_extents: h, yaw } => {
                // In the rectangle's frame: 0 if the segment crosses the box, else the
                // nearest of the segment's ends to the box and the box's corners to the
                // segment (the closest pair of two disjoint convex shapes has a vertex).
                let (s, c) = yaw.sin_cos();
                let local = |p: [f64; 2]| {
                    let d = [p[0] - centre[0], p[1] - centre[1]];
                    [c * d[0] + s * d[1], -s * d[0] + c * d[1]]
                };
                let (la, lb) = (local(a), local(b));
                if segment_crosses_box(la, lb, h) {
                    return 0.0;
                }
                let to_box = |p: [f64; 2]| {
                    let q = [(p[0].abs() - h[0]).max(0.0), (p[1].abs() - h[1]).max(0.0)];
                    (q[0] * q[0] + q[1] * q[1]).sqrt()
                };
                let corners = [[-h[0], -h[1]], [h[0], -h[1]], [h[0], h[1]], [-h[0], h[1]]];
                corners
                    .iter()
                    .map(|q| point_segment_distance(*q, la, lb))
                    .chain([to_box(la), to_box(lb)])
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

/// Whether segment `ab` touches the box `|x| <= h[0], |y| <= h[1]` (Liang-Barsky clipping).
fn segment_crosses_box(a: [f64; 2], b: [f64; 2], h: [f64; 2]) -> bool {
    let (mut enter, mut exit) = (0.0f64, 1.0f64);
    for axis in 0..2 {
        let d = b[axis] - a[axis];
        if d == 0.0 {
            if a[axis].abs() > h[axis] {
                return false;
            }
        } else {
            let (t0, t1) = ((-h[axis] - a[axis]) / d, (h[axis] - a[axis]) / d);
            enter = enter.max(t0.min(t1));
            exit = exit.min(t0.max(t1));
        }
    }
    enter <= exit
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
        self.segment_iter().collect()
    }

    /// [`Route::segments`] without collecting them (people's routes are walked every
    /// physics step).
    fn segment_iter(&self) -> impl Iterator<Item = ([f64; 2], [f64; 2])> + '_ {
        let w = &self.waypoints;
        // A looping route closes back to its start; with two waypoints that is a
        // back-and-forth walk.
        let closing = (self.looping && w.len() >= 2).then(|| (w[w.len() - 1], w[0]));
        w.windows(2).map(|p| (p[0], p[1])).chain(closing)
    }

    /// Length of one traversal in metres.
    pub fn length_m(&self) -> f64 {
        self.segment_iter().map(|(a, b)| dist(a, b)).sum()
    }

    /// Point at arc length `s` along one traversal (clamped; wraps for looping routes).
    pub fn point_at(&self, s: f64) -> ([f64; 2], f64) {
        let count = self.segment_iter().count();
        if count == 0 {
            return (self.waypoints.first().copied().unwrap_or([0.0, 0.0]), 0.0);
        }
        let total = self.length_m();
        let mut s = if self.looping && total > 0.0 { s.rem_euclid(total) } else { s.clamp(0.0, total) };
        for (k, (a, b)) in self.segment_iter().enumerate() {
            let l = dist(a, b);
            if s <= l || k == count - 1 {
                let t = if l > 0.0 { (s / l).clamp(0.0, 1.0) } else { 0.0 };
                let heading = (b[1] - a[1]).atan2(b[0] - a[0]);
                return ([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])], heading);
            }
            s -= l;
        }
        unreachable!("the route has segments")
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
    /// Makes the objects' relative `mesh` paths absolute, as read from `world_file`: a
    /// copy of the world written elsewhere (a run's or a recording's `world.toml`, which
    /// `objslam score --log` reads) then still finds its meshes.
    pub fn resolve_mesh_paths(&mut self, world_file: &std::path::Path) {
        let base = world_file.parent().unwrap_or(std::path::Path::new("."));
        for o in &mut self.objects {
            if let Some(mesh) = &o.mesh
                && std::path::Path::new(mesh).is_relative()
                && let Some(absolute) =
                    std::path::absolute(base.join(mesh)).ok().and_then(|p| p.to_str().map(str::to_owned))
            {
                o.mesh = Some(absolute);
            }
        }
    }

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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn shapes_are_described_in_words() {
        assert_eq!(
            Shape::Post { radius_m: 0.1, height_m: 2.0 }.describe(),
            "a post of radius 0.100 m and height 2.00 m"
        );
        let tree =
            Shape::Trunk { radius_m: 1.0, height_m: 1.6666666666666667, canopy_radius_m: 1.0, canopy_height_m: 0.5 };
        assert!(tree.describe().starts_with("a trunk of radius 1.000 m and height 1.67 m"), "{}", tree.describe());
    }

    proptest! {
        /// The exact segment-to-rectangle distance agrees with a dense sampling of the
        /// segment (which can only overestimate it, by at most half the sample spacing).
        #[test]
        fn segment_to_rectangle_distance_matches_dense_sampling(
            a in prop::array::uniform2(-6.0f64..6.0), b in prop::array::uniform2(-6.0f64..6.0),
            centre in prop::array::uniform2(-2.0f64..2.0), h in prop::array::uniform2(0.05f64..2.0),
            yaw in -3.2f64..3.2,
        ) {
            let fp = Footprint::Rect { centre, half_extents: h, yaw };
            let n = 20_000;
            let sampled = (0..=n)
                .map(|i| {
                    let t = i as f64 / n as f64;
                    fp.distance_to_point([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])])
                })
                .fold(f64::INFINITY, f64::min);
            let exact = fp.distance_to_segment(a, b);
            let spacing = dist(a, b) / n as f64;
            prop_assert!(exact <= sampled + 1e-12 && sampled - exact <= spacing, "exact {exact}, sampled {sampled}");
        }
    }

    #[test]
    fn a_segment_thousands_of_kilometres_long_is_measured_at_once() {
        let fp = Footprint::Rect { centre: [0.0, 0.0], half_extents: [1.0, 0.5], yaw: 0.3 };
        let started = std::time::Instant::now();
        assert_eq!(fp.distance_to_segment([-1e300, 0.0], [1e300, 0.0]), 0.0);
        assert!(
            (fp.distance_to_segment([5.0, -1e6], [5.0, 1e6]) - (5.0 - (1.0 * 0.3f64.cos() + 0.5 * 0.3f64.sin()))).abs()
                < 1e-6
        );
        assert!(started.elapsed().as_millis() < 100);
    }

    #[test]
    fn a_tilted_board_turns_its_face_upwards_about_its_centre() {
        let f = BoardFrame::new(0.8, 0.6, 0.3, 30.0, 0.0);
        let n = f.normal();
        assert!((n[0] - 30f64.to_radians().cos()).abs() < 1e-12 && (n[2] - 30f64.to_radians().sin()).abs() < 1e-12);
        // The top edge leans back (towards -x), the centre stays put.
        let top = f.apply([0.0, 0.0, 0.3]);
        assert!(top[0] < 0.0 && (f.apply([0.0; 3])[2] - 0.6).abs() < 1e-12);
        // Roll keeps the normal and turns the pattern in its plane.
        let r = BoardFrame::new(0.8, 0.6, 0.3, 0.0, 90.0);
        assert!((r.normal()[0] - 1.0).abs() < 1e-12);
        let across = r.apply([0.0, 0.4, 0.0]);
        assert!((across[2] - 0.6 - 0.4).abs() < 1e-12, "{across:?}");
        // Untilted: the old geometry.
        let u =
            Shape::Board { width_m: 0.8, height_m: 0.6, bottom_m: 0.3, squares: [8, 6], tilt_deg: 0.0, roll_deg: 0.0 };
        assert!((u.top_m() - 0.9).abs() < 1e-12);
        let Footprint::Rect { half_extents, .. } = u.footprint(&Pose2 { x: 0.0, y: 0.0, yaw_deg: 0.0 }) else {
            panic!()
        };
        assert!((half_extents[0] - 0.01).abs() < 1e-12 && (half_extents[1] - 0.4).abs() < 1e-12);
    }
}
