//! Times forward and forward+backward renders of a run's surfels from a sequence's first training view,
//! at native and half resolution: `cargo run --release -p trand-cli --example render_run -- RUN SEQ`.
use std::time::Instant;

use trand_render::{Maps, OutputGrads, RenderSettings, render};

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
    let cam0 = seq.train_t0[1].camera;
    for scale in [1.0, 0.5] {
        let cam = trand_core::Camera {
            intrinsics: cam0.intrinsics.scaled(scale),
            ..cam0
        };
        let settings = RenderSettings {
            maps: Maps::All,
            ..Default::default()
        };
        let np = cam.intrinsics.num_pixels();
        let g = OutputGrads {
            rgb: Some(vec![1e-3f32; np * 3]),
            mask: Some(vec![1e-3; np * 3]),
            objects: Some(vec![1e-3; np * s.num_objects]),
            ..Default::default()
        };
        let reps = 5;
        let t = Instant::now();
        let mut pairs = (0, 0);
        for _ in 0..reps {
            let out = render::<f32, _>(&s, &cam, &settings).expect("render");
            pairs = (out.num_pairs, out.pixel_pairs);
        }
        let fwd = t.elapsed().as_secs_f64() / reps as f64;
        let t = Instant::now();
        for _ in 0..reps {
            let out = render::<f32, _>(&s, &cam, &settings).expect("render");
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
