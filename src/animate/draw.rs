//! One frame of the animation: a fixed orthographic camera, convex pieces as shaded faces
//! (painter's order, back faces culled), half-spaces as gridded patches, the ECPs of the active
//! contacts and their normal impulses as arrows.

use nalgebra::{Matrix3, Vector3, Vector4};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use ecp_formulations::rotation::rotation_matrix;

use super::read::{Arrow, RunData};
use crate::plots::FONT;

/// The longest impulse arrow of a run is this fraction of the scene's size (the diagonal of
/// the box holding every body over the whole run); the others scale linearly with `p_n`.
pub const ARROW_FRACTION: f64 = 0.2;

/// Camera azimuth and elevation (rad): looking at the scene from the front right, above.
const AZIMUTH: f64 = -60.0 * std::f64::consts::PI / 180.0;
const ELEVATION: f64 = 25.0 * std::f64::consts::PI / 180.0;
/// Pixels above the scene for the title, and below it for the key.
const TOP: i32 = 48;
const BOTTOM: i32 = 28;
/// A contact whose `p_n` is below this fraction of the run's largest is drawn unloaded (a hollow
/// ECP, no arrow).
const LOADED: f64 = 1e-9;
/// Labels are drawn on the bodies when there are at most this many.
const MAX_LABELS: usize = 12;

/// Colours of dynamic bodies, in scene order (cycled): the plots' palette.
const BODY_COLORS: [RGBColor; 10] = crate::plots::PALETTE;
const FIXED_COLOR: RGBColor = RGBColor(150, 150, 150);
const KINEMATIC_COLOR: RGBColor = RGBColor(230, 170, 40);
const GROUND_COLOR: RGBColor = RGBColor(222, 214, 196);
const ECP_COLOR: RGBColor = RGBColor(200, 0, 0);

/// Which body a solid is.
#[derive(Clone, Copy)]
enum Kind {
    Dynamic(usize),
    Obstacle(usize),
}

/// A body's faces in its frame: each face's corners (counter-clockwise from outside) and normal.
struct Solid {
    name: String,
    kind: Kind,
    color: RGBColor,
    edge: RGBColor,
    faces: Vec<(Vec<Vector3<f64>>, Vector3<f64>)>,
}

/// A half-space as drawn: the corners of a patch and its grid lines.
type PlanePatch = (Vec<Vector3<f64>>, Vec<[Vector3<f64>; 2]>);

/// A face to draw: depth along the view, screen corners, fill, edge colour and width.
type ScreenFace = (f64, Vec<(i32, i32)>, RGBColor, RGBColor, u32);

/// The camera, the scene's solids and the scales of one animation.
pub(super) struct View {
    right: Vector3<f64>,
    up: Vector3<f64>,
    toward: Vector3<f64>,
    light: Vector3<f64>,
    /// Screen = origin + scale · (p·right, −p·up).
    scale: f64,
    origin: (f64, f64),
    solids: Vec<Solid>,
    /// Each half-space as a patch (corners) with its grid lines.
    planes: Vec<PlanePatch>,
    /// Metres of arrow per N s.
    arrow_scale: f64,
    /// The largest normal impulse of the run (N s).
    pub max_pn: f64,
    size: (u32, u32),
}

fn darker(c: RGBColor, f: f64) -> RGBColor {
    let s = |v: u8| (f64::from(v) * f).round().clamp(0.0, 255.0) as u8;
    RGBColor(s(c.0), s(c.1), s(c.2))
}

fn solid(
    name: &str,
    kind: Kind,
    color: RGBColor,
    shape: &ecp_formulations::geometry::Shape,
) -> Solid {
    let faces = shape
        .pieces()
        .iter()
        .filter_map(|p| p.hull().ok())
        .flat_map(|hull| {
            let v = hull.vertices().to_vec();
            hull.faces()
                .iter()
                .map(|f| (f.vertices.iter().map(|&i| v[i]).collect(), f.normal))
                .collect::<Vec<_>>()
        })
        .collect();
    Solid {
        name: name.to_string(),
        kind,
        color,
        edge: darker(color, 0.45),
        faces,
    }
}

fn rotation(q: &Vector4<f64>) -> Matrix3<f64> {
    let n = q.norm();
    if n > 0.0 && n.is_finite() {
        rotation_matrix(&(q / n))
    } else {
        Matrix3::identity()
    }
}

impl View {
    pub(super) fn new(data: &RunData, size: (u32, u32)) -> View {
        let scene = &data.scene;
        let toward = Vector3::new(
            ELEVATION.cos() * AZIMUTH.cos(),
            ELEVATION.cos() * AZIMUTH.sin(),
            ELEVATION.sin(),
        );
        let right = Vector3::z().cross(&toward).normalize();
        let up = toward.cross(&right);
        let light = (toward + Vector3::new(0.3, 0.5, 1.2)).normalize();
        let mut solids: Vec<Solid> = scene
            .bodies
            .iter()
            .enumerate()
            .map(|(b, spec)| {
                let color = BODY_COLORS[b % BODY_COLORS.len()];
                solid(&spec.name, Kind::Dynamic(b), color, &spec.shape)
            })
            .collect();
        for (o, ob) in scene.world.obstacles.iter().enumerate() {
            let color = if ob.is_fixed() {
                FIXED_COLOR
            } else {
                KINEMATIC_COLOR
            };
            solids.push(solid(&ob.name, Kind::Obstacle(o), color, &ob.shape));
        }
        let mut view = View {
            right,
            up,
            toward,
            light,
            scale: 1.0,
            origin: (0.0, 0.0),
            solids,
            planes: Vec::new(),
            arrow_scale: 0.0,
            max_pn: 0.0,
            size,
        };
        // The box holding every body over the run (each row and t = 0).
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(-f64::INFINITY),
        );
        let mut rows: Vec<Option<usize>> = vec![None];
        rows.extend((0..data.times.len()).map(Some));
        for &row in &rows {
            for s in &view.solids {
                for p in view.world_faces(s, data, row).iter().flat_map(|f| &f.0) {
                    if p.iter().all(|v| v.is_finite()) {
                        lo = lo.inf(p);
                        hi = hi.sup(p);
                    }
                }
            }
        }
        if !lo.iter().all(|v| v.is_finite()) {
            (lo, hi) = (Vector3::repeat(-1.0), Vector3::repeat(1.0));
        }
        let extent = (hi - lo).norm().max(1e-3);
        view.max_pn = data
            .contacts
            .iter()
            .flatten()
            .map(|a| a.pn)
            .filter(|p| p.is_finite())
            .fold(0.0, f64::max);
        if view.max_pn > 0.0 {
            view.arrow_scale = ARROW_FRACTION * extent / view.max_pn;
        }
        // Half-spaces: a patch around the bodies' box, 15 % of the scene's size wider.
        let centre = (lo + hi) / 2.0;
        let corners: Vec<Vector3<f64>> = (0..8)
            .map(|k| {
                let pick = |bit: usize, a: f64, b: f64| if k & bit == 0 { a } else { b };
                Vector3::new(
                    pick(1, lo.x, hi.x),
                    pick(2, lo.y, hi.y),
                    pick(4, lo.z, hi.z),
                )
            })
            .collect();
        for plane in &scene.planes {
            let (_, t, o) = plane.contact_frame();
            let c0 = plane.project(&centre);
            let reach = |axis: &Vector3<f64>| {
                let r = corners.iter().map(|c| (c - c0).dot(axis).abs());
                r.fold(0.0, f64::max) + 0.15 * extent
            };
            let (ht, ho) = (reach(&t), reach(&o));
            let corner = |a: f64, b: f64| c0 + t * (a * ht) + o * (b * ho);
            let patch = vec![
                corner(-1.0, -1.0),
                corner(1.0, -1.0),
                corner(1.0, 1.0),
                corner(-1.0, 1.0),
            ];
            let mut grid = Vec::new();
            for k in 1..8 {
                let s = -1.0 + 2.0 * f64::from(k) / 8.0;
                grid.push([corner(s, -1.0), corner(s, 1.0)]);
                grid.push([corner(-1.0, s), corner(1.0, s)]);
            }
            view.planes.push((patch, grid));
        }
        // Framing: everything that is drawn, with equal scales on both screen axes.
        let mut points: Vec<Vector3<f64>> = view.planes.iter().flat_map(|p| p.0.clone()).collect();
        points.extend(&corners);
        for a in data.contacts.iter().flatten() {
            let tip = a.at + a.normal * (a.pn * view.arrow_scale);
            if tip.iter().all(|v| v.is_finite()) {
                points.push(tip);
            }
        }
        let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in &points {
            let (u, v) = (p.dot(&right), p.dot(&up));
            (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
        }
        let margin = 16.0;
        let w = f64::from(size.0) - 2.0 * margin;
        let h = f64::from(size.1) - f64::from(TOP + BOTTOM) - 2.0 * margin;
        view.scale = (w / (u1 - u0).max(1e-9)).min(h / (v1 - v0).max(1e-9));
        let (cu, cv) = ((u0 + u1) / 2.0, (v0 + v1) / 2.0);
        view.origin = (
            f64::from(size.0) / 2.0 - view.scale * cu,
            f64::from(TOP) + margin + h / 2.0 + view.scale * cv,
        );
        view
    }

    fn screen(&self, p: &Vector3<f64>) -> (i32, i32) {
        let u = self.origin.0 + self.scale * p.dot(&self.right);
        let v = self.origin.1 - self.scale * p.dot(&self.up);
        (u.round() as i32, v.round() as i32)
    }

    fn pose(&self, s: &Solid, data: &RunData, row: Option<usize>) -> (Vector3<f64>, Matrix3<f64>) {
        let t = row.and_then(|r| data.times.get(r)).copied().unwrap_or(0.0);
        let (x, q) = match s.kind {
            Kind::Dynamic(b) => match row {
                Some(r) => data.states[r][b],
                None => data.initial()[b],
            },
            Kind::Obstacle(o) => data.scene.world.obstacles[o].pose_at(t),
        };
        (x, rotation(&q))
    }

    /// The solid's faces in the world frame at `row` (`None`: t = 0).
    fn world_faces(
        &self,
        s: &Solid,
        data: &RunData,
        row: Option<usize>,
    ) -> Vec<(Vec<Vector3<f64>>, Vector3<f64>)> {
        let (x, r) = self.pose(s, data, row);
        s.faces
            .iter()
            .map(|(corners, n)| (corners.iter().map(|p| x + r * p).collect(), r * n))
            .collect()
    }

    /// Draws the frame of `row` (`None`: t = 0), frame `k` of `count`.
    pub(super) fn frame<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        data: &RunData,
        row: Option<usize>,
        (k, count): (usize, usize),
    ) -> Result<(), String> {
        let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
        root.fill(&WHITE).map_err(err)?;
        // Half-spaces first: every body is on their free side.
        for (patch, grid) in &self.planes {
            let pts: Vec<(i32, i32)> = patch.iter().map(|p| self.screen(p)).collect();
            root.draw(&Polygon::new(pts.clone(), GROUND_COLOR.filled()))
                .map_err(err)?;
            for [a, b] in grid {
                let line = vec![self.screen(a), self.screen(b)];
                root.draw(&PathElement::new(line, darker(GROUND_COLOR, 0.85)))
                    .map_err(err)?;
            }
            let mut outline = pts;
            outline.extend(outline.first().copied());
            root.draw(&PathElement::new(outline, darker(GROUND_COLOR, 0.6)))
                .map_err(err)?;
        }
        // Faces of every body, far to near; back faces culled.
        let mut faces: Vec<ScreenFace> = Vec::new();
        for s in &self.solids {
            let width = if matches!(s.kind, Kind::Obstacle(_)) {
                2
            } else {
                1
            };
            for (corners, n) in self.world_faces(s, data, row) {
                if n.dot(&self.toward) <= 1e-9 || corners.len() < 3 {
                    continue;
                }
                if !corners.iter().flatten().all(|v| v.is_finite()) {
                    continue;
                }
                let depth =
                    corners.iter().map(|p| p.dot(&self.toward)).sum::<f64>() / corners.len() as f64;
                let shade = 0.5 + 0.5 * n.dot(&self.light).max(0.0);
                let pts = corners.iter().map(|p| self.screen(p)).collect();
                faces.push((depth, pts, darker(s.color, shade), s.edge, width));
            }
        }
        faces.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (_, pts, fill, edge, width) in faces {
            root.draw(&Polygon::new(pts.clone(), fill.filled()))
                .map_err(err)?;
            let mut outline = pts;
            outline.extend(outline.first().copied());
            root.draw(&PathElement::new(outline, edge.stroke_width(width)))
                .map_err(err)?;
        }
        // Contacts on top: the ECP and the normal impulse on body_a.
        let arrows: &[Arrow] = row
            .and_then(|r| data.contacts.get(r))
            .map_or(&[], Vec::as_slice);
        for a in arrows {
            if !a.at.iter().all(|v| v.is_finite()) {
                continue;
            }
            // Round-off impulses of an unloaded contact draw as unloaded.
            let loaded = a.pn > LOADED * self.max_pn;
            let p = self.screen(&a.at);
            if loaded && self.arrow_scale > 0.0 {
                let tip = self.screen(&(a.at + a.normal * (a.pn * self.arrow_scale)));
                self.arrow(root, p, tip).map_err(err)?;
            }
            let style = if loaded {
                ECP_COLOR.filled()
            } else {
                ECP_COLOR.stroke_width(1)
            };
            root.draw(&Circle::new(p, 4, style)).map_err(err)?;
            if loaded {
                root.draw(&Circle::new(p, 4, BLACK.stroke_width(1)))
                    .map_err(err)?;
            }
        }
        // Names on the bodies, when few.
        if self.solids.len() <= MAX_LABELS {
            let style = TextStyle::from((FONT, 13).into_font())
                .pos(Pos::new(HPos::Center, VPos::Center))
                .color(&BLACK);
            for s in &self.solids {
                let (x, _) = self.pose(s, data, row);
                if x.iter().all(|v| v.is_finite()) {
                    root.draw_text(&s.name, &style, self.screen(&x))
                        .map_err(err)?;
                }
            }
        }
        // Title and key.
        let t = row.and_then(|r| data.times.get(r)).copied().unwrap_or(0.0);
        let step = row.map_or(0, |r| r + 1);
        let title = format!(
            "{}   t = {t:.3} s   step {step}/{}   frame {}/{count}",
            data.scene.name,
            data.times.len(),
            k + 1
        );
        let big = TextStyle::from((FONT, 18).into_font()).color(&BLACK);
        root.draw_text(&title, &big, (10, 8)).map_err(err)?;
        let key = if self.max_pn > 0.0 {
            format!(
                "arrows: normal impulse p_n on body_a at its ECP (red dot; hollow: unloaded); longest = {:.3e} N s",
                self.max_pn
            )
        } else {
            "no loaded contact in this run".to_string()
        };
        let small = TextStyle::from((FONT, 13).into_font()).color(&RGBColor(60, 60, 60));
        root.draw_text(&key, &small, (10, 30)).map_err(err)?;
        let legend_y = self.size.1 as i32 - BOTTOM + 6;
        let mut x = 10;
        for (label, color) in [
            ("dynamic", BODY_COLORS[0]),
            ("fixed", FIXED_COLOR),
            ("kinematic", KINEMATIC_COLOR),
            ("half-space", GROUND_COLOR),
        ] {
            root.draw(&Rectangle::new(
                [(x, legend_y), (x + 14, legend_y + 14)],
                color.filled(),
            ))
            .map_err(err)?;
            root.draw_text(label, &small, (x + 18, legend_y))
                .map_err(err)?;
            x += 30 + 8 * label.len() as i32;
        }
        Ok(())
    }

    fn arrow<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        from: (i32, i32),
        to: (i32, i32),
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let style = RGBColor(120, 0, 0).stroke_width(2);
        root.draw(&PathElement::new(vec![from, to], style))?;
        let (dx, dy) = (f64::from(to.0 - from.0), f64::from(to.1 - from.1));
        let len = dx.hypot(dy);
        if len >= 6.0 {
            let (ux, uy) = (dx / len, dy / len);
            let head = 8.0_f64.min(len / 2.0);
            for s in [-1.0, 1.0] {
                // Rotate the backward direction by ±25°.
                let (c, sn) = (25f64.to_radians().cos(), s * 25f64.to_radians().sin());
                let bx = -ux * c + uy * sn;
                let by = -uy * c - ux * sn;
                let end = (
                    to.0 + (bx * head).round() as i32,
                    to.1 + (by * head).round() as i32,
                );
                root.draw(&PathElement::new(vec![to, end], style))?;
            }
        }
        Ok(())
    }
}
