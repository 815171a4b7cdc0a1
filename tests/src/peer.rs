//! A raw protocol peer for the tests over real sockets: it says `Hello`,
//! applies keyframes and deltas exactly as the protocol demands (a delta
//! only onto its exact base, panicking otherwise), and records what it
//! saw.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::lightmap::Lightmap;
use lightwire_protocol::{
    ClientMessage, ErrorCode, LightState, LightStatus, ObjectPose, PROTOCOL_VERSION, Pose, Role,
    SceneInfo, ServerMessage, decode_server, encode_client,
};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

use crate::pose::transform;

pub type Ws = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// The name the kit's peers give in `Hello`.
const CLIENT: &str = "test-peer";

/// Opens a WebSocket to `url` and says `Hello` with `token`, without
/// reading anything; `None` if either fails.
pub async fn hello(url: &str, token: &str) -> Option<Ws> {
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.ok()?;
    ws.send(Message::Binary(encode_client(&hello_message(token)).into()))
        .await
        .ok()?;
    Some(ws)
}

fn hello_message(token: &str) -> ClientMessage {
    hello_with(token, 0)
}

fn hello_with(token: &str, capabilities: u32) -> ClientMessage {
    ClientMessage::Hello {
        protocol_version: PROTOCOL_VERSION,
        client: CLIENT.into(),
        token: Some(token.into()),
        capabilities,
    }
}

/// What [`Peer::read_frame`] met.
pub enum Read {
    Frame,
    Timeout,
    Closed,
}

/// A protocol client that keeps the lightmap it reconstructs.
pub struct Peer {
    pub ws: Ws,
    pub map: Option<Lightmap>,
    pub role: Option<Role>,
    /// The `Welcome`'s capability bits (0 before it).
    pub capabilities: u32,
    /// The scene the `Welcome` described.
    pub scene: Option<SceneInfo>,
    pub versions: Vec<u64>,
    pub keyframes: usize,
    /// (version, arrived as a keyframe) per applied frame.
    pub applied: Vec<(u64, bool)>,
    pub errors: Vec<(ErrorCode, String)>,
    /// Latest transform seq per object reflected by the held version.
    pub reflected: HashMap<u32, u64>,
    /// Whether the `Hello` asked for `Poses` (`HELLO_POSES`); a peer that
    /// did not panics on one (an older client must never see it).
    pub asked_poses: bool,
    /// Every `Poses` received: (version, poses).
    pub poses: Vec<(u64, Vec<ObjectPose>)>,
    /// The version of a `Poses` whose lightmap has not come yet: the very
    /// next frame must be it (PROTOCOL.md §3).
    poses_pending: Option<u64>,
    /// Whether the `Hello` asked for `Lights` (`HELLO_LIGHTS`); a peer that
    /// did not panics on one.
    pub asked_lights: bool,
    /// Every `Lights` received: (version, states).
    pub lights: Vec<(u64, Vec<LightStatus>)>,
}

impl Peer {
    /// Opens a WebSocket to `url`, says `Hello` with `token` and reads
    /// the `Welcome`.
    pub async fn connect(url: &str, token: &str) -> Peer {
        Peer::open(url).await.greet(hello_message(token)).await
    }

    /// A peer on a fresh socket to `url` that has not said `Hello` (it may
    /// say anything, or something else, first).
    pub async fn open(url: &str) -> Peer {
        let (ws, _) = tokio_tungstenite::connect_async(url)
            .await
            .expect("websocket connects");
        Peer::unhandshaken(ws)
    }

    /// A peer on an open socket that has not said `Hello` yet.
    pub fn unhandshaken(ws: Ws) -> Peer {
        Peer {
            ws,
            map: None,
            role: None,
            capabilities: 0,
            scene: None,
            versions: Vec::new(),
            keyframes: 0,
            applied: Vec::new(),
            errors: Vec::new(),
            reflected: Default::default(),
            asked_poses: false,
            poses: Vec::new(),
            poses_pending: None,
            asked_lights: false,
            lights: Vec::new(),
        }
    }

    /// [`Peer::connect`] with `HELLO_POSES` and `HELLO_LIGHTS` set: the
    /// server sends `Poses` and `Lights`.
    pub async fn connect_asking_lights(url: &str, token: &str) -> Peer {
        let mut peer = Peer::open(url).await;
        peer.asked_poses = true;
        peer.asked_lights = true;
        let both = lightwire_protocol::HELLO_POSES | lightwire_protocol::HELLO_LIGHTS;
        peer.greet(hello_with(token, both)).await
    }

    /// Sends a `SetLight` of `light` at `seq` to `state`.
    pub async fn set_light(&mut self, light: u32, seq: u64, state: LightState) {
        self.send(&ClientMessage::SetLight {
            light,
            seq,
            state,
            client_time_us: lightwire_protocol::unix_micros(),
        })
        .await;
    }

    /// [`Peer::connect`] with `HELLO_POSES` set: the server sends `Poses`.
    pub async fn connect_asking_poses(url: &str, token: &str) -> Peer {
        let mut peer = Peer::open(url).await;
        peer.asked_poses = true;
        peer.greet(hello_with(token, lightwire_protocol::HELLO_POSES))
            .await
    }

    /// Says `Hello` on an open socket and reads the `Welcome`.
    pub async fn hello(ws: Ws, token: &str) -> Peer {
        Peer::unhandshaken(ws).greet(hello_message(token)).await
    }

    /// Says `hello` and reads the `Welcome`, which must come first.
    async fn greet(mut self, hello: ClientMessage) -> Peer {
        self.send(&hello).await;
        self.read_one(Duration::from_secs(10)).await;
        assert!(self.role.is_some(), "Welcome is the first frame");
        self
    }

    pub async fn send(&mut self, message: &ClientMessage) {
        self.ws
            .send(Message::Binary(encode_client(message).into()))
            .await
            .expect("send");
    }

    /// Sends a transform of `object` at `seq` (see [`transform`]).
    pub async fn transform(&mut self, object: u32, seq: u64, pose: Pose) {
        self.send(&transform(object, seq, pose)).await;
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
        let message = decode_server(&frame).expect("server frames decode");
        // `Lights` of the same version may come between `Poses` and the
        // lightmap (the server sends Poses, then Lights, then the frame).
        let between = matches!((&message, self.poses_pending),
            (ServerMessage::Lights { version, .. }, Some(v)) if *version == v);
        if let Some(v) = self.poses_pending.take_if(|_| !between) {
            let lightmap = match &message {
                ServerMessage::Keyframe(k) => Some(k.version),
                ServerMessage::Delta(d) => Some(d.version),
                _ => None,
            };
            assert_eq!(
                lightmap,
                Some(v),
                "Poses of version {v} is followed by its lightmap, not {}",
                message.name()
            );
        }
        match message {
            ServerMessage::Welcome {
                role,
                scene,
                protocol_version,
                capabilities,
                ..
            } => {
                assert_eq!(protocol_version, PROTOCOL_VERSION);
                self.role = Some(role);
                self.capabilities = capabilities;
                self.map = Some(Lightmap::for_scene(&scene).expect("valid scene info"));
                self.scene = Some(scene);
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
            ServerMessage::Poses { version, poses } => {
                assert!(
                    self.asked_poses,
                    "Poses sent to a client whose Hello did not ask for them"
                );
                self.poses_pending = Some(version);
                self.poses.push((version, poses));
            }
            ServerMessage::Lights { version, lights } => {
                assert!(
                    self.asked_lights,
                    "Lights sent to a client whose Hello did not ask for them"
                );
                self.poses_pending = Some(version);
                self.lights.push((version, lights));
            }
        }
        Read::Frame
    }

    /// The version held (0: none yet).
    pub fn version(&self) -> u64 {
        self.map.as_ref().map_or(0, |m| m.version)
    }

    /// The texels held (panics before the `Welcome`).
    pub fn texels(&self) -> &[u8] {
        &self.map.as_ref().expect("welcomed").texels
    }

    /// Reads until the peer holds `version` (or fails after `limit`).
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

    /// Reads frames until `done` holds of the peer, for at most `limit`;
    /// panics, saying what it waited for, if the time runs out or the
    /// connection ends first.
    pub async fn read_until(&mut self, limit: Duration, what: &str, done: impl Fn(&Peer) -> bool) {
        let deadline = Instant::now() + limit;
        while !done(self) {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.read_frame(left).await {
                Read::Frame => {}
                Read::Timeout => panic!("timed out after {limit:?} waiting for {what}"),
                Read::Closed => panic!(
                    "the connection ended at version {} waiting for {what}",
                    self.version()
                ),
            }
        }
    }

    /// Reads frames for `time`; the connection must stay open.
    pub async fn pump(&mut self, time: Duration) {
        let until = Instant::now() + time;
        loop {
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return;
            }
            match self.read_frame(left).await {
                Read::Frame => {}
                Read::Timeout => return,
                Read::Closed => panic!(
                    "the server closed a connection at version {}",
                    self.version()
                ),
            }
        }
    }

    /// Reads frames until the peer holds at least `version`.
    pub async fn pump_until_version(&mut self, version: u64, limit: Duration) {
        let deadline = Instant::now() + limit;
        while self.version() < version {
            assert!(
                Instant::now() < deadline,
                "stuck at version {} waiting for {version}",
                self.version()
            );
            self.pump(Duration::from_millis(50)).await;
        }
    }

    /// Reads (recording errors) until the server closes; returns the close
    /// code, or `None` if the connection ended without a close frame.
    pub async fn read_to_close(&mut self, limit: Duration) -> Option<u16> {
        let deadline = Instant::now() + limit;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(!left.is_zero(), "the server never closed");
            match tokio::time::timeout(left, self.ws.next()).await {
                Ok(Some(Ok(Message::Close(frame)))) => return frame.map(|f| u16::from(f.code)),
                Ok(Some(Ok(Message::Binary(bytes)))) => {
                    if let Ok(ServerMessage::Error { code, message }) = decode_server(&bytes) {
                        self.errors.push((code, message));
                    }
                }
                Ok(Some(Ok(_))) => {}
                Ok(None) | Ok(Some(Err(_))) => return None,
                Err(_) => panic!("the server never closed"),
            }
        }
    }
}
