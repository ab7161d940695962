//! Request bodies through the server's own routes (the router, as a
//! client's request reaches it): the first byte picks the route, the rest is
//! the body. Invariant: every answer is a success or a named 4xx error —
//! bad input never makes a server error.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pvsd_fuzz::{TOKEN, check_refusal, fixture};

fuzz_target!(|data: &[u8]| {
    let Some((&route, body)) = data.split_first() else {
        return;
    };
    let f = fixture();
    let frames = format!("/sessions/{}/frames", f.session);
    let bearer = format!("Bearer {TOKEN}");
    let (method, path, auth) = match route % 6 {
        0 => ("POST", "/scenes/city/visible", None),
        5 => ("POST", "/scenes/city/meshes", None),
        1 => ("POST", "/sessions", None),
        2 => ("POST", frames.as_str(), None),
        3 => ("POST", "/walkthroughs", None),
        _ => ("PUT", "/scenes/city/objects/0", Some(bearer.as_str())),
    };
    let (status, answer) = f.call(method, path, body, auth);
    if status >= 300 {
        check_refusal(status, &answer);
    }
});
