//! Writes Victoria Park's published files as a robot log directory (docs/reference/robot-log.md),
//! optionally only its first SECONDS: to read the data as CSV, or to tune on part of the log
//! and report on the whole (docs/results.md#victoria-park).
//!
//! ```sh
//! cargo run --release -p robotlog --example victoria_park_to_log -- DATA_DIR OUT_DIR [SECONDS]
//! ```

use robotlog::{Motion, Observations};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(data), Some(out)) = (args.first(), args.get(1)) else {
        return Err("usage: victoria_park_to_log DATA_DIR OUT_DIR [SECONDS]".into());
    };
    let seconds = match args.get(2) {
        Some(s) => s.parse::<f64>().map_err(|_| format!("SECONDS: `{s}` is not a number"))?,
        None => f64::INFINITY,
    };
    let mut log = robotlog::victoria_park::read(std::path::Path::new(data))?;
    let first = [
        match &log.motion {
            Motion::Increments(v) => v.first().map(|o| o.t),
            Motion::Controls(v) => v.first().map(|c| c.0),
        },
        match &log.observations {
            Observations::Scans(v) => v.first().map(|s| s.t),
            Observations::Detections(v) => v.first().map(|s| s.t),
        },
    ]
    .into_iter()
    .flatten()
    .fold(f64::INFINITY, f64::min);
    let until = first + seconds;
    match &mut log.motion {
        Motion::Increments(v) => v.retain(|o| o.t < until),
        Motion::Controls(v) => v.retain(|c| c.0 < until),
    }
    match &mut log.observations {
        Observations::Scans(v) => v.retain(|s| s.t < until),
        Observations::Detections(v) => v.retain(|s| s.t < until),
    }
    log.reference.retain(|r| r.t < until);
    // Without GPS (none in the files, or none in the part kept) a robot log has no
    // [reference] table, and its replay's estimate then describes the vehicle frame (the
    // rear axle), not the laser as `objslam replay victoria-park` does.
    if log.reference.is_empty() {
        log.manifest.reference = None;
    }
    robotlog::format::write(std::path::Path::new(out), &log)?;
    println!("{} controls and {} scans of Victoria Park written to {out}", log.motion.len(), log.observations.len());
    Ok(())
}
