//! A minimal HTTP/1.1 client over real sockets, without the client library:
//! one GET per fresh connection, with chosen request headers; async (for
//! tokio tests) and [`blocking`].

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// What a GET got back.
pub struct Response {
    pub status: u16,
    /// Names lowercased, in order.
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    /// The first header called `name` (lowercase).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    /// The body as JSON (panics, naming the body, if it is not).
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.text()))
    }

    /// The lightmap version a snapshot or `scene.glb` is of, from its
    /// `x-lightwire-version` header.
    pub fn version(&self) -> Option<u64> {
        self.header("x-lightwire-version")?.parse().ok()
    }

    /// The body as an OpenEXR image (a lightmap snapshot), in f32 RGB (so
    /// bit-exact with what a client decodes from the wire); panics if it is
    /// not one.
    pub fn exr(&self) -> image::Rgb32FImage {
        image::load_from_memory_with_format(&self.body, image::ImageFormat::OpenExr)
            .unwrap_or_else(|e| panic!("not an EXR ({e}): {} bytes", self.body.len()))
            .into_rgb32f()
    }

    /// The texels of [`Response::exr`], row by row.
    pub fn exr_rgb(&self) -> Vec<[f32; 3]> {
        self.exr().pixels().map(|p| p.0).collect()
    }
}

/// The request for `GET path` on `addr` with `Authorization: Bearer
/// <token>` (none if `token` is `None`) and `headers`.
fn request(addr: &str, path: &str, token: Option<&str>, headers: &[(&str, &str)]) -> String {
    let mut request = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n");
    if let Some(token) = token {
        request.push_str(&format!("Authorization: Bearer {token}\r\n"));
    }
    for (name, value) in headers {
        request.push_str(&format!("{name}: {value}\r\n"));
    }
    request.push_str("\r\n");
    request
}

/// A whole response as read until the server closed; `None` if it is not
/// HTTP.
fn parse(response: &[u8]) -> Option<Response> {
    let split = response.windows(4).position(|w| w == b"\r\n\r\n")?;
    let head = String::from_utf8_lossy(&response[..split]).into_owned();
    let mut lines = head.lines();
    let status = lines.next()?.split_whitespace().nth(1)?.parse().ok()?;
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    Some(Response {
        status,
        headers,
        body: response[split + 4..].to_vec(),
    })
}

/// The answer to `GET path`, which there must be.
fn answered(response: Option<Response>, addr: &str, path: &str) -> Response {
    response.unwrap_or_else(|| panic!("no HTTP answer from {addr} to GET {path}"))
}

/// Sends `request` on a fresh connection to `addr` and reads the answer
/// to the end; `None` if the connection fails or the answer is not HTTP.
async fn exchange(addr: &str, request: String) -> Option<Response> {
    let mut stream = TcpStream::connect(addr).await.ok()?;
    stream.write_all(request.as_bytes()).await.ok()?;
    let mut response = Vec::new();
    stream.read_to_end(&mut response).await.ok()?;
    parse(&response)
}

/// `GET path` on `addr` (`HOST:PORT`) with `headers`; `None` if the
/// connection fails or the answer is not HTTP.
pub async fn get_with(addr: &str, path: &str, headers: &[(&str, &str)]) -> Option<Response> {
    exchange(addr, request(addr, path, None, headers)).await
}

/// `GET path` with `Authorization: Bearer <token>` (none if `token` is
/// `None`); panics if the server does not answer.
pub async fn get(addr: &str, path: &str, token: Option<&str>) -> Response {
    let response = exchange(addr, request(addr, path, token, &[])).await;
    answered(response, addr, path)
}

/// [`get`] as a browser on the page `origin` (`scheme://host[:port]`)
/// sends it: with that `Origin` header.
pub async fn get_from(addr: &str, path: &str, token: Option<&str>, origin: &str) -> Response {
    let response = exchange(addr, request(addr, path, token, &[("Origin", origin)])).await;
    answered(response, addr, path)
}

/// The same GETs on the calling thread, for tests without a runtime.
pub mod blocking {
    use std::io::{Read, Write};
    use std::net::TcpStream;

    use super::{Response, answered, parse, request};

    /// [`super::exchange`], blocking.
    fn exchange(addr: &str, request: String) -> Option<Response> {
        let mut stream = TcpStream::connect(addr).ok()?;
        stream.write_all(request.as_bytes()).ok()?;
        let mut response = Vec::new();
        stream.read_to_end(&mut response).ok()?;
        parse(&response)
    }

    /// [`super::get_with`], blocking.
    pub fn get_with(addr: &str, path: &str, headers: &[(&str, &str)]) -> Option<Response> {
        exchange(addr, request(addr, path, None, headers))
    }

    /// [`super::get`], blocking.
    pub fn get(addr: &str, path: &str, token: Option<&str>) -> Response {
        answered(exchange(addr, request(addr, path, token, &[])), addr, path)
    }
}
