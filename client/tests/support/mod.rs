//! What the client's end-to-end tests share: the `lightwire` server binary
//! and a `lightwire serve --dev` child process to run the client against.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// The repository root.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The `lightwire` server binary, fresh, next to ours.
///
/// Cargo hands a test the paths of its own package's binaries only
/// (`CARGO_BIN_EXE_lightwire-client` here), so this runs `cargo test
/// --workspace --no-run` with our profile and target directory: under
/// `make test` (`cargo test --workspace`) that is a no-op check, because
/// the outer run already built every binary with exactly these features;
/// run alone, it builds what is missing or stale, and never leaves a stale
/// binary. A plain `cargo build -p lightwire-server` would not do:
/// dev-dependencies of other members change the unified features of
/// shared crates (wgpu's among them), so it would compile a second copy of
/// half the dependency graph. ARCHITECTURE.md explains the choice.
pub fn lightwire_binary() -> &'static Path {
    static BINARY: OnceLock<PathBuf> = OnceLock::new();
    BINARY.get_or_init(|| {
        let ours = Path::new(env!("CARGO_BIN_EXE_lightwire-client"));
        let profile_dir = ours.parent().expect("target/<profile>/");
        let target_dir = profile_dir.parent().expect("target/");
        let profile: &[&str] = match profile_dir.file_name().and_then(|p| p.to_str()) {
            Some("debug") => &[],
            Some("release") => &["--release"],
            Some(other) => &["--profile", other],
            None => panic!("unexpected binary path {}", ours.display()),
        };
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| env!("CARGO").to_string());
        let status = Command::new(cargo)
            .args(["test", "--workspace", "--no-run", "--quiet"])
            .args(profile)
            .arg("--manifest-path")
            .arg(repo().join("Cargo.toml"))
            .arg("--target-dir")
            .arg(target_dir)
            .status()
            .expect("cargo runs");
        assert!(status.success(), "building the workspace's binaries failed");
        let binary = profile_dir.join(format!("lightwire{}", std::env::consts::EXE_SUFFIX));
        assert!(binary.exists(), "{} was not built", binary.display());
        binary
    })
}

/// A `lightwire serve --dev --listen 127.0.0.1:0` child process, killed on
/// drop.
pub struct Server {
    child: Child,
    addr: String,
}

/// An HTTP response: status, headers (lower-case names), body.
pub struct Response {
    pub status: u16,
    // Each test crate compiles this module on its own; load.rs reads no
    // headers.
    #[allow(dead_code)]
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Server {
    /// Starts the server with `args` after `serve --dev --listen
    /// 127.0.0.1:0` (solver, density, scene, ...) and waits until
    /// `/readyz` answers 200 (at most 60 s).
    pub fn start(args: &[&str]) -> Server {
        let mut child = Command::new(lightwire_binary())
            .args(["serve", "--dev", "--listen", "127.0.0.1:0"])
            .args(args)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("lightwire starts");
        let stdout = child.stdout.take().expect("piped stdout");
        let mut lines = BufReader::new(stdout).lines();
        let addr = loop {
            let line = lines
                .next()
                .expect("the server prints its address before exiting")
                .expect("stdout is UTF-8");
            if let Some(rest) = line.strip_prefix("lightwire listening on http://") {
                break rest
                    .split_whitespace()
                    .next()
                    .expect("an address")
                    .to_string();
            }
        };
        // Keep draining stdout so the server never blocks on a full pipe.
        std::thread::spawn(move || for _ in lines {});
        let server = Server { child, addr };
        let deadline = Instant::now() + Duration::from_secs(60);
        while server.get("/readyz").status != 200 {
            assert!(
                Instant::now() < deadline,
                "the server is not ready after 60 s"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        server
    }

    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// `host:port` it listens on.
    // load.rs uses only `url`.
    #[allow(dead_code)]
    pub fn addr(&self) -> &str {
        &self.addr
    }

    /// A minimal blocking HTTP/1.1 GET, without the client library.
    pub fn get(&self, path: &str) -> Response {
        let mut stream = TcpStream::connect(&self.addr).expect("connect");
        write!(
            stream,
            "GET {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            self.addr
        )
        .expect("send");
        let mut response = Vec::new();
        stream.read_to_end(&mut response).expect("read");
        let split = response
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .expect("end of headers");
        let head = String::from_utf8_lossy(&response[..split]).into_owned();
        let mut lines = head.lines();
        let status = lines
            .next()
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|c| c.parse().ok())
            .expect("status line");
        let headers = lines
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
            .collect();
        Response {
            status,
            headers,
            body: response[split + 4..].to_vec(),
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
