//! `application/x-pvs`: the compact binary encoding of answers, specified
//! in `proto/wire-format.md` (read that first; this is its implementation).
//! The server encodes with it, clients decode with it.
//!
//! Ids travel sorted and delta-coded as unsigned LEB128 varints: a walk's
//! visible sets are runs of nearby ids, so most gaps fit one byte. Sessions
//! also keep their last frames in this form ([`crate::delta::IdSet`]), a
//! quarter of the memory of `u32`s or less.

use crate::json::{FrameResponse as Frame, Stats};

/// The media type.
pub const CONTENT_TYPE: &str = "application/x-pvs";

/// First byte of a visible-set answer (`POST /scenes/{id}/visible`).
pub const KIND_VISIBLE: u8 = b'V';
/// First byte of a session frame.
pub const KIND_FRAME: u8 = b'F';

const FLAG_BASE: u8 = 1;
const FLAG_USERS: u8 = 2;
const FLAG_STATS: u8 = 4;

/// Why bytes are not a message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// The bytes end inside a value.
    Truncated(usize),
    /// A varint longer than its type, or ids past `u32::MAX`.
    Overflow(usize),
    /// Unknown kind or flags.
    Unknown(usize),
    /// A user id that is not UTF-8.
    NotUtf8(usize),
    /// Bytes left over after the message.
    Trailing(usize),
}

impl std::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DecodeError::Truncated(at) => write!(f, "truncated at byte {at}"),
            DecodeError::Overflow(at) => write!(f, "value out of range at byte {at}"),
            DecodeError::Unknown(at) => write!(f, "unknown message kind or flags at byte {at}"),
            DecodeError::NotUtf8(at) => write!(f, "user id at byte {at} is not UTF-8"),
            DecodeError::Trailing(n) => write!(f, "{n} bytes after the end of the message"),
        }
    }
}

impl std::error::Error for DecodeError {}

/// A decoded message.
// A frame is much larger than a visible message's `Vec`; a message is
// made once per decode and taken apart at once, so boxing it would only
// add an allocation per frame.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    /// The ids of a stateless answer.
    Visible(Vec<u32>),
    /// A session frame.
    Frame(Frame),
}

/// Appends `v` as an unsigned LEB128 varint.
pub fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Appends a strictly ascending id set: its length, the first id, then
/// each id minus its predecessor minus one.
pub fn put_ids(out: &mut Vec<u8>, ids: &[u32]) {
    put_varint(out, ids.len() as u64);
    let mut next = 0u64;
    for &id in ids {
        debug_assert!(u64::from(id) >= next, "ids must be strictly ascending");
        put_varint(out, u64::from(id) - next);
        next = u64::from(id) + 1;
    }
}

/// `POST /scenes/{id}/visible`'s answer.
pub fn encode_visible(ids: &[u32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(2 + ids.len() * 2);
    out.push(KIND_VISIBLE);
    put_ids(&mut out, ids);
    out
}

/// A session frame.
pub fn encode_frame(f: &Frame) -> Vec<u8> {
    let mut out = Vec::with_capacity(8 + (f.added.len() + f.removed.len()) * 2);
    out.push(KIND_FRAME);
    let mut flags = 0;
    if f.base.is_some() {
        flags |= FLAG_BASE;
    }
    if f.users_visible.is_some() {
        flags |= FLAG_USERS;
    }
    if f.stats.is_some() {
        flags |= FLAG_STATS;
    }
    out.push(flags);
    put_varint(&mut out, f.frame);
    if let Some(b) = f.base {
        put_varint(&mut out, b);
    }
    put_ids(&mut out, &f.added);
    put_ids(&mut out, &f.removed);
    if let Some(users) = &f.users_visible {
        put_varint(&mut out, users.len() as u64);
        for u in users {
            put_string(&mut out, u);
        }
    }
    if let Some(s) = &f.stats {
        put_string(&mut out, &s.method);
        out.extend_from_slice(&s.cull_us.to_le_bytes());
        put_varint(&mut out, s.nodes_tested);
        match s.in_frustum {
            None => out.push(0),
            Some(n) => {
                out.push(1);
                put_varint(&mut out, n);
            }
        }
        put_varint(&mut out, s.visible);
        put_string(&mut out, s.fallback.as_deref().unwrap_or(""));
        put_string(&mut out, s.fallback_reason.as_deref().unwrap_or(""));
    }
    out
}

fn put_string(out: &mut Vec<u8>, s: &str) {
    put_varint(out, s.len() as u64);
    out.extend_from_slice(s.as_bytes());
}

/// Reads values off a byte slice.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn byte(&mut self) -> Result<u8, DecodeError> {
        let b = *self
            .bytes
            .get(self.at)
            .ok_or(DecodeError::Truncated(self.at))?;
        self.at += 1;
        Ok(b)
    }

    fn varint(&mut self) -> Result<u64, DecodeError> {
        let start = self.at;
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.byte()?;
            let bits = u64::from(b & 0x7f);
            if shift == 63 && bits > 1 {
                return Err(DecodeError::Overflow(start));
            }
            v |= bits << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(DecodeError::Overflow(start))
    }

    fn ids(&mut self) -> Result<Vec<u32>, DecodeError> {
        let mut ids = Vec::new();
        self.ids_into(&mut ids)?;
        Ok(ids)
    }

    /// Appends an id set to `ids`.
    fn ids_into(&mut self, ids: &mut Vec<u32>) -> Result<(), DecodeError> {
        let n = self.varint()?;
        // Each id takes at least a byte: a count past the bytes left is a
        // lie, and must not make us allocate it.
        if n > (self.bytes.len() - self.at) as u64 {
            return Err(DecodeError::Truncated(self.bytes.len()));
        }
        ids.reserve(n as usize);
        let mut next = 0u64;
        for _ in 0..n {
            let at = self.at;
            let id = next
                .checked_add(self.varint()?)
                .filter(|&id| id <= u64::from(u32::MAX))
                .ok_or(DecodeError::Overflow(at))?;
            ids.push(id as u32);
            next = id + 1;
        }
        Ok(())
    }

    fn string(&mut self) -> Result<String, DecodeError> {
        let at = self.at;
        let n = self.varint()?;
        let end = self
            .at
            .checked_add(usize::try_from(n).map_err(|_| DecodeError::Overflow(at))?)
            .filter(|&e| e <= self.bytes.len())
            .ok_or(DecodeError::Truncated(self.bytes.len()))?;
        let s = std::str::from_utf8(&self.bytes[self.at..end])
            .map_err(|_| DecodeError::NotUtf8(at))?
            .to_string();
        self.at = end;
        Ok(s)
    }
}

impl Reader<'_> {
    fn f64(&mut self) -> Result<f64, DecodeError> {
        let end = self.at + 8;
        let bytes = self
            .bytes
            .get(self.at..end)
            .ok_or(DecodeError::Truncated(self.bytes.len()))?;
        self.at = end;
        Ok(f64::from_le_bytes(bytes.try_into().expect("8 bytes")))
    }

    fn stats(&mut self) -> Result<Stats, DecodeError> {
        let method = self.string()?;
        let cull_us = self.f64()?;
        let nodes_tested = self.varint()?;
        let at = self.at;
        let in_frustum = match self.byte()? {
            0 => None,
            1 => Some(self.varint()?),
            _ => return Err(DecodeError::Unknown(at)),
        };
        let visible = self.varint()?;
        let nonempty = |s: String| (!s.is_empty()).then_some(s);
        let fallback = nonempty(self.string()?);
        let fallback_reason = nonempty(self.string()?);
        Ok(Stats {
            method,
            cull_us,
            nodes_tested,
            in_frustum,
            visible,
            fallback,
            fallback_reason,
            // The binary frame carries no request echo (JSON does).
            radius: None,
            angle: None,
            views: None,
        })
    }
}

/// Decodes one whole message.
pub fn decode(bytes: &[u8]) -> Result<Message, DecodeError> {
    let mut r = Reader { bytes, at: 0 };
    let message = match r.byte()? {
        KIND_VISIBLE => Message::Visible(r.ids()?),
        KIND_FRAME => {
            let flags = r.byte()?;
            if flags & !(FLAG_BASE | FLAG_USERS | FLAG_STATS) != 0 {
                return Err(DecodeError::Unknown(1));
            }
            let frame = r.varint()?;
            let base = if flags & FLAG_BASE != 0 {
                Some(r.varint()?)
            } else {
                None
            };
            let added = r.ids()?;
            let removed = r.ids()?;
            let users_visible = if flags & FLAG_USERS != 0 {
                let n = r.varint()?;
                if n > (bytes.len() - r.at) as u64 {
                    return Err(DecodeError::Truncated(bytes.len()));
                }
                (0..n)
                    .map(|_| r.string())
                    .collect::<Result<_, _>>()
                    .map(Some)?
            } else {
                None
            };
            let stats = if flags & FLAG_STATS != 0 {
                Some(r.stats()?)
            } else {
                None
            };
            Message::Frame(Frame {
                frame,
                base,
                added,
                removed,
                users_visible,
                stats,
            })
        }
        _ => return Err(DecodeError::Unknown(0)),
    };
    if r.at != bytes.len() {
        return Err(DecodeError::Trailing(bytes.len() - r.at));
    }
    Ok(message)
}

/// Appends the id set at the start of `bytes` to `ids`; the bytes an
/// [`crate::delta::IdSet`] keeps.
pub(crate) fn ids_into(bytes: &[u8], ids: &mut Vec<u32>) -> Result<(), DecodeError> {
    Reader { bytes, at: 0 }.ids_into(ids)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spec_examples_encode_as_written() {
        // proto/wire-format.md, "Worked example".
        assert_eq!(
            encode_visible(&[3, 4, 10, 300]),
            [0x56, 0x04, 0x03, 0x00, 0x05, 0xA1, 0x02]
        );
        let f = Frame {
            frame: 7,
            base: Some(6),
            added: vec![5],
            removed: vec![3, 4],
            users_visible: None,
            stats: None,
        };
        assert_eq!(
            encode_frame(&f),
            [0x46, 0x01, 0x07, 0x06, 0x01, 0x05, 0x02, 0x03, 0x00]
        );
        let w = Frame {
            frame: 1,
            base: None,
            added: vec![],
            removed: vec![],
            users_visible: Some(vec!["ab".into()]),
            stats: None,
        };
        assert_eq!(
            encode_frame(&w),
            [0x46, 0x02, 0x01, 0x00, 0x00, 0x01, 0x02, b'a', b'b']
        );
    }

    #[test]
    fn round_trips_extremes_and_refuses_bad_bytes() {
        let ids = [0, 1, 127, 128, 16_383, 16_384, u32::MAX - 1, u32::MAX];
        assert_eq!(
            decode(&encode_visible(&ids)),
            Ok(Message::Visible(ids.to_vec()))
        );
        let f = Frame {
            frame: u64::MAX,
            base: Some(0),
            added: vec![u32::MAX],
            removed: vec![0],
            users_visible: Some(vec!["é".into(), String::new()]),
            stats: Some(Stats {
                method: "raster".into(),
                cull_us: 0.1 + 0.2,
                nodes_tested: u64::MAX,
                in_frustum: Some(0),
                visible: 1,
                fallback: Some("frustum".into()),
                fallback_reason: Some("the device was lost".into()),
                radius: None,
                angle: None,
                views: None,
            }),
        };
        assert_eq!(decode(&encode_frame(&f)), Ok(Message::Frame(f.clone())));
        let full = encode_frame(&f);
        for cut in 0..full.len() {
            assert!(decode(&full[..cut]).is_err(), "cut at {cut}");
        }
        let mut long = full.clone();
        long.push(0);
        assert_eq!(decode(&long), Err(DecodeError::Trailing(1)));
        // An id past u32::MAX; a count that promises more than is there.
        assert!(matches!(
            decode(&[b'V', 2, 0xFF, 0xFF, 0xFF, 0xFF, 0x0F, 0x00]),
            Err(DecodeError::Overflow(_))
        ));
        assert!(decode(&[b'V', 0xFF, 0xFF, 0xFF, 0xFF, 0x0F]).is_err());
        assert_eq!(decode(b"X"), Err(DecodeError::Unknown(0)));
        assert_eq!(decode(&[b'F', 8]), Err(DecodeError::Unknown(1)));
        // Stats without a count in the frustum, and no fallback.
        let plain = Frame {
            stats: Some(Stats {
                in_frustum: None,
                fallback: None,
                fallback_reason: None,
                radius: None,
                angle: None,
                views: None,
                ..f.stats.clone().unwrap()
            }),
            ..f
        };
        assert_eq!(decode(&encode_frame(&plain)), Ok(Message::Frame(plain)));
    }
}
