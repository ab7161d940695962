//! `application/x-pvs`, delta chaining and `application/x-pvs-mesh` (the
//! proto crate). Invariants: what decodes encodes back to the same message
//! (compared as bytes: a frame's stats may hold a NaN); a chain of deltas,
//! each encoded, decoded and applied to what the client holds, rebuilds
//! every set; an `IdSet` gives back its ids; a mesh message that decodes is
//! exactly the bytes its meshes encode to.
#![no_main]

use std::collections::BTreeSet;

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use pvsd_proto::delta::{IdSet, diff};
use pvsd_proto::json::FrameResponse;
use pvsd_proto::mesh;
use pvsd_proto::xpvs::{Message, decode, encode_frame, encode_visible};

#[derive(Arbitrary, Debug)]
enum Input {
    /// Bytes off the wire.
    Decode(Vec<u8>),
    /// Visible sets of successive frames.
    Chain(Vec<Vec<u32>>),
    /// Mesh message bytes off the wire.
    Mesh(Vec<u8>),
}

fn encode(m: &Message) -> Vec<u8> {
    match m {
        Message::Visible(ids) => encode_visible(ids),
        Message::Frame(f) => encode_frame(f),
    }
}

fuzz_target!(|input: Input| match input {
    Input::Decode(bytes) => {
        if let Ok(m) = decode(&bytes) {
            let again = encode(&m);
            assert_eq!(decode(&again).map(|m| encode(&m)), Ok(again));
        }
    }
    Input::Mesh(bytes) => {
        if let Ok(m) = mesh::decode(&bytes) {
            let meshes: Vec<mesh::MeshRef<'_>> = m.meshes.iter().map(mesh::Mesh::as_ref).collect();
            assert_eq!(mesh::encode(m.origin, &meshes), bytes);
        }
    }
    Input::Chain(sets) => {
        let mut held: BTreeSet<u32> = BTreeSet::new();
        let mut last: Vec<u32> = Vec::new();
        for (i, set) in sets.into_iter().enumerate() {
            let set: Vec<u32> = set
                .into_iter()
                .collect::<BTreeSet<_>>()
                .into_iter()
                .collect();
            let mut ids = Vec::new();
            IdSet::new(&set).decode_into(&mut ids);
            assert_eq!(ids, set);
            let (mut added, mut removed) = (Vec::new(), Vec::new());
            diff(&last, &set, &mut added, &mut removed);
            let frame = FrameResponse {
                frame: i as u64 + 1,
                base: (i > 0).then_some(i as u64),
                added,
                removed,
                users_visible: None,
                stats: None,
            };
            let Ok(Message::Frame(got)) = decode(&encode_frame(&frame)) else {
                panic!("a frame does not decode");
            };
            assert_eq!(got, frame);
            for r in &got.removed {
                assert!(held.remove(r), "removes {r}, not held");
            }
            for a in &got.added {
                assert!(held.insert(*a), "adds {a}, held");
            }
            assert!(held.iter().copied().eq(set.iter().copied()));
            last = set;
        }
    }
});
