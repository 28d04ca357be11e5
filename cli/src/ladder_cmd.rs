//! `repose ladder`: angle-of-repose runs (each a `result.json` of `repose aor`, or the folder
//! holding it) as one chart, the angle against the heap's height in grain diameters, written as
//! SVG; the points are also printed as CSV. For the grain-size and mass ladders of docs/aor.md.

use anyhow::{bail, Context, Result};
use clap::Args;
use repose_experiments::aor::{ladder_svg, AorResult, LadderPoint};
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Debug, Args)]
pub struct LadderArgs {
    /// Runs: `result.json` files or the folders `repose aor --out` wrote them to. A point is
    /// labelled with its folder's name.
    #[arg(required = true, value_name = "RUN")]
    pub runs: Vec<PathBuf>,
    /// The SVG file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// The angle the ladder is compared with (dashed line), degrees: the paper's 34.85°.
    #[arg(long, default_value_t = 34.85)]
    pub reference: f64,
    /// Half-width of the band drawn around the reference, degrees.
    #[arg(long, default_value_t = 2.0)]
    pub band: f64,
}

pub fn run(args: &LadderArgs) -> Result<()> {
    if !(args.reference.is_finite() && args.band.is_finite() && args.band >= 0.0) {
        bail!("--reference and --band must be finite, --band >= 0");
    }
    let mut points = Vec::new();
    println!("run,height_grains,angle_deg,came_to_rest");
    for run in &args.runs {
        let (file, label) = locate(run);
        let text = std::fs::read_to_string(&file)
            .with_context(|| format!("cannot read {}", file.display()))?;
        let result: AorResult = serde_json::from_str(&text)
            .with_context(|| format!("{} is not an angle-of-repose result", file.display()))?;
        let Some(point) = LadderPoint::from_result(label, &result) else {
            bail!(
                "{}: the run measured no heap (no angle or height)",
                file.display()
            );
        };
        println!(
            "{},{},{},{}",
            point.label, point.height_grains, point.angle_deg, point.came_to_rest
        );
        points.push(point);
    }
    crate::sim::write_file(&args.out, |w| {
        w.write_all(ladder_svg(&points, args.reference, args.band).as_bytes())
    })?;
    eprintln!("{} ({} runs)", args.out.display(), points.len());
    Ok(())
}

/// The result file of a run argument and the label of its point (the folder's name).
fn locate(run: &Path) -> (PathBuf, String) {
    let file = if run.is_dir() {
        run.join("result.json")
    } else {
        run.to_path_buf()
    };
    let folder = file.parent().unwrap_or(Path::new("."));
    let label = folder
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| file.display().to_string());
    (file, label)
}
