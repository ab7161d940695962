//! Limits that hold under abuse, over a real socket: the connection cap,
//! header and body timeouts, slowloris clients, JSON depth and length,
//! client and WebSocket rates, WebSocket message size; graceful shutdown;
//! TLS. Every refusal is a named JSON error, counted in `/metrics`.

mod common;

use std::sync::Arc;
use std::time::{Duration, Instant};

use common::city_scene;
use common::server::{Server, new_session};
use futures_util::{SinkExt, StreamExt};
use pvsd::server::{AppState, ConnectionLimits, JsonLimits, Limits, Rate};
use serde_json::{Value, json};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::CloseFrame;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;

const VIEW: &str = r#"{"eye":[0,1.7,0],"forward":[1,0,0.2]}"#;

fn limits(connections: ConnectionLimits) -> Limits {
    Limits {
        connections,
        ..Limits::default()
    }
}

async fn server(limits: Limits) -> Server {
    Server::with(vec![city_scene(20, 2, [0.0; 3])], limits).await
}

/// Sends raw bytes on a fresh connection and reads until the server closes
/// it or `wait` passes; returns what was read.
async fn raw(server: &Server, bytes: &[u8], wait: Duration) -> String {
    let mut s = TcpStream::connect(server.addr).await.unwrap();
    s.write_all(bytes).await.unwrap();
    let mut out = Vec::new();
    let _ = tokio::time::timeout(wait, s.read_to_end(&mut out)).await;
    String::from_utf8_lossy(&out).into_owned()
}

/// The JSON body of a raw HTTP/1.1 answer.
fn body_of(answer: &str) -> Value {
    let body = answer.split("\r\n\r\n").nth(1).unwrap_or("");
    serde_json::from_str(body).unwrap_or_else(|e| panic!("not JSON ({e}): {answer}"))
}

/// The close frame the server ends `ws` with, skipping what comes before.
async fn close_frame<S>(ws: &mut S) -> CloseFrame
where
    S: StreamExt<Item = Result<Message, tokio_tungstenite::tungstenite::Error>> + Unpin,
{
    loop {
        match ws.next().await {
            Some(Ok(Message::Close(frame))) => return frame.expect("a close frame with a reason"),
            Some(Ok(_)) => continue,
            other => panic!("no close frame: {other:?}"),
        }
    }
}

#[tokio::test]
async fn connections_over_the_cap_get_503_overloaded_and_the_cap_frees_up() {
    let s = server(limits(ConnectionLimits {
        max_connections: 2,
        ..ConnectionLimits::default()
    }))
    .await;
    // Two idle clients hold both places.
    let a = TcpStream::connect(s.addr).await.unwrap();
    let b = TcpStream::connect(s.addr).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let answer = raw(
        &s,
        b"GET /healthz HTTP/1.1\r\nhost: x\r\n\r\n",
        Duration::from_secs(5),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
    assert!(answer.to_lowercase().contains("retry-after: 1"), "{answer}");
    assert_eq!(body_of(&answer)["error"]["code"], "overloaded");
    drop((a, b));
    tokio::time::sleep(Duration::from_millis(100)).await;
    let c = reqwest::Client::new();
    let r = c.get(s.url("/healthz")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(
        s.metric(&c, "pvsd_refused_total{reason=\"connections\"}")
            .await,
        1.0
    );
}

#[tokio::test]
async fn a_slow_head_is_cut_off_and_a_slow_body_gets_408() {
    let s = server(limits(ConnectionLimits {
        header_timeout: Duration::from_millis(300),
        body_timeout: Duration::from_millis(300),
        ..ConnectionLimits::default()
    }))
    .await;
    // Half a head: closed, unanswered, after the header timeout.
    let started = Instant::now();
    let answer = raw(&s, b"GET /healthz HTTP/1.1\r\nhos", Duration::from_secs(5)).await;
    let took = started.elapsed();
    assert!(answer.is_empty() || answer.contains("408"), "{answer}");
    assert!(
        took >= Duration::from_millis(250) && took < Duration::from_secs(3),
        "closed after {took:?}"
    );
    // A head, then 10 of the 100 body bytes promised.
    let answer = raw(
        &s,
        b"POST /scenes/city/visible HTTP/1.1\r\nhost: x\r\ncontent-length: 100\r\n\r\n{\"eye\":[0,",
        Duration::from_secs(5),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
    assert_eq!(body_of(&answer)["error"]["code"], "body_timeout");
    let c = reqwest::Client::new();
    assert_eq!(
        s.metric(&c, "pvsd_refused_total{reason=\"body_timeout\"}")
            .await,
        1.0
    );
    assert_eq!(
        s.metric(&c, "pvsd_refused_total{reason=\"header_timeout\"}")
            .await,
        1.0
    );
}

/// 2,000 clients each holding half a request head do not stop the server
/// answering others promptly; the header timeout then frees their places.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_thousand_slowloris_connections_do_not_stop_others() {
    let s = server(limits(ConnectionLimits {
        header_timeout: Duration::from_secs(2),
        ..ConnectionLimits::default()
    }))
    .await;
    let mut held = Vec::new();
    for _ in 0..2000 {
        let mut t = TcpStream::connect(s.addr).await.unwrap();
        t.write_all(b"POST /scenes/city/visible HTTP/1.1\r\nhost: x\r\nx-slow: ")
            .await
            .unwrap();
        held.push(t);
    }
    let c = reqwest::Client::new();
    for _ in 0..20 {
        let started = Instant::now();
        let r = c
            .post(s.url("/scenes/city/visible"))
            .body(VIEW)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        assert!(started.elapsed() < Duration::from_millis(500));
    }
    // After the timeout, the server has closed every one of them.
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let mut closed = 0;
    for t in &mut held {
        let mut buf = [0u8; 64];
        if let Ok(Ok(0) | Err(_)) =
            tokio::time::timeout(Duration::from_millis(20), t.read(&mut buf)).await
        {
            closed += 1;
        }
    }
    assert_eq!(closed, 2000, "only {closed} of 2000 were closed");
    // Each counted (and so may be this client's idle keep-alive ones).
    let counted = s
        .metric(&c, "pvsd_refused_total{reason=\"header_timeout\"}")
        .await;
    assert!(counted >= 2000.0, "{counted}");
}

#[tokio::test]
async fn deep_or_long_json_gets_413_body_too_complex() {
    let s = server(Limits {
        json: JsonLimits {
            max_depth: 8,
            max_array: 16,
        },
        ..Limits::default()
    })
    .await;
    let c = reqwest::Client::new();
    let deep = format!(
        r#"{{"eye":[0,1.7,0],"forward":[1,0,0],"options":{{"x":{}1{}}}}}"#,
        "[".repeat(20),
        "]".repeat(20)
    );
    let long = format!(
        r#"{{"eye":[0,1.7,0{}],"forward":[1,0,0]}}"#,
        ",0".repeat(30)
    );
    for body in [deep, long] {
        let r = c
            .post(s.url("/scenes/city/visible"))
            .body(body)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 413);
        let e: Value = r.json().await.unwrap();
        assert_eq!(e["error"]["code"], "body_too_complex", "{e}");
    }
    assert_eq!(
        s.metric(&c, "pvsd_refused_total{reason=\"json_limits\"}")
            .await,
        2.0
    );
}

#[tokio::test]
async fn a_client_over_its_rate_gets_429_with_retry_after() {
    let s = server(Limits {
        client_rate: Some(Rate {
            per_s: 1.0,
            burst: 5,
        }),
        ..Limits::default()
    })
    .await;
    let c = reqwest::Client::new();
    for _ in 0..5 {
        let r = c.get(s.url("/healthz")).send().await.unwrap();
        assert_eq!(r.status(), 200);
    }
    let r = c.get(s.url("/healthz")).send().await.unwrap();
    assert_eq!(r.status(), 429);
    assert_eq!(r.headers()["retry-after"], "1");
    let e: Value = r.json().await.unwrap();
    assert_eq!(e["error"]["code"], "rate_limited", "{e}");
    // After a second, one more.
    tokio::time::sleep(Duration::from_millis(1100)).await;
    let r = c.get(s.url("/healthz")).send().await.unwrap();
    assert_eq!(r.status(), 200);
}

#[tokio::test]
async fn a_websocket_over_its_rate_or_size_is_refused_by_name() {
    let s = server(Limits {
        body_bytes: 4096,
        websocket_rate: Some(Rate {
            per_s: 0.5,
            burst: 2,
        }),
        ..Limits::default()
    })
    .await;
    let c = reqwest::Client::new();
    let sid = new_session(&c, &s, json!({"scene": "city", "method": "frustum"})).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(s.ws_url(&format!("/sessions/{sid}/ws")))
        .await
        .unwrap();
    let mut codes = Vec::new();
    for _ in 0..3 {
        ws.send(Message::text(VIEW)).await.unwrap();
        let m: Value =
            serde_json::from_str(ws.next().await.unwrap().unwrap().to_text().unwrap()).unwrap();
        codes.push(m["error"]["code"].as_str().unwrap_or("frame").to_string());
    }
    assert_eq!(codes, ["frame", "frame", "rate_limited"]);
    // A message over the body limit closes the socket with 1009, named.
    let _ = ws.send(Message::text("x".repeat(10_000))).await;
    let frame = close_frame(&mut ws).await;
    assert_eq!(frame.code, CloseCode::Size);
    assert!(frame.reason.starts_with("message_too_large"), "{frame:?}");
    assert_eq!(
        s.metric(&c, "pvsd_refused_total{reason=\"websocket_rate\"}")
            .await,
        1.0
    );
    assert_eq!(
        s.metric(&c, "pvsd_refused_total{reason=\"websocket_size\"}")
            .await,
        1.0
    );
}

/// Shutdown under load: a request in flight is answered, a WebSocket gets
/// `1001` with a reason, and the server returns within its grace period.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_answers_requests_in_flight_and_closes_websockets() {
    let state = AppState::new(
        vec![city_scene(20, 2, [0.0; 3])],
        limits(ConnectionLimits {
            shutdown_grace: Duration::from_secs(3),
            ..ConnectionLimits::default()
        }),
    )
    .unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(pvsd::server::run(listener, state, async {
        stopped.await.ok();
    }));
    let c = reqwest::Client::new();
    let sid = c
        .post(format!("http://{addr}/sessions"))
        .body(r#"{"scene":"city","method":"frustum"}"#)
        .send()
        .await
        .unwrap()
        .json::<Value>()
        .await
        .unwrap()["session"]
        .as_str()
        .unwrap()
        .to_string();
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/sessions/{sid}/ws"))
        .await
        .unwrap();
    // A request whose body is still coming when shutdown begins.
    let mut slow = TcpStream::connect(addr).await.unwrap();
    slow.write_all(
        format!(
            "POST /scenes/city/visible HTTP/1.1\r\nhost: x\r\ncontent-length: {}\r\n\r\n",
            VIEW.len()
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    slow.write_all(&VIEW.as_bytes()[..10]).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let started = Instant::now();
    stop.send(()).unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    slow.write_all(&VIEW.as_bytes()[10..]).await.unwrap();
    let mut answer = Vec::new();
    slow.read_to_end(&mut answer).await.unwrap();
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    let close = close_frame(&mut ws).await;
    assert_eq!(close.code, CloseCode::Away);
    assert_eq!(close.reason, "server shutting down");
    drop(ws);
    tokio::time::timeout(Duration::from_secs(5), server)
        .await
        .expect("the server returns within its grace period")
        .unwrap()
        .unwrap();
    assert!(started.elapsed() < Duration::from_secs(4));
    // No new connections after.
    assert!(TcpStream::connect(addr).await.is_err());
}

/// With a certificate and key, the server speaks HTTPS (rustls).
#[tokio::test]
async fn tls_serves_https_with_the_configured_certificate() {
    use tokio_rustls::rustls::pki_types::pem::PemObject;
    use tokio_rustls::rustls::pki_types::{CertificateDer, ServerName};
    use tokio_rustls::rustls::{ClientConfig, RootCertStore, crypto::ring};
    let cert = rcgen::generate_simple_self_signed(vec!["localhost".into()]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (cert_pem, key_pem) = (dir.path().join("cert.pem"), dir.path().join("key.pem"));
    std::fs::write(&cert_pem, cert.cert.pem()).unwrap();
    std::fs::write(&key_pem, cert.signing_key.serialize_pem()).unwrap();
    let acceptor = pvsd::server::tls::acceptor(&cert_pem, &key_pem).unwrap();
    // A key that is no key is refused, naming the file.
    std::fs::write(dir.path().join("bad.pem"), "not a key").unwrap();
    let e = pvsd::server::tls::acceptor(&cert_pem, &dir.path().join("bad.pem"))
        .err()
        .unwrap();
    assert!(e.to_string().contains("bad.pem"), "{e}");

    let state = AppState::new(vec![city_scene(20, 2, [0.0; 3])], Limits::default()).unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (_stop, stopped) = tokio::sync::oneshot::channel::<()>();
    tokio::spawn(pvsd::server::run_tls(listener, state, acceptor, async {
        stopped.await.ok();
    }));
    let mut roots = RootCertStore::empty();
    roots
        .add(CertificateDer::from_pem_slice(cert.cert.pem().as_bytes()).unwrap())
        .unwrap();
    let config = ClientConfig::builder_with_provider(Arc::new(ring::default_provider()))
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(config));
    let tcp = TcpStream::connect(addr).await.unwrap();
    let mut tls = connector
        .connect(ServerName::try_from("localhost").unwrap(), tcp)
        .await
        .unwrap();
    tls.write_all(b"GET /healthz HTTP/1.1\r\nhost: localhost\r\nconnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut answer = Vec::new();
    tls.read_to_end(&mut answer).await.unwrap();
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    assert!(answer.ends_with("ok"), "{answer}");
    // Plain HTTP on the TLS port gets no answer.
    let mut plain = TcpStream::connect(addr).await.unwrap();
    plain
        .write_all(b"GET /healthz HTTP/1.1\r\nhost: x\r\n\r\n")
        .await
        .unwrap();
    let mut out = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), plain.read_to_end(&mut out)).await;
    assert!(!String::from_utf8_lossy(&out).contains("200 OK"));
}
