//! Properties of the lane kernels: the eight-lane intersection equals the scalar one bit for bit, the
//! per-row column cut never drops a pixel the alpha gate would pass, and the AVX-512, AVX2 and baseline
//! builds of the kernels return identical bits.

mod common;

use rand::{RngExt, SeedableRng};
use trand_core::{Real, Surfels, math::logit, sh::rgb_to_dc, surfels::Surfel};
use trand_render::camera::CamR;
use trand_render::intersect::{Row, intersect, intersect_lanes, row_columns, tile_row_columns};
use trand_render::lanes::{M, V};
use trand_render::preprocess::{Proj, preprocess_one};
use trand_render::simd::{Dispatch, set_dispatch};
use trand_render::{
    GeometryMaps, Maps, ObjectSumGrads, OutputGrads, RenderSettings, render, render_object_sums,
};

/// Surfels of every shape the optimiser produces: tiny to large, round to needle-thin, any tilt
/// (including nearly edge-on), opacity 0.005 to 0.999.
fn varied_scene(n: usize, seed: u64) -> Surfels {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let mut s = Surfels::new(0, 3).unwrap();
    for _ in 0..n {
        let big = rng.random_range(0.002f32..0.15);
        let thin = big * rng.random_range(0.02f32..1.0);
        let q = [0, 1, 2, 3].map(|_| rng.random_range(-1.0f32..1.0));
        s.push(&Surfel {
            mean: [0, 1, 2].map(|_| rng.random_range(-0.3f32..0.3)),
            log_scale: [big.ln(), thin.ln()],
            quat: q,
            opacity_logit: logit(rng.random_range(0.005f32..0.999)),
            sh_dc: [rgb_to_dc(0.5); 3],
            mask_dc: [rgb_to_dc(0.5); 3],
            obj_logits: vec![0.0; 3],
        });
    }
    s
}

fn projections(s: &Surfels, cam: &CamR<f32>) -> Vec<Proj<f32>> {
    (0..s.len())
        .filter_map(|i| preprocess_one::<f32, _>(s, i, cam, 0))
        .collect()
}

#[test]
fn lane_intersection_equals_scalar_intersection_bit_for_bit() {
    let camera = common::test_camera(96, 72, 0.8);
    let cam = CamR::<f32>::new(&camera, 0.2);
    let projs = projections(&varied_scene(400, 3), &cam);
    let mut compared = 0;
    for p in &projs {
        for y in (p.bbox[1]..=p.bbox[3]).step_by(3) {
            let row = Row::new(p, y as f32);
            for x0 in (p.bbox[0]..=p.bbox[2]).step_by(8) {
                let xs = V(std::array::from_fn(|l| (x0 + l as i32) as f32));
                let h = intersect_lanes(p, &row, xs, cam.near, M::from_bits(0xff));
                for l in 0..8 {
                    match intersect(p, &row, xs.0[l], cam.near) {
                        Some(s) => {
                            assert!(h.valid.lane(l));
                            for (a, b) in [
                                (h.u, s.u),
                                (h.v, s.v),
                                (h.z, s.z),
                                (h.g, s.g),
                                (h.alpha, s.alpha),
                            ] {
                                assert_eq!(a.0[l].to_bits(), b.to_bits());
                            }
                            assert_eq!(h.object_space.lane(l), s.object_space);
                            assert_eq!(h.clamped.lane(l), s.clamped);
                            compared += 1;
                        }
                        None => {
                            assert!(!h.valid.lane(l));
                            assert_eq!(h.alpha.0[l], 0.0, "a missed lane carries zero alpha");
                        }
                    }
                }
            }
        }
    }
    assert!(compared > 1000, "only {compared} hits compared");
}

#[test]
fn row_cut_keeps_every_pixel_the_alpha_gate_passes() {
    for (seed, (w, h)) in [
        (1u64, (128u32, 96u32)),
        (2, (64, 48)),
        (9, (200, 150)),
        (17, (320, 240)),
        (23, (160, 120)),
    ] {
        let camera = common::test_camera(w, h, 0.7);
        let cam = CamR::<f32>::new(&camera, 0.2);
        let projs = projections(&varied_scene(600, seed), &cam);
        let (mut hits, mut boxed, mut cut_away) = (0usize, 0usize, 0usize);
        for p in &projs {
            for y in p.bbox[1]..=p.bbox[3] {
                let yr = f32::from_f64(y as f64);
                let cols = row_columns(p, yr);
                let row = Row::new(p, yr);
                for x in p.bbox[0]..=p.bbox[2] {
                    boxed += 1;
                    let inside = cols.is_some_and(|(lo, hi)| lo <= x && x <= hi);
                    cut_away += usize::from(!inside);
                    if intersect(p, &row, x as f32, cam.near).is_some() {
                        hits += 1;
                        assert!(
                            inside,
                            "pixel ({x}, {y}) passes the alpha gate but the cut {cols:?} drops it"
                        );
                    }
                }
            }
        }
        assert!(hits > 1000, "seed {seed}: only {hits} hits");
        // The cut must also do its job: a good share of the boxes' pixels is skipped.
        assert!(
            cut_away * 5 > boxed,
            "seed {seed}: cut removed {cut_away} of {boxed}"
        );
    }
}

#[test]
fn tile_row_columns_equal_the_row_by_row_cut() {
    let camera = common::test_camera(200, 150, 0.7);
    let cam = CamR::<f32>::new(&camera, 0.2);
    let projs = projections(&varied_scene(600, 31), &cam);
    let (mut rows, mut empty) = (0usize, 0usize);
    for p in &projs {
        for ty0 in (p.bbox[1] / 16 * 16..=p.bbox[3]).step_by(16) {
            let (lo, hi) = tile_row_columns(p, ty0);
            for r in 0..16 {
                let want = row_columns(p, (ty0 + r as i32) as f32);
                let got = (lo[r] <= hi[r]).then_some((lo[r], hi[r]));
                assert_eq!(got, want, "surfel {} row {}", p.index, ty0 + r as i32);
                rows += 1;
                empty += usize::from(want.is_none());
            }
        }
    }
    assert!(rows > 10_000 && empty > 1000, "{rows} rows, {empty} empty");
}

/// How a test render is made: every map with the dense object map, or a training step's maps (object
/// sums against a label map, no geometric maps), which the AVX-512 forward build serves.
#[derive(Clone, Copy, Debug)]
enum Pass {
    AllMaps,
    TrainingStep,
}

/// Output and gradient bits of one render and backward pass of `s` in the kernel build `d`.
fn render_bits(s: &Surfels, pass: Pass, d: Dispatch) -> Vec<u32> {
    let camera = common::test_camera(160, 120, 0.9);
    let mut settings = RenderSettings {
        maps: Maps::All,
        background: [0.1, 0.2, 0.3],
        ..Default::default()
    };
    set_dispatch(d);
    let out = match pass {
        Pass::AllMaps => render::<f32, _>(s, &camera, &settings).unwrap(),
        Pass::TrainingStep => {
            settings.geometry = GeometryMaps::Skipped;
            let labels: Vec<u8> = (0..160 * 120).map(|i| ((i / 7) % 3) as u8).collect();
            render_object_sums::<f32, _>(s, &camera, &settings, &labels).unwrap()
        }
    };
    let n = out.alpha.len();
    let mut g = OutputGrads {
        rgb: Some((0..3 * n).map(|i| (i % 7) as f32 * 0.1 - 0.3).collect()),
        mask: Some(vec![0.2; 3 * n]),
        ..Default::default()
    };
    match pass {
        Pass::AllMaps => {
            g.objects = Some((0..3 * n).map(|i| (i % 5) as f32 * 0.1 - 0.2).collect());
            g.depth = Some(vec![0.3; n]);
            g.median = Some(vec![-0.4; n]);
            g.distortion = Some(vec![0.5; n]);
        }
        Pass::TrainingStep => {
            g.object_sums = Some(ObjectSumGrads {
                total: vec![0.01, -0.02, 0.03],
                on_label: vec![-0.1, 0.2, -0.05],
            });
        }
    }
    let grads = out.backward(s, &g);
    set_dispatch(Dispatch::Auto);
    let mut v: Vec<u32> = [
        &out.rgb,
        &out.mask,
        &out.objects,
        &out.depth,
        &out.median,
        &out.distortion,
    ]
    .iter()
    .flat_map(|m| m.iter().map(|x| x.to_bits()))
    .collect();
    if let Some(sums) = &out.object_sums {
        v.extend(sums.total.iter().chain(&sums.on_label).map(|x| x.to_bits()));
    }
    let p = &grads.params;
    for m in [
        p.means.as_flattened(),
        p.quats.as_flattened(),
        &p.opacity_logits,
        &p.sh,
        &p.obj_logits,
    ] {
        v.extend(m.iter().map(|x| x.to_bits()));
    }
    v
}

#[test]
fn every_kernel_build_returns_identical_bits() {
    let s = varied_scene(1500, 5);
    for pass in [Pass::AllMaps, Pass::TrainingStep] {
        let base = render_bits(&s, pass, Dispatch::Baseline);
        for d in [Dispatch::Avx2, Dispatch::Auto] {
            let v = render_bits(&s, pass, d);
            assert_eq!(v.len(), base.len());
            assert!(v == base, "{d:?} and baseline kernels differ ({pass:?})");
        }
    }
}

#[test]
fn skipping_the_geometric_maps_changes_no_other_output_or_gradient() {
    let camera = common::test_camera(128, 96, 0.8);
    let s = varied_scene(1200, 8);
    let run = |geometry: GeometryMaps| {
        let settings = RenderSettings {
            maps: Maps::All,
            background: [0.3, 0.2, 0.1],
            geometry,
            ..Default::default()
        };
        let out = render::<f32, _>(&s, &camera, &settings).unwrap();
        let n = out.alpha.len();
        let g = OutputGrads {
            rgb: Some((0..3 * n).map(|i| (i % 11) as f32 * 0.05 - 0.2).collect()),
            mask: Some(vec![-0.1; 3 * n]),
            objects: Some((0..3 * n).map(|i| (i % 3) as f32 * 0.1).collect()),
            alpha: Some(vec![0.05; n]),
            depth: Some(vec![0.2; n]),
            ..Default::default()
        };
        let grads = out.backward(&s, &g);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let p = &grads.params;
        let maps = [&out.rgb, &out.mask, &out.objects, &out.alpha].map(|m| bits(m));
        let gr = [
            p.means.as_flattened(),
            p.quats.as_flattened(),
            p.log_scales.as_flattened(),
            &p.opacity_logits,
            &p.sh,
            &p.obj_logits,
        ]
        .map(bits);
        (maps, gr, out.depth.len(), out.median.len())
    };
    let (full, skipped) = (run(GeometryMaps::Rendered), run(GeometryMaps::Skipped));
    assert!(full.0 == skipped.0, "rgb/mask/objects/alpha differ");
    assert!(full.1 == skipped.1, "gradients differ");
    assert!(
        full.2 > 0 && skipped.2 == 0 && skipped.3 == 0,
        "skipped maps come back empty"
    );
}
