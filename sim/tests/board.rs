//! Tilted and rolled boards: the laser hits them where their turned face is.

use worlds::*;

fn board_world(tilt_deg: f64, roll_deg: f64) -> World {
    let mut world = worlds::generate::park(&Default::default(), 2006).unwrap();
    world.objects.clear();
    world.people.clear();
    // 2 m ahead of a laser at the origin, facing it (-x), turned 20 deg.
    world.objects.push(StaticObject::checkerboard(
        500,
        Pose2 { x: 2.0, y: 0.0, yaw_deg: 200.0 },
        Shape::Board { width_m: 0.8, height_m: 0.6, bottom_m: 0.2, squares: [8, 6], tilt_deg, roll_deg },
    ));
    world
}

#[test]
fn the_laser_hits_a_tilted_board_on_its_turned_face() {
    for (tilt, roll) in [(0.0, 0.0), (30.0, 0.0), (-35.0, 0.0), (20.0, 15.0)] {
        let world = board_world(tilt, roll);
        let o = &world.objects[0];
        let f = o.shape.board_frame().unwrap();
        // Front face plane in the world: normal and a point.
        let (s, c) = o.pose.yaw_rad().sin_cos();
        let nm = f.normal();
        let n = [c * nm[0] - s * nm[1], s * nm[0] + c * nm[1], nm[2]];
        let pm = f.apply([BOARD_THICKNESS_M / 2.0, 0.0, 0.0]);
        let p = [o.pose.x + c * pm[0] - s * pm[1], o.pose.y + s * pm[0] + c * pm[1], pm[2]];
        let config = sim::SimConfig::default();
        let scene = sim::physics::PhysicsScene::build(&world, &config.robot, 0.01);
        let laser_cfg = sim::LaserConfig { range_noise_sigma_m: 0.0, max_range_m: 32.0, ..Default::default() };
        let mut laser = sim::laser::Laser::new(&laser_cfg, 1);
        // Robot placed so the laser (0.16 m forward) is at the origin.
        let robot = sim::Pose2D { x: -0.16, y: 0.0, theta: 0.0 };
        let (scan, truth) = laser.scan(&scene, &robot, 0.0);
        let z = laser_cfg.mount_xyz_m[2];
        let mut hits = 0;
        for (i, &id) in truth.hit_ids.iter().enumerate() {
            if id != 500 {
                continue;
            }
            let a = scan.angle_min + scan.angle_increment * i as f64;
            let r = truth.true_ranges[i];
            let q = [r * a.cos(), r * a.sin(), z];
            let d: f64 = (0..3).map(|k| (q[k] - p[k]) * n[k]).sum();
            // The stand (below the board) is hit only if the laser passes under it.
            assert!(d.abs() < 2e-3, "tilt {tilt} roll {roll}: beam {i} hit {d} m off the face");
            hits += 1;
        }
        assert!(hits > 20, "tilt {tilt} roll {roll}: only {hits} beams on the board");
    }
}
