//! Top-view maps: the world by class, routes, and (for runs) estimated landmarks with
//! 2-sigma ellipses and trajectories. PNG through plotters, text in embedded DejaVu Sans so
//! it renders the same on any machine.

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;
use plotters::style::FontStyle;
use worlds::{ObjectClass, Shape, World};

/// Error from drawing a plot.
#[derive(Debug, thiserror::Error)]
#[error("{}: cannot draw plot: {message}", file.display())]
pub struct PlotError {
    pub file: std::path::PathBuf,
    pub message: String,
}

/// Makes "sans-serif" available to plotters from embedded font bytes (once per process).
pub fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}

/// A picture being drawn in memory.
type Canvas<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Draws a `size` picture with `draw` in memory and writes it to `file` as a PNG, whole
/// ([`crate::partial_files::write_whole`]): a write that fails (a full disk) leaves no cut
/// picture under the file's name, and its error is the system's, named by the file.
fn write_png(
    file: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(Canvas<'_>) -> Result<(), String>,
) -> Result<(), PlotError> {
    let fail = |message: String| PlotError { file: file.to_path_buf(), message };
    let mut pixels = vec![0u8; width as usize * height as usize * 3];
    draw(BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area()).map_err(fail)?;
    let mut png = std::io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut png,
        &pixels,
        width,
        height,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| fail(e.to_string()))?;
    crate::partial_files::write_whole(file, png.get_ref()).map_err(|e| fail(e.source.to_string()))?;
    Ok(())
}

/// Colour of each class in maps.
pub fn class_colour(class: ObjectClass) -> RGBColor {
    match class {
        ObjectClass::Tree => RGBColor(34, 139, 34),
        ObjectClass::Palm => RGBColor(218, 165, 32),
        ObjectClass::Post => RGBColor(90, 60, 160),
        ObjectClass::Wall => RGBColor(160, 82, 45),
        ObjectClass::Person => RGBColor(220, 20, 60),
        ObjectClass::Ground => RGBColor(200, 230, 190),
        ObjectClass::Checkerboard => RGBColor(0, 0, 0),
        ObjectClass::Foliage => RGBColor(107, 142, 35),
    }
}

/// An estimated landmark to draw: position, 2x2 covariance (row-major) and a label.
#[derive(Debug, Clone)]
pub struct LandmarkMark {
    pub position: [f64; 2],
    pub covariance: [[f64; 2]; 2],
    pub label: String,
    /// Drawn in red when the scorer found something wrong with it (false or duplicate).
    pub flagged: bool,
}

/// What to draw over the world.
#[derive(Debug, Clone, Default)]
pub struct Overlays {
    pub title: String,
    pub landmarks: Vec<LandmarkMark>,
    /// (legend name, colour, path)
    pub trajectories: Vec<(String, RGBColor, Vec<[f64; 2]>)>,
    pub people_tracks: Vec<Vec<[f64; 2]>>,
    /// Draw the planned routes (world plots) or not (run maps show driven paths instead).
    pub routes: bool,
}

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy)]
enum Swatch {
    /// A filled disc (an object's footprint).
    Disc(RGBColor),
    /// A faint wide disc (a canopy).
    Faint(RGBColor, f64),
    /// A line of this width (paths, routes, tracks).
    Line(RGBColor, u32),
    /// A dashed line (people's planned walks).
    Dashed(RGBColor),
    /// A cross in an ellipse (a landmark and its 2-sigma ellipse).
    Landmark(RGBColor),
    /// A thick bar (a wall).
    Bar(RGBColor),
    /// A plain cross (a run of a method drawn as crosses).
    Cross(RGBColor),
    /// An unfilled ring (a run that failed).
    Ring(RGBColor),
}

/// Width of the legend panel to the right of the map, pixels.
const LEGEND_W: u32 = 250;

/// Drops points closer than `min_step` to the last kept one (the last point is always
/// kept): a path logged at the odometry rate moves a fraction of a pixel per point, and
/// drawing every one of them only costs time.
fn thin_path(path: &[[f64; 2]], min_step: f64) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for (i, p) in path.iter().enumerate() {
        let keep = match out.last() {
            None => true,
            Some(&(x, y)) => (p[0] - x).hypot(p[1] - y) >= min_step || i + 1 == path.len(),
        };
        if keep {
            out.push((p[0], p[1]));
        }
    }
    out
}

/// Draws a top view of `world` with `overlays` into a PNG at `path`, with a legend that
/// explains every mark in a panel of its own beside the map.
pub fn draw_map(world: &World, overlays: &Overlays, path: &Path) -> Result<(), PlotError> {
    register_fonts();
    let err = |e: &dyn std::fmt::Display| PlotError { file: path.to_path_buf(), message: e.to_string() };
    // The encoder is chosen by the name; other formats' errors are the image crate's own.
    if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        return Err(err(&"the map is drawn as PNG: give a file name ending in .png"));
    }
    let (min, max) = (world.ground.min_m, world.ground.max_m);
    let margin = 1.0;
    let (mut x0, mut x1, y0, y1) = (min[0] - margin, max[0] + margin, min[1] - margin, max[1] + margin);
    // A ground far deeper than wide is drawn at most four widths tall, with x widened to
    // keep metres square: its height would otherwise follow the ratio to millions of pixels.
    const MAX_DEPTH_PER_WIDTH: f64 = 4.0;
    if y1 - y0 > MAX_DEPTH_PER_WIDTH * (x1 - x0) {
        let (centre, half) = ((x0 + x1) / 2.0, (y1 - y0) / MAX_DEPTH_PER_WIDTH / 2.0);
        (x0, x1) = (centre - half, centre + half);
    }
    let map_w = 1200u32;
    let plot_w = map_w - 90;
    let height_px = (((plot_w as f64) * (y1 - y0) / (x1 - x0)) as u32 + 130).max(420);
    write_png(path, (map_w + LEGEND_W, height_px), |root| {
        let err = |e: &dyn std::fmt::Display| e.to_string();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let (map_area, legend_area) = root.split_horizontally(map_w);
        let mut chart = ChartBuilder::on(&map_area)
            .caption(&overlays.title, ("sans-serif", 22).into_font())
            .margin(15)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("x (m)")
            .y_desc("y (m)")
            .light_line_style(WHITE.mix(0.0))
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(|e| err(&e))?;
        let px_per_m = plot_w as f64 / (x1 - x0) * 0.97;
        let mut legend: Vec<(String, Swatch)> = Vec::new();

        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(min[0], min[1]), (max[0], max[1])],
                class_colour(ObjectClass::Ground).filled(),
            )))
            .map_err(|e| err(&e))?;

        // Canopies first (faint), then footprints.
        let canopy = class_colour(ObjectClass::Tree);
        for o in &world.objects {
            if let Shape::Trunk { canopy_radius_m, .. } = o.shape {
                let r = (canopy_radius_m * px_per_m) as i32;
                chart
                    .draw_series(std::iter::once(Circle::new((o.pose.x, o.pose.y), r, canopy.mix(0.12).filled())))
                    .map_err(|e| err(&e))?;
            }
        }
        let mut classes_drawn = std::collections::BTreeSet::new();
        for o in &world.objects {
            let colour = class_colour(o.class);
            let fp = o.shape.footprint(&o.pose);
            let series: Vec<DynElement<'static, BitMapBackend, (f64, f64)>> = match fp {
                worlds::Footprint::Circle { centre, radius } => {
                    vec![
                        Circle::new((centre[0], centre[1]), ((radius * px_per_m) as i32).max(3), colour.filled())
                            .into_dyn(),
                    ]
                }
                worlds::Footprint::Rect { .. } => {
                    let c = fp.corners();
                    vec![Polygon::new(c.iter().map(|p| (p[0], p[1])).collect::<Vec<_>>(), colour.filled()).into_dyn()]
                }
            };
            chart.draw_series(series).map_err(|e| err(&e))?;
            classes_drawn.insert(o.class);
        }
        for class in &classes_drawn {
            let name = match class {
                ObjectClass::Tree => "tree trunk".to_string(),
                other => other.name().to_string(),
            };
            let swatch = if *class == ObjectClass::Wall {
                Swatch::Bar(class_colour(*class))
            } else {
                Swatch::Disc(class_colour(*class))
            };
            legend.push((name, swatch));
            if *class == ObjectClass::Tree {
                legend.push(("tree canopy".into(), Swatch::Faint(canopy, 0.12)));
            }
        }

        if overlays.routes {
            let mut pts: Vec<(f64, f64)> = world.robot.route.waypoints.iter().map(|p| (p[0], p[1])).collect();
            if world.robot.route.looping {
                pts.push(pts[0]);
            }
            chart.draw_series(LineSeries::new(pts, BLUE.stroke_width(2))).map_err(|e| err(&e))?;
            legend.push((format!("robot route ({} laps)", world.robot.laps), Swatch::Line(BLUE, 2)));
            let s = world.robot.start;
            let (dx, dy) = (s.yaw_rad().cos() * 1.0, s.yaw_rad().sin() * 1.0);
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(s.x, s.y), (s.x + dx, s.y + dy)],
                    BLUE.stroke_width(4),
                )))
                .map_err(|e| err(&e))?;
            for p in &world.people {
                let mut pts: Vec<(f64, f64)> = p.route.waypoints.iter().map(|w| (w[0], w[1])).collect();
                if p.route.looping && pts.len() > 2 {
                    pts.push(pts[0]);
                }
                let colour = class_colour(ObjectClass::Person);
                chart.draw_series(DashedLineSeries::new(pts, 6, 4, colour.stroke_width(2))).map_err(|e| err(&e))?;
            }
            if !world.people.is_empty() {
                legend.push(("person's walk".into(), Swatch::Dashed(class_colour(ObjectClass::Person))));
            }
        }
        let min_step = 2.0 / px_per_m;
        let person = class_colour(ObjectClass::Person);
        for track in &overlays.people_tracks {
            chart.draw_series(LineSeries::new(thin_path(track, min_step), person.mix(0.35))).map_err(|e| err(&e))?;
        }
        if overlays.people_tracks.iter().any(|t| t.len() > 1) {
            legend.push(("person's track".into(), Swatch::Line(person, 1)));
        }
        // Drawn as 1-pixel lines side by side: plotters leaves out the parts of a line wider
        // than a pixel that run (nearly) straight up or down.
        let px = 1.0 / px_per_m;
        for (name, colour, path) in &overlays.trajectories {
            let pts = thin_path(path, min_step);
            for (ox, oy) in [(0.0, 0.0), (px, 0.0), (0.0, px), (px, px)] {
                let shifted = pts.iter().map(|(x, y)| (x + ox, y + oy));
                chart.draw_series(LineSeries::new(shifted, colour.stroke_width(1))).map_err(|e| err(&e))?;
            }
            legend.push((name.clone(), Swatch::Line(*colour, 2)));
        }
        for lm in &overlays.landmarks {
            let colour = if lm.flagged { RED } else { BLACK };
            let ellipse = sigma_ellipse(lm.position, lm.covariance, 2.0, 48);
            chart
                .draw_series(std::iter::once(PathElement::new(ellipse, colour.stroke_width(2))))
                .map_err(|e| err(&e))?;
            chart
                .draw_series(std::iter::once(Cross::new((lm.position[0], lm.position[1]), 5, colour.stroke_width(2))))
                .map_err(|e| err(&e))?;
            chart
                .draw_series(std::iter::once(Text::new(
                    lm.label.clone(),
                    (lm.position[0] + 0.3, lm.position[1] + 0.3),
                    ("sans-serif", 12).into_font(),
                )))
                .map_err(|e| err(&e))?;
        }
        if !overlays.landmarks.is_empty() {
            legend.push(("landmark, 2σ ellipse".into(), Swatch::Landmark(BLACK)));
            legend.push(("landmark on no tree".into(), Swatch::Landmark(RED)));
        }

        // Scale bar: 5 m in the lower left corner of the ground.
        let bar = 5.0;
        let (bx, by) = (min[0] + 0.5, min[1] - 0.5);
        chart
            .draw_series(std::iter::once(PathElement::new(vec![(bx, by), (bx + bar, by)], BLACK.stroke_width(4))))
            .map_err(|e| err(&e))?;
        for t in [bx, bx + bar] {
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(t, by - 0.2), (t, by + 0.2)],
                    BLACK.stroke_width(2),
                )))
                .map_err(|e| err(&e))?;
        }
        chart
            .draw_series(std::iter::once(Text::new(
                format!("{bar:.0} m"),
                (bx + bar + 0.3, by + 0.25),
                ("sans-serif", 15).into_font(),
            )))
            .map_err(|e| err(&e))?;

        draw_legend(&legend_area, &legend).map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
        Ok(())
    })
}

/// The legend panel: one row per entry, its swatch then its name.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    entries: &[(String, Swatch)],
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let font = ("sans-serif", 15).into_font();
    let (left, top, row) = (10i32, 60i32, 26i32);
    area.draw(&Text::new("legend", (left, top - 30), ("sans-serif", 16).into_font().style(FontStyle::Bold)))?;
    // Names wider than the panel go on to further rows (a study's names carry the varied
    // parameters and their values, wider than any panel sized in advance).
    let text_left = left + 42;
    let room = (area.dim_in_pixel().0 as i32 - text_left - 6).max(40) as u32;
    let style: TextStyle = font.clone().into();
    let fits = |text: &str| area.estimate_text_size(text, &style).map_or(true, |(w, _)| w <= room);
    let mut wrapped: Vec<Vec<String>> = entries.iter().map(|(name, _)| wrap_to(name, &fits)).collect();
    // Where wrapping would push entries below the panel, every entry keeps one row (its
    // name then runs past the panel's edge, but no entry is lost).
    let rows: usize = wrapped.iter().map(Vec::len).sum();
    if top + rows as i32 * row > area.dim_in_pixel().1 as i32 {
        wrapped = entries.iter().map(|(name, _)| vec![name.clone()]).collect();
    }
    let mut rows_used = 0i32;
    for ((_, swatch), lines) in entries.iter().zip(wrapped) {
        let y = top + rows_used * row;
        rows_used += lines.len().max(1) as i32;
        let (a, b, mid) = (left, left + 30, left + 15);
        match *swatch {
            Swatch::Disc(c) => area.draw(&Circle::new((mid, y), 6, c.filled()))?,
            Swatch::Faint(c, alpha) => area.draw(&Circle::new((mid, y), 11, c.mix(alpha).filled()))?,
            Swatch::Line(c, w) => area.draw(&PathElement::new(vec![(a, y), (b, y)], c.stroke_width(w)))?,
            Swatch::Dashed(c) => {
                for k in 0..3 {
                    area.draw(&PathElement::new(vec![(a + 11 * k, y), (a + 11 * k + 6, y)], c.stroke_width(2)))?;
                }
            }
            Swatch::Landmark(c) => {
                area.draw(&Cross::new((mid, y), 5, c.stroke_width(2)))?;
                let ring: Vec<(i32, i32)> = (0..=24)
                    .map(|k| {
                        let t = std::f64::consts::TAU * k as f64 / 24.0;
                        (mid + (13.0 * t.cos()) as i32, y + (8.0 * t.sin()) as i32)
                    })
                    .collect();
                area.draw(&PathElement::new(ring, c.stroke_width(2)))?;
            }
            Swatch::Bar(c) => area.draw(&Rectangle::new([(a, y - 4), (b, y + 4)], c.filled()))?,
            Swatch::Cross(c) => area.draw(&Cross::new((mid, y), 5, c.stroke_width(2)))?,
            Swatch::Ring(c) => area.draw(&Circle::new((mid, y), 5, c.stroke_width(2)))?,
        }
        for (k, line) in lines.into_iter().enumerate() {
            area.draw(&Text::new(line, (text_left, y - 8 + k as i32 * (row - 6)), font.clone()))?;
        }
    }
    Ok(())
}

/// `text` in lines that each `fits`, broken at spaces, and inside a word too long for a
/// line of its own.
fn wrap_to(text: &str, fits: &dyn Fn(&str) -> bool) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in text.split(' ') {
        let joined = if line.is_empty() { word.to_string() } else { format!("{line} {word}") };
        if fits(&joined) {
            line = joined;
            continue;
        }
        if !line.is_empty() {
            lines.push(std::mem::take(&mut line));
        }
        for c in word.chars() {
            line.push(c);
            if !fits(&line) && line.chars().count() > 1 {
                line.pop();
                lines.push(std::mem::replace(&mut line, c.to_string()));
            }
        }
    }
    if !line.is_empty() || lines.is_empty() {
        lines.push(line);
    }
    lines
}

/// Points of the `k`-sigma ellipse of a 2-D Gaussian.
pub fn sigma_ellipse(mean: [f64; 2], cov: [[f64; 2]; 2], k: f64, n: usize) -> Vec<(f64, f64)> {
    // Eigen-decomposition of a symmetric 2x2 in closed form.
    let (a, b, c) = (cov[0][0], 0.5 * (cov[0][1] + cov[1][0]), cov[1][1]);
    let tr = a + c;
    let det = a * c - b * b;
    let disc = ((tr * tr / 4.0) - det).max(0.0).sqrt();
    let (l1, l2) = ((tr / 2.0 + disc).max(0.0), (tr / 2.0 - disc).max(0.0));
    let angle = if b.abs() > 1e-15 {
        (l1 - a).atan2(b)
    } else if a >= c {
        0.0
    } else {
        std::f64::consts::FRAC_PI_2
    };
    let (s, co) = angle.sin_cos();
    (0..=n)
        .map(|i| {
            let t = std::f64::consts::TAU * i as f64 / n as f64;
            let (u, v) = (k * l1.sqrt() * t.cos(), k * l2.sqrt() * t.sin());
            (mean[0] + co * u - s * v, mean[1] + s * u + co * v)
        })
        .collect()
}

/// The finite extent of `xs`, a unit range about 0 when none is finite (no method, or
/// values beyond f64's range): an infinite or inverted axis would never finish drawing.
fn axis_range(xs: &[f64]) -> (f64, f64) {
    let finite = xs.iter().copied().filter(|x| x.is_finite());
    let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    // The padded span must stay finite too.
    if lo <= hi && (hi - lo).is_finite() { (lo, hi) } else { (0.0, 0.0) }
}

/// Colours of a plot's series, told apart by colour-blind readers too (Okabe-Ito).
const SERIES_PALETTE: [RGBColor; 6] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(86, 180, 233),
    RGBColor(230, 159, 0),
];

/// Width of a study plot without its legend panel, pixels.
const STUDY_PLOT_W: u32 = 900;

/// Costs against a size, one line per named series, on a logarithmic cost axis (the
/// stages differ by orders of magnitude), with the legend in a panel of its own.
pub fn cost_plot(
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[(String, Vec<(f64, f64)>)],
    png: &Path,
) -> Result<(), PlotError> {
    register_fonts();
    write_png(png, (STUDY_PLOT_W + LEGEND_W, 600), |root| draw_costs(root, title, x_desc, y_desc, series))
}

fn draw_costs<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[(String, Vec<(f64, f64)>)],
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let (plot_area, legend_area) = root.split_horizontally(STUDY_PLOT_W);
    let points = || series.iter().flat_map(|(_, p)| p.iter());
    let xs: Vec<f64> = points().map(|p| p.0).filter(|x| x.is_finite()).collect();
    // A log axis needs positive bounds: costs at or below zero are left out.
    let ys: Vec<f64> = points().map(|p| p.1).filter(|y| *y > 0.0 && y.is_finite()).collect();
    let (x_lo, x_hi) = axis_range(&xs);
    let (y_lo, y_hi) = axis_range(&ys);
    let (y_lo, y_hi) = if y_lo > 0.0 { (y_lo / 1.5, y_hi * 1.5) } else { (0.1, 10.0) };
    let pad = if x_hi > x_lo { 0.04 * (x_hi - x_lo) } else { 1.0 };
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(title, ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(65)
        .build_cartesian_2d((x_lo - pad)..(x_hi + pad), (y_lo..y_hi).log_scale())
        .map_err(|x| e(&x))?;
    // The fine grid of a log axis crowds into a grey band near each decade.
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style(("sans-serif", 14))
        .light_line_style(WHITE)
        .draw()
        .map_err(|x| e(&x))?;
    let mut legend = Vec::new();
    for (k, (name, pts)) in series.iter().enumerate() {
        let colour = SERIES_PALETTE[k % SERIES_PALETTE.len()];
        let pts: Vec<(f64, f64)> =
            pts.iter().copied().filter(|p| p.0.is_finite() && p.1.is_finite() && p.1 > 0.0).collect();
        chart.draw_series(LineSeries::new(pts.clone(), colour.stroke_width(3))).map_err(|x| e(&x))?;
        chart.draw_series(pts.iter().map(|p| Circle::new(*p, 4, colour.filled()))).map_err(|x| e(&x))?;
        legend.push((name.clone(), Swatch::Line(colour, 3)));
    }
    draw_legend(&legend_area, &legend).map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// Failure rate against the first varied parameter, one line per method, with 95%
/// intervals; written as PNG and SVG.
/// Writes the PNG, and returns the same plot as SVG text for the caller to write whole.
pub fn failure_rate_plot(
    plan: &crate::montecarlo::StudyPlan,
    rows: &[crate::montecarlo::SummaryRow],
    png: &Path,
) -> Result<String, PlotError> {
    register_fonts();
    // Tall enough for the legend's names wrapped to its panel (at most about 12 pixels a character
    // at its font), so that a study of many series loses none.
    let names: std::collections::BTreeSet<String> = rows.iter().map(series_name).collect();
    let per_row = (LEGEND_W as usize - 58) / 12;
    let legend_rows: usize = names.iter().map(|n| n.chars().count().div_ceil(per_row).max(1)).sum();
    let size = (STUDY_PLOT_W + LEGEND_W, 600.max(90 + 26 * legend_rows as u32));
    write_png(png, size, |root| draw_failure_rate(root, plan, rows))?;
    let mut svg = String::new();
    draw_failure_rate(SVGBackend::with_string(&mut svg, size).into_drawing_area(), plan, rows)
        .map_err(|message| PlotError { file: png.with_extension("svg"), message })?;
    Ok(svg)
}

/// A failure-rate plot's series: the method and the values of the varied parameters after
/// the first (which is the x axis).
fn series_name(r: &crate::montecarlo::SummaryRow) -> String {
    let others: Vec<String> =
        r.params.iter().skip(1).map(|(p, v)| format!("{p}={}", crate::montecarlo::short_number(*v))).collect();
    if others.is_empty() { r.method.clone() } else { format!("{} ({})", r.method, others.join(", ")) }
}

fn draw_failure_rate<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    plan: &crate::montecarlo::StudyPlan,
    rows: &[crate::montecarlo::SummaryRow],
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    // The legend in a panel of its own: inside the plot it would cover points.
    let (plot_area, legend_area) = root.split_horizontally(STUDY_PLOT_W);
    let mut legend: Vec<(String, Swatch)> = Vec::new();
    let param = plan.vary.first().map(|v| v.param.clone()).unwrap_or_else(|| "method".into());
    let xs: Vec<f64> = match plan.vary.first() {
        Some(v) => v.values.clone(),
        None => (0..plan.methods.len()).map(|i| i as f64).collect(),
    };
    let (lo, hi) = axis_range(&xs);
    let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 };
    // The runs each point holds, which a partial merge or a study under way leaves short of
    // the plan's.
    let least = rows.iter().map(|r| r.runs).min().unwrap_or(0);
    let most = rows.iter().map(|r| r.runs).max().unwrap_or(0);
    let per_point = if least == most { format!("{most}") } else { format!("{least}-{most}") };
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(
            format!("{}: association-failure rate ({per_point} runs per point, 95% CI)", plan.scenario),
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(55)
        .build_cartesian_2d((lo - pad)..(hi + pad), -0.02f64..1.02f64)
        .map_err(|x| e(&x))?;
    // One series per (method, values of the other varied parameters).
    let mut series: std::collections::BTreeMap<String, Vec<(f64, f64, f64, f64)>> = Default::default();
    for (i, r) in rows.iter().enumerate() {
        let x = match plan.vary.first() {
            Some(_) => r.params[0].1,
            None => plan.methods.iter().position(|m| *m == r.method).unwrap_or(i) as f64,
        };
        let name = series_name(r);
        if r.failure_rate.is_finite() {
            series.entry(name).or_default().push((x, r.failure_rate, r.failure_rate_ci95.0, r.failure_rate_ci95.1));
        }
    }
    chart
        .configure_mesh()
        .x_desc(if series.len() > 1 { format!("{param} (lines drawn slightly apart)") } else { param.clone() })
        .y_desc("failure rate")
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|x| e(&x))?;
    let palette = SERIES_PALETTE;
    // Methods with equal rates would hide each other's lines: each series is moved sideways
    // by a small step of its own (the x label says so).
    let step = 0.012 * ((hi - lo).max(1e-9) + 2.0 * pad);
    let n = series.len() as f64;
    for (k, (name, pts)) in series.iter().enumerate() {
        let colour = palette[k % palette.len()];
        let dodge = (k as f64 - (n - 1.0) / 2.0) * step;
        let pts: Vec<(f64, f64, f64, f64)> = pts.iter().map(|p| (p.0 + dodge, p.1, p.2, p.3)).collect();
        // The first series solid and wide, the others dashed over it: lines at equal rates
        // show both colours.
        let line: Vec<(f64, f64)> = pts.iter().map(|p| (p.0, p.1)).collect();
        if k == 0 {
            chart.draw_series(LineSeries::new(line, colour.stroke_width(3))).map_err(|x| e(&x))?;
        } else {
            chart
                .draw_series(DashedLineSeries::new(line, 6 + 4 * k as u32, 6, colour.stroke_width(2)))
                .map_err(|x| e(&x))?;
        }
        legend.push((name.clone(), if k == 0 { Swatch::Line(colour, 3) } else { Swatch::Dashed(colour) }));
        chart.draw_series(pts.iter().map(|p| Circle::new((p.0, p.1), 4, colour.filled()))).map_err(|x| e(&x))?;
        chart
            .draw_series(pts.iter().map(|p| ErrorBar::new_vertical(p.0, p.2, p.1, p.3, colour.stroke_width(1), 8)))
            .map_err(|x| e(&x))?;
    }
    draw_legend(&legend_area, &legend).map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// The generalisation benchmark: each run's tree recall by world, `combined` as discs
/// coloured by training seed (filled where the claim held, a ring where it did not) and
/// `jcbb` as black crosses; the caption gives the claim's rate.
pub fn generalisation_plot(
    report: &crate::montecarlo::generalisation::GeneralisationReport,
    combined: &[crate::montecarlo::generalisation::RecallPoint],
    jcbb: &[crate::montecarlo::generalisation::RecallPoint],
    png: &Path,
) -> Result<(), PlotError> {
    register_fonts();
    write_png(png, (STUDY_PLOT_W + LEGEND_W, 600), |root| draw_generalisation(root, report, combined, jcbb))
}

fn draw_generalisation<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    report: &crate::montecarlo::generalisation::GeneralisationReport,
    combined: &[crate::montecarlo::generalisation::RecallPoint],
    jcbb: &[crate::montecarlo::generalisation::RecallPoint],
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let (plot_area, legend_area) = root.split_horizontally(STUDY_PLOT_W);
    let claim = match report.claim.rate {
        Some(r) => format!("claim held in {:.0}% of {} runs", 100.0 * r, report.claim.runs),
        None => "no run scored".into(),
    };
    let worlds = report.worlds.max(1) as f64;
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(format!("generalisation ({} split): {claim}", report.split.name()), ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(55)
        .build_cartesian_2d(-0.5f64..(worlds - 0.5), -0.02f64..1.05f64)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_labels(report.worlds.clamp(2, 21))
        .x_label_formatter(&|x| format!("{x:.0}"))
        .x_desc("world (index in the split)")
        .y_desc("tree recall (combined: of trees in view; jcbb: of trees the laser saw)")
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|x| e(&x))?;
    let palette = SERIES_PALETTE;
    let seeds = &report.training_seeds;
    let mut legend: Vec<(String, Swatch)> = Vec::new();
    for (k, seed) in seeds.iter().enumerate() {
        let colour = palette[k % palette.len()];
        // Seeds side by side within a world, so equal recalls stay visible.
        let dodge = (k as f64 - (seeds.len() as f64 - 1.0) / 2.0) * 0.08;
        let points: Vec<_> = combined.iter().filter(|p| p.training_seed == Some(*seed)).collect();
        chart
            .draw_series(points.iter().map(|p| {
                let style = if p.claim { colour.filled() } else { colour.stroke_width(2) };
                Circle::new((p.world as f64 + dodge, p.recall), 5, style)
            }))
            .map_err(|x| e(&x))?;
        legend.push((format!("combined, training seed {seed}"), Swatch::Disc(colour)));
    }
    chart
        .draw_series(jcbb.iter().map(|p| Cross::new((p.world as f64 + 0.3, p.recall), 5, BLACK.stroke_width(2))))
        .map_err(|x| e(&x))?;
    legend.push(("jcbb".into(), Swatch::Cross(BLACK)));
    legend.push(("ring: the claim failed".into(), Swatch::Ring(RGBColor(90, 90, 90))));
    draw_legend(&legend_area, &legend).map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// The map of a replayed log: the reference track (GPS or ground truth) in grey, the
/// estimated path in blue and the mapped landmarks as black dots, all in the reference's
/// frame.
pub fn draw_replay_map(
    title: &str,
    path: &[[f64; 2]],
    reference: &[[f64; 2]],
    dropped: &[[f64; 2]],
    landmarks: &[[f64; 2]],
    file: &Path,
) -> Result<(), PlotError> {
    register_fonts();
    // Bounds without the dropped fixes (a spike can be kilometres away): those beyond the
    // map are drawn at its edge.
    let all: Vec<&[f64; 2]> = path.iter().chain(reference).chain(landmarks).collect();
    let (xs, ys): (Vec<f64>, Vec<f64>) = all.iter().map(|p| (p[0], p[1])).unzip();
    let (x0, x1) = axis_range(&xs);
    let (y0, y1) = axis_range(&ys);
    // Equal scales on both axes: a map, not a chart.
    let span = (x1 - x0).max(y1 - y0).max(1.0) * 1.05;
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    write_png(file, (1000, 1000), |root| {
        let e = |x: &dyn std::fmt::Display| x.to_string();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d((cx - span / 2.0)..(cx + span / 2.0), (cy - span / 2.0)..(cy + span / 2.0))
            .map_err(|x| e(&x))?;
        chart
            .configure_mesh()
            .x_desc("x (m)")
            .y_desc("y (m)")
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|x| e(&x))?;
        let grey = RGBColor(150, 150, 150);
        chart
            .draw_series(reference.iter().map(|p| Circle::new((p[0], p[1]), 1, grey.filled())))
            .map_err(|x| e(&x))?
            .label("reference")
            .legend(move |(x, y)| Circle::new((x + 10, y), 3, grey.filled()));
        chart
            .draw_series(LineSeries::new(path.iter().map(|p| (p[0], p[1])), BLUE.stroke_width(1)))
            .map_err(|x| e(&x))?
            .label("estimate")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
        chart
            .draw_series(landmarks.iter().map(|p| Circle::new((p[0], p[1]), 2, BLACK.filled())))
            .map_err(|x| e(&x))?
            .label("landmarks")
            .legend(|(x, y)| Circle::new((x + 10, y), 3, BLACK.filled()));
        if !dropped.is_empty() {
            let red = RGBColor(200, 0, 0);
            chart
                .draw_series(dropped.iter().map(|p| {
                    let (x, y) =
                        (p[0].clamp(cx - span / 2.0, cx + span / 2.0), p[1].clamp(cy - span / 2.0, cy + span / 2.0));
                    Cross::new((x, y), 6, red.stroke_width(2))
                }))
                .map_err(|x| e(&x))?
                .label("GPS fix dropped as a spike")
                .legend(move |(x, y)| Cross::new((x + 10, y), 5, red.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|x| e(&x))?;
        root.present().map_err(|x| e(&x))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A picture that cannot be written leaves no file of its own, cut or partial, and says
    /// why in the system's words.
    #[test]
    fn a_picture_that_cannot_be_written_leaves_nothing_behind() {
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        let file = dir.join("map.png");
        std::fs::create_dir_all(&file).unwrap();
        let path = [[0.0, 0.0], [1.0, 1.0]];
        let e = draw_replay_map("t", &path, &path, &[], &path, &file).unwrap_err();
        assert_eq!(e.file, file);
        assert!(!e.message.contains("Error("), "no debug dump: {}", e.message);
        let left: Vec<_> = std::fs::read_dir(dir).unwrap().map(|f| f.unwrap().file_name()).collect();
        assert_eq!(left, vec![std::ffi::OsString::from("map.png")], "no partial picture");
        std::fs::remove_dir_all(&file).unwrap();
        draw_replay_map("t", &path, &path, &[], &path, &file).unwrap();
        assert_eq!(image::open(&file).unwrap().to_rgb8().dimensions(), (1000, 1000));
    }

    /// A ground a thousand times deeper than wide is drawn at most four widths tall (it had
    /// been a PNG a million pixels tall, gigabytes while drawn).
    #[test]
    fn a_narrow_ground_makes_a_picture_of_bounded_height() {
        let scratch = tempfile::tempdir().unwrap();
        let mut w = worlds::generate::preset("park", None, 3).unwrap();
        w.ground.min_m = [-1.0, -1000.0];
        w.ground.max_m = [1.0, 1000.0];
        let file = scratch.path().join("narrow.png");
        draw_map(&w, &Overlays::default(), &file).unwrap();
        let (width, height) = image::image_dimensions(&file).unwrap();
        assert!(height <= 4 * 1200 + 130, "{width} x {height}");
    }

    /// A legend name too wide for its panel goes on to further rows, whole words where
    /// they fit, and loses no character.
    #[test]
    fn long_legend_names_wrap_and_lose_nothing() {
        let fits = |t: &str| t.chars().count() <= 12;
        let name = "jcbb (sim.odometry.scale_sigma=0.02, a=1)";
        let lines = wrap_to(name, &fits);
        assert!(lines.iter().all(|l| fits(l)), "{lines:?}");
        assert_eq!(lines[0], "jcbb", "{lines:?}");
        assert_eq!(lines.concat().replace(' ', ""), name.replace(' ', ""));
        assert_eq!(wrap_to("nn", &fits), vec!["nn".to_string()]);
        assert_eq!(wrap_to("", &fits), vec![String::new()]);
    }

    #[test]
    fn axes_are_finite_whatever_the_values() {
        assert_eq!(axis_range(&[]), (0.0, 0.0));
        assert_eq!(axis_range(&[f64::INFINITY, f64::NEG_INFINITY, f64::NAN]), (0.0, 0.0));
        assert_eq!(axis_range(&[-f64::MAX, f64::MAX]), (0.0, 0.0), "a span beyond f64");
        assert_eq!(axis_range(&[2.0, 0.5, f64::NAN]), (0.5, 2.0));
    }

    #[test]
    fn sigma_ellipse_of_axis_aligned_covariance() {
        let pts = sigma_ellipse([1.0, 2.0], [[4.0, 0.0], [0.0, 1.0]], 2.0, 4);
        // Semi-axes 2*2 = 4 along x and 2*1 = 2 along y.
        assert!((pts[0].0 - 5.0).abs() < 1e-9 && (pts[0].1 - 2.0).abs() < 1e-9);
        assert!((pts[1].0 - 1.0).abs() < 1e-9 && (pts[1].1 - 4.0).abs() < 1e-9);
    }

    #[test]
    fn world_map_renders_to_png() {
        let world = worlds::generate::park(&Default::default(), 5).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.png");
        draw_map(&world, &Overlays { title: "park".into(), routes: true, ..Default::default() }, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        // Tree green must appear (objects were drawn), and white margins exist.
        let green = img.pixels().filter(|p| p.0 == [34, 139, 34]).count();
        assert!(green > 50, "only {green} tree-coloured pixels");
    }

    /// The path the robot drives twice round `paper_park`'s loop, logged at the odometry
    /// rate, is drawn without a gap: plotters fills a wide line as one polygon, and that
    /// polygon lost the loop's straights (they showed broken, or not at all). And the legend
    /// beside the map names the path without covering the map.
    #[test]
    fn a_driven_path_is_drawn_whole_and_the_legend_stays_beside_the_map() {
        let world = worlds::generate::park(&Default::default(), 2006).unwrap();
        let config = sim::SimConfig {
            camera: sim::camera::CameraConfig { enabled: false, ..Default::default() },
            ..Default::default()
        };
        let mut simulation = sim::Simulation::new(&world, &config, 1).unwrap();
        let mut driven: Vec<[f64; 2]> = Vec::new();
        while let Some(event) = simulation.next_event() {
            if let sim::SensorEvent::Odometry { truth, .. } = event {
                driven.push([truth.robot.x, truth.robot.y]);
            }
        }
        assert!(simulation.route_progress() > 0.99 && driven.len() > 5000);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.png");
        let colour = RGBColor(0, 0, 255);
        let overlays = Overlays {
            title: "driven path".into(),
            trajectories: vec![("path".into(), colour, driven)],
            ..Default::default()
        };
        draw_map(&world, &overlays, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        let map_w = img.width() - LEGEND_W;
        // The rows where the loop's east side shows, in the right half of the map: pixels of
        // the path's blue, within a tolerance (a grid line drawn under it tints a few).
        let blue = |p: &image::Rgb<u8>| p.0[2] >= 220 && p.0[0] <= 80 && p.0[1] <= 80;
        let rows: Vec<u32> =
            (0..img.height()).filter(|&y| (map_w / 2 + 20..map_w).any(|x| blue(img.get_pixel(x, y)))).collect();
        let (first, last) = (rows[0], rows[rows.len() - 1]);
        assert!(last - first > 300, "the path spans {first}..{last}");
        assert_eq!(rows.len() as u32, last - first + 1, "rows without the path between {first} and {last}");
        // The legend's swatch is in the panel to the right of the map.
        let in_legend = (map_w..img.width()).flat_map(|x| (0..img.height()).map(move |y| (x, y)));
        assert!(in_legend.filter(|&(x, y)| blue(img.get_pixel(x, y))).count() > 20);
    }
}
