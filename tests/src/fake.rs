//! A scripted fake server on real sockets: the test plays the server's
//! side frame by frame (a relay's upstream solver, the client library's
//! server) and checks what its peer does.

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::{
    ClientMessage, Delta, Keyframe, PROTOCOL_VERSION, Role, SceneInfo, ServerMessage,
    decode_client, encode_server,
};
use tokio::net::{TcpListener, TcpStream};
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::Message;

/// How long [`FakeServer::accept`] waits for a connection.
const ACCEPT: Duration = Duration::from_secs(20);
/// How long [`recv`] waits for a message.
const RECV: Duration = Duration::from_secs(10);

/// One accepted connection, server side.
pub type Conn = WebSocketStream<TcpStream>;

/// The fake server's listening socket on loopback.
pub struct FakeServer {
    listener: TcpListener,
}

impl FakeServer {
    pub async fn bind() -> FakeServer {
        FakeServer {
            listener: TcpListener::bind("127.0.0.1:0").await.expect("bind"),
        }
    }

    /// `HOST:PORT` it listens on.
    pub fn addr(&self) -> String {
        self.listener.local_addr().expect("addr").to_string()
    }

    /// The WebSocket URL of scene `id` on it.
    pub fn ws_url(&self, id: &str) -> String {
        format!("ws://{}/ws/scenes/{id}", self.addr())
    }

    /// Accepts the next WebSocket and reads its `Hello`, which must come
    /// first and speak this protocol version; returns the connection and
    /// the token it presented.
    pub async fn accept(&self) -> (Conn, Option<String>) {
        let (conn, token, _) = self.accept_hello().await;
        (conn, token)
    }

    /// [`FakeServer::accept`], also returning the `Hello`'s capability bits.
    pub async fn accept_hello(&self) -> (Conn, Option<String>, u32) {
        let (tcp, _) = tokio::time::timeout(ACCEPT, self.listener.accept())
            .await
            .unwrap_or_else(|_| panic!("nothing connected within {ACCEPT:?}"))
            .expect("accept");
        let mut conn = tokio_tungstenite::accept_async(tcp).await.expect("upgrade");
        match recv(&mut conn).await {
            ClientMessage::Hello {
                protocol_version,
                token,
                capabilities,
                ..
            } => {
                assert_eq!(protocol_version, PROTOCOL_VERSION);
                (conn, token, capabilities)
            }
            other => panic!("expected Hello first, got {other:?}"),
        }
    }

    /// Accepts (whatever the token) and welcomes with `role` on `scene`.
    pub async fn welcome(&self, role: Role, scene: SceneInfo) -> Conn {
        let (mut conn, _) = self.accept().await;
        send(&mut conn, &welcome(role, scene)).await;
        conn
    }
}

/// The `Welcome` of the fake server (named "fake") granting `role`.
pub fn welcome(role: Role, scene: SceneInfo) -> ServerMessage {
    ServerMessage::Welcome {
        protocol_version: PROTOCOL_VERSION,
        server: "fake".into(),
        role,
        capabilities: 0,
        scene,
    }
}

pub async fn send(conn: &mut Conn, message: &ServerMessage) {
    raw(conn, Message::Binary(encode_server(message).into())).await;
}

/// Sends any frame, garbage included.
pub async fn raw(conn: &mut Conn, message: Message) {
    conn.send(message).await.expect("send to the peer");
}

pub async fn keyframe(conn: &mut Conn, k: Keyframe) {
    send(conn, &ServerMessage::Keyframe(k)).await;
}

pub async fn delta(conn: &mut Conn, d: Delta) {
    send(conn, &ServerMessage::Delta(d)).await;
}

/// The peer's next message (a binary frame; control frames skipped).
pub async fn recv(conn: &mut Conn) -> ClientMessage {
    loop {
        let frame = tokio::time::timeout(RECV, conn.next())
            .await
            .expect("the peer says something in time")
            .expect("the socket is open")
            .expect("a frame");
        if let Message::Binary(bytes) = frame {
            return decode_client(&bytes).expect("the peer's frames decode");
        }
    }
}
