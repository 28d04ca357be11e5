//! The report's SVG charts, written as strings (no external assets). Every piece of text in
//! them (titles, axis labels, factor names) is escaped by maud ([`text`]); a finished chart is
//! [`Markup`], so the page embeds it as it is.

use std::fmt::Write;

use maud::{html, Markup, PreEscaped};

const W: f64 = 520.0;
const H: f64 = 340.0;
const ML: f64 = 62.0;
const MR: f64 = 18.0;
const MT: f64 = 28.0;
const MB: f64 = 48.0;

/// `s` as SVG text, escaped by maud.
fn text(s: &str) -> String {
    html! { (s) }.into_string()
}

fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let span = (hi - lo).abs().max(1e-12);
    let raw = span / n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let start = (lo / step).ceil() * step;
    let mut out = Vec::new();
    let mut v = start;
    while v <= hi + 1e-9 * span {
        out.push(if v.abs() < 1e-12 * span { 0.0 } else { v });
        v += step;
    }
    out
}

fn fmt_tick(v: f64) -> String {
    let s = format!("{v:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_owned()
}

/// A plot frame with linear axes.
pub(crate) struct Frame {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    out: String,
}

impl Frame {
    pub(crate) fn new(
        title: &str,
        xlabel: &str,
        ylabel: &str,
        x: (f64, f64),
        y: (f64, f64),
    ) -> Self {
        Self::build(title, xlabel, ylabel, x, y, true)
    }

    /// A frame whose y axis is categories drawn by the caller (no numeric ticks).
    pub(crate) fn categorical_y(title: &str, xlabel: &str, x: (f64, f64), y: (f64, f64)) -> Self {
        Self::build(title, xlabel, "", x, y, false)
    }

    fn build(
        title: &str,
        xlabel: &str,
        ylabel: &str,
        x: (f64, f64),
        y: (f64, f64),
        y_ticks: bool,
    ) -> Self {
        let pad = |(a, b): (f64, f64)| {
            let (a, b) = if a.is_finite() && b.is_finite() {
                (a, b)
            } else {
                (0.0, 1.0)
            };
            if (b - a).abs() < 1e-12 {
                (a - 1.0, b + 1.0)
            } else {
                (a, b)
            }
        };
        let (x0, x1) = pad(x);
        let (y0, y1) = pad(y);
        let mut f = Frame {
            x0,
            x1,
            y0,
            y1,
            out: String::new(),
        };
        let _ = write!(
            f.out,
            r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {W} {H}" width="{W}" height="{H}" font-family="sans-serif" font-size="11"><rect x="0" y="0" width="{W}" height="{H}" fill="white"/><text x="{}" y="17" text-anchor="middle" font-size="13" font-weight="bold">{}</text>"#,
            W / 2.0,
            text(title)
        );
        let _ = write!(
            f.out,
            r##"<rect x="{ML}" y="{MT}" width="{}" height="{}" fill="none" stroke="#444"/>"##,
            W - ML - MR,
            H - MT - MB
        );
        for t in nice_ticks(x0, x1, 6) {
            let px = f.px(t);
            let _ = write!(
                f.out,
                r##"<line x1="{px:.1}" y1="{}" x2="{px:.1}" y2="{}" stroke="#444"/><text x="{px:.1}" y="{}" text-anchor="middle">{}</text>"##,
                H - MB,
                H - MB + 4.0,
                H - MB + 16.0,
                fmt_tick(t)
            );
        }
        for t in nice_ticks(y0, y1, 6).into_iter().filter(|_| y_ticks) {
            let py = f.py(t);
            let _ = write!(
                f.out,
                r##"<line x1="{}" y1="{py:.1}" x2="{ML}" y2="{py:.1}" stroke="#444"/><line x1="{ML}" y1="{py:.1}" x2="{}" y2="{py:.1}" stroke="#eee"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>"##,
                ML - 4.0,
                W - MR,
                ML - 6.0,
                py + 4.0,
                fmt_tick(t)
            );
        }
        let _ = write!(
            f.out,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text><text x="14" y="{}" text-anchor="middle" transform="rotate(-90 14 {})">{}</text>"#,
            ML + (W - ML - MR) / 2.0,
            H - 10.0,
            text(xlabel),
            MT + (H - MT - MB) / 2.0,
            MT + (H - MT - MB) / 2.0,
            text(ylabel)
        );
        f
    }

    pub(crate) fn px(&self, x: f64) -> f64 {
        ML + (x - self.x0) / (self.x1 - self.x0) * (W - ML - MR)
    }

    pub(crate) fn py(&self, y: f64) -> f64 {
        H - MB - (y - self.y0) / (self.y1 - self.y0) * (H - MT - MB)
    }

    pub(crate) fn points(&mut self, pts: &[(f64, f64)], colour: &str) {
        for (x, y) in pts {
            if x.is_finite() && y.is_finite() {
                let _ = write!(
                    self.out,
                    r#"<circle cx="{:.1}" cy="{:.1}" r="3.5" fill="{colour}" fill-opacity="0.8"/>"#,
                    self.px(*x),
                    self.py(*y)
                );
            }
        }
    }

    pub(crate) fn polyline(&mut self, pts: &[(f64, f64)], colour: &str, dash: bool) {
        let d: Vec<String> = pts
            .iter()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .map(|(x, y)| format!("{:.1},{:.1}", self.px(*x), self.py(*y)))
            .collect();
        let _ = write!(
            self.out,
            r#"<polyline points="{}" fill="none" stroke="{colour}" stroke-width="1.5"{}/>"#,
            d.join(" "),
            if dash {
                r#" stroke-dasharray="5,4""#
            } else {
                ""
            }
        );
    }

    pub(crate) fn hline(&mut self, y: f64, colour: &str, label: &str) {
        let py = self.py(y);
        let _ = write!(
            self.out,
            r#"<line x1="{ML}" y1="{py:.1}" x2="{}" y2="{py:.1}" stroke="{colour}" stroke-dasharray="6,3"/><text x="{}" y="{:.1}" text-anchor="end" fill="{colour}">{}</text>"#,
            W - MR,
            W - MR - 4.0,
            py - 4.0,
            text(label)
        );
    }

    pub(crate) fn vline(&mut self, x: f64, colour: &str, label: &str) {
        let px = self.px(x);
        let _ = write!(
            self.out,
            r#"<line x1="{px:.1}" y1="{MT}" x2="{px:.1}" y2="{}" stroke="{colour}" stroke-dasharray="6,3"/><text x="{:.1}" y="{}" fill="{colour}">{}</text>"#,
            H - MB,
            px + 4.0,
            MT + 12.0,
            text(label)
        );
    }

    pub(crate) fn raw(&mut self, s: &str) {
        self.out.push_str(s);
    }

    pub(crate) fn finish(mut self) -> Markup {
        self.out.push_str("</svg>");
        PreEscaped(self.out)
    }
}

fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    v.filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        })
}

fn widen((a, b): (f64, f64), frac: f64) -> (f64, f64) {
    let s = (b - a).abs().max(1e-9);
    (a - frac * s, b + frac * s)
}

/// Horizontal Pareto chart of |t| with the critical value.
pub(crate) fn pareto(names: &[String], abs_t: &[f64], t_crit: f64) -> Markup {
    let mut order: Vec<usize> = (0..names.len()).collect();
    order.sort_by(|&a, &b| abs_t[b].total_cmp(&abs_t[a]));
    let xmax = abs_t.iter().copied().fold(t_crit, f64::max) * 1.1;
    let n = names.len().max(1) as f64;
    let mut f = Frame::categorical_y(
        "Pareto chart of standardized effects",
        "|t| (standardized effect)",
        (0.0, xmax),
        (0.0, n),
    );
    let band = (H - MT - MB) / n;
    for (rank, &i) in order.iter().enumerate() {
        let y = MT + rank as f64 * band + band * 0.15;
        let colour = if abs_t[i] > t_crit {
            "#c0392b"
        } else {
            "#7f8c8d"
        };
        f.raw(&format!(
            r#"<rect x="{ML}" y="{y:.1}" width="{:.1}" height="{:.1}" fill="{colour}"/><text x="{:.1}" y="{:.1}" font-weight="bold">{}</text>"#,
            f.px(abs_t[i]) - ML,
            band * 0.7,
            f.px(abs_t[i]) + 4.0,
            y + band * 0.45,
            text(&names[i])
        ));
    }
    f.vline(t_crit, "#2c3e50", &format!("t crit {}", fmt_tick(t_crit)));
    f.finish()
}

/// Responses along the steepest path, with the model's predictions and the target.
pub(crate) fn path_chart(
    steps: &[f64],
    observed: &[f64],
    predicted: &[f64],
    target: f64,
) -> Markup {
    let yr = widen(
        range(observed.iter().chain(predicted).copied().chain([target])),
        0.08,
    );
    let mut f = Frame::new(
        "Steepest path: response per step",
        "step",
        "response",
        widen(range(steps.iter().copied()), 0.05),
        yr,
    );
    let pred: Vec<(f64, f64)> = steps
        .iter()
        .copied()
        .zip(predicted.iter().copied())
        .collect();
    f.polyline(&pred, "#7f8c8d", true);
    let obs: Vec<(f64, f64)> = steps
        .iter()
        .copied()
        .zip(observed.iter().copied())
        .filter(|(_, y)| y.is_finite())
        .collect();
    f.polyline(&obs, "#2980b9", false);
    f.points(&obs, "#2980b9");
    f.hline(target, "#c0392b", &format!("target {}", fmt_tick(target)));
    f.finish()
}

/// Several targets: the overall desirability measured at each path step (1 = every target met).
pub(crate) fn desirability_chart(steps: &[f64], desirability: &[f64]) -> Markup {
    let mut f = Frame::new(
        "Steepest path: overall desirability per step",
        "step",
        "overall desirability",
        widen(range(steps.iter().copied()), 0.05),
        (0.0, 1.05),
    );
    let pts: Vec<(f64, f64)> = steps
        .iter()
        .copied()
        .zip(desirability.iter().copied())
        .filter(|(_, d)| d.is_finite())
        .collect();
    f.polyline(&pts, "#2980b9", false);
    f.points(&pts, "#2980b9");
    f.hline(1.0, "#c0392b", "every target met");
    f.finish()
}

/// Scatter plot; `diagonal` draws y = x, `zero` draws y = 0.
pub(crate) fn scatter(
    title: &str,
    xl: &str,
    yl: &str,
    pts: &[(f64, f64)],
    diagonal: bool,
    zero: bool,
) -> Markup {
    let xr = widen(range(pts.iter().map(|p| p.0)), 0.08);
    let yr = widen(range(pts.iter().map(|p| p.1)), 0.08);
    let (xr, yr) = if diagonal {
        let r = (xr.0.min(yr.0), xr.1.max(yr.1));
        (r, r)
    } else {
        (xr, yr)
    };
    let mut f = Frame::new(title, xl, yl, xr, yr);
    if diagonal {
        f.polyline(&[(xr.0, xr.0), (xr.1, xr.1)], "#7f8c8d", true);
    }
    if zero {
        f.hline(0.0, "#7f8c8d", "");
    }
    f.points(pts, "#2980b9");
    f.finish()
}

/// Filled contour map of `z(x, y)` on a grid, contour lines at `levels`, the `target` level
/// bold, and marked points.
#[allow(clippy::too_many_arguments)]
pub(crate) fn contour(
    title: &str,
    xl: &str,
    yl: &str,
    x: (f64, f64),
    y: (f64, f64),
    z: &dyn Fn(f64, f64) -> f64,
    target: f64,
    marks: &[(f64, f64, &str)],
) -> Markup {
    const N: usize = 40;
    let mut grid = vec![vec![0.0; N + 1]; N + 1];
    let xs: Vec<f64> = (0..=N)
        .map(|i| x.0 + (x.1 - x.0) * i as f64 / N as f64)
        .collect();
    let ys: Vec<f64> = (0..=N)
        .map(|j| y.0 + (y.1 - y.0) * j as f64 / N as f64)
        .collect();
    for (i, xv) in xs.iter().enumerate() {
        for (j, yv) in ys.iter().enumerate() {
            grid[i][j] = z(*xv, *yv);
        }
    }
    let (zmin, zmax) = range(grid.iter().flatten().copied());
    let mut f = Frame::new(title, xl, yl, x, y);
    let colour = |v: f64| {
        let t = ((v - zmin) / (zmax - zmin).max(1e-12)).clamp(0.0, 1.0);
        let r = (40.0 + 215.0 * t) as u8;
        let g = (90.0 + 120.0 * (1.0 - (2.0 * t - 1.0).abs())) as u8;
        let b = (220.0 - 190.0 * t) as u8;
        format!("#{r:02x}{g:02x}{b:02x}")
    };
    for i in 0..N {
        for j in 0..N {
            let v = 0.25 * (grid[i][j] + grid[i + 1][j] + grid[i][j + 1] + grid[i + 1][j + 1]);
            let (px0, px1) = (f.px(xs[i]), f.px(xs[i + 1]));
            let (py0, py1) = (f.py(ys[j + 1]), f.py(ys[j]));
            f.raw(&format!(
                r#"<rect x="{px0:.1}" y="{py0:.1}" width="{:.2}" height="{:.2}" fill="{}"/>"#,
                px1 - px0 + 0.3,
                py1 - py0 + 0.3,
                colour(v)
            ));
        }
    }
    let mut levels: Vec<f64> = nice_ticks(zmin, zmax, 8);
    levels.retain(|l| (l - target).abs() > 1e-9);
    for (level, bold) in levels.iter().map(|l| (*l, false)).chain([(target, true)]) {
        let mut d = String::new();
        for i in 0..N {
            for j in 0..N {
                let c = [
                    (xs[i], ys[j], grid[i][j]),
                    (xs[i + 1], ys[j], grid[i + 1][j]),
                    (xs[i + 1], ys[j + 1], grid[i + 1][j + 1]),
                    (xs[i], ys[j + 1], grid[i][j + 1]),
                ];
                let mut cuts = Vec::new();
                for e in 0..4 {
                    let (a, b) = (c[e], c[(e + 1) % 4]);
                    if (a.2 - level) * (b.2 - level) < 0.0 {
                        let t = (level - a.2) / (b.2 - a.2);
                        cuts.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
                    }
                }
                for pair in cuts.chunks(2) {
                    if let [p, q] = pair {
                        let _ = write!(
                            d,
                            "M{:.1},{:.1}L{:.1},{:.1}",
                            f.px(p.0),
                            f.py(p.1),
                            f.px(q.0),
                            f.py(q.1)
                        );
                    }
                }
            }
        }
        if !d.is_empty() {
            f.raw(&format!(
                r##"<path d="{d}" fill="none" stroke="{}" stroke-width="{}"/>"##,
                if bold { "#000" } else { "#ffffff" },
                if bold { 2.5 } else { 0.8 }
            ));
        }
    }
    for (mx, my, label) in marks {
        let (px, py) = (f.px(*mx), f.py(*my));
        f.raw(&format!(
            r##"<circle cx="{px:.1}" cy="{py:.1}" r="5" fill="none" stroke="#000" stroke-width="2"/><text x="{:.1}" y="{:.1}" font-weight="bold">{}</text>"##,
            px + 7.0,
            py - 6.0,
            text(label)
        ));
    }
    f.raw(&format!(
        r#"<text x="{}" y="{}" text-anchor="end" font-size="9">bold line: {} · range {}..{}</text>"#,
        W - MR,
        H - 2.0,
        fmt_tick(target),
        fmt_tick(zmin),
        fmt_tick(zmax)
    ));
    f.finish()
}

/// Standard normal quantile (Acklam's rational approximation, |error| < 1.2e-9).
pub(crate) fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let pl = 0.02425;
    if p < pl {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - pl {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        -normal_quantile(1.0 - p)
    }
}
