//! PNG plots of a run: velocities, ECP, impulses, contact mode, solver statistics and a
//! top-view footprint of the body with its contact patch.
//!
//! Rendering uses plotters' bitmap backend with the bundled DejaVu Sans font (there are no
//! system fonts with the `ab_glyph` feature). Non-finite values in the records are skipped:
//! lines break at them and axis ranges come from the finite values only.
//!
//! With several bodies or contacts, the time-series plots show up to three of them (legend
//! suffix `[body]` or `[body/plane k]`), and the footprint shows them against plane 0. A
//! multi-body run (one with contact pairs) also gets a top view of all its bodies and loaded
//! contacts and the impulses per pair (`plots/bodies.rs`).

mod bodies;

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use nalgebra::Vector3;
use plotters::coord::Shift;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use ecp_formulations::geometry::{ContactMode, HalfSpace, convex_hull_2d, world_vertices};
use ecp_formulations::rotation::rotation_matrix;
use ecp_formulations::{BodyState, ContactRecord, MODE_TOLERANCE, Scene, StepRecord};

/// Most bodies (or contacts) drawn as separate series in one plot; the rest are left out.
const MAX_SERIES: usize = 3;

/// Font family registered from the bundled font and used for every text.
pub(crate) const FONT: &str = "sans-serif";
/// Size of the time-series figures (pixels).
const SIZE: (u32, u32) = (1100, 650);
/// Size of the footprint figure (pixels).
const FOOTPRINT_SIZE: (u32, u32) = (1100, 800);
/// Width of the legend strip at the right of each panel (pixels).
const LEGEND_WIDTH: u32 = 210;
/// Number of evenly spaced instants in the footprint plot, besides the first step.
const FOOTPRINT_INSTANTS: usize = 5;

/// Matplotlib's "tab10" palette: distinct hues that stay apart when lightened.
pub(crate) const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// Why plots could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The output directory could not be created.
    #[error("cannot create the plot directory {path}: {source}")]
    Io {
        /// The directory.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// Drawing or encoding a plot failed.
    #[error("cannot draw the plot {path}: {message}")]
    Draw {
        /// The image being written.
        path: PathBuf,
        /// What plotters reported.
        message: String,
    },
    /// The bundled font could not be registered.
    #[error("cannot load the bundled plot font (assets/DejaVuSans.ttf): {0}")]
    Font(String),
}

/// Writes the PNG plots of a run into `dir` (created if missing); returns the paths written.
///
/// Without records there is nothing to plot: the result is `Ok` with no paths and `dir` is
/// not created.
pub fn write_plots(
    dir: &Path,
    scene: &Scene,
    records: &[StepRecord],
) -> Result<Vec<PathBuf>, PlotError> {
    if records.is_empty() {
        return Ok(Vec::new());
    }
    register_bundled_font()?;
    std::fs::create_dir_all(dir).map_err(|source| PlotError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    type PlotFn = fn(&Area<'_>, &Scene, &[StepRecord]) -> Result<(), DrawError>;
    let plots: [(&str, (u32, u32), PlotFn); 6] = [
        ("velocity.png", SIZE, velocity_plot),
        ("ecp.png", SIZE, ecp_plot),
        ("impulses.png", SIZE, impulse_plot),
        ("contact_mode.png", SIZE, mode_plot),
        ("solver.png", SIZE, solver_plot),
        ("footprint.png", FOOTPRINT_SIZE, footprint_plot),
    ];
    let mut written = Vec::with_capacity(plots.len());
    for (name, size, plot) in plots {
        let path = dir.join(name);
        render(&path, size, |root| plot(root, scene, records)).map_err(|e| PlotError::Draw {
            path: path.clone(),
            message: e.0,
        })?;
        written.push(path);
    }
    if bodies::is_multibody(records) {
        written.extend(bodies::write(dir, scene, records)?);
    }
    Ok(written)
}

/// One panel of a figure drawn by [`write_time_series`]: curves `(label, points (t, y))`.
#[derive(Clone, Debug, Default)]
pub struct TimePanel {
    /// Panel title.
    pub title: String,
    /// y-axis description.
    pub y_desc: &'static str,
    /// Logarithmic y axis (non-positive values are left out).
    pub log_y: bool,
    /// The curves, in legend order.
    pub curves: Vec<(String, Vec<(f64, f64)>)>,
}

/// Writes a figure of stacked time-series panels (shared t axis) to `path`, in the style of the
/// run plots: used by reports that put several runs side by side.
pub fn write_time_series(path: &Path, title: &str, panels: &[TimePanel]) -> Result<(), PlotError> {
    register_bundled_font()?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| PlotError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    let panels: Vec<Panel> = panels
        .iter()
        .map(|p| Panel {
            title: p.title.clone(),
            x_desc: "t [s]",
            y_desc: p.y_desc,
            y_axis: if p.log_y { YAxis::Log } else { YAxis::Linear },
            series: p
                .curves
                .iter()
                .enumerate()
                .map(|(k, (label, points))| {
                    let points = if p.log_y {
                        points.iter().filter(|(_, y)| *y > 0.0).copied().collect()
                    } else {
                        points.clone()
                    };
                    Series::new(label.clone(), points, PALETTE[k % PALETTE.len()])
                })
                .collect(),
        })
        .collect();
    let height = 120 + 330 * panels.len() as u32;
    render(path, (SIZE.0, height), |root| {
        draw_figure(root, title, &panels)
    })
    .map_err(|e| PlotError::Draw {
        path: path.to_path_buf(),
        message: e.0,
    })
}

/// Registers the bundled font once per process; later calls return the first outcome.
pub(crate) fn register_bundled_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font(
                FONT,
                FontStyle::Normal,
                include_bytes!("../../assets/DejaVuSans.ttf"),
            )
            .map_err(|_| "not a valid TrueType font".to_string())
        })
        .clone()
        .map_err(PlotError::Font)
}

/// A drawing area in pixel coordinates.
type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// A drawing failure, as plotters' message (the path is added by [`write_plots`]).
#[derive(Debug)]
struct DrawError(String);

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for DrawError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        DrawError(e.to_string())
    }
}

/// Draws one PNG: white background, `draw`, then encodes and writes the file.
fn render(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&Area<'_>) -> Result<(), DrawError>,
) -> Result<(), DrawError> {
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    draw(&root)?;
    // `present` reports encoding and I/O errors, which dropping the backend would swallow.
    root.present()?;
    Ok(())
}

fn font(size: u32) -> FontDesc<'static> {
    (FONT, size).into_font()
}

// ---------------------------------------------------------------------------------------------
// Data access
// ---------------------------------------------------------------------------------------------

/// Bodies present in the records, capped for plotting.
fn body_count(records: &[StepRecord]) -> usize {
    let n = records.iter().map(|r| r.bodies.len()).max().unwrap_or(0);
    n.min(MAX_SERIES)
}

/// Contacts present in the records, capped for plotting.
fn contact_count(records: &[StepRecord]) -> usize {
    let n = records.iter().map(|r| r.contacts.len()).max().unwrap_or(0);
    n.min(MAX_SERIES)
}

/// Legend suffix for body `b`: empty when there is only one body.
fn body_suffix(scene: &Scene, b: usize, count: usize) -> String {
    if count <= 1 {
        return String::new();
    }
    match scene.bodies.get(b) {
        Some(spec) => format!(" [{}]", spec.name),
        None => format!(" [body {b}]"),
    }
}

/// Contacts per body in the records (the hull formulation has one per plane; the union and
/// point formulations have one per piece or point and plane).
fn contacts_per_body(scene: &Scene, records: &[StepRecord]) -> usize {
    let contacts = records.iter().map(|r| r.contacts.len()).max().unwrap_or(0);
    (contacts / scene.bodies.len().max(1)).max(1)
}

/// Legend suffix for contact `c` (body-major): empty when there is only one.
fn contact_suffix(scene: &Scene, c: usize, count: usize, per_body: usize) -> String {
    if count <= 1 {
        return String::new();
    }
    let (b, j) = (c / per_body, c % per_body);
    let body = scene
        .bodies
        .get(b)
        .map_or_else(|| format!("body {b}"), |s| s.name.clone());
    if per_body > 1 {
        format!(" [{body}/contact {j}]")
    } else {
        format!(" [{body}]")
    }
}

/// `(t, f(body state))` for every record; NaN where the body is missing.
fn body_points(records: &[StepRecord], b: usize, f: impl Fn(&BodyState) -> f64) -> Vec<(f64, f64)> {
    records
        .iter()
        .map(|r| (r.t, r.bodies.get(b).map_or(f64::NAN, &f)))
        .collect()
}

/// `(t, f(contact record))` for every record; NaN where the contact is missing.
fn contact_points(
    records: &[StepRecord],
    c: usize,
    f: impl Fn(&ContactRecord) -> f64,
) -> Vec<(f64, f64)> {
    records
        .iter()
        .map(|r| (r.t, r.contacts.get(c).map_or(f64::NAN, &f)))
        .collect()
}

/// Variant `index` of colour `c` (lighter or darker), telling apart the series of further
/// bodies or contacts drawn in the same colour family.
fn shade(c: RGBColor, index: usize) -> RGBColor {
    const AMOUNTS: [f64; 4] = [0.0, 0.45, -0.4, 0.7];
    let a = AMOUNTS[index % AMOUNTS.len()];
    let mix = |v: u8| {
        let v = f64::from(v);
        let target = if a > 0.0 { 255.0 } else { 0.0 };
        (v + (target - v) * a.abs()).round() as u8
    };
    RGBColor(mix(c.0), mix(c.1), mix(c.2))
}

// ---------------------------------------------------------------------------------------------
// Axis ranges
// ---------------------------------------------------------------------------------------------

/// Range of the finite values, padded by 5 % on each side; a constant series gets a range
/// around its value, no finite value gives about `-1..1`.
fn linear_range(values: impl IntoIterator<Item = f64>) -> Range<f64> {
    let (lo, hi) = finite_bounds(values).unwrap_or((-1.0, 1.0));
    pad_range(lo, hi)
}

fn finite_bounds(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })
}

fn pad_range(lo: f64, hi: f64) -> Range<f64> {
    // Halving first keeps the span finite for values near ±f64::MAX.
    let half_span = hi / 2.0 - lo / 2.0;
    let scale = lo.abs().max(hi.abs());
    let pad = if half_span > 1e-9 * scale && half_span > f64::MIN_POSITIVE {
        0.1 * half_span
    } else if scale > 0.0 {
        0.1 * scale
    } else {
        1.0
    };
    (lo - pad).max(-f64::MAX)..(hi + pad).min(f64::MAX)
}

/// Range for a log axis from the finite positive values, padded by a factor 2 (and widened
/// to at least a decade); `1e-16..1` without any.
fn log_range(values: impl IntoIterator<Item = f64>) -> Range<f64> {
    let positive = values.into_iter().filter(|v| *v > 0.0);
    let (lo, hi) = finite_bounds(positive).unwrap_or((1e-16, 1.0));
    // Clamped so that subnormal or huge values still give a valid, finite range.
    let (lo, hi) = ((lo / 2.0).max(f64::MIN_POSITIVE), (hi * 2.0).min(f64::MAX));
    if hi / lo < 10.0 {
        let mid = (lo * hi).sqrt();
        mid / 10f64.sqrt()..mid * 10f64.sqrt()
    } else {
        lo..hi
    }
}

// ---------------------------------------------------------------------------------------------
// Time-series panels
// ---------------------------------------------------------------------------------------------

/// How a series is drawn.
#[derive(Clone, Copy, PartialEq)]
enum Stroke {
    Solid,
    Dashed,
    /// Isolated markers (circles), for flagged points.
    Markers,
}

/// One line (or set of markers) of a panel.
struct Series {
    label: String,
    points: Vec<(f64, f64)>,
    color: RGBColor,
    stroke: Stroke,
}

impl Series {
    fn new(label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Series {
            label: label.into(),
            points,
            color,
            stroke: Stroke::Solid,
        }
    }

    fn with_stroke(mut self, stroke: Stroke) -> Self {
        self.stroke = stroke;
        self
    }
}

/// The y axis of a panel.
enum YAxis {
    /// Linear, from the data.
    Linear,
    /// Linear from 0, for counts.
    Count,
    /// Logarithmic, from the positive data.
    Log,
    /// Categories at 0, 1, 2, … named by the slice.
    Categories(&'static [&'static str]),
}

/// One chart of a figure.
struct Panel {
    title: String,
    x_desc: &'static str,
    y_desc: &'static str,
    y_axis: YAxis,
    series: Vec<Series>,
}

/// Draws a figure: a title over `panels` stacked vertically, each with a legend at its right.
/// The panels share the x range.
fn draw_figure(root: &Area<'_>, title: &str, panels: &[Panel]) -> Result<(), DrawError> {
    let body = root.titled(title, font(26))?;
    let x_range = linear_range(
        panels
            .iter()
            .flat_map(|p| &p.series)
            .flat_map(|s| s.points.iter().filter(|p| p.1.is_finite()).map(|p| p.0)),
    );
    for (area, panel) in body.split_evenly((panels.len(), 1)).iter().zip(panels) {
        let (width, _) = area.dim_in_pixel();
        let (chart_area, legend_area) = area.split_horizontally(width.saturating_sub(LEGEND_WIDTH));
        draw_panel(&chart_area, panel, x_range.clone())?;
        let entries: Vec<LegendEntry> = panel
            .series
            .iter()
            .map(|s| LegendEntry {
                label: s.label.clone(),
                color: s.color,
                glyph: match s.stroke {
                    Stroke::Solid => Glyph::Line,
                    Stroke::Dashed => Glyph::Dashed,
                    Stroke::Markers => Glyph::Circle,
                },
            })
            .collect();
        draw_legend(&legend_area, &entries)?;
    }
    Ok(())
}

/// Builds the chart of one panel with the y coordinate its axis kind needs.
fn draw_panel(area: &Area<'_>, panel: &Panel, x_range: Range<f64>) -> Result<(), DrawError> {
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(&panel.title, font(20))
        .margin(8)
        .x_label_area_size(42)
        .y_label_area_size(82);
    let ys = || {
        panel
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.1))
    };
    match panel.y_axis {
        YAxis::Linear => {
            let y_range = linear_range(ys());
            let span = y_range.end - y_range.start;
            let chart = builder.build_cartesian_2d(x_range, y_range)?;
            finish_panel(chart, panel, &|y: &f64| tick_label(*y, span))
        }
        YAxis::Count => {
            let max = finite_bounds(ys()).map_or(1.0, |(_, hi)| hi.max(1.0));
            let chart = builder.build_cartesian_2d(x_range, 0.0..max * 1.1)?;
            // Counts are whole: ticks between them stay unlabelled.
            let label = |y: &f64| {
                let i = y.round();
                if (y - i).abs() < 1e-6 {
                    format!("{i}")
                } else {
                    String::new()
                }
            };
            finish_panel(chart, panel, &label)
        }
        YAxis::Log => {
            let chart = builder.build_cartesian_2d(x_range, log_range(ys()).log_scale())?;
            finish_panel(chart, panel, &|y: &f64| format!("{y:.0e}"))
        }
        YAxis::Categories(names) => {
            let top = names.len() as f64 - 0.5;
            let chart = builder.build_cartesian_2d(x_range, -0.5..top)?;
            // Ticks fall on halves too; only the whole ones are categories.
            let label = |y: &f64| {
                let i = y.round();
                if (y - i).abs() < 1e-6 && i >= 0.0 {
                    names
                        .get(i as usize)
                        .map_or(String::new(), |s| s.to_string())
                } else {
                    String::new()
                }
            };
            finish_panel(chart, panel, &label)
        }
    }
}

/// Short tick label without float noise; values below 1e-9 of the axis `span` are 0 (the
/// tick generator yields e.g. -5.6e-17 for zero).
fn tick_label(v: f64, span: f64) -> String {
    let a = v.abs();
    if a <= 1e-9 * span {
        "0".into()
    } else if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.1e}")
    } else {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" { "0".into() } else { s.into() }
    }
}

/// Mesh, axis descriptions and series of a panel whose chart is built.
fn finish_panel<Y>(
    mut chart: ChartContext<'_, BitMapBackend<'_>, Cartesian2d<RangedCoordf64, Y>>,
    panel: &Panel,
    y_label: &dyn Fn(&f64) -> String,
) -> Result<(), DrawError>
where
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let x_span = chart.x_range().end - chart.x_range().start;
    chart
        .configure_mesh()
        .x_desc(panel.x_desc)
        .y_desc(panel.y_desc)
        .axis_desc_style(font(17))
        .label_style(font(15))
        .x_label_formatter(&|x| tick_label(*x, x_span))
        .y_label_formatter(y_label)
        .y_labels(match panel.y_axis {
            YAxis::Categories(names) => 2 * names.len() + 1,
            _ => 10,
        })
        .light_line_style(RGBAColor(0, 0, 0, 0.04))
        .bold_line_style(RGBAColor(0, 0, 0, 0.15))
        .draw()?;
    let finite = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite();
    if !panel.series.iter().any(|s| s.points.iter().any(finite)) {
        let area = chart.plotting_area().strip_coord_spec();
        let (w, h) = area.dim_in_pixel();
        let style = TextStyle::from(font(18)).pos(Pos::new(HPos::Center, VPos::Center));
        let center = (w as i32 / 2, h as i32 / 2);
        area.draw_text("no finite values to plot", &style, center)?;
    }
    for s in &panel.series {
        match s.stroke {
            Stroke::Markers => {
                let style = s.color.filled();
                let points = s
                    .points
                    .iter()
                    .filter(|p| p.0.is_finite() && p.1.is_finite());
                chart.draw_series(points.map(|p| Circle::new(*p, 5, style)))?;
            }
            Stroke::Solid | Stroke::Dashed => {
                let style = s.color.stroke_width(2);
                for segment in finite_segments(&s.points) {
                    if s.stroke == Stroke::Dashed {
                        chart.draw_series(DashedLineSeries::new(segment, 8, 5, style))?;
                    } else {
                        chart.draw_series(LineSeries::new(segment, style))?;
                    }
                }
            }
        }
    }
    Ok(())
}

/// Splits a polyline at non-finite points, so that gaps stay visible instead of being bridged.
fn finite_segments(points: &[(f64, f64)]) -> Vec<Vec<(f64, f64)>> {
    points
        .split(|p| !(p.0.is_finite() && p.1.is_finite()))
        .filter(|s| !s.is_empty())
        .map(<[_]>::to_vec)
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Legend
// ---------------------------------------------------------------------------------------------

/// The sample drawn in front of a legend label.
#[derive(Clone, Copy)]
enum Glyph {
    Line,
    Dashed,
    Circle,
    Cross,
    /// Marker with a black border (the ECP in the footprint).
    BorderedCircle,
    /// Translucent filled square (the contact patch).
    Fill,
    /// Small dot.
    Dot,
    /// Filled triangle (an ECP between two bodies).
    Triangle,
}

struct LegendEntry {
    label: String,
    color: RGBColor,
    glyph: Glyph,
}

/// Draws a legend in its own area (so that it never hides data).
fn draw_legend(area: &Area<'_>, entries: &[LegendEntry]) -> Result<(), DrawError> {
    let text = TextStyle::from(font(15))
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    for (i, e) in entries.iter().enumerate() {
        let y = 48 + 24 * i as i32;
        let c = e.color;
        match e.glyph {
            Glyph::Line => {
                area.draw(&PathElement::new(vec![(6, y), (40, y)], c.stroke_width(3)))?
            }
            Glyph::Dashed => {
                for x in [6, 20, 34] {
                    area.draw(&PathElement::new(
                        vec![(x, y), (x + 8, y)],
                        c.stroke_width(3),
                    ))?;
                }
            }
            Glyph::Circle => area.draw(&Circle::new((23, y), 5, c.filled()))?,
            Glyph::Cross => area.draw(&Cross::new((23, y), 6, c.stroke_width(2)))?,
            Glyph::BorderedCircle => {
                area.draw(&Circle::new((23, y), 6, c.filled()))?;
                area.draw(&Circle::new((23, y), 6, BLACK.stroke_width(1)))?;
            }
            Glyph::Fill => {
                area.draw(&Rectangle::new(
                    [(10, y - 7), (36, y + 7)],
                    c.mix(0.3).filled(),
                ))?;
                area.draw(&Rectangle::new(
                    [(10, y - 7), (36, y + 7)],
                    c.stroke_width(2),
                ))?;
            }
            Glyph::Dot => area.draw(&Circle::new((23, y), 3, c.filled()))?,
            Glyph::Triangle => {
                area.draw(&TriangleMarker::new((23, y), 8, c.filled()))?;
            }
        }
        area.draw_text(&e.label, &text, (48, y))?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The plots
// ---------------------------------------------------------------------------------------------

/// Components `(name, colour, accessor)` of a vector-valued body quantity.
type Component<T> = (&'static str, RGBColor, fn(&T) -> f64);

/// Series of the given body components, one per body and component.
fn body_series(
    scene: &Scene,
    records: &[StepRecord],
    components: &[Component<BodyState>],
    stroke: Stroke,
    prefix: &str,
) -> Vec<Series> {
    let bodies = body_count(records);
    (0..bodies)
        .flat_map(|b| {
            components.iter().map(move |(name, color, f)| {
                let label = format!("{prefix}{name}{}", body_suffix(scene, b, bodies));
                Series::new(label, body_points(records, b, f), shade(*color, b)).with_stroke(stroke)
            })
        })
        .collect()
}

/// Series of the given contact components, one per contact and component.
fn contact_series(
    scene: &Scene,
    records: &[StepRecord],
    components: &[Component<ContactRecord>],
) -> Vec<Series> {
    let contacts = contact_count(records);
    let per_body = contacts_per_body(scene, records);
    (0..contacts)
        .flat_map(|c| {
            components.iter().map(move |(name, color, f)| {
                let label = format!("{name}{}", contact_suffix(scene, c, contacts, per_body));
                Series::new(label, contact_points(records, c, f), shade(*color, c))
            })
        })
        .collect()
}

fn velocity_plot(root: &Area<'_>, scene: &Scene, records: &[StepRecord]) -> Result<(), DrawError> {
    let linear: [Component<BodyState>; 3] = [
        ("vx", PALETTE[0], |s| s.v.x),
        ("vy", PALETTE[1], |s| s.v.y),
        ("vz", PALETTE[2], |s| s.v.z),
    ];
    let angular: [Component<BodyState>; 3] = [
        ("ωx", PALETTE[3], |s| s.w.x),
        ("ωy", PALETTE[4], |s| s.w.y),
        ("ωz", PALETTE[5], |s| s.w.z),
    ];
    let panels = [
        Panel {
            title: "Linear velocity of the CM".into(),
            x_desc: "t [s]",
            y_desc: "v [m/s]",
            y_axis: YAxis::Linear,
            series: body_series(scene, records, &linear, Stroke::Solid, ""),
        },
        Panel {
            title: "Angular velocity (world frame)".into(),
            x_desc: "t [s]",
            y_desc: "ω [rad/s]",
            y_axis: YAxis::Linear,
            series: body_series(scene, records, &angular, Stroke::Solid, ""),
        },
    ];
    draw_figure(root, &format!("{}: velocities", scene.name), &panels)
}

fn ecp_plot(root: &Area<'_>, scene: &Scene, records: &[StepRecord]) -> Result<(), DrawError> {
    let ecp: [Component<ContactRecord>; 3] = [
        ("ecp_x", PALETTE[0], |c| c.a1.x),
        ("ecp_y", PALETTE[1], |c| c.a1.y),
        ("ecp_z", PALETTE[2], |c| c.a1.z),
    ];
    let cm: [Component<BodyState>; 3] = [
        ("x", PALETTE[0], |s| s.x.x),
        ("y", PALETTE[1], |s| s.x.y),
        ("z", PALETTE[2], |s| s.x.z),
    ];
    let mut series = contact_series(scene, records, &ecp);
    series.extend(body_series(scene, records, &cm, Stroke::Dashed, "CM "));
    let panels = [Panel {
        title: "Equivalent contact point a1 (solid) and CM position (dashed), world frame".into(),
        x_desc: "t [s]",
        y_desc: "position [m]",
        y_axis: YAxis::Linear,
        series,
    }];
    draw_figure(
        root,
        &format!("{}: equivalent contact point", scene.name),
        &panels,
    )
}

fn impulse_plot(root: &Area<'_>, scene: &Scene, records: &[StepRecord]) -> Result<(), DrawError> {
    let forces: [Component<ContactRecord>; 3] = [
        ("pn", PALETTE[0], |c| c.pn),
        ("pt", PALETTE[1], |c| c.pt),
        ("po", PALETTE[2], |c| c.po),
    ];
    let moment: [Component<ContactRecord>; 1] = [("pr", PALETTE[4], |c| c.pr)];
    let panels = [
        Panel {
            title: "Normal and tangential impulses per step".into(),
            x_desc: "t [s]",
            y_desc: "impulse [N s]",
            y_axis: YAxis::Linear,
            series: contact_series(scene, records, &forces),
        },
        Panel {
            title: "Torsional friction impulse per step".into(),
            x_desc: "t [s]",
            y_desc: "pr [N m s]",
            y_axis: YAxis::Linear,
            series: contact_series(scene, records, &moment),
        },
    ];
    draw_figure(root, &format!("{}: contact impulses", scene.name), &panels)
}

/// Contact-mode categories, bottom to top.
const MODES: [&str; 4] = ["none", "point", "line", "patch"];

fn mode_level(mode: ContactMode) -> f64 {
    match mode {
        ContactMode::None => 0.0,
        ContactMode::Point => 1.0,
        ContactMode::Line => 2.0,
        ContactMode::Patch => 3.0,
    }
}

fn mode_plot(root: &Area<'_>, scene: &Scene, records: &[StepRecord]) -> Result<(), DrawError> {
    let contacts = contact_count(records);
    let per_body = contacts_per_body(scene, records);
    // The mode is a property of a body and a plane, shared by the union's and the point
    // formulation's contacts: draw each distinct mode history once.
    let mut shown: Vec<Vec<ContactMode>> = Vec::new();
    let distinct: Vec<usize> = (0..contacts)
        .filter(|&c| {
            let history: Vec<ContactMode> = records
                .iter()
                .filter_map(|r| r.contacts.get(c).map(|k| k.mode))
                .collect();
            let new = !shown.contains(&history);
            if new {
                shown.push(history);
            }
            new
        })
        .collect();
    let contacts = distinct.len();
    // The mode recorded at the end of a step holds over that step: draw it as a step line
    // from t − h to t. Several contacts are offset slightly so that they do not hide each other.
    let h = if scene.h.is_finite() { scene.h } else { 0.0 };
    let series = distinct
        .iter()
        .enumerate()
        .map(|(k, &c)| {
            let offset = (k as f64 - (contacts as f64 - 1.0) / 2.0) * 0.08;
            let points = records
                .iter()
                .flat_map(|r| {
                    let y = r
                        .contacts
                        .get(c)
                        .map_or(f64::NAN, |k| mode_level(k.mode) + offset);
                    [(r.t - h, y), (r.t, y)]
                })
                .collect();
            let label = format!("mode{}", contact_suffix(scene, c, contacts, per_body));
            Series::new(label, points, PALETTE[k % PALETTE.len()])
        })
        .collect();
    let panels = [Panel {
        title: format!(
            "Contact mode from the state (vertices within {MODE_TOLERANCE:e} m of the plane)"
        ),
        x_desc: "t [s]",
        y_desc: "contact mode",
        y_axis: YAxis::Categories(&MODES),
        series,
    }];
    draw_figure(root, &format!("{}: contact mode", scene.name), &panels)
}

fn solver_plot(root: &Area<'_>, scene: &Scene, records: &[StepRecord]) -> Result<(), DrawError> {
    let per_step = |f: fn(&StepRecord) -> f64| -> Vec<(f64, f64)> {
        records.iter().map(|r| (r.step as f64, f(r))).collect()
    };
    let failed = |f: fn(&StepRecord) -> f64| -> Vec<(f64, f64)> {
        records
            .iter()
            .filter(|r| !r.converged)
            .map(|r| (r.step as f64, f(r)))
            .collect()
    };
    let iterations = |r: &StepRecord| r.summary.iterations as f64;
    let residual = |r: &StepRecord| r.summary.residual;
    let n_failed = records.iter().filter(|r| !r.converged).count();
    let failed_label = format!("not converged ({n_failed})");
    let panels = [
        Panel {
            title: "Solver iterations per step".into(),
            x_desc: "step",
            y_desc: "iterations",
            y_axis: YAxis::Count,
            series: vec![
                Series::new("iterations", per_step(iterations), PALETTE[0]),
                Series::new(failed_label.clone(), failed(iterations), PALETTE[3])
                    .with_stroke(Stroke::Markers),
            ],
        },
        Panel {
            title: "Natural residual of the returned point".into(),
            x_desc: "step",
            y_desc: "residual",
            y_axis: YAxis::Log,
            series: vec![
                Series::new("residual", per_step(residual), PALETTE[2]),
                Series::new(failed_label, failed(residual), PALETTE[3])
                    .with_stroke(Stroke::Markers),
            ],
        },
    ];
    let title = format!(
        "{}: solver ({} of {} steps converged)",
        scene.name,
        records.len() - n_failed,
        records.len()
    );
    draw_figure(root, &title, &panels)
}

// ---------------------------------------------------------------------------------------------
// Footprint
// ---------------------------------------------------------------------------------------------

/// What the footprint shows of one body at one instant, in plane coordinates.
struct Footprint {
    /// 2-D hull of each convex piece's projected vertices.
    pieces: Vec<Vec<(f64, f64)>>,
    /// Projected vertices of the real body touching the plane.
    patch: Vec<(f64, f64)>,
    /// 2-D hull of `patch`.
    patch_hull: Vec<(f64, f64)>,
    cm: (f64, f64),
    /// The ECP of the body's contact, or with several contacts per body (union, point
    /// formulations) the contact points that carry a normal impulse.
    ecp: Vec<(f64, f64)>,
}

/// In-plane axes `(t, o)` of plane 0 (world x, y for the ground, or without planes).
fn plane_axes(scene: &Scene) -> (Vector3<f64>, Vector3<f64>) {
    match scene.planes.first() {
        Some(plane) => {
            let (_, t, o) = plane.contact_frame();
            (t, o)
        }
        None => (Vector3::x(), Vector3::y()),
    }
}

fn footprint(
    scene: &Scene,
    record: &StepRecord,
    b: usize,
    plane: Option<&HalfSpace>,
    (t, o): (Vector3<f64>, Vector3<f64>),
) -> Option<Footprint> {
    let spec = scene.bodies.get(b)?;
    let state = record.bodies.get(b)?;
    let finite = state.x.iter().chain(state.q.iter()).all(|v| v.is_finite());
    if !finite || state.q.norm() == 0.0 {
        return None;
    }
    let r = rotation_matrix(&(state.q / state.q.norm()));
    let project = |p: &Vector3<f64>| (t.dot(p), o.dot(p));
    let pieces = spec
        .shape
        .pieces()
        .iter()
        .map(|piece| {
            let world = world_vertices(&piece.vertices(), &state.x, &r);
            hull_2d(world.iter().map(project).collect())
        })
        .collect();
    // Same tolerance as the recorded contact mode, so the patch matches contact_mode.png.
    let patch: Vec<(f64, f64)> = plane.map_or_else(Vec::new, |plane| {
        world_vertices(spec.shape.vertices(), &state.x, &r)
            .iter()
            .filter(|p| plane.value(p) <= MODE_TOLERANCE)
            .map(project)
            .collect()
    });
    let per_body = (record.contacts.len() / scene.bodies.len().max(1)).max(1);
    let mine = record.contacts.iter().skip(b * per_body).take(per_body);
    let ecp = mine
        .filter(|c| per_body == 1 || c.pn > 0.0)
        .map(|c| project(&c.a1))
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .collect();
    Some(Footprint {
        pieces,
        patch_hull: hull_2d(patch.clone()),
        patch,
        cm: project(&state.x),
        ecp,
    })
}

/// Convex hull (counter-clockwise) of the finite points, with duplicates and collinear points
/// dropped to a tolerance relative to the points' size, so 1 or 2 points come back for
/// degenerate input.
fn hull_2d(points: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    let points: Vec<[f64; 2]> = points
        .into_iter()
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .map(|p| [p.0, p.1])
        .collect();
    let scale = points
        .iter()
        .fold(1.0f64, |m, p| m.max(p[0].abs()).max(p[1].abs()));
    // Relative tolerances: `eps` on lengths, `eps * scale` on cross products (lengths squared).
    let eps = 1e-12 * scale;
    convex_hull_2d(points, eps, eps * scale)
        .into_iter()
        .map(|p| (p[0], p[1]))
        .collect()
}

/// Record indices shown in the footprint: the first step and evenly spaced ones to the last.
fn footprint_instants(n: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..=FOOTPRINT_INSTANTS)
        .map(|k| k * n.saturating_sub(1) / FOOTPRINT_INSTANTS)
        .collect();
    idx.dedup();
    idx
}

/// Decimals that resolve the step length in time labels.
fn time_decimals(h: f64) -> usize {
    if h.is_finite() && h > 0.0 {
        (-h.log10()).ceil().clamp(0.0, 6.0) as usize
    } else {
        3
    }
}

/// Sampled instants at which the bodies have the same pose, drawn once in one colour.
struct InstantGroup {
    times: Vec<f64>,
    color: RGBColor,
    prints: Vec<Footprint>,
}

impl InstantGroup {
    /// "t = 0.40 s", "t = 0.40, 0.80 s" or "t = 0.40, …, 2.00 s".
    fn label(&self, decimals: usize) -> String {
        let f = |t: &f64| format!("{t:.decimals$}");
        match self.times.as_slice() {
            [] => String::new(),
            [a] => format!("t = {} s", f(a)),
            [a, b] => format!("t = {}, {} s", f(a), f(b)),
            [a, .., b] => format!("t = {}, …, {} s", f(a), f(b)),
        }
    }
}

/// Whether two records place every body and ECP identically (to far below a pixel), so that
/// e.g. a body at rest is drawn once instead of stacking translucent fills.
fn same_pose(a: &StepRecord, b: &StepRecord) -> bool {
    const TOL: f64 = 1e-6;
    let close = |u: &[f64], v: &[f64]| u.iter().zip(v).all(|(x, y)| (x - y).abs() <= TOL);
    a.bodies.len() == b.bodies.len()
        && a.contacts.len() == b.contacts.len()
        && a.bodies.iter().zip(&b.bodies).all(|(p, q)| {
            close(p.x.as_slice(), q.x.as_slice()) && close(p.q.as_slice(), q.q.as_slice())
        })
        && a.contacts
            .iter()
            .zip(&b.contacts)
            .all(|(p, q)| close(p.a1.as_slice(), q.a1.as_slice()))
}

fn instant_groups(scene: &Scene, records: &[StepRecord]) -> Vec<InstantGroup> {
    let axes = plane_axes(scene);
    let plane = scene.planes.first();
    let bodies = body_count(records);
    let mut groups: Vec<(&StepRecord, InstantGroup)> = Vec::new();
    for r in footprint_instants(records.len())
        .into_iter()
        .filter_map(|i| records.get(i))
    {
        if let Some((first, group)) = groups.last_mut()
            && same_pose(first, r)
        {
            group.times.push(r.t);
            continue;
        }
        let prints = (0..bodies)
            .filter_map(|b| footprint(scene, r, b, plane, axes))
            .collect();
        let color = PALETTE[groups.len() % PALETTE.len()];
        groups.push((
            r,
            InstantGroup {
                times: vec![r.t],
                color,
                prints,
            },
        ));
    }
    groups.into_iter().map(|(_, g)| g).collect()
}

/// The chart of the footprint plot.
type PlaneChart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

fn footprint_plot(root: &Area<'_>, scene: &Scene, records: &[StepRecord]) -> Result<(), DrawError> {
    let groups = instant_groups(scene, records);
    let decimals = time_decimals(scene.h);
    let ground = scene
        .planes
        .first()
        .is_none_or(|p| (p.normal() - Vector3::z()).norm() < 1e-12);
    let (view, x_desc, y_desc) = if ground {
        ("top view (x–y)", "x [m]", "y [m]")
    } else {
        ("view onto plane 0 (its t–o axes)", "t [m]", "o [m]")
    };
    let body = root.titled(
        &format!("{}: footprint, contact patch and ECP, {view}", scene.name),
        font(26),
    )?;
    let (width, _) = body.dim_in_pixel();
    let (chart_area, legend_area) = body.split_horizontally(width.saturating_sub(LEGEND_WIDTH));

    let (xs, ys): (Vec<f64>, Vec<f64>) = groups
        .iter()
        .flat_map(|g| &g.prints)
        .flat_map(|f| {
            let pieces = f.pieces.iter().flatten();
            pieces.chain(&f.patch).chain(&f.ecp).chain([&f.cm]).copied()
        })
        .unzip();
    let mut chart = plan_chart(&chart_area, xs, ys, x_desc, y_desc)?;

    // Layer by layer over all instants, so that no fill hides another instant's outline.
    for layer in [Layer::Fill, Layer::Outline, Layer::Markers] {
        for g in &groups {
            for f in &g.prints {
                draw_footprint(&mut chart, f, g.color, layer)?;
            }
        }
    }
    label_instants(root, &chart, &groups, decimals)?;

    let mut entries: Vec<LegendEntry> = groups
        .iter()
        .map(|g| LegendEntry {
            label: g.label(decimals),
            color: g.color,
            glyph: Glyph::Line,
        })
        .collect();
    let key = [
        ("convex pieces", Glyph::Line),
        ("contact patch hull", Glyph::Fill),
        ("patch vertices", Glyph::Dot),
        ("CM (projected)", Glyph::Cross),
        ("ECP a1", Glyph::BorderedCircle),
    ];
    entries.extend(key.into_iter().map(|(label, glyph)| LegendEntry {
        label: label.into(),
        color: PALETTE[7],
        glyph,
    }));
    draw_legend(&legend_area, &entries)
}

/// Writes each instant's time next to its footprint on a light box, skipping labels that
/// would overlap one already placed (the legend still names every colour).
fn label_instants(
    root: &Area<'_>,
    chart: &PlaneChart<'_, '_>,
    groups: &[InstantGroup],
    decimals: usize,
) -> Result<(), DrawError> {
    let label_style = TextStyle::from(font(15)).pos(Pos::new(HPos::Center, VPos::Center));
    let (root_w, root_h) = root.dim_in_pixel();
    let (root_w, root_h) = (root_w as i32, root_h as i32);
    let mut placed: Vec<[i32; 4]> = Vec::new();
    for g in groups {
        let text = g.label(decimals);
        let (w, h) = root.estimate_text_size(&text, &label_style)?;
        let (w, h) = (w as i32 + 8, h as i32 + 8);
        // Centred above, else below, the first body's footprint that leaves room.
        let candidates: Vec<(i32, i32)> = g
            .prints
            .iter()
            .filter_map(|f| {
                let points = f.pieces.iter().flatten();
                let (x0, x1) = finite_bounds(points.clone().map(|p| p.0))?;
                let (y0, y1) = finite_bounds(points.map(|p| p.1))?;
                let mid = x0 / 2.0 + x1 / 2.0;
                let above = chart.backend_coord(&(mid, y1));
                let below = chart.backend_coord(&(mid, y0));
                Some([
                    (above.0 - w / 2, above.1 - 6 - h),
                    (below.0 - w / 2, below.1 + 6),
                ])
            })
            .flatten()
            .collect();
        let free = |(x, y): (i32, i32)| {
            x >= 0
                && y >= 0
                && x + w <= root_w
                && y + h <= root_h
                && placed
                    .iter()
                    .all(|b| x + w <= b[0] || b[2] <= x || y + h <= b[1] || b[3] <= y)
        };
        if let Some((x, y)) = candidates.into_iter().find(|c| free(*c)) {
            root.draw(&Rectangle::new(
                [(x, y), (x + w, y + h)],
                WHITE.mix(0.85).filled(),
            ))?;
            let style = label_style.color(&g.color);
            root.draw_text(&text, &style, (x + w / 2, y + h / 2))?;
            placed.push([x, y, x + w, y + h]);
        }
    }
    Ok(())
}
/// The chart of a plan view (footprints, bodies from above): equal aspect over the points
/// `xs`, `ys` (the shorter data range widened to the plotting area's shape), with its mesh drawn.
fn plan_chart<'a, 'b>(
    area: &'a Area<'b>,
    xs: Vec<f64>,
    ys: Vec<f64>,
    x_desc: &str,
    y_desc: &str,
) -> Result<
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    DrawError,
> {
    let configure = |builder: &mut ChartBuilder<'_, '_, BitMapBackend<'_>>| {
        builder
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(70);
    };
    // Equal aspect: measure the plotting area once, then widen the shorter data range to match.
    let mut probe = ChartBuilder::on(area);
    configure(&mut probe);
    let (pw, ph) = probe
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)?
        .plotting_area()
        .dim_in_pixel();
    let (x_range, y_range) = equal_aspect(linear_range(xs), linear_range(ys), pw, ph);
    let span = x_range.end - x_range.start;
    let mut builder = ChartBuilder::on(area);
    configure(&mut builder);
    let mut chart = builder.build_cartesian_2d(x_range, y_range)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .axis_desc_style(font(17))
        .label_style(font(15))
        .x_label_formatter(&|x| tick_label(*x, span))
        .y_label_formatter(&|y| tick_label(*y, span))
        .light_line_style(RGBAColor(0, 0, 0, 0.04))
        .bold_line_style(RGBAColor(0, 0, 0, 0.15))
        .draw()?;
    Ok(chart)
}

/// Widens the range whose data-per-pixel is smaller so both axes share one scale.
fn equal_aspect(x: Range<f64>, y: Range<f64>, pw: u32, ph: u32) -> (Range<f64>, Range<f64>) {
    let (pw, ph) = (f64::from(pw.max(1)), f64::from(ph.max(1)));
    let (sx, sy) = ((x.end - x.start) / pw, (y.end - y.start) / ph);
    let widen = |r: Range<f64>, span: f64| {
        let mid = r.start / 2.0 + r.end / 2.0;
        mid - span / 2.0..mid + span / 2.0
    };
    if sx > sy {
        (x.clone(), widen(y, sx * ph))
    } else {
        (widen(x, sy * pw), y)
    }
}

/// Drawing layers of the footprint plot, bottom to top.
#[derive(Clone, Copy, PartialEq)]
enum Layer {
    Fill,
    Outline,
    Markers,
}

fn draw_footprint(
    chart: &mut PlaneChart<'_, '_>,
    f: &Footprint,
    color: RGBColor,
    layer: Layer,
) -> Result<(), DrawError> {
    let closed = |hull: &[(f64, f64)]| {
        let mut path = hull.to_vec();
        path.extend(hull.first());
        path
    };
    match layer {
        Layer::Fill => {
            if f.patch_hull.len() >= 3 {
                let fill = color.mix(0.18).filled();
                chart.draw_series([Polygon::new(f.patch_hull.clone(), fill)])?;
            }
        }
        Layer::Outline => {
            let thin = color.stroke_width(1);
            chart.draw_series(f.pieces.iter().map(|p| PathElement::new(closed(p), thin)))?;
            if f.patch_hull.len() >= 2 {
                let thick = color.stroke_width(3);
                chart.draw_series([PathElement::new(closed(&f.patch_hull), thick)])?;
            }
            chart.draw_series(f.patch.iter().map(|p| Circle::new(*p, 3, color.filled())))?;
        }
        Layer::Markers => {
            chart.draw_series([Cross::new(f.cm, 7, color.stroke_width(2))])?;
            for &ecp in &f.ecp {
                chart.draw_series([Circle::new(ecp, 6, color.filled())])?;
                chart.draw_series([Circle::new(ecp, 6, BLACK.stroke_width(1))])?;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecp_formulations::Simulation;
    use ecp_formulations::scenarios;
    use ecp_solvers::{NewtonSettings, NewtonSolver};

    fn run(scene: Scene, steps: usize) -> Vec<StepRecord> {
        let mut sim = Simulation::new(scene).expect("valid scene");
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        (0..steps)
            .map(|_| sim.step(&mut solver).expect("step"))
            .collect()
    }

    fn temp_dir(tag: &str) -> PathBuf {
        std::env::temp_dir().join(format!("ecp-plots-{tag}-{}", std::process::id()))
    }

    #[test]
    fn writes_png_files_for_a_short_desk_run() {
        let scene = scenarios::desk();
        let records = run(scene.clone(), 20);
        let dir = temp_dir("desk");
        let paths = write_plots(&dir, &scene, &records).expect("plots");
        assert_eq!(paths.len(), 6);
        for path in &paths {
            let bytes = std::fs::read(path).expect("written");
            assert!(
                bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
                "{}",
                path.display()
            );
            // A flat image compresses to well under a kilobyte.
            assert!(
                bytes.len() > 8_000,
                "{} is only {} bytes",
                path.display(),
                bytes.len()
            );
        }
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }

    #[test]
    fn empty_records_write_nothing() {
        let dir = temp_dir("empty");
        let paths = write_plots(&dir, &scenarios::desk(), &[]).expect("no error");
        assert!(paths.is_empty());
        assert!(!dir.exists());
    }

    #[test]
    fn unusable_directory_is_an_error_naming_it() {
        let file = temp_dir("file");
        std::fs::write(&file, b"not a directory").expect("temp file");
        let dir = file.join("plots");
        let scene = scenarios::a1_sliding();
        let records = run(scene.clone(), 1);
        let err = write_plots(&dir, &scene, &records).expect_err("a file is in the way");
        assert!(matches!(err, PlotError::Io { .. }));
        assert!(
            err.to_string().contains(&dir.display().to_string()),
            "{err}"
        );
        std::fs::remove_file(&file).expect("cleanup");
    }

    #[test]
    fn non_finite_values_do_not_panic() {
        let scene = scenarios::a5_drop_tilted();
        let mut records = run(scene.clone(), 3);
        records[0].bodies[0].v.x = f64::NAN;
        records[0].bodies[0].x.y = f64::INFINITY;
        records[1].bodies[0].q.x = f64::NAN;
        records[1].contacts[0].a1.x = f64::NEG_INFINITY;
        records[1].contacts[0].pn = 1e300;
        records[2].summary.residual = f64::NAN;
        records[2].converged = false;
        // A series that is constant, and one that is entirely NaN.
        for r in &mut records {
            r.contacts[0].pr = f64::NAN;
            r.bodies[0].w.z = 2.0;
        }
        let dir = temp_dir("nan");
        let paths = write_plots(&dir, &scene, &records).expect("plots");
        assert_eq!(paths.len(), 6);
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }

    #[test]
    fn ranges_and_hull() {
        assert_eq!(linear_range([f64::NAN]), -1.1..1.1);
        assert_eq!(linear_range([0.0, 0.0]), -1.0..1.0);
        let r = linear_range([2.0, 2.0, f64::INFINITY]);
        assert!(r.start < 2.0 && r.end > 2.0);
        let r = linear_range([-f64::MAX, f64::MAX]);
        assert!(r.start.is_finite() && r.end.is_finite());
        let l = log_range([0.0, -1.0, 1e-3]);
        assert!(l.start > 0.0 && l.start < 1e-3 && l.end > 1e-3);
        let l = log_range([5e-324, f64::MAX]);
        assert!(l.start > 0.0 && l.end.is_finite());
        let square = [
            (0.0, 0.0),
            (1.0, 0.0),
            (1.0, 1.0),
            (0.0, 1.0),
            (0.5, 0.5),
            (0.5, 0.0),
        ];
        assert_eq!(hull_2d(square.to_vec()).len(), 4);
        assert_eq!(hull_2d(vec![(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)]).len(), 2);
        assert_eq!(footprint_instants(1), vec![0]);
        assert_eq!(footprint_instants(400), vec![0, 79, 159, 239, 319, 399]);
    }
}
