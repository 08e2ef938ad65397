//! `cargo bench -p trand-render`: forward and forward+backward at 640×480 on the tabletop scene with
//! 10k, 30k and 100k surfels (all maps: RGB, mask, 15-channel object map, geometry), and the render a
//! TRAN-D training step makes (`training_step`: RGB, mask, object sums against a label map, no geometry).
//! With the allocator the `trand` binary ships with (mimalloc): each call allocates tens of megabytes of
//! tile blocks and pair records, and glibc's allocator returns them to the system and faults them back
//! in on every call, which is not what a training run pays.

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use std::sync::OnceLock;

use trand_core::Surfels;
use trand_render::bench_scene::{tabletop_camera, tabletop_scene};
use trand_render::{
    GeometryMaps, Maps, ObjectSumGrads, OutputGrads, RenderSettings, render, render_object_sums,
};

const SIZES: [usize; 3] = [10_000, 30_000, 100_000];

fn scene(n: usize) -> &'static Surfels {
    static SCENES: OnceLock<Vec<Surfels>> = OnceLock::new();
    let all = SCENES.get_or_init(|| SIZES.iter().map(|&n| tabletop_scene(n, 7)).collect());
    &all[SIZES.iter().position(|&s| s == n).expect("known size")]
}

fn settings() -> RenderSettings {
    RenderSettings {
        maps: Maps::All,
        ..Default::default()
    }
}

#[divan::bench(args = SIZES, sample_count = 20)]
fn forward(b: divan::Bencher, n: usize) {
    let s = scene(n);
    let cam = tabletop_camera();
    b.bench(|| render::<f32, _>(s, &cam, &settings()).expect("render"));
}

#[divan::bench(args = SIZES, sample_count = 20)]
fn forward_backward(b: divan::Bencher, n: usize) {
    let s = scene(n);
    let cam = tabletop_camera();
    let np = 640 * 480;
    let grads = OutputGrads {
        rgb: Some(vec![1e-3f32; np * 3]),
        mask: Some(vec![1e-3; np * 3]),
        objects: Some(vec![1e-3; np * 15]),
        ..Default::default()
    };
    b.bench(|| {
        let out = render::<f32, _>(s, &cam, &settings()).expect("render");
        out.backward(s, &grads)
    });
}

/// Labels as a training view has them: channel 1 on the covered pixels, 0 (background) elsewhere.
fn labels(n: usize) -> &'static [u8] {
    static LABELS: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    let all = LABELS.get_or_init(|| {
        SIZES
            .iter()
            .map(|&n| {
                let out =
                    render::<f32, _>(scene(n), &tabletop_camera(), &settings()).expect("render");
                out.alpha.iter().map(|&a| u8::from(a > 0.5)).collect()
            })
            .collect()
    });
    &all[SIZES.iter().position(|&s| s == n).expect("known size")]
}

#[divan::bench(args = SIZES, sample_count = 20)]
fn training_step(b: divan::Bencher, n: usize) {
    let s = scene(n);
    let cam = tabletop_camera();
    let np = 640 * 480;
    let lab = labels(n);
    let settings = RenderSettings {
        maps: Maps::All,
        geometry: GeometryMaps::Skipped,
        ..Default::default()
    };
    let grads = OutputGrads {
        rgb: Some(vec![1e-3f32; np * 3]),
        mask: Some(vec![1e-3; np * 3]),
        object_sums: Some(ObjectSumGrads {
            total: vec![1e-6; 15],
            on_label: vec![-1e-5; 15],
        }),
        ..Default::default()
    };
    b.bench(|| {
        let out = render_object_sums::<f32, _>(s, &cam, &settings, lab).expect("render");
        out.backward(s, &grads)
    });
}

fn main() {
    let cam = tabletop_camera();
    for n in SIZES {
        let out = render::<f32, _>(scene(n), &cam, &settings()).expect("render");
        let covered = out.alpha.iter().filter(|&&a| a > 0.5).count();
        println!(
            "scene n={n}: visible {}, tile pairs {}, pixel-surfel pairs {}, covered pixels {covered}",
            out.num_visible(),
            out.num_pairs,
            out.pixel_pairs
        );
    }
    divan::main();
}
