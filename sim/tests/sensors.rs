//! Sensor and robot behaviour on small hand-built worlds with known answers.

use sim::{LaserConfig, OdometryConfig, SensorEvent, SimConfig, Simulation};

/// Default settings without the camera (these tests are about physics, laser, odometry).
fn cfg() -> SimConfig {
    let mut c = SimConfig::default();
    c.camera.enabled = false;
    c
}
use worlds::*;

fn appearance(material: Material) -> Appearance {
    Appearance { material, colour: [0.4, 0.3, 0.2], texture_seed: 1 }
}

/// An empty 40 x 40 m ground with the robot at the origin heading +x, route along +y.
fn empty_world() -> World {
    World {
        format_version: WORLD_FORMAT_VERSION,
        name: "test".into(),
        seed: 0,
        ground: Ground { min_m: [-20.0, -20.0], max_m: [20.0, 20.0], appearance: appearance(Material::Grass) },
        objects: vec![],
        people: vec![],
        robot: RobotSpec {
            start: Pose2 { x: 0.0, y: 0.0, yaw_deg: 0.0 },
            route: Route { waypoints: vec![[0.0, 0.0], [3.0, 0.0]], looping: false },
            laps: 1,
        },
    }
}

fn tree(id: u16, x: f64, y: f64, r: f64) -> StaticObject {
    StaticObject {
        id,
        class: ObjectClass::Tree,
        pose: Pose2 { x, y, yaw_deg: 0.0 },
        shape: Shape::Trunk { radius_m: r, height_m: 5.0, canopy_radius_m: 1.0, canopy_height_m: 1.4 },
        appearance: appearance(Material::Bark),
        mesh: None,
        mesh_data: Default::default(),
    }
}

fn first_scan(world: &World, config: &SimConfig, seed: u64) -> (sim::LaserScan, sim::LaserTruth) {
    let mut s = Simulation::new(world, config, seed).unwrap();
    while let Some(e) = s.next_event() {
        if let SensorEvent::Laser { scan, beams, .. } = e {
            return (scan, beams);
        }
    }
    panic!("no scan");
}

#[test]
fn beam_on_known_trunk_returns_analytic_distance() {
    let mut w = empty_world();
    w.objects.push(tree(7, 6.0, 0.0, 0.3));
    let config = cfg();
    let (scan, truth) = first_scan(&w, &config, 3);
    // Centre beam (index 180) points straight ahead from the laser at x = 0.16.
    let expected = 6.0 - 0.3 - 0.16;
    assert_eq!(truth.hit_ids[180], 7);
    assert!((truth.true_ranges[180] - expected).abs() < 1e-4, "true {}", truth.true_ranges[180]);
    // sigma 1 cm plus 1 cm quantisation in 80 m mode: within 5 cm (> 4 sigma).
    assert!((scan.ranges[180] - expected).abs() < 0.05, "measured {}", scan.ranges[180]);
    // Beams either side of the trunk's angular extent hit nothing.
    let half_angle = (0.3f64 / (6.0 - 0.16)).asin().to_degrees();
    let outside = 180 + ((half_angle + 1.0) / 0.5).ceil() as usize;
    assert_eq!(truth.hit_ids[outside], 0);
    assert!(scan.ranges[outside].is_infinite());
    // Every beam on the trunk agrees with the circle geometry.
    for (i, id) in truth.hit_ids.iter().enumerate() {
        if *id == 7 {
            let a = scan.angle_min + scan.angle_increment * i as f64;
            let (dx, dy) = (a.cos(), a.sin());
            let (cx, cy) = (6.0 - 0.16, 0.0);
            let b = dx * cx + dy * cy;
            let c = cx * cx + cy * cy - 0.09;
            let analytic = b - (b * b - c).sqrt();
            assert!((truth.true_ranges[i] - analytic).abs() < 1e-3, "beam {i}: {} vs {analytic}", truth.true_ranges[i]);
        }
    }
}

#[test]
fn range_noise_has_the_configured_spread() {
    let mut w = empty_world();
    w.objects.push(tree(7, 6.0, 0.0, 0.3));
    let mut config = cfg();
    config.laser.max_range_m = 8.0; // mm quantisation, so the noise dominates
    let mut errors = Vec::new();
    for seed in 0..200 {
        let (scan, truth) = first_scan(&w, &config, seed);
        errors.push(scan.ranges[180] - truth.true_ranges[180]);
    }
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let sd = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
    assert!(mean.abs() < 0.003, "mean error {mean}");
    assert!((sd - 0.01).abs() < 0.002, "sd {sd}");
}

#[test]
fn no_return_beyond_maximum_range() {
    let mut w = empty_world();
    w.objects.push(tree(7, 12.0, 0.0, 0.3));
    let mut config = cfg();
    config.laser.max_range_m = 8.0;
    let (scan, truth) = first_scan(&w, &config, 1);
    assert!(scan.ranges.iter().all(|r| r.is_infinite()), "a return beyond 8 m");
    assert!(truth.hit_ids.iter().all(|&id| id == 0));
    config.laser.max_range_m = 16.0;
    let (scan, _) = first_scan(&w, &config, 1);
    assert!(scan.ranges[180].is_finite());
    // Nearer than the minimum range: too close to measure, -inf (REP-117), not "no return".
    config.laser.min_range_m = 13.0;
    let (scan, _) = first_scan(&w, &config, 1);
    assert_eq!(scan.ranges[180], f64::NEG_INFINITY);
    assert_eq!(scan.ranges[0], f64::INFINITY, "nothing to the right");
}

#[test]
fn person_legs_block_beams() {
    let mut w = empty_world();
    w.objects.push(tree(7, 8.0, 0.0, 0.3));
    // A person standing (start time far in the future) between the robot and the tree.
    w.people.push(Person {
        id: 30,
        // Walking towards the robot: the hips are side by side as the laser sees them.
        route: Route { waypoints: vec![[4.0, 0.0], [2.0, 0.0]], looping: true },
        speed_mps: 1.0,
        start_time_s: 1000.0,
        height_m: 1.75,
        hip_half_width_m: 0.1,
        leg_radius_m: 0.07,
        stride_m: 0.7,
        shirt: appearance(Material::Clothes),
        trousers: appearance(Material::Clothes),
    });
    let (_, truth) = first_scan(&w, &cfg(), 1);
    let legs: Vec<usize> = truth.hit_ids.iter().enumerate().filter(|(_, id)| **id == 30).map(|(i, _)| i).collect();
    assert!(!legs.is_empty(), "no beam hit the legs");
    // Two separate legs: two runs of beams with a gap between.
    let runs = legs.windows(2).filter(|w| w[1] != w[0] + 1).count() + 1;
    assert_eq!(runs, 2, "expected two legs, beams {legs:?}");
    // The legs shadow part of the tree behind them.
    let tree_beams = truth.hit_ids.iter().filter(|&&id| id == 7).count();
    let mut w2 = w.clone();
    w2.people.clear();
    let (_, clear) = first_scan(&w2, &cfg(), 1);
    assert!(clear.hit_ids.iter().filter(|&&id| id == 7).count() >= tree_beams);
    for i in &legs {
        assert!((truth.true_ranges[*i] - (4.0 - 0.16)).abs() < 0.15);
    }
}

#[test]
fn noiseless_odometry_integrates_to_the_true_path() {
    let world = worlds::generate::park(&Default::default(), 3).unwrap();
    let config = SimConfig { odometry: OdometryConfig::noiseless(), max_duration_s: Some(60.0), ..cfg() };
    let mut s = Simulation::new(&world, &config, 9).unwrap();
    let mut pose: Option<sim::Pose2D> = None;
    let mut n = 0;
    while let Some(e) = s.next_event() {
        if let SensorEvent::Odometry { odometry, truth } = e {
            let p = match pose {
                None => truth.robot,
                Some(p) => p.compose(odometry.dx, odometry.dy, odometry.dtheta),
            };
            assert!(
                (p.x - truth.robot.x).abs() < 1e-6 && (p.y - truth.robot.y).abs() < 1e-6,
                "drift at t = {}",
                odometry.t
            );
            pose = Some(p);
            n += 1;
        }
    }
    assert!(n > 1000, "{n} odometry messages in a minute at 20 Hz");
}

#[test]
fn noisy_odometry_drifts() {
    let world = worlds::generate::park(&Default::default(), 3).unwrap();
    let config = SimConfig { max_duration_s: Some(60.0), ..cfg() };
    let mut s = Simulation::new(&world, &config, 9).unwrap();
    let mut pose: Option<sim::Pose2D> = None;
    let mut last = None;
    while let Some(e) = s.next_event() {
        if let SensorEvent::Odometry { odometry, truth } = e {
            pose = Some(match pose {
                None => truth.robot,
                Some(p) => p.compose(odometry.dx, odometry.dy, odometry.dtheta),
            });
            last = Some(truth.robot);
        }
    }
    let (p, t) = (pose.unwrap(), last.unwrap());
    let err = ((p.x - t.x).powi(2) + (p.y - t.y).powi(2)).sqrt();
    assert!(err > 0.01, "default noise left no drift after a minute ({err} m)");
}

#[test]
fn a_route_of_a_few_metres_counts_as_completed_when_the_robot_reaches_its_end() {
    // 9 m: the controller stops 0.15 m short of the end, 1.7% of this route.
    let mut world = empty_world();
    world.robot.route.waypoints = vec![[0.0, 0.0], [9.0, 0.0]];
    let config = SimConfig { max_duration_s: Some(60.0), ..cfg() };
    let mut s = Simulation::new(&world, &config, 1).unwrap();
    while s.next_event().is_some() {}
    assert!(s.time() < 59.0, "the run went on to its time limit, {} s", s.time());
    assert!(s.route_completed(), "stopped at {:.3} of the route", s.route_progress());
    // A run stopped by its time limit short of the end has not completed it.
    let config = SimConfig { max_duration_s: Some(3.0), ..cfg() };
    let mut s = Simulation::new(&world, &config, 1).unwrap();
    while s.next_event().is_some() {}
    assert!(!s.route_completed(), "completed at {:.3} of the route", s.route_progress());
}

#[test]
fn controller_completes_the_park_route_without_collision() {
    let world = worlds::generate::park(&Default::default(), 1).unwrap();
    let mut s = Simulation::new(&world, &cfg(), 1).unwrap();
    while s.next_event().is_some() {}
    assert!(s.route_completed(), "stopped at {:.2} of the route", s.route_progress());
    assert!(s.collisions().is_empty(), "collisions: {:?}", s.collisions());
    let gt = s.ground_truth();
    let start = world.robot.start;
    assert!(
        ((gt.robot.x - start.x).powi(2) + (gt.robot.y - start.y).powi(2)).sqrt() < 0.5,
        "did not return to the start"
    );
}

#[test]
fn collision_with_an_obstacle_is_recorded() {
    // A route straight through a trunk is rejected by validation, so place the trunk after
    // building the world description without validation: the simulator must record the hit.
    let mut w = empty_world();
    w.robot.route.waypoints = vec![[0.0, 0.0], [6.0, 0.0]];
    w.objects.push(tree(9, 3.0, 0.0, 0.3));
    let mut config = SimConfig { max_duration_s: Some(20.0), ..cfg() };
    config.robot.safety_stop_m = 0.0;
    let mut s = Simulation::new(&w, &config, 1).unwrap();
    while s.next_event().is_some() {}
    assert!(s.collisions().iter().any(|c| c.instance_id == 9), "{:?}", s.collisions());
    // The robot did not drive through the trunk.
    assert!(s.ground_truth().robot.x < 3.0);
}

#[test]
fn bad_settings_are_named() {
    let w = empty_world();
    let mut c = cfg();
    c.laser.rate_hz = -10.0;
    let e = Simulation::new(&w, &c, 1).err().unwrap().to_string();
    assert!(e.contains("laser.rate_hz"), "{e}");
    let mut c = cfg();
    c.laser.fov_deg = 0.1;
    let e = Simulation::new(&w, &c, 1).err().unwrap().to_string();
    assert!(e.contains("beams"), "{e}");
    let mut c = cfg();
    c.laser = LaserConfig { max_range_m: 50.0, ..Default::default() };
    let e = Simulation::new(&w, &c, 1).err().unwrap().to_string();
    assert!(e.contains("max_range_m"), "{e}");
    // Faster or quicker-turning than a Pioneer 2-AT.
    let mut c = cfg();
    c.robot.max_speed_mps = 3.0;
    let e = Simulation::new(&w, &c, 1).err().unwrap().to_string();
    assert!(e.contains("robot.max_speed_mps") && e.contains("1.2 m/s"), "{e}");
    let mut c = cfg();
    c.robot.max_turn_rate_dps = 330.0;
    let e = Simulation::new(&w, &c, 1).err().unwrap().to_string();
    assert!(e.contains("robot.max_turn_rate_dps") && e.contains("300 deg/s"), "{e}");
    // So slow the run would look hung (it had started on 3e11 simulated seconds).
    let mut c = cfg();
    c.robot.cruise_speed_mps = 1e-9;
    let e = Simulation::new(&w, &c, 1).err().unwrap().to_string();
    assert!(e.contains("robot.cruise_speed_mps") && e.contains("sim.max_duration_s"), "{e}");
    c.max_duration_s = Some(10.0);
    Simulation::new(&w, &c, 1).unwrap();
    let e = worlds::load(std::path::Path::new("/no/such/world.toml")).unwrap_err().to_string();
    assert!(e.contains("/no/such/world.toml"));
}

/// Without `max_duration_s` a run may take three times the route's driving time and 30 s
/// more (people may block it); with it, exactly that.
#[test]
fn the_time_limit_is_the_set_one_or_derived_from_the_route() {
    let world = empty_world();
    let s = Simulation::new(&world, &cfg(), 1).unwrap();
    let expected = 3.0 * s.nominal_duration_s() + 30.0;
    assert!((s.time_limit_s() - expected).abs() < 1e-9, "{} against {expected}", s.time_limit_s());
    let set = Simulation::new(&world, &SimConfig { max_duration_s: Some(12.5), ..cfg() }, 1).unwrap();
    assert_eq!(set.time_limit_s(), 12.5);
}
