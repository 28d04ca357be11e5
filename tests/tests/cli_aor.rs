//! `repose aor` as a user runs it: preset and --set in, result.json / pile.svg / final.csv out.

use crate::common;
use common::{repose, skipped_without_gpu, stderr, stdout};

#[test]
fn aor_writes_result_svg_and_csv() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = repose(&[
        "aor",
        "--preset",
        "fast",
        "--set",
        "total_mass=0.012",
        "--out",
        out.to_str().unwrap(),
        "--threads",
        "1",
        "--quiet",
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let printed: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("result.json")).unwrap()).unwrap();
    assert_eq!(printed, file);
    assert!(file.get("angle_deg").is_some());
    assert!(file["status"].is_string());
    assert!(file["grains"]["inserted"]["count"].as_u64().unwrap() > 400);
    // A small pour may not form a measurable heap; then there is no angle and no picture.
    if file["angle_deg"].is_number() {
        let svg = std::fs::read_to_string(out.join("pile.svg")).unwrap();
        assert!(svg.contains("<svg"));
    } else {
        assert_ne!(file["status"], "ok");
        assert!(!out.join("pile.svg").exists());
    }
    let csv = std::fs::read_to_string(out.join("final.csv")).unwrap();
    assert!(csv.lines().count() > 400);

    // `repose ladder` charts runs given as folders or result files; anything else is one line
    // and exit status 2.
    let chart = dir.path().join("ladder.svg");
    let result = out.join("result.json");
    let o = repose(&[
        "ladder",
        "--out",
        chart.to_str().unwrap(),
        out.to_str().unwrap(),
        result.to_str().unwrap(),
    ]);
    if file["angle_deg"].is_number() {
        assert!(o.status.success(), "stderr: {}", stderr(&o));
        let rows: Vec<String> = stdout(&o).lines().map(str::to_owned).collect();
        assert_eq!(rows.len(), 3, "{rows:?}");
        assert!(rows[1].starts_with("run,"), "{rows:?}");
        assert_eq!(rows[1], rows[2]);
        let svg = std::fs::read_to_string(&chart).unwrap();
        assert_eq!(svg.matches("<circle").count(), 2);
        // The table it printed is input too: the same points, the same chart.
        let table = dir.path().join("points.csv");
        std::fs::write(&table, stdout(&o)).unwrap();
        let again = repose(&[
            "ladder",
            "--out",
            chart.to_str().unwrap(),
            table.to_str().unwrap(),
        ]);
        assert!(again.status.success(), "stderr: {}", stderr(&again));
        assert_eq!(stdout(&again), stdout(&o));
        assert_eq!(std::fs::read_to_string(&chart).unwrap(), svg);
    } else {
        assert_eq!(o.status.code(), Some(2));
        assert!(stderr(&o).contains("measured no heap"), "{}", stderr(&o));
    }
    let o = repose(&[
        "ladder",
        "--out",
        chart.to_str().unwrap(),
        out.join("final.csv").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(stderr(&o).trim().lines().count(), 1, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("is not a ladder table"),
        "{}",
        stderr(&o)
    );
    let not_a_result = dir.path().join("other.json");
    std::fs::write(&not_a_result, r#"{"x": 1}"#).unwrap();
    let o = repose(&[
        "ladder",
        "--out",
        chart.to_str().unwrap(),
        not_a_result.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(stderr(&o).trim().lines().count(), 1, "{}", stderr(&o));
    assert!(stderr(&o).contains("is not an angle-of-repose result"));
}

#[test]
fn aor_print_spec_applies_sets_and_spec_files() {
    let dir = tempfile::tempdir().unwrap();
    let spec = dir.path().join("spec.json");
    std::fs::write(
        &spec,
        r#"{"soil_soil": {"rolling_friction": 0.3}, "total_mass": 0.02}"#,
    )
    .unwrap();
    let o = repose(&[
        "aor",
        "--spec",
        spec.to_str().unwrap(),
        "--set",
        "funnel.outlet_height=0.09",
        "--print-spec",
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["soil_soil"]["rolling_friction"], 0.3);
    assert_eq!(v["soil_soil"]["static_friction"], 0.442);
    assert_eq!(v["total_mass"], 0.02);
    assert_eq!(v["funnel"]["outlet_height"], 0.09);
}

#[test]
fn aor_bad_set_is_one_line_and_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    for args in [
        vec!["aor", "--set", "soil_soil.rolling=0.3", "--print-spec"],
        vec!["aor", "--set", "total_mass=-1", "--print-spec"],
        vec!["aor", "--preset", "huge", "--print-spec"],
    ] {
        let mut args = args.clone();
        let out = dir.path().join("x");
        args.extend(["--out", out.to_str().unwrap()]);
        let o = repose(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        let err = stderr(&o);
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.starts_with("error:"), "{err}");
    }
}

/// A 35° cone of 1 mm spheres on z = 0 (as in the measurement's doc example), plus grains held
/// up in the funnel above the outlet, which the measurement must leave out.
fn cone_csv() -> String {
    let (radius, base_radius) = (1e-3, 0.03);
    let (tan, cos) = (35f64.to_radians().tan(), 35f64.to_radians().cos());
    let mut csv = String::from("id,type,x,y,z,radius\n");
    let mut id = 0;
    for i in -16i32..=16 {
        for j in -16i32..=16 {
            let lift = f64::from((i * 7 + j * 13).rem_euclid(5)) * 0.4e-3;
            for k in 0..16 {
                let p = [
                    f64::from(i) * 2e-3,
                    f64::from(j) * 2e-3,
                    radius + lift + f64::from(k) * 2e-3,
                ];
                let surface = (base_radius - p[0].hypot(p[1])) * tan;
                if p[2] <= surface - radius / cos {
                    id += 1;
                    csv += &format!("{id},1,{},{},{},{radius}\n", p[0], p[1], p[2]);
                }
            }
        }
    }
    for k in 0..40 {
        // In the funnel, 110-130 mm up: not part of the heap.
        let z = 0.11 + 0.0005 * f64::from(k);
        csv += &format!(
            "{},1,{},0.0,{z},{radius}\n",
            id + k + 1,
            0.004 * f64::from(k % 3)
        );
    }
    csv
}

#[test]
fn aor_measure_reads_a_particle_file_as_a_run_measures_its_heap() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("peer.csv");
    std::fs::write(&file, cone_csv()).unwrap();
    let out = dir.path().join("measured");
    let o = repose(&[
        "aor",
        "--preset",
        "paper-scale",
        "--measure",
        file.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let m: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let angle = m["angle_deg"].as_f64().unwrap();
    assert!((angle - 35.0).abs() < 1.5, "{angle}");
    // The held-up grains are left out: the apex is the cone's, not the funnel's.
    assert!(m["pile_height_m"].as_f64().unwrap() < 0.03, "{m}");
    let saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("measure.json")).unwrap()).unwrap();
    assert_eq!(saved, m);
    assert!(std::fs::read_to_string(out.join("pile.svg"))
        .unwrap()
        .contains("<svg"));

    // A file without a radius column: one line naming it, exit 2.
    std::fs::write(&file, "x,y,z\n0,0,0.001\n").unwrap();
    let o = repose(&["aor", "--measure", file.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    let err = stderr(&o);
    assert!(err.contains("radius"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

#[test]
fn aor_export_stl_writes_the_rig_in_the_run_frame() {
    let dir = tempfile::tempdir().unwrap();
    let o = repose(&[
        "aor",
        "--preset",
        "paper-scale",
        "--export-stl",
        dir.path().to_str().unwrap(),
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let read = |name: &str| {
        let bytes = std::fs::read(dir.path().join(name)).unwrap();
        assert!(bytes.starts_with(b"solid"), "{name} is ASCII STL");
        repose_engine::mesh::TriMesh::from_stl_bytes(&bytes, 1.0).unwrap()
    };
    let (lo, hi) = read("base.stl").aabb();
    assert!(
        (lo.x + 0.15).abs() < 1e-9 && (hi.x - 0.15).abs() < 1e-9,
        "{lo:?} {hi:?}"
    );
    assert!(lo.z.abs() < 1e-9 && hi.z.abs() < 1e-9);
    let (lo, hi) = read("funnel.stl").aabb();
    // Outlet 105 mm up, 40 mm cone; top diameter 63.2 mm.
    assert!(
        (lo.z - 0.105).abs() < 1e-6 && (hi.z - 0.145).abs() < 1e-6,
        "{lo:?} {hi:?}"
    );
    assert!((hi.x - 0.0316).abs() < 1e-3, "{hi:?}");
}

#[test]
fn ladder_reads_the_table_it_prints() {
    let dir = tempfile::tempdir().unwrap();
    let table = dir.path().join("points.csv");
    let text = "run,height_grains,angle_deg,came_to_rest\n\
                \"0.3 kg, 2 mm\",21.3,40.37,true\n\
                50 g #1,8.55,24.93,false\n";
    std::fs::write(&table, text).unwrap();
    let chart = dir.path().join("ladder.svg");
    let o = repose(&[
        "ladder",
        "--out",
        chart.to_str().unwrap(),
        table.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    assert_eq!(stdout(&o), text);
    let svg = std::fs::read_to_string(&chart).unwrap();
    assert_eq!(svg.matches("<circle").count(), 2);
    assert!(svg.contains("0.3 kg, 2 mm (40.4°)"), "{svg}");

    // A bad value names the file and the row; exit status 2, one line.
    for (bad, says) in [
        (
            "run,height_grains,angle_deg,came_to_rest\nx,1.0,steep,true\n",
            "row 1",
        ),
        (
            "run,height_grains,angle_deg,came_to_rest\nx,-1.0,30,true\n",
            "row 1 (x)",
        ),
        ("run,angle_deg\nx,30\n", "is not a ladder table"),
    ] {
        std::fs::write(&table, bad).unwrap();
        let o = repose(&[
            "ladder",
            "--out",
            chart.to_str().unwrap(),
            table.to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(2), "{bad}");
        assert_eq!(stderr(&o).trim().lines().count(), 1, "{}", stderr(&o));
        assert!(stderr(&o).contains(says), "{bad}: {}", stderr(&o));
    }
}

#[test]
fn aor_killed_mid_run_goes_on_from_its_checkpoint_and_ends_as_if_never_stopped() {
    // A short fast pour, cut by the time cap while it settles. One copy runs through; another
    // keeps a checkpoint, is killed (SIGKILL) once it has one, and is run again with the same
    // command: it must continue from the checkpoint and write the same result to the last bit.
    let dir = tempfile::tempdir().unwrap();
    let args = short_pour;
    let whole = dir.path().join("whole");
    let o = repose(&args(&whole).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "stderr: {}", stderr(&o));

    let cut = dir.path().join("cut");
    let checkpoint = dir.path().join("state/aor.checkpoint");
    let with_checkpoint = checkpointed(args(&cut), &checkpoint);
    let mut child = std::process::Command::new(common::repose_bin())
        .args(&with_checkpoint)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    while !checkpoint.exists() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before it kept a checkpoint"
        );
        assert!(
            started.elapsed().as_secs() < 120,
            "no checkpoint after 2 min"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert!(
        child.try_wait().unwrap().is_none(),
        "the run must be killed before it ends"
    );
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!cut.join("result.json").exists());
    let kept = std::fs::read(&checkpoint).unwrap();

    // A checkpoint is refused by another spec (the error names the field) and garbage is
    // refused as garbage; neither is overwritten.
    let other = dir.path().join("other.checkpoint");
    std::fs::write(&other, &kept).unwrap();
    let mut other_args = args(&dir.path().join("other"));
    other_args
        .extend(["--set", "seed=2", "--checkpoint", other.to_str().unwrap()].map(str::to_owned));
    let o = repose(&other_args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!o.status.success());
    assert!(stderr(&o).contains("`seed`"), "stderr: {}", stderr(&o));
    assert_eq!(std::fs::read(&other).unwrap(), kept);
    std::fs::write(&other, b"{}").unwrap();
    let o = repose(&other_args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("not an angle-of-repose checkpoint"),
        "stderr: {}",
        stderr(&o)
    );

    let o = repose(
        &with_checkpoint
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    assert!(
        stderr(&o).contains("continuing from"),
        "stderr: {}",
        stderr(&o)
    );
    assert!(
        !checkpoint.exists(),
        "a finished run deletes its checkpoint"
    );
    let read = |dir: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join("result.json")).unwrap()).unwrap()
    };
    let (mut a, mut b) = (read(&whole), read(&cut));
    assert!(b["resumed_at_step"].as_u64().unwrap() > 0);
    assert!(a.get("resumed_at_step").is_none());
    for r in [&mut a, &mut b] {
        let o = r.as_object_mut().unwrap();
        o.remove("wall_time_s");
        o.remove("resumed_at_step");
    }
    assert_eq!(a, b);
    assert_eq!(
        std::fs::read_to_string(whole.join("final.csv")).unwrap(),
        std::fs::read_to_string(cut.join("final.csv")).unwrap()
    );
}

/// A small tmpfs mounted for one test and unmounted when dropped, also on failure.
struct SmallDisk {
    path: std::path::PathBuf,
}

impl SmallDisk {
    /// `None` (with the reason) where mounting is not allowed (not root, no CAP_SYS_ADMIN).
    fn mount(path: std::path::PathBuf, size: &str) -> Result<SmallDisk, String> {
        std::fs::create_dir_all(&path).map_err(|e| e.to_string())?;
        let out = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(&path)
            .output()
            .map_err(|e| format!("cannot run mount: {e}"))?;
        if out.status.success() {
            Ok(SmallDisk { path })
        } else {
            Err(String::from_utf8_lossy(&out.stderr).trim().to_owned())
        }
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount")
            .arg(&self.path)
            .status();
    }
}

#[test]
fn aor_with_its_checkpoint_on_a_full_disk_warns_and_ends_as_without() {
    // The checkpoint goes to a 192 KiB tmpfs: the first ones (few grains poured) fit, the
    // later ones do not. A checkpoint that cannot be written costs only the restart point:
    // the run says so and ends exactly as a run without a checkpoint. Needs the privilege to
    // mount (root); prints why and skips otherwise.
    let dir = tempfile::tempdir().unwrap();
    let disk = match SmallDisk::mount(dir.path().join("small"), "192k") {
        Ok(disk) => disk,
        Err(why) => {
            eprintln!("skipped: cannot mount a small tmpfs ({why})");
            return;
        }
    };
    let args = short_pour;
    let plain = dir.path().join("plain");
    let o = repose(&args(&plain).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "stderr: {}", stderr(&o));

    let full = dir.path().join("full");
    let checkpoint = disk.path.join("aor.checkpoint");
    let with_checkpoint = checkpointed(args(&full), &checkpoint);
    let o = repose(
        &with_checkpoint
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    let err = stderr(&o);
    assert!(o.status.success(), "stderr: {err}");
    assert!(
        err.contains("warning: checkpoint not kept"),
        "stderr: {err}"
    );
    assert!(err.contains("No space left on device"), "stderr: {err}");
    assert!(
        !checkpoint.exists(),
        "the finished run's checkpoint is deleted"
    );
    let result = |dir: &std::path::Path| -> serde_json::Value {
        let mut r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("result.json")).unwrap())
                .unwrap();
        r.as_object_mut().unwrap().remove("wall_time_s");
        r
    };
    assert_eq!(result(&full), result(&plain));
    assert_eq!(
        std::fs::read(full.join("final.csv")).unwrap(),
        std::fs::read(plain.join("final.csv")).unwrap()
    );
}

/// `repose aor` on a short fast pour (cut by the time cap while it settles), writing to `out`.
fn short_pour(out: &std::path::Path) -> Vec<String> {
    [
        "aor",
        "--preset",
        "fast",
        "--set",
        "settle.min_time=0.1",
        "--set",
        "settle.check_interval=0.05",
        "--set",
        "time_cap=0.25",
        "--threads",
        "1",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]
    .map(str::to_owned)
    .to_vec()
}

/// `args` with a checkpoint kept in `file` at every chance.
fn checkpointed(mut args: Vec<String>, file: &std::path::Path) -> Vec<String> {
    args.extend(
        [
            "--checkpoint",
            file.to_str().unwrap(),
            "--checkpoint-every",
            "0",
        ]
        .map(str::to_owned),
    );
    args
}

/// `--backend gpu`: `--checkpoint` is refused by name
/// before an adapter is opened; with one (lavapipe in CI) a small funnel (about 300 grains of
/// 4 mm, seconds) runs on the GPU and its result names the adapter. Without an adapter the run
/// is an error naming the problem, never a CPU run (`REPOSE_REQUIRE_GPU=1` makes that a
/// failure of the test).
#[test]
fn aor_runs_the_funnel_on_the_gpu_backend_and_refuses_checkpoints_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let gpu_run = |extra: &[&str]| {
        let mut args = vec!["aor", "--backend", "gpu", "--preset", "fast", "--quiet"];
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        args.extend_from_slice(extra);
        repose(&args)
    };
    let checkpoint = dir.path().join("run.ckpt");
    let o = gpu_run(&["--checkpoint", checkpoint.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--checkpoint"), "{}", stderr(&o));
    assert!(!out.exists(), "nothing ran");

    let mut small = vec![];
    for set in [
        "particle.radius=0.002",
        "total_mass=0.027",
        "mass_rate=0.1",
        "funnel.outlet_diameter=0.04",
        "base.size=0.15",
        "materials.soil.youngs_modulus=1e6",
        "soil_soil.rolling_friction=0.3",
    ] {
        small.extend_from_slice(&["--set", set]);
    }
    let o = gpu_run(&small);
    if !o.status.success() && skipped_without_gpu(&stderr(&o)) {
        return;
    }
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("result.json")).unwrap()).unwrap();
    let engine = file["engine_version"].as_str().unwrap();
    assert!(engine.contains("+gpu:"), "{engine}");
    assert!(stderr(&o).contains("GPU: "), "{}", stderr(&o));
    let inserted = file["grains"]["inserted"]["count"].as_u64().unwrap();
    assert!(inserted > 250, "{file}");
    let csv = std::fs::read_to_string(out.join("final.csv")).unwrap();
    let escaped = file["grains"]["escaped"]["count"].as_u64().unwrap();
    assert_eq!(csv.lines().count() as u64 - 1, inserted - escaped);
}
