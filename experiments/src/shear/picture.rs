//! Pictures of a shear test as self-contained SVG text: the shear stress against the
//! displacement for each normal stress ([`curves_svg`]) and the Mohr-Coulomb lines with their
//! points ([`strength_svg`]).

use std::fmt::Write as _;

use crate::svg::{escape, header, trim, Frame, HEIGHT, ML, MT, WIDTH};

use super::run::{ShearResult, ShearSample};

/// One colour per stage, cycling.
const COLOURS: [&str; 6] = [
    "#1f5fa8", "#d35400", "#27ae60", "#8e44ad", "#c0392b", "#7f8c8d",
];

/// Shear stress (kPa) against displacement (mm), one curve per normal stress, each peak
/// marked.
pub fn curves_svg(result: &ShearResult) -> String {
    let mut s = header(WIDTH, HEIGHT);
    let title = match (result.cohesion_kpa, result.friction_angle_deg) {
        (Some(c), Some(phi)) => {
            format!(
                "direct shear: shear stress against displacement (c = {c:.2} kPa, φ = {phi:.1}°)"
            )
        }
        _ => "direct shear: shear stress against displacement".to_owned(),
    };
    let _ = writeln!(s, "<text x=\"{ML}\" y=\"28\">{}</text>", escape(&title));
    let samples = result.stages.iter().flat_map(|st| &st.series);
    let (mut x1, mut y0, mut y1) = (0.0f64, 0.0f64, 0.0f64);
    for p in samples {
        x1 = x1.max(p.displacement_mm);
        y0 = y0.min(p.shear_stress_kpa).min(p.window_shear_kpa);
        y1 = y1.max(p.shear_stress_kpa).max(p.window_shear_kpa);
    }
    let frame = Frame {
        x0: 0.0,
        x1: x1.max(1e-6),
        y0: y0 - 0.05 * (y1 - y0),
        y1: (y1 + 0.08 * (y1 - y0)).max(1e-6),
    };
    frame.axes(&mut s, "shear displacement (mm)", "shear stress (kPa)");
    for (k, stage) in result.stages.iter().enumerate() {
        let colour = COLOURS[k % COLOURS.len()];
        // The box's shear stress (solid) and the soil's in the measurement window (dashed).
        let curve = |tau: fn(&ShearSample) -> f64| {
            let mut pts = String::new();
            for p in &stage.series {
                let _ = write!(
                    pts,
                    "{:.1},{:.1} ",
                    frame.x(p.displacement_mm),
                    frame.y(tau(p))
                );
            }
            pts
        };
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"{colour}\" stroke-width=\"1.3\" points=\"{}\"/>",
            curve(|p| p.shear_stress_kpa)
        );
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"{colour}\" stroke-width=\"1\" stroke-dasharray=\"5 3\" points=\"{}\"/>",
            curve(|p| p.window_shear_kpa)
        );
        let _ = writeln!(
            s,
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"{colour}\"/>",
            frame.x(stage.peak_displacement_mm),
            frame.y(stage.peak_kpa)
        );
        let legend_y = MT + 18.0 + 18.0 * k as f64;
        let _ = writeln!(
            s,
            "<line x1=\"{:.1}\" y1=\"{legend_y:.1}\" x2=\"{:.1}\" y2=\"{legend_y:.1}\" stroke=\"{colour}\" stroke-width=\"2\"/>",
            ML + 12.0,
            ML + 36.0
        );
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\">σ = {} kPa: box peak {:.2} kPa at {:.2} mm, residual {:.2} kPa; window (dashed) peak {:.2} kPa{}</text>",
            ML + 42.0,
            legend_y + 4.0,
            trim(stage.normal_stress_kpa),
            stage.peak_kpa,
            stage.peak_displacement_mm,
            stage.residual_kpa,
            stage.window_peak_kpa,
            if stage.consolidated { "" } else { " (not consolidated)" }
        );
    }
    s.push_str("</svg>\n");
    s
}

/// The Mohr-Coulomb lines τ = c + σ tan φ: the soil's (the measurement window's peaks, green
/// squares, solid line), and the box's through its peaks (filled points, solid line) and
/// residuals (open points, dashed line), against the normal stress on the shear plane.
pub fn strength_svg(result: &ShearResult) -> String {
    let mut s = header(WIDTH, HEIGHT);
    let title = match &result.window_fit {
        Some(f) => format!(
            "Mohr-Coulomb: c = {:.2} kPa, φ = {:.1}° (R² = {:.3}, {} stresses)",
            f.cohesion_kpa, f.friction_angle_deg, f.r_squared, f.points
        ),
        None => "Mohr-Coulomb: no fit".to_owned(),
    };
    let _ = writeln!(s, "<text x=\"{ML}\" y=\"28\">{}</text>", escape(&title));
    let sigma_max = result
        .stages
        .iter()
        .map(|st| st.plane_normal_stress_kpa.max(st.window_normal_stress_kpa))
        .fold(0.0, f64::max);
    let x1 = 1.1 * sigma_max.max(1e-6);
    let mut y0 = 0.0f64;
    let mut y1 = 0.0f64;
    for st in &result.stages {
        y1 = y1
            .max(st.peak_kpa)
            .max(st.residual_kpa)
            .max(st.window_peak_kpa);
        y0 = y0.min(st.residual_kpa);
    }
    for fit in [&result.window_fit, &result.peak_fit, &result.residual_fit]
        .into_iter()
        .flatten()
    {
        let slope = fit.friction_angle_deg.to_radians().tan();
        for sigma in [0.0, x1] {
            let tau = fit.cohesion_kpa + slope * sigma;
            y0 = y0.min(tau);
            y1 = y1.max(tau);
        }
    }
    let frame = Frame {
        x0: 0.0,
        x1,
        y0: y0 - 0.05 * (y1 - y0),
        y1: (y1 + 0.1 * (y1 - y0)).max(1e-6),
    };
    frame.axes(
        &mut s,
        "normal stress on the shear plane σ (kPa)",
        "shear stress τ (kPa)",
    );
    let lines = [
        (&result.window_fit, "#1e8449", "", "soil (window)"),
        (&result.peak_fit, "#1f5fa8", "", "box, peak"),
        (
            &result.residual_fit,
            "#d35400",
            " stroke-dasharray=\"6 4\"",
            "box, residual",
        ),
    ];
    for (k, (fit, colour, dash, name)) in lines.iter().enumerate() {
        if let Some(fit) = fit {
            let slope = fit.friction_angle_deg.to_radians().tan();
            let _ = writeln!(
                s,
                "<line x1=\"{:.1}\" y1=\"{:.1}\" x2=\"{:.1}\" y2=\"{:.1}\" stroke=\"{colour}\" stroke-width=\"1.5\"{dash}/>",
                frame.x(0.0),
                frame.y(fit.cohesion_kpa),
                frame.x(x1),
                frame.y(fit.cohesion_kpa + slope * x1)
            );
            let legend_y = MT + 18.0 + 18.0 * k as f64;
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{legend_y:.1}\" fill=\"{colour}\">{name}: c = {:.2} kPa, φ = {:.1}°, R² = {:.3}</text>",
                ML + 12.0,
                fit.cohesion_kpa,
                fit.friction_angle_deg,
                fit.r_squared
            );
        }
    }
    for st in &result.stages {
        let _ = writeln!(
            s,
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"8\" height=\"8\" fill=\"#1e8449\"/>",
            frame.x(st.window_normal_stress_kpa) - 4.0,
            frame.y(st.window_peak_kpa) - 4.0
        );
        let x = frame.x(st.plane_normal_stress_kpa);
        let _ = writeln!(
            s,
            "<circle cx=\"{x:.1}\" cy=\"{:.1}\" r=\"4.5\" fill=\"#1f5fa8\"/>",
            frame.y(st.peak_kpa)
        );
        let _ = writeln!(
            s,
            "<circle cx=\"{x:.1}\" cy=\"{:.1}\" r=\"4.5\" fill=\"white\" stroke=\"#d35400\" stroke-width=\"1.5\"/>",
            frame.y(st.residual_kpa)
        );
    }
    s.push_str("</svg>\n");
    s
}
