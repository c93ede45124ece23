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

class Player {
  constructor(canvas, meta, buffer) {
    this.meta = meta;
    const n = meta.gaussians, k = meta.keyframes;
    let offset = 0;
    const take = (count) => { const a = new Float32Array(buffer, offset, count); offset += count * 4; return a; };
    const low = take(n * CHANNELS), span = take(n * CHANNELS);
    this.opacities = take(n);
    this.sh = take(n * meta.sh_stored * 3);
    const quantised = new Uint16Array(buffer, offset, k * n * CHANNELS);
    this.keyframes = new Float32Array(k * n * CHANNELS);
    for (let j = 0; j < k * n * CHANNELS; j++) {
      const c = j % (n * CHANNELS);
      this.keyframes[j] = low[c] + span[c] * (quantised[j] / 65535);
    }
    this.state = new Float32Array(n * CHANNELS);
    this.splats = new Float32Array(n * FLOATS_PER_SPLAT);
    this.depths = new Float32Array(n);
    this.order = new Uint32Array(n);
    this.canvas = canvas;
    this.time = 0;
    this.frames = 0;
    this.setCamera(0);
    this.initGL();
  }

  setCamera(index) {
    const c = this.meta.cameras[index];
    this.camera = { width: c.width, height: c.height, fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy, view: c.viewmat.slice() };
    this.canvas.width = c.width;
    this.canvas.height = c.height;
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

  interpolate(time) {
    const k = this.meta.keyframes, n = this.meta.gaussians, key = this.keyframes, out = this.state;
    const stride = n * CHANNELS;
    if (k === 1) { out.set(key.subarray(0, stride)); return; }
    const u = Math.min(Math.max(time, 0), 1) * (k - 1);
    const i = Math.min(Math.floor(u), k - 2), f = u - i, f2 = f * f, f3 = f2 * f;
    const o1 = i * stride, o2 = (i + 1) * stride;
    const o0 = i > 0 ? (i - 1) * stride : -1, o3 = i + 2 < k ? (i + 2) * stride : -1;
    for (let j = 0; j < stride; j++) {
      const p1 = key[o1 + j], p2 = key[o2 + j];
      const p0 = o0 >= 0 ? key[o0 + j] : 2 * p1 - p2;
      const p3 = o3 >= 0 ? key[o3 + j] : 2 * p2 - p1;
      out[j] = 0.5 * (2 * p1 + (p2 - p0) * f + (2 * p0 - 5 * p1 + 4 * p2 - p3) * f2 + (3 * p1 - p0 - 3 * p2 + p3) * f3);
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

  draw() {
    this.interpolate(this.time);
    const instances = this.project();
    const gl = this.gl, bg = this.meta.background;
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.uniform2f(this.viewport, this.canvas.width, this.canvas.height);
    gl.clearColor(bg[0], bg[1], bg[2], 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.instanceBuffer);
    gl.bufferData(gl.ARRAY_BUFFER, instances, gl.DYNAMIC_DRAW);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, instances.length / 12);
    this.frames++;
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

  setPose(rows, centre) {
    const v = this.camera.view;
    for (let row = 0; row < 3; row++) {
      v[row * 4] = rows[row][0]; v[row * 4 + 1] = rows[row][1]; v[row * 4 + 2] = rows[row][2];
      v[row * 4 + 3] = -(rows[row][0] * centre[0] + rows[row][1] * centre[1] + rows[row][2] * centre[2]);
    }
  }
}

async function start() {
  const [meta, buffer] = await Promise.all([
    fetch("scene.json").then((r) => r.json()),
    fetch("scene.bin").then((r) => r.arrayBuffer()),
  ]);
  const player = new Player(document.getElementById("canvas"), meta, buffer);
  player.target = meta.target;
  const first = meta.cameras[0].viewmat;
  player.up = [-first[4], -first[5], -first[6]];
  const slider = document.getElementById("time"), button = document.getElementById("play");
  const cameraSelect = document.getElementById("camera"), fpsLabel = document.getElementById("fps");
  meta.cameras.forEach((c, i) => cameraSelect.add(new Option(c.name, String(i))));
  let playing = false, last = performance.now(), frameTimes = [];
  const show = () => { slider.value = String(player.time); player.draw(); };
  slider.addEventListener("input", () => { player.time = Number(slider.value); player.draw(); });
  button.addEventListener("click", () => { playing = !playing; button.textContent = playing ? "pause" : "play"; last = performance.now(); });
  cameraSelect.addEventListener("change", () => { player.setCamera(Number(cameraSelect.value)); player.draw(); });
  let dragging = null;
  player.canvas.addEventListener("pointerdown", (e) => { dragging = [e.clientX, e.clientY]; player.canvas.setPointerCapture(e.pointerId); });
  player.canvas.addEventListener("pointerup", () => { dragging = null; });
  player.canvas.addEventListener("pointermove", (e) => {
    if (!dragging) return;
    player.orbit(-(e.clientX - dragging[0]) * 0.01, -(e.clientY - dragging[1]) * 0.01);
    dragging = [e.clientX, e.clientY];
    player.draw();
  });
  player.canvas.addEventListener("wheel", (e) => { e.preventDefault(); player.zoom(Math.exp(e.deltaY * 0.001)); player.draw(); }, { passive: false });
  const tick = (now) => {
    if (playing) {
      player.time = (player.time + (now - last) / 1000 / meta.duration_s) % 1;
      frameTimes.push(now);
      while (frameTimes.length && now - frameTimes[0] > 1000) frameTimes.shift();
      fpsLabel.textContent = `${frameTimes.length} fps`;
      show();
    }
    last = now;
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);
  show();
  // For scripts and tests: jump to a camera and time, or measure the frame rate.
  window.player = {
    show(camera, time) { player.setCamera(camera); cameraSelect.value = String(camera); player.time = time; show(); return player.frames; },
    benchmark(frames) {
      const begin = performance.now();
      for (let i = 0; i < frames; i++) { player.time = i / frames; player.draw(); }
      player.gl.finish();
      return (frames * 1000) / (performance.now() - begin);
    },
    orbit(dx, dy) { player.orbit(dx, dy); player.draw(); },
    view() { return Array.from(player.camera.view); },
  };
  document.body.dataset.ready = "true";
}

start().catch((err) => {
  document.getElementById("message").textContent = String(err);
  console.error(err);
});
