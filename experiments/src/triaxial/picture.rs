//! Pictures of a triaxial test as self-contained SVG text: the failure circles with the fitted
//! envelope and the paper's ([`mohr_svg`]), the deviator and volumetric strain against the
//! axial strain ([`curves_svg`]) and the last specimen at the end of loading ([`specimen_svg`]).

use std::fmt::Write as _;

use crate::svg::{escape, header, Frame, HEIGHT, MB, ML, MR, MT, WIDTH};

use super::run::TriaxialResult;

/// The paper's envelope (its triaxial test): c = 2.5 kPa, φ = 30.6°.
pub const PAPER_COHESION_KPA: f64 = 2.5;
pub const PAPER_FRICTION_DEG: f64 = 30.6;

/// One colour per stage, cycling.
const COLOURS: [&str; 6] = [
    "#1f5fa8", "#d35400", "#27ae60", "#8e44ad", "#c0392b", "#7f8c8d",
];

fn title(s: &mut String, text: &str) {
    let _ = writeln!(s, "<text x=\"{ML}\" y=\"28\">{}</text>", escape(text));
}

/// The line τ = c + σ tan φ over the frame's σ range, dashed or not.
fn envelope_line(s: &mut String, frame: &Frame, c: f64, phi_deg: f64, colour: &str, dash: bool) {
    let tan = phi_deg.to_radians().tan();
    let (a, b) = (frame.x0.max(0.0), frame.x1);
    let dash = if dash {
        " stroke-dasharray=\"6 4\""
    } else {
        ""
    };
    let _ = writeln!(
        s,
        "<line x1=\"{:.1}\" y1=\"{:.1}\" x2=\"{:.1}\" y2=\"{:.1}\" stroke=\"{colour}\" stroke-width=\"1.5\"{dash}/>",
        frame.x(a),
        frame.y(c + a * tan),
        frame.x(b),
        frame.y(c + b * tan)
    );
}

/// The Mohr circles at failure (σ3 and σ1 = σ3 + q of each stage, kPa) with the fitted
/// envelope (solid) and the paper's (dashed), on equal scales.
pub fn mohr_svg(result: &TriaxialResult) -> String {
    let mut s = header(WIDTH, HEIGHT);
    let text = match (result.cohesion_kpa, result.friction_angle_deg) {
        (Some(c), Some(phi)) => format!(
            "triaxial: Mohr circles at failure, c = {c:.2} kPa, φ = {phi:.1}° (paper: {PAPER_COHESION_KPA} kPa, {PAPER_FRICTION_DEG}°, dashed)"
        ),
        _ => "triaxial: Mohr circles at failure (no envelope)".to_owned(),
    };
    title(&mut s, &text);
    let s1_max = result
        .stages
        .iter()
        .map(|st| st.failure_confining_kpa + st.peak_deviator_kpa)
        .fold(1.0_f64, f64::max);
    let x1 = 1.1 * s1_max;
    let (w, h) = (WIDTH - ML - MR, HEIGHT - MT - MB);
    let frame = Frame {
        x0: 0.0,
        x1,
        y0: 0.0,
        y1: x1 * h / w,
    };
    frame.axes(&mut s, "normal stress σ (kPa)", "shear stress τ (kPa)");
    let scale = w / x1;
    for (k, st) in result.stages.iter().enumerate() {
        let colour = COLOURS[k % COLOURS.len()];
        let centre = st.failure_confining_kpa + 0.5 * st.peak_deviator_kpa;
        let radius = 0.5 * st.peak_deviator_kpa;
        let _ = writeln!(
            s,
            "<path d=\"M {:.1} {:.1} A {r:.1} {r:.1} 0 0 1 {:.1} {:.1}\" fill=\"none\" stroke=\"{colour}\" stroke-width=\"1.5\"/>",
            frame.x(centre - radius),
            frame.y(0.0),
            frame.x(centre + radius),
            frame.y(0.0),
            r = radius * scale
        );
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" fill=\"{colour}\">σ3 {:.1}</text>",
            frame.x(centre),
            frame.y(radius) - 6.0,
            st.confining_kpa
        );
    }
    if let (Some(c), Some(phi)) = (result.cohesion_kpa, result.friction_angle_deg) {
        envelope_line(&mut s, &frame, c, phi, "#222", false);
    }
    envelope_line(
        &mut s,
        &frame,
        PAPER_COHESION_KPA,
        PAPER_FRICTION_DEG,
        "#c0392b",
        true,
    );
    s.push_str("</svg>\n");
    s
}

/// The deviator q (solid, left scale, kPa) and the volumetric strain (dashed, right scale, %,
/// contraction positive) against the axial strain (%), one colour per stage, each failure
/// marked.
pub fn curves_svg(result: &TriaxialResult) -> String {
    let mut s = header(WIDTH, HEIGHT);
    title(
        &mut s,
        "triaxial: deviator q (solid) and volumetric strain (dashed, right) against axial strain",
    );
    let samples = || result.stages.iter().flat_map(|st| &st.series);
    let x1 = samples()
        .map(|p| 100.0 * p.axial_strain)
        .fold(1e-6, f64::max);
    let q1 = samples().map(|p| p.deviator_kpa).fold(1e-6, f64::max);
    let q0 = samples().map(|p| p.deviator_kpa).fold(0.0, f64::min);
    let v0 = samples()
        .map(|p| 100.0 * p.volumetric_strain)
        .fold(0.0, f64::min);
    let v1 = samples()
        .map(|p| 100.0 * p.volumetric_strain)
        .fold(1e-6, f64::max);
    let frame = Frame {
        x0: 0.0,
        x1,
        y0: q0 - 0.05 * (q1 - q0),
        y1: q1 + 0.08 * (q1 - q0),
    };
    frame.axes(&mut s, "axial strain εa (%)", "deviator q = σ1 − σ3 (kPa)");
    // The volumetric strain mapped onto the same plot area.
    let vy = |v: f64| MT + (v1 - v) / (v1 - v0).max(1e-9) * (HEIGHT - MT - MB);
    let _ = writeln!(
        s,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\" fill=\"#555\">εv {v1:.2} %</text><text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\" fill=\"#555\">εv {v0:.2} %</text>",
        WIDTH - MR - 4.0,
        MT + 14.0,
        WIDTH - MR - 4.0,
        HEIGHT - MB - 4.0
    );
    for (k, st) in result.stages.iter().enumerate() {
        let colour = COLOURS[k % COLOURS.len()];
        let (mut q, mut v) = (String::new(), String::new());
        for p in &st.series {
            let x = frame.x(100.0 * p.axial_strain);
            let _ = write!(q, "{x:.1},{:.1} ", frame.y(p.deviator_kpa));
            let _ = write!(v, "{x:.1},{:.1} ", vy(100.0 * p.volumetric_strain));
        }
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"{colour}\" stroke-width=\"1.4\" points=\"{q}\"/>"
        );
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"{colour}\" stroke-width=\"1\" stroke-dasharray=\"5 3\" points=\"{v}\"/>"
        );
        let _ = writeln!(
            s,
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"{colour}\"/>",
            frame.x(100.0 * st.axial_strain_at_peak),
            frame.y(st.peak_deviator_kpa)
        );
        let legend_y = MT + 18.0 + 18.0 * k as f64;
        let _ = writeln!(
            s,
            "<line x1=\"{:.1}\" y1=\"{legend_y:.1}\" x2=\"{:.1}\" y2=\"{legend_y:.1}\" stroke=\"{colour}\" stroke-width=\"2\"/><text x=\"{:.1}\" y=\"{:.1}\">σ3 = {:.1} kPa</text>",
            ML + 12.0,
            ML + 36.0,
            ML + 42.0,
            legend_y + 4.0,
            st.confining_kpa
        );
    }
    s.push_str("</svg>\n");
    s
}

/// The grains of the last stage at the end of loading seen from the side (x-z): the slice one
/// mean grain diameter thick through the specimen's middle (y), so the packing inside shows.
pub fn specimen_svg(result: &TriaxialResult, grains: &[([f64; 3], f64)]) -> String {
    let (w, h) = (420.0, 640.0);
    let mut s = header(w, h);
    let last = result.stages.last();
    let text = match last {
        Some(st) => format!(
            "specimen at εa = {:.0} %, σ3 = {:.1} kPa: the middle slice",
            100.0 * st.series.last().map_or(0.0, |p| p.axial_strain),
            st.confining_kpa
        ),
        None => "specimen".to_owned(),
    };
    let _ = writeln!(s, "<text x=\"20\" y=\"28\">{}</text>", escape(&text));
    if grains.is_empty() {
        s.push_str("</svg>\n");
        return s;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for (p, r) in grains {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] - r);
            hi[a] = hi[a].max(p[a] + r);
        }
    }
    let mean_r = grains.iter().map(|g| g.1).sum::<f64>() / grains.len() as f64;
    let y_mid = 0.5 * (lo[1] + hi[1]);
    let scale = ((w - 60.0) / (hi[0] - lo[0])).min((h - 90.0) / (hi[2] - lo[2]));
    let (cx, cy) = (0.5 * w, 50.0 + 0.5 * (h - 70.0));
    let mid = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[2] + hi[2])];
    let _ = writeln!(
        s,
        "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"#f4f1ea\" stroke=\"#555\"/>",
        cx - 0.5 * (hi[0] - lo[0]) * scale,
        cy - 0.5 * (hi[2] - lo[2]) * scale,
        (hi[0] - lo[0]) * scale,
        (hi[2] - lo[2]) * scale
    );
    for (p, r) in grains.iter().filter(|g| (g.0[1] - y_mid).abs() < mean_r) {
        let _ = writeln!(
            s,
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"{:.1}\" fill=\"#c9a66b\" stroke=\"#5a4630\" stroke-width=\"0.5\"/>",
            cx + (p[0] - mid[0]) * scale,
            cy - (p[2] - mid[1]) * scale,
            r * scale
        );
    }
    if let Some(st) = last {
        let _ = writeln!(
            s,
            "<text x=\"20\" y=\"{:.1}\">{} grains, εv at the end {:.2} %</text>",
            h - 12.0,
            st.particles,
            100.0 * st.series.last().map_or(0.0, |p| p.volumetric_strain)
        );
    }
    s.push_str("</svg>\n");
    s
}
