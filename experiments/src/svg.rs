//! The SVG pieces every experiment's pictures share: the document header, text escaping, tick
//! steps and number formatting, and the plot frame of the x-y charts (the shear curves and
//! Mohr-Coulomb lines, the angle-of-repose ladder).

use std::fmt::Write as _;

/// The XML prolog, the `<svg>` element of `w` × `h` pixels and a white background.
pub(crate) fn header(w: f64, h: f64) -> String {
    format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<svg xmlns=\"http://www.w3.org/2000/svg\" \
         width=\"{w:.0}\" height=\"{h:.0}\" viewBox=\"0 0 {w:.0} {h:.0}\" \
         font-family=\"sans-serif\" font-size=\"13\">\n<rect width=\"100%\" height=\"100%\" \
         fill=\"white\"/>\n"
    )
}

/// XML text escaping for the few characters that matter. The workspace's one hand-written
/// escaper: these pictures are standalone SVG files from a crate without an HTML engine; the
/// campaign report and the server's status page escape through maud.
pub(crate) fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            _ => out.push(c),
        }
    }
    out
}

/// A "nice" tick step (1, 2 or 5 × 10ⁿ) giving about `target` ticks over `span`.
pub(crate) fn tick_step(span: f64, target: usize) -> f64 {
    let raw = span / target.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let norm = raw / mag;
    let nice = if norm < 1.5 {
        1.0
    } else if norm < 3.5 {
        2.0
    } else if norm < 7.5 {
        5.0
    } else {
        10.0
    };
    nice * mag
}

/// `v` with at most three decimals and no trailing zeros ("-0" as "0").
pub(crate) fn trim(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".to_owned()
    } else {
        s.to_owned()
    }
}

/// The x-y charts' page (760 × 500 px) and margins.
pub(crate) const ML: f64 = 70.0;
pub(crate) const MR: f64 = 30.0;
pub(crate) const MT: f64 = 60.0;
pub(crate) const MB: f64 = 50.0;
pub(crate) const WIDTH: f64 = 760.0;
pub(crate) const HEIGHT: f64 = 500.0;

/// The plot area mapping data (x in `[x0, x1]`, y in `[y0, y1]`) to the page.
pub(crate) struct Frame {
    pub(crate) x0: f64,
    pub(crate) x1: f64,
    pub(crate) y0: f64,
    pub(crate) y1: f64,
}

impl Frame {
    pub(crate) fn x(&self, v: f64) -> f64 {
        ML + (v - self.x0) / (self.x1 - self.x0) * (WIDTH - ML - MR)
    }
    pub(crate) fn y(&self, v: f64) -> f64 {
        MT + (self.y1 - v) / (self.y1 - self.y0) * (HEIGHT - MT - MB)
    }

    /// Box, zero lines, ticks and axis labels.
    pub(crate) fn axes(&self, s: &mut String, x_label: &str, y_label: &str) {
        let (w, h) = (WIDTH - ML - MR, HEIGHT - MT - MB);
        let _ = writeln!(
            s,
            "<rect x=\"{ML}\" y=\"{MT}\" width=\"{w:.1}\" height=\"{h:.1}\" fill=\"none\" stroke=\"#999\"/>"
        );
        if self.y0 < 0.0 && self.y1 > 0.0 {
            let _ = writeln!(
                s,
                "<line x1=\"{ML}\" y1=\"{0:.1}\" x2=\"{1:.1}\" y2=\"{0:.1}\" stroke=\"#bbb\"/>",
                self.y(0.0),
                ML + w
            );
        }
        let step = tick_step(self.x1 - self.x0, 8);
        let mut v = (self.x0 / step).ceil() * step;
        while v <= self.x1 + 1e-12 {
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" fill=\"#333\">{}</text>",
                self.x(v),
                MT + h + 18.0,
                trim(v)
            );
            v += step;
        }
        let step = tick_step(self.y1 - self.y0, 6);
        let mut v = (self.y0 / step).ceil() * step;
        while v <= self.y1 + 1e-12 {
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\" fill=\"#333\">{}</text>",
                ML - 6.0,
                self.y(v) + 4.0,
                trim(v)
            );
            v += step;
        }
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            ML + 0.5 * w,
            HEIGHT - 10.0,
            escape(x_label)
        );
        let _ = writeln!(
            s,
            "<text transform=\"translate(18 {:.1}) rotate(-90)\" text-anchor=\"middle\">{}</text>",
            MT + 0.5 * h,
            escape(y_label)
        );
    }
}
