//! Object sums against a label map ([`trand_render::render_object_sums`]) against the dense K-channel
//! object map: the same sums and the same gradients, to rounding.

mod common;

use trand_render::{
    GeometryMaps, Maps, ObjectSumGrads, OutputGrads, ParamsOf, RenderError, RenderSettings, render,
    render_object_sums,
};

const K: usize = 4;

/// Stripes of every label, several per tile, on an image whose size is not a multiple of the tile.
fn labels(w: usize, h: usize) -> Vec<u8> {
    (0..w * h)
        .map(|i| (((i % w) / 7 + (i / w) / 5) % K) as u8)
        .collect()
}

fn flat(p: &ParamsOf<f64>) -> Vec<f64> {
    [
        p.means.as_flattened(),
        p.log_scales.as_flattened(),
        p.quats.as_flattened(),
        &p.opacity_logits,
        &p.sh,
        &p.mask_sh,
        &p.obj_logits,
    ]
    .concat()
}

#[test]
fn sums_and_their_gradients_equal_the_dense_object_maps() {
    let camera = common::test_camera(90, 70, 0.8);
    let scene = common::random_scene(300, 1, K, 0.25, 11);
    let (w, h) = (90, 70);
    let lab = labels(w, h);
    let settings = RenderSettings {
        maps: Maps::All,
        background: [0.2, 0.4, 0.1],
        ..Default::default()
    };
    let dense = render::<f64, _>(&scene, &camera, &settings).unwrap();
    let sums = render_object_sums::<f64, _>(&scene, &camera, &settings, &lab).unwrap();

    // Forward: P_c = Σ_x p_c(x), I_c = Σ_{ℓ(x)=c} p_c(x).
    let (mut p, mut i) = ([0.0; K], [0.0; K]);
    for (x, px) in dense.objects.chunks_exact(K).enumerate() {
        for c in 0..K {
            p[c] += px[c];
        }
        i[lab[x] as usize] += px[lab[x] as usize];
    }
    let got = sums.object_sums.as_ref().expect("sums");
    for c in 0..K {
        assert!(
            p[c] > 1.0 && i[c] > 0.1,
            "channel {c} barely covered: P {} I {}",
            p[c],
            i[c]
        );
        assert!(
            (got.total[c] - p[c]).abs() < 1e-10 * p[c],
            "P_{c}: {} vs {}",
            got.total[c],
            p[c]
        );
        assert!(
            (got.on_label[c] - i[c]).abs() < 1e-10 * i[c],
            "I_{c}: {} vs {}",
            got.on_label[c],
            i[c]
        );
    }
    assert!(sums.objects.is_empty() && dense.object_sums.is_none());
    assert_eq!(dense.rgb, sums.rgb);
    assert_eq!(dense.alpha, sums.alpha);
    assert_eq!(dense.mask, sums.mask);

    // Backward: a loss on the sums, and the same loss as a per-pixel map gradient.
    let gp = common::cotangent(K, 1);
    let gi = common::cotangent(K, 2);
    let n = w * h;
    let shared = |o: &mut OutputGrads<f64>| {
        o.rgb = Some(common::cotangent(3 * n, 3));
        o.alpha = Some(common::cotangent(n, 4));
    };
    let mut g_dense = OutputGrads {
        objects: Some(
            (0..n * K)
                .map(|j| {
                    gp[j % K]
                        + if lab[j / K] as usize == j % K {
                            gi[j % K]
                        } else {
                            0.0
                        }
                })
                .collect(),
        ),
        ..Default::default()
    };
    shared(&mut g_dense);
    let mut g_sums = OutputGrads {
        object_sums: Some(ObjectSumGrads {
            total: gp,
            on_label: gi,
        }),
        ..Default::default()
    };
    shared(&mut g_sums);
    let a = flat(&dense.backward(&scene, &g_dense).params);
    let b = flat(&sums.backward(&scene, &g_sums).params);
    let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(scale > 1e-3, "gradients vanish");
    assert!(
        worst < 1e-10 * scale,
        "largest difference {worst} (scale {scale})"
    );
    // The object logits get their gradient only through the object term: it must be there.
    let obj = &sums.backward(&scene, &g_sums).params.obj_logits;
    assert!(obj.iter().any(|v| v.abs() > 1e-4));
}

#[test]
fn sums_without_geometry_maps_give_the_same_sums() {
    let camera = common::test_camera(64, 48, 0.8);
    let scene = common::random_scene(200, 0, K, 0.25, 5);
    let lab = labels(64, 48);
    let run = |geometry| {
        let settings = RenderSettings {
            maps: Maps::All,
            geometry,
            ..Default::default()
        };
        render_object_sums::<f64, _>(&scene, &camera, &settings, &lab)
            .unwrap()
            .object_sums
            .unwrap()
    };
    assert_eq!(run(GeometryMaps::Rendered), run(GeometryMaps::Skipped));
}

#[test]
fn bad_label_maps_are_errors() {
    let camera = common::test_camera(32, 16, 0.8);
    let scene = common::random_scene(20, 0, K, 0.25, 5);
    let all = RenderSettings {
        maps: Maps::All,
        ..Default::default()
    };
    let mut lab = vec![0u8; 32 * 16];
    assert_eq!(
        render_object_sums::<f64, _>(&scene, &camera, &all, &lab[1..]).err(),
        Some(RenderError::LabelsSize {
            got: 511,
            expected: 512
        })
    );
    lab[40] = K as u8;
    assert_eq!(
        render_object_sums::<f64, _>(&scene, &camera, &all, &lab).err(),
        Some(RenderError::Label {
            label: K as u8,
            pixel: 40,
            num_objects: K
        })
    );
    let rgb = RenderSettings {
        maps: Maps::Rgb,
        ..Default::default()
    };
    assert_eq!(
        render_object_sums::<f64, _>(&scene, &camera, &rgb, &[0; 512]).err(),
        Some(RenderError::SumsWithoutObjects)
    );
}

#[test]
fn the_cpu_rasterizer_behind_the_trait_is_render_and_backward() {
    use trand_render::{Cpu, Rasterizer};
    let camera = common::test_camera(48, 40, 0.8);
    let scene = common::random_scene(120, 1, K, 0.25, 5);
    let settings = RenderSettings {
        maps: Maps::All,
        ..Default::default()
    };
    let lab = labels(48, 40);
    for labels in [None, Some(&lab[..])] {
        let direct = match labels {
            Some(l) => render_object_sums::<f64, _>(&scene, &camera, &settings, l),
            None => render::<f64, _>(&scene, &camera, &settings),
        }
        .unwrap();
        let frame = Cpu.forward(&scene, &camera, &settings, labels).unwrap();
        assert_eq!(frame.rgb, direct.rgb);
        assert_eq!(frame.objects, direct.objects);
        assert_eq!(frame.object_sums, direct.object_sums);
        let grads = OutputGrads {
            rgb: Some(vec![1.0; 48 * 40 * 3]),
            ..Default::default()
        };
        let via_trait = Cpu.backward(&frame, &scene, &grads);
        let plain = direct.backward(&scene, &grads);
        assert_eq!(flat(&via_trait.params), flat(&plain.params));
        assert_eq!(via_trait.densify, plain.densify);
    }
}
