//! A raw protocol peer for the tests over real sockets: it says `Hello`,
//! applies keyframes and deltas exactly as the protocol demands (a delta
//! only onto its exact base, panicking otherwise), and records what it
//! saw.

use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::lightmap::Lightmap;
use lightwire_protocol::{
    ClientMessage, ErrorCode, PROTOCOL_VERSION, Role, ServerMessage, decode_server, encode_client,
};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

pub type Ws = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// What [`Client::read_frame`] met.
pub enum Read {
    Frame,
    Timeout,
    Closed,
}

/// A protocol client that keeps the lightmap it reconstructs.
pub struct Client {
    pub ws: Ws,
    pub map: Option<Lightmap>,
    pub role: Option<Role>,
    pub versions: Vec<u64>,
    pub keyframes: usize,
    /// (version, arrived as a keyframe) per applied frame.
    pub applied: Vec<(u64, bool)>,
    pub errors: Vec<(ErrorCode, String)>,
    /// Latest transform seq per object reflected by the held version.
    pub reflected: std::collections::HashMap<u32, u64>,
}

impl Client {
    pub async fn connect(url: &str, token: &str) -> Client {
        let (ws, _) = tokio_tungstenite::connect_async(url)
            .await
            .expect("websocket connects");
        Self::hello(ws, token).await
    }

    /// A client on an open socket that has not said `Hello` yet.
    pub fn unhandshaken(ws: Ws) -> Client {
        Client {
            ws,
            map: None,
            role: None,
            versions: Vec::new(),
            keyframes: 0,
            applied: Vec::new(),
            errors: Vec::new(),
            reflected: Default::default(),
        }
    }

    pub async fn hello(mut ws: Ws, token: &str) -> Client {
        let hello = ClientMessage::Hello {
            protocol_version: PROTOCOL_VERSION,
            client: "test-peer".into(),
            token: Some(token.into()),
            capabilities: 0,
        };
        ws.send(Message::Binary(encode_client(&hello).into()))
            .await
            .expect("send hello");
        let mut client = Client::unhandshaken(ws);
        client.read_one(Duration::from_secs(10)).await;
        assert!(client.role.is_some(), "Welcome is the first frame");
        client
    }

    pub async fn send(&mut self, message: &ClientMessage) {
        self.ws
            .send(Message::Binary(encode_client(message).into()))
            .await
            .expect("send");
    }

    /// Reads and applies one frame; false on close or timeout.
    pub async fn read_one(&mut self, timeout: Duration) -> bool {
        matches!(self.read_frame(timeout).await, Read::Frame)
    }

    /// Reads and applies one frame, saying whether one came, the time ran
    /// out or the connection ended.
    pub async fn read_frame(&mut self, timeout: Duration) -> Read {
        let frame = match tokio::time::timeout(timeout, self.ws.next()).await {
            Ok(Some(Ok(Message::Binary(bytes)))) => bytes,
            Ok(Some(Ok(Message::Close(_)))) | Ok(None) => return Read::Closed,
            Err(_) => return Read::Timeout,
            Ok(Some(Ok(_))) => return Read::Frame,
            Ok(Some(Err(e))) => panic!("websocket error: {e}"),
        };
        match decode_server(&frame).expect("server frames decode") {
            ServerMessage::Welcome {
                role,
                scene,
                protocol_version,
                ..
            } => {
                assert_eq!(protocol_version, PROTOCOL_VERSION);
                self.role = Some(role);
                self.map = Some(Lightmap::for_scene(&scene).expect("valid scene info"));
            }
            ServerMessage::Keyframe(k) => {
                let map = self.map.as_mut().expect("Welcome came first");
                map.apply_keyframe(&k).expect("keyframes always apply");
                self.keyframes += 1;
                self.applied.push((k.version, true));
                self.reflected = k.reflected.iter().map(|r| (r.object, r.seq)).collect();
                self.versions.push(k.version);
            }
            ServerMessage::Delta(d) => {
                let map = self.map.as_mut().expect("Welcome came first");
                // The contract: a delta is only ever sent onto the exact
                // version the client holds.
                map.apply_delta(&d).unwrap_or_else(|e| {
                    panic!(
                        "delta {} -> {} onto {}: {e}",
                        d.base_version, d.version, map.version
                    )
                });
                self.versions.push(d.version);
                self.applied.push((d.version, false));
                for r in &d.reflected {
                    self.reflected.insert(r.object, r.seq);
                }
            }
            ServerMessage::Error { code, message } => self.errors.push((code, message)),
            ServerMessage::Stats(_) | ServerMessage::Pong { .. } => {}
        }
        Read::Frame
    }

    pub fn version(&self) -> u64 {
        self.map.as_ref().map_or(0, |m| m.version)
    }

    /// Reads until the client holds `version` (or fails after `limit`).
    pub async fn read_until_version(&mut self, version: u64, limit: Duration) {
        let deadline = Instant::now() + limit;
        while self.version() < version {
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(
                !left.is_zero(),
                "stuck at version {} waiting for {version}",
                self.version()
            );
            assert!(
                self.read_one(left).await,
                "connection ended at version {}",
                self.version()
            );
        }
        assert_eq!(
            self.version(),
            version,
            "overshot: the server published more than expected"
        );
    }
}
