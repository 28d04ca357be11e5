//! `repose sim` as a user runs it: a scene file in, result files out.

use crate::common;
use common::{repose, skipped_without_gpu, stderr, stdout, workspace_root};

const SCENE: &str = r#"
duration = 0.05
[domain]
min = [-0.03, -0.03, -0.01]
max = [0.03, 0.03, 0.06]
periodic_x = false
periodic_y = false
[materials]
materials = [
  { name = "soil", density = 2664.0, youngs_modulus = 3.67e6, poisson = 0.36 },
  { name = "steel", density = 7850.0, youngs_modulus = 2.1e11, poisson = 0.30 },
]
interactions = [
  { a = "soil", b = "soil", restitution = 0.45, static_friction = 0.442, rolling_friction = 0.14 },
  { a = "soil", b = "steel", restitution = 0.4, static_friction = 0.305, rolling_friction = 0.5 },
  { a = "steel", b = "steel", restitution = 0.5, static_friction = 0.3, rolling_friction = 0.01 },
]
[[geometries]]
name = "plate"
material = "steel"
mesh = { kind = "plane", size_x = 0.05, size_y = 0.05, cells_x = 2, cells_y = 2 }
[[factories]]
material = "soil"
region = { kind = "box", min = [-0.01, -0.01, 0.005], max = [0.01, 0.01, 0.02] }
mass_rate = 0.1
total_mass = 0.0005
size = { kind = "fixed", radius = 0.001 }
[output]
snapshot_interval = 0.025
geometry_record_interval = 10
"#;

#[test]
fn sim_writes_final_state_forces_and_snapshots() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let out_dir = dir.path().join("out");
    let out = repose(&[
        "sim",
        scene.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--threads",
        "2",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let summary: serde_json::Value = serde_json::from_str(&stdout(&out)).unwrap();
    let particles = summary["particles"].as_u64().unwrap();
    assert!(particles > 10, "{summary}");

    let final_csv = std::fs::read_to_string(out_dir.join("final.csv")).unwrap();
    let mut lines = final_csv.lines();
    assert_eq!(lines.next().unwrap(), "id,x,y,z,vx,vy,vz,wx,wy,wz,radius");
    assert_eq!(lines.count() as u64, particles);

    let forces = std::fs::read_to_string(out_dir.join("geometry_forces.csv")).unwrap();
    assert!(forces.starts_with("geometry,time,fx,fy,fz,tx,ty,tz\nplate,"));
    // Grains land on the plate: at some time it is pushed down.
    let min_fz = forces
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(4).unwrap().parse::<f64>().unwrap())
        .fold(f64::INFINITY, f64::min);
    assert!(min_fz < 0.0, "plate force never downward: {min_fz}");

    for name in [
        "particles_00000.vtk",
        "plate_00000.vtk",
        "particles_00002.vtk",
    ] {
        let vtk = std::fs::read_to_string(out_dir.join(name)).unwrap();
        assert!(vtk.starts_with("# vtk DataFile Version 3.0"), "{name}");
    }
}

#[test]
fn invalid_scene_is_one_line_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene.toml");
    std::fs::write(&scene, SCENE.replace("poisson = 0.36", "poisson = 0.6")).unwrap();
    let out = repose(&[
        "sim",
        scene.to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    let err = stderr(&out);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("materials.soil.poisson"), "{err}");

    let missing = dir.path().join("missing.toml");
    let out = repose(&[
        "sim",
        missing.to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("missing.toml"));

    std::fs::write(
        &scene,
        SCENE.replace("duration = 0.05", "duration = \"soon\""),
    )
    .unwrap();
    let out = repose(&[
        "sim",
        scene.to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("duration"), "{}", stderr(&out));
}

#[test]
fn example_scenes_parse_and_validate() {
    let dir = workspace_root().join("examples/scenes");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        // A zero-length run validates the scene without simulating it.
        let out = repose(&[
            "sim",
            path.to_str().unwrap(),
            "--out",
            tempfile::tempdir().unwrap().path().to_str().unwrap(),
            "--duration",
            "1e-9",
        ]);
        assert!(out.status.success(), "{}: {}", path.display(), stderr(&out));
        seen += 1;
    }
    assert!(seen >= 1);
}

/// `repose bench engine --backend gpu` where no Vulkan driver can be found: a clear error naming
/// the problem and the flag, exit non-zero, no fall back to the CPU engine.
#[test]
fn bench_engine_on_the_gpu_without_an_adapter_names_the_problem() {
    let out = std::process::Command::new(common::repose_bin())
        .args(["bench", "engine", "--backend", "gpu", "--particles", "200"])
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .output()
        .expect("spawning repose");
    let err = stderr(&out);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("--backend gpu") && err.contains("no GPU adapter"),
        "{err}"
    );
    assert!(
        !stdout(&out).contains(" cpu ") && !stdout(&out).lines().any(|l| l.contains(" 1 ")),
        "{}",
        stdout(&out)
    );
}

/// The GPU engine times a small bed and the CPU engine on the same bed (on lavapipe in CI;
/// skipped with a message where no Vulkan adapter exists at all).
#[test]
fn bench_engine_on_the_gpu_times_the_gpu_and_the_cpu_on_one_bed() {
    let out = repose(&[
        "bench",
        "engine",
        "--backend",
        "gpu",
        "--particles",
        "300",
        "--steps",
        "20",
        "--cpu-steps",
        "20",
        "--threads",
        "1",
        "--json",
    ]);
    let err = stderr(&out);
    if !out.status.success() && skipped_without_gpu(&err) {
        return;
    }
    assert!(out.status.success(), "{err}");
    let rows: Vec<serde_json::Value> = stdout(&out)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(rows.len(), 2, "{rows:?}");
    assert_eq!(rows[0]["backend"], "cpu");
    assert_eq!(rows[1]["backend"], "gpu");
    for row in &rows {
        assert_eq!(row["particles"], 300);
        assert!(row["mega_particle_steps_per_s"].as_f64().unwrap() > 0.0);
        // The same settled bed: a dense packing, a handful of contacts per grain on both.
        let contacts = row["contacts_per_particle"].as_f64().unwrap();
        assert!((3.0..8.0).contains(&contacts), "{row}");
    }
    assert!(rows[1]["speedup_vs_1_thread"].as_f64().is_some());
}
