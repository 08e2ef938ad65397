//! `trand bench` end to end with a stand-in `trand` (see `common`): resume, sharding + merge, failures,
//! bad input.

mod common;

use common::{Fixture, text};

fn s(p: &std::path::Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn second_run_recomputes_nothing() {
    let f = Fixture::new("bench-resume");
    let out = f.path().join("report");
    let (a, b) = (f.seq("seq_a"), f.seq("seq_b"));
    let args = [
        "bench",
        "--data",
        s(&a),
        s(&b),
        "--out",
        s(&out),
        "--jobs",
        "2",
    ];
    let o = f.trand(&args, "");
    assert!(o.status.success(), "{}", text(&o));
    let calls = f.calls();
    let count = |c: &str| calls.iter().filter(|x| *x == c).count();
    // Per sequence: 5 t0 owners, 7 t1 owners (all but views-6), each step runs one eval.
    assert_eq!(
        (count("reconstruct"), count("update"), count("eval")),
        (10, 14, 24),
        "{calls:?}"
    );
    let o = f.trand(&args, "");
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(f.calls().len(), calls.len(), "nothing recomputed");
    assert_eq!(
        String::from_utf8_lossy(&o.stdout)
            .matches("cached ")
            .count(),
        24,
        "{}",
        text(&o)
    );
    for (seq, m, st) in [("seq_a", "trand", "t0"), ("seq_b", "physics-only", "t1")] {
        assert!(
            out.join(format!("runs/{seq}/{m}/{st}/metrics.json"))
                .is_file()
        );
        assert!(out.join(format!("runs/{seq}/{m}/{st}.log")).is_file());
    }
    assert!(
        !out.join("runs/seq_a/no-simulation/t0").exists(),
        "no-simulation reuses trand's t0"
    );
    assert!(!out.join("runs/seq_a/views-6").exists(), "views-6 is trand");
}

#[test]
fn two_merged_shards_give_the_tables_of_one_run() {
    let f = Fixture::new("bench-shards");
    let whole = f.path().join("whole");
    let o = f.trand(
        &[
            "bench",
            "--synth",
            "2",
            "--synth-preset",
            "tiny",
            "--out",
            s(&whole),
        ],
        "",
    );
    assert!(o.status.success(), "{}", text(&o));
    let n_whole = f.calls().len();
    let mut shards = Vec::new();
    for i in 0..2 {
        let d = f.path().join(format!("shard{i}"));
        let spec = format!("{i}/2");
        let o = f.trand(
            &[
                "bench",
                "--synth",
                "2",
                "--synth-preset",
                "tiny",
                "--out",
                s(&d),
                "--shard",
                &spec,
            ],
            "",
        );
        assert!(o.status.success(), "{}", text(&o));
        shards.push(d);
    }
    // Both shards generate both sequences (each has jobs of each), the steps are split.
    assert_eq!(f.calls().iter().filter(|c| *c == "synth").count(), 2 + 4);
    assert_eq!(f.calls().len() - n_whole, n_whole + 2);
    let merged = f.path().join("merged");
    let o = f.trand(
        &[
            "bench",
            "merge",
            "--out",
            s(&merged),
            s(&shards[0]),
            s(&shards[1]),
        ],
        "",
    );
    assert!(o.status.success(), "{}", text(&o));
    for file in ["tables.json", "tables.md", "bench.json"] {
        assert_eq!(
            std::fs::read_to_string(whole.join(file)).unwrap(),
            std::fs::read_to_string(merged.join(file)).unwrap(),
            "{file}"
        );
    }
    let t = std::fs::read_to_string(merged.join("tables.md")).unwrap();
    assert!(t.contains("| trand t0 | 0.0050 |"), "{t}");
    assert!(merged.join("data/synth_1001/sequence.json").is_file());
}

#[test]
fn a_failed_step_is_logged_and_the_bench_goes_on_but_exits_non_zero() {
    let f = Fixture::new("bench-fail");
    let out = f.path().join("report");
    let o = f.trand(
        &[
            "bench",
            "--data",
            s(&f.seq("seq_a")),
            "--out",
            s(&out),
            "--methods",
            "trand,plain-2dgs",
        ],
        "plain-2dgs",
    );
    assert!(!o.status.success());
    let msg = text(&o);
    assert!(
        msg.contains("FAILED  seq_a/plain-2dgs/t0") && msg.contains("2 of 4 steps failed"),
        "{msg}"
    );
    let log = std::fs::read_to_string(out.join("runs/seq_a/plain-2dgs/t0.log")).unwrap();
    assert!(log.contains("fake failure of plain-2dgs"), "{log}");
    assert!(out.join("runs/seq_a/trand/t1/metrics.json").is_file());
    let t = std::fs::read_to_string(out.join("tables.md")).unwrap();
    assert!(t.contains("| plain-2dgs t0 [0/1 seq] | – |"), "{t}");
    let index = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        index.contains("runs/seq_a/plain-2dgs/t0.log")
            && index.contains("runs/seq_a/plain-2dgs/t1.log")
    );
    check_links(&out);
    // The failed step runs again next time, afresh (an interrupted reconstruct's checkpoint goes), and
    // the finished ones do not.
    let ckpt = out.join("runs/seq_a/plain-2dgs/t0.checkpoint");
    std::fs::create_dir_all(&ckpt).unwrap();
    let before = f.calls().len();
    let o = f.trand(
        &[
            "bench",
            "--data",
            s(&f.seq("seq_a")),
            "--out",
            s(&out),
            "--methods",
            "trand,plain-2dgs",
        ],
        "",
    );
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(
        f.calls()[before..],
        ["reconstruct", "eval", "update", "eval"]
    );
}

#[test]
fn generated_and_folder_sequences_are_benchmarked_together() {
    let f = Fixture::new("bench-mixed");
    let out = f.path().join("report");
    let a = f.seq("seq_a");
    let o = f.trand(
        &[
            "bench",
            "--synth",
            "1",
            "--synth-preset",
            "containers",
            "--data",
            s(&a),
            "--out",
            s(&out),
            "--methods",
            "trand",
        ],
        "",
    );
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(f.calls().iter().filter(|c| *c == "synth").count(), 1);
    for seq in ["containers_1000", "seq_a"] {
        assert!(
            out.join(format!("runs/{seq}/trand/t1/metrics.json"))
                .is_file(),
            "{seq}: {}",
            text(&o)
        );
    }
    assert!(out.join("data/containers_1000/sequence.json").is_file());
}

#[test]
fn bad_input_is_a_clear_error() {
    let f = Fixture::new("bench-bad");
    let a = f.seq("seq_a");
    let out = f.path().join("r");
    let under_file = a.join("sequence.json/r");
    let cases: [(Vec<&str>, &str); 6] = [
        (vec!["--synth", "0", "--out", s(&out)], "--synth 0"),
        (
            vec!["--data", "/no/such/seq", "--out", s(&out)],
            "--data /no/such/seq: no such folder",
        ),
        (
            vec!["--data", s(&a), "--out", s(&out), "--shard", "0/0"],
            "n must be at least 1",
        ),
        (
            vec!["--data", s(&a), "--out", s(&out), "--shard", "3/2"],
            "i must be below n",
        ),
        (
            vec!["--data", s(&a), "--out", s(&under_file)],
            "cannot create report folder",
        ),
        (
            vec![
                "--data",
                s(&a),
                "--out",
                s(&out),
                "--methods",
                "trand,views-5",
            ],
            "unknown method `views-5`",
        ),
    ];
    for (args, want) in cases {
        let mut all = vec!["bench"];
        all.extend(args);
        let o = f.trand(&all, "");
        assert!(!o.status.success(), "{all:?}");
        assert!(text(&o).contains(want), "{all:?}: {}", text(&o));
    }
    assert!(f.calls().is_empty());
}

/// Every `src="…"` and local `href="…"` of the report's pages names an existing file.
fn check_links(report: &std::path::Path) -> usize {
    let mut pages = vec![report.join("index.html")];
    for e in std::fs::read_dir(report.join("seq")).unwrap() {
        pages.push(e.unwrap().path());
    }
    let mut n = 0;
    for p in pages {
        let html = std::fs::read_to_string(&p).unwrap();
        assert!(
            !html.contains("http://") && !html.contains("https://") && !html.contains("<script"),
            "{}",
            p.display()
        );
        for attr in ["src=\"", "href=\""] {
            for part in html.split(attr).skip(1) {
                let target = part.split('"').next().unwrap();
                let file = p.parent().unwrap().join(target);
                assert!(
                    file.is_file(),
                    "{}: {attr}{target} does not exist",
                    p.display()
                );
                n += 1;
            }
        }
    }
    n
}

#[test]
fn every_image_and_link_of_the_report_exists() {
    let f = Fixture::new("bench-html");
    let out = f.path().join("report");
    let o = f.trand(
        &[
            "bench",
            "--data",
            s(&f.seq("seq_a")),
            s(&f.seq("seq_b")),
            "--out",
            s(&out),
        ],
        "",
    );
    assert!(o.status.success(), "{}", text(&o));
    let n = check_links(&out);
    let page = std::fs::read_to_string(out.join("seq/seq_a.html")).unwrap();
    // 4 training thumbnails, and per state 2 views × (5 written images: GT and rendered depth,
    // |error|, signed error, GT objects; + the run's object map).
    assert_eq!(page.matches("<img").count(), 4 + 2 * 2 * 6, "{page}");
    assert_eq!(
        page.matches("_signed_error.png\" alt=").count(),
        2 * 2,
        "{page}"
    );
    assert!(page.contains("saturating at ±0.05: blue too near, red too far"));
    // Object 1 (20 pixels per view, two views) at t0, and the kinds of the sequence.
    assert!(
        page.contains("<tr><td>1</td><td>bowl (upright)</td><td>40</td><td>0.0050</td>"),
        "{page}"
    );
    assert!(
        page.contains("<tr><td>mug (inverted)</td><td>1</td><td>1</td><td>8</td>"),
        "{page}"
    );
    assert!(n >= 2 * 24 + 4, "{n}");
    for plot in [
        "|error| of trand at t0",
        "accuracy vs threshold at t1",
        "training loss at t0",
        "time per stage at t1",
    ] {
        assert!(page.contains(plot), "{plot}");
    }
    assert!(
        page.contains("<h2>Metrics per object and per kind</h2>"),
        "per-object and per-kind tables"
    );
    let index = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        index.contains("<td>trand t0</td><td>0.0050</td>"),
        "{index}"
    );
    assert!(index.contains("per object kind"), "per-kind section");
    assert!(index.contains("<h3>trand t1 (2 sequences)</h3>"), "{index}");
}

#[test]
fn per_kind_tables_pool_the_objects_of_every_sequence() {
    let f = Fixture::new("bench-kinds");
    let out = f.path().join("report");
    let o = f.trand(
        &[
            "bench",
            "--data",
            s(&f.seq("seq_a")),
            s(&f.seq("seq_b")),
            "--out",
            s(&out),
            "--methods",
            "trand",
        ],
        "",
    );
    assert!(o.status.success(), "{}", text(&o));
    let t = std::fs::read_to_string(out.join("tables.md")).unwrap();
    // Each sequence: the bowl has 20 pixels and the mug 4 in each of two test views; frame 0 is
    // 1 cm off at t0 and 3 cm off at t1, frame 1 exact; the mug is removed at t1.
    for row in [
        "| bowl (upright) | 2 | 2 | 80 | 0.0050 | 100.00% | 100.00% |",
        "| mug (inverted) | 2 | 2 | 16 | 0.0050 | 100.00% | 100.00% |",
        "| bowl (upright) | 2 | 2 | 80 | 0.0150 | 50.00% | 100.00% |",
        "| 1 | bowl (upright) | 40 | 0.0050 |",
    ] {
        assert!(t.contains(row), "{row}\n{t}");
    }
    let kind_rows = |label: &str| t.lines().filter(|l| l.starts_with(label)).count();
    assert_eq!(kind_rows("| mug (inverted) |"), 1, "removed at t1: {t}");
    assert_eq!(kind_rows("| bowl (upright) |"), 2, "{t}");
    assert!(t.contains("**trand t1 (2 sequences)**"), "{t}");
    assert!(
        text(&o).contains("| bowl (upright) | 2 | 2 | 80 | 0.0150 | 50.00% | 100.00% |"),
        "the bench prints the per-kind tables: {}",
        text(&o)
    );
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("tables.json")).unwrap()).unwrap();
    let kinds = j["per_kind"].as_array().unwrap();
    assert_eq!(kinds.len(), 2, "trand t0 and t1");
    assert_eq!(kinds[1]["state"], "t1");
    assert_eq!(kinds[1]["rows"][0]["label"], "bowl (upright)");
    assert_eq!(kinds[1]["rows"][0]["sequences"], 2);
    assert_eq!(
        j["per_object"].as_array().unwrap().len(),
        4,
        "2 sequences × t0, t1"
    );
}

#[test]
fn resuming_with_other_reconstruct_settings_is_refused() {
    let f = Fixture::new("bench-settings");
    let out = f.path().join("report");
    let a = f.seq("seq_a");
    let run = |it: &str| {
        f.trand(
            &[
                "bench",
                "--data",
                s(&a),
                "--out",
                s(&out),
                "--methods",
                "trand",
                "--iterations",
                it,
            ],
            "",
        )
    };
    assert!(run("50").status.success());
    let n = f.calls().len();
    let o = run("60");
    assert!(!o.status.success());
    let msg = text(&o);
    assert!(
        msg.contains("bench.json") && msg.contains("settings") && msg.contains("new --out"),
        "{msg}"
    );
    assert_eq!(f.calls().len(), n);
    assert!(run("50").status.success());
    assert_eq!(f.calls().len(), n, "same settings resume, all cached");
}

#[test]
fn merge_refuses_a_folder_that_is_not_a_shard_before_writing() {
    let f = Fixture::new("bench-merge-bad");
    let out = f.path().join("merged");
    let o = f.trand(
        &["bench", "merge", "--out", s(&out), s(&f.seq("seq_a"))],
        "",
    );
    assert!(!o.status.success());
    assert!(
        text(&o).contains("has no bench.json (not a bench folder)"),
        "{}",
        text(&o)
    );
    assert!(!out.exists());
}
