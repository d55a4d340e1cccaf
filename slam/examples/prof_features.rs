use slam::features::*;
use std::time::Instant;
fn main() {
    let (w, h) = (640u32, 480u32);
    let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
    let image = ImageRef::new(w, h, &rgb).unwrap();
    let config = FeatureConfig::default();
    let grey = Plane { width: 640, height: 480, data: vec![0.5; 640 * 480] };
    let t = Instant::now();
    for _ in 0..10 {
        let _ = config.bank.apply(&grey).unwrap();
    }
    println!("bank {:?}", t.elapsed() / 10);
    let rect = PatchRect::whole(&image, 9);
    let t = Instant::now();
    for _ in 0..10 {
        let _ = raw_patches(&image, &config, &rect).unwrap();
    }
    println!("raw (incl bank) {:?}", t.elapsed() / 10);
    let raw = raw_patches(&image, &config, &rect).unwrap();
    let pca = Pca::fit(&raw.rows(0, 1000).into_owned(), 10).unwrap();
    let fx = FeatureExtractor::new(config.clone(), pca.clone()).unwrap();
    let t = Instant::now();
    for _ in 0..10 {
        let _ = fx.features(&image, None).unwrap();
    }
    println!("features whole {:?}", t.elapsed() / 10);
    let t = Instant::now();
    for _ in 0..10 {
        let _ = pca.project(&raw).unwrap();
    }
    println!("project {:?}", t.elapsed() / 10);
    let data = slam::gmm::bench_data::mixture_20000x14();
    let t = Instant::now();
    let m = slam::gmm::fit(&data, None, &slam::gmm::VbOptions { fixed_k: true, ..Default::default() }).unwrap();
    println!("fixed k: {:?} {} iterations, bound {}", t.elapsed(), m.iterations, m.lower_bound);
    let t = Instant::now();
    let m = slam::gmm::fit(&data, None, &slam::gmm::VbOptions::default()).unwrap();
    println!(
        "search: {:?} {} iterations, bound {} k {}",
        t.elapsed(),
        m.iterations,
        m.lower_bound,
        m.effective_components(1e-3)
    );
}
