//! # scenarios — scenario runner, scoring, reports, Monte Carlo and datasets
//!
//! Joins the crates: worlds are simulated by `sim`, the stream feeds `slam`, and the
//! results are scored against ground truth. The `objslam` binary (the `cli` crate) is a
//! thin layer over this library, which prints nothing: progress and warnings come back to
//! its caller.
//!
//! ```no_run
//! let world = worlds::generate::park(&Default::default(), 7).unwrap();
//! scenarios::plot::draw_map(&world, &scenarios::plot::Overlays::default(), "map.png".as_ref()).unwrap();
//! ```

pub mod appearance;
pub mod build;
pub mod calibrate;
pub mod dataset;
pub mod files;
pub mod foxglove;
pub mod montecarlo;
pub mod objects;
pub mod partial_files;
pub mod plot;
pub mod record;
pub mod replay;
pub mod ros2;
pub mod run;
pub mod scaling;
pub mod scenario;
pub mod score;
pub mod train;
pub mod visibility;
