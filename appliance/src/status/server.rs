//! The read-only HTTP/1 server behind the status page (hyper): GET/HEAD of `/`,
//! `/status.json` and `/metrics` from the latest published [`Snapshot`]; nothing changes state.
//! Bounded so that a misbehaving client cannot hurt the event loop it shares a thread with.

use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use http_body_util::Full;
use hyper::body::Bytes;
use hyper::header::{self, HeaderValue};
use hyper::server::conn::http1;
use hyper::service::service_fn;
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use thiserror::Error;
use tokio::net::TcpListener;
use tokio::sync::{Semaphore, watch};

use super::snapshot::Snapshot;
use super::{html, metrics};

#[derive(Debug, Error)]
pub enum StatusError {
    #[error("status page: cannot listen on {addr}: {source}")]
    Bind { addr: SocketAddr, source: std::io::Error },
}

/// How much one client may take.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Connections served at once; more wait in the kernel's accept queue.
    pub max_connections: usize,
    /// From connecting (or the previous response) to the end of the request head.
    pub header_read_timeout: Duration,
    /// A connection's whole life, slow readers of the response included.
    pub connection_timeout: Duration,
    /// The request head's size (request line and headers); larger: 431 and closed.
    pub max_header_bytes: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_connections: 16,
            header_read_timeout: Duration::from_secs(5),
            connection_timeout: Duration::from_secs(20),
            max_header_bytes: 16 * 1024,
        }
    }
}

/// Binds the status page's listener (separate from [`serve`] so a taken port is reported
/// at start, and tests can bind port 0 and read the address back).
pub async fn bind(addr: SocketAddr) -> Result<TcpListener, StatusError> {
    TcpListener::bind(addr).await.map_err(|source| StatusError::Bind { addr, source })
}

/// Serves the latest snapshot in `snapshots` on `listener` until the task is aborted. Meant
/// to be `tokio::spawn`ed on the appliance's runtime; each connection is its own task.
pub async fn serve(listener: TcpListener, snapshots: watch::Receiver<Arc<Snapshot>>, limits: Limits) {
    let permits = Arc::new(Semaphore::new(limits.max_connections.max(1)));
    let mut http = http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout)
        // One request per connection: nothing idles between the page's reloads.
        .keep_alive(false)
        .max_buf_size(limits.max_header_bytes.max(8192))
        .max_header_size(limits.max_header_bytes);
    loop {
        let Ok(permit) = permits.clone().acquire_owned().await else { return };
        let stream = match listener.accept().await {
            Ok((stream, _peer)) => stream,
            Err(e) => {
                // Out of descriptors and the like: wait instead of spinning on the error.
                tracing::warn!("status page: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(200)).await;
                continue;
            }
        };
        let rx = snapshots.clone();
        let http = http.clone();
        tokio::spawn(async move {
            let _permit = permit;
            let service = service_fn(move |req: Request<hyper::body::Incoming>| {
                // Clone the Arc and release the lock at once: the event loop's send never waits.
                let snap = rx.borrow().clone();
                async move { Ok::<_, Infallible>(respond(req.method(), req.uri().path(), &snap)) }
            });
            let conn = http.serve_connection(TokioIo::new(stream), service);
            match tokio::time::timeout(limits.connection_timeout, conn).await {
                Ok(Ok(())) => {}
                Ok(Err(e)) => tracing::debug!("status page: connection: {e}"),
                Err(_) => tracing::debug!("status page: connection timed out"),
            }
        });
    }
}

/// The response to `method path` (the whole routing: pure, so tests need no socket).
pub fn respond(method: &Method, path: &str, snap: &Snapshot) -> Response<Full<Bytes>> {
    if method != Method::GET && method != Method::HEAD {
        let mut r = text(StatusCode::METHOD_NOT_ALLOWED, "read-only: GET or HEAD\n".into());
        r.headers_mut().insert(header::ALLOW, HeaderValue::from_static("GET, HEAD"));
        return r;
    }
    match path {
        "/" => with_type(StatusCode::OK, "text/html; charset=utf-8", html::render(snap)),
        "/status.json" => match serde_json::to_string_pretty(snap) {
            Ok(json) => with_type(StatusCode::OK, "application/json", json + "\n"),
            Err(e) => text(StatusCode::INTERNAL_SERVER_ERROR, format!("cannot encode the status: {e}\n")),
        },
        "/metrics" => with_type(StatusCode::OK, metrics::CONTENT_TYPE, metrics::render(snap)),
        _ => text(StatusCode::NOT_FOUND, "not found: try /, /status.json or /metrics\n".into()),
    }
}

fn text(status: StatusCode, body: String) -> Response<Full<Bytes>> {
    with_type(status, "text/plain; charset=utf-8", body)
}

fn with_type(status: StatusCode, content_type: &'static str, body: String) -> Response<Full<Bytes>> {
    let mut r = Response::new(Full::new(Bytes::from(body)));
    *r.status_mut() = status;
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    // Even if escaping failed somewhere, nothing on the page could run or load.
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static("default-src 'none'; style-src 'unsafe-inline'; frame-ancestors 'none'"),
    );
    r
}

#[cfg(test)]
mod tests {
    use http_body_util::BodyExt;

    use super::*;

    fn body(r: Response<Full<Bytes>>) -> String {
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let bytes = rt.block_on(r.into_body().collect()).unwrap().to_bytes();
        String::from_utf8(bytes.to_vec()).unwrap()
    }

    #[test]
    fn routes() {
        let s = Snapshot::example();
        let r = respond(&Method::GET, "/", &s);
        assert_eq!(r.status(), StatusCode::OK);
        assert_eq!(r.headers()[header::CONTENT_TYPE], "text/html; charset=utf-8");
        assert!(
            r.headers()[header::CONTENT_SECURITY_POLICY].to_str().unwrap().contains("default-src 'none'")
        );
        let r = respond(&Method::HEAD, "/metrics", &s);
        assert_eq!(r.headers()[header::CONTENT_TYPE], metrics::CONTENT_TYPE);
        let r = respond(&Method::GET, "/status.json", &s);
        let back: Snapshot = serde_json::from_str(&body(r)).unwrap();
        assert_eq!(back, s);
        assert_eq!(respond(&Method::GET, "/nope", &s).status(), StatusCode::NOT_FOUND);
        assert_eq!(respond(&Method::GET, "/status.json/", &s).status(), StatusCode::NOT_FOUND);
    }

    #[test]
    fn only_get_and_head() {
        let s = Snapshot::example();
        for m in [Method::POST, Method::PUT, Method::DELETE, Method::PATCH, Method::OPTIONS] {
            let r = respond(&m, "/", &s);
            assert_eq!(r.status(), StatusCode::METHOD_NOT_ALLOWED, "{m}");
            assert_eq!(r.headers()[header::ALLOW], "GET, HEAD");
        }
    }
}
