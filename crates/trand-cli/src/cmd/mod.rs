//! One module per subcommand.
pub mod eval;
pub mod info;
pub mod reconstruct;
pub mod update;
pub mod synth;
