//! `trand demo` with the stand-in `trand`: one scene, t=0 and t=1, a report; the rerun is all cached.

mod common;

use common::{Fixture, text};

#[test]
fn demo_makes_a_report_once_and_then_reuses_it() {
    let f = Fixture::new("demo");
    let out = f.path().join("demo");
    let o = f.trand(&["demo", "--out", out.to_str().unwrap()], "");
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(
        f.calls(),
        ["synth", "reconstruct", "eval", "update", "eval"]
    );
    let msg = String::from_utf8_lossy(&o.stdout);
    assert!(
        msg.contains("| trand t0 | 0.0050 |") && msg.contains("| trand t1 |"),
        "{msg}"
    );
    assert!(
        msg.contains(&out.join("index.html").display().to_string()),
        "{msg}"
    );
    assert!(out.join("data/synth_1000/sequence.json").is_file());
    assert!(out.join("seq/synth_1000.html").is_file());
    let o = f.trand(&["demo", "--out", out.to_str().unwrap()], "");
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(f.calls().len(), 5, "nothing recomputed");
}
