//! Where to connect: a server address and a scene id, turned into the
//! WebSocket URL `ws://HOST:PORT/ws/scenes/{id}` that `lightwire serve`
//! serves.
//!
//! Users write addresses the way they see them: the dashboard's
//! `http://127.0.0.1:8080`, a bare `127.0.0.1:8080`, or the full WebSocket
//! URL from PROTOCOL.md. [`Endpoint::parse`] accepts all three, so the CLI
//! takes `URL [--scene ID]` and the library `connect(url, token, scene)`:
//!
//! | URL | scene |
//! | --- | --- |
//! | `http://host:port`, `ws://host:port`, `host:port` (path empty or `/`) | from the `scene` argument (required) |
//! | `ws://host:port/ws/scenes/ID` (or `http://…/ws/scenes/ID`) | `ID`; a `scene` argument must agree |
//!
//! TLS (`https://`, `wss://`) is not built in: terminate TLS in front of
//! the client or use a plain `ws://` address (keeps the client free of a
//! TLS stack; see README).

use std::fmt;

/// A parsed server address plus scene: everything needed to open the
/// WebSocket and to reach the REST API next to it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Endpoint {
    /// `host:port` (or `host`, meaning port 80).
    authority: String,
    /// The scene id, unescaped.
    scene: String,
}

/// Why an address could not be used. The message names the input.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("server address {url:?}: {reason}")]
pub struct EndpointError {
    /// The address as given.
    pub url: String,
    /// What is wrong with it.
    pub reason: String,
}

impl Endpoint {
    /// Parses `url` (see the module docs for the accepted forms) and picks
    /// the scene from its path or from `scene`.
    pub fn parse(url: &str, scene: Option<&str>) -> Result<Endpoint, EndpointError> {
        let fail = |reason: String| EndpointError {
            url: url.to_string(),
            reason,
        };
        let trimmed = url.trim();
        let rest = match trimmed.split_once("://") {
            Some((scheme, rest)) => match scheme.to_ascii_lowercase().as_str() {
                "http" | "ws" => rest,
                "https" | "wss" => {
                    return Err(fail(
                        "TLS is not built into lightwire-client; use a plain ws:// or http:// address (terminate TLS in a proxy in front of the client)".into(),
                    ));
                }
                other => {
                    return Err(fail(format!(
                        "unknown scheme {other:?}; use http://HOST:PORT or ws://HOST:PORT/ws/scenes/ID"
                    )));
                }
            },
            None => trimmed,
        };
        // Drop a query or fragment: tokens travel in Hello, not the URL.
        let rest = rest.split(['?', '#']).next().unwrap_or_default();
        let (authority, path) = match rest.find('/') {
            Some(i) => (&rest[..i], &rest[i..]),
            None => (rest, ""),
        };
        if authority.is_empty() {
            return Err(fail("no host; expected e.g. http://127.0.0.1:8080".into()));
        }
        if authority.contains('@') {
            return Err(fail(
                "user information in the address is not supported; pass the token with --token or LIGHTWIRE_TOKEN".into(),
            ));
        }
        if let Some((_, port)) = authority.rsplit_once(':') {
            // An IPv6 literal without a port ("[::1]") has its colons inside brackets.
            if !port.ends_with(']') && port.parse::<u16>().is_err() {
                return Err(fail(format!("port {port:?} is not a number 0-65535")));
            }
        }
        let path = path.trim_end_matches('/');
        let from_path = if path.is_empty() {
            None
        } else if let Some(id) = path.strip_prefix("/ws/scenes/") {
            if id.is_empty() || id.contains('/') {
                return Err(fail(format!(
                    "path {path:?} should be /ws/scenes/ID with one scene id"
                )));
            }
            Some(percent_decode(id).ok_or_else(|| {
                fail(format!(
                    "scene id {id:?} in the path is not valid percent-encoded UTF-8"
                ))
            })?)
        } else {
            return Err(fail(format!(
                "unexpected path {path:?}; give the server's base address (http://HOST:PORT) with a scene id, or ws://HOST:PORT/ws/scenes/ID"
            )));
        };
        let scene = match (from_path, scene) {
            (Some(p), Some(s)) if p != s => {
                return Err(fail(format!(
                    "the path names scene {p:?} but scene {s:?} was also asked for"
                )));
            }
            (Some(p), _) => p,
            (None, Some(s)) if !s.is_empty() => s.to_string(),
            (None, _) => {
                return Err(fail(
                    "no scene: pass --scene ID (GET /api/scenes lists them) or a URL ending in /ws/scenes/ID".into(),
                ));
            }
        };
        Ok(Endpoint {
            authority: authority.to_string(),
            scene,
        })
    }

    /// The scene id.
    pub fn scene(&self) -> &str {
        &self.scene
    }

    /// `host:port` as given.
    pub fn authority(&self) -> &str {
        &self.authority
    }

    /// The WebSocket URL: `ws://HOST:PORT/ws/scenes/{id}` (id percent-encoded).
    pub fn ws_url(&self) -> String {
        format!(
            "ws://{}/ws/scenes/{}",
            self.authority,
            percent_encode(&self.scene)
        )
    }

    /// The HTTP base of the same server, e.g. for `/api/scenes/{id}`.
    pub fn http_base(&self) -> String {
        format!("http://{}", self.authority)
    }
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.ws_url())
    }
}

/// Where to connect, with what token: the arguments every subcommand of
/// `lightwire-client` takes. See [`Endpoint::parse`] for the URL forms.
#[derive(clap::Args, Debug, Clone)]
pub struct ServerArgs {
    /// The server: its base address `http://HOST:PORT` (then --scene
    /// picks the scene) or the WebSocket URL `ws://HOST:PORT/ws/scenes/ID`.
    pub url: String,
    /// Scene id (`GET /api/scenes` lists them); not needed when the URL
    /// ends in /ws/scenes/ID.
    #[arg(long)]
    pub scene: Option<String>,
    /// Access token [env: LIGHTWIRE_TOKEN]: a viewer token watches and
    /// views, drivers need a driver or admin token; omit only for a `--dev`
    /// server.
    #[arg(long)]
    pub token: Option<String>,
}

impl ServerArgs {
    /// The parsed endpoint.
    pub fn endpoint(&self) -> Result<Endpoint, EndpointError> {
        Endpoint::parse(&self.url, self.scene.as_deref())
    }

    /// `--token`, else `LIGHTWIRE_TOKEN`, else none.
    pub fn token(&self) -> Option<String> {
        self.token
            .clone()
            .or_else(|| std::env::var("LIGHTWIRE_TOKEN").ok())
            .filter(|t| !t.is_empty())
    }

    /// The default [`Options`](crate::Options) with [`ServerArgs::token`],
    /// the client naming itself `lightwire-client/VERSION COMMAND` in its
    /// `Hello`.
    pub fn options(&self, command: &str) -> crate::Options {
        crate::Options {
            token: self.token(),
            client_name: format!("lightwire-client/{} {command}", env!("CARGO_PKG_VERSION")),
            ..crate::Options::default()
        }
    }
}

/// Percent-encodes everything but RFC 3986's unreserved characters, so
/// any scene name makes one path segment.
fn percent_encode(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'.' | b'_' | b'~') {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Decodes `%XX` escapes; `None` for a broken escape or invalid UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = std::str::from_utf8(bytes.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base_addresses_take_the_scene_argument() {
        for url in [
            "http://127.0.0.1:8080",
            "http://127.0.0.1:8080/",
            "ws://127.0.0.1:8080",
            "127.0.0.1:8080",
        ] {
            let e = Endpoint::parse(url, Some("cornell-low")).expect(url);
            assert_eq!(e.ws_url(), "ws://127.0.0.1:8080/ws/scenes/cornell-low");
            assert_eq!(e.http_base(), "http://127.0.0.1:8080");
        }
    }

    #[test]
    fn a_full_websocket_url_names_its_scene() {
        let e = Endpoint::parse("ws://h:1/ws/scenes/a%20b", None).expect("valid");
        assert_eq!(e.scene(), "a b");
        assert_eq!(e.ws_url(), "ws://h:1/ws/scenes/a%20b");
        Endpoint::parse("ws://h:1/ws/scenes/a%20b", Some("a b")).expect("agreeing scene");
    }

    #[test]
    fn bad_addresses_say_what_is_wrong() {
        let cases = [
            ("http://h:1", None, "no scene"),
            ("ws://h:1/ws/scenes/x", Some("y"), "also asked for"),
            ("https://h:1", Some("x"), "TLS"),
            ("ftp://h:1", Some("x"), "unknown scheme"),
            ("http://h:99999", Some("x"), "port"),
            ("http://h:1/api/scenes", Some("x"), "unexpected path"),
            ("http://", Some("x"), "no host"),
            ("ws://h:1/ws/scenes/%zz", None, "percent"),
        ];
        for (url, scene, needle) in cases {
            let err = Endpoint::parse(url, scene).expect_err(url).to_string();
            assert!(err.contains(needle), "{url}: {err}");
            assert!(err.contains(url), "the error names the input: {err}");
        }
    }
}
