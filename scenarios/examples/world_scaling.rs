//! Cost against world size (see `scenarios::scaling`): runs `paper_park`'s park at 1, 2,
//! 4, 7 and 10 times its size with `jcbb` and `combined`, and writes `scaling.csv` and
//! `scaling.png` into the directory given (default `runs/scaling`). Some factors only:
//! `-- DIR 1 2`. The plot of a CSV written before, drawn again: `-- --plot CSV DIR`.
//!
//! cargo run --release -p scenarios --example world_scaling -- runs/scaling

fn main() {
    let all: Vec<String> = std::env::args().skip(1).collect();
    if all.first().map(String::as_str) == Some("--plot") {
        let (Some(csv), Some(dir)) = (all.get(1), all.get(2)) else {
            eprintln!("usage: world_scaling --plot CSV DIR");
            std::process::exit(2)
        };
        let rows = scenarios::scaling::read_csv(std::path::Path::new(csv))
            .and_then(|rows| scenarios::scaling::write(&rows, std::path::Path::new(dir)).map(|()| rows.len()));
        match rows {
            Ok(n) => eprintln!("drew {n} runs into {dir}/scaling.png"),
            Err(e) => {
                eprintln!("error: {e}");
                std::process::exit(2)
            }
        }
        return;
    }
    let mut args = all.into_iter();
    let dir = std::path::PathBuf::from(args.next().unwrap_or_else(|| "runs/scaling".into()));
    let factors: Vec<u32> = args.map(|a| a.parse().expect("factors are whole numbers")).collect();
    let factors = if factors.is_empty() { scenarios::scaling::FACTORS.to_vec() } else { factors };
    let started = std::time::Instant::now();
    let rows = scenarios::scaling::measure(&factors, std::path::Path::new("."), |factor, method| {
        eprintln!("[{:6.1} s] park x{factor}, {method}", started.elapsed().as_secs_f64());
    })
    .unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(2)
    });
    if let Err(e) = scenarios::scaling::write(&rows, &dir) {
        eprintln!("error: {e}");
        std::process::exit(2);
    }
    // The table is the CSV just written.
    match std::fs::read_to_string(dir.join("scaling.csv")) {
        Ok(table) => print!("{table}"),
        Err(e) => eprintln!("error: {}: {e}", dir.join("scaling.csv").display()),
    }
    eprintln!("wrote {}/scaling.csv and scaling.png", dir.display());
}
