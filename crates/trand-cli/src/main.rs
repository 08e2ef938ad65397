//! `trand`: depth of transparent objects from a few views (TRAN-D in Rust).
//!
//! Each subcommand lives in its own module under `cmd/`; `main` only parses and dispatches.

use clap::{Parser, Subcommand};

mod alloc;
mod cmd;

#[derive(Parser)]
#[command(
    name = "trand",
    version,
    about = "Transparent-object depth from a few views with 2D Gaussian splatting and physics"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Benchmark methods over sequences (t=0 and t=1), with tables and an HTML report.
    Bench(cmd::bench::Args),
    /// Generate a small scene, run t=0 and t=1, evaluate and write a report (a few minutes).
    Demo(cmd::demo::Args),
    /// A finished run's objects as PLY: point clouds and meshes per object, and with --splats a 3DGS
    /// file for splat viewers.
    Export(cmd::export::Args),
    /// Version and machine facts.
    Info(cmd::info::Args),
    /// A copy of a sequence with perturbed training inputs (per-image ids, mask boundaries, missed
    /// masks, pose error), seeded; the test views stay exact.
    Perturb(cmd::perturb::Args),
    /// t=0: object-aware 2DGS reconstruction from the training views.
    Reconstruct(cmd::reconstruct::Args),
    /// Depth, object ids, alpha and normals of a finished run at cameras given in a JSON file.
    Render(cmd::render::Args),
    /// t=1: scene update after objects were taken away (detection, physics, single-image refinement).
    Update(cmd::update::Args),
    /// Depth metrics (MAE, RMSE, accuracies) of a run's predicted test depths.
    Eval(cmd::eval::Args),
    /// Generate a synthetic transparent-object sequence with exact ground truth.
    Synth(cmd::synth::Args),
}

fn main() -> std::process::ExitCode {
    alloc::keep_freed_pages();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bench(a) => cmd::bench::run(a),
        Command::Demo(a) => cmd::demo::run(a),
        Command::Export(a) => cmd::export::run(a),
        Command::Info(a) => cmd::info::run(a),
        Command::Perturb(a) => cmd::perturb::run(a),
        Command::Reconstruct(a) => cmd::reconstruct::run(a),
        Command::Render(a) => cmd::render::run(a),
        Command::Update(a) => cmd::update::run(a),
        Command::Eval(a) => cmd::eval::run(a),
        Command::Synth(a) => cmd::synth::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_message(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes joined by `: `, leaving out a cause whose text the message already
/// holds (library errors often print their source themselves as well as exposing it).
fn error_message(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let s = cause.to_string();
        if out.contains(&s) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&s);
    }
    out
}

#[cfg(test)]
mod tests {
    use clap::Parser;
    use trand_pipeline::Method;
    use trand_pipeline::associate::Identity;
    use trand_pipeline::update::SurfelMotion;

    use super::{Cli, Command, error_message};

    fn update_args(extra: &[&str]) -> super::cmd::update::Args {
        let base = ["trand", "update", "--run", "r", "--data", "d", "--out", "o"];
        match Cli::try_parse_from(base.iter().chain(extra))
            .unwrap()
            .command
        {
            Command::Update(a) => a,
            _ => unreachable!("an update command"),
        }
    }

    #[test]
    fn flag_values_are_the_toml_names_and_the_old_spellings_still_parse() {
        for (flag, want) in [
            ("translate-rotate", SurfelMotion::TranslateRotate),
            ("rotate", SurfelMotion::TranslateRotate),
            ("rigid-per-object", SurfelMotion::RigidPerObject),
            ("rigid", SurfelMotion::RigidPerObject),
            ("translate", SurfelMotion::Translate),
        ] {
            assert_eq!(update_args(&["--motion", flag]).motion, Some(want));
            let toml: SurfelMotion = serde_json::from_value(serde_json::json!(flag)).unwrap();
            assert_eq!(toml, want, "{flag} in a config file");
        }
        for (flag, want) in [
            ("ids", Identity::ObjectIds),
            ("object-ids", Identity::ObjectIds),
        ] {
            assert_eq!(update_args(&["--identity", flag]).identity, Some(want));
        }
        for name in ["plain2dgs", "plain-2dgs"] {
            let base = [
                "trand",
                "reconstruct",
                "--data",
                "d",
                "--out",
                "o",
                "--method",
                name,
            ];
            let Command::Reconstruct(a) = Cli::try_parse_from(base).unwrap().command else {
                unreachable!("a reconstruct command")
            };
            assert_eq!(a.method, Some(Method::Plain2dgs));
        }
        assert!(Cli::try_parse_from(["trand", "update", "--motion", "spin"]).is_err());
    }

    #[test]
    fn error_messages_print_their_source_once() {
        // A library error whose message repeats its source, as `#[error("...: {0}")]` with `#[from]` does.
        let e = anyhow::anyhow!("disk on fire")
            .context("reading x.json: disk on fire")
            .context("loading the run");
        assert_eq!(
            error_message(&e),
            "loading the run: reading x.json: disk on fire"
        );
    }
}
