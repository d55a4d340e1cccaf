//! Drives the park route once without the camera and prints timing and collisions.
//! `cargo run --release -p sim --example drive_park -- [SEED] [--camera]`
fn main() {
    let seed: u64 = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let world = worlds::generate::park(&Default::default(), seed).expect("park generates");
    let mut config = sim::SimConfig::default();
    config.camera.enabled = std::env::args().nth(2).as_deref() == Some("--camera");
    let mut sim = sim::Simulation::new(&world, &config, seed).expect("valid config");
    let start = std::time::Instant::now();
    let (mut scans, mut odo, mut frames) = (0, 0, 0);
    while let Some(e) = sim.next_event() {
        match e {
            sim::SensorEvent::Laser { .. } => scans += 1,
            sim::SensorEvent::Odometry { .. } => odo += 1,
            sim::SensorEvent::Camera { .. } => frames += 1,
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let gt = sim.ground_truth();
    println!(
        "sim {:.1} s in {:.3} s wall ({:.0}x), {scans} scans, {odo} odometry, {frames} camera frames, progress {:.3}, end pose ({:.2}, {:.2}), collisions {:?}",
        sim.time(),
        wall,
        sim.time() / wall,
        sim.route_progress(),
        gt.robot.x,
        gt.robot.y,
        sim.collisions()
    );
}
