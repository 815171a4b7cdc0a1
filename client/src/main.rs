//! `lightwire-client`: watch, drive, view and load-test a Lightwire server.
//!
//! Every subcommand takes the server as `URL [--scene ID]`: the server's
//! base address (`http://127.0.0.1:8080`, as `lightwire serve` prints it)
//! plus `--scene`, or the WebSocket URL `ws://HOST:PORT/ws/scenes/ID`.
//! The token comes from `--token` or `LIGHTWIRE_TOKEN` (none for a `--dev`
//! server). Exit codes: 0 success, 1 a `load` limit was missed, 2 an
//! error (bad arguments, script, connection).

mod cli;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "lightwire-client",
    version,
    about = "Watch, drive, view and load-test a Lightwire server"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// A live line: version, convergence, frames/s, bytes/s, latency.
    Watch(cli::watch::WatchArgs),
    /// Move a dynamic object and play light keys along a script, or set a
    /// light (--light).
    Drive(cli::drive::DriveArgs),
    /// Render the scene with the streamed lightmap to PNG (headless wgpu).
    View(lightwire_client::view::ViewArgs),
    /// Many viewers and drivers at once; a JSON report; limits.
    Load(cli::load::LoadArgs),
}

fn main() -> ExitCode {
    // SAFETY: first thing in main, before any thread starts.
    unsafe { lightwire_adapter::quiet_device_select() };
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Watch(args) => cli::watch::run(args).map(|()| true),
        Command::Drive(args) => cli::drive::run(args).map(|()| true),
        // Synchronous, outside any tokio runtime: the renderer makes its own.
        Command::View(args) => lightwire_client::view::run(args).map(|()| true),
        Command::Load(args) => cli::load::run(args),
    };
    match result {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
