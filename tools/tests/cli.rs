//! The `scalpel` binary as a user runs it: reports, exports, and clear failures.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use scalpel_sim::geometry::{LengthUnit, MeshFormat, ValidationOptions, import_mesh, validate};

fn scalpel(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_scalpel"))
        .args(args)
        .output()
        .expect("the scalpel binary runs")
}

fn ok_json(args: &[&str]) -> serde_json::Value {
    let out = scalpel(args);
    assert!(
        out.status.success(),
        "{args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("valid JSON on stdout")
}

/// Runs a command that must fail; returns its stderr.
fn fails(args: &[&str]) -> String {
    let out = scalpel(args);
    assert!(!out.status.success(), "{args:?} should fail");
    assert!(out.stdout.is_empty(), "nothing on stdout when failing");
    String::from_utf8(out.stderr).expect("utf-8 stderr")
}

#[test]
fn demo_prints_the_liver_report() {
    let out = scalpel(&["demo"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.starts_with("scene liver"), "{text}");
    assert!(text.contains("508 triangles"), "{text}");
}

/// `scalpel settle` brings the liver to rest on its tray under standard gravity and writes
/// the settled surface and its render; a block held by nothing is refused.
#[test]
fn settle_rests_the_liver_on_its_supports() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("settled");
    let r = ok_json(&["settle", "liver", "--json", "--out", out.to_str().unwrap()]);
    for key in [
        "sag_mm",
        "max_displacement_mm",
        "settle_s",
        "residual_n",
        "on_tray",
    ] {
        assert!(r.get(key).is_some(), "missing {key}: {r}");
    }
    assert_eq!(r["settled"], true, "{r}");
    // The liver has standard gravity of its own.
    assert_eq!(r["gravity_added"], false, "{r}");
    assert_eq!(r["gravity_m_s2"][2], -9.81, "{r}");
    assert!(r["sag_mm"].as_f64().unwrap() > 0.1, "{r}");
    assert!(r["on_tray"].as_u64().unwrap() > 0, "{r}");
    for file in ["settled.vtk", "settled.png"] {
        assert!(
            std::fs::metadata(out.join(file)).unwrap().len() > 1000,
            "{file}"
        );
    }
    let refused = scalpel(&["settle", "block", "--out", out.to_str().unwrap()]);
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(err.contains("nothing holds the body"), "{err}");
}

/// `scalpel probe` presses the liver on its supports and reads the force from the tissue;
/// the block, held by nothing, is refused with the reason.
#[test]
fn probe_reads_the_force_from_the_tissue() {
    let r = ok_json(&["probe", "liver", "--json", "--depth-mm", "2"]);
    for key in [
        "force_n",
        "stiffness_n_per_mm",
        "analytic_n_per_mm",
        "contact_points",
        "max_det_f_loss",
        "curve",
    ] {
        assert!(r.get(key).is_some(), "missing {key}: {r}");
    }
    assert_eq!(r["converged"], true, "{r}");
    // The liver has standard gravity of its own.
    assert_eq!(r["gravity_added"], false, "{r}");
    assert_eq!(r["gravity_m_s2"][2], -9.81, "{r}");
    let force = r["force_n"].as_f64().unwrap();
    let secant = r["secant_n_per_mm"].as_f64().unwrap();
    let half_space = r["analytic_n_per_mm"].as_f64().unwrap();
    assert!(
        force > 0.0 && (secant / half_space - 1.0).abs() < 0.5,
        "{r}"
    );
    assert!(r["contact_points"].as_u64().unwrap() > 0, "{r}");
    let refused = scalpel(&["probe", "block"]);
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(err.contains("nothing holds the body"), "{err}");
    let bad = scalpel(&["probe", "liver", "--at", "1,2"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("X,Y,Z"));
}

#[test]
fn scene_list_names_every_builtin() {
    let list = ok_json(&["scene", "list", "--json"]);
    let names: Vec<&str> = list
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["liver", "shoulder", "cerebroma", "block", "beam"]);
}

#[test]
fn inspect_json_has_the_documented_keys() {
    let r = ok_json(&["scene", "inspect", "liver", "--json"]);
    for key in [
        "name",
        "triangles",
        "vertices",
        "points",
        "spacing_mm",
        "bbox_mm",
        "volume_ml",
        "mass_g",
        "min_angle_deg",
        "build_ms",
    ] {
        assert!(r.get(key).is_some(), "missing {key} in {r}");
    }
    assert_eq!(r["name"], "liver");
    assert_eq!(r["triangles"], 508);
    let points = r["points"].as_u64().unwrap();
    assert!(points.abs_diff(1526) <= 45, "{points}");
    assert!(r["build_ms"].as_f64().unwrap() > 0.0);
    // The time step its solver plans for 1 ms ticks: one sub-step, by the mass floor.
    assert_eq!(r["time_step"]["substeps_per_tick"], 1, "{r}");
    assert_eq!(r["time_step"]["mass_floor"]["substeps_before"], 2, "{r}");
    assert!(r["time_step"]["dt_crit_ms"].as_f64().unwrap() >= 2.0, "{r}");
    let bbox: Vec<f64> = r["bbox_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!((bbox[0] - 250.0).abs() < 1e-6 && (bbox[2] - 50.0).abs() < 1e-6);
    // Mass = ρ × volume for liver tissue.
    let mass = r["mass_g"].as_f64().unwrap();
    let volume = r["volume_ml"].as_f64().unwrap();
    assert!((mass / (1.06 * volume) - 1.0).abs() < 1e-9);
}

#[test]
fn inspect_reads_scene_files_and_mesh_files() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("stiff_block.toml");
    std::fs::write(
        &scene,
        "extends = \"block\"\n[material]\nyoungs_modulus_kpa = 1000\npoisson_ratio = 0.499\n[sampling]\nspacing_mm = 5\n",
    )
    .unwrap();
    let r = ok_json(&["scene", "inspect", scene.to_str().unwrap(), "--json"]);
    assert_eq!(r["name"], "stiff_block");
    assert_eq!(r["points"], 7 * 7 * 7);
    assert!((r["spacing_mm"].as_f64().unwrap() - 5.0).abs() < 1e-12);
    assert_eq!(r["material"]["youngs_modulus_kpa"], 1000.0);

    // A mesh file in millimetres, sampled with a given point count.
    let mesh = dir.path().join("tetra.obj");
    std::fs::write(
        &mesh,
        "v 0 0 0\nv 30 0 0\nv 0 30 0\nv 0 0 30\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n",
    )
    .unwrap();
    let inspect = |extra: &[&str]| {
        let mesh = mesh.to_str().unwrap();
        let args = [
            &["scene", "inspect", mesh, "--units", "mm", "--json"],
            extra,
        ]
        .concat();
        ok_json(&args)
    };
    let r = inspect(&["--target-points", "300"]);
    assert_eq!(r["triangles"], 4);
    assert!((r["volume_ml"].as_f64().unwrap() - 4.5).abs() < 1e-9);
    assert!(r["points"].as_u64().unwrap().abs_diff(300) < 30);
    assert!(
        r["sampling_plan"].is_null(),
        "a given count is not planned: {r}"
    );

    // At a mesh file's default sampling the small tetrahedron's 2000 points would take more
    // point-sub-steps per 1 ms tick than real time affords: it is sampled coarser.
    let r = inspect(&[]);
    let plan = &r["sampling_plan"];
    let cost =
        |s: &serde_json::Value| s["points"].as_u64().unwrap() * s["substeps"].as_u64().unwrap();
    let budget = plan["budget"].as_u64().unwrap();
    assert!(cost(&plan["first"]) > budget, "{r}");
    assert!(cost(&plan["kept"]) <= budget, "{r}");
    assert_eq!(r["points"], plan["kept"]["points"], "{r}");
    assert_eq!(
        r["time_step"]["substeps_per_tick"], plan["kept"]["substeps"],
        "{r}"
    );
}

#[test]
fn malformed_inputs_fail_with_a_message_on_stderr() {
    let dir = tempfile::tempdir().unwrap();
    let open = dir.path().join("open.obj");
    std::fs::write(
        &open,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\n",
    )
    .unwrap();
    // A negative fault parameter reaches the range check (clap took `-5` for a flag and
    // advised `-- -5`, which does not work either); checked before any connection.
    let err = fails(&[
        "instruct",
        "127.0.0.1:9",
        "--certs",
        dir.path().to_str().unwrap(),
        "--name",
        "ann",
        "fault",
        "force-spike",
        "--newtons",
        "-5",
    ]);
    assert!(err.contains("newtons -5 is outside 0..=1000"), "{err}");
    // Table 1's physical cut takes β as a scene file would, range-checked before any run.
    for beta in ["200", "NaN"] {
        let err = fails(&["bench", "table1", "--fracture", beta]);
        assert!(
            err.contains("material.stiffening") && err.contains("out of range"),
            "{err}"
        );
    }
    // A certificate that is a device or huge is refused, not read whole (/dev/zero was read
    // until memory ran out).
    let lab = dir.path().join("lab");
    std::fs::create_dir(&lab).unwrap();
    std::os::unix::fs::symlink("/dev/zero", lab.join("ca.pem")).unwrap();
    let instruct = |lab: &Path| {
        fails(&[
            "instruct",
            "127.0.0.1:9",
            "--certs",
            lab.to_str().unwrap(),
            "--name",
            "ann",
            "list",
        ])
    };
    let err = instruct(&lab);
    assert!(err.contains("ca.pem: not a regular file"), "{err}");
    std::fs::remove_file(lab.join("ca.pem")).unwrap();
    std::fs::write(lab.join("ca.pem"), vec![b'A'; 2 << 20]).unwrap();
    let err = instruct(&lab);
    assert!(err.contains("ca.pem: over 1048576 bytes"), "{err}");
    let err = fails(&["scene", "inspect", open.to_str().unwrap()]);
    assert!(
        err.contains("open.obj") && err.contains("not closed"),
        "{err}"
    );

    let txt = dir.path().join("organ.txt");
    std::fs::write(&txt, "hello").unwrap();
    let err = fails(&["scene", "inspect", txt.to_str().unwrap()]);
    assert!(err.contains("unsupported mesh format"), "{err}");

    let err = fails(&[
        "scene",
        "inspect",
        dir.path().join("missing.stl").to_str().unwrap(),
    ]);
    assert!(err.contains("cannot open mesh file"), "{err}");

    let err = fails(&["scene", "inspect", "kidney"]);
    assert!(err.contains("not a built-in scene"), "{err}");

    let bad_scene = dir.path().join("bad.toml");
    std::fs::write(
        &bad_scene,
        "extends = \"liver\"\n\n[material]\nstiffness = 3\n",
    )
    .unwrap();
    let err = fails(&["scene", "inspect", bad_scene.to_str().unwrap()]);
    assert!(
        err.contains("bad.toml") && err.contains("line 4") && err.contains("stiffness"),
        "{err}"
    );

    let range = dir.path().join("range.toml");
    std::fs::write(
        &range,
        "extends = \"liver\"\n[material]\npoisson_ratio = 0.5\n",
    )
    .unwrap();
    let err = fails(&["scene", "inspect", range.to_str().unwrap()]);
    assert!(err.contains("material.poisson_ratio"), "{err}");

    let truncated = dir.path().join("cut.stl");
    let mut bytes = vec![0u8; 80];
    bytes.extend_from_slice(&12u32.to_le_bytes());
    bytes.extend_from_slice(&[0u8; 100]);
    std::fs::write(&truncated, bytes).unwrap();
    let err = fails(&["scene", "inspect", truncated.to_str().unwrap()]);
    assert!(err.contains("truncated"), "{err}");

    let err = fails(&["scene", "inspect", "liver", "--spacing-mm=-1"]);
    assert!(err.contains("spacing"), "{err}");
    // The command line keeps a scene file's sampling bounds.
    let err = fails(&["scene", "inspect", "liver", "--spacing-mm=1e9"]);
    assert!(
        err.contains("--spacing-mm") && err.contains("1000 mm"),
        "{err}"
    );
    let err = fails(&["scene", "inspect", "liver", "--target-points=1"]);
    assert!(err.contains("--target-points must be 8"), "{err}");
    let err = fails(&[
        "cut",
        "liver",
        "--strokes",
        "50000",
        "--out",
        "/nonexistent",
    ]);
    assert!(err.contains("--strokes must be 1 to 1000"), "{err}");

    // A device or a pipe named like a mesh or a scene: refused at once (/dev/zero was read
    // until memory ran out, a FIFO blocked for ever).
    let zero_obj = dir.path().join("zero.obj");
    std::os::unix::fs::symlink("/dev/zero", &zero_obj).unwrap();
    let err = fails(&["scene", "inspect", zero_obj.to_str().unwrap()]);
    assert!(
        err.contains("zero.obj") && err.contains("not a regular file"),
        "{err}"
    );
    let zero_toml = dir.path().join("zero.toml");
    std::os::unix::fs::symlink("/dev/zero", &zero_toml).unwrap();
    let err = fails(&["scene", "inspect", zero_toml.to_str().unwrap()]);
    assert!(err.contains("not a regular file"), "{err}");
    let fifo = dir.path().join("fifo.obj");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let err = fails(&["scene", "inspect", fifo.to_str().unwrap()]);
    assert!(err.contains("not a regular file"), "{err}");
}

fn reimport(path: &Path) -> scalpel_sim::geometry::ValidatedMesh {
    let bytes = std::fs::read(path).unwrap();
    let name = path.display().to_string();
    let format = MeshFormat::from_file_name(&name).unwrap();
    let mesh = import_mesh(&bytes, format, &name, LengthUnit::M, &Default::default()).unwrap();
    validate(mesh, &name, &ValidationOptions::default()).unwrap()
}

#[test]
fn export_writes_files_other_tools_read() {
    let dir = tempfile::tempdir().unwrap();
    let vtk = dir.path().join("beam.vtk");
    let out = scalpel(&["scene", "export", "beam", "--out", vtk.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // An independent VTK reader (vtkio) parses it: all surface vertices plus 425 points.
    let parsed = vtkio::Vtk::parse_legacy_be(std::fs::File::open(&vtk).unwrap())
        .expect("vtkio reads the export");
    let vtkio::model::DataSet::PolyData { pieces, .. } = parsed.data else {
        panic!("expected POLYDATA")
    };
    let vtkio::model::Piece::Inline(piece) = &pieces[0] else {
        panic!("expected inline data")
    };
    let surface = reimport(&vtk);
    assert_eq!(piece.num_points(), surface.stats.vertices + 425);
    assert_eq!(surface.stats.triangles, 576);
    assert!((surface.stats.volume_m3 - 4e-6).abs() < 1e-15);

    for ext in ["ply", "obj"] {
        let path = dir.path().join(format!("liver.{ext}"));
        let out = scalpel(&["scene", "export", "liver", "--out", path.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let back = reimport(&path);
        assert_eq!(back.stats.triangles, 508, "{ext}");
        assert!((back.stats.bbox.size().x - 0.25).abs() < 1e-9, "{ext}");
    }

    let err = fails(&[
        "scene",
        "export",
        "beam",
        "--out",
        dir.path().join("beam.stl").to_str().unwrap(),
    ]);
    assert!(err.contains("unsupported export format"), "{err}");
}

#[test]
fn validate_reports_json_and_rejects_unknown_names() {
    let r = ok_json(&["validate", "--only", "B1,B9,B11", "--json"]);
    let rows = r.as_array().unwrap();
    assert_eq!(rows.len(), 3);
    for row in rows {
        for key in ["name", "error", "tolerance", "pass", "wall_ms"] {
            assert!(row.get(key).is_some(), "missing {key}");
        }
        assert_eq!(row["pass"], true, "{row}");
    }
    let err = fails(&["validate", "--only", "B42"]);
    assert!(err.contains("unknown benchmark"), "{err}");
}

#[test]
fn a_report_piped_into_a_closed_reader_ends_quietly() {
    // `scalpel scene list | head -0`: the reader is gone before the first line; the
    // command ends by SIGPIPE, as `ls` would, with nothing on stderr (it used to panic in
    // println! with exit status 101 and a backtrace).
    use std::os::unix::process::ExitStatusExt;
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_scalpel"))
        .args(["scene", "list"])
        .stdout(writer)
        .output()
        .unwrap();
    assert_eq!(out.status.signal(), Some(libc::SIGPIPE), "{:?}", out.status);
    assert!(
        out.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `scalpel bench accuracy --out OUT` at 3 points across, then `rest`.
fn accuracy_args<'a>(out: &'a str, rest: &[&'a str]) -> Vec<&'a str> {
    let head = [
        "bench",
        "accuracy",
        "--out",
        out,
        "--min-across",
        "3",
        "--max-across",
        "3",
    ];
    head.into_iter().chain(rest.iter().copied()).collect()
}

#[test]
fn accuracy_bench_writes_csv_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let r = ok_json(&accuracy_args(
        out,
        &["--cut-points", "600", "--cut-reference", "1200", "--json"],
    ));
    let rows = r["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 16, "3 bodies × 5 integrators, and the cut");
    // The implicit rows take one step a tick and say how many CG iterations it took; the
    // stiff beam's explicit rows take many sub-steps.
    for row in rows.iter() {
        let mode = row["mode"].as_str().unwrap();
        if mode.starts_with("implicit") {
            assert_eq!(row["substeps_per_tick"], 1, "{row}");
            assert!(row["iterations_per_tick"].as_f64().unwrap() > 0.0, "{row}");
        }
        if mode == "explicit" && row["case"] == "cantilever-stiff" {
            assert!(row["substeps_per_tick"].as_u64().unwrap() >= 20, "{row}");
        }
    }
    // The liver stroke at 600 points against the same at 1200: the force curves differ, by
    // a few per cent (a sheared or missing curve would be off by far more).
    let cut = rows.iter().find(|row| row["case"] == "cut").unwrap();
    let e = cut["error"].as_f64().unwrap();
    assert!(e > 1e-4 && e < 0.2, "{cut}");
    assert!(cut["wall_s_per_simulated_s"].as_f64().unwrap() > 0.0);
    let reference = r["reference_tip_m"].as_f64().unwrap();
    assert!((reference - 5.19e-4).abs() < 1e-6, "{reference}");
    for row in rows.iter().filter(|row| row["case"] == "cantilever") {
        // Three points across are coarse: too stiff, and Timoshenko's figure sits further
        // off than the 3D reference's.
        let (e, t) = (
            row["error"].as_f64().unwrap(),
            row["error_timoshenko"].as_f64().unwrap(),
        );
        assert!(e > 0.05 && e < 0.3 && t > e, "{row}");
    }
    let csv = std::fs::read_to_string(dir.path().join("accuracy.csv")).unwrap();
    assert!(csv.starts_with("case,mode,points_across"));
    assert_eq!(csv.lines().count(), 17);
    let png = std::fs::read(dir.path().join("accuracy.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");

    // A peer's points join the report with their error against the same reference; one
    // case and one mode can be run alone (the peers script times scalpel that way).
    let peers = dir.path().join("peers.json");
    std::fs::write(
        &peers,
        r#"{"rows": [{"peer": "mujoco-flex", "across": 3, "nodes": 81,
            "wall_s_per_simulated_s": 0.5, "tip_m": 3.894e-4}]}"#,
    )
    .unwrap();
    let peers_arg = peers.to_str().unwrap();
    let r = ok_json(&accuracy_args(
        out,
        &[
            "--case",
            "cantilever",
            "--mode",
            "explicit",
            "--peers",
            peers_arg,
            "--json",
        ],
    ));
    assert_eq!(r["rows"].as_array().unwrap().len(), 1);
    let peer_error = r["peers"][0]["error"].as_f64().unwrap();
    assert!(
        (peer_error - (1.0 - 3.894e-4 / reference)).abs() < 1e-9,
        "{peer_error}"
    );
    let fits = r["fits"].as_array().unwrap();
    assert!(fits.iter().any(|f| f["mode"] == "mujoco-flex"), "{fits:?}");

    std::fs::write(&peers, "{\"rows\": [{\"peer\": \"x\"}]}").unwrap();
    let err = fails(&accuracy_args(
        out,
        &["--case", "cantilever", "--peers", peers_arg],
    ));
    assert!(err.contains("peers.json is not a peers file"), "{err}");
    let err = fails(&accuracy_args(
        out,
        &["--case", "cut", "--mode", "projective"],
    ));
    assert!(
        err.contains("the cut runs in the liver scene's own mode"),
        "{err}"
    );
    let err = fails(&accuracy_args(out, &["--case", "beam"]));
    assert!(
        err.contains(
            "--case beam: expected one of cantilever, cantilever-stiff, uniaxial, cut or all"
        ),
        "{err}"
    );
}

/// A short scripted cut on the liver: down 14 mm at 10 mm/s, 20 mm along, back up.
const SHORT_CUT: &str = r#"
[[keyframe]]
t_s = 0.0
tip_mm = [-10.0, 0.0, 25.0]
edge = [0.0, 0.0, 1.0]

[[keyframe]]
t_s = 1.4
tip_mm = [-10.0, 0.0, 11.0]

[[keyframe]]
t_s = 3.4
tip_mm = [10.0, 0.0, 12.0]

[[keyframe]]
t_s = 4.9
tip_mm = [10.0, 0.0, 27.0]
"#;

/// `scalpel cut TARGET` with the short script into `dir`/out, with `extra` arguments: the
/// metrics it printed, and the output folder.
fn short_cut(dir: &Path, target: &str, extra: &[&str]) -> (serde_json::Value, PathBuf) {
    let script = dir.join("short.toml");
    std::fs::write(&script, SHORT_CUT).unwrap();
    let out = dir.join("out");
    let mut args = vec![
        "cut",
        target,
        "--script",
        script.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(extra);
    (ok_json(&args), out)
}

#[test]
fn cut_writes_forces_mesh_render_and_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let (m, out) = short_cut(dir.path(), "liver", &["--mesh-format", "ply"]);
    for key in [
        "steps",
        "surface_ms",
        "internal_ms",
        "lip_max_turn_deg",
        "min_angle_deg",
        "closed",
        "manifold",
        "peak_force_n",
        "steady_force_n",
        "ripple_n",
    ] {
        assert!(m.get(key).is_some(), "metrics lack {key}: {m}");
    }
    assert_eq!(m["steps"].as_u64(), Some(4901));
    assert!(m["surface_ms"]["p50"].as_f64().unwrap() > 0.0);
    assert!(m["internal_ms"]["p99"].as_f64().unwrap() > 0.0);
    // All of a step's work: the re-cut ran on the worker, and its time is counted in the
    // step it landed in, over what the simulation's thread did.
    let worker_ms = m["recut_worker_ms"].as_f64().unwrap();
    assert!(worker_ms > 0.0, "{m}");
    let (total, on_thread) = (&m["total_ms"], &m["on_thread_ms"]);
    assert!(total["max"].as_f64().unwrap() >= on_thread["max"].as_f64().unwrap());
    let steps = m["cut_steps"].as_f64().unwrap();
    assert!(m["work_per_cut_step_ms"].as_f64().unwrap() * steps >= worker_ms);
    // The surface opens just behind the blade (a re-cut every 0.5 mm of its entry's
    // travel, landing 40 ticks later), and a landing moves what was drawn by a fraction
    // of a millimetre; the walls grow with the crack. The stroke's first tenth of an edge
    // (1.8 mm of the liver's 17.7 mm surface edges) draws nothing: an incision is at least
    // that long (`IncisionError::TooShort`).
    let lag = &m["lip_lag_mm"];
    let (lag_p50, lag_max) = (lag["p50"].as_f64().unwrap(), lag["max"].as_f64().unwrap());
    assert!(
        lag_p50 <= 1.0 && lag_max <= 3.0 && lag_max >= lag_p50,
        "{m}"
    );
    assert!(m["max_vertex_jump_mm"].as_f64().unwrap() <= 1.0, "{m}");
    assert!(m["max_surface_growth_mm"].as_f64().unwrap() > 0.0, "{m}");
    assert_eq!(m["closed"], true);
    assert_eq!(m["manifold"], true);
    assert_eq!(m["incisions"].as_u64(), Some(1));
    assert_eq!(m["diverged_ticks"].as_u64(), Some(0), "{m}");
    // The guard's reasons are counted: none acted on this cut.
    for reason in ["energy_growth", "speed", "non_finite", "diverged"] {
        assert_eq!(m["guard"][reason].as_u64(), Some(0), "{m}");
    }
    assert!(m["guard"]["first_tick"].is_null(), "{m}");
    assert!(m["min_angle_deg"].as_f64().unwrap() >= 15.0, "{m}");
    // At a depth d the blade meets 0.19 N/mm × d and friction growing to 0.3 N at 10 mm
    // (the liver resting on its tray has sagged some 10 mm under the script's fixed path:
    // it cuts about 4.5 mm deep); the press before the capsule ruptures is the soft
    // liver's push back, a tenth of a newton, not the 3 N peak of the loading curve it
    // replaced: the peak is the cutting's.
    let peak = m["peak_force_n"].as_f64().unwrap();
    let steady = m["steady_force_n"].as_f64().unwrap();
    let depth_mm = m["steady_depth_mm"].as_f64().unwrap();
    let cutting_force = |d: f64| 0.19 * d + 0.3 * (d / 10.0).min(1.0);
    let want = cutting_force(depth_mm);
    assert!((steady - want).abs() < 0.1 * want, "{steady} vs {want}");
    // The peak is where it went deepest (the path rises 1 mm, the settled top more).
    let csv = std::fs::read_to_string(out.join("force.csv")).unwrap();
    let deepest = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(7).unwrap().parse::<f64>().unwrap())
        .fold(0.0, f64::max);
    let at_deepest = cutting_force(deepest);
    assert!(
        peak >= steady && peak < 1.15 * at_deepest,
        "{peak} vs {at_deepest} at {deepest} mm"
    );
    // The drawn walls go as deep as the blade did.
    let walls_mm = m["wall_depth_mm"].as_f64().unwrap();
    assert!(
        (walls_mm - depth_mm).abs() < 2.0,
        "{walls_mm} vs {depth_mm}"
    );
    // Every file is there and readable.
    assert!(csv.starts_with("t_s,tip_x_mm"));
    assert_eq!(csv.lines().count(), 4902);
    for png in ["force.png", "incision.png"] {
        let bytes = std::fs::read(out.join(png)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{png}");
    }
    let mesh = reimport(&out.join("incision.ply"));
    assert!(mesh.mesh.triangles.len() > 508);
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics, m);
}

/// A mesh file is cut as a cutting station would cut it (its bare scene has cutting off):
/// the liver written out as an OBJ in millimetres, the short cut.
/// cutting-physics.md §4's opening check on the liver without gravity (the default
/// stroke), two seconds after the blade's edge passed (10 mm behind it, past its 8 mm
/// width): with no residual tension the wound stays narrower than the blade is thick
/// (0.30 mm: the lips the flats pushed apart still coming back, onto the incision's
/// drawn hairline of at most 0.2 mm, which they reach some seconds later with or without
/// the flats' push — docs/CUTTING-DECISIONS.md, "The lips against the flats"); with
/// `prestrain` the cut releases the layer's tension and the wound gapes by the field
/// (3.28 mm), calmly.
#[test]
fn residual_tension_opens_the_wound_the_field_otherwise_closes() {
    let dir = tempfile::tempdir().unwrap();
    let gap = |prestrain: f64| {
        let scene = dir.path().join(format!("liver_{prestrain}.toml"));
        std::fs::write(
            &scene,
            format!(
                "extends = \"liver\"\n[material]\nprestrain = {prestrain}\n\
                 [loads]\ngravity_m_s2 = [0.0, 0.0, 0.0]\n"
            ),
        )
        .unwrap();
        let out = dir.path().join(format!("out_{prestrain}"));
        let m = ok_json(&[
            "cut",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--json",
        ]);
        assert_eq!(m["rollback_ticks"], 0, "{m}");
        assert!(m["min_angle_deg"].as_f64().unwrap() >= 15.0, "{m}");
        m["opening_mm"]["after_2s"].as_f64().unwrap()
    };
    let (shut, open) = (gap(0.0), gap(0.1));
    // The report names the layer and its tension: σ = E ε/(1 − ν) = 909 Pa.
    let scene = dir.path().join("liver_0.1.toml");
    let r = ok_json(&["scene", "inspect", scene.to_str().unwrap(), "--json"]);
    let m = &r["material"];
    assert_eq!(m["prestrain"], 0.1, "{r}");
    assert!(
        (m["prestrain_tension_pa"].as_f64().unwrap() - 909.09).abs() < 0.1,
        "{r}"
    );
    assert!(m["prestrain_layer_points"].as_u64().unwrap() > 100, "{r}");
    assert!(shut < 0.4, "{shut} mm");
    assert!(open > 1.0 && open > 8.0 * shut, "{open} mm against {shut}");
}

#[test]
fn cut_takes_a_bare_mesh_file() {
    let dir = tempfile::tempdir().unwrap();
    let liver = scalpel_sim::scene::BuiltinMesh::Liver.generate();
    let mut obj = String::new();
    for p in &liver.positions {
        obj += &format!("v {} {} {}\n", p.x * 1e3, p.y * 1e3, p.z * 1e3);
    }
    for t in &liver.triangles {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    let mesh = dir.path().join("organ.obj");
    std::fs::write(&mesh, obj).unwrap();
    let (m, _) = short_cut(dir.path(), mesh.to_str().unwrap(), &["--units", "mm"]);
    assert_eq!(m["incisions"], 1, "{m}");
    assert!(m["closed"].as_bool().unwrap() && m["manifold"].as_bool().unwrap());
    // The peak is the cutting's (the press before rupture is the tissue's, far under it).
    let (peak, steady) = (
        m["peak_force_n"].as_f64().unwrap(),
        m["steady_force_n"].as_f64().unwrap(),
    );
    assert!(peak >= steady && peak < 1.15 * steady, "{m}");
}

/// The real organ meshes of ../shared/meshes cut end to end with the default stroke: the
/// scanned pig liver lobe, the deltoid sheet (nothing above its centre: the stroke goes
/// onto its top nearby) and the liver tumour (12 mm across: the stroke runs onto its steep
/// sides). All three are remeshed on loading (angles under 15°). The stroke's plunge
/// ruptures the liver's capsule at the rupture force; the deltoid, sampled
/// coarsely (8.1 mm spacing), gives way under the 3 mm plunge (1.3 mm of indentation at
/// 2.7 N), and the blade goes in as it moves on. Ignored in a plain `cargo test`; CI runs
/// it.
#[test]
#[ignore = "reads ../shared/meshes"]
fn shared_meshes_cut_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    for (file, units) in [
        ("pig_liver_lobe0_surface500.obj", "m"),
        ("deltoid_tri.obj", "mm"),
        ("liver_tumour_PPP_Tumor.obj", "cm"),
    ] {
        let mesh = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/meshes")
            .join(file);
        assert!(
            mesh.exists(),
            "{} (is ../shared beside the project?)",
            mesh.display()
        );
        let out = dir.path().join(file);
        let m = ok_json(&[
            "cut",
            mesh.to_str().unwrap(),
            "--units",
            units,
            "--out",
            out.to_str().unwrap(),
            "--json",
        ]);
        assert_eq!(m["incisions"], 1, "{file}: {m}");
        for key in ["closed", "manifold", "oriented"] {
            assert_eq!(m[key], true, "{file}: {key}");
        }
        assert_eq!(m["diverged_ticks"], 0, "{file}: {m}");
        // (The deltoid's default cut drew 8.3° skin cells: a triangle outside the region,
        // its edge split next to a corner, fanned from its far corner. The tumour's drew a
        // 10.3° cell of the region on such a split, lifted onto its steep side; the split
        // is now collapsed.)
        let min_angle = m["min_angle_deg"].as_f64().unwrap();
        assert!(min_angle >= 15.0, "{file}: {m}");
        // The peak is the cutting's: the press before rupture is the tissue's push back,
        // under the 3 N the loading curve drew.
        let peak = m["peak_force_n"].as_f64().unwrap();
        let steady = m["steady_force_n"].as_f64().unwrap();
        assert!(peak >= steady && peak > 0.5 && peak < 3.1, "{file}: {m}");
        // The walls as deep as the cut (6 mm for a 3.4 mm cut on this liver before).
        let (walls, depth) = (
            m["wall_depth_mm"].as_f64().unwrap(),
            m["steady_depth_mm"].as_f64().unwrap(),
        );
        assert!(
            (walls - depth).abs() < 1.0,
            "{file}: walls {walls} mm, cut {depth} mm"
        );
    }
}

#[test]
fn cut_refuses_scenes_that_do_not_cut_and_bad_scripts() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let e = fails(&["cut", "block", "--out", out.to_str().unwrap()]);
    assert!(e.contains("does not cut"), "{e}");
    let script = dir.path().join("bad.toml");
    std::fs::write(&script, "[[keyframe]]\nt_s = 0\ntip_mm = [0, 0, 0]\n").unwrap();
    let e = fails(&[
        "cut",
        "liver",
        "--script",
        script.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(e.contains("bad.toml") && e.contains("at least 2"), "{e}");
}

/// `scalpel bench session`: strokes one after the other on the liver, each reported, the
/// solver calm throughout (a session of several wounds once made it diverge), the surface
/// sound at the end. `scalpel cut` refuses a script file and a session together.
#[test]
fn a_session_of_strokes_stays_calm_and_sound() {
    let r = ok_json(&["bench", "session", "liver", "--strokes", "3", "--json"]);
    let strokes = r["strokes"].as_array().expect("strokes");
    assert_eq!(strokes.len(), 3, "{r}");
    for s in strokes {
        assert!(s["cut_steps"].as_u64().unwrap() > 1000, "{s}");
        assert_eq!(s["rollback_ticks"], 0, "{s}");
        assert!(s["total_ms"]["p50"].as_f64().unwrap() > 0.0, "{s}");
    }
    assert_eq!(r["diverged_ticks"], 0, "{r}");
    assert!(r["incisions"].as_u64().unwrap() >= 3, "{r}");
    assert!(r["min_angle_deg"].as_f64().unwrap() >= 15.0, "{r}");
    for key in ["closed", "manifold", "oriented"] {
        assert_eq!(r[key], true, "{key}: {r}");
    }
    let err = fails(&[
        "cut",
        "liver",
        "--strokes",
        "2",
        "--script",
        "x.toml",
        "--out",
        "/tmp/never",
    ]);
    assert!(
        err.contains("--strokes") || err.contains("--script"),
        "{err}"
    );
}
