//! Renders the tabletop benchmark scene a few times, for profilers and instruction counters:
//! `cargo run --release --example render_once -- 30000 MODE REPS` with MODE `fwd` (all maps, forward),
//! `bwd` (all maps, forward+backward) or `train` (what a training step renders: object sums against a
//! label map, no geometric maps, forward+backward). With the `trand` binary's allocator (mimalloc).
//! `TRAND_CHECKSUM=1` also prints a hash of the bits of every output and gradient, to check that a
//! change of the kernels left the results identical.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;
use std::hash::{Hash, Hasher};

use trand_render::bench_scene::{tabletop_camera, tabletop_scene};
use trand_render::{
    GeometryMaps, Maps, ObjectSumGrads, OutputGrads, RenderSettings, render, render_object_sums,
};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(30_000);
    let mode = args.get(2).map_or("fwd", String::as_str);
    let reps: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(5);
    let s = tabletop_scene(n, 7);
    let cam = tabletop_camera();
    let all = RenderSettings {
        maps: Maps::All,
        ..Default::default()
    };
    let train = RenderSettings {
        geometry: GeometryMaps::Skipped,
        ..all
    };
    let np = 640 * 480;
    let mut grads = OutputGrads {
        rgb: Some(vec![1e-3f32; np * 3]),
        mask: Some(vec![1e-3; np * 3]),
        ..Default::default()
    };
    let labels: Vec<u8> = render::<f32, _>(&s, &cam, &all)
        .expect("render")
        .alpha
        .iter()
        .map(|&a| u8::from(a > 0.5))
        .collect();
    if mode == "train" {
        grads.object_sums = Some(ObjectSumGrads {
            total: vec![1e-6; 15],
            on_label: vec![-1e-5; 15],
        });
    } else {
        grads.objects = Some(vec![1e-3; np * 15]);
    }
    let t0 = std::time::Instant::now();
    for _ in 0..reps {
        let out = match mode {
            "train" => render_object_sums::<f32, _>(&s, &cam, &train, &labels),
            _ => render::<f32, _>(&s, &cam, &all),
        }
        .expect("render");
        let g = (mode != "fwd").then(|| out.backward(&s, &grads));
        if std::env::var_os("TRAND_CHECKSUM").is_some() {
            let mut h = std::collections::hash_map::DefaultHasher::new();
            let mut put = |v: &[f32]| v.iter().for_each(|x| x.to_bits().hash(&mut h));
            for m in [
                &out.rgb,
                &out.mask,
                &out.objects,
                &out.alpha,
                &out.depth,
                &out.normal,
            ] {
                put(m);
            }
            if let Some(g) = &g {
                let p = &g.params;
                put(p.means.as_flattened());
                put(p.log_scales.as_flattened());
                put(p.quats.as_flattened());
                put(&p.opacity_logits);
                put(&p.sh);
                put(&p.mask_sh);
                put(&p.obj_logits);
                put(g.densify.as_flattened());
            }
            println!("checksum {:016x}", h.finish());
        }
        std::hint::black_box(g);
    }
    println!(
        "{:.1} ms per call",
        t0.elapsed().as_secs_f64() * 1e3 / reps as f64
    );
}
