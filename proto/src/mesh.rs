//! `application/x-pvs-mesh`: objects' triangles for clients that draw
//! what they are told is visible, specified in `proto/mesh-format.md` (read
//! that first; this is its implementation).
//!
//! Positions travel as the `f32`s the server culls with, relative to the
//! scene's `f64` origin, not quantized: a client that draws exactly the
//! server's triangles sees exactly what a conservative answer promises
//! (nothing it was not sent can show), and a scene far from the world's
//! origin keeps its precision. Fields are little-endian and 4-byte
//! aligned, so a browser reads positions and indices as typed arrays over
//! the response's buffer without copying.

/// The media type.
pub const CONTENT_TYPE: &str = "application/x-pvs-mesh";

/// The first four bytes of every message.
pub const MAGIC: [u8; 4] = *b"PVSM";

/// The format's version, after the magic; a decoder refuses others.
pub const VERSION: u32 = 1;

/// Bytes of the message header.
pub const HEADER_BYTES: usize = 40;

/// Bytes of each mesh's header.
pub const MESH_HEADER_BYTES: usize = 20;

/// Mesh flag: indices are `u16` (the mesh has at most 65,536 vertices).
pub const FLAG_U16: u32 = 1;
/// Mesh flag: the object is movable; positions are where it is now.
pub const FLAG_MOVABLE: u32 = 2;

/// One object's triangles, borrowed, for encoding.
#[derive(Clone, Copy, Debug)]
pub struct MeshRef<'a> {
    /// The object id.
    pub id: u32,
    /// Whether the object may move ([`FLAG_MOVABLE`]).
    pub movable: bool,
    /// Vertex positions relative to the message's origin.
    pub positions: &'a [[f32; 3]],
    /// Three vertex indices per triangle.
    pub indices: &'a [u32],
    /// How many of the first triangles are opaque; the rest are see-through.
    pub opaque: u32,
}

/// One object's triangles, decoded.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// The object id.
    pub id: u32,
    /// Whether the object may move.
    pub movable: bool,
    /// Vertex positions relative to the message's origin.
    pub positions: Vec<[f32; 3]>,
    /// Three vertex indices per triangle.
    pub indices: Vec<u32>,
    /// How many of the first triangles are opaque; the rest are see-through.
    pub opaque: u32,
}

impl Mesh {
    /// This mesh, borrowed for [`encode`].
    pub fn as_ref(&self) -> MeshRef<'_> {
        MeshRef {
            id: self.id,
            movable: self.movable,
            positions: &self.positions,
            indices: &self.indices,
            opaque: self.opaque,
        }
    }
}

/// A decoded message: meshes around one origin.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Meshes {
    /// The world position every mesh's positions are relative to.
    pub origin: [f64; 3],
    /// The meshes, in the order they were asked for.
    pub meshes: Vec<Mesh>,
}

/// The bytes `mesh` takes in a message, its header and padding included.
pub fn encoded_len(mesh: &MeshRef<'_>) -> usize {
    let index_bytes = if small(mesh.positions) { 2 } else { 4 };
    MESH_HEADER_BYTES + mesh.positions.len() * 12 + padded(mesh.indices.len() * index_bytes)
}

fn small(positions: &[[f32; 3]]) -> bool {
    positions.len() <= 1 << 16
}

fn padded(n: usize) -> usize {
    n.next_multiple_of(4)
}

/// Encodes `meshes` around `origin` into one message.
///
/// # Panics
/// When a mesh's index is past its vertices, its index count is no multiple
/// of 3, or `opaque` is past its triangles: a caller bug.
pub fn encode<'a>(origin: [f64; 3], meshes: &[MeshRef<'a>]) -> Vec<u8> {
    let total = HEADER_BYTES + meshes.iter().map(encoded_len).sum::<usize>();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(meshes.len() as u32).to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    for c in origin {
        out.extend_from_slice(&c.to_le_bytes());
    }
    for m in meshes {
        let vertices = m.positions.len();
        assert!(
            m.indices.len() % 3 == 0 && m.indices.iter().all(|&i| (i as usize) < vertices),
            "mesh {}: indices are whole triangles of its vertices",
            m.id
        );
        let triangles = (m.indices.len() / 3) as u32;
        assert!(
            m.opaque <= triangles,
            "mesh {}: opaque past its triangles",
            m.id
        );
        let u16s = small(m.positions);
        let flags = if u16s { FLAG_U16 } else { 0 } | if m.movable { FLAG_MOVABLE } else { 0 };
        for field in [m.id, flags, vertices as u32, triangles, m.opaque] {
            out.extend_from_slice(&field.to_le_bytes());
        }
        for p in m.positions {
            for c in p {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        if u16s {
            for &i in m.indices {
                out.extend_from_slice(&(i as u16).to_le_bytes());
            }
            if m.indices.len() % 2 == 1 {
                out.extend_from_slice(&[0, 0]);
            }
        } else {
            for &i in m.indices {
                out.extend_from_slice(&i.to_le_bytes());
            }
        }
    }
    debug_assert_eq!(out.len(), total);
    out
}

/// Why bytes are not a mesh message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MeshError {
    /// Not `PVSM`, another version, or a nonzero reserved word.
    Header,
    /// The bytes end inside the named mesh (by its place in the message).
    Truncated(usize),
    /// The named mesh has unknown flags, an index past its vertices, an
    /// opaque count past its triangles, or nonzero padding.
    Invalid(usize),
    /// Bytes left over after the last mesh.
    Trailing(usize),
}

impl std::fmt::Display for MeshError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MeshError::Header => write!(f, "not an x-pvs-mesh message of version {VERSION}"),
            MeshError::Truncated(i) => write!(f, "the message ends inside mesh {i}"),
            MeshError::Invalid(i) => write!(f, "mesh {i} is malformed"),
            MeshError::Trailing(n) => write!(f, "{n} bytes after the last mesh"),
        }
    }
}

impl std::error::Error for MeshError {}

/// Decodes one whole message.
pub fn decode(bytes: &[u8]) -> Result<Meshes, MeshError> {
    let word = |at: usize| -> Option<u32> {
        Some(u32::from_le_bytes(bytes.get(at..at + 4)?.try_into().ok()?))
    };
    if bytes.len() < HEADER_BYTES
        || bytes[..4] != MAGIC
        || word(4) != Some(VERSION)
        || word(12) != Some(0)
    {
        return Err(MeshError::Header);
    }
    let count = word(8).ok_or(MeshError::Header)? as usize;
    let mut origin = [0.0; 3];
    for (i, c) in origin.iter_mut().enumerate() {
        let at = 16 + i * 8;
        *c = f64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"));
    }
    // Every mesh takes at least its header: a count past that is a lie and
    // must not make us allocate it.
    if count > (bytes.len() - HEADER_BYTES) / MESH_HEADER_BYTES {
        return Err(MeshError::Truncated(0));
    }
    let mut meshes = Vec::with_capacity(count);
    let mut at = HEADER_BYTES;
    for n in 0..count {
        let field = |k: usize| word(at + 4 * k).ok_or(MeshError::Truncated(n));
        let (id, flags, vertices, triangles, opaque) =
            (field(0)?, field(1)?, field(2)?, field(3)?, field(4)?);
        if flags & !(FLAG_U16 | FLAG_MOVABLE) != 0 || opaque > triangles {
            return Err(MeshError::Invalid(n));
        }
        let (vertices, indices) = (vertices as usize, triangles as usize * 3);
        let u16s = flags & FLAG_U16 != 0;
        if u16s != (vertices <= 1 << 16) {
            return Err(MeshError::Invalid(n));
        }
        let index_bytes = if u16s { 2 } else { 4 };
        let body = vertices
            .checked_mul(12)
            .and_then(|p| Some(p + padded(indices.checked_mul(index_bytes)?)))
            .ok_or(MeshError::Truncated(n))?;
        at += MESH_HEADER_BYTES;
        let end = at.checked_add(body).ok_or(MeshError::Truncated(n))?;
        if end > bytes.len() {
            return Err(MeshError::Truncated(n));
        }
        let f32_at = |k: usize| f32::from_le_bytes(bytes[k..k + 4].try_into().expect("4 bytes"));
        let positions: Vec<[f32; 3]> = (0..vertices)
            .map(|v| {
                let p = at + v * 12;
                [f32_at(p), f32_at(p + 4), f32_at(p + 8)]
            })
            .collect();
        let first = at + vertices * 12;
        let index: Vec<u32> = (0..indices)
            .map(|i| {
                if u16s {
                    let k = first + i * 2;
                    u32::from(u16::from_le_bytes([bytes[k], bytes[k + 1]]))
                } else {
                    word(first + i * 4).expect("inside the checked body")
                }
            })
            .collect();
        let used = first + indices * index_bytes;
        if index.iter().any(|&i| i as usize >= vertices) || bytes[used..end].iter().any(|&b| b != 0)
        {
            return Err(MeshError::Invalid(n));
        }
        meshes.push(Mesh {
            id,
            movable: flags & FLAG_MOVABLE != 0,
            positions,
            indices: index,
            opaque,
        });
        at = end;
    }
    if at != bytes.len() {
        return Err(MeshError::Trailing(bytes.len() - at));
    }
    Ok(Meshes { origin, meshes })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(id: u32) -> Mesh {
        Mesh {
            id,
            movable: false,
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            indices: vec![0, 1, 2, 0, 2, 3],
            opaque: 1,
        }
    }

    #[test]
    fn the_spec_example_encodes_as_written() {
        // proto/mesh-format.md, "Worked example": one triangle, object 5.
        let tri = Mesh {
            id: 5,
            movable: false,
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            indices: vec![0, 1, 2],
            opaque: 1,
        };
        let bytes = encode([100.0, 0.0, -2.5], &[tri.as_ref()]);
        assert_eq!(bytes.len(), 40 + 20 + 36 + 8);
        assert_eq!(&bytes[..16], b"PVSM\x01\0\0\0\x01\0\0\0\0\0\0\0");
        assert_eq!(&bytes[16..24], &100.0f64.to_le_bytes());
        assert_eq!(
            &bytes[40..60],
            &[5, 0, 0, 0, 1, 0, 0, 0, 3, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0]
        );
        assert_eq!(&bytes[96..], &[0, 0, 1, 0, 2, 0, 0, 0]);
    }

    #[test]
    fn round_trips_and_refuses_bad_bytes() {
        let mut big = quad(u32::MAX);
        big.movable = true;
        big.positions = (0..70_000)
            .map(|i| [i as f32, f32::MIN, f32::MAX])
            .collect();
        big.indices = vec![0, 69_999, 65_536];
        big.opaque = 0;
        let meshes = Meshes {
            origin: [1e12, -0.5, f64::MIN_POSITIVE],
            meshes: vec![quad(0), big, Mesh::default()],
        };
        let refs: Vec<MeshRef<'_>> = meshes.meshes.iter().map(Mesh::as_ref).collect();
        let bytes = encode(meshes.origin, &refs);
        assert_eq!(
            bytes.len(),
            HEADER_BYTES + refs.iter().map(encoded_len).sum::<usize>()
        );
        assert_eq!(decode(&bytes), Ok(meshes));
        for cut in [0, 4, 39, 40, 59, 60, 100, bytes.len() - 1] {
            assert!(decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let mut long = bytes.clone();
        long.extend_from_slice(&[0; 4]);
        assert_eq!(decode(&long), Err(MeshError::Trailing(4)));
        let one = encode([0.0; 3], &[quad(1).as_ref()]);
        let mut bad = one.clone();
        bad[4] = 2;
        assert_eq!(decode(&bad), Err(MeshError::Header));
        let mut bad = one.clone();
        bad[12] = 1; // the reserved word
        assert_eq!(decode(&bad), Err(MeshError::Header));
        let mut bad = one.clone();
        bad[44] |= 8; // an unknown flag
        assert_eq!(decode(&bad), Err(MeshError::Invalid(0)));
        let mut bad = one.clone();
        bad[40 + 20 + 48] = 4; // an index past the 4 vertices
        assert_eq!(decode(&bad), Err(MeshError::Invalid(0)));
        let mut bad = one;
        bad[8] = 200; // more meshes than bytes
        assert_eq!(decode(&bad), Err(MeshError::Truncated(0)));
    }
}
