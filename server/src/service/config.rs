//! Service configuration: a TOML file, overridden by environment
//! variables, overridden by command-line flags. `lightwire serve` and
//! `lightwire relay` read the same format (one file can configure both:
//! each ignores the other's keys), so that a deployment keeps one
//! ConfigMap and one token Secret.
//!
//! ```toml
//! listen = "127.0.0.1:8080"
//! scenes = ["scenes/cornell-low.json"]
//! solver = "progressive"             # or "reference"
//! redistribution = "cross"            # how the GPU solver follows moves:
//!                                     # full | incremental | cross
//! [scene_redistribution]              # per scene id, overrides the above
//! cornell-low = "incremental"
//! tick_hz = 60
//! budget_ms = 8.0
//! epsilon = 0.015625                  # error budget of the stream (PROTOCOL.md §5)
//! settle_ms = 500                     # idle time before waiting texels are sent
//! density_scale = 1.0
//! charts = "lightmap-uvs"             # a mesh's charts: triangles | pairs | parallelograms | lightmap-uvs | generated
//! dev_mode = false                    # no tokens: everyone is admin (loud)
//! allowed_origins = ["https://dash.example"]
//! max_message_bytes = 4096
//! transforms_per_second = 120
//! max_bad_frames = 20
//! socket_send_buffer = 262144         # SO_SNDBUF per connection, bytes
//! metrics = "open"                    # or "token": /metrics needs an admin token
//! # lightwire relay only:
//! upstreams = ["ws://solver-0:8080/ws/scenes/cornell-low"]
//! upstream_token = "d-secret"          # presented to the solver
//! [tokens]
//! viewer = ["v-secret"]
//! driver = ["d-secret"]
//! admin = ["a-secret"]
//! ```
//!
//! Environment: `LIGHTWIRE_LISTEN`, `LIGHTWIRE_DEV=1`,
//! `LIGHTWIRE_SEND_BUFFER=<bytes>`, `LIGHTWIRE_METRICS=open|token`,
//! `LIGHTWIRE_EPSILON=<fraction>`, `LIGHTWIRE_SETTLE_MS=<ms>`,
//! `LIGHTWIRE_TOKENS="viewer:abc,driver:def,admin:ghi"` (added to the
//! file's tokens), and for the relay `LIGHTWIRE_UPSTREAM=url,url` (replaces
//! the file's `upstreams`) and `LIGHTWIRE_UPSTREAM_TOKEN`.
//!
//! Access. With tokens configured, the REST routes (`/api/scenes`,
//! `/api/scenes/{id}`, the snapshots) need at least a viewer token, like
//! the WebSocket; `/healthz`, `/readyz` and the dashboard's files are open.
//! `metrics` decides `/metrics`:
//!
//! - `"open"` (the default): anyone who reaches the port may scrape it.
//!   Metrics are counters and timings (connections, frames, refusals,
//!   tick times per scene id), never lightmaps, scene geometry or tokens;
//!   and the scrape convention the deployment uses (`prometheus.io/*` pod
//!   annotations, `deploy/k8s/`) cannot present a token. Where the port
//!   is reachable from outside, route only `/`, `/dashboard/`, `/api/`
//!   and `/ws/` to it, or choose `"token"`.
//! - `"token"`: `/metrics` needs an admin token (`Authorization: Bearer`,
//!   or `?token=`), for a server whose port is public; give Prometheus
//!   that token (`authorization: credentials_file` in its scrape config).
//!   Admin rather than viewer because viewer tokens are handed to browsers.
//!
//! In development mode without tokens everything is open.
//!
//! Test only:
//! `LIGHTWIRE_TEST_FAIL_SOLVER=at_seq:S[,rebuild_at_seq:R][,rebuild_fails:K]`
//! makes each scene's solver fail once, the first time its tick loop takes
//! a transform with seq >= S (the GPU solver destroys its device, so the
//! failure goes through the same path as a lost device); with
//! `rebuild_at_seq`, the rebuild also waits (besides its backoff) until a
//! transform with seq >= R has been taken, so that a test can look at the
//! failed state for as long as it needs; with `rebuild_fails`, the first K
//! rebuild attempts fail (and back off) before one is let through. It exists for the tests of
//! failure handling (`server/tests/gpu_failure.rs`); it has no config-file
//! key or flag, is off unless the variable is set, and a malformed value
//! stops the server. Never set it in production.

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use serde::Deserialize;

/// Which solver a scene's tick loop runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum SolverChoice {
    /// GPU progressive refinement (thesis Alg. 4.2); moves are followed by
    /// the configured redistribution method.
    Progressive,
    /// The CPU reference solver, re-solved on moves (small scenes only).
    Reference,
}

/// Who may read `/metrics` (see the module doc).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MetricsAccess {
    /// Anyone who reaches the port.
    #[default]
    Open,
    /// Requests with an admin token.
    Token,
}

/// Tokens per role.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tokens {
    #[serde(default)]
    pub viewer: Vec<String>,
    #[serde(default)]
    pub driver: Vec<String>,
    #[serde(default)]
    pub admin: Vec<String>,
}

impl Tokens {
    pub fn is_empty(&self) -> bool {
        self.viewer.is_empty() && self.driver.is_empty() && self.admin.is_empty()
    }
}

/// The whole configuration of one `lightwire serve` process.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Address to listen on.
    pub listen: SocketAddr,
    /// Scene files to serve; each scene's `name` is its id.
    pub scenes: Vec<PathBuf>,
    /// Ticks per second of each scene's loop (a transform arriving between
    /// ticks starts the next one early, no sooner than a quarter period
    /// after the last).
    pub tick_hz: f64,
    /// Solver time per tick, milliseconds.
    pub budget_ms: f64,
    /// Multiplies every texel density (coarser or finer lightmaps).
    pub density_scale: f32,
    /// How a mesh's triangles get charts (`scene::Charts`).
    pub charts: lightwire_scene::Charts,
    /// Serve without tokens; every client is an admin. Loud on purpose.
    pub dev_mode: bool,
    /// Browser origins allowed to open WebSockets, besides the server's
    /// own (`http://<listen>`, `http://localhost:<port>`). Requests without
    /// an `Origin` header (non-browser clients) are not affected.
    pub allowed_origins: Vec<String>,
    /// Largest client frame accepted, bytes.
    pub max_message_bytes: usize,
    /// Sustained transforms per second per connection (burst: twice that).
    pub transforms_per_second: f64,
    /// Invalid frames a connection may send before it is closed.
    pub max_bad_frames: u32,
    /// Seconds a client has to send `Hello` after connecting.
    pub hello_timeout_secs: f64,
    /// The relative error budget of the lightmap stream (PROTOCOL.md §5,
    /// "The error budget"): a texel viewers hold may differ from the
    /// solver's by this fraction of its value before it is sent; 0 sends
    /// every change.
    pub epsilon: f32,
    /// Milliseconds the solver must have been idle, with no transform
    /// arriving, before the texels waiting within the budget are sent (one
    /// more version), so viewers hold the solver's lightmap exactly.
    pub settle_ms: f64,
    /// Solver per scene.
    pub solver: SolverChoice,
    /// How the GPU solver follows moved objects, for every scene not named
    /// in `scene_redistribution`.
    pub redistribution: lightwire_solve::gpu::Redistribution,
    /// Per scene id: how its moves are followed.
    pub scene_redistribution:
        std::collections::BTreeMap<String, lightwire_solve::gpu::Redistribution>,
    /// GPU adapter name substring (default: prefer a discrete GPU).
    pub adapter: Option<String>,
    /// Kernel send buffer per connection, bytes (SO_SNDBUF; 0 = OS default).
    pub socket_send_buffer: usize,
    /// Who may read `/metrics`.
    pub metrics: MetricsAccess,
    pub tokens: Tokens,
    /// `lightwire relay`: the solver scenes it relays, one WebSocket URL
    /// each (`ws://HOST:PORT/ws/scenes/ID`; `http://` means the same).
    pub upstreams: Vec<String>,
    /// `lightwire relay`: the token it presents to its solvers. A driver or
    /// admin token lets it forward its own drivers' transforms; with a
    /// viewer token the relay is read-only and refuses transforms.
    pub upstream_token: Option<String>,
    /// Test only (`LIGHTWIRE_TEST_FAIL_SOLVER`, see the module doc).
    /// Never read from the config file.
    #[serde(skip)]
    pub test_fail_solver: Option<FailSolverHook>,
}

/// Test only: when to fail each scene's solver (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FailSolverHook {
    /// Fail at the first transform with a seq of at least this.
    pub at_seq: u64,
    /// Rebuild only once a transform with a seq of at least this came.
    pub rebuild_at_seq: Option<u64>,
    /// Make this many rebuild attempts fail (to exercise the backoff).
    pub rebuild_fails: u32,
}

impl FailSolverHook {
    /// Parses `at_seq:S[,rebuild_at_seq:R][,rebuild_fails:K]`.
    pub fn parse(value: &str) -> Option<Self> {
        let mut hook = Self {
            at_seq: u64::MAX,
            rebuild_at_seq: None,
            rebuild_fails: 0,
        };
        let mut seen = [false; 3];
        for part in value.split(',') {
            let (key, n) = part.split_once(':')?;
            let n: u64 = n.parse().ok()?;
            let slot = match key {
                "at_seq" => {
                    hook.at_seq = n;
                    0
                }
                "rebuild_at_seq" => {
                    hook.rebuild_at_seq = Some(n);
                    1
                }
                "rebuild_fails" => {
                    hook.rebuild_fails = u32::try_from(n).ok()?;
                    2
                }
                _ => return None,
            };
            if std::mem::replace(&mut seen[slot], true) {
                return None;
            }
        }
        seen[0].then_some(hook)
    }
}

impl Default for Config {
    fn default() -> Self {
        Self {
            listen: SocketAddr::from(([127, 0, 0, 1], 8080)),
            scenes: Vec::new(),
            tick_hz: 60.0,
            budget_ms: 8.0,
            density_scale: 1.0,
            charts: lightwire_scene::Charts::default(),
            dev_mode: false,
            allowed_origins: Vec::new(),
            max_message_bytes: 4096,
            transforms_per_second: 120.0,
            max_bad_frames: 20,
            hello_timeout_secs: 5.0,
            // Measured (docs/benchmarks-history.md, "Bandwidth"): a 1.6% budget, about
            // Weber's fraction, brings a rotating box on cornell-large to
            // 3.5 KB per version.
            epsilon: 1.0 / 64.0,
            settle_ms: 500.0,
            socket_send_buffer: 256 * 1024,
            solver: SolverChoice::Progressive,
            redistribution: lightwire_solve::gpu::Redistribution::default(),
            scene_redistribution: Default::default(),
            adapter: None,
            metrics: MetricsAccess::Open,
            tokens: Tokens::default(),
            upstreams: Vec::new(),
            upstream_token: None,
            test_fail_solver: None,
        }
    }
}

/// `value`, the value of the variable `key`, parsed; the error says that
/// it is not `what`.
fn parsed<T>(key: &str, value: &str, what: &str) -> Result<T>
where
    T: std::str::FromStr,
    T::Err: std::error::Error + Send + Sync + 'static,
{
    value
        .parse()
        .with_context(|| format!("{key}={value:?} is not {what}"))
}

impl Config {
    /// Reads a TOML config file.
    pub fn from_file(path: &std::path::Path) -> Result<Config> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config file {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("invalid config file {}", path.display()))
    }

    /// Applies `LIGHTWIRE_*` environment variables from `vars`.
    pub fn apply_env(&mut self, vars: impl Iterator<Item = (String, String)>) -> Result<()> {
        for (key, value) in vars {
            match key.as_str() {
                "LIGHTWIRE_LISTEN" => {
                    self.listen = parsed(&key, &value, "an address like 127.0.0.1:8080")?
                }
                "LIGHTWIRE_SEND_BUFFER" => {
                    self.socket_send_buffer = parsed(&key, &value, "a byte count")?
                }
                "LIGHTWIRE_EPSILON" => {
                    self.epsilon = parsed(
                        &key,
                        &value,
                        "a number (the stream's relative error budget, e.g. 0.0039)",
                    )?
                }
                "LIGHTWIRE_SETTLE_MS" => {
                    self.settle_ms = parsed(&key, &value, "a number of milliseconds")?
                }
                "LIGHTWIRE_METRICS" => {
                    self.metrics = match value.as_str() {
                        "open" => MetricsAccess::Open,
                        "token" => MetricsAccess::Token,
                        other => bail!("LIGHTWIRE_METRICS={other:?}: use open or token"),
                    };
                }
                "LIGHTWIRE_TEST_FAIL_SOLVER" => {
                    let hook = FailSolverHook::parse(&value).with_context(|| {
                        format!(
                            "LIGHTWIRE_TEST_FAIL_SOLVER={value:?} must look like at_seq:SEQ[,rebuild_at_seq:SEQ][,rebuild_fails:N] (a test hook)"
                        )
                    })?;
                    self.test_fail_solver = Some(hook);
                }
                "LIGHTWIRE_DEV" => self.dev_mode = matches!(value.as_str(), "1" | "true" | "yes"),
                "LIGHTWIRE_UPSTREAM" => {
                    self.upstreams = value
                        .split(',')
                        .map(str::trim)
                        .filter(|u| !u.is_empty())
                        .map(str::to_string)
                        .collect();
                }
                "LIGHTWIRE_UPSTREAM_TOKEN" => {
                    self.upstream_token = Some(value).filter(|t| !t.is_empty());
                }
                "LIGHTWIRE_TOKENS" => {
                    for entry in value.split(',').filter(|e| !e.trim().is_empty()) {
                        let Some((role, token)) = entry.trim().split_once(':') else {
                            bail!("LIGHTWIRE_TOKENS entry {entry:?} must look like role:token");
                        };
                        let list = match role {
                            "viewer" => &mut self.tokens.viewer,
                            "driver" => &mut self.tokens.driver,
                            "admin" => &mut self.tokens.admin,
                            other => bail!(
                                "LIGHTWIRE_TOKENS: unknown role {other:?} (viewer, driver or admin)"
                            ),
                        };
                        list.push(token.to_string());
                    }
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// Checks a `lightwire serve` configuration: values that would
    /// otherwise fail later or silently.
    pub fn validate(&self) -> Result<()> {
        if self.scenes.is_empty() {
            bail!(
                "no scenes to serve: pass --scene FILE (repeatable) or set `scenes` in the config file"
            );
        }
        self.validate_sessions()
    }

    /// Checks a `lightwire relay` configuration (the upstream URLs
    /// themselves are parsed by the relay, which names the bad one).
    pub fn validate_relay(&self) -> Result<()> {
        if self.upstreams.is_empty() {
            bail!(
                "no upstreams to relay: pass --upstream ws://SOLVER:PORT/ws/scenes/ID (repeatable), set LIGHTWIRE_UPSTREAM or `upstreams` in the config file"
            );
        }
        self.validate_sessions()
    }

    /// Checks what both servers need: session limits and tokens.
    fn validate_sessions(&self) -> Result<()> {
        if !(self.tick_hz.is_finite() && self.tick_hz > 0.0 && self.tick_hz <= 1000.0) {
            bail!("tick_hz = {} must be in (0, 1000]", self.tick_hz);
        }
        if !(self.budget_ms.is_finite() && self.budget_ms > 0.0) {
            bail!("budget_ms = {} must be > 0", self.budget_ms);
        }
        if !(self.density_scale.is_finite() && self.density_scale > 0.0) {
            bail!("density_scale = {} must be > 0", self.density_scale);
        }
        if !(self.transforms_per_second.is_finite() && self.transforms_per_second > 0.0) {
            bail!(
                "transforms_per_second = {} must be > 0",
                self.transforms_per_second
            );
        }
        if self.max_message_bytes < 64 {
            bail!(
                "max_message_bytes = {} is too small for a Hello frame",
                self.max_message_bytes
            );
        }
        if !(self.epsilon.is_finite() && (0.0..1.0).contains(&self.epsilon)) {
            bail!(
                "epsilon = {} must be >= 0 and < 1 (a fraction of the texel's value)",
                self.epsilon
            );
        }
        if !(self.settle_ms.is_finite() && self.settle_ms >= 0.0) {
            bail!("settle_ms = {} must be >= 0", self.settle_ms);
        }
        if self.tokens.is_empty() && !self.dev_mode {
            bail!(
                "no tokens configured: set [tokens] in the config file or LIGHTWIRE_TOKENS=role:token,..., or pass --dev for an unauthenticated development server"
            );
        }
        Ok(())
    }

    /// Tick period.
    pub fn tick(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(1.0 / self.tick_hz)
    }

    /// How long the solver must be idle before waiting texels are sent.
    pub fn settle(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(self.settle_ms / 1000.0)
    }

    /// Solver budget per tick.
    pub fn budget(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(self.budget_ms / 1000.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `c` with the one environment variable `key` set to `value`.
    fn set(c: &mut Config, key: &str, value: &str) -> Result<()> {
        c.apply_env([(key.to_string(), value.to_string())].into_iter())
    }

    #[test]
    fn environment_tokens_are_parsed_and_bad_ones_rejected() {
        let mut c = Config::default();
        set(&mut c, "LIGHTWIRE_TOKENS", "viewer:a, driver:b,admin:c").expect("valid");
        assert_eq!(
            (
                c.tokens.viewer[0].as_str(),
                c.tokens.driver[0].as_str(),
                c.tokens.admin[0].as_str()
            ),
            ("a", "b", "c")
        );
        let err = set(&mut c, "LIGHTWIRE_TOKENS", "root:x").expect_err("unknown role");
        assert!(err.to_string().contains("unknown role"), "{err}");
    }

    #[test]
    fn the_test_failure_hook_parses_strictly() {
        let hook = |v: &str| FailSolverHook::parse(v);
        assert_eq!(
            hook("at_seq:5"),
            Some(FailSolverHook {
                at_seq: 5,
                rebuild_at_seq: None,
                rebuild_fails: 0,
            })
        );
        assert_eq!(
            hook("rebuild_fails:2,at_seq:5,rebuild_at_seq:9"),
            Some(FailSolverHook {
                at_seq: 5,
                rebuild_at_seq: Some(9),
                rebuild_fails: 2,
            })
        );
        for bad in [
            "",
            "5",
            "at_seq:",
            "at_seq:x",
            "at_seq:5,",
            "at_seq:5,x:1",
            "at_seq:1,at_seq:2",
            "rebuild_at_seq:9",
            "at_seq:1,rebuild_fails:-1",
        ] {
            assert_eq!(hook(bad), None, "{bad:?}");
        }
        let mut c = Config::default();
        assert!(c.test_fail_solver.is_none(), "off unless set");
        assert!(set(&mut c, "LIGHTWIRE_TEST_FAIL_SOLVER", "soon").is_err());
    }

    #[test]
    fn a_server_without_tokens_needs_dev_mode() {
        let mut c = Config {
            scenes: vec!["x.json".into()],
            ..Config::default()
        };
        assert!(
            c.validate()
                .expect_err("no tokens")
                .to_string()
                .contains("--dev")
        );
        c.dev_mode = true;
        c.validate().expect("dev mode is allowed without tokens");
    }

    #[test]
    fn metrics_access_is_open_by_default_and_set_by_file_or_environment() {
        assert_eq!(Config::default().metrics, MetricsAccess::Open);
        let c: Config = toml::from_str("metrics = \"token\"").expect("valid");
        assert_eq!(c.metrics, MetricsAccess::Token);
        assert!(toml::from_str::<Config>("metrics = \"public\"").is_err());
        let mut c = Config::default();
        set(&mut c, "LIGHTWIRE_METRICS", "token").expect("valid");
        assert_eq!(c.metrics, MetricsAccess::Token);
        let err = set(&mut c, "LIGHTWIRE_METRICS", "closed").expect_err("unknown value");
        assert!(err.to_string().contains("open or token"), "{err}");
    }

    #[test]
    fn config_files_reject_unknown_keys() {
        let err = toml::from_str::<Config>("listne = \"1.2.3.4:5\"").expect_err("typo");
        assert!(err.to_string().contains("listne"), "{err}");
    }

    #[test]
    fn charts_are_lightmap_uvs_by_default_and_set_by_name() {
        use lightwire_scene::Charts;
        assert_eq!(Config::default().charts, Charts::LightmapUvs);
        for (name, charts) in [
            ("triangles", Charts::Triangles),
            ("pairs", Charts::Pairs),
            ("parallelograms", Charts::Parallelograms),
            ("lightmap-uvs", Charts::LightmapUvs),
            ("generated", Charts::Generated),
            ("uvunwrap", Charts::Uvunwrap),
        ] {
            let c: Config = toml::from_str(&format!("charts = \"{name}\"")).expect(name);
            assert_eq!(c.charts, charts);
        }
        let err = toml::from_str::<Config>("charts = \"quads\"").expect_err("unknown");
        assert!(err.to_string().contains("quads"), "{err}");
    }
}
