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

// -- FRAME_ENCODING_OPS_LINKED: the proto's "OPS_LINKED" (caveclod/opstream.py's decode_linked) --

const SPLIT0 = 5, MERGE0 = 8, ADJ = 11, ADJ_TX = 12, ADJ_TY = 13, N_LINKED_KINDS = 14;
const LINKED_PAYLOAD = [3, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 2, 1, 1];
const APPENDED_KINDS = [NEW, COPY, ADJ, ADJ_TX, ADJ_TY], APPENDED_PER_VARINT = 3, APPENDED_PACK_LIMIT = 125;
const Z_MODES = 4, Z_DELTA = 0, Z_CHILD_X = 1, Z_CHILD_Y = 2;
const LINKED_KIND_NAMES = "0 NEW, 1 COPY, 2-4 CORNER, 5-7 SPLIT, 8-10 MERGE, 11-13 ADJ";

/**
 * The children of each vertex under the morph targets: the other vertices whose
 * target it is, ascending (what SPLIT and ADJ name vertices by). Once per vertex buffer.
 * @param {Uint32Array} targets each vertex's morph target (its own index without one)
 */
export function linksOf(targets) {
  const d = targets.length, start = new Int32Array(d + 1);
  for (let v = 0; v < d; v++) if (targets[v] !== v) start[targets[v] + 1]++;
  for (let v = 0; v < d; v++) start[v + 1] += start[v];
  const children = new Int32Array(start[d]), fill = start.slice(0, d);
  for (let v = 0; v < d; v++) if (targets[v] !== v) children[fill[targets[v]]++] = v;   // ascending v
  return { targets, start, children };
}

/**
 * decodeOps for FRAME_ENCODING_OPS_LINKED streams.
 * @param {Uint8Array} ops @param {Uint32Array} old @param {number} oldCount @param {number} count
 * @param {{targets: Uint32Array, start: Int32Array, children: Int32Array}} links from linksOf
 * @returns {{slots: Uint32Array, tris: Uint32Array}}
 */
export function decodeLinked(ops, old, oldCount, count, links) {
  const nVertices = links.targets.length;
  const values = readVarints(ops);
  if (values.length === 0) throw new OpStreamError("an empty op stream (it starts with the number of writes)");
  const n = values[0], appended = Math.max(count - oldCount, 0), inPlace = n - appended;
  const packs = Math.ceil(appended / APPENDED_PER_VARINT);
  if (inPlace < 0) throw new OpStreamError(`the buffer grows from ${oldCount} to ${count} triangles but the op stream announces only ${n} writes`);
  if (inPlace + packs > values.length - 1) throw new OpStreamError(`the op stream announces ${n} writes but holds ${values.length - 1} varints`);
  const slots = new Uint32Array(n), kinds = new Uint8Array(n), first = new Array(n);
  let slot = -1;
  for (let i = 0; i < inPlace; i++) {
    const h = values[1 + i], kind = h % 16, gap = Math.floor(h / 16);
    if (kind >= N_LINKED_KINDS) throw new OpStreamError(`op kind ${kind} is unknown (${LINKED_KIND_NAMES})`);
    if (gap >= count) throw new OpStreamError(`a slot gap of ${gap} in a buffer of ${count} triangles`);
    slot += gap + 1;
    slots[i] = slot;
    kinds[i] = kind;
  }
  const keep = Math.min(oldCount, count);
  if (inPlace > 0 && slot >= keep) throw new OpStreamError(`slot ${slot} of an in-place write, past the ${keep} slots the buffer keeps`);
  for (let g = 0; g < packs; g++) {
    let pack = values[1 + inPlace + g];
    if (pack >= APPENDED_PACK_LIMIT) throw new OpStreamError(`appended writes' kinds ${pack} (at most ${APPENDED_PACK_LIMIT - 1})`);
    for (let t = 0; t < APPENDED_PER_VARINT; t++) {
      const i = inPlace + APPENDED_PER_VARINT * g + t;
      if (i < n) { kinds[i] = APPENDED_KINDS[pack % APPENDED_KINDS.length]; slots[i] = oldCount + (i - inPlace); }
      pack = Math.floor(pack / APPENDED_KINDS.length);
    }
  }
  let need = 0;
  for (let i = 0; i < n; i++) { first[i] = 1 + inPlace + packs + need; need += LINKED_PAYLOAD[kinds[i]]; }
  if (need !== values.length - 1 - inPlace - packs) {
    throw new OpStreamError(`${n} writes need ${need} payload varints, the stream holds ${values.length - 1 - inPlace - packs}`);
  }
  const vertex = (v) => {
    if (!(v >= 0 && v < nVertices)) throw new OpStreamError(`vertex index ${v} outside the vertex buffer's ${nVertices} vertices`);
    return v;
  };
  const child = (x, r) => {
    const have = links.start[x + 1] - links.start[x];
    if (!(r < have)) throw new OpStreamError(`child ${r} of vertex ${x}, which has ${have} (see the morph targets)`);
    return links.children[links.start[x] + r];
  };
  const tris = new Uint32Array(3 * n), done = new Uint8Array(n);
  for (let i = 0; i < n; i++) {                  // the base writes: from the old buffer
    const kind = kinds[i], o = 3 * i, p = first[i];
    if (kind === COPY) {
      const r = values[p];
      if (r >= oldCount) throw new OpStreamError(`a COPY from ${r} slots before the end of a buffer of ${oldCount}`);
      const from = 3 * (oldCount - 1 - r);
      tris[o] = old[from]; tris[o + 1] = old[from + 1]; tris[o + 2] = old[from + 2];
    } else if (kind >= CORNER0 && kind < ADJ) {
      const s = 3 * slots[i];
      tris[o] = old[s]; tris[o + 1] = old[s + 1]; tris[o + 2] = old[s + 2];
      const c = (kind - CORNER0) % 3, x = old[s + c];
      tris[o + c] = kind < SPLIT0 ? vertex(x + unzigzag(values[p])) : kind < MERGE0 ? child(x, values[p]) : links.targets[x];
    } else continue;
    done[i] = 1;
  }
  const named = (j, i) => {
    if (!(j >= 0 && j < n) || j === i) throw new OpStreamError(`write ${i} names write ${j} of ${n}`);
    if (!done[j]) throw new OpStreamError(`write ${i} names write ${j}, a NEW or ADJ write after it`);
    return 3 * j;
  };
  let last = 0;
  for (let i = 0; i < n; i++) {                  // then NEW and ADJ, in stream order
    const kind = kinds[i], o = 3 * i, p = first[i];
    if (kind === NEW) {
      for (let k = 0; k < 3; k++) { last += unzigzag(values[p + k]); tris[o + k] = vertex(last); }
    } else if (kind >= ADJ) {
      const h = values[p], w = kind === ADJ ? values[p + 1] : 0;
      const j = named(i + unzigzag(Math.floor(h / 9)), i), e = Math.floor((h % 9) / 3), q = h % 3;
      const x = tris[j + e], y = tris[j + (e + 1) % 3];
      const v = Math.floor(w / Z_MODES), mode = w % Z_MODES;
      let z;
      if (kind !== ADJ) z = links.targets[kind === ADJ_TX ? x : y];
      else if (mode === Z_DELTA) { last += unzigzag(v); z = vertex(last); }
      else if (mode === Z_CHILD_X || mode === Z_CHILD_Y) z = child(mode === Z_CHILD_X ? x : y, v);
      else z = tris[named(i + unzigzag(Math.floor(v / 3)), i) + v % 3];
      tris[o + q] = y; tris[o + (q + 1) % 3] = x; tris[o + (q + 2) % 3] = z;
    }
    done[i] = 1;
  }
  return { slots, tris };
}
