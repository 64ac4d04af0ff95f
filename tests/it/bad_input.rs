//! The bad-input corpus: every way a user has been seen to hand mrbp
//! nonsense, as a table of cases. Each case builds its files in a fresh
//! folder, runs one command, and states the exit status and fragments of
//! the one-line message it expects. Refusals are exit 2 and name the file,
//! row, column or option; nothing is left half-written.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crate::common::{mrbp_in, said};

/// A record of `n` samples at 1 kHz: two cycles of ±5 mm and a force that
/// follows the velocity's sign, as a damper's does.
fn record(n: usize) -> String {
    let mut s = String::from("time_s,displacement_m,force_n\n");
    for k in 0..n {
        let t = k as f64 * 1e-3;
        let phase = 2.0 * std::f64::consts::PI * 2.0 * t * 1000.0 / n as f64;
        s += &format!(
            "{t},{},{}\n",
            0.005 * phase.sin(),
            800.0 * phase.cos().signum() * (1.0 - (-5.0 * phase.cos().abs()).exp())
        );
    }
    s
}

const GEOMETRY: &str = "[geometry]\narea_m2 = 0.05\ngap_m = 0.001\n";

fn manifest_with(extra_top: &str, runs: &str) -> String {
    format!("name = \"t\"\n{extra_top}{GEOMETRY}{runs}")
}

fn one_run(file: &str) -> String {
    format!("[[run]]\nid = \"r1\"\nfile = \"{file}\"\ncurrent_a = 1.0\n")
}

/// A folder `campaign/` holding `files` and `campaign.toml` = `manifest`.
fn setup(root: &Path, manifest: &str, files: &[(&str, Vec<u8>)]) -> PathBuf {
    let dir = root.join("campaign");
    std::fs::create_dir_all(&dir).unwrap();
    for (name, bytes) in files {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
    let m = dir.join("campaign.toml");
    std::fs::write(&m, manifest).unwrap();
    m
}

fn csv_campaign(root: &Path, csv: &str) -> PathBuf {
    setup(root, &manifest_with("", &one_run("run1.csv")), &[("run1.csv", csv.as_bytes().to_vec())])
}

fn good(root: &Path) -> PathBuf {
    csv_campaign(root, &record(400))
}

fn parquet_bytes(
    columns: Vec<(&str, Vec<Option<f64>>)>,
    text: Option<(&str, Vec<&str>)>,
) -> Vec<u8> {
    use polars::prelude::*;
    let mut cols: Vec<Column> =
        columns.into_iter().map(|(n, v)| Column::new(n.into(), v)).collect();
    if let Some((n, v)) = text {
        cols.push(Column::new(n.into(), v));
    }
    let mut df = DataFrame::new_infer_height(cols).unwrap();
    let mut buf = Vec::new();
    ParquetWriter::new(&mut buf).finish(&mut df).unwrap();
    buf
}

fn parquet_campaign(root: &Path, bytes: Vec<u8>) -> PathBuf {
    setup(root, &manifest_with("", &one_run("run1.parquet")), &[("run1.parquet", bytes)])
}

type Cells = Vec<Option<f64>>;

fn sine(n: usize) -> (Cells, Cells, Cells) {
    let t: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
    let x: Vec<f64> =
        t.iter().map(|t| 0.005 * (2.0 * std::f64::consts::PI * 5.0 * t).sin()).collect();
    let f: Vec<f64> =
        t.iter().map(|t| 500.0 * (2.0 * std::f64::consts::PI * 5.0 * t).cos()).collect();
    let some = |v: Vec<f64>| v.into_iter().map(Some).collect();
    (some(t), some(x), some(f))
}

/// A small calibration of the virtual stand, made once for the cases that
/// need one (predict, report, resume).
fn calibration() -> &'static (PathBuf, PathBuf) {
    static CAL: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    CAL.get_or_init(|| {
        let root = tempfile::tempdir().unwrap().keep();
        let data = root.join("data");
        let o = mrbp_in(
            &root,
            &["synth", "--out", "data", "--currents", "1.0", "--rate", "2000", "--cycles", "1"],
        );
        assert!(o.status.success(), "{}", said(&o));
        let out = root.join("cal");
        let o = mrbp_in(&root, &["sample", "data/campaign.toml", "--out", "cal", "--steps", "30"]);
        assert!(o.status.success(), "{}", said(&o));
        (data.join("campaign.toml"), out)
    })
}

/// `sample` of the good campaign into `out` with the settings file
/// `c.toml` holding `text`.
fn sample_with_config(root: &Path, text: &str) -> Vec<String> {
    std::fs::write(root.join("c.toml"), text).unwrap();
    s(&[
        "sample",
        &p(&good(root)),
        "--out",
        &p(&root.join("out")),
        "--config",
        &p(&root.join("c.toml")),
    ])
}

fn s(args: &[&str]) -> Vec<String> {
    args.iter().map(|a| a.to_string()).collect()
}

/// A case: builds what it needs under `root` and returns the arguments.
struct Case {
    name: &'static str,
    make: fn(&Path) -> Vec<String>,
    code: i32,
    expect: &'static [&'static str],
}

fn p(path: &Path) -> String {
    path.to_str().unwrap().to_string()
}

fn cases() -> Vec<Case> {
    vec![
        // --- the manifest
        Case {
            name: "missing manifest",
            make: |r| s(&["check", &p(&r.join("nope.toml"))]),
            code: 2,
            expect: &["nope.toml", "not found"],
        },
        Case {
            name: "malformed manifest",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        "name = \"t\"\n[geometry]\narea_m2 = \"big\"\ngap_m = 0.001\n",
                        &[],
                    )),
                ])
            },
            code: 2,
            expect: &["campaign.toml", "invalid manifest"],
        },
        Case {
            name: "unknown manifest key",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with("colour = \"red\"\n", &one_run("run1.csv")),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["campaign.toml", "colour"],
        },
        Case {
            name: "no runs",
            make: |r| s(&["check", &p(&setup(r, &manifest_with("", ""), &[]))]),
            code: 2,
            expect: &["no [[run]]"],
        },
        Case {
            name: "empty name",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &format!("name = \" \"\n{GEOMETRY}{}", one_run("run1.csv")),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["name must not be empty"],
        },
        Case {
            name: "zero area",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &format!(
                            "name = \"t\"\n[geometry]\narea_m2 = 0.0\ngap_m = 0.001\n{}",
                            one_run("run1.csv")
                        ),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["area_m2", "positive"],
        },
        Case {
            name: "negative gap",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &format!(
                            "name = \"t\"\n[geometry]\narea_m2 = 0.05\ngap_m = -1e-3\n{}",
                            one_run("run1.csv")
                        ),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["gap_m", "positive"],
        },
        Case {
            name: "zero column scale",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with("[columns]\nforce_scale = 0.0\n", &one_run("run1.csv")),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["columns.force_scale", "positive"],
        },
        Case {
            name: "negative limit",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with("[limits]\nforce_n = -1.0\n", &one_run("run1.csv")),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["limits.force_n", "positive"],
        },
        Case {
            name: "duplicate run id",
            make: |r| {
                let runs = format!("{}{}", one_run("run1.csv"), one_run("run1.csv"));
                s(&[
                    "check",
                    &p(&setup(r, &manifest_with("", &runs), &[("run1.csv", record(400).into())])),
                ])
            },
            code: 2,
            expect: &["duplicate run id 'r1'"],
        },
        Case {
            name: "empty run id",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with(
                            "",
                            "[[run]]\nid = \"\"\nfile = \"run1.csv\"\ncurrent_a = 1.0\n",
                        ),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["empty id"],
        },
        Case {
            name: "negative current",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with(
                            "",
                            "[[run]]\nid = \"r1\"\nfile = \"run1.csv\"\ncurrent_a = -1.0\n",
                        ),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["current_a", "non-negative"],
        },
        // --- CSV records
        Case {
            name: "missing data file",
            make: |r| s(&["check", &p(&setup(r, &manifest_with("", &one_run("run1.csv")), &[]))]),
            code: 2,
            expect: &["run1.csv", "not found"],
        },
        Case {
            name: "unknown file type",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with("", &one_run("run1.txt")),
                        &[("run1.txt", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["run1.txt", "unknown data file type"],
        },
        Case {
            name: "missing column",
            make: |r| s(&["check", &p(&csv_campaign(r, "time_s,displacement_m\n0,0\n1,1\n"))]),
            code: 2,
            expect: &["run1.csv", "column 'force_n'"],
        },
        Case {
            name: "duplicate column",
            make: |r| s(&["check", &p(&csv_campaign(r, &duplicate_force_column()))]),
            code: 2,
            expect: &["run1.csv", "column 'force_n'", "twice"],
        },
        Case {
            name: "text in a number",
            make: |r| {
                s(&["check", &p(&csv_campaign(r, &nth_row(&record(400), 2, "0.001,abc,10")))])
            },
            code: 2,
            expect: &["row 2", "text where a number belongs"],
        },
        Case {
            name: "NaN in a number",
            make: |r| s(&["check", &p(&csv_campaign(r, &nth_row(&record(400), 3, "0.002,0,NaN")))]),
            code: 2,
            expect: &["row 3", "column 'force_n'", "finite"],
        },
        Case {
            name: "infinity in a number",
            make: |r| s(&["check", &p(&csv_campaign(r, &nth_row(&record(400), 3, "0.002,inf,1")))]),
            code: 2,
            expect: &["row 3", "column 'displacement_m'", "finite"],
        },
        Case {
            name: "time that does not increase",
            make: |r| s(&["check", &p(&csv_campaign(r, &nth_row(&record(400), 3, "0.001,0,1")))]),
            code: 2,
            expect: &["row 3", "column 'time_s'", "does not increase"],
        },
        Case {
            name: "empty record",
            make: |r| s(&["check", &p(&csv_campaign(r, "time_s,displacement_m,force_n\n"))]),
            code: 2,
            expect: &["0 data rows"],
        },
        Case {
            name: "record of two rows",
            make: |r| s(&["check", &p(&csv_campaign(r, &record(2)))]),
            code: 2,
            expect: &["2 data rows", "at least 10"],
        },
        Case {
            name: "ragged row",
            make: |r| s(&["check", &p(&csv_campaign(r, &nth_row(&record(400), 4, "0.003,0")))]),
            code: 2,
            expect: &["run1.csv", "row 4"],
        },
        Case {
            name: "force of 1e300",
            make: |r| {
                s(&["check", &p(&csv_campaign(r, &nth_row(&record(400), 7, "0.006,0,1e300")))])
            },
            code: 2,
            expect: &["row 7", "column 'force_n'", "plausible"],
        },
        Case {
            name: "displacement of a kilometre",
            make: |r| {
                s(&["check", &p(&csv_campaign(r, &nth_row(&record(400), 5, "0.004,1000,1")))])
            },
            code: 2,
            expect: &["row 5", "column 'displacement_m'", "plausible"],
        },
        Case {
            name: "time of thirty years",
            make: |r| s(&["check", &p(&csv_campaign(r, &format!("{}1e9,0,0\n", record(400))))]),
            code: 2,
            expect: &["row 401", "column 'time_s'", "plausible"],
        },
        Case {
            name: "a raised limit lets a big force through",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with("[limits]\nforce_n = 1e7\n", &one_run("run1.csv")),
                        &[("run1.csv", nth_row(&record(400), 7, "0.006,0,2e6").into())],
                    )),
                ])
            },
            code: 0,
            expect: &[],
        },
        Case {
            name: "file current disagrees with the manifest",
            make: |r| s(&["check", &p(&csv_campaign(r, &with_current(&record(400), 2.5)))]),
            code: 2,
            expect: &["column 'current_a'", "2.5 A", "1 A", "current_varies = true"],
        },
        Case {
            name: "a varying current without its column",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with(
                            "",
                            &format!("{}current_varies = true\n", one_run("run1.csv")),
                        ),
                        &[("run1.csv", record(400).into())],
                    )),
                ])
            },
            code: 2,
            expect: &["column 'current_a'", "missing", "current_varies = true"],
        },
        Case {
            name: "a varying current below 0 A",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with(
                            "",
                            &format!("{}current_varies = true\n", one_run("run1.csv")),
                        ),
                        &[(
                            "run1.csv",
                            nth_row(&with_current(&record(400), 0.5), 4, "0.003,0,0,-0.2").into(),
                        )],
                    )),
                ])
            },
            code: 2,
            expect: &["row 4", "column 'current_a'", "-0.2 A", "0 A or more"],
        },
        Case {
            name: "a varying current is read",
            make: |r| {
                s(&[
                    "check",
                    &p(&setup(
                        r,
                        &manifest_with(
                            "",
                            &format!("{}current_varies = true\n", one_run("run1.csv")),
                        ),
                        &[("run1.csv", with_current(&record(400), 2.5).into())],
                    )),
                ])
            },
            code: 0,
            expect: &[],
        },
        Case {
            name: "file current within ripple",
            make: |r| s(&["check", &p(&csv_campaign(r, &with_current(&record(400), 1.02)))]),
            code: 0,
            expect: &[],
        },
        Case {
            name: "file outside the manifest folder is read with a note",
            make: |r| {
                std::fs::write(r.join("outside.csv"), record(400)).unwrap();
                s(&["check", &p(&setup(r, &manifest_with("", &one_run("../outside.csv")), &[]))])
            },
            code: 0,
            expect: &["outside the manifest's folder"],
        },
        // --- Parquet records
        Case {
            name: "parquet text cell",
            make: |r| {
                let (t, x, _) = sine(400);
                let mut f: Vec<String> = (0..400).map(|k| format!("{}", k)).collect();
                f[4] = "abc".into();
                let f: Vec<&str> = f.iter().map(String::as_str).collect();
                s(&[
                    "check",
                    &p(&parquet_campaign(
                        r,
                        parquet_bytes(
                            vec![("time_s", t), ("displacement_m", x)],
                            Some(("force_n", f)),
                        ),
                    )),
                ])
            },
            code: 2,
            expect: &["run1.parquet", "row 5", "column 'force_n'", "text where a number belongs"],
        },
        Case {
            name: "parquet missing value",
            make: |r| {
                let (t, mut x, f) = sine(400);
                x[2] = None;
                s(&[
                    "check",
                    &p(&parquet_campaign(
                        r,
                        parquet_bytes(
                            vec![("time_s", t), ("displacement_m", x), ("force_n", f)],
                            None,
                        ),
                    )),
                ])
            },
            code: 2,
            expect: &["row 3", "column 'displacement_m'", "missing value"],
        },
        Case {
            name: "parquet NaN",
            make: |r| {
                let (t, x, mut f) = sine(400);
                f[1] = Some(f64::NAN);
                s(&[
                    "check",
                    &p(&parquet_campaign(
                        r,
                        parquet_bytes(
                            vec![("time_s", t), ("displacement_m", x), ("force_n", f)],
                            None,
                        ),
                    )),
                ])
            },
            code: 2,
            expect: &["row 2", "column 'force_n'", "finite"],
        },
        Case {
            name: "parquet missing column",
            make: |r| {
                let (t, x, _) = sine(400);
                s(&[
                    "check",
                    &p(&parquet_campaign(
                        r,
                        parquet_bytes(vec![("time_s", t), ("displacement_m", x)], None),
                    )),
                ])
            },
            code: 2,
            expect: &[
                "column 'force_n'",
                "no such column",
                "its columns: 'time_s', 'displacement_m'",
            ],
        },
        Case {
            name: "not a parquet file",
            make: |r| s(&["check", &p(&parquet_campaign(r, b"PAR1 this is not parquet".to_vec()))]),
            code: 2,
            expect: &["run1.parquet", "not a readable Parquet"],
        },
        // --- records with nothing to fit
        Case {
            name: "no motion: identify refuses",
            make: |r| {
                s(&[
                    "identify",
                    &p(&csv_campaign(r, &constant_displacement())),
                    "--out",
                    &p(&r.join("out")),
                ])
            },
            code: 2,
            expect: &["no loading branch", "identification"],
        },
        Case {
            name: "no motion: check notes it",
            make: |r| s(&["check", &p(&csv_campaign(r, &constant_displacement()))]),
            code: 0,
            expect: &["no loading branch"],
        },
        Case {
            name: "no force: sample refuses",
            make: |r| {
                s(&["sample", &p(&csv_campaign(r, &zero_force())), "--out", &p(&r.join("out"))])
            },
            code: 2,
            expect: &["no force signal", "calibration"],
        },
        // --- options, refused before any work
        Case {
            name: "--walkers 1",
            make: |r| s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--walkers", "1"]),
            code: 2,
            expect: &["--walkers"],
        },
        Case {
            // a campaign of several currents: each current's folder is made
            // inside --out, and a refusal removes both
            name: "--walkers 1, several currents",
            make: |r| {
                let campaign = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/campaign.toml");
                s(&["sample", &p(&campaign), "--out", &p(&r.join("out")), "--walkers", "1"])
            },
            code: 2,
            expect: &["--walkers"],
        },
        Case {
            name: "synth at a negative current",
            make: |r| {
                s(&["synth", "--out", &p(&r.join("out")), "--law", "spencer", "--currents=-1"])
            },
            code: 2,
            expect: &["coil currents must be 0 A or more", "-1"],
        },
        Case {
            // 1 Hz at 100 rpm: 0.6 samples a revolution, 3 in a record
            name: "synth sampled too coarsely",
            make: |r| s(&["synth", "--out", &p(&r.join("out")), "--rate", "1"]),
            code: 2,
            expect: &["0.600 samples a revolution", "at least 8", "raise --rate to 14 Hz"],
        },
        Case {
            name: "a virtual study sampled too coarsely",
            make: |r| {
                let args = ["--replicates", "2", "--cycles", "1", "--rate", "10", "--rpm", "200"];
                let mut a = s(&["study", "plan", &p(&r.join("out"))]);
                a.extend(s(&args));
                a
            },
            code: 2,
            expect: &["3.000 samples a revolution", "raise --rate to 27 Hz"],
        },
        Case {
            name: "--walkers odd",
            make: |r| s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--walkers", "33"]),
            code: 2,
            expect: &["--walkers", "even"],
        },
        Case {
            name: "--ensembles 0",
            make: |r| s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--ensembles", "0"]),
            code: 2,
            expect: &["--ensembles"],
        },
        Case {
            name: "--steps 0",
            make: |r| s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--steps", "0"]),
            code: 2,
            expect: &["--steps"],
        },
        Case {
            name: "--substeps 0",
            make: |r| s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--substeps", "0"]),
            code: 2,
            expect: &["--substeps"],
        },
        Case {
            name: "--threads 0",
            make: |r| s(&["--threads", "0", "check", &p(&good(r))]),
            code: 2,
            expect: &["--threads"],
        },
        Case {
            name: "--current not in the campaign",
            make: |r| s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--current", "3"]),
            code: 2,
            expect: &["no run at 3 A"],
        },
        Case {
            name: "--hold-out-current without a current law",
            make: |r| {
                s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--hold-out-current", "1"])
            },
            code: 2,
            expect: &["--model current-law"],
        },
        Case {
            name: "--current with a law across currents",
            make: |r| {
                s(&[
                    "sample",
                    &p(&good(r)),
                    "--out",
                    &p(&r.join("out")),
                    "--model",
                    "current-law",
                    "--current",
                    "1",
                ])
            },
            code: 2,
            expect: &[
                "--current 1", "the current law", "spans every current", "--hold-out-current",
            ],
        },
        Case {
            name: "run --current with a law across currents",
            make: |r| {
                s(&[
                    "run",
                    &p(&good(r)),
                    "--out",
                    &p(&r.join("out")),
                    "--model",
                    "current-curves",
                    "--current",
                    "1",
                ])
            },
            code: 2,
            expect: &[
                "--current 1", "the current curves", "spans every current", "--hold-out-current",
            ],
        },
        Case {
            name: "current curves from one current",
            make: |r| {
                s(&[
                    "sample",
                    &p(&good(r)),
                    "--out",
                    &p(&r.join("out")),
                    "--model",
                    "current-curves",
                ])
            },
            code: 2,
            expect: &["two or more currents"],
        },
        Case {
            name: "--config curves' anchors reversed",
            make: |r| {
                sample_with_config(
                    r,
                    "model = \"current-curves\"\nanchor_currents_a = [1.0, 0.5]\n",
                )
            },
            code: 2,
            expect: &["c.toml", "anchor_currents_a", "low < high"],
        },
        Case {
            name: "--config map_start names a parameter the calibration lacks",
            make: |r| sample_with_config(r, "[map_start]\nGx = 2e5\n"),
            code: 2,
            expect: &["map_start names Gx", "does not have"],
        },
        Case {
            name: "--noise unknown",
            make: |r| s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--noise", "pink"]),
            code: 2,
            expect: &["pink"],
        },
        Case {
            name: "--config missing",
            make: |r| {
                s(&[
                    "sample",
                    &p(&good(r)),
                    "--out",
                    &p(&r.join("out")),
                    "--config",
                    &p(&r.join("none.toml")),
                ])
            },
            code: 2,
            expect: &["none.toml"],
        },
        Case {
            name: "--config unknown key",
            make: |r| sample_with_config(r, "[sampler]\nwalkerz = 3\n"),
            code: 2,
            expect: &["c.toml", "walkerz"],
        },
        // --- output folders
        Case {
            name: "--out is a file",
            make: |r| {
                std::fs::write(r.join("file"), "x").unwrap();
                s(&["identify", &p(&good(r)), "--out", &p(&r.join("file"))])
            },
            code: 2,
            expect: &["--out", "is a file"],
        },
        Case {
            name: "--out under a file",
            make: |r| {
                std::fs::write(r.join("file"), "x").unwrap();
                s(&["sample", &p(&good(r)), "--out", &p(&r.join("file").join("sub"))])
            },
            code: 2,
            expect: &["--out", "cannot create"],
        },
        Case {
            name: "--out in an unwritable place",
            make: |r| s(&["identify", &p(&good(r)), "--out", "/proc/mrbp-results"]),
            code: 2,
            expect: &["--out", "/proc/mrbp-results"],
        },
        Case {
            name: "--out is the campaign's folder",
            make: |r| s(&["identify", &p(&good(r)), "--out", &p(&r.join("campaign"))]),
            code: 2,
            expect: &["--out", "folder of the campaign"],
        },
        Case {
            name: "laws ranked by held-out tests where a current has one run",
            make: |r| {
                s(&[
                    "run",
                    &p(&good(r)),
                    "--out",
                    &p(&r.join("out")),
                    "--law",
                    "bodner-partom,bingham",
                    "--leave-one-out",
                ])
            },
            code: 2,
            expect: &["--leave-one-out", "single run (r1)", "--current"],
        },
        Case {
            name: "identify of a law without the paper's identification",
            make: |r| {
                s(&["identify", &p(&good(r)), "--out", &p(&r.join("out")), "--law", "spencer"])
            },
            code: 2,
            expect: &["identify", "B-P law", "spencer", "mrbp sample --law spencer"],
        },
        Case {
            name: "sample over an interrupted calibration without --resume",
            make: |r| {
                std::fs::create_dir_all(r.join("out")).unwrap();
                std::fs::write(r.join("out/sampler.checkpoint"), "steps").unwrap();
                s(&["sample", &p(&good(r)), "--out", &p(&r.join("out"))])
            },
            code: 2,
            expect: &["sampler.checkpoint", "interrupted", "--resume", "--force"],
        },
        Case {
            name: "identify over an earlier identification",
            make: |r| {
                std::fs::create_dir_all(r.join("out")).unwrap();
                std::fs::write(r.join("out/identification.parquet"), "old").unwrap();
                s(&["identify", &p(&good(r)), "--out", &p(&r.join("out"))])
            },
            code: 2,
            expect: &["already holds results", "identification.parquet", "--force"],
        },
        Case {
            name: "sample over an earlier calibration",
            make: |r| {
                std::fs::create_dir_all(r.join("out")).unwrap();
                std::fs::write(r.join("out/chains.parquet"), "old").unwrap();
                s(&["sample", &p(&good(r)), "--out", &p(&r.join("out"))])
            },
            code: 2,
            expect: &["already holds results", "chains.parquet", "--force"],
        },
        Case {
            name: "--resume with a damaged checkpoint",
            make: |r| {
                std::fs::create_dir_all(r.join("out")).unwrap();
                std::fs::write(r.join("out/sampler.checkpoint"), "garbage").unwrap();
                s(&["sample", &p(&good(r)), "--out", &p(&r.join("out")), "--resume"])
            },
            code: 2,
            expect: &["sampler.checkpoint", "not a sampler checkpoint"],
        },
        // --- later stages
        Case {
            name: "predict a folder that is no calibration",
            make: |r| s(&["predict", &p(r)]),
            code: 2,
            expect: &["not a calibration folder"],
        },
        Case {
            name: "report a missing folder",
            make: |r| s(&["report", &p(&r.join("nowhere"))]),
            code: 2,
            expect: &["nowhere"],
        },
        Case {
            name: "predict --draws 0",
            make: |_| s(&["predict", &p(&calibration().1), "--draws", "0", "--out", "bands"]),
            code: 2,
            expect: &["--draws"],
        },
        Case {
            name: "predict another current with a per-current calibration",
            make: |r| {
                let o = mrbp_in(
                    r,
                    &[
                        "synth", "--out", "half", "--currents", "0.5", "--rate", "2000",
                        "--cycles", "1",
                    ],
                );
                assert!(o.status.success());
                s(&[
                    "predict",
                    &p(&calibration().1),
                    "--campaign",
                    &p(&r.join("half/campaign.toml")),
                    "--out",
                    &p(&r.join("pred")),
                ])
            },
            code: 2,
            expect: &["no run at 1 A"],
        },
        Case {
            name: "compare a folder that is no calibration",
            make: |r| s(&["compare", &p(r), &p(&calibration().1), "--out", &p(&r.join("cmp"))]),
            code: 2,
            expect: &["not a calibration folder"],
        },
    ]
}

/// The record with data row `row` (from 1) replaced by `line`.
fn nth_row(csv: &str, row: usize, line: &str) -> String {
    let mut lines: Vec<&str> = csv.lines().collect();
    lines[row] = line;
    lines.join("\n") + "\n"
}

fn duplicate_force_column() -> String {
    record(400)
        .lines()
        .enumerate()
        .map(|(i, l)| if i == 0 { format!("{l},force_n\n") } else { format!("{l},1\n") })
        .collect()
}

fn with_current(csv: &str, current: f64) -> String {
    csv.lines()
        .enumerate()
        .map(|(i, l)| if i == 0 { format!("{l},current_a\n") } else { format!("{l},{current}\n") })
        .collect()
}

fn constant_displacement() -> String {
    (0..400).fold(String::from("time_s,displacement_m,force_n\n"), |s, k| {
        s + &format!("{},0.001,{}\n", k as f64 * 1e-3, (k as f64).sin())
    })
}

fn zero_force() -> String {
    record(400)
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 0 {
                format!("{l}\n")
            } else {
                format!("{},0\n", l.rsplit_once(',').unwrap().0)
            }
        })
        .collect()
}

#[test]
fn every_bad_input_is_refused_clearly() {
    let cases = cases();
    assert!(cases.len() >= 50, "{} cases", cases.len());
    let mut failures = Vec::new();
    for case in &cases {
        let root = tempfile::tempdir().unwrap();
        let args = (case.make)(root.path());
        let results = ["out", "pred", "cmp"];
        let existed = results.map(|d| root.path().join(d).exists());
        let o = mrbp_in(root.path(), &args.iter().map(String::as_str).collect::<Vec<_>>());
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        let all = said(&o);
        let code = o.status.code();
        if code != Some(case.code) {
            failures.push(format!(
                "{}: exit {code:?}, expected {} — {}",
                case.name,
                case.code,
                err.trim()
            ));
            continue;
        }
        if case.code == 2 {
            // one line on stderr (clap's usage errors excepted), naming what it should
            let lines = err
                .trim_end()
                .lines()
                .filter(|l| l.starts_with("mrbp: error") || l.starts_with("error:"))
                .count();
            if lines != 1 {
                failures.push(format!(
                    "{}: expected one 'mrbp: error' line, got: {}",
                    case.name,
                    err.trim()
                ));
            }
        }
        for fragment in case.expect {
            if !all.contains(fragment) {
                failures.push(format!(
                    "{}: the message lacks '{fragment}': {}",
                    case.name,
                    all.trim()
                ));
            }
        }
        // a refused command writes no results (the lock file of a folder it
        // held is no result: docs/contract.md) and leaves no folder it made
        if case.code == 2 {
            for (dir, existed) in results.iter().zip(existed) {
                let d = root.path().join(dir);
                // nor a folder it created and then wrote nothing into
                let only_lock = std::fs::read_dir(&d)
                    .map(|it| it.flatten().all(|e| e.file_name() == mrbp::lock::FILE))
                    .unwrap_or(false);
                if !existed && only_lock {
                    failures.push(format!("{}: left the empty folder {dir}/", case.name));
                }
                let written: Vec<String> = std::fs::read_dir(&d)
                    .map(|it| {
                        it.filter_map(|e| e.ok())
                            .map(|e| e.file_name().to_string_lossy().into_owned())
                            .filter(|n| {
                                ![
                                    "identification.parquet",
                                    "chains.parquet",
                                    "sampler.checkpoint",
                                    mrbp::lock::FILE,
                                ]
                                .contains(&n.as_str())
                            })
                            .collect()
                    })
                    .unwrap_or_default();
                if !written.is_empty() {
                    failures.push(format!("{}: left {written:?} in {dir}/", case.name));
                }
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}
