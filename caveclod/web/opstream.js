// Decoder of FRAME_ENCODING_OPS op streams (SurfaceDelta.ops): the proto's
// comment on `ops` is the specification, caveclod/opstream.py the Python
// decoder this one follows error for error. Anything inconsistent throws
// an OpStreamError (the page then asks for a keyframe), never a wrong buffer.

export class OpStreamError extends Error {}

const NEW = 0, COPY = 1, CORNER0 = 2, EDGE0 = 5, N_KINDS = 14, MAX_VARINT_BYTES = 9;

/** Every LEB128 varint of `bytes` (Uint8Array), as numbers (exact below 2^53). */
function readVarints(bytes) {
  const values = [];
  let pos = 0;
  while (pos < bytes.length) {
    let value = 0, scale = 1, used = 0;
    for (;;) {
      if (pos >= bytes.length) throw new OpStreamError(`the op stream's last varint is cut off (${bytes.length} bytes)`);
      const b = bytes[pos++];
      value += (b & 0x7f) * scale;
      if (b < 0x80) break;
      scale *= 128;
      if (++used >= MAX_VARINT_BYTES) throw new OpStreamError(`a varint of more than ${MAX_VARINT_BYTES} bytes in the op stream`);
    }
    values.push(value);
  }
  return values;
}

const unzigzag = (z) => (z % 2 === 0 ? z / 2 : -(z + 1) / 2);

/**
 * The slot writes an op stream encodes, against the buffer held before it.
 * @param {Uint8Array} ops the SurfaceDelta's ops
 * @param {Uint32Array} old the held buffer's rows, (oldCount * 3) values
 * @param {number} oldCount triangles held before this delta
 * @param {number} count the SurfaceDelta's count (triangles after it)
 * @param {number} nVertices vertex indices must be below it
 * @returns {{slots: Uint32Array, tris: Uint32Array}} n slots and (n * 3) vertices
 */
export function decodeOps(ops, old, oldCount, count, nVertices) {
  const values = readVarints(ops);
  if (values.length === 0) throw new OpStreamError("an empty op stream (it starts with the number of writes)");
  const n = values[0];
  if (n > values.length - 1) throw new OpStreamError(`the op stream announces ${n} writes but holds ${values.length - 1} varints`);
  const slots = new Uint32Array(n), kinds = new Uint8Array(n);
  let slot = -1, grown = 0, need = 0;
  for (let i = 0; i < n; i++) {
    const h = values[1 + i], kind = h % 16, gap = Math.floor(h / 16);
    if (kind >= N_KINDS) throw new OpStreamError(`op kind ${kind} is unknown (0 NEW, 1 COPY, 2-4 CORNER, 5-13 EDGE)`);
    if (gap >= count) throw new OpStreamError(`a slot gap of ${gap} in a buffer of ${count} triangles`);
    slot += gap + 1;
    if (slot >= count) throw new OpStreamError(`slot ${slot} past the count ${count}`);
    slots[i] = slot;
    kinds[i] = kind;
    if (slot >= oldCount) grown++;
    need += kind === NEW ? 3 : 1;
  }
  if (count > oldCount && grown !== count - oldCount) {
    throw new OpStreamError(`the buffer grows from ${oldCount} to ${count} triangles but not every new slot is written`);
  }
  if (need !== values.length - 1 - n) throw new OpStreamError(`${n} writes need ${need} payload varints, the stream holds ${values.length - 1 - n}`);
  const tris = new Uint32Array(3 * n);
  const vertex = (v) => {
    if (!(v >= 0 && v < nVertices)) throw new OpStreamError(`vertex index ${v} outside the vertex buffer's ${nVertices} vertices`);
    return v;
  };
  let p = 1 + n, last = 0;
  for (let i = 0; i < n; i++) {
    const kind = kinds[i], s = slots[i], o = 3 * i;
    if (kind === NEW) {
      for (let k = 0; k < 3; k++) { last += unzigzag(values[p++]); tris[o + k] = vertex(last); }
    } else if (kind === COPY) {
      const r = values[p++];
      if (r >= oldCount) throw new OpStreamError(`a COPY from ${r} slots before the end of a buffer of ${oldCount}`);
      const from = 3 * (oldCount - 1 - r);
      tris[o] = old[from]; tris[o + 1] = old[from + 1]; tris[o + 2] = old[from + 2];
    } else if (kind < EDGE0) {
      if (s >= oldCount) throw new OpStreamError(`a CORNER write to slot ${s}, which the buffer of ${oldCount} triangles does not hold yet`);
      const c = kind - CORNER0;
      tris[o] = old[3 * s]; tris[o + 1] = old[3 * s + 1]; tris[o + 2] = old[3 * s + 2];
      const v = old[3 * s + c] + unzigzag(values[p++]);
      if (!(v >= 0 && v < nVertices)) throw new OpStreamError(`a CORNER write to a vertex outside the vertex buffer's ${nVertices} vertices`);
      tris[o + c] = v;
    } else {
      if (i === 0 || kinds[i - 1] !== NEW) throw new OpStreamError("an EDGE write that does not follow a NEW one");
      const e = Math.floor((kind - EDGE0) / 3), q = (kind - EDGE0) % 3, prev = o - 3;
      last += unzigzag(values[p++]);
      tris[o + q] = tris[prev + (e + 1) % 3];
      tris[o + (q + 1) % 3] = tris[prev + e];
      tris[o + (q + 2) % 3] = vertex(last);
    }
  }
  return { slots, tris };
}
