//! The rasterizer against an independent dense float64 implementation (`tests/data/surfel-raster`,
//! PyTorch autograd, same 2DGS rules): forward maps and gradients.

mod common;

use trand_render::{OutputGrads, RenderSettings, render};

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

fn check(name: &str) {
    let f = common::load_fixture(name);
    let out = render::<f64, _>(&f.params, &f.camera, &RenderSettings::default()).expect("render");
    let a = &f.arrays;
    let tol = 1e-9;
    assert!(
        max_abs_diff(&out.rgb, &a["out_rgb"]) < tol,
        "rgb differs by {}",
        max_abs_diff(&out.rgb, &a["out_rgb"])
    );
    assert!(max_abs_diff(&out.alpha, &a["out_alpha"]) < tol, "alpha");
    assert!(max_abs_diff(&out.normal, &a["out_normal"]) < tol, "normal");
    let ed = out.expected_depth();
    assert!(
        max_abs_diff(&ed, &a["out_depth_expected"]) < 1e-7,
        "expected depth {}",
        max_abs_diff(&ed, &a["out_depth_expected"])
    );
    assert!(
        max_abs_diff(&out.median, &a["out_depth_median"]) < tol,
        "median {}",
        max_abs_diff(&out.median, &a["out_depth_median"])
    );

    let grads = OutputGrads {
        rgb: Some(a["cotangent_rgb"].clone()),
        alpha: Some(a["cotangent_alpha"].clone()),
        ..Default::default()
    };
    let g = out.backward(&f.params, &grads).params;
    let n = f.opacities.len();
    let rel = |an: &[f64], re: &[f64], what: &str| {
        let scale = re.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
        let err = max_abs_diff(an, re);
        assert!(
            err / scale < 1e-6,
            "{name}: {what} max error {err:e} (scale {scale:e})"
        );
    };
    rel(g.means.as_flattened(), &a["grad_means"], "means");
    rel(g.quats.as_flattened(), &a["grad_quats"], "quats");
    let gs: Vec<f64> = (0..n)
        .flat_map(|i| (0..2).map(move |k| (i, k)))
        .map(|(i, k)| g.log_scales[i][k] / f.scales[i][k])
        .collect();
    rel(&gs, &a["grad_scales"], "scales");
    let go: Vec<f64> = (0..n)
        .map(|i| g.opacity_logits[i] / (f.opacities[i] * (1.0 - f.opacities[i])))
        .collect();
    rel(&go, &a["grad_opacities"], "opacities");
    let gc: Vec<f64> = g.sh.iter().map(|v| v / trand_core::sh::SH_C0).collect();
    rel(&gc, &a["grad_colors"], "colors");
}

#[test]
fn forward_and_gradients_match_dense_reference_small() {
    check("small.npz");
}

#[test]
fn forward_and_gradients_match_dense_reference_medium() {
    check("medium.npz");
}
