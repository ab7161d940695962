//! WebSocket messages on a live session, through the socket's own reply
//! function: the first byte picks the kind of message (text, binary, ping)
//! and the encoding of answers. Invariants: a text reply is a frame or a
//! named error that is not the server's fault; a binary reply is an x-pvs
//! frame; the session never ends from a client's message.
#![no_main]

use axum::extract::ws::Message;
use libfuzzer_sys::fuzz_target;
use pvsd::server::ws::{Encoding, Reply, reply};
use pvsd_proto::error::ErrorBody;
use pvsd_proto::json::FrameResponse;

fuzz_target!(|data: &[u8]| {
    let Some((&kind, payload)) = data.split_first() else {
        return;
    };
    let f = pvsd_fuzz::fixture();
    let message = match kind % 3 {
        0 => Message::Text(String::from_utf8_lossy(payload).into_owned().into()),
        1 => Message::Binary(payload.to_vec().into()),
        _ => Message::Ping(payload.to_vec().into()),
    };
    let binary = kind & 0x80 != 0;
    let encoding = Encoding {
        binary,
        stats: kind & 0x40 != 0,
    };
    let answer = f
        .runtime
        .block_on(reply(&f.state, &f.session, message, encoding, None));
    match answer {
        Reply::Send(Message::Text(text)) => {
            if let Ok(e) = serde_json::from_str::<ErrorBody>(&text) {
                assert_ne!(e.error.code.as_str(), "internal", "{}", e.error.message);
            } else {
                let _: FrameResponse = serde_json::from_str(&text)
                    .unwrap_or_else(|e| panic!("neither an error nor a frame ({e}): {text}"));
            }
        }
        Reply::Send(Message::Binary(bytes)) => {
            assert!(binary);
            pvsd_proto::xpvs::decode(&bytes).expect("an x-pvs frame");
        }
        Reply::Send(other) => panic!("replied {other:?}"),
        Reply::End(m, close) => panic!("the session ended: {m:?} {close:?}"),
        Reply::Nothing | Reply::Closed => {}
    }
});
