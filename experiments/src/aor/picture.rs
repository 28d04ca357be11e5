//! Side-view picture of a measured pile, as a self-contained SVG document.
//!
//! It reproduces what the reference experiment looked at (a photograph of the heap from the side
//! with a straight line on each flank) so that a person can check at a glance that the lines sit
//! on the flanks and that the band excluded the apex and the toe: projected grains, the silhouette,
//! the base line, the fit band, both fitted lines (solid where they were fitted, dashed where
//! extrapolated to the base), the angle at each toe, and mm axes. Equal scales on both axes, so
//! the angles on screen are the true angles.

use super::measure::{AngleOfRepose, FlankFit, ProjectionPlane};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

use crate::svg::escape;

/// How to draw the side view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PictureOptions {
    /// Which side projection to draw (x-z is the one `left_deg` / `right_deg` come from).
    pub plane: ProjectionPlane,
    /// Width of the picture in SVG user units (pixels); the height follows from the pile's aspect.
    pub width_px: f64,
    /// Draw every projected grain as a small disk (otherwise only the filled silhouette).
    pub draw_particles: bool,
    /// Replaces the generated title line.
    pub title: Option<String>,
}

impl Default for PictureOptions {
    fn default() -> Self {
        Self {
            plane: ProjectionPlane::Xz,
            width_px: 900.0,
            draw_particles: true,
            title: None,
        }
    }
}

const MARGIN_LEFT: f64 = 70.0;
const MARGIN_RIGHT: f64 = 30.0;
const MARGIN_TOP: f64 = 62.0;
const MARGIN_BOTTOM: f64 = 52.0;
const LEFT_COLOUR: &str = "#c0392b";
const RIGHT_COLOUR: &str = "#1f5fa8";

/// Maps metres to picture units with one scale for both axes.
#[derive(Debug, Clone, Copy)]
struct Frame {
    s0: f64,
    z1: f64,
    scale: f64,
    plot_w: f64,
    plot_h: f64,
}

impl Frame {
    fn x(&self, s: f64) -> f64 {
        MARGIN_LEFT + (s - self.s0) * self.scale
    }
    fn y(&self, z: f64) -> f64 {
        MARGIN_TOP + (self.z1 - z) * self.scale
    }
}

/// Renders the side view of `result` as an SVG document (UTF-8 text, with a `viewBox`, no external
/// resources). `positions` / `radii` are the grains that were measured; pass empty slices to draw
/// only the silhouette. Grains outside the drawn window (strays) are left out.
pub fn side_view_svg(
    result: &AngleOfRepose,
    positions: &[[f64; 3]],
    radii: &[f64],
    options: &PictureOptions,
) -> String {
    let view = result.projection(options.plane);
    let base_z = result.base_z_m;
    let d = result.particle_diameter_m.max(f64::MIN_POSITIVE);

    // Data window: the silhouette, both toes, some air around it.
    let mut s_lo = view.left.toe_m.min(view.right.toe_m);
    let mut s_hi = view.left.toe_m.max(view.right.toe_m);
    for p in &view.silhouette {
        s_lo = s_lo.min(p[0]);
        s_hi = s_hi.max(p[0]);
    }
    let top_z = view.apex[1].max(base_z + d);
    let pad = 0.06 * (s_hi - s_lo).max(4.0 * d);
    s_lo -= pad;
    s_hi += pad;
    let z0 = base_z - 0.08 * (top_z - base_z) - d;
    let z1 = top_z + 0.12 * (top_z - base_z) + d;

    let width = if options.width_px.is_finite() && options.width_px >= 200.0 {
        options.width_px
    } else {
        900.0
    };
    let plot_w = width - MARGIN_LEFT - MARGIN_RIGHT;
    let scale = plot_w / (s_hi - s_lo);
    let plot_h = (z1 - z0) * scale;
    let height = MARGIN_TOP + plot_h + MARGIN_BOTTOM;
    let f = Frame {
        s0: s_lo,
        z1,
        scale,
        plot_w,
        plot_h,
    };

    let mut svg = String::new();
    let _ = writeln!(svg, r#"<?xml version="1.0" encoding="UTF-8"?>"#);
    let _ = writeln!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {w:.1} {h:.1}" width="{w:.0}" height="{h:.0}" font-family="Helvetica, Arial, sans-serif" font-size="12">"#,
        w = width,
        h = height
    );
    let _ = writeln!(
        svg,
        r#"<rect x="0" y="0" width="{width:.1}" height="{height:.1}" fill="white"/>"#
    );
    let _ = writeln!(
        svg,
        r#"<defs><clipPath id="aor-plot-area"><rect x="{:.2}" y="{:.2}" width="{:.2}" height="{:.2}"/></clipPath></defs>"#,
        MARGIN_LEFT, MARGIN_TOP, plot_w, plot_h
    );

    // Grains, then silhouette over them.
    let _ = writeln!(svg, r#"<g clip-path="url(#aor-plot-area)">"#);
    if options.draw_particles {
        let _ = writeln!(
            svg,
            r##"<g fill="#dcc9a0" stroke="#8a7650" stroke-width="0.3">"##
        );
        for (p, r) in positions.iter().zip(radii) {
            let s = match options.plane {
                ProjectionPlane::Xz => p[0],
                ProjectionPlane::Yz => p[1],
            };
            let inside = s + r >= s_lo && s - r <= s_hi && p[2] + r >= z0 && p[2] - r <= z1;
            if !(r.is_finite() && *r > 0.0 && p[2].is_finite() && inside) {
                continue;
            }
            let _ = writeln!(
                svg,
                r#"<circle cx="{:.2}" cy="{:.2}" r="{:.2}"/>"#,
                f.x(s),
                f.y(p[2]),
                r * scale
            );
        }
        let _ = writeln!(svg, "</g>");
    }
    if let (Some(first), Some(last)) = (view.silhouette.first(), view.silhouette.last()) {
        let mut points = format!("{:.2},{:.2}", f.x(first[0]), f.y(base_z));
        for p in &view.silhouette {
            let _ = write!(points, " {:.2},{:.2}", f.x(p[0]), f.y(p[1]));
        }
        let _ = write!(points, " {:.2},{:.2}", f.x(last[0]), f.y(base_z));
        let opacity = if options.draw_particles { 0.25 } else { 0.8 };
        let _ = writeln!(
            svg,
            r##"<polygon points="{points}" fill="#b08d57" fill-opacity="{opacity}" stroke="#4a3a1a" stroke-width="1.2" stroke-linejoin="round"/>"##
        );
    }
    let _ = writeln!(svg, "</g>");

    // Base line with a light hatch below it (the plate).
    let yb = f.y(base_z);
    let _ = writeln!(
        svg,
        r##"<rect x="{:.2}" y="{:.2}" width="{:.2}" height="{:.2}" fill="#e4e4e4"/>"##,
        MARGIN_LEFT,
        yb,
        plot_w,
        (MARGIN_TOP + plot_h - yb).max(0.0)
    );
    let _ = writeln!(
        svg,
        r#"<line x1="{:.2}" y1="{yb:.2}" x2="{:.2}" y2="{yb:.2}" stroke="black" stroke-width="2"/>"#,
        MARGIN_LEFT,
        MARGIN_LEFT + plot_w
    );

    // Fit band.
    for (fraction, label) in [
        (result.band_fractions[0], "band low"),
        (result.band_fractions[1], "band high"),
    ] {
        let y = f.y(base_z + fraction * view.pile_height_m);
        let _ = writeln!(
            svg,
            r##"<line x1="{:.2}" y1="{y:.2}" x2="{:.2}" y2="{y:.2}" stroke="#777" stroke-width="0.8" stroke-dasharray="2 4"/>"##,
            MARGIN_LEFT,
            MARGIN_LEFT + plot_w
        );
        let _ = writeln!(
            svg,
            r##"<text x="{:.2}" y="{:.2}" text-anchor="end" fill="#555" font-size="10">{} {:.0} %</text>"##,
            MARGIN_LEFT + plot_w - 4.0,
            y - 3.0,
            label,
            fraction * 100.0
        );
    }

    // Fitted lines and angles.
    flank(&mut svg, &f, &view.left, base_z, Side::Left);
    flank(&mut svg, &f, &view.right, base_z, Side::Right);

    // Plot frame and axes.
    let _ = writeln!(
        svg,
        r##"<rect x="{:.2}" y="{:.2}" width="{:.2}" height="{:.2}" fill="none" stroke="#333" stroke-width="1"/>"##,
        MARGIN_LEFT, MARGIN_TOP, plot_w, plot_h
    );
    axes(&mut svg, &f, s_lo, s_hi, z0, z1, options.plane);

    // Title and subtitle.
    let title = options.title.clone().unwrap_or_else(|| {
        format!(
            "Angle of repose, {} side view: left {:.1}°, right {:.1}°, mean {:.1}°",
            options.plane.label(),
            view.left_deg,
            view.right_deg,
            view.mean_deg
        )
    });
    let subtitle = format!(
        "{} half-planes: {:.1}° ± {:.1}° (min {:.1}°, max {:.1}°) · height {:.1} mm · base Ø {:.1} mm · {} grains · fit band {:.0}–{:.0} % of height",
        result.per_direction_deg.len(),
        result.angle_deg,
        result.std_dev_deg,
        result.min_deg,
        result.max_deg,
        result.pile_height_m * 1e3,
        result.base_diameter_m * 1e3,
        result.particles_considered,
        result.band_fractions[0] * 100.0,
        result.band_fractions[1] * 100.0
    );
    let _ = writeln!(
        svg,
        r#"<text x="{:.2}" y="24" text-anchor="middle" font-size="16" font-weight="bold">{}</text>"#,
        width / 2.0,
        escape(&title)
    );
    let _ = writeln!(
        svg,
        r##"<text x="{:.2}" y="44" text-anchor="middle" font-size="11" fill="#444">{}</text>"##,
        width / 2.0,
        escape(&subtitle)
    );
    let _ = writeln!(svg, "</svg>");
    svg
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Side {
    Left,
    Right,
}

/// One fitted flank: solid over the fitted band, dashed down to the base, an arc at the toe and
/// the angle label.
fn flank(svg: &mut String, f: &Frame, fit: &FlankFit, base_z: f64, side: Side) {
    let colour = match side {
        Side::Left => LEFT_COLOUR,
        Side::Right => RIGHT_COLOUR,
    };
    let (a, b) = (fit.band_start_m, fit.band_end_m);
    // The end of the band nearer the toe.
    let near_toe = if side == Side::Left { a } else { b };
    let _ = writeln!(
        svg,
        r#"<line x1="{:.2}" y1="{:.2}" x2="{:.2}" y2="{:.2}" stroke="{colour}" stroke-width="1.5" stroke-dasharray="6 4"/>"#,
        f.x(fit.toe_m),
        f.y(base_z),
        f.x(near_toe),
        f.y(fit.height_at(near_toe))
    );
    let _ = writeln!(
        svg,
        r#"<line x1="{:.2}" y1="{:.2}" x2="{:.2}" y2="{:.2}" stroke="{colour}" stroke-width="3" stroke-linecap="round"/>"#,
        f.x(a),
        f.y(fit.height_at(a)),
        f.x(b),
        f.y(fit.height_at(b))
    );
    // Arc between the base and the line, at the toe.
    let alpha = fit.angle_deg.to_radians();
    let radius = 42.0;
    let (tx, ty) = (f.x(fit.toe_m), f.y(base_z));
    let dir = if side == Side::Left { 1.0 } else { -1.0 };
    let sweep = if side == Side::Left { 0 } else { 1 };
    let _ = writeln!(
        svg,
        r#"<path d="M {:.2} {:.2} A {radius} {radius} 0 0 {sweep} {:.2} {:.2}" fill="none" stroke="{colour}" stroke-width="1.2"/>"#,
        tx + dir * radius,
        ty,
        tx + dir * radius * alpha.cos(),
        ty - radius * alpha.sin()
    );
    let label_r = radius + 10.0;
    let half = alpha / 2.0;
    let anchor = if side == Side::Left { "start" } else { "end" };
    let _ = writeln!(
        svg,
        r#"<text x="{:.2}" y="{:.2}" text-anchor="{anchor}" fill="{colour}" font-size="15" font-weight="bold">{:.1}°</text>"#,
        tx + dir * label_r * half.cos(),
        ty - label_r * half.sin() + 4.0,
        fit.angle_deg
    );
    let _ = writeln!(
        svg,
        r#"<circle cx="{tx:.2}" cy="{ty:.2}" r="2.5" fill="{colour}"/>"#
    );
}

/// Tick step of about `span / 6`, rounded to 1, 2 or 5 times a power of ten.
fn nice_step(span: f64) -> f64 {
    if !(span.is_finite() && span > 0.0) {
        return 1.0;
    }
    let raw = span / 6.0;
    let magnitude = 10f64.powf(raw.log10().floor());
    let m = raw / magnitude;
    let nice = if m < 1.5 {
        1.0
    } else if m < 3.5 {
        2.0
    } else if m < 7.5 {
        5.0
    } else {
        10.0
    };
    nice * magnitude
}

/// Tick values in [lo, hi] at multiples of `step` (capped in number so odd inputs stay bounded).
fn ticks(lo: f64, hi: f64, step: f64) -> Vec<f64> {
    let mut out = Vec::new();
    let mut t = (lo / step).ceil() * step;
    while t <= hi + 1e-9 * step && out.len() < 50 {
        out.push(if t.abs() < 1e-9 * step { 0.0 } else { t });
        t += step;
    }
    out
}

fn format_mm(value_mm: f64, step_mm: f64) -> String {
    let decimals = if step_mm >= 1.0 {
        0
    } else {
        (-step_mm.log10().floor()) as usize
    };
    format!("{value_mm:.decimals$}")
}

fn axes(
    svg: &mut String,
    f: &Frame,
    s_lo: f64,
    s_hi: f64,
    z0: f64,
    z1: f64,
    plane: ProjectionPlane,
) {
    let bottom = MARGIN_TOP + f.plot_h;
    let step_mm = nice_step((s_hi - s_lo) * 1e3);
    for t in ticks(s_lo * 1e3, s_hi * 1e3, step_mm) {
        let x = f.x(t * 1e-3);
        let _ = writeln!(
            svg,
            r##"<line x1="{x:.2}" y1="{bottom:.2}" x2="{x:.2}" y2="{:.2}" stroke="#333"/>"##,
            bottom + 5.0
        );
        let _ = writeln!(
            svg,
            r#"<text x="{x:.2}" y="{:.2}" text-anchor="middle">{}</text>"#,
            bottom + 18.0,
            format_mm(t, step_mm)
        );
    }
    let _ = writeln!(
        svg,
        r#"<text x="{:.2}" y="{:.2}" text-anchor="middle">{} (mm)</text>"#,
        MARGIN_LEFT + f.plot_w / 2.0,
        bottom + 38.0,
        plane.abscissa_name()
    );
    let step_mm = nice_step((z1 - z0) * 1e3).max(nice_step((s_hi - s_lo) * 1e3) / 2.0);
    for t in ticks(z0 * 1e3, z1 * 1e3, step_mm) {
        let y = f.y(t * 1e-3);
        let _ = writeln!(
            svg,
            r##"<line x1="{:.2}" y1="{y:.2}" x2="{MARGIN_LEFT:.2}" y2="{y:.2}" stroke="#333"/>"##,
            MARGIN_LEFT - 5.0
        );
        let _ = writeln!(
            svg,
            r#"<text x="{:.2}" y="{:.2}" text-anchor="end">{}</text>"#,
            MARGIN_LEFT - 8.0,
            y + 4.0,
            format_mm(t, step_mm)
        );
    }
    let (lx, ly) = (18.0, MARGIN_TOP + f.plot_h / 2.0);
    let _ = writeln!(
        svg,
        r#"<text x="{lx:.2}" y="{ly:.2}" text-anchor="middle" transform="rotate(-90 {lx:.2} {ly:.2})">z (mm)</text>"#
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_steps_are_round() {
        assert_eq!(nice_step(60.0), 10.0);
        assert_eq!(nice_step(12.0), 2.0);
        assert_eq!(nice_step(0.3), 0.05);
        assert_eq!(nice_step(f64::NAN), 1.0);
        assert_eq!(ticks(-12.0, 12.0, 5.0), vec![-10.0, -5.0, 0.0, 5.0, 10.0]);
        assert_eq!(format_mm(2.5, 0.5), "2.5");
        assert_eq!(format_mm(20.0, 10.0), "20");
    }

    #[test]
    fn escapes_markup() {
        assert_eq!(escape("a<b & \"c\""), "a&lt;b &amp; &quot;c&quot;");
    }
}
