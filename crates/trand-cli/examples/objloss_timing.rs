//! Times the object-aware 3D loss on a run's surfels: `cargo run --release -p trand-cli --example
//! objloss_timing -- RUN [REPS]`.
use std::time::Instant;

use trand_train::losses::object::{ObjectLossParams, object_aware_loss, object_members, select};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let s =
        trand_io::read_surfels_ply(std::path::Path::new(&args[1]).join("surfels.ply").as_path())
            .expect("surfels");
    let reps: usize = args.get(2).and_then(|v| v.parse().ok()).unwrap_or(50);
    let params = ObjectLossParams::default();
    let k = s.num_objects;
    let sel = select(&s.means, &s.obj_logits, k, &params);
    for o in &sel {
        println!("object {} members {}", o.channel, o.num_members);
    }
    let t = Instant::now();
    for _ in 0..reps {
        std::hint::black_box(object_members(&s.obj_logits, k, 0.5));
    }
    println!(
        "members: {:.2} ms",
        t.elapsed().as_secs_f64() * 1e3 / reps as f64
    );
    if std::env::var_os("ONLY_MEMBERS").is_some() {
        return;
    }
    let t = Instant::now();
    for _ in 0..reps {
        std::hint::black_box(select(&s.means, &s.obj_logits, k, &params));
    }
    println!(
        "select: {:.2} ms",
        t.elapsed().as_secs_f64() * 1e3 / reps as f64
    );
    let t = Instant::now();
    let mut v = 0.0;
    for _ in 0..reps {
        v += std::hint::black_box(object_aware_loss(&s.means, &s.obj_logits, k, &params)).value;
    }
    println!(
        "loss: {:.2} ms ({v})",
        t.elapsed().as_secs_f64() * 1e3 / reps as f64
    );
}
