//! Wall-clock timing of the image losses at 640×480 (`TRAND_HALF=1`: 320×240, the `--downsample 2`
//! training size): `cargo run --release -p trand-train --example loss_timing [FILTER]`.

use std::time::Instant;

use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;
use trand_train::init::{InitConfig, SlabBounds, SlabBox, random_init};
use trand_train::losses::object::{ObjectLossParams, object_aware_loss};
use trand_train::losses::{dice, photometric};
use trand_train::{Adam, AdamParams, DensifyStats, TrainConfig, densify_and_prune};

/// Process CPU time (user + system) in seconds, from `/proc/self/stat` (Linux; 0 elsewhere). On a shared
/// machine it is a steadier measure than wall time.
fn cpu_seconds() -> f64 {
    let Ok(s) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    let after = s.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0 // utime, stime in clock ticks (USER_HZ = 100)
}

fn time<T>(label: &str, reps: usize, mut f: impl FnMut() -> T) {
    // An optional first argument selects the timings whose label contains it.
    if let Some(filter) = std::env::args().nth(1)
        && !label.contains(&filter)
    {
        return;
    }
    let _ = f(); // warm-up
    let (t, c) = (Instant::now(), cpu_seconds());
    for _ in 0..reps {
        std::hint::black_box(f());
    }
    let wall = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
    let cpu = (cpu_seconds() - c) * 1e3 / reps as f64;
    println!("{label}: wall {wall:.2} ms, cpu {cpu:.2} ms");
}

fn main() {
    let (w, h) = if std::env::var_os("TRAND_HALF").is_some() {
        (320usize, 240usize)
    } else {
        (640, 480)
    };
    let mut rng = Pcg64::seed_from_u64(0);
    let x: Vec<f32> = (0..w * h * 3).map(|_| rng.random::<f32>()).collect();
    let y: Vec<f32> = (0..w * h * 3).map(|_| rng.random::<f32>()).collect();
    println!("rayon threads: {}", rayon::current_num_threads());
    time(&format!("l1 {w}x{h}x3 (fwd+bwd)"), 50, || {
        photometric::l1(&x, &y)
    });
    time(&format!("ssim {w}x{h}x3 (fwd+bwd)"), 50, || {
        photometric::ssim(&x, &y, w, h, 3)
    });
    time(&format!("photometric {w}x{h}x3 (fwd+bwd)"), 50, || {
        photometric::photometric(&x, &y, w, h, 3, 0.2)
    });
    let k = 15;
    let p: Vec<f32> = (0..w * h * k).map(|_| rng.random::<f32>()).collect();
    let t: Vec<f32> = (0..w * h * k)
        .map(|i| if i % k == 0 { 1.0 } else { 0.0 })
        .collect();
    time(&format!("dice {w}x{h}x15 (fwd+bwd)"), 50, || {
        dice::dice(&p, &t, k)
    });

    // TRAN-D-sized scene: 100k surfels, 10 objects of 6k members each, the rest background/unassigned.
    let n = 100_000;
    let num_obj = 15;
    let means: Vec<[f32; 3]> = (0..n)
        .map(|_| {
            [
                rng.random::<f32>(),
                rng.random::<f32>(),
                rng.random::<f32>(),
            ]
        })
        .collect();
    let mut logits = vec![0.0f32; n * num_obj];
    for i in 0..60_000 {
        logits[i * num_obj + 1 + i % 10] = 5.0;
    }
    let params = ObjectLossParams::default();
    time(
        "object-aware loss, 100k surfels, 10 objects x 6k",
        5,
        || object_aware_loss(&means, &logits, num_obj, &params),
    );
    let init = InitConfig {
        bounds: SlabBounds::Explicit(SlabBox::tran_d()),
        ..Default::default()
    };
    time("random init 100k (kd-tree 3-NN scales)", 3, || {
        random_init(&init, &[], 0, num_obj).unwrap()
    });
    let surfels = random_init(&init, &[], 0, num_obj).unwrap();
    let grads = surfels.zeros_like();
    let mut params = surfels.clone();
    let mut adam = Adam::new(&params, AdamParams::default());
    let lr = TrainConfig::default().learning_rates(1, 1.0);
    time("adam step, 100k surfels (SH 0, 15 objects)", 10, || {
        adam.step(&mut params, &grads, &lr)
    });
    let radii = vec![1.0f32; surfels.len()];
    let g2d: Vec<[f32; 2]> = (0..surfels.len())
        .map(|i| [if i % 3 == 0 { 1e-3 } else { 0.0 }, 0.0])
        .collect();
    time(
        "densify_and_prune, 100k surfels, 1/3 above threshold",
        3,
        || {
            let mut s = surfels.clone();
            let mut a = Adam::new(&s, AdamParams::default());
            let mut st = DensifyStats::new(s.len());
            st.add(&radii, &g2d);
            let cfg = TrainConfig::default();
            densify_and_prune(
                &mut s,
                &mut a,
                &mut st,
                &cfg.densify,
                1.0,
                Some(20.0),
                &mut Pcg64::seed_from_u64(0),
            )
        },
    );
}
