//! One module per subcommand.
pub mod bench;
pub mod demo;
pub mod eval;
pub mod export;
pub mod info;
pub mod perturb;
pub mod reconstruct;
pub mod render;
pub mod synth;
pub mod update;
