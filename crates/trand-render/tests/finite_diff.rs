//! Finite-difference checks (f64) of every parameter's gradient through every output map.
//!
//! The loss is `Σ cotangent ⊙ map` with random cotangents; central differences with h = 1e-6 are
//! compared with the analytic backward of the same code instantiated in f64. Perturbations that change
//! a discrete decision of the forward pass (visibility, tiles, last/median surfel, colour clamp) are
//! skipped; the test asserts that almost all parameters were checked.

mod common;

use trand_render::{Maps, OutputGrads, ParamsOf, RenderSettings, Rendered, render};

#[derive(Clone, Copy, Debug)]
enum Map {
    Rgb,
    Mask,
    Objects,
    Alpha,
    Depth,
    ExpectedDepth,
    Median,
    Normal,
    Distortion,
}

fn loss(out: &Rendered<f64>, map: Map, cot: &[f64]) -> f64 {
    let v: Vec<f64> = match map {
        Map::Rgb => out.rgb.clone(),
        Map::Mask => out.mask.clone(),
        Map::Objects => out.objects.clone(),
        Map::Alpha => out.alpha.clone(),
        Map::Depth => out.depth.clone(),
        Map::ExpectedDepth => out.expected_depth(),
        Map::Median => out.median.clone(),
        Map::Normal => out.normal.clone(),
        Map::Distortion => out.distortion.clone(),
    };
    v.iter().zip(cot).map(|(a, b)| a * b).sum()
}

fn grads_for(out: &Rendered<f64>, map: Map, cot: Vec<f64>) -> OutputGrads<f64> {
    let mut g = OutputGrads::default();
    match map {
        Map::Rgb => g.rgb = Some(cot),
        Map::Mask => g.mask = Some(cot),
        Map::Objects => g.objects = Some(cot),
        Map::Alpha => g.alpha = Some(cot),
        Map::Depth => g.depth = Some(cot),
        Map::ExpectedDepth => g.add_expected_depth(out, &cot),
        Map::Median => g.median = Some(cot),
        Map::Normal => g.normal = Some(cot),
        Map::Distortion => g.distortion = Some(cot),
    }
    g
}

/// Every scalar parameter as (name, getter/setter index).
fn flat_mut(p: &mut ParamsOf<f64>) -> Vec<(&'static str, &mut f64)> {
    let mut v: Vec<(&'static str, &mut f64)> = Vec::new();
    v.extend(p.means.as_flattened_mut().iter_mut().map(|x| ("means", x)));
    v.extend(
        p.log_scales
            .as_flattened_mut()
            .iter_mut()
            .map(|x| ("log_scales", x)),
    );
    v.extend(p.quats.as_flattened_mut().iter_mut().map(|x| ("quats", x)));
    v.extend(p.opacity_logits.iter_mut().map(|x| ("opacity", x)));
    v.extend(p.sh.iter_mut().map(|x| ("sh", x)));
    v.extend(p.mask_sh.iter_mut().map(|x| ("mask_sh", x)));
    v.extend(p.obj_logits.iter_mut().map(|x| ("obj_logits", x)));
    v
}

/// A random 16-surfel scene seen by a 48×40 camera, its render and a random cotangent for `map`.
struct Case {
    cam: trand_core::Camera,
    params: ParamsOf<f64>,
    settings: RenderSettings,
    out: Rendered<f64>,
    cot: Vec<f64>,
}

fn case(map: Map, seed: u64, cot_seed: u64) -> Case {
    let cam = common::test_camera(48, 40, 1.2);
    let params = common::random_scene(16, 3, 3, 0.2, seed);
    let settings = RenderSettings {
        background: [0.2, 0.5, 0.7],
        maps: Maps::All,
        ..Default::default()
    };
    let out = render::<f64, _>(&params, &cam, &settings).unwrap();
    let len = match map {
        Map::Rgb | Map::Mask | Map::Normal | Map::Objects => 48 * 40 * 3,
        _ => 48 * 40,
    };
    Case {
        cam,
        params,
        settings,
        out,
        cot: common::cotangent(len, cot_seed),
    }
}

fn check_map(map: Map, seed: u64) {
    let Case {
        cam,
        params,
        settings,
        out,
        cot,
    } = case(map, seed, seed + 100);
    let analytic = out
        .backward(&params, &grads_for(&out, map, cot.clone()))
        .params;
    let mut an = analytic.clone();
    let an_flat: Vec<f64> = flat_mut(&mut an).into_iter().map(|(_, v)| *v).collect();
    let sig = out.decision_signature();
    let n_params = an_flat.len();
    let (mut checked, mut skipped) = (0usize, 0usize);
    let mut failures = Vec::new();
    for (k, &a) in an_flat.iter().enumerate() {
        let h = 1e-6;
        let eval = |delta: f64| {
            let mut p = params.clone();
            *flat_mut(&mut p)[k].1 += delta;
            let o = render::<f64, _>(&p, &cam, &settings).unwrap();
            (loss(&o, map, &cot), o.decision_signature())
        };
        let ((lp, sp), (lm, sm)) = (eval(h), eval(-h));
        if sp != sig || sm != sig {
            skipped += 1;
            continue;
        }
        checked += 1;
        let fd = (lp - lm) / (2.0 * h);
        if (fd - a).abs() > 1e-6 + 1e-5 * fd.abs().max(a.abs()) {
            let mut tmp = params.clone();
            let name = flat_mut(&mut tmp)[k].0;
            failures.push(format!("param {k} ({name}): fd {fd:.9e} analytic {a:.9e}"));
        }
    }
    assert!(
        failures.is_empty(),
        "{map:?}: {} of {checked} mismatches:\n{}",
        failures.len(),
        failures[..failures.len().min(12)].join("\n")
    );
    assert!(
        checked * 10 >= n_params * 9,
        "{map:?}: only {checked} of {n_params} parameters checked ({skipped} skipped)"
    );
    // The scene must actually exercise the map.
    assert!(
        an_flat.iter().any(|v| v.abs() > 1e-6),
        "{map:?}: all gradients zero"
    );
}

#[test]
fn rgb_gradients_match_finite_differences() {
    check_map(Map::Rgb, 1);
}
#[test]
fn mask_gradients_match_finite_differences() {
    check_map(Map::Mask, 2);
}
#[test]
fn object_map_gradients_match_finite_differences() {
    check_map(Map::Objects, 3);
}
#[test]
fn alpha_gradients_match_finite_differences() {
    check_map(Map::Alpha, 4);
}
#[test]
fn depth_gradients_match_finite_differences() {
    check_map(Map::Depth, 5);
}
#[test]
fn expected_depth_gradients_match_finite_differences() {
    check_map(Map::ExpectedDepth, 6);
}
#[test]
fn median_depth_gradients_match_finite_differences() {
    check_map(Map::Median, 7);
}
#[test]
fn normal_gradients_match_finite_differences() {
    check_map(Map::Normal, 8);
}
#[test]
fn distortion_gradients_match_finite_differences() {
    check_map(Map::Distortion, 9);
}

/// The camera moved by the rigid motion `x_c ↦ exp([ω]×) x_c + δ` of its own frame.
fn moved_camera(cam: &trand_core::Camera, w: [f64; 3], d: [f64; 3]) -> trand_core::Camera {
    use glam::{DMat3, DQuat, DVec3};
    let rot = DMat3::from_quat(DQuat::from_scaled_axis(DVec3::from_array(w)));
    trand_core::Camera::from_glam(
        cam.intrinsics,
        rot * cam.rotation(),
        rot * cam.translation() + DVec3::from_array(d),
    )
}

/// `Gradients::camera` against central differences of the loss under a rigid motion of the camera.
fn check_camera(map: Map, seed: u64) {
    let Case {
        cam,
        params,
        settings,
        out,
        cot,
    } = case(map, seed, seed + 200);
    let analytic = out
        .backward(&params, &grads_for(&out, map, cot.clone()))
        .camera;
    let sig = out.decision_signature();
    let mut checked = 0;
    for k in 0..6 {
        let h = 1e-6;
        let eval = |delta: f64| {
            let mut v = [0.0; 6];
            v[k] = delta;
            let c = moved_camera(&cam, [v[0], v[1], v[2]], [v[3], v[4], v[5]]);
            let o = render::<f64, _>(&params, &c, &settings).unwrap();
            (loss(&o, map, &cot), o.decision_signature())
        };
        let ((lp, sp), (lm, sm)) = (eval(h), eval(-h));
        if sp != sig || sm != sig {
            continue;
        }
        checked += 1;
        let fd = (lp - lm) / (2.0 * h);
        let a = analytic[k];
        assert!(
            (fd - a).abs() <= 1e-6 + 1e-5 * fd.abs().max(a.abs()),
            "{map:?}: camera component {k}: fd {fd:.9e} analytic {a:.9e}"
        );
    }
    assert!(
        checked >= 5,
        "{map:?}: only {checked} of 6 camera components checked"
    );
    assert!(
        analytic.iter().any(|v| v.abs() > 1e-6),
        "{map:?}: camera gradient zero"
    );
}

#[test]
fn camera_gradient_through_rgb_matches_finite_differences() {
    check_camera(Map::Rgb, 11);
}
#[test]
fn camera_gradient_through_mask_matches_finite_differences() {
    check_camera(Map::Mask, 12);
}
#[test]
fn camera_gradient_through_objects_matches_finite_differences() {
    check_camera(Map::Objects, 13);
}
#[test]
fn camera_gradient_through_depth_matches_finite_differences() {
    check_camera(Map::ExpectedDepth, 14);
}
#[test]
fn camera_gradient_through_median_depth_matches_finite_differences() {
    check_camera(Map::Median, 15);
}
#[test]
fn camera_gradient_through_normals_matches_finite_differences() {
    check_camera(Map::Normal, 16);
}
#[test]
fn camera_gradient_through_distortion_matches_finite_differences() {
    check_camera(Map::Distortion, 17);
}
