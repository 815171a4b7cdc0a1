//! [`Client`]: the handle a game, a renderer or a load tester holds.
//!
//! `Client::connect` opens the WebSocket, completes the handshake and then
//! hands the socket to a background task (see [`crate::connection`]). The
//! handle and the task share the front lightmap, the scene, role and
//! capabilities, the outbox of poses and light states, the counters and
//! the send times ([`crate::shared`]).
//! Everything else the task reports goes through a bounded event channel;
//! when the application does not read it, events are dropped and counted
//! ([`Event::Lagged`]), never queued without bound.
//!
//! Dependencies run one way: this handle over the connection task, both
//! over the shared state, the [`Event`]s and the [`Options`].

use std::sync::Arc;
use std::time::Duration;

use lightwire_protocol::backoff::Backoff;
use lightwire_protocol::{CAP_LIGHTS, LightState, LightStatus, Pose, Role, SceneInfo, Stats};
use tokio::sync::{mpsc, watch};

use crate::buffer::{DoubleBuffer, Frame};
use crate::connection::{self, Task};
use crate::endpoint::Endpoint;
use crate::error::ClientError;
use crate::events::Event;
use crate::latency::LatencyBook;
use crate::options::Options;
use crate::shared::{Counters, Shared};

/// A connection to one scene of a `lightwire serve`; see the crate docs.
///
/// Dropping the handle stops the background task (the socket is closed
/// with a close frame); [`Client::close`] does the same and waits for it.
pub struct Client {
    shared: Arc<Shared>,
    events: mpsc::Receiver<Event>,
    shutdown: watch::Sender<bool>,
    task: Option<tokio::task::JoinHandle<()>>,
}

impl Client {
    /// Connects to scene `scene` of the server at `url` (see
    /// [`Endpoint::parse`] for the accepted forms) with `token`, and
    /// returns once the server's `Welcome` arrived. The first attempt's
    /// failure is returned; later disconnects reconnect by themselves.
    /// Must be called within a tokio runtime.
    pub async fn connect(
        url: &str,
        token: Option<&str>,
        scene: Option<&str>,
    ) -> Result<Client, ClientError> {
        let endpoint = Endpoint::parse(url, scene)?;
        let options = Options {
            token: token.map(str::to_string),
            ..Options::default()
        };
        Client::connect_with(endpoint, options).await
    }

    /// [`Client::connect`] with every setting.
    pub async fn connect_with(endpoint: Endpoint, options: Options) -> Result<Client, ClientError> {
        let url = endpoint.ws_url();
        let opened = connection::open(&url, &options).await?;
        let scene = Arc::new(opened.scene.clone());
        let buffer = DoubleBuffer::new(scene.clone()).map_err(|e| ClientError::Protocol {
            url: url.clone(),
            reason: format!("the Welcome's atlas is unusable: {e}"),
        })?;
        let shared = Arc::new(Shared::new(
            endpoint,
            scene,
            opened.role,
            opened.capabilities,
            options.latency.clone(),
            options.seqs.clone(),
        ));
        let (events_tx, events) = mpsc::channel(options.event_capacity.max(1));
        let (shutdown, shutdown_rx) = watch::channel(false);
        let task = Task {
            shared: shared.clone(),
            backoff: Backoff::new(options.backoff),
            options,
            buffer,
            events: events_tx,
            shutdown: shutdown_rx,
        };
        let handle = tokio::spawn(connection::run(task, opened));
        Ok(Client {
            shared,
            events,
            shutdown,
            task: Some(handle),
        })
    }

    /// Where this client connects.
    pub fn endpoint(&self) -> &Endpoint {
        &self.shared.endpoint
    }

    /// The scene as the latest `Welcome` described it: atlas layout,
    /// objects, materials and the quads with their atlas rectangles.
    pub fn scene(&self) -> Arc<SceneInfo> {
        self.shared.scene.borrow().clone()
    }

    /// The role the server granted.
    pub fn role(&self) -> Role {
        self.shared.role()
    }

    /// The latest `Welcome`'s capability bits (`lightwire_protocol::CAP_*`).
    pub fn capabilities(&self) -> u32 {
        self.shared.capabilities()
    }

    /// Whether the server follows `SetLight` (its `Welcome` offers
    /// `CAP_LIGHTS`: a `lightwire serve`, or a relay while its upstream
    /// does, which forwards `SetLight` upstream).
    pub fn follows_lights(&self) -> bool {
        self.capabilities() & CAP_LIGHTS != 0
    }

    /// The front buffer: the newest complete lightmap version, with the
    /// scene it belongs to (`None` until the first keyframe).
    pub fn frame(&self) -> Option<Arc<Frame>> {
        self.shared.frames.borrow().clone()
    }

    /// The front's version.
    pub fn version(&self) -> Option<u64> {
        self.shared.frames.borrow().as_ref().map(|f| f.version())
    }

    /// A receiver that wakes whenever a new version is in front (newest
    /// only: a slow reader skips versions, it never queues them).
    pub fn subscribe(&self) -> watch::Receiver<Option<Arc<Frame>>> {
        self.shared.frames.subscribe()
    }

    /// Waits until the front is at `version` or newer.
    pub async fn wait_for_version(
        &self,
        version: u64,
        timeout: Duration,
    ) -> Result<Arc<Frame>, ClientError> {
        let mut frames = self.subscribe();
        let wait = frames.wait_for(|f| f.as_ref().is_some_and(|f| f.version() >= version));
        match tokio::time::timeout(timeout, wait).await {
            Ok(Ok(frame)) => Ok(frame.clone().ok_or(ClientError::Closed)?),
            Ok(Err(_)) => Err(ClientError::Closed),
            Err(_) => Err(ClientError::Timeout {
                what: format!(
                    "{}: waiting for lightmap version {version} (holding {:?})",
                    self.shared.endpoint,
                    self.version()
                ),
                seconds: timeout.as_secs_f64(),
            }),
        }
    }

    /// The server's latest `Stats`.
    pub fn stats(&self) -> Option<Stats> {
        *self.shared.stats.borrow()
    }

    /// Counts since `connect`.
    pub fn counters(&self) -> Counters {
        self.shared.counters.snapshot()
    }

    /// The send-time book this client measures latency with.
    pub fn latency_book(&self) -> &Arc<LatencyBook> {
        &self.shared.latency
    }

    /// The index of the object called `name`.
    pub fn object_index(&self, name: &str) -> Option<u32> {
        let scene = self.scene();
        scene
            .objects
            .iter()
            .position(|o| o.name == name)
            .map(|i| i as u32)
    }

    /// Queues `pose` for dynamic object `object` and returns its seq. The
    /// newest pose per object wins: one not yet written to the socket is
    /// replaced (and counted in [`Counters::poses_coalesced`]). Checked
    /// here like the server would: the role, the object, the pose.
    pub fn send_pose(&self, object: u32, pose: Pose) -> Result<u64, ClientError> {
        let role = self.role();
        if role == Role::Viewer {
            return Err(ClientError::Forbidden { role });
        }
        let scene = self.scene();
        match scene.objects.get(object as usize) {
            None => {
                return Err(ClientError::UnknownObject {
                    object: object.to_string(),
                    reason: format!("scene \"{}\" has {} objects", scene.id, scene.objects.len()),
                });
            }
            Some(o) if !o.dynamic => {
                return Err(ClientError::UnknownObject {
                    object: format!("{object} (\"{}\")", o.name),
                    reason: format!("not a dynamic object of scene \"{}\"", scene.id),
                });
            }
            Some(_) => {}
        }
        pose.validate()
            .map_err(|reason| ClientError::InvalidPose { object, reason })?;
        if self.task.as_ref().is_none_or(|t| t.is_finished()) {
            return Err(ClientError::Closed);
        }
        Ok(self.shared.queue_pose(object, pose))
    }

    /// [`Client::send_pose`] by object name.
    pub fn send_pose_named(&self, name: &str, pose: Pose) -> Result<u64, ClientError> {
        let object = self
            .object_index(name)
            .ok_or_else(|| ClientError::UnknownObject {
                object: format!("{name:?}"),
                reason: format!("scene \"{}\" has no object by that name", self.scene().id),
            })?;
        self.send_pose(object, pose)
    }

    /// The index of the light called `name`.
    pub fn light_index(&self, name: &str) -> Option<u32> {
        self.scene()
            .lights
            .iter()
            .position(|l| l.name == name)
            .map(|i| i as u32)
    }

    /// The lights' states the front version was lit with, by light index
    /// ([`Frame::lights`]; empty before the first keyframe, and unless
    /// the client asked for them, [`Options::lights`]).
    pub fn lights(&self) -> std::collections::BTreeMap<u32, LightStatus> {
        self.frame().map(|f| f.lights.clone()).unwrap_or_default()
    }

    /// Queues `state`, the whole new state of light `light` (an index into
    /// `scene().lights`), and returns its seq. The newest state per light
    /// wins: one not yet written to the socket is replaced (and counted
    /// in [`Counters::lights_coalesced`]). The seq is newer, in
    /// serial-number order, than both the last one this client saw for
    /// the light in a `Lights` and its own last one (see
    /// [`Options::lights`]: a client that did not ask sees none, and its
    /// seqs are the clock's). Checked here like the server would: the
    /// role, that the server follows lights, the light, the state.
    pub fn send_light(&self, light: u32, state: LightState) -> Result<u64, ClientError> {
        let role = self.role();
        if role == Role::Viewer {
            return Err(ClientError::Forbidden { role });
        }
        if !self.follows_lights() {
            return Err(ClientError::NoLights {
                url: self.shared.endpoint.ws_url(),
            });
        }
        let scene = self.scene();
        let Some(info) = scene.lights.get(light as usize) else {
            return Err(ClientError::UnknownLight {
                light: light.to_string(),
                reason: format!(
                    "scene \"{}\" has {} lights; {}",
                    scene.id,
                    scene.lights.len(),
                    lightwire_protocol::script::light_names(&scene)
                ),
            });
        };
        state
            .validate()
            .map_err(|reason| ClientError::InvalidLight {
                light: format!("{light} ({:?})", info.name),
                reason,
            })?;
        if self.task.as_ref().is_none_or(|t| t.is_finished()) {
            return Err(ClientError::Closed);
        }
        Ok(self.shared.queue_light(light, state))
    }

    /// [`Client::send_light`] by light name; a name the scene does not have
    /// is refused with the scene's light names.
    pub fn send_light_named(&self, name: &str, state: LightState) -> Result<u64, ClientError> {
        let light = self.light_index(name).ok_or_else(|| {
            let scene = self.scene();
            ClientError::UnknownLight {
                light: format!("{name:?}"),
                reason: format!(
                    "scene \"{}\" has no light by that name; {}",
                    scene.id,
                    lightwire_protocol::script::light_names(&scene)
                ),
            }
        })?;
        self.send_light(light, state)
    }

    /// Waits until the front is a version lit with `SetLight` `seq` of
    /// `light`, or with a newer one (another driver's, or this client's
    /// next), and returns it. Needs [`Options::lights`]: without it
    /// frames carry no lights and this times out.
    pub async fn wait_for_light(
        &self,
        light: u32,
        seq: u64,
        timeout: Duration,
    ) -> Result<Arc<Frame>, ClientError> {
        let mut frames = self.subscribe();
        let shows = |f: &Option<Arc<Frame>>| {
            f.as_ref()
                .and_then(|f| f.lights.get(&light))
                .is_some_and(|l| l.seq == seq || lightwire_protocol::seq_is_newer(l.seq, seq))
        };
        match tokio::time::timeout(timeout, frames.wait_for(shows)).await {
            Ok(Ok(frame)) => Ok(frame.clone().ok_or(ClientError::Closed)?),
            Ok(Err(_)) => Err(ClientError::Closed),
            Err(_) => Err(ClientError::Timeout {
                what: format!(
                    "{}: waiting for a version lit with seq {seq} of light {light} (holding version {:?}, light state seq {:?})",
                    self.shared.endpoint,
                    self.version(),
                    self.frame()
                        .and_then(|f| f.lights.get(&light).map(|l| l.seq))
                ),
                seconds: timeout.as_secs_f64(),
            }),
        }
    }

    /// The next event; `None` once the task has ended and every event was
    /// read.
    pub async fn next_event(&mut self) -> Option<Event> {
        self.events.recv().await
    }

    /// An event if one is waiting.
    pub fn try_next_event(&mut self) -> Option<Event> {
        self.events.try_recv().ok()
    }

    /// Whether the background task still runs (it ends on close or a
    /// permanent error).
    pub fn is_running(&self) -> bool {
        self.task.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Closes the socket (with a close frame) and waits for the task.
    pub async fn close(mut self) {
        let _ = self.shutdown.send(true);
        if let Some(task) = self.task.take() {
            let _ = task.await;
        }
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        // The task sees this and closes the socket itself.
        let _ = self.shutdown.send(true);
    }
}
