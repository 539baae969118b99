//! Plots of a multi-body run (the `bodies` formulation): a top view of every body and its
//! loaded contacts at a few instants, and the impulses of each contact pair over time, from the
//! records' pairs (the rows of `contacts.csv`).

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use ecp_formulations::geometry::{Shape, world_vertices};
use ecp_formulations::rotation::rotation_matrix;
use ecp_formulations::{Scene, StepRecord};

use super::{
    Area, DrawError, FOOTPRINT_SIZE, Glyph, LEGEND_WIDTH, LegendEntry, PALETTE, PlotError,
    TimePanel, draw_legend, font, footprint_instants, hull_2d, plan_chart, render, time_decimals,
    write_time_series,
};

/// Pairs drawn in the impulse plot: those with the largest normal impulse.
const MAX_PAIRS: usize = 10;
/// A pair is loaded when its `p_n` exceeds this fraction of the run's largest.
const LOADED: f64 = 1e-9;
const FIXED_FILL: RGBColor = RGBColor(150, 150, 150);
const KINEMATIC_FILL: RGBColor = RGBColor(230, 170, 40);

/// Whether the records are of a multi-body run (they have contact pairs).
pub(super) fn is_multibody(records: &[StepRecord]) -> bool {
    records.iter().any(|r| !r.pairs.is_empty())
}

/// Writes `bodies_footprint.png` and `pair_impulses.png` into `dir`.
pub(super) fn write(
    dir: &Path,
    scene: &Scene,
    records: &[StepRecord],
) -> Result<Vec<PathBuf>, PlotError> {
    let footprint = dir.join("bodies_footprint.png");
    render(&footprint, FOOTPRINT_SIZE, |root| {
        footprint_plot(root, scene, records)
    })
    .map_err(|e| PlotError::Draw {
        path: footprint.clone(),
        message: e.0,
    })?;
    let impulses = dir.join("pair_impulses.png");
    write_time_series(
        &impulses,
        &format!("{}: impulses per contact pair", scene.name),
        &impulse_panels(records),
    )?;
    Ok(vec![footprint, impulses])
}

/// The pairs of the run as `body_a – body_b`, in order of first appearance.
fn pair_names(records: &[StepRecord]) -> Vec<(String, String)> {
    let mut names: Vec<(String, String)> = Vec::new();
    for p in records.iter().flat_map(|r| &r.pairs) {
        if !names.iter().any(|(a, b)| *a == p.body_a && *b == p.body_b) {
            names.push((p.body_a.clone(), p.body_b.clone()));
        }
    }
    names
}

/// `p_n` and the friction impulse `|(p_t, p_o)|` per pair over time (NaN where a pair has no
/// contact set, which breaks its line), for the [`MAX_PAIRS`] pairs with the largest `p_n`.
fn impulse_panels(records: &[StepRecord]) -> Vec<TimePanel> {
    let mut pairs: Vec<((String, String), f64)> = pair_names(records)
        .into_iter()
        .map(|(a, b)| {
            let max = records
                .iter()
                .flat_map(|r| &r.pairs)
                .filter(|p| p.body_a == a && p.body_b == b)
                .map(|p| p.pn)
                .filter(|v| v.is_finite())
                .fold(0.0, f64::max);
            ((a, b), max)
        })
        .collect();
    let total = pairs.len();
    // Stable: pairs of equal load keep their order of appearance.
    pairs.sort_by(|x, y| y.1.total_cmp(&x.1));
    pairs.truncate(MAX_PAIRS);
    let curve = |f: fn(&ecp_formulations::PairRecord) -> f64| {
        pairs
            .iter()
            .map(|((a, b), _)| {
                let points = records
                    .iter()
                    .map(|r| {
                        let p = r.pairs.iter().find(|p| p.body_a == *a && p.body_b == *b);
                        (r.t, p.map_or(f64::NAN, f))
                    })
                    .collect();
                (format!("{a} – {b}"), points)
            })
            .collect::<Vec<_>>()
    };
    let shown = if total > MAX_PAIRS {
        format!(" ({MAX_PAIRS} of {total} pairs, the most loaded)")
    } else {
        String::new()
    };
    vec![
        TimePanel {
            title: format!("normal impulse p_n on body_a{shown}"),
            y_desc: "p_n [N s]",
            log_y: false,
            curves: curve(|p| p.pn),
        },
        TimePanel {
            title: format!("friction impulse |(p_t, p_o)| on body_a{shown}"),
            y_desc: "|p_t, p_o| [N s]",
            log_y: false,
            curves: curve(|p| p.pt.hypot(p.po)),
        },
    ]
}

/// A body in the top view: the 2-D hull of each piece.
type Outline = Vec<Vec<(f64, f64)>>;

/// The body's [`Outline`] at pose `(x, Q)`.
fn outline(shape: &Shape, x: &Vector3<f64>, q: &nalgebra::Vector4<f64>) -> Outline {
    let n = q.norm();
    if !(n > 0.0 && n.is_finite() && x.iter().all(|v| v.is_finite())) {
        return Vec::new();
    }
    let r = rotation_matrix(&(q / n));
    shape
        .pieces()
        .iter()
        .map(|piece| {
            let world = world_vertices(&piece.vertices(), x, &r);
            hull_2d(world.iter().map(|p| (p.x, p.y)).collect())
        })
        .collect()
}

/// What is drawn at one instant.
struct Instant {
    t: f64,
    color: RGBColor,
    /// Dynamic bodies: (name, CM, piece outlines).
    bodies: Vec<(String, (f64, f64), Outline)>,
    /// Kinematic bodies' piece outlines.
    kinematic: Vec<Vec<(f64, f64)>>,
    /// Loaded ECPs: (point, against a half-space).
    ecps: Vec<((f64, f64), bool)>,
}

fn footprint_plot(root: &Area<'_>, scene: &Scene, records: &[StepRecord]) -> Result<(), DrawError> {
    let max_pn = records
        .iter()
        .flat_map(|r| &r.pairs)
        .map(|p| p.pn)
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let planes: Vec<String> = (0..scene.planes.len())
        .map(|p| scene.world.plane_name(p))
        .collect();
    let instants: Vec<Instant> = footprint_instants(records.len())
        .into_iter()
        .filter_map(|i| records.get(i))
        .enumerate()
        .map(|(k, r)| Instant {
            t: r.t,
            color: PALETTE[k % PALETTE.len()],
            bodies: scene
                .bodies
                .iter()
                .zip(&r.bodies)
                .map(|(spec, s)| {
                    (
                        spec.name.clone(),
                        (s.x.x, s.x.y),
                        outline(&spec.shape, &s.x, &s.q),
                    )
                })
                .collect(),
            kinematic: scene
                .world
                .obstacles
                .iter()
                .filter(|o| !o.is_fixed())
                .flat_map(|o| {
                    let (x, q) = o.pose_at(r.t);
                    outline(&o.shape, &x, &q)
                })
                .collect(),
            ecps: r
                .pairs
                .iter()
                .filter(|p| p.pn > LOADED * max_pn && p.a1.iter().all(|v| v.is_finite()))
                .map(|p| ((p.a1.x, p.a1.y), planes.contains(&p.body_b)))
                .collect(),
        })
        .collect();
    let fixed: Vec<Vec<(f64, f64)>> = scene
        .world
        .obstacles
        .iter()
        .filter(|o| o.is_fixed())
        .flat_map(|o| {
            let (x, q) = o.pose_at(0.0);
            outline(&o.shape, &x, &q)
        })
        .collect();

    let body = root.titled(
        &format!("{}: bodies and loaded contacts, top view (x–y)", scene.name),
        font(26),
    )?;
    let (width, _) = body.dim_in_pixel();
    let (chart_area, legend_area) = body.split_horizontally(width.saturating_sub(LEGEND_WIDTH));
    let (xs, ys): (Vec<f64>, Vec<f64>) = instants
        .iter()
        .flat_map(|i| {
            let b = i.bodies.iter().flat_map(|b| b.2.iter().flatten());
            b.chain(i.kinematic.iter().flatten())
                .copied()
                .chain(i.ecps.iter().map(|e| e.0))
        })
        .chain(fixed.iter().flatten().copied())
        .unzip();
    let mut chart = plan_chart(&chart_area, xs, ys, "x [m]", "y [m]")?;
    let span = chart.x_range().end - chart.x_range().start;
    let closed = |hull: &[(f64, f64)]| {
        let mut path = hull.to_vec();
        path.extend(hull.first());
        path
    };
    let fill = |hull: &Vec<(f64, f64)>, c: RGBColor, alpha: f64| {
        Polygon::new(
            hull.clone(),
            c.mix(if hull.len() >= 3 { alpha } else { 0.0 }).filled(),
        )
    };
    chart.draw_series(fixed.iter().map(|h| fill(h, FIXED_FILL, 0.35)))?;
    chart.draw_series(
        fixed
            .iter()
            .map(|h| PathElement::new(closed(h), BLACK.stroke_width(1))),
    )?;
    for i in &instants {
        // Light: the instants overlap.
        chart.draw_series(i.kinematic.iter().map(|h| fill(h, KINEMATIC_FILL, 0.12)))?;
    }
    for i in &instants {
        let thin = i.color.stroke_width(1);
        chart.draw_series(
            i.kinematic
                .iter()
                .chain(i.bodies.iter().flat_map(|b| &b.2))
                .map(|h| PathElement::new(closed(h), thin)),
        )?;
    }
    for i in &instants {
        for &(p, half_space) in &i.ecps {
            if half_space {
                chart.draw_series([Circle::new(p, 5, i.color.filled())])?;
                chart.draw_series([Circle::new(p, 5, BLACK.stroke_width(1))])?;
            } else {
                chart.draw_series([TriangleMarker::new(p, 8, i.color.filled())])?;
            }
        }
    }
    // Names at the last instant, when they can be read.
    if let Some(last) = instants.last()
        && last.bodies.len() <= 30
    {
        let style = TextStyle::from(font(14))
            .pos(Pos::new(HPos::Center, VPos::Center))
            .color(&BLACK);
        for (name, cm, _) in &last.bodies {
            if cm.0.is_finite() && cm.1.is_finite() {
                // Above the CM, clear of an ECP marker there.
                let at = (cm.0, cm.1 + 0.025 * span);
                chart.draw_series([Text::new(name.clone(), at, style.clone())])?;
            }
        }
    }
    let decimals = time_decimals(scene.h);
    let mut entries: Vec<LegendEntry> = instants
        .iter()
        .map(|i| LegendEntry {
            label: format!("t = {:.decimals$} s", i.t),
            color: i.color,
            glyph: Glyph::Line,
        })
        .collect();
    let key = [
        ("fixed body", FIXED_FILL, Glyph::Fill),
        ("kinematic body", KINEMATIC_FILL, Glyph::Fill),
        ("ECP on a half-space", PALETTE[7], Glyph::BorderedCircle),
        ("ECP between bodies", PALETTE[7], Glyph::Triangle),
    ];
    entries.extend(key.into_iter().map(|(label, color, glyph)| LegendEntry {
        label: label.into(),
        color,
        glyph,
    }));
    draw_legend(&legend_area, &entries)
}
