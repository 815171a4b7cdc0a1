//! Where the `lightwire` binary is, and starting it.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use crate::process::Proc;
use crate::{DRIVER_TOKEN, SCENE, scene_path, tokens};

/// The `lightwire` binary a test runs.
///
/// Cargo hands a test the paths of its own package's binaries only, and at
/// compile time (`env!("CARGO_BIN_EXE_lightwire")`), so the kit cannot find
/// the binary on its own; the caller says where it is:
///
/// - the server's tests and benchmarks: [`lightwire!`](crate::lightwire)
///   (the path Cargo gave them, always fresh);
/// - tests of other packages (the client's): [`Lightwire::built`];
/// - the server's examples (Cargo gives them no path):
///   [`Lightwire::beside_current_exe`].
#[derive(Clone, Debug)]
pub struct Lightwire {
    path: PathBuf,
}

/// The `lightwire` binary of the package under test, from
/// `CARGO_BIN_EXE_lightwire` (so only in `lightwire-server`'s integration
/// tests and benchmarks).
#[macro_export]
macro_rules! lightwire {
    () => {
        $crate::Lightwire::at(env!("CARGO_BIN_EXE_lightwire"))
    };
}

impl Lightwire {
    /// The binary at `path`.
    pub fn at(path: impl Into<PathBuf>) -> Lightwire {
        Lightwire { path: path.into() }
    }

    /// The binary next to the running executable's profile directory
    /// (`target/<profile>/lightwire` for `target/<profile>/examples/x` or
    /// `target/<profile>/deps/x`), as built: nothing rebuilds it.
    pub fn beside_current_exe() -> Lightwire {
        Lightwire::at(profile_dir().join(binary_name()))
    }

    /// The binary, fresh, in the running test's target directory and
    /// profile.
    ///
    /// This runs `cargo test --workspace --no-run` with the test's profile
    /// and target directory: under `make test` (`cargo test --workspace`)
    /// that is a no-op check, because the outer run already built every
    /// binary with exactly these features; run alone, it builds what is
    /// missing or stale, and never leaves a stale binary. A plain `cargo
    /// build -p lightwire-server` would not do: dev-dependencies of other
    /// members change the unified features of shared crates (wgpu's among
    /// them), so it would compile a second copy of half the dependency
    /// graph. ARCHITECTURE.md explains the choice.
    pub fn built() -> Lightwire {
        static BINARY: OnceLock<PathBuf> = OnceLock::new();
        let path = BINARY.get_or_init(|| {
            let profile_dir = profile_dir();
            let target_dir = profile_dir.parent().expect("target/");
            let profile: &[&str] = match profile_dir.file_name().and_then(|p| p.to_str()) {
                Some("debug") => &[],
                Some("release") => &["--release"],
                Some(other) => &["--profile", other],
                None => panic!("unexpected profile directory {}", profile_dir.display()),
            };
            let cargo = std::env::var("CARGO").unwrap_or_else(|_| env!("CARGO").to_string());
            let status = Command::new(cargo)
                .args(["test", "--workspace", "--no-run", "--quiet"])
                .args(profile)
                .arg("--manifest-path")
                .arg(crate::repo().join("Cargo.toml"))
                .arg("--target-dir")
                .arg(target_dir)
                .status()
                .expect("cargo runs");
            assert!(status.success(), "building the workspace's binaries failed");
            let binary = profile_dir.join(binary_name());
            assert!(binary.exists(), "{} was not built", binary.display());
            binary
        });
        Lightwire::at(path.clone())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// `target/`, from the binary's path (`target/<profile>/lightwire`).
    pub fn target_dir(&self) -> PathBuf {
        self.path
            .parent()
            .and_then(Path::parent)
            .expect("the binary lives in target/<profile>/")
            .to_path_buf()
    }

    /// A command running the binary, for a run to completion
    /// (`validate`, `bake`, ...).
    pub fn command(&self) -> Command {
        Command::new(&self.path)
    }

    /// Starts `lightwire ARGS` with `RUST_LOG=warn` and then `env`, and
    /// waits for the line that names its address (see [`Proc`]).
    pub fn spawn<S: AsRef<OsStr>>(&self, args: &[S], env: &[(&str, String)]) -> Proc {
        let mut command = self.command();
        command
            .args(args)
            .env("RUST_LOG", "warn")
            .envs(env.iter().map(|(k, v)| (*k, v.as_str())));
        Proc::start(command)
    }

    /// `lightwire serve --dev --listen 127.0.0.1:0 FLAGS` (solver, density,
    /// scene, ...).
    pub fn serve_dev(&self, flags: &[&str]) -> Proc {
        let args: Vec<&str> = ["serve", "--dev", "--listen", "127.0.0.1:0"]
            .into_iter()
            .chain(flags.iter().copied())
            .collect();
        self.spawn(&args, &[])
    }

    /// [`Lightwire::serve_dev`] of the scene file at `scene`, `flags`
    /// first.
    pub fn serve_dev_on(&self, scene: impl AsRef<Path>, flags: &[&str]) -> Proc {
        let scene = scene.as_ref().to_str().expect("a UTF-8 scene path");
        let flags: Vec<&str> = flags.iter().copied().chain(["--scene", scene]).collect();
        self.serve_dev(&flags)
    }

    /// [`Lightwire::solver`]'s scene, density and solver in development
    /// mode (no tokens), on any port.
    pub fn dev_solver(&self) -> Proc {
        self.serve_dev_on(
            scene_path(&format!("{SCENE}.json")),
            &["--density-scale", "0.5", "--solver", "reference"],
        )
    }

    /// A solver on `listen` (port 0: any) with cornell-low at a coarse
    /// density on the CPU reference solver, which re-solves a move in well
    /// under a second, with the three tokens.
    pub fn solver(&self, listen: &str) -> Proc {
        self.solver_with(listen, "reference", &[])
    }

    /// [`Lightwire::solver`] with another solver and extra environment.
    pub fn solver_with(&self, listen: &str, solver: &str, env: &[(&str, String)]) -> Proc {
        self.solver_of(&format!("{SCENE}.json"), (listen, solver), env)
    }

    /// A solver of `scenes/<file>` on `listen` at half its density on
    /// `solver`, with the three tokens and extra environment `env`.
    pub fn solver_of(
        &self,
        file: &str,
        (listen, solver): (&str, &str),
        env: &[(&str, String)],
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
        .chain([scene_path(file).display().to_string()])
        .collect::<Vec<_>>();
        let env: Vec<(&str, String)> = [("LIGHTWIRE_TOKENS", tokens())]
            .into_iter()
            .chain(env.iter().cloned())
            .collect();
        self.spawn(&args, &env)
    }

    /// A relay of the solver at `upstream` (`HOST:PORT`), presenting the
    /// driver token, with the three tokens of its own.
    pub fn relay(&self, upstream: &str) -> Proc {
        self.relay_with(upstream, &[])
    }

    /// [`Lightwire::relay`] with extra environment.
    pub fn relay_with(&self, upstream: &str, env: &[(&str, String)]) -> Proc {
        self.relay_of(upstream, SCENE, env)
    }

    /// A relay of scene `scene` of the solver at `upstream` (`HOST:PORT`),
    /// presenting the driver token, with the three tokens of its own and
    /// extra environment `env`.
    pub fn relay_of(&self, upstream: &str, scene: &str, env: &[(&str, String)]) -> Proc {
        let args = [
            "relay",
            "--listen",
            "127.0.0.1:0",
            "--upstream",
            &format!("ws://{upstream}/ws/scenes/{scene}"),
        ];
        let env: Vec<(&str, String)> = [
            ("LIGHTWIRE_TOKENS", tokens()),
            ("LIGHTWIRE_UPSTREAM_TOKEN", DRIVER_TOKEN.to_string()),
        ]
        .into_iter()
        .chain(env.iter().cloned())
        .collect();
        self.spawn(&args, &env)
    }
}

fn binary_name() -> String {
    format!("lightwire{}", std::env::consts::EXE_SUFFIX)
}

/// `target/<profile>/`, from the running executable
/// (`target/<profile>/deps/<test>` or `target/<profile>/examples/<name>`).
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the running executable's path");
    let dir = exe.parent().expect("target/<profile>/...");
    match dir.file_name().and_then(|d| d.to_str()) {
        Some("deps" | "examples") => dir.parent().expect("target/<profile>/"),
        _ => dir,
    }
    .to_path_buf()
}
