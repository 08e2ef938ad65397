//! Times renders of a run's surfels from a sequence's first training view:
//! `cargo run --release -p trand-cli --example render_run -- RUN SEQ [MODE] [SCALE] [REPS]`.
//!
//! * MODE `all` (default): forward and forward+backward of every map, at native and half resolution
//!   (SCALE ignored).
//! * MODE `train`: what a training step renders (RGB, mask colour, object sums against a label map,
//!   no geometric maps), forward+backward at SCALE (default 0.5, the `--downsample 2` training
//!   resolution). The labels are the argmax of the rendered object map, so their regions follow the
//!   objects as a segmenter's would.
//!
//! REPS (default 5) calls per figure; with REPS = 1 the process is short enough for callgrind.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;
use std::time::Instant;

use trand_render::{
    GeometryMaps, Maps, ObjectSumGrads, OutputGrads, RenderSettings, render, render_object_sums,
};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let s =
        trand_io::read_surfels_ply(std::path::Path::new(&args[1]).join("surfels.ply").as_path())
            .expect("surfels");
    let seq = trand_io::read_sequence_with(
        std::path::Path::new(&args[2]),
        &trand_io::LoadOptions::cameras_only(),
    )
    .expect("sequence");
    let mode = args.get(3).map_or("all", String::as_str);
    let scale: f64 = args.get(4).and_then(|v| v.parse().ok()).unwrap_or(0.5);
    let reps: usize = args.get(5).and_then(|v| v.parse().ok()).unwrap_or(5);
    let cam0 = seq.train_t0[1].camera;
    let at = |scale: f64| trand_core::Camera {
        intrinsics: cam0.intrinsics.scaled(scale),
        ..cam0
    };
    let all = RenderSettings {
        maps: Maps::All,
        ..Default::default()
    };
    let k = s.num_objects;
    if mode == "train" {
        let cam = at(scale);
        let np = cam.intrinsics.num_pixels();
        let objects = render::<f32, _>(&s, &cam, &all).expect("render").objects;
        let labels: Vec<u8> = objects
            .chunks_exact(k)
            .map(|p| {
                let best = (0..k).fold(0, |b, c| if p[c] > p[b] { c } else { b });
                best as u8
            })
            .collect();
        let settings = RenderSettings {
            geometry: GeometryMaps::Skipped,
            ..all
        };
        let g = OutputGrads {
            rgb: Some(vec![1e-3f32; np * 3]),
            mask: Some(vec![1e-3; np * 3]),
            object_sums: Some(ObjectSumGrads {
                total: vec![1e-6; k],
                on_label: vec![-1e-5; k],
            }),
            ..Default::default()
        };
        let t = Instant::now();
        let mut pairs = 0;
        for _ in 0..reps {
            let out = render_object_sums::<f32, _>(&s, &cam, &settings, &labels).expect("render");
            pairs = out.num_pairs;
            std::hint::black_box(out.backward(&s, &g));
        }
        println!(
            "{:.1} ms per training step ({}x{}, {} surfels, {} tile pairs)",
            t.elapsed().as_secs_f64() * 1e3 / reps as f64,
            cam.intrinsics.width,
            cam.intrinsics.height,
            s.len(),
            pairs
        );
        return;
    }
    for scale in [1.0, 0.5] {
        let cam = at(scale);
        let np = cam.intrinsics.num_pixels();
        let g = OutputGrads {
            rgb: Some(vec![1e-3f32; np * 3]),
            mask: Some(vec![1e-3; np * 3]),
            objects: Some(vec![1e-3; np * k]),
            ..Default::default()
        };
        let t = Instant::now();
        let mut pairs = (0, 0);
        for _ in 0..reps {
            let out = render::<f32, _>(&s, &cam, &all).expect("render");
            pairs = (out.num_pairs, out.pixel_pairs);
        }
        let fwd = t.elapsed().as_secs_f64() / reps as f64;
        let t = Instant::now();
        for _ in 0..reps {
            let out = render::<f32, _>(&s, &cam, &all).expect("render");
            std::hint::black_box(out.backward(&s, &g));
        }
        let fb = t.elapsed().as_secs_f64() / reps as f64;
        println!(
            "{}x{}: {} surfels, tile pairs {}, pixel pairs {}: forward {:.1} ms, forward+backward {:.1} ms",
            cam.intrinsics.width,
            cam.intrinsics.height,
            s.len(),
            pairs.0,
            pairs.1,
            fwd * 1e3,
            fb * 1e3
        );
    }
}
