//! The rapier3d world built from a `worlds::World`: fixed colliders for every object and
//! the ground, kinematic legs and bodies for people, and the robot as a dynamic body.
//!
//! Every collider's `user_data` is the instance id it belongs to, so a raycast hit or a
//! contact names the object directly. rapier works in f32 with glam types; conversion to
//! the f64 world happens here and nowhere else.

use rapier3d::prelude::*;
use worlds::{Person, Shape, World, mesh::HIP_FRACTION, validate::GROUND_INSTANCE_ID};

use crate::config::RobotConfig;
use crate::messages::{PersonState, Pose2D};
use crate::people::{leg_pose, person_state_at};

/// Collision groups: the laser and camera see everything but the robot itself.
const GROUP_STATIC: Group = Group::GROUP_1;
const GROUP_ROBOT: Group = Group::GROUP_2;
const GROUP_PEOPLE: Group = Group::GROUP_3;
const GROUP_GROUND: Group = Group::GROUP_4;

/// The bodies of one person: two legs and the upper body.
#[derive(Debug, Clone, Copy)]
struct PersonBodies {
    left: RigidBodyHandle,
    right: RigidBodyHandle,
    torso: RigidBodyHandle,
}

/// The physical scene.
pub struct PhysicsScene {
    pub world: PhysicsWorld,
    pub robot: RigidBodyHandle,
    pub robot_collider: ColliderHandle,
    people: Vec<(Person, PersonBodies)>,
    /// Distance each person has walked so far.
    walked: Vec<f64>,
    /// How long each person has been waiting for the robot.
    waited: Vec<f64>,
}

/// A person waits while the robot is closer than this ahead of them.
const GIVE_WAY_DISTANCE_M: f64 = 1.5;
/// After waiting this long face to face with the robot, a person turns back.
const GIVE_UP_WAIT_S: f64 = 4.0;

fn v3(x: f64, y: f64, z: f64) -> Vector {
    Vector::new(x as f32, y as f32, z as f32)
}

/// A pose from a position and a rotation about z.
fn pose_z(x: f64, y: f64, z: f64, yaw: f64) -> Pose {
    Pose::from_parts(v3(x, y, z), Rotation::from_rotation_z(yaw as f32))
}

/// Collider pose that stands parry's y-axis cylinders upright along z.
fn upright() -> Rotation {
    Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2)
}

impl PhysicsScene {
    pub fn build(world: &World, robot: &RobotConfig, dt: f64) -> Self {
        let mut pw = PhysicsWorld::new();
        pw.gravity = Vector::new(0.0, 0.0, -9.81);
        pw.integration_parameters.dt = dt as f32;

        // Ground: a thin slab under the whole area.
        let g = &world.ground;
        let ground_body = pw.insert_body(RigidBodyBuilder::fixed());
        let (cx, cy) = ((g.min_m[0] + g.max_m[0]) / 2.0, (g.min_m[1] + g.max_m[1]) / 2.0);
        let (hx, hy) = ((g.max_m[0] - g.min_m[0]) / 2.0, (g.max_m[1] - g.min_m[1]) / 2.0);
        pw.insert_collider(
            ColliderBuilder::cuboid(hx as f32, hy as f32, 0.05)
                .translation(v3(cx, cy, -0.05))
                .user_data(GROUND_INSTANCE_ID as u128)
                .collision_groups(InteractionGroups::new(GROUP_GROUND, Group::ALL, InteractionTestMode::And)),
            Some(ground_body),
        );

        for o in &world.objects {
            let body =
                pw.insert_body(RigidBodyBuilder::fixed().pose(pose_z(o.pose.x, o.pose.y, 0.0, o.pose.yaw_rad())));
            let groups = InteractionGroups::new(GROUP_STATIC, Group::ALL, InteractionTestMode::And);
            let collider = match o.shape {
                Shape::Trunk { radius_m, height_m, .. }
                | Shape::Palm { radius_m, height_m, .. }
                | Shape::Post { radius_m, height_m } => {
                    ColliderBuilder::cylinder((height_m / 2.0) as f32, radius_m as f32)
                        .position(Pose::from_parts(v3(0.0, 0.0, height_m / 2.0), upright()))
                }
                Shape::Wall { length_m, thickness_m, height_m } => ColliderBuilder::cuboid(
                    (length_m / 2.0) as f32,
                    (thickness_m / 2.0) as f32,
                    (height_m / 2.0) as f32,
                )
                .translation(v3(0.0, 0.0, height_m / 2.0)),
                Shape::Board { width_m, height_m, .. } => {
                    // Turned (tilt, roll) about its centre as the mesh is (worlds::BoardFrame).
                    let f = o.shape.board_frame().expect("a board");
                    let r = f.rotation;
                    let m = Matrix::from_cols_array(&[
                        r[0][0] as f32,
                        r[1][0] as f32,
                        r[2][0] as f32,
                        r[0][1] as f32,
                        r[1][1] as f32,
                        r[2][1] as f32,
                        r[0][2] as f32,
                        r[1][2] as f32,
                        r[2][2] as f32,
                    ]);
                    let c = f.centre_m;
                    ColliderBuilder::cuboid(
                        (worlds::BOARD_THICKNESS_M / 2.0) as f32,
                        (width_m / 2.0) as f32,
                        (height_m / 2.0) as f32,
                    )
                    .position(Pose::from_parts(v3(c[0], c[1], c[2]), Rotation::from_mat3(&m)))
                }
            };
            pw.insert_collider(collider.user_data(o.id as u128).collision_groups(groups), Some(body));
            if let Some(frame) = o.shape.board_frame()
                && frame.lowest_m() > 0.0
            {
                // The board's stand (up to its lowest corner), so the laser sees a leg
                // below a raised board.
                let h = frame.lowest_m();
                pw.insert_collider(
                    ColliderBuilder::cuboid(0.02, 0.02, (h / 2.0) as f32)
                        .translation(v3(0.0, 0.0, h / 2.0))
                        .user_data(o.id as u128)
                        .collision_groups(groups),
                    Some(body),
                );
            }
        }

        let mut people = Vec::new();
        for p in &world.people {
            let groups = InteractionGroups::new(GROUP_PEOPLE, Group::ALL, InteractionTestMode::And);
            let hip = HIP_FRACTION * p.height_m;
            let mut leg = || {
                let b = pw.insert_body(RigidBodyBuilder::kinematic_position_based());
                // A leg hangs from the hip joint (body origin) along -z.
                pw.insert_collider(
                    ColliderBuilder::cylinder((hip / 2.0) as f32, p.leg_radius_m as f32)
                        .position(Pose::from_parts(v3(0.0, 0.0, -hip / 2.0), upright()))
                        .user_data(p.id as u128)
                        .collision_groups(groups),
                    Some(b),
                );
                b
            };
            let left = leg();
            let right = leg();
            let torso = pw.insert_body(RigidBodyBuilder::kinematic_position_based());
            let torso_h = 0.42 * p.height_m;
            pw.insert_collider(
                ColliderBuilder::cylinder((torso_h / 2.0) as f32, (0.13 * p.height_m) as f32)
                    .position(Pose::from_parts(v3(0.0, 0.0, hip + torso_h / 2.0), upright()))
                    .user_data(p.id as u128)
                    .collision_groups(groups),
                Some(torso),
            );
            people.push((p.clone(), PersonBodies { left, right, torso }));
        }

        // The robot: a dynamic box kept upright and on the ground plane (locked z, roll,
        // pitch), driven by setting its velocity each step as the wheel motors would.
        let s = world.robot.start;
        let robot_body = pw.insert_body(
            RigidBodyBuilder::dynamic()
                .pose(pose_z(s.x, s.y, 0.0, s.yaw_rad()))
                .locked_axes(
                    LockedAxes::TRANSLATION_LOCKED_Z | LockedAxes::ROTATION_LOCKED_X | LockedAxes::ROTATION_LOCKED_Y,
                )
                .can_sleep(false)
                .ccd_enabled(true),
        );
        let clearance = 0.06;
        let robot_collider = pw.insert_collider(
            ColliderBuilder::cuboid(
                (robot.length_m / 2.0) as f32,
                (robot.width_m / 2.0) as f32,
                (robot.body_height_m / 2.0) as f32,
            )
            .translation(v3(0.0, 0.0, clearance + robot.body_height_m / 2.0))
            .density(100.0)
            .friction(0.0)
            .active_events(ActiveEvents::COLLISION_EVENTS)
            // The robot rolls on wheels: it never touches the ground slab.
            .collision_groups(InteractionGroups::new(
                GROUP_ROBOT,
                GROUP_STATIC | GROUP_PEOPLE,
                InteractionTestMode::And,
            )),
            Some(robot_body),
        );

        let walked = vec![0.0; people.len()];
        let waited = vec![0.0; people.len()];
        let mut scene = PhysicsScene { world: pw, robot: robot_body, robot_collider, people, walked, waited };
        scene.pose_people(0.0, 0.0, true);
        scene
    }

    /// Advances every person by `dt` to time `t` and poses their bodies. People walk from
    /// their start time on, and wait while the robot is right ahead of them (people give
    /// way to a robot; without it they would walk into it). `teleport` sets positions
    /// directly (at start); otherwise kinematic targets are set for the next step.
    pub fn pose_people(&mut self, t: f64, dt: f64, teleport: bool) -> Vec<PersonState> {
        let mut states = Vec::with_capacity(self.people.len());
        let robot = self.robot_pose();
        for (k, (p, b)) in self.people.iter().enumerate() {
            if t >= p.start_time_s && dt > 0.0 {
                let now = person_state_at(p, self.walked[k]);
                let (dx, dy) = (robot.x - now.x, robot.y - now.y);
                let (sh, ch) = now.heading.sin_cos();
                let ahead = dx * ch + dy * sh;
                let lateral = -dx * sh + dy * ch;
                // Wait only while the robot is in front of them: someone already crossing in
                // front of the robot walks on and clears its path.
                let blocked = (dx * dx + dy * dy).sqrt() < GIVE_WAY_DISTANCE_M && ahead > 0.25 && lateral.abs() < 0.9;
                if blocked {
                    self.waited[k] += dt;
                    // Face to face for long (both waiting): turn back, if the walk is a
                    // back-and-forth one where that is the mirrored point of the cycle.
                    let length = p.route.length_m();
                    if self.waited[k] > GIVE_UP_WAIT_S
                        && p.route.looping
                        && p.route.waypoints.len() == 2
                        && length > 0.0
                    {
                        self.walked[k] =
                            length - self.walked[k].rem_euclid(length) + length * (self.walked[k] / length).floor();
                        self.waited[k] = 0.0;
                    }
                } else {
                    self.waited[k] = 0.0;
                    self.walked[k] += p.speed_mps * dt;
                }
            }
            let s = person_state_at(p, self.walked[k]);
            for (handle, side) in [(b.left, 1.0), (b.right, -1.0)] {
                let (hip, swing) = leg_pose(p, &s, side);
                // Positive swing moves the foot forward: rotate -swing about the body's y.
                let rot = Rotation::from_rotation_z(s.heading as f32) * Rotation::from_rotation_y(-swing as f32);
                let pose = Pose::from_parts(v3(hip[0], hip[1], hip[2]), rot);
                set_kinematic(&mut self.world, handle, pose, teleport);
            }
            set_kinematic(&mut self.world, b.torso, pose_z(s.x, s.y, 0.0, s.heading), teleport);
            states.push(s);
        }
        if teleport {
            // Refresh the query structures so raycasts see the new positions at once.
            self.world.detect_collisions(&(), &());
        }
        states
    }

    /// Ground-truth robot pose.
    pub fn robot_pose(&self) -> Pose2D {
        let body = &self.world.bodies[self.robot];
        let t = body.translation();
        let r = body.rotation();
        // Yaw of a rotation that only turns about z.
        let fwd = r.mul_vec3(Vector::X);
        Pose2D { x: t.x as f64, y: t.y as f64, theta: (fwd.y as f64).atan2(fwd.x as f64) }
    }

    /// Commands the robot's forward speed and turn rate for the next step.
    pub fn drive(&mut self, v: f64, omega: f64) {
        let pose = self.robot_pose();
        let body = &mut self.world.bodies[self.robot];
        body.set_linvel(v3(v * pose.theta.cos(), v * pose.theta.sin(), 0.0), true);
        body.set_angvel(v3(0.0, 0.0, omega), true);
    }

    /// Instance ids of everything the robot is touching now.
    pub fn robot_contacts(&self) -> Vec<u16> {
        let mut ids: Vec<u16> = self
            .world
            .narrow_phase
            .contact_pairs_with(self.robot_collider)
            .filter(|pair| pair.has_any_active_contact())
            .map(|pair| {
                let other = if pair.collider1 == self.robot_collider { pair.collider2 } else { pair.collider1 };
                self.world.colliders[other].user_data as u16
            })
            .collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }

    pub fn step(&mut self) {
        self.world.step();
    }

    /// Casts a horizontal ray; returns (range, instance id) of the first hit other than the
    /// robot within `max_range`.
    pub fn cast(&self, origin: [f64; 3], dir: [f64; 2], max_range: f64) -> Option<(f64, u16)> {
        let filter = QueryFilter::default().exclude_rigid_body(self.robot);
        let query = self.world.query_pipeline_with_filter(filter);
        crate::raycast::first_hit(&query, origin, [dir[0], dir[1], 0.0], max_range)
            .map(|(h, toi)| (toi, self.world.colliders[h].user_data as u16))
    }
}

fn set_kinematic(pw: &mut PhysicsWorld, handle: RigidBodyHandle, pose: Pose, teleport: bool) {
    // A body already headed where it is asked to go (a person standing before their walk
    // or giving way) is left alone: a mutable borrow puts it on rapier's list of changed
    // bodies, which each step processes again (in `city_park`, whose people mostly stand
    // waiting for their start, the physics took about twice the CPU that way).
    if !teleport && *pw.bodies[handle].next_position() == pose {
        return;
    }
    let body = &mut pw.bodies[handle];
    if teleport {
        body.set_position(pose, true);
    } else {
        body.set_next_kinematic_position(pose);
    }
}
