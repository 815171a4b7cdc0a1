//! `lightwire serve` and `lightwire relay`: configuration from file,
//! environment and flags, then the listener and the service until a
//! signal.

use std::path::PathBuf;

use std::future::Future;
use std::net::SocketAddr;

use anyhow::{Context, Result};
use lightwire_server::service::{self, Config};
use tokio::sync::watch;

/// Flags of `lightwire serve`.
#[derive(clap::Args)]
pub(crate) struct ServeFlags {
    /// Scene files to serve (repeatable; each scene's name is its id).
    #[arg(long = "scene", num_args = 1.., action = clap::ArgAction::Append)]
    scenes: Vec<PathBuf>,
    /// Address to listen on [default: 127.0.0.1:8080].
    #[arg(long)]
    listen: Option<std::net::SocketAddr>,
    /// TOML config file (flags override it, it overrides defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Serve without authentication: every client is an admin.
    #[arg(long)]
    dev: bool,
    /// Ticks per second per scene [default: 60].
    #[arg(long)]
    tick_hz: Option<f64>,
    /// Solver time per tick in milliseconds [default: 8].
    #[arg(long)]
    budget_ms: Option<f64>,
    /// Multiply every texel density [default: 1].
    #[arg(long)]
    density_scale: Option<f32>,
    /// How a mesh's triangles get charts: each its own (`triangles`), two
    /// that form a parallelogram one (`pairs`), pairs merged into the
    /// parallelograms they tile, or, for the static meshes that have them,
    /// their own lightmap UVs (`lightmap-uvs`) [default: lightmap-uvs].
    #[arg(long, value_enum)]
    charts: Option<lightwire_scene::Charts>,
    /// Solver per scene [default: progressive].
    #[arg(long, value_enum)]
    solver: Option<lightwire_server::service::config::SolverChoice>,
    /// GPU solver: how moves are followed, full | incremental | cross
    /// [default: cross] (per scene: `scene_redistribution` in the config).
    #[arg(long)]
    redistribution: Option<lightwire_solve::gpu::Redistribution>,
    /// GPU adapter whose name contains this (default: prefer a discrete GPU).
    #[arg(long)]
    adapter: Option<String>,
}

pub(crate) fn serve_command(flags: ServeFlags) -> Result<()> {
    let mut config = configure(flags.config.as_deref(), flags.listen, flags.dev)?;
    if !flags.scenes.is_empty() {
        config.scenes = flags.scenes;
    }
    if let Some(v) = flags.tick_hz {
        config.tick_hz = v;
    }
    if let Some(v) = flags.budget_ms {
        config.budget_ms = v;
    }
    if let Some(v) = flags.density_scale {
        config.density_scale = v;
    }
    if let Some(v) = flags.charts {
        config.charts = v;
    }
    if let Some(v) = flags.solver {
        config.solver = v;
    }
    if let Some(v) = flags.redistribution {
        config.redistribution = v;
    }
    if flags.adapter.is_some() {
        config.adapter = flags.adapter;
    }
    config.validate()?;
    start(
        config,
        true,
        |addr, _| format!("lightwire listening on http://{addr} (dashboard: http://{addr}/)"),
        "shutting down: finishing ticks, closing connections",
        service::serve,
    )
}

/// Flags of `lightwire relay`. Tokens for its own clients come from the
/// config file or `LIGHTWIRE_TOKENS`, as for `serve`; the token it presents
/// upstream from `upstream_token` or `LIGHTWIRE_UPSTREAM_TOKEN` (not a
/// flag, so that it does not show in `ps`).
#[derive(clap::Args)]
pub(crate) struct RelayFlags {
    /// A solver scene to relay: ws://HOST:PORT/ws/scenes/ID (repeatable;
    /// served here under the same path).
    #[arg(long = "upstream", num_args = 1.., action = clap::ArgAction::Append)]
    upstreams: Vec<String>,
    /// Address to listen on [default: 127.0.0.1:8080].
    #[arg(long)]
    listen: Option<std::net::SocketAddr>,
    /// TOML config file, the same format as `serve`'s (flags override it,
    /// it overrides defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// No authentication for the relay's own clients: every client is an
    /// admin (the upstream still checks the relay's upstream token).
    #[arg(long)]
    dev: bool,
}

/// Logging on, then the configuration `serve` and `relay` share: the
/// config file (or defaults) and `LIGHTWIRE_*` variables, overridden by
/// `--listen` and `--dev`.
fn configure(
    path: Option<&std::path::Path>,
    listen: Option<SocketAddr>,
    dev: bool,
) -> Result<Config> {
    init_logging();
    let mut config = load_config(path)?;
    if let Some(listen) = listen {
        config.listen = listen;
    }
    config.dev_mode |= dev;
    Ok(config)
}

/// Logs to stderr, `RUST_LOG` or `info`.
fn init_logging() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
}

/// The configuration of `serve` and `relay` before their flags: the TOML
/// file when given (else the defaults), then `LIGHTWIRE_*` variables.
fn load_config(path: Option<&std::path::Path>) -> Result<Config> {
    let mut config = match path {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    config.apply_env(std::env::vars())?;
    Ok(config)
}

pub(crate) fn relay_command(flags: RelayFlags) -> Result<()> {
    let mut config = configure(flags.config.as_deref(), flags.listen, flags.dev)?;
    if !flags.upstreams.is_empty() {
        config.upstreams = flags.upstreams;
    }
    config.validate_relay()?;
    start(
        config,
        false,
        |addr, config| {
            format!(
                "lightwire relay listening on http://{addr} (relaying {})",
                config.upstreams.join(", ")
            )
        },
        "shutting down: closing connections",
        lightwire_server::relay::relay,
    )
}

/// What `serve` and `relay` share once configured: bind the listener
/// (`config.listen` becomes the bound address, so port 0 works), warn in
/// development mode (`log_dev` also logs it), print `banner` on stdout
/// (the line tools and tests wait for: where to connect), and run `run`
/// until SIGINT or SIGTERM, logging `stopping` then.
fn start<Fut>(
    mut config: Config,
    log_dev: bool,
    banner: impl FnOnce(SocketAddr, &Config) -> String,
    stopping: &'static str,
    run: impl FnOnce(Config, tokio::net::TcpListener, watch::Receiver<bool>) -> Fut,
) -> Result<()>
where
    Fut: Future<Output = Result<()>>,
{
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(config.listen)
            .await
            .with_context(|| format!("cannot listen on {}", config.listen))?;
        let addr = listener.local_addr()?;
        config.listen = addr;
        if config.dev_mode && config.tokens.is_empty() {
            if log_dev {
                tracing::warn!(
                    "DEVELOPMENT MODE: no tokens; every client is an admin and may move objects"
                );
            }
            eprintln!(
                "*** DEVELOPMENT MODE: no authentication. Do not expose {addr} to a network. ***"
            );
        }
        println!("{}", banner(addr, &config));
        let (stop_tx, stop_rx) = watch::channel(false);
        tokio::spawn(async move {
            wait_for_signal().await;
            tracing::info!("{stopping}");
            let _ = stop_tx.send(true);
        });
        run(config, listener, stop_rx).await
    })
}

/// Resolves on SIGINT or SIGTERM.
async fn wait_for_signal() {
    let ctrl_c = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = ctrl_c => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = ctrl_c.await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = ctrl_c.await;
    }
}
