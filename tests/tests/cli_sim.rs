//! `repose sim` as a user runs it: a scene file in, result files out.

mod common;
use common::{repose, stderr, stdout, workspace_root};

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
