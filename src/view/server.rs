//! The live view's HTTP server (docs/ARCHITECTURE.md, Live view): the page, the API for scripts
//! (`/camera`, `/settings`, `/frame.png`, `/stats`) and the page's WebSocket (`/ws`: JPEG frames
//! out, camera and settings in). axum on a small tokio runtime; it talks to the GPU thread only
//! through `Shared`.

use super::camera::CameraJson;
use super::state::{Shared, lock};
use crate::shading::{MAX_SPP, Mode};
use axum::Router;
use axum::body::Bytes;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{DefaultBodyLimit, Query, Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use std::sync::Arc;
use std::time::Duration;

/// The largest request body and WebSocket message taken; larger ones are refused.
pub const MESSAGE_LIMIT: usize = 16 * 1024;
/// How long `GET /frame.png` waits for its frame before answering 504.
pub const FRAME_WAIT: Duration = Duration::from_secs(60);

const PAGE: &str = include_str!("page.html");

type S = State<Arc<Shared>>;

pub fn router(shared: Arc<Shared>) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/camera", get(get_camera).post(post_camera))
        .route("/settings", get(get_settings).post(post_settings))
        .route("/frame.png", get(frame_png))
        .route("/stats", get(stats))
        .route("/ws", get(ws))
        .layer(axum::middleware::from_fn_with_state(shared.clone(), token))
        .layer(DefaultBodyLimit::max(MESSAGE_LIMIT))
        .with_state(shared)
}

/// Off loopback every request carries the session's token (`?token=`): 403 without it.
async fn token(State(s): S, req: Request, next: Next) -> Response {
    if let Some(want) = &s.token {
        let given = req
            .uri()
            .query()
            .unwrap_or("")
            .split('&')
            .find_map(|kv| kv.strip_prefix("token="));
        if given != Some(want.as_str()) {
            return (
                StatusCode::FORBIDDEN,
                "this view needs its token: open the URL dcrt printed (with ?token=...)\n",
            )
                .into_response();
        }
    }
    next.run(req).await
}

fn bad(message: impl std::fmt::Display) -> Response {
    (StatusCode::BAD_REQUEST, format!("{message}\n")).into_response()
}

fn json(v: serde_json::Value) -> Response {
    ([(header::CONTENT_TYPE, "application/json")], v.to_string()).into_response()
}

async fn page() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        PAGE,
    )
        .into_response()
}

async fn get_camera(State(s): S) -> Response {
    json(serde_json::json!(CameraJson::of(&s.wish().camera)))
}

async fn post_camera(State(s): S, body: Bytes) -> Response {
    match CameraJson::parse(&body) {
        Ok(camera) => {
            let seq = s.change(|w| {
                w.camera = camera;
                w.interactive = false;
            });
            json(serde_json::json!({ "seq": seq }))
        }
        Err(e) => bad(e),
    }
}

/// The page's and scripts' shading settings.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Settings {
    mode: Option<Mode>,
    spp: Option<u32>,
}

/// A message of the page's WebSocket: a camera (moving or at rest), or settings.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ClientMessage {
    camera: Option<CameraJson>,
    #[serde(default)]
    interactive: bool,
    settings: Option<Settings>,
}

/// Applies checked settings; the error names what is wrong.
fn apply_settings(s: &Shared, set: &Settings) -> Result<u64, String> {
    if let Some(spp) = set.spp
        && !(1..=MAX_SPP.min(s.max_spp)).contains(&spp)
    {
        return Err(format!(
            "spp must be 1..={}, got {spp}",
            MAX_SPP.min(s.max_spp)
        ));
    }
    Ok(s.change(|w| {
        w.mode = set.mode.unwrap_or(w.mode);
        w.spp = set.spp.unwrap_or(w.spp);
        w.interactive = false;
    }))
}

async fn get_settings(State(s): S) -> Response {
    let w = s.wish();
    json(serde_json::json!({
        "mode": w.mode,
        "spp": w.spp,
        "max_spp": MAX_SPP.min(s.max_spp),
        "modes": ["cast", "shadows", "ao", "path"],
        "home": CameraJson::of(&s.home),
    }))
}

async fn post_settings(State(s): S, body: Bytes) -> Response {
    let set: Settings = match serde_json::from_slice(&body) {
        Ok(v) => v,
        Err(e) => return bad(format!("settings: not the settings' JSON: {e}")),
    };
    match apply_settings(&s, &set) {
        Ok(seq) => json(serde_json::json!({ "seq": seq })),
        Err(e) => bad(e),
    }
}

#[derive(serde::Deserialize)]
struct After {
    #[serde(default)]
    after: u64,
}

/// The first finished frame (full size, every sample) of wish `seq >= after`, as PNG.
async fn frame_png(State(s): S, Query(q): Query<After>) -> Response {
    let mut rx = s.still.subscribe();
    let wait = async {
        loop {
            if let Some(f) = rx.borrow_and_update().as_ref()
                && f.seq >= q.after
            {
                return Some(f.clone());
            }
            if rx.changed().await.is_err() {
                return None;
            }
        }
    };
    let frame = match tokio::time::timeout(FRAME_WAIT, wait).await {
        Ok(Some(f)) => f,
        Ok(None) => {
            return (StatusCode::SERVICE_UNAVAILABLE, "the view is ending\n").into_response();
        }
        Err(_) => {
            return (
                StatusCode::GATEWAY_TIMEOUT,
                format!(
                    "no finished frame of seq {} or later within {} s\n",
                    q.after,
                    FRAME_WAIT.as_secs()
                ),
            )
                .into_response();
        }
    };
    let seq = frame.seq;
    let png = tokio::task::spawn_blocking(move || {
        let mut out = std::io::Cursor::new(Vec::new());
        frame
            .image
            .write_to(&mut out, image::ImageFormat::Png)
            .map(|_| out.into_inner())
    })
    .await;
    match png {
        Ok(Ok(bytes)) => (
            [
                (header::CONTENT_TYPE, "image/png".to_string()),
                (
                    header::HeaderName::from_static("x-dcrt-seq"),
                    seq.to_string(),
                ),
            ],
            bytes,
        )
            .into_response(),
        Ok(Err(e)) => (StatusCode::INTERNAL_SERVER_ERROR, format!("PNG: {e}\n")).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, format!("PNG: {e}\n")).into_response(),
    }
}

async fn stats(State(s): S) -> Response {
    json(lock(&s.stats).clone())
}

async fn ws(State(s): S, upgrade: WebSocketUpgrade) -> Response {
    upgrade
        .max_message_size(MESSAGE_LIMIT)
        .max_frame_size(MESSAGE_LIMIT)
        .on_upgrade(move |socket| client(socket, s))
}

/// One page: the newest frame whenever there is one (a frame the client had no time for is
/// replaced, never queued), its messages applied; a malformed one is answered, not fatal.
async fn client(mut socket: WebSocket, s: Arc<Shared>) {
    let mut frames = s.live.subscribe();
    frames.mark_changed();
    loop {
        tokio::select! {
            changed = frames.changed() => {
                if changed.is_err() {
                    break;
                }
                let Some(f) = frames.borrow_and_update().clone() else { continue };
                let info = Message::Text(f.info.to_string().into());
                if socket.send(info).await.is_err()
                    || socket.send(Message::Binary(Bytes::from(f.jpeg.clone()))).await.is_err()
                {
                    break;
                }
            }
            m = socket.recv() => match m {
                Some(Ok(Message::Text(t))) => {
                    if let Err(e) = on_message(&s, t.as_bytes()) {
                        let reply = serde_json::json!({ "error": e }).to_string();
                        if socket.send(Message::Text(reply.into())).await.is_err() {
                            break;
                        }
                    }
                }
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                Some(Ok(_)) => {}
            },
        }
    }
}

fn on_message(s: &Shared, text: &[u8]) -> Result<u64, String> {
    let m: ClientMessage =
        serde_json::from_slice(text).map_err(|e| format!("not a view message: {e}"))?;
    if let Some(set) = &m.settings {
        apply_settings(s, set)?;
    }
    match m.camera {
        Some(c) => {
            let camera = c.camera().map_err(|e| e.to_string())?;
            Ok(s.change(|w| {
                w.camera = camera;
                w.interactive = m.interactive;
            }))
        }
        None => Ok(s.wish().seq),
    }
}
