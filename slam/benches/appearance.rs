//! Offline/appearance benchmarks: one VBEM fit on 20,000 x 14 points with up to 10
//! components (birth-death search and fixed K = 10), and patch features for a whole
//! 640x480 image and for the columns of one laser cluster.
//! `cargo bench -p slam --bench appearance`
use divan::Bencher;
use slam::features::{FeatureConfig, FeatureExtractor, ImageRef, PatchRect, Pca, raw_patches};
use slam::gmm::{VbOptions, fit};

fn main() {
    divan::main();
}

#[divan::bench(args = [false, true], sample_count = 3, sample_size = 1)]
fn vbem_fit_20000x14(bencher: Bencher, fixed_k: bool) {
    let data = slam::gmm::bench_data::mixture_20000x14();
    let options = VbOptions { max_components: 10, fixed_k, ..Default::default() };
    bencher.bench_local(|| fit(&data, None, &options).unwrap());
}

/// A 640x480 image with bark-like stripes, grass-like noise and smooth sky.
fn park_like_image() -> Vec<u8> {
    let (w, h) = (640u32, 480u32);
    let mut s = 99u64;
    (0..w * h)
        .flat_map(|i| {
            let (x, y) = (i % w, i / w);
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let n = (s >> 58) as u8;
            if y < 200 {
                [150 + n, 180 + n, 230]
            } else if (200..280).contains(&x) {
                let stripe = if x % 5 < 2 { 30 } else { 0 };
                [90 + stripe + n, 60 + stripe + n, 40 + n]
            } else {
                [40 + n * 2, 110 + n * 3, 40 + n]
            }
        })
        .collect()
}

fn extractor(image: &ImageRef) -> FeatureExtractor {
    let config = FeatureConfig::default();
    let raw = raw_patches(image, &config, &PatchRect::whole(image, 9)).unwrap();
    FeatureExtractor::new(config, Pca::fit(&raw.rows(0, 2000).into_owned(), 10).unwrap()).unwrap()
}

#[divan::bench]
fn features_whole_640x480(bencher: Bencher) {
    let rgb = park_like_image();
    let image = ImageRef::new(640, 480, &rgb).unwrap();
    let fx = extractor(&image);
    bencher.bench_local(|| fx.features(&image, None).unwrap());
}

/// A trunk 1.5 m away spans about 6 patch columns at 640x480 and 60 deg.
#[divan::bench]
fn features_one_cluster_6_columns(bencher: Bencher) {
    let rgb = park_like_image();
    let image = ImageRef::new(640, 480, &rgb).unwrap();
    let fx = extractor(&image);
    let rect = PatchRect::columns(&image, 9, 30, 36);
    bencher.bench_local(|| fx.features(&image, Some(rect)).unwrap());
}
