//! The depth inside an open vessel after a short run: a tiny synthetic scene (generated here, exact
//! ground truth) whose third object is an upright glass bowl standing alone on the table.
//!
//! Without the opening prior the masks' visual hull puts a lid over the bowl at rim height and above:
//! about 40 % of its pixels within 2.5 cm, depth 3 cm too near on average. With it the inside is fitted.

mod common;

use std::sync::atomic::AtomicBool;

use trand_io::View;
use trand_pipeline::openings::{Shape, Top};
use trand_pipeline::outputs::render_views;
use trand_pipeline::reconstruct::OpeningPrior;
use trand_pipeline::{ReconstructOptions, reconstruct};
use trand_render::RenderSettings;

const BOWL: u16 = 3;

/// `(share of the object's pixels within 2.5 cm, mean signed error (m))` of `id` over `views`.
fn object_depth(surfels: &trand_core::Surfels, views: &[View], id: u16) -> (f64, f64) {
    let renders = render_views(surfels, views, &RenderSettings::default()).expect("render");
    let (mut n, mut near, mut signed) = (0usize, 0usize, 0.0f64);
    for (v, r) in views.iter().zip(&renders) {
        let gt = v.depth.as_ref().expect("GT depth");
        let inst = v.instance.as_ref().expect("GT instances");
        for (i, (&g, &o)) in gt.data.iter().zip(&inst.data).enumerate() {
            if o == id && g > 0.0 {
                let e = (r.depth.data[i] - g) as f64;
                n += 1;
                near += usize::from(e.abs() < 0.025);
                signed += e;
            }
        }
    }
    assert!(n > 500, "the bowl covers {n} test pixels");
    (near as f64 / n as f64, signed / n as f64)
}

#[test]
fn an_upright_bowl_is_fitted_inside_instead_of_under_a_lid() {
    let dir = trand_io::ScratchDir::new("open-bowl").expect("scratch dir");
    let seq = common::tiny(12, dir.path());
    let mut opts = ReconstructOptions::default();
    assert_eq!(
        opts.openings,
        OpeningPrior::Carve,
        "the prior is the default"
    );
    opts.train.iterations = 300;
    let rec = reconstruct(&seq, &opts, None, &mut |_, _| {}, &AtomicBool::new(false))
        .expect("reconstruct");
    let bowl = rec
        .vessel_tops
        .iter()
        .find(|t| t.object_id == BOWL)
        .expect("a decision for the bowl");
    assert!(
        matches!(
            bowl.top,
            Top::Open {
                shape: Shape::Bowl,
                ..
            }
        ),
        "{:?}",
        bowl.top
    );
    let (share, signed) = object_depth(&rec.surfels, &seq.test_t0, BOWL);
    println!(
        "bowl: {:.1} % within 2.5 cm, mean signed error {signed:+.4} m",
        100.0 * share
    );
    assert!(share > 0.75, "bowl pixels within 2.5 cm: {share}");
    assert!(
        signed > -0.012,
        "bowl depth too near by {signed} m on average: a lid"
    );
}
