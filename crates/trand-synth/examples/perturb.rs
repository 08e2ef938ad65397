//! Writes a copy of a BOP sequence with degraded training inputs (see `trand_synth::perturb`).
//!
//! ```text
//! cargo run --release -p trand-synth --example perturb -- SRC DST SEED ids,boundary,miss,pose
//! ```

use trand_synth::perturb::{Imperfection, Perturbation, perturb_bop};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 5 {
        eprintln!("usage: perturb SRC DST SEED ids,boundary,miss,pose");
        std::process::exit(2);
    }
    let seed: u64 = args[3].parse().unwrap_or_else(|_| {
        eprintln!("SEED `{}` is not an integer", args[3]);
        std::process::exit(2)
    });
    let mut kinds = Vec::new();
    for k in args[4].split(',') {
        kinds.push(match k {
            "ids" => Imperfection::Ids,
            "boundary" => Imperfection::Boundary,
            "miss" => Imperfection::Miss,
            "pose" => Imperfection::Pose,
            _ => {
                eprintln!("unknown imperfection `{k}` (ids, boundary, miss, pose)");
                std::process::exit(2)
            }
        });
    }
    match perturb_bop(
        args[1].as_ref(),
        args[2].as_ref(),
        &Perturbation::new(kinds, seed),
    ) {
        Ok(r) => println!("{}", serde_json::to_string(&r).expect("serialises")),
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1)
        }
    }
}
