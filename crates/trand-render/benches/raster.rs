//! `cargo bench -p trand-render`: forward and forward+backward at 640×480 on the tabletop scene with
//! 10k, 30k and 100k surfels (all maps: RGB, mask, 15-channel object map, geometry).

use std::sync::OnceLock;

use trand_core::Surfels;
use trand_render::bench_scene::{tabletop_camera, tabletop_scene};
use trand_render::{Maps, OutputGrads, RenderSettings, render};

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
