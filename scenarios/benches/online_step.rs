//! One whole online step of the paper's pipeline in the park: an image (stored for
//! segmentation) and the laser scan of the same instant (clustering, laser-camera
//! segmentation with Gabor/PCA features and the patch classifier, object models, KL
//! association, EKF update), with the map the pipeline has built over the first 60 s of
//! `paper_park`. The simulator is not timed.
//! `cargo bench -p scenarios --bench online_step`
use std::path::Path;

use divan::Bencher;
use scenarios::run::{camera_geometry, resolve_appearance, resolve_calibration, slam_scan};
use scenarios::scenario::Scenario;
use sim::{SensorEvent, Simulation};
use slam::pipeline::{Appearance, Pipeline};

fn main() {
    divan::main();
}

/// The pipeline after `warm_s` seconds of paper_park, and the next (image, scan) pair that
/// has clusters in view.
fn warmed_pipeline(warm_s: f64) -> (Pipeline, (f64, u32, u32, Vec<u8>), slam::messages::LaserScan) {
    let (scenario, base) = Scenario::load("paper_park").expect("built-in scenario");
    let base: &Path = &base;
    let config = scenarios::run::pipeline_config(&scenario, None).expect("pipeline config");
    let model = resolve_appearance(&scenario, base, |_, _, _| {}).expect("appearance model");
    let world = scenario.world(base, scenario.seed).expect("world");
    let calibration = resolve_calibration(&scenario, base, scenario.seed).expect("calibration");
    let mut sim = Simulation::new(&world, &scenario.sim, sim::derive_seed(scenario.seed, "sim")).expect("simulation");
    let appearance =
        Appearance::new(model, camera_geometry(&scenario.sim, &calibration.extrinsics)).expect("appearance");
    let start = world.robot.start;
    let mut pipeline = Pipeline::new(config, [start.x, start.y, start.yaw_rad()], Some(appearance)).expect("pipeline");
    let mut image = None;
    while let Some(event) = sim.next_event() {
        match event {
            SensorEvent::Odometry { odometry, .. } => pipeline
                .on_odometry(&slam::messages::OdometryIncrement {
                    t: odometry.t,
                    dx: odometry.dx,
                    dy: odometry.dy,
                    dtheta: odometry.dtheta,
                })
                .expect("odometry"),
            SensorEvent::Camera { frame, .. } => {
                let img = &frame.image;
                image = Some((frame.t, img.width, img.height, img.rgb.clone()));
                pipeline.on_image(frame.t, img.width, img.height, img.rgb.clone()).expect("image");
            }
            SensorEvent::Laser { scan, .. } => {
                let s = slam_scan(&scan);
                let fresh = image.as_ref().is_some_and(|i| i.0 == s.t);
                if s.t >= warm_s && fresh {
                    return (pipeline, image.expect("checked"), s);
                }
                pipeline.on_scan(&s).expect("scan");
            }
        }
    }
    panic!("paper_park ended before {warm_s} s");
}

#[divan::bench(sample_count = 50)]
fn image_and_scan_in_the_park(bencher: Bencher) {
    let (pipeline, (t, w, h, rgb), scan) = warmed_pipeline(60.0);
    bencher.with_inputs(|| (pipeline.clone(), rgb.clone())).bench_local_values(|(mut p, rgb)| {
        p.on_image(t, w, h, rgb).expect("image");
        let result = p.on_scan(&scan).expect("scan");
        (p, result)
    });
}
