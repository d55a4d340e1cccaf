//! Renders the robot camera's view at a time of the park run and saves the colour image
//! and a false-colour instance mask. `cargo run --release -p sim --example camera_view -- [T] [OUT_PREFIX]`
fn main() {
    let t_end: f64 = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(5.0);
    let prefix = std::env::args().nth(2).unwrap_or_else(|| "camera_view".into());
    let world = worlds::generate::park(&Default::default(), 2006).expect("park generates");
    let config = sim::SimConfig { max_duration_s: Some(t_end), ..Default::default() };
    let mut s = sim::Simulation::new(&world, &config, 1).expect("valid config");
    while s.next_event().is_some() {}
    let mut cam = sim::camera::CameraSensor::new(&world, &Default::default(), 1).expect("a renderer");
    eprintln!("adapter: {}", cam.adapter());
    let truth = s.ground_truth();
    let start = std::time::Instant::now();
    let frame = cam.capture(truth.t, &truth.robot, &truth.people).expect("render");
    eprintln!("rendered in {:.1} ms", start.elapsed().as_secs_f64() * 1e3);
    let img = &frame.image;
    image::RgbImage::from_raw(img.width, img.height, img.rgb.clone()).unwrap().save(format!("{prefix}.png")).unwrap();
    let mask: Vec<u8> = img
        .instance
        .iter()
        .flat_map(|&id| {
            let h = (id as u32).wrapping_mul(2654435761);
            if id == 0 { [0, 0, 0] } else { [(h >> 16) as u8, (h >> 8) as u8, h as u8] }
        })
        .collect();
    image::RgbImage::from_raw(img.width, img.height, mask).unwrap().save(format!("{prefix}_instance.png")).unwrap();
}
