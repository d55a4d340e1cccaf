//! Compares our VBEM with scikit-learn's BayesianGaussianMixture on the benchmark data.
//!
//! 1. `cargo run --release -p slam --example vbem_compare -- write DIR` writes DIR/data.csv
//!    and DIR/prior.json (the prior both sides use) and fits ours (fixed K = 10 and the
//!    birth-death search), printing time, iterations and the full bound.
//! 2. `python3 slam/benches/sklearn_compare.py DIR` fits scikit-learn with the same prior
//!    on one thread and writes its responsibilities to DIR/sklearn_resp.csv.
//! 3. `cargo run --release -p slam --example vbem_compare -- score DIR` scores
//!    scikit-learn's solution with our full bound, so the two bounds compare.
use std::io::Write;
use std::time::Instant;

use nalgebra::DMatrix;
use slam::gmm::{VbOptions, VbPrior, bench_data, fit, vbem};

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
            let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("data.csv")).unwrap());
            for i in 0..data.nrows() {
                let row: Vec<String> = data.row(i).iter().map(|v| format!("{v:e}")).collect();
                writeln!(f, "{}", row.join(",")).unwrap();
            }
            std::fs::write(dir.join("prior.json"), serde_json::to_string(&prior).unwrap()).unwrap();
            for fixed_k in [true, false] {
                let t = Instant::now();
                let m =
                    fit(&data, Some(&prior), &VbOptions { max_components: 10, fixed_k, ..Default::default() }).unwrap();
                println!(
                    "objslam {}: {:.3} s, {} VBEM iterations, {} components above 1e-3, full bound {:.3}",
                    if fixed_k { "fixed K = 10" } else { "birth-death (K <= 10)" },
                    t.elapsed().as_secs_f64(),
                    m.iterations,
                    m.effective_components(1e-3),
                    m.lower_bound
                );
            }
        }
        "score" => {
            let text = std::fs::read_to_string(dir.join("sklearn_resp.csv")).unwrap();
            let rows: Vec<Vec<f64>> =
                text.lines().map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect();
            let r = DMatrix::from_fn(rows.len(), rows[0].len(), |i, j| rows[i][j]);
            println!(
                "scikit-learn's solution under the same full bound: {:.3}",
                vbem::bound_at_responsibilities(&data, &r, &prior).unwrap()
            );
        }
        "profile" => {
            for _ in 0..5 {
                fit(&data, Some(&prior), &VbOptions { max_components: 10, fixed_k: true, ..Default::default() })
                    .unwrap();
            }
        }
        other => eprintln!("unknown mode {other}: use write, score or profile"),
    }
}
