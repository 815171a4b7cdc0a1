//! A `lightwire` child process: its address, readiness, its output, and
//! killing it on drop.

use std::io::{BufRead, BufReader, Read};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::{SCENE, http};

/// How long a child may take to print its address.
const STARTUP: Duration = Duration::from_secs(300);
/// How long [`Proc::ready`] and [`Proc::wait_ready`] wait for `/readyz`.
const READY: Duration = Duration::from_secs(60);

/// Lines a child wrote to one of its pipes.
type Lines = Arc<Mutex<Vec<String>>>;

/// A `lightwire serve` or `lightwire relay` child process, killed on drop.
///
/// Its stdout and its stderr are read by a thread each for the whole life
/// of the child, into [`Proc::stdout_lines`] and [`Proc::stderr_lines`]
/// (stderr is also echoed to the test's stderr, which the test harness
/// shows for a failed test): the child never blocks on a full pipe, and a
/// late print never meets a closed one.
pub struct Proc {
    pub child: Child,
    /// `HOST:PORT` it listens on.
    pub addr: String,
    stdout: Lines,
    stderr: Lines,
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Proc {
    /// Runs `command` with both pipes captured and waits for the line that
    /// names its address (`... listening on http://HOST:PORT ...`).
    pub(crate) fn start(mut command: Command) -> Proc {
        let program = command.get_program().to_string_lossy().into_owned();
        let mut child = command
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {program}: {e}"));
        let (stdout, stderr) = (Lines::default(), Lines::default());
        let (address, banner) = mpsc::channel();
        let out = child.stdout.take().expect("piped stdout");
        drain(out, stdout.clone(), move |line| {
            if let Some(addr) = banner_address(line) {
                let _ = address.send(addr);
            }
        });
        let err = child.stderr.take().expect("piped stderr");
        drain(err, stderr.clone(), |line| eprintln!("lightwire: {line}"));
        let mut proc = Proc {
            child,
            addr: String::new(),
            stdout,
            stderr,
        };
        match banner.recv_timeout(STARTUP) {
            Ok(addr) => proc.addr = addr,
            Err(_) => panic!(
                "{program} did not print its address (exited, or took over {STARTUP:?}); its stderr:\n{}",
                proc.stderr_lines(&[]).join("\n")
            ),
        }
        proc
    }

    /// `http://HOST:PORT{path}`.
    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }

    /// The WebSocket URL of [`SCENE`].
    pub fn ws_url(&self) -> String {
        format!("ws://{}/ws/scenes/{SCENE}", self.addr)
    }

    /// A blocking `GET path` without a token (see [`http::blocking::get`]).
    pub fn get(&self, path: &str) -> http::Response {
        http::blocking::get(&self.addr, path, None)
    }

    /// Polls `/readyz` until it answers 200 (the first lightmap is
    /// published; a relay holds a version), for at most a minute.
    pub async fn ready(&self) {
        let deadline = Instant::now() + READY;
        while http::get_with(&self.addr, "/readyz", &[])
            .await
            .map(|r| r.status)
            != Some(200)
        {
            assert!(
                Instant::now() < deadline,
                "lightwire at {} is not ready after {READY:?}",
                self.addr
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// [`Proc::ready`], blocking.
    pub fn wait_ready(&self) {
        let deadline = Instant::now() + READY;
        while http::blocking::get_with(&self.addr, "/readyz", &[]).map(|r| r.status) != Some(200) {
            assert!(
                Instant::now() < deadline,
                "lightwire at {} is not ready after {READY:?}",
                self.addr
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Lines of stderr so far that contain every one of `words`.
    pub fn stderr_lines(&self, words: &[&str]) -> Vec<String> {
        matching(&self.stderr, words)
    }

    /// Lines of stdout so far that contain every one of `words`.
    pub fn stdout_lines(&self, words: &[&str]) -> Vec<String> {
        matching(&self.stdout, words)
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

/// The address in a start-up banner, `... listening on http://ADDR ...`.
fn banner_address(line: &str) -> Option<String> {
    let rest = line.split("listening on http://").nth(1)?;
    Some(rest.split_whitespace().next()?.to_string())
}

/// Reads `pipe` line by line (lossily: a stray byte never stops it) until
/// it closes, handing each line to `each` and keeping it in `lines`.
fn drain(pipe: impl Read + Send + 'static, lines: Lines, each: impl Fn(&str) + Send + 'static) {
    std::thread::spawn(move || {
        let mut reader = BufReader::new(pipe);
        let mut buffer = Vec::new();
        loop {
            buffer.clear();
            match reader.read_until(b'\n', &mut buffer) {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
            let line = String::from_utf8_lossy(&buffer);
            let line = line.trim_end_matches(['\n', '\r']).to_string();
            each(&line);
            lines.lock().unwrap_or_else(|p| p.into_inner()).push(line);
        }
    });
}

fn matching(lines: &Lines, words: &[&str]) -> Vec<String> {
    lines
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .iter()
        .filter(|l| words.iter().all(|w| l.contains(w)))
        .cloned()
        .collect()
}
