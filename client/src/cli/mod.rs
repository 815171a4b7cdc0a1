//! What the subcommands share: the server arguments, duration parsing,
//! percentiles, the async runtime.

pub mod drive;
pub mod load;
pub mod watch;

use std::time::Duration;

use anyhow::{Context, Result, bail};
pub use lightwire_client::endpoint::ServerArgs;

/// Parses `20s`, `1.5m`, `500ms`, `2h` or a bare number of seconds.
pub fn parse_duration(text: &str) -> Result<Duration, String> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number
        .parse()
        .map_err(|_| format!("{text:?} is not a duration like 20s, 500ms, 2m"))?;
    let seconds = match unit.trim() {
        "" | "s" => value,
        "ms" => value / 1000.0,
        "m" | "min" => value * 60.0,
        "h" => value * 3600.0,
        other => {
            return Err(format!(
                "{text:?}: unknown unit {other:?} (use ms, s, m or h)"
            ));
        }
    };
    if !seconds.is_finite() || seconds > 1e7 {
        return Err(format!("{text:?} is too long"));
    }
    Ok(Duration::from_secs_f64(seconds))
}

/// A positive rate in Hz, at most 1000.
pub fn parse_rate(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of poses per second"))?;
    if !(v.is_finite() && v > 0.0 && v <= 1000.0) {
        return Err(format!("{v} must be in (0, 1000] poses per second"));
    }
    Ok(v)
}

/// A multi-threaded tokio runtime for one subcommand.
pub fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")
}

/// The index of the object to drive: `--object`, else the script's
/// `object`, else the scene's only dynamic object.
pub fn pick_object(
    scene: &lightwire_client::SceneInfo,
    flag: Option<&str>,
    script: Option<&str>,
) -> Result<u32> {
    let dynamic: Vec<&str> = scene
        .objects
        .iter()
        .filter(|o| o.dynamic)
        .map(|o| o.name.as_str())
        .collect();
    let name = match flag.or(script) {
        Some(n) => n,
        None => match dynamic.as_slice() {
            [only] => only,
            [] => bail!("scene \"{}\" has no dynamic object to drive", scene.id),
            many => bail!(
                "scene \"{}\" has several dynamic objects ({}); pick one with --object",
                scene.id,
                many.join(", ")
            ),
        },
    };
    let Some(index) = scene.objects.iter().position(|o| o.name == name) else {
        bail!(
            "scene \"{}\" has no object {name:?}; its dynamic objects: {}",
            scene.id,
            dynamic.join(", ")
        );
    };
    if !scene.objects[index].dynamic {
        bail!(
            "object {name:?} of scene \"{}\" is static; dynamic objects: {}",
            scene.id,
            dynamic.join(", ")
        );
    }
    Ok(index as u32)
}

/// Milliseconds with two decimals, from microseconds.
pub fn ms(us: u64) -> f64 {
    (us as f64 / 10.0).round() / 100.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_parse_with_units_and_refuse_nonsense() {
        assert_eq!(parse_duration("20s"), Ok(Duration::from_secs(20)));
        assert_eq!(parse_duration("20"), Ok(Duration::from_secs(20)));
        assert_eq!(parse_duration("250ms"), Ok(Duration::from_millis(250)));
        assert_eq!(parse_duration("1.5m"), Ok(Duration::from_secs(90)));
        for bad in ["", "x", "5 parsecs", "-3s", "1e400"] {
            assert!(parse_duration(bad).is_err(), "{bad:?} accepted");
        }
        assert!(parse_rate("30").is_ok());
        for bad in ["0", "-1", "nan", "1e9", "fast"] {
            assert!(parse_rate(bad).is_err(), "{bad:?} accepted");
        }
    }
}
