//! `lightwire-client drive`: moves a dynamic object along a script, plays
//! a script's light keys, or sets one light.
//!
//! **Script mode** (`--script FILE [--object NAME]`): the script is
//! sampled `--rate` times per second on the wall clock and each sample is
//! sent with `Client::send_pose` (the newest pose wins if the socket is
//! slow); a script with light keys also sends each light's sampled state
//! with `Client::send_light` whenever it differs from the last one sent
//! (fields the keys leave out come from the light's state in the first
//! `Lights`). Once a second a line reports poses and light states sent,
//! the latency of this driver's own poses and states to the first version
//! lit with them (exact: the client remembers when it sent each seq), and
//! refusals. A looping script runs until `--duration` or Ctrl-C; a finite
//! one ends when it has played out and its last pose and states have
//! reached the light.
//!
//! **Light mode** (`--light NAME` with any of `--on`/`--off`,
//! `--intensity`, `--color`, `--position`, `--direction`): learns the
//! light's current state from the server's first `Lights`, changes the
//! fields given, sends that one `SetLight`, waits until a `Lights` (a
//! version) shows its seq, an `Error` arrives or `--timeout` passes, and
//! prints what was set and the version that shows it.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use hdrhistogram::Histogram;
use lightwire_client::script::{Script, light_names};
use lightwire_client::{
    Client, ClientError, ErrorCode, Event, Frame, LightState, LightType, Options, Role, SceneInfo,
};

use super::{ServerArgs, ms, parse_duration, parse_rate, pick_object};

/// Arguments of `drive`.
#[derive(clap::Args, Debug)]
pub struct DriveArgs {
    #[command(flatten)]
    pub server: ServerArgs,
    /// The dynamic object to move (default: the script's `object`, else
    /// the scene's only dynamic object).
    #[arg(long, conflicts_with = "light")]
    pub object: Option<String>,
    /// The transform script (see scenes/scripts/README.md): an object's
    /// keyframes, light keys, or both.
    #[arg(long, required_unless_present = "light", conflicts_with = "light")]
    pub script: Option<PathBuf>,
    /// Poses (and light states) per second.
    #[arg(long, value_parser = parse_rate, default_value = "30", conflicts_with = "light")]
    pub rate: f64,
    /// Stop after this long (default: a looping script runs until Ctrl-C,
    /// a finite one until it has played out).
    #[arg(long, value_parser = parse_duration, conflicts_with = "light")]
    pub duration: Option<Duration>,
    #[command(flatten)]
    pub set: LightArgs,
}

/// `drive --light NAME ...`: one light's new state. Fields not given keep
/// the light's current state (the server's first `Lights`).
#[derive(clap::Args, Debug)]
pub struct LightArgs {
    /// Set this light (a name of the scene's lights) instead of running a
    /// script: send one SetLight, wait for a version lit with it, exit.
    #[arg(long, value_name = "NAME")]
    pub light: Option<String>,
    /// Switch the light on.
    #[arg(long, requires = "light", conflicts_with = "off")]
    pub on: bool,
    /// Switch the light off.
    #[arg(long, requires = "light")]
    pub off: bool,
    /// Radiant intensity, W/sr (point, spot), or irradiance, W/m²
    /// (directional), in [0, 1e6].
    #[arg(long, requires = "light", allow_negative_numbers = true)]
    pub intensity: Option<f32>,
    /// Linear RGB, each channel in [0, 1]: r,g,b.
    #[arg(long, requires = "light", value_parser = parse_triple, value_name = "R,G,B", allow_hyphen_values = true)]
    pub color: Option<[f32; 3]>,
    /// World-space position, metres (point and spot lights): x,y,z.
    #[arg(long, requires = "light", value_parser = parse_triple, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub position: Option<[f32; 3]>,
    /// Direction (a spot's axis, where a directional light's light
    /// travels), normalised: x,y,z.
    #[arg(long, requires = "light", value_parser = parse_triple, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub direction: Option<[f32; 3]>,
    /// Give up waiting for a version lit with the new state after this
    /// long.
    #[arg(long, requires = "light", value_parser = parse_duration, default_value = "60s")]
    pub timeout: Duration,
}

/// Three comma-separated finite numbers.
pub fn parse_triple(text: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let numbers: Vec<f32> = parts
        .iter()
        .filter_map(|p| p.parse::<f32>().ok())
        .filter(|v| v.is_finite())
        .collect();
    match numbers.as_slice() {
        [x, y, z] if parts.len() == 3 => Ok([*x, *y, *z]),
        _ => Err(format!(
            "{text:?} is not three finite numbers separated by commas, like 1,0.5,0.25"
        )),
    }
}

/// Runs `drive`.
pub fn run(args: DriveArgs) -> Result<()> {
    if let Some(light) = args.set.light.clone() {
        return super::runtime()?.block_on(set_light(&args, &light));
    }
    let Some(path) = args.script.clone() else {
        bail!("drive needs --script FILE, or --light NAME to set a light");
    };
    // A bad script is refused before connecting.
    let script = Script::load(&path)?;
    super::runtime()?.block_on(drive(args, path, script))
}

/// The flag of the field `LightState::validate`'s `reason` is about.
fn flag_of(reason: &str) -> &'static str {
    ["color", "intensity", "position", "direction"]
        .into_iter()
        .find(|f| reason.starts_with(f))
        .map_or("--light", |f| match f {
            "color" => "--color",
            "intensity" => "--intensity",
            "position" => "--position",
            _ => "--direction",
        })
}

/// `state`, made of the flags `set` (and the normalised `direction`) over
/// some other state, as `LightState::validate` judges it; a failure names
/// the flag and its value.
fn check(
    name: &str,
    set: &LightArgs,
    direction: Option<[f32; 3]>,
    state: &LightState,
) -> Result<()> {
    let Err(reason) = state.validate() else {
        return Ok(());
    };
    let flag = flag_of(reason);
    let given = match flag {
        "--color" => set.color.map(triple),
        "--intensity" => set.intensity.map(|i| i.to_string()),
        "--position" => set.position.map(triple),
        "--direction" => direction.map(triple),
        _ => None,
    };
    match given {
        Some(value) => bail!("light {name:?}: {flag} {value}: {reason}"),
        None => bail!(
            "light {name:?}: its current state is invalid ({reason}); give {flag} to replace it"
        ),
    }
}

/// `x,y,z`, as the flags take it.
fn triple(v: [f32; 3]) -> String {
    format!("{},{},{}", v[0], v[1], v[2])
}

/// The unit of a light's intensity.
fn intensity_unit(kind: LightType) -> &'static str {
    match kind {
        LightType::Directional => "W/m²",
        LightType::Point | LightType::Spot => "W/sr",
    }
}

/// A state in words: `on, intensity 4 W/sr, color [1, 0.5, 0.25], ...`.
pub fn describe(state: &LightState, kind: LightType) -> String {
    let v = |a: [f32; 3]| format!("[{}, {}, {}]", a[0], a[1], a[2]);
    format!(
        "{}, intensity {} {}, color {}, position {}, direction {}",
        if state.on { "on" } else { "off" },
        state.intensity,
        intensity_unit(kind),
        v(state.color),
        v(state.position),
        v(state.direction)
    )
}

/// The index of light `name` in `scene`, or an error listing its lights.
fn light_index(scene: &SceneInfo, name: &str) -> Result<u32> {
    match scene.lights.iter().position(|l| l.name == name) {
        Some(i) => Ok(i as u32),
        None => bail!(
            "scene \"{}\" has no light {name:?}; {}",
            scene.id,
            light_names(scene)
        ),
    }
}

/// Waits for the first lightmap, whose frame carries the first `Lights`.
async fn first_frame(client: &Client, timeout: Duration) -> Result<Arc<Frame>> {
    client
        .wait_for_version(0, timeout)
        .await
        .context("waiting for the first lightmap")
}

/// `drive --light`: see the module docs.
async fn set_light(args: &DriveArgs, name: &str) -> Result<()> {
    let set = &args.set;
    // What can be refused without the server is refused before connecting.
    let direction = match set.direction {
        None => None,
        Some(d) => {
            let length = d.iter().map(|v| v * v).sum::<f32>().sqrt();
            if !(length.is_finite() && length > 1e-6) {
                bail!("--direction {}: must not be zero", triple(d));
            }
            Some(d.map(|v| v / length))
        }
    };
    // `LightState::validate` checks each field on its own: the fields
    // given, on a state whose other fields are valid, fail as they would
    // on the light's.
    let neutral = LightState {
        on: true,
        color: [1.0; 3],
        intensity: 1.0,
        position: [0.0; 3],
        direction: [0.0, -1.0, 0.0],
    };
    check(
        name,
        set,
        direction,
        &LightState {
            color: set.color.unwrap_or(neutral.color),
            intensity: set.intensity.unwrap_or(neutral.intensity),
            position: set.position.unwrap_or(neutral.position),
            direction: direction.unwrap_or(neutral.direction),
            ..neutral
        },
    )?;
    let endpoint = args.server.endpoint()?;
    let options = Options {
        lights: true,
        ..args.server.options("drive")
    };
    let mut client = Client::connect_with(endpoint.clone(), options).await?;
    if client.role() == Role::Viewer {
        bail!(
            "{endpoint}: the token grants the viewer role, which may not set lights; use a driver or admin token"
        );
    }
    let scene = client.scene();
    let light = light_index(&scene, name)?;
    let kind = scene.lights[light as usize].kind;
    if !client.follows_lights() {
        bail!(
            "{}",
            ClientError::NoLights {
                url: endpoint.ws_url()
            }
        );
    }
    let frame = first_frame(&client, set.timeout).await?;
    let Some(current) = frame.lights.get(&light).map(|l| l.state) else {
        bail!(
            "{endpoint}: the server sent no Lights before its first lightmap, so light {name:?}'s current state is unknown"
        );
    };
    let state = LightState {
        on: if set.on {
            true
        } else if set.off {
            false
        } else {
            current.on
        },
        color: set.color.unwrap_or(current.color),
        intensity: set.intensity.unwrap_or(current.intensity),
        position: set.position.unwrap_or(current.position),
        direction: direction.unwrap_or(current.direction),
    };
    check(name, set, direction, &state)?;
    eprintln!("light {name:?} now: {}", describe(&current, kind));
    let mut frames = client.subscribe();
    let sent_at = Instant::now();
    let seq = client.send_light(light, state)?;
    let deadline = tokio::time::Instant::now() + set.timeout;
    let shown = loop {
        let front = frames.borrow_and_update().clone();
        if let Some(f) = front {
            if let Some(l) = f.lights.get(&light) {
                if l.seq == seq {
                    break f;
                }
                if lightwire_protocol::seq_is_newer(l.seq, seq) {
                    bail!(
                        "light {name:?}: another driver's state (seq {}) replaced seq {seq} before a version showed it; the light is now {}",
                        l.seq,
                        describe(&l.state, kind)
                    );
                }
            }
        }
        tokio::select! {
            changed = frames.changed() => {
                if changed.is_err() {
                    bail!("{endpoint}: the client closed while waiting for a version lit with seq {seq}");
                }
            }
            event = client.next_event() => match event {
                Some(Event::ServerError { code, message }) => {
                    let hint = match code {
                        ErrorCode::Forbidden => " (a driver or admin token is needed; on a relay, its upstream token must grant the driver role too)",
                        ErrorCode::StaleSeq => " (another driver set the light with a newer seq; try again)",
                        _ => "",
                    };
                    bail!("{endpoint}: the server refused SetLight seq {seq} for light {name:?}: {code}: {message}{hint}");
                }
                Some(Event::Disconnected(e)) => eprintln!("disconnected: {e}"),
                Some(Event::Reconnecting { attempt, delay }) => {
                    eprintln!("reconnecting (attempt {attempt}) in {:.1} s", delay.as_secs_f64());
                }
                Some(Event::Closed(Some(e))) => bail!("{e}"),
                Some(Event::Closed(None)) | None => {
                    bail!("{endpoint}: the connection closed while waiting for a version lit with seq {seq}");
                }
                Some(_) => {}
            },
            _ = tokio::time::sleep_until(deadline) => bail!(
                "{endpoint}: no version showed light {name:?}'s seq {seq} within {:.1} s (holding version {:?})",
                set.timeout.as_secs_f64(),
                client.version()
            ),
        }
    };
    println!(
        "light {name:?} of scene \"{}\": {} (seq {seq}), shown from version {} after {:.2} s",
        scene.id,
        describe(&state, kind),
        shown.version(),
        sent_at.elapsed().as_secs_f64()
    );
    client.close().await;
    Ok(())
}

/// One light track of a script, as driven.
struct Track {
    /// Index in `SceneInfo::lights`.
    light: u32,
    /// The light's state when the script started: what its keys leave out.
    base: LightState,
    /// The last state sent and its seq.
    last: Option<(LightState, u64)>,
}

async fn drive(args: DriveArgs, path: PathBuf, script: Script) -> Result<()> {
    let endpoint = args.server.endpoint()?;
    let options = Options {
        lights: !script.lights().is_empty(),
        ..args.server.options("drive")
    };
    let mut client = Client::connect_with(endpoint.clone(), options).await?;
    if client.role() == Role::Viewer {
        bail!(
            "{endpoint}: the token grants the viewer role, which may not move objects or set lights; use a driver or admin token"
        );
    }
    let scene = client.scene();
    let object = if script.has_poses() {
        let object = pick_object(&scene, args.object.as_deref(), script.object.as_deref())?;
        if let Some(warning) = script.leaves_the_room(&scene, object) {
            eprintln!("warning: {}: {warning}", path.display());
        }
        Some(object)
    } else {
        if args.object.is_some() {
            bail!(
                "--object: {} has no keyframes to move an object along",
                path.display()
            );
        }
        None
    };
    let mut tracks = Vec::new();
    if !script.lights().is_empty() {
        let indices = script.light_indices(&scene)?;
        if !client.follows_lights() {
            bail!(
                "{}: {}",
                path.display(),
                ClientError::NoLights {
                    url: endpoint.ws_url()
                }
            );
        }
        let frame = first_frame(&client, Duration::from_secs(60)).await?;
        for light in indices {
            // The first `Lights`; the Welcome's state (the lights as the
            // first lightmap was lit, without seqs) only from a server
            // that sent none.
            let base = frame
                .lights
                .get(&light)
                .map_or(scene.lights[light as usize].state, |l| l.state);
            tracks.push(Track {
                light,
                base,
                last: None,
            });
        }
    }
    let what: Vec<String> = object
        .map(|o| format!("\"{}\"", scene.objects[o as usize].name))
        .into_iter()
        .chain(
            script
                .lights()
                .iter()
                .map(|l| format!("light \"{}\"", l.name)),
        )
        .collect();
    eprintln!(
        "driving {} of scene \"{}\" at {} samples/s from {} ({})",
        what.join(", "),
        scene.id,
        args.rate,
        path.display(),
        if script.looping { "looping" } else { "once" }
    );
    let histogram = || {
        Histogram::<u64>::new_with_bounds(1, 60_000_000, 3).context("creating a latency histogram")
    };
    let mut latency = histogram()?;
    let mut light_latency = histogram()?;
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
                if let Some(object) = object {
                    let pose = script.pose_at(t.as_secs_f64());
                    last_seq = client.send_pose(object, pose)?;
                }
                for (i, track) in tracks.iter_mut().enumerate() {
                    let state = script.light_at(i, t.as_secs_f64(), &track.base);
                    if track.last.is_none_or(|(last, _)| last != state) {
                        let seq = client.send_light(track.light, state)?;
                        track.last = Some((state, seq));
                    }
                }
                if done || script.is_finished(t.as_secs_f64()) {
                    finished_at = Some(Instant::now());
                }
            }
            _ = report.tick() => {
                let c = client.counters();
                let mut line = vec![
                    format!("t {:.1} s", started.elapsed().as_secs_f64()),
                    format!("v{}", client.version().unwrap_or(0)),
                ];
                if object.is_some() {
                    line.push(format!(
                        "{} poses sent ({} coalesced), latency p50 {:.1} ms p99 {:.1} ms max {:.1} ms (n={})",
                        c.poses_sent,
                        c.poses_coalesced,
                        ms(latency.value_at_quantile(0.5)),
                        ms(latency.value_at_quantile(0.99)),
                        ms(latency.max()),
                        latency.len(),
                    ));
                }
                if !tracks.is_empty() {
                    line.push(format!(
                        "{} light states sent ({} coalesced), latency p50 {:.1} ms p99 {:.1} ms max {:.1} ms (n={})",
                        c.lights_sent,
                        c.lights_coalesced,
                        ms(light_latency.value_at_quantile(0.5)),
                        ms(light_latency.value_at_quantile(0.99)),
                        ms(light_latency.max()),
                        light_latency.len(),
                    ));
                }
                line.push(format!("stale {stale} rate-limited {}", c.rate_limited));
                eprintln!("{}", line.join(" | "));
                if let Some(at) = finished_at {
                    let poses_there = object.is_none() || last_delivered >= last_seq;
                    let lights_shown: BTreeMap<u32, u64> =
                        client.lights().into_iter().map(|(i, l)| (i, l.seq)).collect();
                    let lights_there = tracks.iter().all(|t| {
                        t.last.is_none_or(|(_, seq)| lights_shown.get(&t.light) == Some(&seq))
                    });
                    if (poses_there && lights_there) || at.elapsed() > Duration::from_secs(10) {
                        break;
                    }
                }
            }
            event = client.next_event() => match event {
                Some(Event::Version(v)) => {
                    for d in v.delivered.iter().filter(|d| Some(d.object) == object) {
                        last_delivered = last_delivered.max(d.seq);
                        if let Some(l) = d.latency {
                            latency.saturating_record(l.as_micros() as u64);
                        }
                    }
                    for d in &v.lights_delivered {
                        if let Some(l) = d.latency {
                            light_latency.saturating_record(l.as_micros() as u64);
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
    let mut done = Vec::new();
    if object.is_some() {
        done.push(format!(
            "{} poses sent, {} reached the light; latency p50 {:.1} ms p95 {:.1} ms p99 {:.1} ms max {:.1} ms",
            c.poses_sent,
            latency.len(),
            ms(latency.value_at_quantile(0.5)),
            ms(latency.value_at_quantile(0.95)),
            ms(latency.value_at_quantile(0.99)),
            ms(latency.max()),
        ));
    }
    if !tracks.is_empty() {
        done.push(format!(
            "{} light states sent, {} shown; latency p50 {:.1} ms p95 {:.1} ms p99 {:.1} ms max {:.1} ms",
            c.lights_sent,
            light_latency.len(),
            ms(light_latency.value_at_quantile(0.5)),
            ms(light_latency.value_at_quantile(0.95)),
            ms(light_latency.value_at_quantile(0.99)),
            ms(light_latency.max()),
        ));
    }
    eprintln!("done: {}", done.join("; "));
    client.close().await;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triples_parse_and_refuse_nonsense() {
        assert_eq!(parse_triple("1,0.5,0.25"), Ok([1.0, 0.5, 0.25]));
        assert_eq!(parse_triple(" 0, -1 ,0 "), Ok([0.0, -1.0, 0.0]));
        for bad in ["", "1,2", "1,2,3,4", "a,b,c", "1,,2", "1,2,nan", "1,inf,0"] {
            assert!(parse_triple(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn a_validation_reason_names_its_flag() {
        let state = LightState {
            on: true,
            color: [2.0, 0.0, 0.0],
            intensity: 1.0,
            position: [0.0; 3],
            direction: [0.0, -1.0, 0.0],
        };
        let reason = state.validate().expect_err("colour out of range");
        assert_eq!(flag_of(reason), "--color");
        assert_eq!(
            flag_of("intensity is out of range (0 to 1e6)"),
            "--intensity"
        );
        assert_eq!(flag_of("direction is not a unit vector"), "--direction");
        assert_eq!(flag_of("position is not finite"), "--position");
    }
}
