//! `lightwire-client drive URL --object NAME --script FILE`: moves a
//! dynamic object along a script.
//!
//! The script is sampled `--rate` times per second on the wall clock and
//! each sample is sent with `Client::send_pose` (the newest pose wins if
//! the socket is slow). Once a second a line reports poses sent, the
//! transform-to-light latency of this driver's own poses (exact: the
//! client remembers when it sent each seq), and refusals. A looping
//! script runs until `--duration` or Ctrl-C; a finite one ends when it has
//! played out and its last pose has reached the light.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use hdrhistogram::Histogram;
use lightwire_client::script::Script;
use lightwire_client::{Client, ErrorCode, Event, Role};

use super::{ServerArgs, ms, parse_duration, parse_rate, pick_object};

/// Arguments of `drive`.
#[derive(clap::Args, Debug)]
pub struct DriveArgs {
    #[command(flatten)]
    pub server: ServerArgs,
    /// The dynamic object to move (default: the script's `object`, else
    /// the scene's only dynamic object).
    #[arg(long)]
    pub object: Option<String>,
    /// The transform script (see scenes/scripts/README.md).
    #[arg(long)]
    pub script: PathBuf,
    /// Poses per second.
    #[arg(long, value_parser = parse_rate, default_value = "30")]
    pub rate: f64,
    /// Stop after this long (default: a looping script runs until Ctrl-C,
    /// a finite one until it has played out).
    #[arg(long, value_parser = parse_duration)]
    pub duration: Option<Duration>,
}

/// Runs `drive`.
pub fn run(args: DriveArgs) -> Result<()> {
    // A bad script is refused before connecting.
    let script = Script::load(&args.script)?;
    super::runtime()?.block_on(drive(args, script))
}

async fn drive(args: DriveArgs, script: Script) -> Result<()> {
    let endpoint = args.server.endpoint()?;
    let options = args.server.options("drive");
    let mut client = Client::connect_with(endpoint.clone(), options).await?;
    if client.role() == Role::Viewer {
        bail!(
            "{endpoint}: the token grants the viewer role, which may not move objects; use a driver or admin token"
        );
    }
    let scene = client.scene();
    let object = pick_object(&scene, args.object.as_deref(), script.object.as_deref())?;
    let name = scene.objects[object as usize].name.clone();
    if let Some(warning) = script.leaves_the_room(&scene, object) {
        eprintln!("warning: {}: {warning}", args.script.display());
    }
    eprintln!(
        "driving \"{name}\" of scene \"{}\" at {} poses/s from {} ({})",
        scene.id,
        args.rate,
        args.script.display(),
        if script.looping { "looping" } else { "once" }
    );
    let mut latency = Histogram::<u64>::new_with_bounds(1, 60_000_000, 3)
        .context("creating the latency histogram")?;
    let started = Instant::now();
    let period = Duration::from_secs_f64(1.0 / args.rate);
    let mut poses = tokio::time::interval(period);
    poses.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut report = tokio::time::interval(Duration::from_secs(1));
    report.tick().await;
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    let mut last_seq = 0u64;
    let mut last_delivered = 0u64;
    let mut finished_at: Option<Instant> = None;
    let mut stale = 0u64;
    loop {
        tokio::select! {
            _ = &mut ctrl_c => break,
            _ = poses.tick(), if finished_at.is_none() => {
                let t = started.elapsed();
                let done = args.duration.is_some_and(|d| t >= d);
                let pose = script.pose_at(t.as_secs_f64());
                last_seq = client.send_pose(object, pose)?;
                if done || script.is_finished(t.as_secs_f64()) {
                    finished_at = Some(Instant::now());
                }
            }
            _ = report.tick() => {
                let c = client.counters();
                eprintln!(
                    "t {:.1} s | v{} | {} poses sent ({} coalesced) | latency p50 {:.1} ms p99 {:.1} ms max {:.1} ms (n={}) | stale {} rate-limited {}",
                    started.elapsed().as_secs_f64(),
                    client.version().unwrap_or(0),
                    c.poses_sent,
                    c.poses_coalesced,
                    ms(latency.value_at_quantile(0.5)),
                    ms(latency.value_at_quantile(0.99)),
                    ms(latency.max()),
                    latency.len(),
                    stale,
                    c.rate_limited,
                );
                if let Some(at) = finished_at {
                    if last_delivered >= last_seq || at.elapsed() > Duration::from_secs(10) {
                        break;
                    }
                }
            }
            event = client.next_event() => match event {
                Some(Event::Version(v)) => {
                    for d in v.delivered.iter().filter(|d| d.object == object) {
                        last_delivered = last_delivered.max(d.seq);
                        if let Some(l) = d.latency {
                            latency.saturating_record(l.as_micros() as u64);
                        }
                    }
                }
                Some(Event::ServerError { code: ErrorCode::StaleSeq, .. }) => stale += 1,
                Some(Event::ServerError { code, message }) => eprintln!("server error {code}: {message}"),
                Some(Event::Disconnected(e)) => eprintln!("disconnected: {e}"),
                Some(Event::Reconnecting { attempt, delay }) => {
                    eprintln!("reconnecting (attempt {attempt}) in {:.1} s", delay.as_secs_f64());
                }
                Some(Event::Error(e)) => eprintln!("error: {e}"),
                Some(Event::Closed(Some(e))) => bail!("{e}"),
                Some(Event::Closed(None)) | None => break,
                Some(_) => {}
            },
        }
    }
    let c = client.counters();
    eprintln!(
        "done: {} poses sent, {} reached the light; latency p50 {:.1} ms p95 {:.1} ms p99 {:.1} ms max {:.1} ms",
        c.poses_sent,
        latency.len(),
        ms(latency.value_at_quantile(0.5)),
        ms(latency.value_at_quantile(0.95)),
        ms(latency.value_at_quantile(0.99)),
        ms(latency.max()),
    );
    client.close().await;
    Ok(())
}
