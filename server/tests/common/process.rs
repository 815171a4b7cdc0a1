//! `lightwire serve` and `lightwire relay` as child processes, for the
//! tests over real sockets.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};

use super::scene_path;

pub const DRIVER_TOKEN: &str = "driver-token-0123";
pub const VIEWER_TOKEN: &str = "viewer-token-0123";
pub const ADMIN_TOKEN: &str = "admin-token-0123";
/// The scene [`Proc::solver`] serves.
pub const SCENE: &str = "cornell-low";

/// `LIGHTWIRE_TOKENS` for the three tokens above.
pub fn tokens() -> String {
    format!("driver:{DRIVER_TOKEN},viewer:{VIEWER_TOKEN},admin:{ADMIN_TOKEN}")
}

/// A `lightwire` child process, killed on drop.
pub struct Proc {
    pub child: Child,
    /// `HOST:PORT` it listens on.
    pub addr: String,
    /// Its stderr, line by line, when spawned with `capture_stderr` (also
    /// echoed to the test's stderr); empty otherwise.
    log: Arc<Mutex<Vec<String>>>,
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Proc {
    /// Runs `lightwire ARGS` with `RUST_LOG=warn` and `env`, and waits for
    /// the line that names its address (stdout keeps being drained, so the
    /// process never blocks on a full pipe).
    pub fn spawn(args: &[String], env: &[(&str, String)]) -> Proc {
        Self::spawn_with(args, env, false)
    }

    /// [`Proc::spawn`], optionally collecting stderr for [`Proc::log_lines`].
    pub fn spawn_with(args: &[String], env: &[(&str, String)], capture_stderr: bool) -> Proc {
        let mut child = Command::new(env!("CARGO_BIN_EXE_lightwire"))
            .args(args)
            .env("RUST_LOG", "warn")
            .envs(env.iter().map(|(k, v)| (*k, v.as_str())))
            .stdout(Stdio::piped())
            .stderr(if capture_stderr {
                Stdio::piped()
            } else {
                Stdio::inherit()
            })
            .spawn()
            .expect("lightwire starts");
        let log = Arc::new(Mutex::new(Vec::new()));
        if let Some(pipe) = child.stderr.take() {
            let lines = log.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(pipe).lines().map_while(Result::ok) {
                    eprintln!("lightwire: {line}");
                    lines.lock().unwrap_or_else(|p| p.into_inner()).push(line);
                }
            });
        }
        let stdout = child.stdout.take().expect("piped stdout");
        let mut lines = BufReader::new(stdout).lines();
        let addr = loop {
            let line = lines
                .next()
                .expect("lightwire prints its address before exiting")
                .expect("stdout is UTF-8");
            if let Some(rest) = line.split("listening on http://").nth(1) {
                break rest
                    .split_whitespace()
                    .next()
                    .expect("an address")
                    .to_string();
            }
        };
        std::thread::spawn(move || for _ in lines {});
        Proc { child, addr, log }
    }

    /// A solver on `listen` (port 0: any) with cornell-low at a coarse
    /// density on the CPU reference solver, which re-solves a move in well
    /// under a second, with the three tokens.
    pub fn solver(listen: &str) -> Proc {
        Self::solver_with(listen, "reference", &[])
    }

    /// [`Proc::solver`] with another solver and extra environment.
    pub fn solver_with(listen: &str, solver: &str, env: &[(&str, String)]) -> Proc {
        Self::solver_logged(listen, solver, env, false)
    }

    /// [`Proc::solver_with`], optionally collecting stderr.
    pub fn solver_logged(
        listen: &str,
        solver: &str,
        env: &[(&str, String)],
        capture_stderr: bool,
    ) -> Proc {
        let args = [
            "serve",
            "--listen",
            listen,
            "--density-scale",
            "0.5",
            "--solver",
            solver,
            "--scene",
        ]
        .map(String::from)
        .into_iter()
        .chain([scene_path("cornell-low.json").display().to_string()])
        .collect::<Vec<_>>();
        let env: Vec<(&str, String)> = [("LIGHTWIRE_TOKENS", tokens())]
            .into_iter()
            .chain(env.iter().cloned())
            .collect();
        Proc::spawn_with(&args, &env, capture_stderr)
    }

    /// Lines of stderr so far that contain every one of `words` (empty
    /// unless spawned with `capture_stderr`).
    pub fn log_lines(&self, words: &[&str]) -> Vec<String> {
        self.log
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .iter()
            .filter(|l| words.iter().all(|w| l.contains(w)))
            .cloned()
            .collect()
    }

    /// A relay of the solver at `upstream` (`HOST:PORT`), presenting the
    /// driver token, with the three tokens of its own.
    pub fn relay(upstream: &str) -> Proc {
        Self::relay_with(upstream, &[])
    }

    /// [`Proc::relay`] with extra environment.
    pub fn relay_with(upstream: &str, env: &[(&str, String)]) -> Proc {
        let args = [
            "relay",
            "--listen",
            "127.0.0.1:0",
            "--upstream",
            &format!("ws://{upstream}/ws/scenes/{SCENE}"),
        ]
        .map(String::from);
        let env: Vec<(&str, String)> = [
            ("LIGHTWIRE_TOKENS", tokens()),
            ("LIGHTWIRE_UPSTREAM_TOKEN", DRIVER_TOKEN.to_string()),
        ]
        .into_iter()
        .chain(env.iter().cloned())
        .collect();
        Proc::spawn(&args, &env)
    }

    /// `http://HOST:PORT{path}`.
    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }

    /// The WebSocket URL of [`SCENE`].
    pub fn ws_url(&self) -> String {
        format!("ws://{}/ws/scenes/{SCENE}", self.addr)
    }

    /// Kilobytes of resident memory of the process.
    pub fn rss_kib(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id()))
            .expect("/proc status");
        status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .expect("VmRSS")
    }
}
