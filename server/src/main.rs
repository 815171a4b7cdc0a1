//! `lightwire`: the Lightwire server command.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};

use lightwire_server::atlas::Atlas;
use lightwire_server::bake::{self, BakeStats};
use lightwire_server::reference::{self, ReferenceSolver, SolveOptions};
use lightwire_server::scene::{LoadOptions, Scene};

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
    Bake {
        /// The scene file (JSON, see scenes/README.md).
        #[arg(long)]
        scene: PathBuf,
        /// Which solver computes the lightmap.
        #[arg(long, value_enum, default_value_t = SolverKind::Reference)]
        solver: SolverKind,
        /// Output directory (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Multiply every texel density of the scene by this factor.
        #[arg(long, default_value_t = 1.0)]
        density_scale: f32,
        /// Stop when one sweep adds less than this fraction of the emitted
        /// power.
        #[arg(long, default_value_t = 1e-4)]
        tolerance: f64,
    },
    /// Serve scenes over HTTP and WebSocket: live lightmaps, REST, metrics.
    Serve {
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
    },
    /// Check scene files and print what they contain.
    Validate {
        /// Scene files.
        #[arg(required = true)]
        scenes: Vec<PathBuf>,
        /// Multiply every texel density by this factor.
        #[arg(long, default_value_t = 1.0)]
        density_scale: f32,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum SolverKind {
    /// CPU: analytic form factors, ray-cast visibility, Jacobi iteration.
    Reference,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bake {
            scene,
            solver,
            out,
            density_scale,
            tolerance,
        } => bake_command(scene, solver, out, density_scale, tolerance),
        Command::Validate {
            scenes,
            density_scale,
        } => validate_command(&scenes, density_scale),
        Command::Serve {
            scenes,
            listen,
            config,
            dev,
            tick_hz,
            budget_ms,
            density_scale,
        } => serve_command(ServeFlags {
            scenes,
            listen,
            config,
            dev,
            tick_hz,
            budget_ms,
            density_scale,
        }),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn load(path: &Path, density_scale: f32) -> Result<(Scene, Atlas)> {
    let scene = Scene::load_with(path, LoadOptions { density_scale })?;
    let atlas =
        Atlas::build(&scene).map_err(|issue| anyhow::anyhow!("{}: {issue}", path.display()))?;
    Ok((scene, atlas))
}

fn validate_command(paths: &[PathBuf], density_scale: f32) -> Result<()> {
    let mut failed = 0;
    for path in paths {
        match load(path, density_scale) {
            Ok((scene, atlas)) => {
                let dynamic = atlas.dynamic_element_count(&scene);
                println!(
                    "{}: ok: scene \"{}\", {} surfaces, {} objects, atlas {}x{}, {} static + {} dynamic elements",
                    path.display(),
                    scene.name,
                    scene.patches.len(),
                    scene.objects.len(),
                    atlas.width,
                    atlas.height,
                    atlas.elements.len() - dynamic,
                    dynamic
                );
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                failed += 1;
            }
        }
    }
    if failed > 0 {
        anyhow::bail!("{failed} of {} scene files are invalid", paths.len());
    }
    Ok(())
}

/// Prints solver progress to stderr: every 10% of the form factors and
/// every tenth sweep.
struct StderrProgress {
    started: Instant,
    last_decile: AtomicUsize,
}

impl reference::Progress for StderrProgress {
    fn form_factors(&self, done: usize, total: usize) {
        let decile = done * 10 / total.max(1);
        if self.last_decile.fetch_max(decile, Ordering::Relaxed) < decile {
            eprintln!(
                "  form factors: {:3}% ({done}/{total} rows, {:.1} s)",
                decile * 10,
                self.started.elapsed().as_secs_f64()
            );
        }
    }
    fn iteration(&self, iteration: usize, residual: f64) {
        if iteration % 10 == 0 || iteration == 1 {
            eprintln!("  sweep {iteration}: residual {residual:.3e} of emitted power");
        }
    }
}

fn bake_command(
    path: PathBuf,
    solver: SolverKind,
    out: PathBuf,
    density_scale: f32,
    tolerance: f64,
) -> Result<()> {
    if !(tolerance > 0.0 && tolerance < 1.0) {
        anyhow::bail!("--tolerance {tolerance} must be between 0 and 1");
    }
    let started = Instant::now();
    let (scene, atlas) = load(&path, density_scale)?;
    let poses = scene.initial_poses();
    let dynamic = atlas.dynamic_element_count(&scene);
    eprintln!(
        "baking {} ({} elements, atlas {}x{})",
        scene.name,
        atlas.elements.len(),
        atlas.width,
        atlas.height
    );
    let (values, stats) = match solver {
        SolverKind::Reference => {
            let progress = StderrProgress {
                started,
                last_decile: AtomicUsize::new(0),
            };
            let solver = ReferenceSolver::new(&scene, &atlas, &poses, &progress)?;
            let options = SolveOptions {
                tolerance,
                ..SolveOptions::default()
            };
            let solution = solver.solve(options, &progress);
            let balance = solver.energy_balance(&solution);
            eprintln!(
                "  converged after {} sweeps (residual {:.2e})",
                solution.iterations, solution.residual_fraction
            );
            let stats = BakeStats {
                scene: scene.name.clone(),
                solver: "reference".into(),
                elements: atlas.elements.len(),
                static_elements: atlas.elements.len() - dynamic,
                dynamic_elements: dynamic,
                atlas_width: atlas.width,
                atlas_height: atlas.height,
                iterations: solution.iterations,
                residual_fraction: solution.residual_fraction,
                seconds: started.elapsed().as_secs_f64(),
                form_factor_seconds: solver.form_factor_seconds,
                solve_seconds: solution.seconds,
                emitted_power: balance.emitted.element_sum(),
                absorbed_power: balance.absorbed.element_sum(),
                escaped_power: balance.escaped.element_sum(),
            };
            (solution.radiosity, stats)
        }
    };
    bake::write_outputs(&out, &scene, &atlas, &poses, &values, &stats)
        .with_context(|| format!("writing bake of {}", path.display()))?;
    eprintln!(
        "wrote {}/lightmap.exr, lightmap.png, atlas.json, stats.json in {:.1} s",
        out.display(),
        stats.seconds
    );
    Ok(())
}

struct ServeFlags {
    scenes: Vec<PathBuf>,
    listen: Option<std::net::SocketAddr>,
    config: Option<PathBuf>,
    dev: bool,
    tick_hz: Option<f64>,
    budget_ms: Option<f64>,
    density_scale: Option<f32>,
}

fn serve_command(flags: ServeFlags) -> Result<()> {
    use lightwire_server::service::{self, Config};

    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    let mut config = match &flags.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    config.apply_env(std::env::vars())?;
    if !flags.scenes.is_empty() {
        config.scenes = flags.scenes;
    }
    if let Some(listen) = flags.listen {
        config.listen = listen;
    }
    config.dev_mode |= flags.dev;
    if let Some(v) = flags.tick_hz {
        config.tick_hz = v;
    }
    if let Some(v) = flags.budget_ms {
        config.budget_ms = v;
    }
    if let Some(v) = flags.density_scale {
        config.density_scale = v;
    }
    config.validate()?;
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
            tracing::warn!(
                "DEVELOPMENT MODE: no tokens; every client is an admin and may move objects"
            );
            eprintln!(
                "*** DEVELOPMENT MODE: no authentication. Do not expose {addr} to a network. ***"
            );
        }
        // The line tools and tests wait for: where to connect.
        println!("lightwire listening on http://{addr} (dashboard: http://{addr}/)");
        let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
        tokio::spawn(async move {
            wait_for_signal().await;
            tracing::info!("shutting down: finishing ticks, closing connections");
            let _ = stop_tx.send(true);
        });
        service::serve(config, listener, stop_rx).await
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
