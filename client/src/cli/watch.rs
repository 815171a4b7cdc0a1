//! `lightwire-client watch URL`: one live status line.
//!
//! Every `--every` it prints the lightmap version, the solver's
//! convergence (unshot power over emitted power, from `Stats`), lightmap
//! versions and frames per second, received bytes per second, and the
//! transform-to-light latency of the moves it saw. A watcher sends no
//! poses, so latency is estimated from the seqs the frames echo under the
//! convention that drivers use Unix microseconds as seqs (this client's
//! `drive` and `load`, and the dashboard, do); it is shown only for seqs
//! that look like such timestamps, and is exact only if the clocks of
//! driver and watcher agree. On a terminal the line is redrawn in place;
//! otherwise one line per interval is printed (for logs).

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use lightwire_client::latency::{seq_clock_age, unix_micros};
use lightwire_client::{Client, Event};

use super::{ServerArgs, parse_duration};

/// Latencies kept per interval (the line shows their median and max).
const MAX_SAMPLES: usize = 10_000;

/// Arguments of `watch`.
#[derive(clap::Args, Debug)]
pub struct WatchArgs {
    #[command(flatten)]
    pub server: ServerArgs,
    /// How often to print the line (e.g. 1s, 500ms).
    #[arg(long, value_parser = parse_duration, default_value = "1s")]
    pub every: Duration,
    /// Stop after this long (default: until Ctrl-C).
    #[arg(long, value_parser = parse_duration)]
    pub duration: Option<Duration>,
}

/// Runs `watch`.
pub fn run(args: WatchArgs) -> Result<()> {
    super::runtime()?.block_on(watch(args))
}

async fn watch(args: WatchArgs) -> Result<()> {
    let endpoint = args.server.endpoint()?;
    let options = args.server.options("watch");
    let mut client = Client::connect_with(endpoint.clone(), options).await?;
    let scene = client.scene();
    eprintln!(
        "watching {endpoint}: scene \"{}\", atlas {}x{}, role {:?}",
        scene.id,
        scene.atlas_width,
        scene.atlas_height,
        client.role()
    );
    let tty = std::io::stdout().is_terminal();
    let started = Instant::now();
    let mut ticker = tokio::time::interval(args.every);
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    ticker.tick().await;
    let mut last = (Instant::now(), client.counters());
    let mut versions = 0u64;
    let mut latencies: Vec<Duration> = Vec::new();
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    loop {
        tokio::select! {
            _ = &mut ctrl_c => break,
            _ = ticker.tick() => {
                let now = Instant::now();
                let counters = client.counters();
                let secs = now.duration_since(last.0).as_secs_f64().max(1e-6);
                let frames = (counters.frames - last.1.frames) as f64 / secs;
                let bytes = (counters.bytes - last.1.bytes) as f64 / secs;
                let line = status_line(&client, versions as f64 / secs, frames, bytes, &mut latencies, counters);
                if tty {
                    print!("\r\x1b[2K{line}");
                } else {
                    println!("{line}");
                }
                let _ = std::io::stdout().flush();
                last = (now, counters);
                versions = 0;
                latencies.clear();
                if args.duration.is_some_and(|d| started.elapsed() >= d) {
                    break;
                }
            }
            event = client.next_event() => match event {
                Some(Event::Version(v)) => {
                    versions += 1;
                    let now_us = unix_micros();
                    for d in &v.delivered {
                        if let Some(age) = seq_clock_age(d.seq, now_us) {
                            if latencies.len() < MAX_SAMPLES {
                                latencies.push(age);
                            }
                        }
                    }
                }
                Some(Event::Disconnected(e)) => report(tty, &format!("disconnected: {e}")),
                Some(Event::Reconnecting { attempt, delay }) => {
                    report(tty, &format!("reconnecting (attempt {attempt}) in {:.1} s", delay.as_secs_f64()));
                }
                Some(Event::Connected { server, .. }) => report(tty, &format!("reconnected to {server}")),
                Some(Event::Error(e)) => report(tty, &format!("error: {e}")),
                Some(Event::ServerError { code, message }) => report(tty, &format!("server error {code}: {message}")),
                Some(Event::Closed(Some(e))) => {
                    if tty { println!(); }
                    bail!("{e}");
                }
                Some(Event::Closed(None)) | None => break,
                Some(_) => {}
            },
        }
    }
    if tty {
        println!();
    }
    client.close().await;
    Ok(())
}

fn report(tty: bool, message: &str) {
    if tty {
        println!();
    }
    eprintln!("{message}");
}

fn status_line(
    client: &Client,
    versions_per_s: f64,
    frames_per_s: f64,
    bytes_per_s: f64,
    latencies: &mut [Duration],
    counters: lightwire_client::Counters,
) -> String {
    let version = client
        .version()
        .map_or_else(|| "-".to_string(), |v| v.to_string());
    let (unshot, clients) = match client.stats() {
        Some(s) => (
            format!("{:.4}%", s.unshot_fraction * 100.0),
            s.clients.to_string(),
        ),
        None => ("-".into(), "-".into()),
    };
    latencies.sort_unstable();
    let latency = match (latencies.get(latencies.len() / 2), latencies.last()) {
        (Some(p50), Some(max)) => format!(
            "{:.1} ms p50, {:.1} ms max (n={})",
            p50.as_secs_f64() * 1e3,
            max.as_secs_f64() * 1e3,
            latencies.len()
        ),
        _ => "-".into(),
    };
    format!(
        "v{version} | unshot {unshot} | {versions_per_s:.1} versions/s | {frames_per_s:.1} frames/s | {:.1} KiB/s | latency {latency} | clients {clients} | resyncs {} reconnects {}",
        bytes_per_s / 1024.0,
        counters.resyncs,
        counters.reconnects
    )
}
