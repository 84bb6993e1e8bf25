// WebGL2 drawing of a session's cameras, one quadrant each (the paper's
// layout). Plain WebGL2 rather than three.js: the vertex buffer's layout
// comes from SessionInfo.vertex_format (attribute offsets and strides, any
// layout), index buffers are patched in place by byte range, and the
// shading is one small program; three.js would add 600 KB and a scene graph
// to go round for each of those (docs/web.md).
//
// Lighting is Lambert with a directional light plus ambient, two-sided (scan
// borders and terrain edges show their back faces), as the Python renderer's.

const VERTEX = `#version 300 es
uniform mat4 u_mvp;      // projection * view, relative to u_origin
uniform vec3 u_origin;   // the mesh's centre: keeps coordinates small
in vec3 a_position;
in vec3 a_normal;
in vec4 a_color;
out vec3 v_normal;
out vec4 v_color;
void main() {
  gl_Position = u_mvp * vec4(a_position - u_origin, 1.0);
  v_normal = a_normal;
  v_color = a_color;
}`;

const FRAGMENT = `#version 300 es
precision highp float;
uniform vec3 u_light;
uniform vec3 u_tint;
in vec3 v_normal;
in vec4 v_color;
out vec4 colour;
void main() {
  vec3 n = normalize(v_normal);
  if (!gl_FrontFacing) n = -n;
  float diffuse = abs(dot(n, u_light));
  vec3 base = v_color.rgb * u_tint;
  colour = vec4(base * (0.3 + 0.7 * diffuse), 1.0);
}`;

// SessionInfo.vertex_format's semantics and scalar types (caveclod.proto).
const SEMANTIC = { 1: "a_position", 2: "a_normal", 4: "a_color" };
const FLOAT32 = 1, UINT8 = 2;

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(shader)}`);
  return shader;
}

/** A column-major perspective matrix. */
function perspective(fovYDeg, aspect, near, far) {
  const f = 1 / Math.tan((fovYDeg * Math.PI) / 360), nf = 1 / (near - far);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
}

/** A column-major view matrix looking from eye to target. */
function lookAt(eye, target, up) {
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => { const l = Math.hypot(...a) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const f = norm(sub(target, eye)), s = norm(cross(f, up)), u = cross(s, f);
  return [s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0, -dot(s, eye), -dot(u, eye), dot(f, eye), 1];
}

function multiply(a, b) {
  const out = new Array(16).fill(0);
  for (let col = 0; col < 4; col++) for (let row = 0; row < 4; row++) {
    for (let k = 0; k < 4; k++) out[4 * col + row] += a[4 * k + row] * b[4 * col + k];
  }
  return out;
}

/** The drawing-buffer rectangles [x, y, width, height] of `n` cameras: 1 whole, 2 side by side, 3-4 in quadrants. */
export function quadrants(n, width, height) {
  if (n === 1) return [[0, 0, width, height]];
  const w = Math.floor(width / 2), h = n === 2 ? height : Math.floor(height / 2);
  const rects = [];
  for (let c = 0; c < n; c++) {
    const col = c % 2, row = Math.floor(c / 2);
    rects.push([col * w, n === 2 ? 0 : height - (row + 1) * h, w, h]);
  }
  return rects;
}

export class Renderer {
  constructor(canvas) {
    const gl = canvas.getContext("webgl2", { antialias: true, preserveDrawingBuffer: true });
    if (!gl) throw new Error("this browser has no WebGL2; use a recent Chrome, Firefox or Safari");
    this.gl = gl;
    this.canvas = canvas;
    const program = gl.createProgram();
    gl.attachShader(program, compile(gl, gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(program)}`);
    this.program = program;
    this.uniforms = Object.fromEntries(["u_mvp", "u_origin", "u_light", "u_tint"].map((n) => [n, gl.getUniformLocation(program, n)]));
    this.vao = null;
    this.elements = []; // [camera][material] {buffer, capacity}
  }

  /** Upload the vertex buffer once (`payload`: the session's whole vertex payload, laid out as `format` says;
   *  `materials`: MeshInfo.materials, whose names pick the colours). With `morphCameras` (geomorphs), each
   *  camera draws from a position buffer of its own (writePositions), the other attributes shared. */
  setVertexBuffer(format, payload, lo, hi, materials, morphCameras = 0) {
    this.colours = materials.length ? materials.map((m, i) => materialColour(m.name, i)) : [materialColour("", 0)];
    const gl = this.gl;
    for (const v of this.vaos || []) gl.deleteVertexArray(v);
    for (const b of this.positions || []) gl.deleteBuffer(b);
    const buffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, payload, gl.STATIC_DRAW);
    const d = Number(format.vertexCount);
    this.positions = [];
    for (let c = 0; c < morphCameras; c++) {
      const own = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, own);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(payload.buffer, payload.byteOffset, 3 * d), gl.DYNAMIC_DRAW);
      this.positions.push(own);
    }
    this.vaos = [];
    for (let c = 0; c < Math.max(1, morphCameras); c++) {
      const vao = gl.createVertexArray();
      gl.bindVertexArray(vao);
      gl.vertexAttrib4f(gl.getAttribLocation(this.program, "a_color"), 1, 1, 1, 1); // no colours: the material's alone
      for (const a of format.attributes) {
        const name = SEMANTIC[a.semantic];
        const loc = name ? gl.getAttribLocation(this.program, name) : -1;
        if (loc < 0) continue;
        const type = a.type === FLOAT32 ? gl.FLOAT : a.type === UINT8 ? gl.UNSIGNED_BYTE : null;
        if (type === null) continue;
        const own = morphCameras && name === "a_position";
        gl.bindBuffer(gl.ARRAY_BUFFER, own ? this.positions[c] : buffer);
        gl.enableVertexAttribArray(loc);
        gl.vertexAttribPointer(loc, a.components, type, a.normalized, own ? 12 : a.stride, own ? 0 : Number(a.offset));
      }
      this.vaos.push(vao);
    }
    this.vao = this.vaos[0];
    gl.bindVertexArray(null);
    this.origin = [0, 1, 2].map((i) => 0.5 * (lo[i] + hi[i]));
    this.diagonal = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) || 1;
    for (const row of this.elements) for (const e of row) gl.deleteBuffer(e.buffer);
    this.elements = [];
  }

  /** Geomorphs: move `vertices` (Int32Array) of camera `c` to `positions` (3 floats each); each run of
   *  consecutive vertices is one write. */
  writePositions(c, vertices, positions) {
    if (!vertices.length || !this.positions[c]) return;
    const gl = this.gl;
    gl.bindVertexArray(null);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.positions[c]);
    let i = 0;
    while (i < vertices.length) {
      let j = i + 1;
      while (j < vertices.length && vertices[j] === vertices[j - 1] + 1) j++;
      gl.bufferSubData(gl.ARRAY_BUFFER, 12 * vertices[i], positions, 3 * i, 3 * (j - i));
      i = j;
    }
  }

  /** Bring the GPU's copy of each index buffer up to date: only the rows the frames wrote. */
  sync(buffers) {
    const gl = this.gl;
    gl.bindVertexArray(null);
    buffers.forEach((row, c) => {
      this.elements[c] = this.elements[c] || [];
      row.forEach((b, m) => {
        let e = this.elements[c][m];
        if (!e) e = this.elements[c][m] = { buffer: gl.createBuffer(), capacity: 0 };
        gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, e.buffer);
        if (b.grown || e.capacity < b.rows.length) {
          gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, b.rows, gl.DYNAMIC_DRAW);
          e.capacity = b.rows.length;
        } else if (b.dirtyLo <= b.dirtyHi) {
          gl.bufferSubData(gl.ELEMENT_ARRAY_BUFFER, 12 * b.dirtyLo, b.rows, 3 * b.dirtyLo, 3 * (b.dirtyHi - b.dirtyLo + 1));
        }
        b.grown = false;
        b.dirtyLo = Infinity;
        b.dirtyHi = -1;
      });
    });
  }

  /** Draw every camera in its quadrant: `poses[c]` {eye, target, up}, `counts[c][m]` triangles of each buffer. */
  draw(poses, counts, fovYDeg) {
    const gl = this.gl, canvas = this.canvas;
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(0.08, 0.09, 0.11, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (!this.vao) return;
    gl.enable(gl.DEPTH_TEST);
    gl.enable(gl.SCISSOR_TEST);
    gl.useProgram(this.program);
    gl.uniform3fv(this.uniforms.u_origin, this.origin);
    gl.uniform3fv(this.uniforms.u_light, [0.37, 0.45, 0.81]);
    quadrants(poses.length, canvas.width, canvas.height).forEach(([x, y, w, h], c) => {
      const pose = poses[c];
      if (!pose) return;
      gl.bindVertexArray(this.vaos[Math.min(c, this.vaos.length - 1)]);
      gl.viewport(x, y, w, h);
      gl.scissor(x, y, w, h);
      gl.clearColor(0.52 + 0.04 * c, 0.66, 0.82, 1);   // a sky, a shade apart per camera
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      const eye = pose.eye.map((v, i) => v - this.origin[i]), target = pose.target.map((v, i) => v - this.origin[i]);
      const far = Math.hypot(...eye) + this.diagonal, near = Math.max(far / 20000, 1e-6);
      gl.uniformMatrix4fv(this.uniforms.u_mvp, false, multiply(perspective(fovYDeg, w / h, near, far), lookAt(eye, target, pose.up)));
      (this.elements[c] || []).forEach((e, m) => {
        const count = counts[c][m];
        if (!count) return;
        gl.uniform3fv(this.uniforms.u_tint, this.colours[m] || materialColour("", m));
        gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, e.buffer);
        gl.drawElements(gl.TRIANGLES, 3 * count, gl.UNSIGNED_INT, 0);
      });
    });
    gl.disable(gl.SCISSOR_TEST);
    gl.bindVertexArray(null);
  }
}

// Base colours of the built-in terrains' classes (caveclod/render/textures.py's
// palette); the protocol carries material names, not textures.
const PALETTE = { water: [0.16, 0.34, 0.58], grass: [0.3, 0.5, 0.18], rock: [0.47, 0.44, 0.41], snow: [0.9, 0.93, 0.97] };

/** A material's colour: the palette's by name, else a light hue of its own. */
export function materialColour(name, m) {
  const known = PALETTE[(name || "").toLowerCase()];
  if (known) return known;
  if (m === 0) return [0.8, 0.8, 0.78];
  const h = (m * 0.618034) % 1;
  const k = (n) => (n + h * 6) % 6;
  const f = (n) => 1 - 0.35 * Math.max(0, Math.min(k(n), 4 - k(n), 1));
  return [f(5), f(3), f(1)];
}
