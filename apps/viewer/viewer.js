// SPDX-License-Identifier: Apache-2.0
// The hisnegs MIP viewer's logic: decodes the embedded model and cameras, draws each
// Gaussian as an instanced screen-space quad from the EWA projection of
// splat/splat_math.hpp (same Σ2D incl. low_pass, same cutoff q <= δ, value a·exp(−q/2))
// blended with MAX into a float target (a hard MIP, order-free), then maps it for
// display (window, gamma, colour map). Orbit/zoom with the mouse. Not a soft MIP.
//
// Contract (tests rely on it): `#view=N&ui=0` shows view N of the embedded cameras with
// its own intrinsics and size and no UI; document.body.dataset.ready = "1" once drawn.
"use strict";
(function () {
  const errorBox = document.getElementById("error");
  function report(message) {
    // One recognisable console line per failure; headless tests scan for it.
    console.error("hisnegs-viewer error: " + message);
    errorBox.textContent = message;
  }
  window.addEventListener("error", (e) => report(e.message || String(e)));

  // --- data ------------------------------------------------------------------------
  // hisnegs-meta: {"count", "floats_per_gaussian": 10, "cutoff", "low_pass", "cameras": cameras.json}
  // hisnegs-model: base64 of count × 10 little-endian float32: mean x y z, Σ xx xy xz yy yz zz, amplitude.
  const meta = JSON.parse(document.getElementById("hisnegs-meta").textContent);
  const packed = (function () {
    const text = document.getElementById("hisnegs-model").textContent.trim();
    const bin = atob(text);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; ++i) bytes[i] = bin.charCodeAt(i);
    const stride = meta.floats_per_gaussian;
    if (bytes.length !== meta.count * stride * 4) {
      throw new Error("model holds " + bytes.length + " bytes, expected " + meta.count * stride * 4);
    }
    // Little-endian floats: read through a DataView so a big-endian host would still be right.
    const view = new DataView(bytes.buffer);
    const out = new Float32Array(meta.count * stride);
    for (let i = 0; i < out.length; ++i) out[i] = view.getFloat32(4 * i, true);
    return out;
  })();
  const cams = meta.cameras;

  // --- camera state ------------------------------------------------------------------
  // R: rows of world->camera rotation (OpenCV axes), t: p_cam = R p + t.
  let camera = null;
  function cameraOfView(n) {
    const v = cams.views[n];
    return { R: v.R.map((r) => r.slice()), t: v.T.slice() };
  }
  function center(c) {  // C = −Rᵀ t
    const R = c.R, t = c.t;
    return [0, 1, 2].map((i) => -(R[0][i] * t[0] + R[1][i] * t[1] + R[2][i] * t[2]));
  }
  // CONVENTIONS "Orbit pose": C = r (cos e cos φ, cos e sin φ, sin e) looking at the origin.
  function orbitCamera(e, phi, r) {
    const C = [r * Math.cos(e) * Math.cos(phi), r * Math.cos(e) * Math.sin(phi), r * Math.sin(e)];
    const norm = (v) => { const l = Math.hypot(v[0], v[1], v[2]); return v.map((x) => x / l); };
    const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    const z = norm(C.map((x) => -x));
    const up = Math.abs(Math.sin(e)) > 0.999 ? [0, 1, 0] : [0, 0, 1];
    const x = norm(cross(z, up));
    const y = cross(z, x);
    const R = [x, y, z];
    const t = R.map((row) => -(row[0] * C[0] + row[1] * C[1] + row[2] * C[2]));
    return { R, t };
  }

  // --- WebGL2 ----------------------------------------------------------------------
  const canvas = document.getElementById("view");
  const W = cams.width, H = cams.height;
  canvas.width = W;
  canvas.height = H;
  canvas.style.width = W + "px";
  canvas.style.height = H + "px";
  const gl = canvas.getContext("webgl2", { antialias: false, alpha: false, depth: false, preserveDrawingBuffer: true });
  if (!gl) throw new Error("WebGL2 is not available");
  if (!gl.getExtension("EXT_color_buffer_float")) throw new Error("EXT_color_buffer_float is not available");
  // 32-bit float targets blend only with EXT_float_blend; 16-bit ones always (error < 2^-11 in [0, 1]).
  const float32 = !!gl.getExtension("EXT_float_blend");

  const splatVS = `#version 300 es
precision highp float;
layout(location = 0) in vec2 corner;     // quad corner in {-1, 1}²
layout(location = 1) in vec3 mean;       // μ, world
layout(location = 2) in vec3 covA;       // Σ xx xy xz
layout(location = 3) in vec3 covB;       // Σ yy yz zz
layout(location = 4) in float amp;       // a = sigmoid(logit)
uniform vec3 r0, r1, r2, t;              // rows of R, translation
uniform vec4 K;                          // fx fy cx cy
uniform vec2 clipZ;                      // near far
uniform vec2 size;                       // W H
uniform float cutoff, lowPass;
flat out vec3 conic;
flat out vec2 centre;
flat out float amplitude;
void cull() { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); conic = vec3(0.0); centre = vec2(0.0); amplitude = 0.0; }
void main() {
  vec3 mc = vec3(dot(r0, mean), dot(r1, mean), dot(r2, mean)) + t;
  // Culled by the centre's depth, as splat_math.hpp project_gaussian.
  if (!(mc.z >= clipZ.x && mc.z <= clipZ.y)) { cull(); return; }
  float iz = 1.0 / mc.z;
  // W = J R, J the pinhole Jacobian at μ_cam (Eq. 4).
  vec3 w0 = (K.x * iz) * r0 + (-K.x * mc.x * iz * iz) * r2;
  vec3 w1 = (K.y * iz) * r1 + (-K.y * mc.y * iz * iz) * r2;
  mat3 S = mat3(covA.x, covA.y, covA.z, covA.y, covB.x, covB.y, covA.z, covB.y, covB.z);
  vec3 Sw0 = S * w0, Sw1 = S * w1;
  float a = dot(w0, Sw0) + lowPass, b = dot(w0, Sw1), c = dot(w1, Sw1) + lowPass;
  float det = a * c - b * b;
  if (!(det > 0.0) || !(a > 0.0)) { cull(); return; }
  conic = vec3(c, -b, a) / det;
  centre = vec2(K.x * mc.x * iz + K.z, K.y * mc.y * iz + K.w);
  amplitude = amp;
  // The δ ellipse's bounding box (±sqrt(δ Σxx), ±sqrt(δ Σyy)) plus a pixel; the
  // fragment test q <= δ decides, as the CPU's per-pixel test does.
  vec2 halfExtent = sqrt(cutoff * vec2(a, c)) + 1.0;
  vec2 p = centre + corner * halfExtent;
  // Pixel coordinates (y down) -> NDC (y up): image row 0 is the top row.
  gl_Position = vec4(2.0 * p.x / size.x - 1.0, 1.0 - 2.0 * p.y / size.y, 0.0, 1.0);
}`;
  const splatFS = `#version 300 es
precision highp float;
flat in vec3 conic;
flat in vec2 centre;
flat in float amplitude;
uniform float cutoff, height;
out vec4 value;
void main() {
  // gl_FragCoord is the pixel centre (c + 0.5, row-from-bottom + 0.5); v counts rows from the top.
  vec2 d = vec2(gl_FragCoord.x, height - gl_FragCoord.y) - centre;
  float q = conic.x * d.x * d.x + 2.0 * conic.y * d.x * d.y + conic.z * d.y * d.y;
  if (q > cutoff) discard;
  value = vec4(amplitude * exp(-0.5 * q), 0.0, 0.0, 1.0);
}`;
  const displayVS = `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}`;
  const displayFS = `#version 300 es
precision highp float;
uniform highp sampler2D mip;
uniform float lo, hi, gamma;
uniform int cmap;
out vec4 colour;
vec3 inferno(float x) {  // polynomial fit of matplotlib's inferno (Matt Zucker, CC0)
  const vec3 c0 = vec3(0.0002189403691192265, 0.001651004631001012, -0.01948089843709184);
  const vec3 c1 = vec3(0.1065134194856116, 0.5639564367884091, 3.932712388889277);
  const vec3 c2 = vec3(11.60249308247187, -3.972853965665698, -15.9423941062914);
  const vec3 c3 = vec3(-41.70399613139459, 17.43639888205313, 44.35414519872813);
  const vec3 c4 = vec3(77.162935699427, -33.40235894210092, -81.80730925738993);
  const vec3 c5 = vec3(-71.31942824499214, 32.62606426397723, 73.20951985803202);
  const vec3 c6 = vec3(25.13112622477341, -12.24266895238567, -23.07032500287172);
  return clamp(c0 + x * (c1 + x * (c2 + x * (c3 + x * (c4 + x * (c5 + x * c6))))), 0.0, 1.0);
}
void main() {
  float v = texelFetch(mip, ivec2(gl_FragCoord.xy), 0).r;
  float x = clamp((v - lo) / (hi - lo), 0.0, 1.0);
  if (gamma != 1.0) x = pow(x, gamma);
  vec3 c = cmap == 1 ? inferno(x) : (cmap == 2 ? vec3(0.0, x, 0.0) : vec3(x));
  colour = vec4(c, 1.0);
}`;

  function compile(type, source, name) {
    const s = gl.createShader(type);
    gl.shaderSource(s, source);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) {
      throw new Error("shader compile error in " + name + ": " + gl.getShaderInfoLog(s));
    }
    return s;
  }
  function program(vs, fs, name) {
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl.VERTEX_SHADER, vs, name + " vertex"));
    gl.attachShader(p, compile(gl.FRAGMENT_SHADER, fs, name + " fragment"));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error("program link error in " + name + ": " + gl.getProgramInfoLog(p));
    const u = {};
    const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < n; ++i) {
      const info = gl.getActiveUniform(p, i);
      u[info.name] = gl.getUniformLocation(p, info.name);
    }
    return { p, u };
  }
  const splat = program(splatVS, splatFS, "splat");
  const display = program(displayVS, displayFS, "display");

  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  const cornerBuf = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, cornerBuf);
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
  gl.enableVertexAttribArray(0);
  gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
  const instBuf = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, instBuf);
  gl.bufferData(gl.ARRAY_BUFFER, packed, gl.STATIC_DRAW);
  const stride = 4 * meta.floats_per_gaussian;
  [[1, 3, 0], [2, 3, 12], [3, 3, 24], [4, 1, 36]].forEach(([loc, n, offset]) => {
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, n, gl.FLOAT, false, stride, offset);
    gl.vertexAttribDivisor(loc, 1);
  });
  gl.bindVertexArray(null);

  const target = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, target);
  gl.texStorage2D(gl.TEXTURE_2D, 1, float32 ? gl.R32F : gl.R16F, W, H);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  const fbo = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
  gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, target, 0);
  if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) throw new Error("float render target is incomplete");
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);

  const el = (id) => document.getElementById(id);
  function displaySettings() {
    return { lo: parseFloat(el("lo").value), hi: parseFloat(el("hi").value),
             gamma: parseFloat(el("gamma").value), cmap: parseInt(el("cmap").value, 10) };
  }

  function draw() {
    const t0 = performance.now();
    const c = camera;
    // Pass 1: hard MIP of the splats into the float target.
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.viewport(0, 0, W, H);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.enable(gl.BLEND);
    gl.blendEquation(gl.MAX);
    gl.blendFunc(gl.ONE, gl.ONE);
    gl.useProgram(splat.p);
    const u = splat.u;
    gl.uniform3fv(u.r0, c.R[0]);
    gl.uniform3fv(u.r1, c.R[1]);
    gl.uniform3fv(u.r2, c.R[2]);
    gl.uniform3fv(u.t, c.t);
    gl.uniform4f(u.K, cams.fx, cams.fy, cams.cx, cams.cy);
    gl.uniform2f(u.clipZ, cams.near, cams.far);
    gl.uniform2f(u.size, W, H);
    gl.uniform1f(u.cutoff, meta.cutoff);
    gl.uniform1f(u.lowPass, meta.low_pass);
    gl.uniform1f(u.height, H);
    gl.bindVertexArray(vao);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, meta.count);
    gl.bindVertexArray(null);
    gl.disable(gl.BLEND);
    // Pass 2: window / gamma / colour map to the canvas.
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, W, H);
    gl.useProgram(display.p);
    const s = displaySettings();
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, target);
    gl.uniform1i(display.u.mip, 0);
    gl.uniform1f(display.u.lo, s.lo);
    gl.uniform1f(display.u.hi, s.hi > s.lo ? s.hi : s.lo + 1e-6);
    gl.uniform1f(display.u.gamma, s.gamma > 0 ? s.gamma : 1);
    gl.uniform1i(display.u.cmap, s.cmap);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.finish();
    const ms = performance.now() - t0;
    el("stats").textContent = meta.count + " Gaussians, " + W + "×" + H + ", " + ms.toFixed(1) + " ms/frame (" +
                              (float32 ? "32" : "16") + "-bit float target)";
  }

  // --- views, hash, UI ---------------------------------------------------------------
  const select = el("view-select");
  cams.views.forEach((v, i) => {
    const o = document.createElement("option");
    o.value = String(i);
    o.textContent = i + ": " + v.name;
    select.appendChild(o);
  });
  function parseHash() {
    const params = new URLSearchParams(location.hash.replace(/^#/, ""));
    const view = params.has("view") ? parseInt(params.get("view"), 10) : 0;
    if (!(view >= 0 && view < cams.views.length)) throw new Error("#view=" + params.get("view") + ": expected 0.." + (cams.views.length - 1));
    return { view, ui: params.get("ui") !== "0" };
  }
  function applyHash() {
    const h = parseHash();
    document.body.classList.toggle("noui", !h.ui);
    select.value = String(h.view);
    camera = cameraOfView(h.view);
    draw();
  }
  window.addEventListener("hashchange", applyHash);
  select.addEventListener("change", () => { camera = cameraOfView(parseInt(select.value, 10)); draw(); });
  el("reset").addEventListener("click", () => { camera = cameraOfView(parseInt(select.value, 10)); draw(); });
  ["lo", "hi", "gamma", "cmap"].forEach((id) => el(id).addEventListener("input", draw));

  // Orbit about the origin from the current camera centre; wheel scales the radius.
  function spherical() {
    const C = center(camera);
    const r = Math.hypot(C[0], C[1], C[2]);
    return { e: Math.asin(Math.max(-1, Math.min(1, C[2] / r))), phi: Math.atan2(C[1], C[0]), r };
  }
  let drag = null;
  canvas.addEventListener("pointerdown", (ev) => { drag = { x: ev.clientX, y: ev.clientY, s: spherical() }; canvas.setPointerCapture(ev.pointerId); });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("pointermove", (ev) => {
    if (!drag) return;
    const k = Math.PI / 360;  // 0.5° per pixel
    const e = Math.max(-1.55, Math.min(1.55, drag.s.e + (ev.clientY - drag.y) * k));
    camera = orbitCamera(e, drag.s.phi - (ev.clientX - drag.x) * k, drag.s.r);
    draw();
  });
  canvas.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const s = spherical();
    camera = orbitCamera(s.e, s.phi, s.r * Math.exp(ev.deltaY * 0.001));
    draw();
  }, { passive: false });

  applyHash();
  // #bench=N: N more frames of the same view, timed to a readPixels that waits for each (real time only when
  // the browser runs without a virtual time budget), logged as one console line.
  const benchFrames = parseInt(new URLSearchParams(location.hash.replace(/^#/, "")).get("bench") || "0", 10);
  if (benchFrames > 0) {
    const t0 = performance.now();
    const pixel = new Uint8Array(4);
    for (let i = 0; i < benchFrames; ++i) {
      draw();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);  // waits for the frame, unlike finish()
    }
    console.log("hisnegs-viewer bench: " + ((performance.now() - t0) / benchFrames).toFixed(2) + " ms/frame over " +
                benchFrames + " frames, " + meta.count + " Gaussians, " + W + "x" + H);
  }
  document.body.dataset.ready = "1";
  // The same signal for tools that read the console rather than the DOM.
  console.log("hisnegs-viewer ready: view " + select.value + " drawn");
})();
