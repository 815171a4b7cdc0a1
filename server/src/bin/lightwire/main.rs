//! `lightwire`: the Lightwire server command. This file parses the command
//! line and dispatches; each subcommand lives in its own module with its
//! arguments.

mod args;
mod bake;
mod bench;
mod serve;
mod validate;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use bake::BakeArgs;
use bench::BenchCommand;
use serve::{RelayFlags, ServeFlags, relay_command, serve_command};
use validate::ValidateArgs;

#[derive(Parser)]
#[command(
    name = "lightwire",
    version,
    about = "Lightwire: a networked radiosity service"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Solve a scene once and write lightmap.exr, lightmap.png, atlas.json
    /// and stats.json.
    Bake(BakeArgs),
    /// Benchmarks (run the release build).
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
    /// Serve scenes over HTTP and WebSocket: live lightmaps, REST, metrics.
    Serve(ServeFlags),
    /// Relay scenes of solvers to many viewers: subscribes to each upstream
    /// scene as a client and serves it with the same protocol, forwarding
    /// drivers' transforms; keeps serving the last version while an
    /// upstream is down.
    Relay(RelayFlags),
    /// Check scene files and print what they contain.
    Validate(ValidateArgs),
}

fn main() -> ExitCode {
    // SAFETY: first thing in main, before any thread starts.
    unsafe { lightwire_adapter::quiet_device_select() };
    let result = match Cli::parse().command {
        Command::Bake(args) => args.run(),
        Command::Bench { what } => what.run(),
        Command::Serve(flags) => serve_command(flags),
        Command::Relay(flags) => relay_command(flags),
        Command::Validate(args) => args.run(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
