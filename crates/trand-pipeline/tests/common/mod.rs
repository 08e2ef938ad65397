//! What the pipeline's integration tests share: the tiny synthetic scene of a seed.

use std::path::Path;

use trand_io::{Sequence, read_sequence};

/// `trand synth --preset tiny --seed SEED`, written under `dir` and read back.
pub fn tiny(seed: u64, dir: &Path) -> Sequence {
    let out = dir.join(format!("seq{seed}"));
    trand_synth::generate(&trand_synth::SynthConfig::new(
        trand_synth::Preset::Tiny,
        seed,
        &out,
    ))
    .expect("synth");
    read_sequence(&out).expect("read synthetic sequence")
}
