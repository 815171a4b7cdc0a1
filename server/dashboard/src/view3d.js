// The 3D view: the scene's quads drawn with WebGL2, lit by the streamed
// lightmap, with an orbit camera and direct manipulation of dynamic objects.
//
// Geometry comes from the `Welcome` (SceneInfo): every surface is a quad in
// object-local coordinates, corners in winding order [origin, origin+u,
// origin+u+v, origin+v], with a rectangle in the atlas. Texel centres lie on
// the quad's edges (ARCHITECTURE.md, atlas.rs: texel (a, b) of a w x h chart
// sits at patch parameters a/(w-1), b/(h-1)), so a corner maps to the centre
// of the chart's corner texel and bilinear filtering never reads outside the
// chart. The lightmap is uploaded as received: RGB9E5 words are a native
// WebGL2 format (RGB9_E5, filterable), RGBA16F likewise. The fragment shader
// is the GPU twin of the one tone curve (tone.js, `protocol/src/tone.rs`):
// sRGB(clamp(1 - exp(-max(B, 0) * exposure), 0, 1)) at the page's exposure,
// 1 / white point times 2^EV; the canvas stores it in 8 bits.
//
// Mouse: drag the background to orbit, wheel to zoom; drag a dynamic object
// (outlined) to slide it on its horizontal plane, shift-drag or right-drag it
// to turn it about the vertical axis; drag a point or spot light's gizmo to
// slide the light on its horizontal plane likewise.
//
// The scene's point, spot and directional lights (`setLights`, from the
// lights route) are drawn as gizmos in their colours after the surfaces,
// depth-tested, where their current states put them (`setLightStates`;
// gizmos.js has their geometry); `setShowLights(false)` hides them.

import { FLOATS_PER_VERTEX, gizmoSize, lightGizmos, placedLights } from './gizmos.js';

const VERTEX = `#version 300 es
layout(location = 0) in vec3 aPos;
layout(location = 1) in vec2 aUv;
uniform mat4 uViewProj;
uniform mat4 uModel;
out vec2 vUv;
void main() {
  vUv = aUv;
  gl_Position = uViewProj * uModel * vec4(aPos, 1.0);
}`;

const FRAGMENT = `#version 300 es
precision highp float;
in vec2 vUv;
uniform sampler2D uLightmap;
uniform float uExposure;
out vec4 outColor;
vec3 srgb(vec3 c) {
  return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
void main() {
  vec3 b = max(texture(uLightmap, vUv).rgb, vec3(0.0));
  vec3 y = 1.0 - exp(-b * uExposure);
  outColor = vec4(srgb(clamp(y, 0.0, 1.0)), 1.0);
}`;

const LINE_VERTEX = `#version 300 es
layout(location = 0) in vec3 aPos;
uniform mat4 uViewProj;
uniform mat4 uModel;
void main() { gl_Position = uViewProj * uModel * vec4(aPos, 1.0); }`;

const LINE_FRAGMENT = `#version 300 es
precision mediump float;
uniform vec4 uColor;
out vec4 outColor;
void main() { outColor = uColor; }`;

// Light gizmos: a colour per vertex, encoded to sRGB like the surfaces.
const GIZMO_VERTEX = `#version 300 es
layout(location = 0) in vec3 aPos;
layout(location = 1) in vec3 aColor;
uniform mat4 uViewProj;
out vec3 vColor;
void main() {
  vColor = aColor;
  gl_Position = uViewProj * vec4(aPos, 1.0);
}`;

const GIZMO_FRAGMENT = `#version 300 es
precision mediump float;
in vec3 vColor;
out vec4 outColor;
vec3 srgb(vec3 c) {
  return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
void main() { outColor = vec4(srgb(clamp(vColor, 0.0, 1.0)), 1.0); }`;

/** The clear colour; the e2e test counts pixels that differ from it. */
export const BACKGROUND = [0.07, 0.08, 0.1];

// --- Small vector, quaternion and matrix helpers (column-major mat4). ---

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale3 = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const normalize = (a) => scale3(a, 1 / (Math.hypot(...a) || 1));

/** Rotates `v` by the unit quaternion `q` = [x, y, z, w]. */
function rotate(q, v) {
  const u = [q[0], q[1], q[2]];
  const t = scale3(cross(u, v), 2);
  return add(add(v, scale3(t, q[3])), cross(u, t));
}

/** Hamilton product a * b (apply b, then a). */
export function quatMul(a, b) {
  return [
    a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1],
    a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
    a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3],
    a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2],
  ];
}

/** A turn of `angle` radians about +y. */
export function quatYaw(angle) {
  return [0, Math.sin(angle / 2), 0, Math.cos(angle / 2)];
}

/** The model matrix of a pose: p' = translation + rotation * (scale * p). */
function poseMatrix(pose) {
  const s = pose.scale;
  const x = rotate(pose.rotation, [s, 0, 0]);
  const y = rotate(pose.rotation, [0, s, 0]);
  const z = rotate(pose.rotation, [0, 0, s]);
  const t = pose.translation;
  return new Float32Array([...x, 0, ...y, 0, ...z, 0, ...t, 1]);
}

function transformPoint(pose, p) {
  return add(pose.translation, rotate(pose.rotation, scale3(p, pose.scale)));
}

function multiply(a, b) {
  const out = new Float32Array(16);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      out[c * 4 + r] = s;
    }
  }
  return out;
}

function perspective(fovy, aspect, near, far) {
  const f = 1 / Math.tan(fovy / 2);
  const nf = 1 / (near - far);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
}

function lookAt(eye, target, up) {
  const z = normalize(sub(eye, target));
  const x = normalize(cross(up, z));
  const y = cross(z, x);
  return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
}

/** The distance along a ray (unit `dir`) to the point nearest `p`, and
 * how far `p` is from the ray there; null if `p` is behind the origin. */
function rayPoint(origin, dir, p) {
  const t = dot(sub(p, origin), dir);
  if (t <= 0) return null;
  return { t, distance: Math.hypot(...sub(p, add(origin, scale3(dir, t)))) };
}

/** Slab test of a ray against an axis-aligned box; the entry distance or null. */
function rayBox(origin, dir, lo, hi) {
  let t0 = -Infinity;
  let t1 = Infinity;
  for (let i = 0; i < 3; i++) {
    if (Math.abs(dir[i]) < 1e-12) {
      if (origin[i] < lo[i] || origin[i] > hi[i]) return null;
      continue;
    }
    let a = (lo[i] - origin[i]) / dir[i];
    let b = (hi[i] - origin[i]) / dir[i];
    if (a > b) [a, b] = [b, a];
    t0 = Math.max(t0, a);
    t1 = Math.min(t1, b);
  }
  if (t0 > t1 || t1 < 0) return null;
  return Math.max(t0, 0);
}

function compile(gl, vertex, fragment) {
  const program = gl.createProgram();
  for (const [type, source] of [
    [gl.VERTEX_SHADER, vertex],
    [gl.FRAGMENT_SHADER, fragment],
  ]) {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
      throw new Error(`shader does not compile: ${gl.getShaderInfoLog(shader)}`);
    }
    gl.attachShader(program, shader);
  }
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) {
    throw new Error(`shaders do not link: ${gl.getProgramInfoLog(program)}`);
  }
  return program;
}

/**
 * A vertex array, left bound, over a new buffer of `data` (floats): one
 * attribute per entry of `sizes` (its float count), at locations 0, 1, ...,
 * interleaved. Returns the vertex array and its buffer.
 */
function vertexArray(gl, data, sizes) {
  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  const buffer = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(data), gl.STATIC_DRAW);
  const stride = 4 * sizes.reduce((a, b) => a + b, 0);
  let offset = 0;
  sizes.forEach((size, location) => {
    gl.enableVertexAttribArray(location);
    gl.vertexAttribPointer(location, size, gl.FLOAT, false, stride, offset);
    offset += 4 * size;
  });
  return [vao, buffer];
}

/**
 * The lightmap coordinates of a surface's four corners (PROTOCOL.md §3):
 * `uvs` when it carries four (a triangle on its mesh's own lightmap UVs,
 * version 3), else the centres of its chart's corner texels, in [0, 1].
 */
export function cornerUvs(s, W, H) {
  if (s.uvs && s.uvs.length === 4) return s.uvs.map((uv) => [uv[0], uv[1]]);
  const [x, y, w, h] = s.rect;
  const u0 = (x + 0.5) / W;
  const u1 = (x + w - 0.5) / W;
  const v0 = (y + 0.5) / H;
  const v1 = (y + h - 0.5) / H;
  return [
    [u0, v0],
    [u1, v0],
    [u1, v1],
    [u0, v1],
  ];
}

export class View3D {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {{onDrag?: (object: number, pose: object) => void,
   *   onLightDrag?: (light: number, position: number[]) => void}} callbacks
   *   `onDrag` is called with every pose the user gives a dynamic object,
   *   `onLightDrag` with every position the user drags a light to (the
   *   view draws the light there once `setLightStates` says so).
   * Throws if WebGL2 is unavailable.
   */
  constructor(canvas, callbacks = {}) {
    this.canvas = canvas;
    // preserveDrawingBuffer: the picture stays readable (screenshots, tests)
    // between frames; the view redraws only when something changed.
    const gl = canvas.getContext('webgl2', { antialias: true, preserveDrawingBuffer: true });
    if (!gl) throw new Error('this browser has no WebGL2');
    this.gl = gl;
    this.onDrag = callbacks.onDrag ?? (() => {});
    this.onLightDrag = callbacks.onLightDrag ?? (() => {});
    this.program = compile(gl, VERTEX, FRAGMENT);
    this.lineProgram = compile(gl, LINE_VERTEX, LINE_FRAGMENT);
    this.gizmoProgram = compile(gl, GIZMO_VERTEX, GIZMO_FRAGMENT);
    this.uniforms = {
      viewProj: gl.getUniformLocation(this.program, 'uViewProj'),
      model: gl.getUniformLocation(this.program, 'uModel'),
      lightmap: gl.getUniformLocation(this.program, 'uLightmap'),
      exposure: gl.getUniformLocation(this.program, 'uExposure'),
      lineViewProj: gl.getUniformLocation(this.lineProgram, 'uViewProj'),
      lineModel: gl.getUniformLocation(this.lineProgram, 'uModel'),
      lineColor: gl.getUniformLocation(this.lineProgram, 'uColor'),
      gizmoViewProj: gl.getUniformLocation(this.gizmoProgram, 'uViewProj'),
    };
    this.texture = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, 1, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array([0, 0, 0, 255]));
    for (const [k, v] of [
      [gl.TEXTURE_MIN_FILTER, gl.LINEAR],
      [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
      [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE],
      [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE],
    ]) {
      gl.texParameteri(gl.TEXTURE_2D, k, v);
    }
    this.objects = [];
    /** The scene's lights (entries of the lights route), their states
     * (SceneInfo order), the entries where the states put them, and their
     * gizmos. */
    this.lights = [];
    this.lightStates = [];
    this.placed = [];
    this.gizmos = null;
    this.showLights = true;
    /** Whether the user may drag dynamic objects (`draggable`) and lights. */
    this.draggable = false;
    this.lightsDraggable = false;
    this.exposure = 1;
    this.camera = { yaw: 0, pitch: 0.12, distance: 10, target: [0, 0, 0] };
    this.drag = null;
    /** What the pointer is over (`pick`), or null. */
    this.hover = null;
    this.framesDrawn = 0;
    this.needsDraw = true;
    this.installInput();
    const debug = gl.getExtension('WEBGL_debug_renderer_info');
    /** The GL renderer string (e.g. SwiftShader in headless tests). */
    this.renderer = debug ? gl.getParameter(debug.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
  }

  /** Builds buffers for a scene (the `scene` of a Welcome) and frames the camera. */
  setScene(scene) {
    const gl = this.gl;
    for (const o of this.objects) {
      gl.deleteVertexArray(o.vao);
      gl.deleteVertexArray(o.lineVao);
      for (const b of o.buffers) gl.deleteBuffer(b);
    }
    const W = scene.atlas_width;
    const H = scene.atlas_height;
    this.objects = scene.objects.map((info, index) => {
      const surfaces = scene.surfaces.filter((s) => s.object === index);
      const vertices = [];
      const lines = [];
      const indices = [];
      const lo = [Infinity, Infinity, Infinity];
      const hi = [-Infinity, -Infinity, -Infinity];
      let reach = 0; // farthest corner from the local y axis
      surfaces.forEach((s, k) => {
        const uvs = cornerUvs(s, W, H);
        s.corners.forEach((c, i) => {
          vertices.push(...c, ...uvs[i]);
          reach = Math.max(reach, Math.hypot(c[0], c[2]));
          for (let a = 0; a < 3; a++) {
            lo[a] = Math.min(lo[a], c[a]);
            hi[a] = Math.max(hi[a], c[a]);
          }
        });
        for (let i = 0; i < 4; i++) lines.push(...s.corners[i], ...s.corners[(i + 1) % 4]);
        const b = k * 4;
        indices.push(b, b + 1, b + 2, b, b + 2, b + 3);
      });
      // Position and atlas UV per vertex; the indices belong to this VAO.
      const [vao, vbo] = vertexArray(gl, vertices, [3, 2]);
      const ibo = gl.createBuffer();
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ibo);
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint32Array(indices), gl.STATIC_DRAW);
      const [lineVao, lbo] = vertexArray(gl, lines, [3]);
      gl.bindVertexArray(null);
      return {
        info,
        pose: structuredClone(info.pose),
        vao,
        lineVao,
        buffers: [vbo, ibo, lbo],
        count: indices.length,
        lineCount: lines.length / 3,
        lo,
        hi,
        reach,
      };
    });
    // Frame the static geometry.
    const lo = [Infinity, Infinity, Infinity];
    const hi = [-Infinity, -Infinity, -Infinity];
    for (const o of this.objects) {
      if (o.info.dynamic || o.count === 0) continue;
      for (const s of scene.surfaces.filter((s) => scene.objects[s.object] === o.info)) {
        for (const c of s.corners) {
          const p = transformPoint(o.pose, c);
          for (let a = 0; a < 3; a++) {
            lo[a] = Math.min(lo[a], p[a]);
            hi[a] = Math.max(hi[a], p[a]);
          }
        }
      }
    }
    if (!Number.isFinite(lo[0])) {
      lo.fill(-1);
      hi.fill(1);
    }
    this.bounds = { lo, hi };
    this.camera.target = scale3(add(lo, hi), 0.5);
    this.camera.distance = Math.hypot(...sub(hi, lo)) * 1.05;
    this.camera.yaw = 0;
    this.camera.pitch = 0.12;
    this.buildGizmos();
    this.needsDraw = true;
  }

  /** Sets the lights to draw as gizmos (entries of the lights route; [] for none). */
  setLights(lights) {
    this.lights = Array.isArray(lights) ? lights : [];
    this.buildGizmos();
    this.needsDraw = true;
  }

  /** Sets the lights' states (LightStates in SceneInfo order): where the
   * gizmos are drawn, which way they point and their colours. */
  setLightStates(states) {
    this.lightStates = states;
    this.buildGizmos();
    this.needsDraw = true;
  }

  /** Shows or hides the light gizmos. */
  setShowLights(show) {
    this.showLights = !!show;
    this.needsDraw = true;
  }

  /** How many light gizmo segments there are to draw (for tests and tools). */
  gizmoSegments() {
    return this.gizmos ? this.gizmos.count / 2 : 0;
  }

  /** (Re)builds the gizmos' buffer: their size and a sun's place follow the bounds. */
  buildGizmos() {
    const gl = this.gl;
    if (this.gizmos) {
      gl.deleteVertexArray(this.gizmos.vao);
      gl.deleteBuffer(this.gizmos.buffer);
      this.gizmos = null;
    }
    this.placed = placedLights(this.lights, this.lightStates);
    const data = lightGizmos(this.placed, this.bounds);
    if (!data.length) return;
    const [vao, buffer] = vertexArray(gl, data, [3, 3]);
    gl.bindVertexArray(null);
    this.gizmos = { vao, buffer, count: data.length / FLOATS_PER_VERTEX };
  }

  /** Where a dynamic object's translation may go on x and z: inside the
   * static geometry's bounds, kept far enough from them that the object,
   * turned any way about y, does not poke through a wall. */
  translationRange(index) {
    const o = this.objects[index];
    const r = o ? o.reach * o.pose.scale : 0;
    const range = (a) => {
      const lo = this.bounds.lo[a] + r;
      const hi = this.bounds.hi[a] - r;
      return lo <= hi ? [lo, hi] : [(lo + hi) / 2, (lo + hi) / 2];
    };
    return { x: range(0), z: range(2) };
  }

  /** Sets an object's pose (from a drag here, or the app). */
  setPose(index, pose) {
    if (this.objects[index]) {
      this.objects[index].pose = structuredClone(pose);
      this.needsDraw = true;
    }
  }

  pose(index) {
    return this.objects[index]?.pose;
  }

  /** Uploads the whole lightmap (a `Lightmap`) as a texture. */
  uploadLightmap(map) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 4);
    if (map.format === 'Rgb9e5') {
      const words = new Uint32Array(map.bytes.buffer, map.bytes.byteOffset, map.width * map.height);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB9_E5, map.width, map.height, 0, gl.RGB, gl.UNSIGNED_INT_5_9_9_9_REV, words);
    } else {
      const halves = new Uint16Array(map.bytes.buffer, map.bytes.byteOffset, map.width * map.height * 4);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA16F, map.width, map.height, 0, gl.RGBA, gl.HALF_FLOAT, halves);
    }
    this.hasLightmap = true;
    this.needsDraw = true;
  }

  setExposure(exposure) {
    this.exposure = exposure;
    this.needsDraw = true;
  }

  eye() {
    const { yaw, pitch, distance, target } = this.camera;
    return add(target, [distance * Math.sin(yaw) * Math.cos(pitch), distance * Math.sin(pitch), distance * Math.cos(yaw) * Math.cos(pitch)]);
  }

  matrices() {
    const canvas = this.canvas;
    const aspect = canvas.width / Math.max(1, canvas.height);
    const fovy = (45 * Math.PI) / 180;
    const d = this.camera.distance;
    const proj = perspective(fovy, aspect, d * 0.01, d * 10);
    const view = lookAt(this.eye(), this.camera.target, [0, 1, 0]);
    return { proj, view, viewProj: multiply(proj, view), fovy, aspect };
  }

  resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(this.canvas.clientWidth * dpr));
    const h = Math.max(1, Math.round(this.canvas.clientHeight * dpr));
    if (this.canvas.width !== w || this.canvas.height !== h) {
      this.canvas.width = w;
      this.canvas.height = h;
      this.needsDraw = true;
    }
  }

  /** Draws if anything changed. Call once per animation frame. */
  draw() {
    this.resize();
    if (!this.needsDraw) return;
    this.needsDraw = false;
    const gl = this.gl;
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.clearColor(...BACKGROUND, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    const { viewProj } = this.matrices();
    gl.useProgram(this.program);
    gl.uniformMatrix4fv(this.uniforms.viewProj, false, viewProj);
    gl.uniform1f(this.uniforms.exposure, this.exposure);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.uniform1i(this.uniforms.lightmap, 0);
    for (const o of this.objects) {
      if (!o.count) continue;
      gl.uniformMatrix4fv(this.uniforms.model, false, poseMatrix(o.pose));
      gl.bindVertexArray(o.vao);
      gl.drawElements(gl.TRIANGLES, o.count, gl.UNSIGNED_INT, 0);
    }
    // Outline what can be dragged.
    gl.useProgram(this.lineProgram);
    gl.uniformMatrix4fv(this.uniforms.lineViewProj, false, viewProj);
    gl.depthFunc(gl.LEQUAL);
    this.objects.forEach((o, i) => {
      if (!o.info.dynamic || !o.lineCount) return;
      const active = this.drag?.object === i || this.hover?.object === i;
      gl.uniform4fv(this.uniforms.lineColor, active ? [1, 0.8, 0.2, 1] : [0.95, 0.65, 0.15, 0.6]);
      gl.uniformMatrix4fv(this.uniforms.lineModel, false, poseMatrix(o.pose));
      gl.bindVertexArray(o.lineVao);
      gl.drawArrays(gl.LINES, 0, o.lineCount);
    });
    if (this.showLights && this.gizmos) {
      gl.useProgram(this.gizmoProgram);
      gl.uniformMatrix4fv(this.uniforms.gizmoViewProj, false, viewProj);
      gl.bindVertexArray(this.gizmos.vao);
      gl.drawArrays(gl.LINES, 0, this.gizmos.count);
    }
    gl.depthFunc(gl.LESS);
    gl.bindVertexArray(null);
    this.framesDrawn++;
  }

  /** The world-space ray through client coordinates (x, y). */
  ray(clientX, clientY) {
    const rect = this.canvas.getBoundingClientRect();
    const nx = ((clientX - rect.left) / rect.width) * 2 - 1;
    const ny = 1 - ((clientY - rect.top) / rect.height) * 2;
    const { fovy, aspect } = this.matrices();
    const eye = this.eye();
    const forward = normalize(sub(this.camera.target, eye));
    const right = normalize(cross(forward, [0, 1, 0]));
    const up = cross(right, forward);
    const t = Math.tan(fovy / 2);
    const dir = normalize(add(forward, add(scale3(right, nx * t * aspect), scale3(up, ny * t))));
    return { origin: eye, dir };
  }

  /**
   * What a drag at client coordinates would take, the nearest first: a
   * dynamic object (`{ object }`, if `draggable`) or a point or spot
   * light (`{ light }`, if `lightsDraggable` and the gizmos are shown;
   * the pointer within a gizmo's size of the light), or null.
   */
  pick(clientX, clientY) {
    const { origin, dir } = this.ray(clientX, clientY);
    let best = null;
    let bestT = Infinity;
    if (this.draggable) {
      this.objects.forEach((o, i) => {
        if (!o.info.dynamic || !o.count) return;
        // Into object space: p_local = R^-1 (p - t) / s.
        const inv = [-o.pose.rotation[0], -o.pose.rotation[1], -o.pose.rotation[2], o.pose.rotation[3]];
        const lo = scale3(rotate(inv, sub(origin, o.pose.translation)), 1 / o.pose.scale);
        const ld = scale3(rotate(inv, dir), 1 / o.pose.scale);
        const hit = rayBox(lo, ld, o.lo, o.hi);
        if (hit !== null && hit < bestT) {
          bestT = hit;
          best = { object: i };
        }
      });
    }
    if (this.lightsDraggable && this.showLights) {
      const reach = gizmoSize(this.bounds);
      this.placed.forEach((l, i) => {
        if (!l?.position || !(l.type === 'point' || l.type === 'spot')) return;
        const near = rayPoint(origin, dir, l.position);
        if (near && near.distance <= reach && near.t < bestT) {
          bestT = near.t;
          best = { light: i };
        }
      });
    }
    return best;
  }

  /** Client coordinates of world point `p` in the view. */
  project(p) {
    const { viewProj } = this.matrices();
    const v = [0, 1, 2, 3].map((r) => viewProj[r] * p[0] + viewProj[4 + r] * p[1] + viewProj[8 + r] * p[2] + viewProj[12 + r]);
    const rect = this.canvas.getBoundingClientRect();
    return {
      x: rect.left + ((v[0] / v[3] + 1) / 2) * rect.width,
      y: rect.top + ((1 - v[1] / v[3]) / 2) * rect.height,
    };
  }

  /** Client coordinates of a dynamic object's centre (for tests and tools). */
  screenPoint(index) {
    const o = this.objects[index];
    return o ? this.project(transformPoint(o.pose, scale3(add(o.lo, o.hi), 0.5))) : null;
  }

  /** Client coordinates of a point or spot light (for tests and tools). */
  lightScreenPoint(index) {
    const p = this.placed[index]?.position;
    return p ? this.project(p) : null;
  }

  /** Where a ray meets the horizontal plane y = height, or null. */
  planeHit(clientX, clientY, height) {
    const { origin, dir } = this.ray(clientX, clientY);
    if (Math.abs(dir[1]) < 1e-6) return null;
    const t = (height - origin[1]) / dir[1];
    return t > 0 ? add(origin, scale3(dir, t)) : null;
  }

  installInput() {
    const canvas = this.canvas;
    canvas.addEventListener('contextmenu', (e) => e.preventDefault());
    canvas.addEventListener('pointerdown', (e) => {
      canvas.setPointerCapture(e.pointerId);
      const picked = this.pick(e.clientX, e.clientY);
      const start = { x: e.clientX, y: e.clientY };
      if (picked?.light !== undefined) {
        const position = [...this.placed[picked.light].position];
        this.drag = { mode: 'light', light: picked.light, start, position, hit: this.planeHit(e.clientX, e.clientY, position[1]) };
      } else if (picked?.object !== undefined) {
        const object = picked.object;
        const pose = structuredClone(this.objects[object].pose);
        const rotateMode = e.shiftKey || e.button === 2;
        this.drag = {
          mode: rotateMode ? 'rotate' : 'move',
          object,
          start,
          pose,
          hit: this.planeHit(e.clientX, e.clientY, pose.translation[1]),
        };
      } else {
        this.drag = { mode: 'orbit', start, camera: { ...this.camera } };
      }
      this.needsDraw = true;
    });
    canvas.addEventListener('pointermove', (e) => {
      const d = this.drag;
      if (!d) {
        const hover = this.pick(e.clientX, e.clientY);
        if (hover?.object !== this.hover?.object || hover?.light !== this.hover?.light) {
          this.hover = hover;
          canvas.style.cursor = hover ? 'grab' : '';
          this.needsDraw = true;
        }
        return;
      }
      const dx = e.clientX - d.start.x;
      const dy = e.clientY - d.start.y;
      if (d.mode === 'orbit') {
        this.camera.yaw = d.camera.yaw - dx * 0.006;
        this.camera.pitch = Math.max(-1.45, Math.min(1.45, d.camera.pitch + dy * 0.006));
      } else if (d.mode === 'move') {
        const hit = this.planeHit(e.clientX, e.clientY, d.pose.translation[1]);
        if (!hit || !d.hit) return;
        const t = add(d.pose.translation, sub(hit, d.hit));
        const range = this.translationRange(d.object);
        t[0] = Math.max(range.x[0], Math.min(range.x[1], t[0]));
        t[2] = Math.max(range.z[0], Math.min(range.z[1], t[2]));
        this.setDragged(d.object, { ...d.pose, translation: t });
      } else if (d.mode === 'light') {
        const hit = this.planeHit(e.clientX, e.clientY, d.position[1]);
        if (!hit || !d.hit) return;
        // Kept a gizmo's size inside the static geometry's bounds (off the
        // walls of a room), or as far out as the drag started.
        const margin = gizmoSize(this.bounds);
        const p = add(d.position, sub(hit, d.hit));
        p[1] = d.position[1];
        for (const a of [0, 2]) {
          const lo = Math.min(this.bounds.lo[a] + margin, d.position[a]);
          const hi = Math.max(this.bounds.hi[a] - margin, d.position[a]);
          p[a] = Math.max(lo, Math.min(hi, p[a]));
        }
        this.onLightDrag(d.light, p);
      } else {
        const rotation = quatMul(quatYaw(dx * 0.01), d.pose.rotation);
        this.setDragged(d.object, { ...d.pose, rotation });
      }
      this.needsDraw = true;
    });
    const end = () => {
      this.drag = null;
      this.needsDraw = true;
    };
    canvas.addEventListener('pointerup', end);
    canvas.addEventListener('pointercancel', end);
    canvas.addEventListener(
      'wheel',
      (e) => {
        e.preventDefault();
        this.camera.distance *= Math.exp(e.deltaY * 0.001);
        this.needsDraw = true;
      },
      { passive: false },
    );
  }

  setDragged(index, pose) {
    this.setPose(index, pose);
    this.onDrag(index, pose);
  }
}
