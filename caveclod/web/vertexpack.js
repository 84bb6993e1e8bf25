// The packed vertex download (VERTEX_ENCODING_PACKED): inflate, undo the deltas,
// dequantize into the PLANAR float32 payload that SessionInfo.vertex_format
// describes. The proto's VertexPacking comment is the specification; every step
// is float64 arithmetic in its order, then rounded to float32 by the
// Float32Array store, so this page makes the bytes caveclod.vertexpack makes
// (the session checks SessionInfo.vertex_payload_crc32 against them).

export class PackedVertexError extends Error {}

const COLOR = 4; // AttributeSemantic.ATTRIBUTE_SEMANTIC_COLOR
const MORPH_TARGET = 5; // AttributeSemantic.ATTRIBUTE_SEMANTIC_MORPH_TARGET

async function inflate(bytes) {
  // zlib format (RFC 1950): the Compression Streams API's "deflate".
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
  try {
    return new Uint8Array(await new Response(stream).arrayBuffer());
  } catch (err) {
    throw new PackedVertexError(`the packed vertex buffer does not inflate (${err.message}); it is damaged: reload the page, or open it with ?vertices=float32`);
  }
}

/** Decode stream `s` of `raw` (four byte planes of d bytes) into `out[i * stride + offset]`, mapped by `f`. */
function decodeStream(raw, s, d, f, out, stride, offset) {
  const base = 4 * d * s;
  let q = 0;
  for (let i = 0; i < d; i++) {
    const z = raw[base + i] | (raw[base + d + i] << 8) | (raw[base + 2 * d + i] << 16) | (raw[base + 3 * d + i] << 24);
    q = (q + ((z >>> 1) ^ -(z & 1))) | 0;
    out[i * stride + offset] = f(q);
  }
}

/**
 * The decoded PLANAR payload (Uint8Array) of a packed vertex buffer.
 * @param {object} packing SessionInfo.vertexPacking
 * @param {object} format SessionInfo.vertexFormat (PLANAR: position, normal, texcoord[, color])
 * @param {Uint8Array} packed the VertexChunk data, concatenated
 */
export async function unpackVertices(packing, format, packed) {
  const d = Number(format.vertexCount);
  const hasColor = format.attributes.some((a) => a.semantic === COLOR);
  const hasMorph = format.attributes.some((a) => a.semantic === MORPH_TARGET);
  const k = 7 + (hasColor ? 4 : 0) + (hasMorph ? 1 : 0);
  const raw = await inflate(packed);
  if (raw.length !== 4 * d * k) {
    throw new PackedVertexError(`the packed vertex buffer inflates to ${raw.length} bytes where ${d} vertices need ${4 * d * k}; it is damaged: reload the page`);
  }
  const out = new Uint8Array(d * (32 + (hasColor ? 4 : 0) + (hasMorph ? 4 : 0)));
  const pos = new Float32Array(out.buffer, 0, 3 * d);
  const nrm = new Float32Array(out.buffer, 12 * d, 3 * d);
  const uv = new Float32Array(out.buffer, 24 * d, 2 * d);
  const o = packing.positionOrigin || { x: 0, y: 0, z: 0 };
  const step = packing.positionStep;
  [o.x, o.y, o.z].forEach((origin, c) => decodeStream(raw, c, d, (q) => origin + q * step, pos, 3, c));
  // Octahedral normals: both codes first, then the unfolding, in the proto's order.
  const qa = new Int32Array(d), qb = new Int32Array(d);
  decodeStream(raw, 3, d, (q) => q, qa, 1, 0);
  decodeStream(raw, 4, d, (q) => q, qb, 1, 0);
  const s = 2 ** (packing.normalBits - 1) - 1;
  for (let i = 0; i < d; i++) {
    let x = qa[i] / s, y = qb[i] / s;
    const z = 1 - Math.abs(x) - Math.abs(y);
    const t = Math.max(-z, 0);
    x = x >= 0 ? x - t : x + t;
    y = y >= 0 ? y - t : y + t;
    const n = Math.sqrt(x * x + y * y + z * z);
    nrm[3 * i] = x / n;
    nrm[3 * i + 1] = y / n;
    nrm[3 * i + 2] = z / n;
  }
  const tstep = packing.texcoordStep;
  for (let c = 0; c < 2; c++) decodeStream(raw, 5 + c, d, (q) => q * tstep, uv, 2, c);
  if (hasColor) {
    const col = new Uint8Array(out.buffer, 32 * d, 4 * d);
    for (let c = 0; c < 4; c++) decodeStream(raw, 7 + c, d, (q) => q, col, 4, c);
  }
  if (hasMorph) {
    // The target's index minus the vertex's own; out of range: damaged (the CRC check says so too).
    const morph = new Uint32Array(out.buffer, (32 + (hasColor ? 4 : 0)) * d, d);
    const rel = new Int32Array(d);
    decodeStream(raw, k - 1, d, (q) => q, rel, 1, 0);
    for (let i = 0; i < d; i++) {
      const t = rel[i] + i;
      if (t < 0 || t >= d) throw new PackedVertexError("the packed vertex buffer's morph targets fall outside the buffer; it is damaged: reload the page");
      morph[i] = t;
    }
  }
  return out;
}
