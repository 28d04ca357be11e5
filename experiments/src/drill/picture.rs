//! Pictures of a drilling run as self-contained SVG text: a vertical section through the hole
//! axis ([`section_svg`]) and the load curves ([`forces_svg`]).

use std::fmt::Write as _;

use crate::svg::{escape, header, tick_step, trim};

use super::run::{DrillResult, DrillRun};
use crate::soil::HeightField;

const ML: f64 = 70.0;
const MR: f64 = 30.0;
const MT: f64 = 60.0;
const MB: f64 = 50.0;

/// Section y = 0 through the axis: grains the plane cuts (their cut circles), the bin, the
/// original surface (dashed), the settled surface profile (red), the auger outline at full
/// depth (blue dashes) and the measured opening and bottom. Axes in mm, equal scales.
pub fn section_svg(run: &DrillRun) -> String {
    let spec = &run.spec;
    let r = &run.result;
    let surface = run.bed.surface_z;
    let hx = 0.5 * spec.bin.size_x;
    let mut z_top = surface + 0.2 * spec.bin.size_x.max(0.02);
    for (p, &rad) in run.positions.iter().zip(&run.radii) {
        if p[1].abs() < rad {
            z_top = z_top.max(p[2] + rad);
        }
    }
    let z_top = z_top.min(spec.bin.height.max(surface) + 0.1);
    let width = 900.0;
    let scale = (width - ML - MR) / (2.0 * hx);
    let plot_h = z_top * scale;
    let height = plot_h + MT + MB;
    let x = |v: f64| ML + (v + hx) * scale;
    let y = |z: f64| MT + (z_top - z) * scale;
    let mut s = header(width, height);
    let title = format!(
        "section y = 0: opening {} mm (x {} mm, y {} mm), effective depth {} mm of {:.0} mm fed, status {:?}",
        fmt_opt(r.opening_diameter_mm),
        fmt_opt(r.opening_diameter_x_mm),
        fmt_opt(r.opening_diameter_y_mm),
        fmt_opt(r.effective_depth_mm),
        r.feed_depth_mm,
        r.status
    );
    let _ = writeln!(s, "<text x=\"{ML}\" y=\"24\">{}</text>", escape(&title));
    let _ = writeln!(
        s,
        "<text x=\"{ML}\" y=\"42\" fill=\"#555\">grains cut by the plane (tan), original surface \
         (dashed), settled surface (red), auger at full depth (blue)</text>"
    );
    // Grains.
    let _ = writeln!(
        s,
        "<g fill=\"#d9b77e\" stroke=\"#8a6d3b\" stroke-width=\"0.5\">"
    );
    for (p, &rad) in run.positions.iter().zip(&run.radii) {
        if p[1].abs() >= rad || p[2] > z_top {
            continue;
        }
        let cut = (rad * rad - p[1] * p[1]).sqrt();
        let _ = writeln!(
            s,
            "<circle cx=\"{:.2}\" cy=\"{:.2}\" r=\"{:.2}\"/>",
            x(p[0]),
            y(p[2]),
            cut * scale
        );
    }
    let _ = writeln!(s, "</g>");
    // Bin.
    let _ = writeln!(
        s,
        "<polyline fill=\"none\" stroke=\"#333\" stroke-width=\"2\" points=\"{:.1},{:.1} {:.1},{:.1} {:.1},{:.1} {:.1},{:.1}\"/>",
        x(-hx),
        y(spec.bin.height.min(z_top)),
        x(-hx),
        y(0.0),
        x(hx),
        y(0.0),
        x(hx),
        y(spec.bin.height.min(z_top))
    );
    // Original surface.
    let _ = writeln!(
        s,
        "<line x1=\"{:.1}\" y1=\"{:.1}\" x2=\"{:.1}\" y2=\"{:.1}\" stroke=\"#333\" stroke-dasharray=\"6 4\"/>",
        x(-hx),
        y(surface),
        x(hx),
        y(surface)
    );
    // Settled surface profile along x through the axis.
    if let Some(hf) = &run.surface {
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"#c0392b\" stroke-width=\"1.5\" points=\"{}\"/>",
            profile_points(hf, &x, &y)
        );
    }
    // Auger outline at full depth.
    let a = &spec.auger;
    let ra = 0.5 * a.outer_diameter;
    let tip = surface - spec.drill.depth;
    let _ = writeln!(
        s,
        "<polygon fill=\"none\" stroke=\"#1f5fa8\" stroke-dasharray=\"4 3\" points=\"{:.1},{:.1} {:.1},{:.1} {:.1},{:.1} {:.1},{:.1} {:.1},{:.1}\"/>",
        x(0.0),
        y(tip),
        x(ra),
        y(tip + a.tip_length),
        x(ra),
        y(surface + a.flight_above_surface),
        x(-ra),
        y(surface + a.flight_above_surface),
        x(-ra),
        y(tip + a.tip_length)
    );
    // Measured bottom and opening.
    if let (Some(m), Some(depth)) = (&run.measurement, r.effective_depth_mm) {
        let _ = writeln!(
            s,
            "<line x1=\"{:.1}\" y1=\"{:.1}\" x2=\"{:.1}\" y2=\"{:.1}\" stroke=\"#117a37\" stroke-width=\"2\"/>",
            x(0.0),
            y(surface),
            x(0.0),
            y(m.bottom_z)
        );
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" fill=\"#117a37\">{depth:.1} mm</text>",
            x(0.0) + 6.0,
            y(0.5 * (surface + m.bottom_z))
        );
        let w = 0.5 * m.opening_x;
        let _ = writeln!(
            s,
            "<line x1=\"{:.1}\" y1=\"{:.1}\" x2=\"{:.1}\" y2=\"{:.1}\" stroke=\"#117a37\" stroke-width=\"3\"/>",
            x(-w),
            y(surface),
            x(w),
            y(surface)
        );
    }
    // Axes (mm).
    let _ = writeln!(s, "<g stroke=\"#333\" fill=\"#333\">");
    let step = tick_step(2e3 * hx, 8) * 1e-3;
    let mut v = (-hx / step).ceil() * step;
    while v <= hx + 1e-12 {
        let _ = writeln!(
            s,
            "<line x1=\"{0:.1}\" y1=\"{1:.1}\" x2=\"{0:.1}\" y2=\"{2:.1}\"/><text x=\"{0:.1}\" y=\"{3:.1}\" stroke=\"none\" text-anchor=\"middle\">{4:.0}</text>",
            x(v),
            y(0.0),
            y(0.0) + 5.0,
            y(0.0) + 20.0,
            v * 1e3
        );
        v += step;
    }
    let zstep = tick_step(z_top * 1e3, 6) * 1e-3;
    let mut v = 0.0;
    while v <= z_top + 1e-12 {
        let _ = writeln!(
            s,
            "<line x1=\"{0:.1}\" y1=\"{1:.1}\" x2=\"{2:.1}\" y2=\"{1:.1}\"/><text x=\"{3:.1}\" y=\"{4:.1}\" stroke=\"none\" text-anchor=\"end\">{5:.0}</text>",
            ML - 5.0,
            y(v),
            ML,
            ML - 8.0,
            y(v) + 4.0,
            v * 1e3
        );
        v += zstep;
    }
    let _ = writeln!(
        s,
        "<text x=\"{:.1}\" y=\"{:.1}\" stroke=\"none\" text-anchor=\"middle\">x (mm)</text>",
        x(0.0),
        height - 8.0
    );
    let _ = writeln!(
        s,
        "<text x=\"16\" y=\"{:.1}\" stroke=\"none\" transform=\"rotate(-90 16 {:.1})\" text-anchor=\"middle\">z (mm)</text>",
        MT + 0.5 * plot_h,
        MT + 0.5 * plot_h
    );
    let _ = writeln!(s, "</g>\n</svg>");
    s
}

fn profile_points(hf: &HeightField, x: &dyn Fn(f64) -> f64, y: &dyn Fn(f64) -> f64) -> String {
    let (_, j) = hf.cell_of(0.0, 0.0);
    let mut pts = String::new();
    for i in 0..hf.nx {
        let _ = write!(pts, "{:.1},{:.1} ", x(hf.x(i)), y(hf.at(i, j)));
    }
    pts
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("-".to_owned(), |v| format!("{v:.1}"))
}

/// Three stacked panels against time: drive torque (N·m), axial force (N, positive upward on
/// the auger) and tip depth below the original surface (mm).
pub fn forces_svg(result: &DrillResult) -> String {
    let width = 900.0;
    let panel_h = 170.0;
    let gap = 40.0;
    let height = MT + 3.0 * panel_h + 2.0 * gap + MB;
    let mut s = header(width, height);
    let title = format!(
        "auger loads: peak torque {:.3} N·m, peak axial force {:.2} N, energy {:.2} J",
        result.peak_torque_nm, result.peak_axial_force_n, result.energy_j
    );
    let _ = writeln!(s, "<text x=\"{ML}\" y=\"28\">{}</text>", escape(&title));
    let series = &result.series;
    let t_max = series.last().map_or(1.0, |p| p.time_s).max(1e-9);
    let plot_w = width - ML - MR;
    type Pick = fn(&super::run::LoadSample) -> f64;
    let panels: [(&str, Pick); 3] = [
        ("torque (N·m)", |p| p.torque_nm),
        ("axial force (N)", |p| p.axial_force_n),
        ("tip depth (mm)", |p| p.tip_depth_mm),
    ];
    for (k, (label, pick)) in panels.iter().enumerate() {
        let top = MT + k as f64 * (panel_h + gap);
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for p in series {
            lo = lo.min(pick(p));
            hi = hi.max(pick(p));
        }
        if hi - lo < 1e-12 {
            hi = lo + 1.0;
        }
        let pad = 0.05 * (hi - lo);
        let (lo, hi) = (lo - pad, hi + pad);
        let x = |t: f64| ML + t / t_max * plot_w;
        let y = |v: f64| top + (hi - v) / (hi - lo) * panel_h;
        let _ = writeln!(
            s,
            "<rect x=\"{ML}\" y=\"{top:.1}\" width=\"{plot_w:.1}\" height=\"{panel_h:.1}\" fill=\"none\" stroke=\"#999\"/>"
        );
        let _ = writeln!(
            s,
            "<line x1=\"{ML}\" y1=\"{0:.1}\" x2=\"{1:.1}\" y2=\"{0:.1}\" stroke=\"#bbb\"/>",
            y(0.0),
            ML + plot_w
        );
        let mut pts = String::new();
        for p in series {
            let _ = write!(pts, "{:.1},{:.1} ", x(p.time_s), y(pick(p)));
        }
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"#1f5fa8\" stroke-width=\"1.5\" points=\"{pts}\"/>"
        );
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" fill=\"#333\">{label}</text>",
            ML + 6.0,
            top + 16.0
        );
        let step = tick_step(hi - lo, 4);
        let mut v = (lo / step).ceil() * step;
        while v <= hi {
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\" fill=\"#333\">{}</text>",
                ML - 6.0,
                y(v) + 4.0,
                trim(v)
            );
            v += step;
        }
        if k == 2 {
            let step = tick_step(t_max, 8);
            let mut t = 0.0;
            while t <= t_max + 1e-12 {
                let _ = writeln!(
                    s,
                    "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" fill=\"#333\">{}</text>",
                    x(t),
                    top + panel_h + 18.0,
                    trim(t)
                );
                t += step;
            }
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">time since the feed started (s)</text>",
                ML + 0.5 * plot_w,
                height - 8.0
            );
        }
    }
    s.push_str("</svg>\n");
    s
}
