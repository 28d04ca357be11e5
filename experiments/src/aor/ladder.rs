//! A ladder of angle-of-repose runs (grain sizes, masses) as one chart: the angle against the
//! heap's height in grain diameters, the axis along which a coarse heap differs from a fine one
//! (issue 13, docs/aor.md). Pure: the caller reads the results.

use std::fmt::Write as _;

use crate::svg::{escape, header, Frame, HEIGHT, ML, MT};

use super::run::AorResult;

/// One run of a ladder; serialized as a row of `repose ladder`'s table
/// (`run,height_grains,angle_deg,came_to_rest`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LadderPoint {
    /// What the run is (a preset or a folder name), written next to its point.
    #[serde(rename = "run")]
    pub label: String,
    /// The heap's height over the mean grain diameter.
    pub height_grains: f64,
    pub angle_deg: f64,
    /// Whether the heap came to rest (an open marker otherwise).
    pub came_to_rest: bool,
}

impl LadderPoint {
    /// The point of a measured run; `None` when the run measured no heap (no angle or height).
    pub fn from_result(label: impl Into<String>, result: &AorResult) -> Option<LadderPoint> {
        let (angle, height) = (result.angle_deg?, result.pile_height_m?);
        if !(result.grain_diameter_m > 0.0 && angle.is_finite() && height.is_finite()) {
            return None;
        }
        Some(LadderPoint {
            label: label.into(),
            height_grains: height / result.grain_diameter_m,
            angle_deg: angle,
            came_to_rest: result.came_to_rest,
        })
    }
}

/// The chart: each point labelled, joined in order of height, with a reference angle (the
/// measured one a ladder is compared with) as a dashed line and a ± `band_deg` band.
pub fn ladder_svg(points: &[LadderPoint], reference_deg: f64, band_deg: f64) -> String {
    let mut s = header(crate::svg::WIDTH, HEIGHT);
    let _ = writeln!(
        s,
        "<text x=\"{ML}\" y=\"28\">{}</text>",
        escape(&format!(
            "angle of repose against heap height ({} runs; reference {reference_deg}° ± {band_deg}°)",
            points.len()
        ))
    );
    let x1 = points
        .iter()
        .map(|p| p.height_grains)
        .fold(0.0f64, f64::max)
        .max(1.0)
        * 1.15;
    let (mut y0, mut y1) = (reference_deg - band_deg, reference_deg + band_deg);
    for p in points {
        y0 = y0.min(p.angle_deg);
        y1 = y1.max(p.angle_deg);
    }
    let pad = 0.1 * (y1 - y0).max(1.0);
    let frame = Frame {
        x0: 0.0,
        x1,
        y0: (y0 - pad).max(0.0),
        y1: y1 + pad,
    };
    let (left, right) = (frame.x(0.0), frame.x(x1));
    let _ = writeln!(
        s,
        "<rect x=\"{left:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"#e8f4ea\"/>",
        frame.y(reference_deg + band_deg),
        right - left,
        frame.y(reference_deg - band_deg) - frame.y(reference_deg + band_deg)
    );
    frame.axes(
        &mut s,
        "heap height / grain diameter",
        "angle of repose (°)",
    );
    let _ = writeln!(
        s,
        "<line x1=\"{left:.1}\" y1=\"{0:.1}\" x2=\"{right:.1}\" y2=\"{0:.1}\" stroke=\"#1e8449\" stroke-dasharray=\"6 4\"/>",
        frame.y(reference_deg)
    );
    let _ = writeln!(
        s,
        "<text x=\"{:.1}\" y=\"{:.1}\" fill=\"#1e8449\">reference {reference_deg}°</text>",
        left + 8.0,
        frame.y(reference_deg) - 6.0
    );
    let mut order: Vec<&LadderPoint> = points.iter().collect();
    order.sort_by(|a, b| a.height_grains.total_cmp(&b.height_grains));
    if order.len() > 1 {
        let path: Vec<String> = order
            .iter()
            .map(|p| {
                format!(
                    "{:.1},{:.1}",
                    frame.x(p.height_grains),
                    frame.y(p.angle_deg)
                )
            })
            .collect();
        let _ = writeln!(
            s,
            "<polyline points=\"{}\" fill=\"none\" stroke=\"#1f5fa8\" stroke-width=\"1.5\"/>",
            path.join(" ")
        );
    }
    for (k, p) in order.iter().enumerate() {
        let (x, y) = (frame.x(p.height_grains), frame.y(p.angle_deg));
        let fill = if p.came_to_rest { "#1f5fa8" } else { "white" };
        let _ = writeln!(
            s,
            "<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"5\" fill=\"{fill}\" stroke=\"#1f5fa8\" stroke-width=\"1.5\"/>"
        );
        // Labels of points in the right third read leftward, so they stay on the page; they
        // sit above and below their points in turn, so neighbours do not overwrite each other.
        let ly = if k % 2 == 0 { y - 8.0 } else { y + 18.0 };
        let (lx, anchor) = if x > left + 0.66 * (right - left) {
            (x - 8.0, "end")
        } else {
            (x + 8.0, "start")
        };
        let _ = writeln!(
            s,
            "<text x=\"{lx:.1}\" y=\"{ly:.1}\" text-anchor=\"{anchor}\" fill=\"#333\">{} ({:.1}°)</text>",
            escape(&p.label),
            p.angle_deg
        );
    }
    let _ = writeln!(
        s,
        "<text x=\"{ML}\" y=\"{:.1}\" fill=\"#666\">open markers: the heap had not come to rest</text>",
        MT - 12.0
    );
    s.push_str("</svg>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(label: &str, height_grains: f64, angle_deg: f64, rest: bool) -> LadderPoint {
        LadderPoint {
            label: label.into(),
            height_grains,
            angle_deg,
            came_to_rest: rest,
        }
    }

    #[test]
    fn the_chart_has_every_point_its_label_and_the_reference() {
        let points = [
            point("size-1.5mm", 30.0, 38.0, true),
            point("size-2.5mm", 15.0, 41.0, false),
            point("a <b>", 21.0, 40.4, true),
        ];
        let svg = ladder_svg(&points, 34.85, 2.0);
        assert!(svg.starts_with("<?xml") && svg.ends_with("</svg>\n"));
        assert_eq!(svg.matches("<circle").count(), 3);
        assert_eq!(
            svg.matches("fill=\"white\" stroke").count(),
            1,
            "one open marker"
        );
        assert!(svg.contains("size-1.5mm (38.0°)"));
        assert!(svg.contains("a &lt;b&gt; (40.4°)"), "labels are escaped");
        assert!(svg.contains("reference 34.85°"));
        // Joined in order of height: 15, 21, 30 grains.
        let line = svg.split("<polyline points=\"").nth(1).unwrap();
        let xs: Vec<f64> = line
            .split('"')
            .next()
            .unwrap()
            .split(' ')
            .map(|p| p.split(',').next().unwrap().parse().unwrap())
            .collect();
        assert_eq!(xs.len(), 3);
        assert!(xs.windows(2).all(|w| w[0] < w[1]), "{xs:?}");
        // One point, no line; no points, still a chart.
        assert!(!ladder_svg(&points[..1], 34.85, 2.0).contains("<polyline"));
        assert!(ladder_svg(&[], 34.85, 2.0).ends_with("</svg>\n"));
    }
}
