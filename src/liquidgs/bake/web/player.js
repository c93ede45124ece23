// liquidgs web player: a baked dynamic Gaussian scene (scene.json + scene.bin) drawn with WebGL2.
// Per frame, on the CPU: keyframes -> Catmull-Rom state at the time (bake/motion.py), EWA projection
// as liquidgs' rasteriser does it (render/projection.py: 0.3 px blur, frustum-clamped Jacobian,
// opacity-aware extent), SH colour, a depth sort. The GPU draws one quad per Gaussian, back to front,
// alpha = min(0.999, opacity * exp(-sigma)), fragments under 1/255 dropped (render/composite.py).
"use strict";

const SH_C0 = 0.28209479177387814;
const SH_C1 = 0.4886025119029199;
const SH_C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396];
const SH_C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
  -0.4570457994644658, 1.445305721320277, -0.5900435899266435];
const EPS2D = 0.3, FRUSTUM_MARGIN = 0.3, ALPHA_THRESHOLD = 1 / 255, MAX_EXTENT = 3.33, NEAR = 0.01;
const CHANNELS = 10;
const TIMED_FRAMES = 30;
const FLOATS_PER_SPLAT = 11; // mean2d, radius (2 each), conic (3), opacity, rgb (3): the instance layout

const VERTEX_SHADER = `#version 300 es
precision highp float;
in vec2 corner;
in vec4 splatA;  // mean2d.xy, radius.xy
in vec4 splatB;  // conic a b c, opacity
in vec3 splatC;  // rgb
uniform vec2 viewport;
out vec2 mean2d;
out vec3 conic;
out float opacity;
out vec3 rgb;
void main() {
  vec2 pixel = splatA.xy + corner * splatA.zw;
  gl_Position = vec4(pixel.x / viewport.x * 2.0 - 1.0, 1.0 - pixel.y / viewport.y * 2.0, 0.0, 1.0);
  mean2d = splatA.xy; conic = splatB.xyz; opacity = splatB.w; rgb = splatC;
}`;

const FRAGMENT_SHADER = `#version 300 es
precision highp float;
in vec2 mean2d;
in vec3 conic;
in float opacity;
in vec3 rgb;
uniform vec2 viewport;
out vec4 color;
void main() {
  vec2 d = vec2(gl_FragCoord.x, viewport.y - gl_FragCoord.y) - mean2d;
  float sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
  float alpha = min(0.999, opacity * exp(-sigma));
  if (sigma < 0.0 || alpha < ${ALPHA_THRESHOLD}) discard;
  color = vec4(rgb * alpha, alpha);
}`;

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
  return shader;
}

function shColor(out, o, coeffs, base, bases, x, y, z) {
  const n = Math.hypot(x, y, z) || 1;
  x /= n; y /= n; z /= n;
  const b = [SH_C0];
  if (bases >= 4) b.push(-SH_C1 * y, SH_C1 * z, -SH_C1 * x);
  if (bases >= 9) {
    const xx = x * x, yy = y * y, zz = z * z;
    b.push(SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * x * z, SH_C2[4] * (xx - yy));
    if (bases >= 16) {
      b.push(SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
        SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy), SH_C3[5] * z * (xx - yy),
        SH_C3[6] * x * (xx - 3 * yy));
    }
  }
  for (let c = 0; c < 3; c++) {
    let v = 0.5;
    for (let k = 0; k < b.length; k++) v += b[k] * coeffs[base + k * 3 + c];
    out[o + c] = Math.max(v, 0);
  }
}

// The dataset camera's intrinsics for a canvas of width x height: the focal scaled so the camera's
// whole field of view fits the canvas (the longer side of the window shows more, not a stretch),
// its principal point moved with it.
function fitIntrinsics(c, width, height) {
  const s = Math.min(width / c.width, height / c.height);
  return { width, height, fx: c.fx * s, fy: c.fy * s, cx: c.cx * s + (width - c.width * s) / 2,
    cy: c.cy * s + (height - c.height * s) / 2 };
}

// scene.bin's sections (scene.json "sections": name, type, length, in file order) as typed arrays.
const SECTION_TYPES = { float32: Float32Array, int16: Int16Array, float16: Uint16Array, uint8: Uint8Array };

function readSections(meta, buffer) {
  const out = {};
  let offset = 0;
  for (const [name, type, length] of meta.sections) {
    const Type = SECTION_TYPES[type];
    out[name] = new Type(buffer, offset, length);
    offset += length * Type.BYTES_PER_ELEMENT;
  }
  return out;
}

// IEEE half-precision bits to a number (subnormals, infinities and NaN included).
function halfToFloat(h) {
  const sign = h & 0x8000 ? -1 : 1, exponent = (h >> 10) & 0x1f, fraction = h & 0x3ff;
  if (exponent === 0) return sign * fraction * 2 ** -24;
  if (exponent === 31) return fraction ? NaN : sign * Infinity;
  return sign * (1 + fraction / 1024) * 2 ** (exponent - 15);
}

const halves = (bits) => Float32Array.from(bits, halfToFloat);

// The channel groups (position, rotation, scale) whose codes are stored block by block, and the top
// code of 8 and 16 bits: bake/tracks.py.
const CHANNEL_GROUPS = [[0, 3], [3, 7], [7, 10]];
const CODE_LEVELS = { 8: 255, 16: 65535 };

// Each keyframe count's Gaussians (ascending) and their keyframes [K, n, CHANNELS], decoded from the
// codes as bake/tracks.py's unpack() does: block by block, count ascending (the Gaussians of one
// keyframe hold their value in `low`), then channel group, then 8 before 16 bits.
function decodeTracks(sections, n) {
  const { counts, wide, low, codes8, codes16 } = sections;
  const span = halves(sections.span);
  const members = new Map();
  for (let i = 0; i < n; i++) {
    if (!members.has(counts[i])) members.set(counts[i], []);
    members.get(counts[i]).push(i);
  }
  const streams = { 8: [codes8, 0, 0], 16: [codes16, 32768, 0] }; // codes, offset, read so far
  const groups = [];
  for (const count of [...members.keys()].sort((a, b) => a - b)) {
    if (count < 1) throw new SceneError(`scene.bin: a keyframe count of ${count}; export the scene again`);
    const index = Uint32Array.from(members.get(count)), size = index.length;
    const keys = new Float32Array(count * size * CHANNELS);
    for (let j = 0; j < size; j++) {
      for (let k = 0; k < count; k++) keys.set(low.subarray(index[j] * CHANNELS, (index[j] + 1) * CHANNELS), (k * size + j) * CHANNELS);
    }
    if (count > 1) {
      CHANNEL_GROUPS.forEach(([first, last], group) => {
        for (const bits of [8, 16]) {
          const chosen = [];
          for (let j = 0; j < size; j++) if (((wide[index[j]] >> group) & 1) === (bits === 16 ? 1 : 0)) chosen.push(j);
          const stream = streams[bits], width = last - first;
          if (stream[2] + count * chosen.length * width > stream[0].length) {
            throw new SceneError(`scene.bin: its ${bits}-bit codes end before the keyframes they hold; export the scene again`);
          }
          for (let k = 0; k < count; k++) {
            chosen.forEach((j, m) => {
              const gaussian = index[j] * CHANNELS;
              for (let c = 0; c < width; c++) {
                const code = stream[0][stream[2] + (k * chosen.length + m) * width + c] + stream[1];
                keys[(k * size + j) * CHANNELS + first + c] = low[gaussian + first + c] + span[gaussian + first + c] * code / CODE_LEVELS[bits];
              }
            });
          }
          stream[2] += count * chosen.length * width;
        }
      });
    }
    groups.push({ count, index, keys });
  }
  if (streams[8][2] !== codes8.length || streams[16][2] !== codes16.length) {
    throw new SceneError("scene.bin: more keyframe codes than its keyframe counts hold; export the scene again");
  }
  return groups;
}

// bake/motion.py's spline_weights: the first keyframe and the Catmull-Rom weights of the (up to) four
// keyframes around `time` among `count` uniform ones, the mirrored phantom keyframe at either end folded in.
function splineWeights(count, time) {
  if (count === 1) return [0, [1]];
  const u = Math.min(Math.max(time, 0), 1) * (count - 1);
  const i = Math.min(Math.floor(u), count - 2), f = u - i, f2 = f * f, f3 = f2 * f;
  let w0 = 0.5 * (2 * f2 - f - f3), w1 = 0.5 * (2 - 5 * f2 + 3 * f3), w2 = 0.5 * (f + 4 * f2 - 3 * f3), w3 = 0.5 * (f3 - f2);
  let first = i - 1;
  if (i === 0) { w1 += 2 * w0; w2 -= w0; w0 = null; first = i; }
  if (i + 2 === count) { w1 -= w3; w2 += 2 * w3; w3 = null; }
  return [first, [w0, w1, w2, w3].filter((w) => w !== null)];
}

class Player {
  constructor(canvas, meta, buffer) {
    this.meta = meta;
    const n = meta.gaussians, stored = meta.sh_stored, sections = readSections(meta, buffer);
    this.groups = decodeTracks(sections, n);
    this.opacities = Float32Array.from(halves(sections.opacities), (x) => 1 / (1 + Math.exp(-x)));
    // SH [N, stored, 3]: degree 0 as stored, the higher ones from their 8-bit codes of each Gaussian's range.
    const sh0 = halves(sections.sh0), shLow = halves(sections.sh_low), shSpan = halves(sections.sh_span);
    this.sh = new Float32Array(n * stored * 3);
    for (let i = 0; i < n; i++) {
      for (let c = 0; c < 3; c++) this.sh[i * stored * 3 + c] = sh0[i * 3 + c];
      for (let j = 3; j < stored * 3; j++) {
        this.sh[i * stored * 3 + j] = shLow[i] + shSpan[i] * sections.sh_codes[i * (stored - 1) * 3 + j - 3] / CODE_LEVELS[8];
      }
    }
    this.state = new Float32Array(n * CHANNELS);
    this.splats = new Float32Array(n * FLOATS_PER_SPLAT);
    this.depths = new Float32Array(n);
    this.order = new Uint32Array(n);
    this.canvas = canvas;
    this.time = 0;
    this.frames = 0;
    this.timings = [];
    this.probe = new Uint8Array(4);
    this.setCamera(0);
    this.initGL();
  }

  setCamera(index) {
    this.cameraIndex = index;
    this.view = this.meta.cameras[index].viewmat.slice();
    this.fit();
  }

  // The canvas at the window's size in device pixels, the camera's intrinsics scaled to it.
  fit() {
    const dpr = window.devicePixelRatio || 1;
    const width = Math.max(1, Math.round(this.canvas.clientWidth * dpr));
    const height = Math.max(1, Math.round(this.canvas.clientHeight * dpr));
    if (this.canvas.width !== width) this.canvas.width = width;
    if (this.canvas.height !== height) this.canvas.height = height;
    this.camera = { ...fitIntrinsics(this.meta.cameras[this.cameraIndex], width, height), view: this.view };
  }

  initGL() {
    const gl = this.canvas.getContext("webgl2", { antialias: false, premultipliedAlpha: true, preserveDrawingBuffer: true });
    if (!gl) throw new Error("WebGL2 is not available in this browser");
    this.gl = gl;
    const program = gl.createProgram();
    gl.attachShader(program, compile(gl, gl.VERTEX_SHADER, VERTEX_SHADER));
    gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT_SHADER));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
    gl.useProgram(program);
    this.program = program;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const corners = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, corners);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
    const corner = gl.getAttribLocation(program, "corner");
    gl.enableVertexAttribArray(corner);
    gl.vertexAttribPointer(corner, 2, gl.FLOAT, false, 0, 0);
    this.instanceBuffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.instanceBuffer);
    const attribute = (name, size, offset) => {
      const location = gl.getAttribLocation(program, name);
      gl.enableVertexAttribArray(location);
      gl.vertexAttribPointer(location, size, gl.FLOAT, false, 48, offset);
      gl.vertexAttribDivisor(location, 1);
    };
    attribute("splatA", 4, 0);
    attribute("splatB", 4, 16);
    attribute("splatC", 3, 32);
    gl.disable(gl.DEPTH_TEST);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA); // premultiplied "over", drawn back to front
    this.viewport = gl.getUniformLocation(program, "viewport");
  }

  // Every Gaussian's state at `time`: per keyframe count, one weighted sum of the (up to) four
  // keyframes around it (quaternions left unnormalised: project() normalises them).
  interpolate(time) {
    const out = this.state;
    for (const { count, index, keys } of this.groups) {
      const [first, weights] = splineWeights(count, time);
      const stride = index.length * CHANNELS;
      for (let j = 0; j < index.length; j++) {
        const o = index[j] * CHANNELS;
        for (let c = 0; c < CHANNELS; c++) {
          let value = 0;
          for (let m = 0; m < weights.length; m++) value += weights[m] * keys[(first + m) * stride + j * CHANNELS + c];
          out[o + c] = value;
        }
      }
    }
  }

  project() {
    const { width, height, fx, fy, cx, cy, view: v } = this.camera;
    const n = this.meta.gaussians, s = this.state, bases = this.meta.sh_bases;
    // Camera centre: -R^T t.
    const camX = -(v[0] * v[3] + v[4] * v[7] + v[8] * v[11]);
    const camY = -(v[1] * v[3] + v[5] * v[7] + v[9] * v[11]);
    const camZ = -(v[2] * v[3] + v[6] * v[7] + v[10] * v[11]);
    const limXPos = (width - cx) / fx + FRUSTUM_MARGIN * 0.5 * width / fx;
    const limXNeg = cx / fx + FRUSTUM_MARGIN * 0.5 * width / fx;
    const limYPos = (height - cy) / fy + FRUSTUM_MARGIN * 0.5 * height / fy;
    const limYNeg = cy / fy + FRUSTUM_MARGIN * 0.5 * height / fy;
    const rgb = new Float32Array(3);
    let visible = 0;
    const records = this.splats;
    for (let i = 0; i < n; i++) {
      const o = i * CHANNELS;
      const mx = s[o], my = s[o + 1], mz = s[o + 2];
      const x = v[0] * mx + v[1] * my + v[2] * mz + v[3];
      const y = v[4] * mx + v[5] * my + v[6] * mz + v[7];
      const z = v[8] * mx + v[9] * my + v[10] * mz + v[11];
      const opacity = this.opacities[i];
      if (z < NEAR || opacity < ALPHA_THRESHOLD) continue;
      let qw = s[o + 3], qx = s[o + 4], qy = s[o + 5], qz = s[o + 6];
      const qn = Math.hypot(qw, qx, qy, qz) || 1;
      qw /= qn; qx /= qn; qy /= qn; qz /= qn;
      const sx = s[o + 7], sy = s[o + 8], sz = s[o + 9];
      // M = R S (world), then the camera rotation: W R S.
      const r = [
        1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy),
        2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx),
        2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy),
      ];
      const m = new Array(9);
      for (let a = 0; a < 3; a++) {
        for (let b = 0; b < 3; b++) {
          const scale = b === 0 ? sx : b === 1 ? sy : sz;
          m[a * 3 + b] = (v[a * 4] * r[b] + v[a * 4 + 1] * r[3 + b] + v[a * 4 + 2] * r[6 + b]) * scale;
        }
      }
      const tx = z * Math.min(Math.max(x / z, -limXNeg), limXPos);
      const ty = z * Math.min(Math.max(y / z, -limYNeg), limYPos);
      // Rows of J M: J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]].
      const j0 = [0, 1, 2].map((b) => (fx / z) * m[b] - (fx * tx / (z * z)) * m[6 + b]);
      const j1 = [0, 1, 2].map((b) => (fy / z) * m[3 + b] - (fy * ty / (z * z)) * m[6 + b]);
      const covA = j0[0] * j0[0] + j0[1] * j0[1] + j0[2] * j0[2] + EPS2D;
      const covB = j0[0] * j1[0] + j0[1] * j1[1] + j0[2] * j1[2];
      const covC = j1[0] * j1[0] + j1[1] * j1[1] + j1[2] * j1[2] + EPS2D;
      const det = covA * covC - covB * covB;
      if (!(det > 0)) continue;
      const u = fx * x / z + cx, w = fy * y / z + cy;
      const extent = Math.min(Math.sqrt(2 * Math.log(opacity / ALPHA_THRESHOLD)), MAX_EXTENT);
      const rx = Math.ceil(extent * Math.sqrt(covA)), ry = Math.ceil(extent * Math.sqrt(covC));
      if (u + rx <= 0 || u - rx >= width || w + ry <= 0 || w - ry >= height || (rx <= 0 && ry <= 0)) continue;
      shColor(rgb, 0, this.sh, i * this.meta.sh_stored * 3, bases, mx - camX, my - camY, mz - camZ);
      const p = visible * FLOATS_PER_SPLAT;
      records[p] = u; records[p + 1] = w; records[p + 2] = rx + 0.5; records[p + 3] = ry + 0.5;
      records[p + 4] = covC / det; records[p + 5] = -covB / det; records[p + 6] = covA / det; records[p + 7] = opacity;
      records[p + 8] = rgb[0]; records[p + 9] = rgb[1]; records[p + 10] = rgb[2];
      this.depths[visible] = z;
      this.order[visible] = visible;
      visible++;
    }
    // Back to front: the largest depth first.
    const order = this.order.subarray(0, visible);
    const depths = this.depths;
    order.sort((a, b) => depths[b] - depths[a]);
    const instances = new Float32Array(visible * 12);
    for (let j = 0; j < visible; j++) {
      const p = order[j] * FLOATS_PER_SPLAT;
      instances.set(records.subarray(p, p + FLOATS_PER_SPLAT), j * 12);
    }
    return instances;
  }

  // One frame. Its cost is measured, not inferred from the frame rate (which the display's refresh
  // and the time between frames set): the CPU's part (motion, projection, sort) and the GPU's
  // (upload, draw, waited for by reading a pixel back, so what it reports is what the frame took).
  draw() {
    this.fit();
    const begin = performance.now();
    this.interpolate(this.time);
    const instances = this.project();
    const projected = performance.now();
    const gl = this.gl, bg = this.meta.background;
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.uniform2f(this.viewport, this.canvas.width, this.canvas.height);
    gl.clearColor(bg[0], bg[1], bg[2], 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.instanceBuffer);
    gl.bufferData(gl.ARRAY_BUFFER, instances, gl.DYNAMIC_DRAW);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, instances.length / 12);
    // Reading a pixel back waits until the frame is drawn (Chromium's gl.finish did not: 0.1-1.2 ms
    // where the frame took 290 in SwiftShader).
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, this.probe);
    const end = performance.now();
    this.timings.push([projected - begin, end - projected]);
    if (this.timings.length > TIMED_FRAMES) this.timings.shift();
    this.frames++;
  }

  // Mean CPU and GPU milliseconds over the last TIMED_FRAMES frames drawn.
  frameTime() {
    const count = this.timings.length;
    const cpu = this.timings.reduce((sum, t) => sum + t[0], 0) / Math.max(count, 1);
    const gpu = this.timings.reduce((sum, t) => sum + t[1], 0) / Math.max(count, 1);
    return { cpu, gpu, total: cpu + gpu, frames: count };
  }

  // Orbit about `target`: yaw about the world's up (the first camera's -y), pitch about the camera's x.
  orbit(dx, dy) {
    const v = this.camera.view;
    const rot = [v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]];
    const t = [v[3], v[7], v[11]];
    const centre = [0, 1, 2].map((a) => -(rot[a] * t[0] + rot[3 + a] * t[1] + rot[6 + a] * t[2]));
    const up = this.up;
    const right = [rot[0], rot[1], rot[2]];
    const turn = (axis, angle, p) => {
      const c = Math.cos(angle), s = Math.sin(angle), d = axis[0] * p[0] + axis[1] * p[1] + axis[2] * p[2];
      const cross = [axis[1] * p[2] - axis[2] * p[1], axis[2] * p[0] - axis[0] * p[2], axis[0] * p[1] - axis[1] * p[0]];
      return [0, 1, 2].map((a) => p[a] * c + cross[a] * s + axis[a] * d * (1 - c));
    };
    const apply = (p) => turn(right, dy, turn(up, dx, p));
    const offset = apply(centre.map((c, a) => c - this.target[a]));
    const newCentre = offset.map((o, a) => o + this.target[a]);
    // Camera axes (rows of the rotation) turn with it.
    const rows = [0, 1, 2].map((row) => apply([rot[row * 3], rot[row * 3 + 1], rot[row * 3 + 2]]));
    this.setPose(rows, newCentre);
  }

  zoom(factor) {
    const v = this.camera.view;
    const rows = [0, 1, 2].map((row) => [v[row * 4], v[row * 4 + 1], v[row * 4 + 2]]);
    const centre = [0, 1, 2].map((a) => -(rows[0][a] * v[3] + rows[1][a] * v[7] + rows[2][a] * v[11]));
    this.setPose(rows, centre.map((c, a) => this.target[a] + (c - this.target[a]) * factor));
  }

  // Move the camera and the point it orbits across the view: `dx`, `dy` in device pixels, the
  // scene under the pointer following it at the target's depth.
  pan(dx, dy) {
    const v = this.camera.view;
    const rows = [0, 1, 2].map((row) => [v[row * 4], v[row * 4 + 1], v[row * 4 + 2]]);
    const centre = [0, 1, 2].map((a) => -(rows[0][a] * v[3] + rows[1][a] * v[7] + rows[2][a] * v[11]));
    const depth = [0, 1, 2].reduce((sum, a) => sum + rows[2][a] * (this.target[a] - centre[a]), 0);
    const shift = [0, 1, 2].map((a) => -(rows[0][a] * dx / this.camera.fx + rows[1][a] * dy / this.camera.fy) * depth);
    this.target = this.target.map((t, a) => t + shift[a]);
    this.setPose(rows, centre.map((c, a) => c + shift[a]));
  }

  setPose(rows, centre) {
    const v = this.camera.view;
    for (let row = 0; row < 3; row++) {
      v[row * 4] = rows[row][0]; v[row * 4 + 1] = rows[row][1]; v[row * 4 + 2] = rows[row][2];
      v[row * 4 + 3] = -(rows[row][0] * centre[0] + rows[row][1] * centre[1] + rows[row][2] * centre[2]);
    }
  }
}

// --- loading: the scene beside the page (scene.json, scene.bin) or inside it (the single-file export)

const FORMAT = "liquidgs-web/2";

class SceneError extends Error {}

// The sections' lengths scene.json promises for its Gaussians, checked before any is read.
function sectionsProblem(meta) {
  const n = meta.gaussians, higher = (meta.sh_stored - 1) * 3;
  const need = { low: n * CHANNELS, counts: n, span: n * CHANNELS, opacities: n, sh0: n * 3, sh_low: n, sh_span: n,
    wide: n, sh_codes: n * higher, codes8: null, codes16: null };
  if (!Array.isArray(meta.sections)) return "no sections";
  const names = meta.sections.map((s) => s[0]);
  for (const [name, length] of Object.entries(need)) {
    if (!names.includes(name)) return `no section "${name}"`;
    const section = meta.sections[names.indexOf(name)];
    if (!(section[1] in SECTION_TYPES) || !Number.isInteger(section[2]) || section[2] < 0) return `section "${name}" is malformed`;
    if (length !== null && section[2] !== length) return `section "${name}" holds ${section[2]} values, where ${n} Gaussians need ${length}`;
  }
  let offset = 0;
  for (const [name, type, length] of meta.sections) {
    if (offset % SECTION_TYPES[type].BYTES_PER_ELEMENT) return `section "${name}" is not aligned`;
    offset += length * SECTION_TYPES[type].BYTES_PER_ELEMENT;
  }
  return null;
}

function sceneBytes(meta) {
  return meta.sections.reduce((sum, [, type, length]) => sum + length * SECTION_TYPES[type].BYTES_PER_ELEMENT, 0);
}

async function fetched(name, read) {
  let response;
  try {
    response = await fetch(name);
  } catch (err) {
    throw new SceneError(`${name} could not be loaded (${err.message})`);
  }
  if (!response.ok) throw new SceneError(`${name} could not be loaded: HTTP ${response.status} ${response.statusText}`.trim());
  return read(response);
}

async function loadScene() {
  const embedded = document.getElementById("scene-data");
  if (embedded) {
    const meta = JSON.parse(document.getElementById("scene-meta").textContent);
    const text = atob(embedded.textContent.trim());
    const bytes = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
    return checked(meta, bytes.buffer, "the scene inside this page");
  }
  if (location.protocol === "file:") {
    throw new SceneError("This page was opened from disk, where the browser will not let it read scene.json and scene.bin " +
      "beside it. Serve its folder instead: run `python -m http.server` in it and open localhost:8000, " +
      "or export one file that opens from disk: liquidgs export --format html.");
  }
  const text = await fetched("scene.json", (r) => r.text());
  let meta;
  try {
    meta = JSON.parse(text);
  } catch (err) {
    throw new SceneError(`scene.json is not valid JSON (${err.message}): truncated, or not written by liquidgs export`);
  }
  return checked(meta, await fetched("scene.bin", (r) => r.arrayBuffer()), "scene.bin");
}

function checked(meta, buffer, where) {
  if (meta.format !== FORMAT) throw new SceneError(`scene.json: format ${JSON.stringify(meta.format)}, where this player reads ${FORMAT}`);
  if (!meta.cameras || !meta.cameras.length) throw new SceneError("scene.json: no cameras");
  const problem = sectionsProblem(meta);
  if (problem) throw new SceneError(`scene.json: ${problem}; export the scene again`);
  const expected = sceneBytes(meta);
  if (buffer.byteLength !== expected) {
    throw new SceneError(`${where} holds ${buffer.byteLength.toLocaleString("en")} bytes, where the ${meta.gaussians.toLocaleString("en")} ` +
      `Gaussians of scene.json need ${expected.toLocaleString("en")}: ` +
      (buffer.byteLength < expected ? "it is truncated" : "it belongs to another export") + "; export the scene again");
  }
  return [meta, buffer];
}

// --- the address: #t=0.370&camera=NAME opens at that time and camera

function parseLink(hash, cameras) {
  const fields = new URLSearchParams(hash.replace(/^#/, ""));
  const notes = [];
  let time = null, camera = null;
  if (fields.has("t")) {
    const asked = fields.get("t"), value = Number(asked);
    if (asked.trim() === "" || !Number.isFinite(value)) notes.push(`time ${JSON.stringify(asked)} in the link is not a number: showing time 0`);
    else {
      time = Math.min(Math.max(value, 0), 1);
      if (time !== value) notes.push(`time ${asked} in the link is outside [0, 1]: clamped to ${time}`);
    }
  }
  if (fields.has("camera")) {
    const name = fields.get("camera"), index = cameras.findIndex((c) => c.name === name);
    if (index < 0) {
      notes.push(`camera ${JSON.stringify(name)} in the link is not one of this scene's ${cameras.length} cameras: showing ${cameras[0].name}`);
    } else camera = index;
  }
  return { time, camera, notes };
}

function linkTo(time, camera) {
  const name = encodeURIComponent(camera).replace(/%2F/g, "/"); // "train/r_003" reads better unescaped
  return `${location.href.replace(/#.*$/, "")}#t=${time.toFixed(4)}&camera=${name}`;
}

async function start() {
  const [meta, buffer] = await loadScene();
  const message = document.getElementById("message");
  const player = new Player(document.getElementById("canvas"), meta, buffer);
  player.target = meta.target;
  const first = meta.cameras[0].viewmat;
  player.up = [-first[4], -first[5], -first[6]];
  const slider = document.getElementById("time"), button = document.getElementById("play");
  const cameraSelect = document.getElementById("camera"), timeLabel = document.getElementById("timelabel");
  const frameLabel = document.getElementById("frametime");
  meta.cameras.forEach((c, i) => cameraSelect.add(new Option(c.name, String(i))));
  let playing = false, last = performance.now();
  const show = () => {
    slider.value = String(player.time);
    timeLabel.textContent = `t = ${player.time.toFixed(3)}`;
    player.draw();
    const t = player.frameTime();
    frameLabel.textContent = `${t.total.toFixed(1)} ms/frame (CPU ${t.cpu.toFixed(1)} + GPU ${t.gpu.toFixed(1)}, mean of ${t.frames})`;
  };
  const open = (hash) => {
    const link = parseLink(hash, meta.cameras);
    player.setCamera(link.camera ?? 0);
    cameraSelect.value = String(player.cameraIndex);
    player.time = link.time ?? 0;
    message.textContent = link.notes.join("\n");
    show();
  };
  slider.addEventListener("input", () => { player.time = Number(slider.value); show(); });
  button.addEventListener("click", () => { playing = !playing; button.textContent = playing ? "pause" : "play"; last = performance.now(); });
  cameraSelect.addEventListener("change", () => { player.setCamera(Number(cameraSelect.value)); show(); });
  document.getElementById("copy").addEventListener("click", async () => {
    const link = linkTo(player.time, meta.cameras[player.cameraIndex].name);
    try {
      await navigator.clipboard.writeText(link);
      message.textContent = `copied ${link}`;
    } catch (err) {
      message.textContent = `the browser refused the clipboard (${err.message}); the link: ${link}`;
    }
  });
  window.addEventListener("hashchange", () => open(location.hash));
  window.addEventListener("resize", show);
  // Drag orbits; with the right button or shift held it pans. The wheel zooms.
  let dragging = null;
  player.canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  player.canvas.addEventListener("pointerdown", (e) => {
    dragging = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
    player.canvas.setPointerCapture(e.pointerId);
  });
  player.canvas.addEventListener("pointerup", () => { dragging = null; });
  player.canvas.addEventListener("pointermove", (e) => {
    if (!dragging) return;
    const dx = e.clientX - dragging.x, dy = e.clientY - dragging.y;
    if (dragging.pan) player.pan(dx * devicePixelRatio, dy * devicePixelRatio);
    else player.orbit(-dx * 0.01, -dy * 0.01);
    dragging.x = e.clientX; dragging.y = e.clientY;
    show();
  });
  player.canvas.addEventListener("wheel", (e) => { e.preventDefault(); player.zoom(Math.exp(e.deltaY * 0.001)); show(); }, { passive: false });
  const tick = (now) => {
    if (playing) {
      player.time = (player.time + (now - last) / 1000 / meta.duration_s) % 1;
      show();
    }
    last = now;
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);
  open(location.hash);
  // For scripts and tests: jump to a camera and time, measure frames, read the camera and the link.
  window.player = {
    show(camera, time) { player.setCamera(camera); cameraSelect.value = String(camera); player.time = time; show(); return player.frames; },
    benchmark(frames) {
      player.timings = [];
      for (let i = 0; i < frames; i++) { player.time = i / frames; player.draw(); }
      return player.frameTime();
    },
    orbit(dx, dy) { player.orbit(dx, dy); show(); },
    // What the player decoded: every Gaussian's state at `time` (quaternions unnormalised), its
    // opacity and SH coefficients.
    gaussians(time) {
      player.interpolate(time);
      return { state: Array.from(player.state), opacities: Array.from(player.opacities), sh: Array.from(player.sh) };
    },
    state() {
      const { width, height, fx, fy, cx, cy } = player.camera;
      return { camera: player.cameraIndex, time: player.time, width, height, fx, fy, cx, cy, view: Array.from(player.view) };
    },
    link() { return linkTo(player.time, meta.cameras[player.cameraIndex].name); },
  };
  document.body.dataset.ready = "true";
}

start().catch((err) => {
  document.getElementById("message").textContent = err instanceof SceneError ? err.message : `the player failed: ${err}`;
  document.body.dataset.ready = "error";
  if (!(err instanceof SceneError)) console.error(err);
});
