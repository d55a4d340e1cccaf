//! Benchmarks: one 361-beam scan in the park, and simulating the park route without the
//! camera. `cargo bench -p sim --bench laser`
use divan::Bencher;
use sim::{SimConfig, Simulation};

fn main() {
    divan::main();
}

/// One scan from the robot's start pose in the default park (single thread).
#[divan::bench]
fn scan_361_beams_park(bencher: Bencher) {
    let world = worlds::generate::park(&Default::default(), 1).unwrap();
    let mut config = SimConfig::default();
    config.camera.enabled = false;
    let sim = Simulation::new(&world, &config, 1).unwrap();
    let mut laser = sim::laser::Laser::new(&config.laser, 1);
    let pose = sim.ground_truth().robot;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    // Each iteration hands the scan to a one-thread pool (a few microseconds of the figure).
    bencher.bench_local(|| pool.install(|| laser.scan(sim.scene(), &pose, 0.0)));
}

/// The whole park route (two laps, about 260 simulated seconds), laser and odometry only.
#[divan::bench(sample_count = 3, sample_size = 1)]
fn park_route_without_camera(bencher: Bencher) {
    let world = worlds::generate::park(&Default::default(), 1).unwrap();
    bencher.bench_local(|| {
        let mut config = SimConfig::default();
        config.camera.enabled = false;
        let mut s = Simulation::new(&world, &config, 1).unwrap();
        while s.next_event().is_some() {}
        s.time()
    });
}
