//! The VBEM benchmark data and our fits of it, for the comparison with scikit-learn.
//!
//! 1. `cargo run --release -p slam --example vbem_compare -- write DIR` writes DIR/train.csv
//!    (20,000 x 14) and DIR/heldout.csv (5,000 more points of the same mixture), then fits
//!    ours (fixed K = 10 and both searches) in process, printing time, iterations, the full
//!    bound and the held-out predictive log-likelihood per point.
//! 2. `python3 slam/benches/sklearn_compare.py --train DIR/train.csv --heldout DIR/heldout.csv`
//!    times `objslam gmm fit` against scikit-learn on those files and scores both.
//!
//! `profile DIR [fixed|grow|prune]` runs five fits, for `perf record`.
use std::io::Write;
use std::time::Instant;

use nalgebra::DMatrix;
use slam::gmm::{Search, VbOptions, VbPrior, bench_data, fit};

fn write_csv(path: &std::path::Path, data: &DMatrix<f64>) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    for i in 0..data.nrows() {
        let row: Vec<String> = data.row(i).iter().map(|v| format!("{v:e}")).collect();
        writeln!(f, "{}", row.join(",")).unwrap();
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (mode, dir) = (
        args.get(1).map(String::as_str).unwrap_or("write"),
        std::path::PathBuf::from(args.get(2).map(String::as_str).unwrap_or("vbem_compare")),
    );
    let data = bench_data::mixture_20000x14();
    let prior = VbPrior::from_data(&data).unwrap();
    match mode {
        "write" => {
            std::fs::create_dir_all(&dir).unwrap();
            let heldout = bench_data::heldout_5000x14();
            write_csv(&dir.join("train.csv"), &data);
            write_csv(&dir.join("heldout.csv"), &heldout);
            let runs = [
                ("fixed K = 10", VbOptions { fixed_k: true, ..Default::default() }),
                ("growing search (K <= 10)", VbOptions { search: Search::Grow, ..Default::default() }),
                ("pruning search (K <= 10)", VbOptions { search: Search::Prune, ..Default::default() }),
            ];
            for (label, options) in runs {
                let t = Instant::now();
                let m = fit(&data, Some(&prior), &VbOptions { max_components: 10, ..options }).unwrap();
                println!(
                    "objslam {label}: {:.3} s, {} VBEM iterations, {} components above 1e-3, full bound {:.3}, held-out {:.4} nats per point",
                    t.elapsed().as_secs_f64(),
                    m.iterations,
                    m.effective_components(1e-3),
                    m.lower_bound,
                    m.mean_log_predictive(&heldout).unwrap()
                );
            }
        }
        "profile" => {
            // `profile DIR [fixed|grow|prune]`: five fits, for `perf record`.
            let options = match args.get(3).map(String::as_str).unwrap_or("fixed") {
                "grow" => VbOptions { search: Search::Grow, ..Default::default() },
                "prune" => VbOptions { search: Search::Prune, ..Default::default() },
                _ => VbOptions { fixed_k: true, ..Default::default() },
            };
            for _ in 0..5 {
                fit(&data, Some(&prior), &VbOptions { max_components: 10, ..options.clone() }).unwrap();
            }
        }
        other => eprintln!("unknown mode {other}: use write or profile"),
    }
}
