//! Renders the 30k-surfel tabletop benchmark scene once (forward, or forward+backward with `bwd`), for
//! profilers and instruction counters: `cargo run --release --example render_once -- 30000 bwd`.
use trand_render::bench_scene::{tabletop_camera, tabletop_scene};
use trand_render::{Maps, OutputGrads, RenderSettings, render};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(30_000);
    let bwd = args.get(2).is_some_and(|s| s == "bwd");
    let reps: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(5);
    let s = tabletop_scene(n, 7);
    let cam = tabletop_camera();
    let settings = RenderSettings {
        maps: Maps::All,
        ..Default::default()
    };
    let np = 640 * 480;
    let grads = OutputGrads {
        rgb: Some(vec![1e-3f32; np * 3]),
        mask: Some(vec![1e-3; np * 3]),
        objects: Some(vec![1e-3; np * 15]),
        ..Default::default()
    };
    let t0 = std::time::Instant::now();
    for _ in 0..reps {
        let out = render::<f32, _>(&s, &cam, &settings).expect("render");
        if bwd {
            std::hint::black_box(out.backward(&s, &grads));
        }
    }
    println!(
        "{:.1} ms per call",
        t0.elapsed().as_secs_f64() * 1e3 / reps as f64
    );
}
