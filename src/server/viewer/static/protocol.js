// pvsd's binary wire formats, decoded in the browser:
// - application/x-pvs frames (proto/wire-format.md),
// - application/x-pvs-mesh messages (proto/mesh-format.md).
// Both decoders refuse what the documents do not allow, as the Rust ones do.

/** Reads the building blocks of an x-pvs message. */
class Reader {
  constructor(buffer) {
    this.bytes = new Uint8Array(buffer);
    this.at = 0;
  }

  byte() {
    if (this.at >= this.bytes.length) throw new Error(`x-pvs: the message ends at byte ${this.at}`);
    return this.bytes[this.at++];
  }

  // LEB128; ids are below 2^32 and frame numbers below 2^53 here, which
  // a double holds exactly.
  varint() {
    let value = 0;
    let scale = 1;
    for (;;) {
      const b = this.byte();
      value += (b & 0x7f) * scale;
      if ((b & 0x80) === 0) return value;
      scale *= 128;
      if (scale > 2 ** 56) throw new Error('x-pvs: a varint past 2^56');
    }
  }

  ids() {
    const n = this.varint();
    if (n > this.bytes.length - this.at) throw new Error('x-pvs: more ids than bytes');
    const out = new Array(n);
    let next = 0;
    for (let i = 0; i < n; i++) {
      const id = next + this.varint();
      if (id > 0xffffffff) throw new Error('x-pvs: an id past 2^32 - 1');
      out[i] = id;
      next = id + 1;
    }
    return out;
  }

  string() {
    const n = this.varint();
    if (n > this.bytes.length - this.at) throw new Error('x-pvs: a string past the end');
    const s = new TextDecoder('utf-8', { fatal: true }).decode(this.bytes.subarray(this.at, this.at + n));
    this.at += n;
    return s;
  }

  f64() {
    if (this.at + 8 > this.bytes.length) throw new Error('x-pvs: the message ends inside a number');
    const v = new DataView(this.bytes.buffer, this.bytes.byteOffset + this.at, 8).getFloat64(0, true);
    this.at += 8;
    return v;
  }
}

/**
 * A session frame: { frame, base, added, removed, users, stats }.
 * Apply `removed`, then `added`, to the set held for `base` (all of it
 * when `base` is null).
 */
export function decodeFrame(buffer) {
  const r = new Reader(buffer);
  if (r.byte() !== 0x46) throw new Error('x-pvs: not a frame message');
  const flags = r.byte();
  if (flags & ~7) throw new Error(`x-pvs: unknown flags ${flags}`);
  const frame = r.varint();
  const base = flags & 1 ? r.varint() : null;
  const added = r.ids();
  const removed = r.ids();
  let users = null;
  if (flags & 2) {
    const n = r.varint();
    users = [];
    for (let i = 0; i < n; i++) users.push(r.string());
  }
  let stats = null;
  if (flags & 4) {
    stats = { method: r.string(), cull_us: r.f64(), nodes_tested: r.varint() };
    const counted = r.byte();
    if (counted > 1) throw new Error('x-pvs: in_frustum is neither absent nor present');
    stats.in_frustum = counted ? r.varint() : null;
    stats.visible = r.varint();
    stats.fallback = r.string() || null;
    stats.fallback_reason = r.string() || null;
  }
  if (r.at !== r.bytes.length) throw new Error(`x-pvs: ${r.bytes.length - r.at} bytes after the frame`);
  return { frame, base, added, removed, users, stats };
}

const MAGIC = 0x4d535650; // "PVSM", little-endian

/**
 * A mesh message: { origin: [x, y, z], meshes: [{ id, movable, positions,
 * indices, opaque, bytes }] }. Positions and indices are views of `buffer`
 * (no copy); positions are relative to `origin`.
 */
export function decodeMeshes(buffer) {
  const view = new DataView(buffer);
  if (buffer.byteLength < 40 || view.getUint32(0, true) !== MAGIC || view.getUint32(4, true) !== 1
    || view.getUint32(12, true) !== 0) {
    throw new Error('x-pvs-mesh: not a version 1 message');
  }
  const count = view.getUint32(8, true);
  const origin = [16, 24, 32].map((at) => view.getFloat64(at, true));
  const meshes = [];
  let at = 40;
  for (let n = 0; n < count; n++) {
    if (at + 20 > buffer.byteLength) throw new Error(`x-pvs-mesh: the message ends inside mesh ${n}`);
    const start = at;
    const id = view.getUint32(at, true);
    const flags = view.getUint32(at + 4, true);
    const vertices = view.getUint32(at + 8, true);
    const triangles = view.getUint32(at + 12, true);
    const opaque = view.getUint32(at + 16, true);
    if (flags & ~3 || opaque > triangles) throw new Error(`x-pvs-mesh: mesh ${n} is malformed`);
    const small = (flags & 1) !== 0;
    if (small !== vertices <= 65536) throw new Error(`x-pvs-mesh: mesh ${n} has the wrong index size`);
    at += 20;
    const indexBytes = triangles * 3 * (small ? 2 : 4);
    const end = at + vertices * 12 + Math.ceil(indexBytes / 4) * 4;
    if (end > buffer.byteLength) throw new Error(`x-pvs-mesh: the message ends inside mesh ${n}`);
    const positions = new Float32Array(buffer, at, vertices * 3);
    at += vertices * 12;
    const indices = small ? new Uint16Array(buffer, at, triangles * 3) : new Uint32Array(buffer, at, triangles * 3);
    for (let i = 0; i < indices.length; i++) {
      if (indices[i] >= vertices) throw new Error(`x-pvs-mesh: mesh ${n} has an index past its vertices`);
    }
    for (let k = at + indexBytes; k < end; k++) {
      if (view.getUint8(k) !== 0) throw new Error(`x-pvs-mesh: mesh ${n} has nonzero padding`);
    }
    at = end;
    meshes.push({ id, movable: (flags & 2) !== 0, positions, indices, opaque, bytes: end - start });
  }
  if (at !== buffer.byteLength) throw new Error('x-pvs-mesh: bytes after the last mesh');
  return { origin, meshes };
}
