"""The page template: HTML, CSS and the WebGL2 script, inlined (``%%DATA%%`` is the JSON :func:`page.collect` makes).

URL parameters set the view deterministically (tests, links): ``eye=x,y,z``, ``light=x,y,z``, ``intensity=I``,
``exposure=E`` (linear), ``object=plane|sphere``, ``mode=shaded|false``, ``channel=NAME``, ``width=W``,
``height=H``, ``texel=u,v`` (plot that texel's samples), ``ui=0`` (the canvas alone).  The script exposes
``window.sbrdfViewer``: ``ready``, ``errors``, ``set({...same keys...})``, ``state``, ``pick(u, v)``.
"""

TEMPLATE = r"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>%%TITLE%%</title>
<style>
body { font: 13px system-ui, sans-serif; margin: 0; background: #1e1e1e; color: #ddd; }
#wrap { display: flex; gap: 12px; padding: 10px; align-items: flex-start; }
#view { display: block; background: #000; cursor: grab; }
#side { min-width: 300px; max-width: 420px; }
fieldset { border: 1px solid #444; margin: 0 0 8px 0; }
label { display: block; margin: 3px 0; }
input[type=range] { width: 200px; vertical-align: middle; }
#plot { background: #fff; display: block; margin-top: 4px; }
#info, #pickinfo { white-space: pre-wrap; color: #aaa; font-size: 12px; }
#legend { height: 10px; width: 256px; }
body.bare #side, body.bare #info { display: none; }
body.bare #wrap { padding: 0; }
</style>
</head>
<body>
<div id="wrap">
<div>
<canvas id="view" width="640" height="480"></canvas>
<div id="info"></div>
</div>
<div id="side">
<fieldset><legend>Display</legend>
<label>object <select id="object"><option value="plane">plane</option><option value="sphere">sphere</option></select></label>
<label>view <select id="mode"><option value="shaded">shaded (point light)</option><option value="false">false colour</option></select></label>
<label>channel <select id="channel"></select></label>
<canvas id="legend" width="256" height="10"></canvas> <span id="range"></span>
<label>exposure (stops) <input id="exposure" type="range" min="-10" max="10" step="0.1" value="0"> <span id="exposure_v"></span></label>
<label>light intensity <input id="intensity" type="range" min="-3" max="6" step="0.1" value="2.6"> <span id="intensity_v"></span></label>
</fieldset>
<div id="help">drag: orbit the view · shift-drag or right-drag: move the light · wheel: zoom · click: plot a texel's samples</div>
<canvas id="plot" width="400" height="260"></canvas>
<div id="pickinfo">click the surface to plot the samples of the nearest embedded texel</div>
</div>
</div>
<script id="sbrdf-data" type="application/json">%%DATA%%</script>
<script>
"use strict";
(function () {
const D = JSON.parse(document.getElementById("sbrdf-data").textContent);
const V = window.sbrdfViewer = { ready: false, errors: [], state: {} };
function fail(msg) { V.errors.push(msg); console.error(msg); document.getElementById("info").textContent = msg; }
function f32(b64) {
  const s = atob(b64), n = s.length, u8 = new Uint8Array(n);
  for (let i = 0; i < n; i++) u8[i] = s.charCodeAt(i);
  return new Float32Array(u8.buffer);
}
// --- state ---------------------------------------------------------------------------------------------------------
const q = new URLSearchParams(location.search);
const vec = (s, d) => s ? s.split(",").map(Number) : d.slice();
const S = V.state = {
  eye: vec(q.get("eye"), D.view.eye), light: vec(q.get("light"), D.view.light),
  intensity: Number(q.get("intensity") || D.view.intensity), exposure: Number(q.get("exposure") || D.view.exposure),
  object: q.get("object") || "plane", mode: q.get("mode") || "shaded",
  channel: q.get("channel") || (D.channels.find(c => c.name === "rms") || D.channels[0]).name,
  width: Number(q.get("width") || D.view.width), height: Number(q.get("height") || D.view.height),
  fov: D.view.fov_deg,
};
if (q.get("ui") === "0") document.body.classList.add("bare");
const canvas = document.getElementById("view");
canvas.width = S.width; canvas.height = S.height;
const gl = canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: true, premultipliedAlpha: false });
if (!gl) { fail("WebGL2 is not available in this browser"); return; }
// --- shaders: the model's own GLSL (ES 3.00) ---------------------------------------------------------------------
function compile(type, src) {
  const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader does not compile: " + gl.getShaderInfoLog(s));
  return s;
}
let prog;
try {
  prog = gl.createProgram();
  gl.attachShader(prog, compile(gl.VERTEX_SHADER, D.vertex));
  gl.attachShader(prog, compile(gl.FRAGMENT_SHADER, D.fragment));
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("program does not link: " + gl.getProgramInfoLog(prog));
} catch (e) { fail(String(e.message || e)); return; }
gl.useProgram(prog);
// --- textures: parameter maps packed 4 channels per RGBA32F texture, NEAREST, repeat --------------------------------
const [TV, TU] = D.shape;
function floatTexture(unit, data) {
  const t = gl.createTexture(); gl.activeTexture(gl.TEXTURE0 + unit); gl.bindTexture(gl.TEXTURE_2D, t);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, TU, TV, 0, gl.RGBA, gl.FLOAT, data);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.REPEAT);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.REPEAT);
  return t;
}
const params = D.params.map(f32);
for (let k = 0; k < D.ntex; k++) { floatTexture(k, params[k]); gl.uniform1i(gl.getUniformLocation(prog, "u_params_" + k), k); }
const extra = f32(D.extra);
floatTexture(D.ntex, extra); gl.uniform1i(gl.getUniformLocation(prog, "u_extra"), D.ntex);
D.model_textures.forEach((mt, i) => {  // the model's own tables (gl_textures), NEAREST as the gl renderer
  const [h, w, c] = mt.shape, unit = D.ntex + 1 + i;
  const fmt = [[gl.R32F, gl.RED], [gl.RG32F, gl.RG], [gl.RGB32F, gl.RGB], [gl.RGBA32F, gl.RGBA]][c - 1];
  const t = gl.createTexture(); gl.activeTexture(gl.TEXTURE0 + unit); gl.bindTexture(gl.TEXTURE_2D, t);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  gl.texImage2D(gl.TEXTURE_2D, 0, fmt[0], w, h, 0, fmt[1], gl.FLOAT, f32(mt.data));
  for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
  gl.uniform1i(gl.getUniformLocation(prog, mt.uniform), unit);
});
// --- geometry: the plane (2 wide, z = 0) and the unit sphere, tessellated as sbrdf_lib.surface.tessellate -----------
const aspect = D.size_mm[1] / D.size_mm[0];
function mesh(kind) {
  const P = [], I = [];
  if (kind === "plane") {
    const sx = 2, sy = 2 * aspect;
    for (const [s, t] of [[0, 0], [1, 0], [0, 1], [1, 1]]) P.push((s - 0.5) * sx, (t - 0.5) * sy, 0, 0, 0, 1, 1, 0, 0, 1, s, t);
    I.push(0, 1, 3, 0, 3, 2);
  } else {
    const nu = 128, nv = 64;
    for (let j = 0; j <= nv; j++) for (let i = 0; i <= nu; i++) {
      const s = i / nu, t = j / nv, phi = 2 * Math.PI * s, th = Math.PI * (1 - t);
      const n = [Math.cos(phi) * Math.sin(th), Math.sin(phi) * Math.sin(th), Math.cos(th)];
      P.push(n[0], n[1], n[2], n[0], n[1], n[2], -Math.sin(phi), Math.cos(phi), 0, 1, s, t);
    }
    for (let j = 0; j < nv; j++) for (let i = 0; i < nu; i++) {
      const a = j * (nu + 1) + i; I.push(a, a + 1, a + nu + 2, a, a + nu + 2, a + nu + 1);
    }
  }
  const vao = gl.createVertexArray(); gl.bindVertexArray(vao);
  const vb = gl.createBuffer(); gl.bindBuffer(gl.ARRAY_BUFFER, vb); gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(P), gl.STATIC_DRAW);
  const ib = gl.createBuffer(); gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib); gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint32Array(I), gl.STATIC_DRAW);
  let off = 0;
  for (const [name, n] of [["in_pos", 3], ["in_normal", 3], ["in_tangent", 4], ["in_uv", 2]]) {
    const loc = gl.getAttribLocation(prog, name);
    if (loc >= 0) { gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, n, gl.FLOAT, false, 48, off); }
    off += 4 * n;
  }
  gl.bindVertexArray(null);
  return { vao, count: I.length };
}
const meshes = { plane: mesh("plane"), sphere: mesh("sphere") };
// --- camera: the matrices of sbrdf_lib.scene.Camera (look at the origin, +z up) -------------------------------------
const sub = (a, b) => a.map((x, i) => x - b[i]), dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = a => { const l = Math.hypot(a[0], a[1], a[2]); return a.map(x => x / l); };
function basis() {
  const f = norm(sub([0, 0, 0], S.eye)), r = norm(cross(f, [0, 0, 1])), u = cross(r, f);
  return [r, u, f];
}
function mvp() {
  const [r, u, f] = basis(), e = S.eye, W = S.width, H = S.height;
  const view = [[r[0], r[1], r[2], -dot(r, e)], [u[0], u[1], u[2], -dot(u, e)], [-f[0], -f[1], -f[2], dot(f, e)], [0, 0, 0, 1]];
  const d = Math.hypot(e[0], e[1], e[2]), far = d + 3 * Math.max(1, aspect), near = Math.max(far * 1e-5, d - 3 * Math.max(1, aspect));
  const fl = 1 / Math.tan(S.fov * Math.PI / 360);
  const proj = [[fl * H / W, 0, 0, 0], [0, fl, 0, 0], [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)], [0, 0, -1, 0]];
  const m = new Float32Array(16);
  for (let i = 0; i < 4; i++) for (let j = 0; j < 4; j++) {
    let s = 0; for (let k = 0; k < 4; k++) s += proj[i][k] * view[k][j];
    m[j * 4 + i] = s;  // column-major
  }
  return m;
}
// --- drawing --------------------------------------------------------------------------------------------------------
const U = n => gl.getUniformLocation(prog, n);
function channel() { return D.channels.find(c => c.name === S.channel) || D.channels[0]; }
function draw() {
  canvas.width = S.width; canvas.height = S.height;
  gl.viewport(0, 0, S.width, S.height);
  gl.clearColor(0, 0, 0, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.enable(gl.DEPTH_TEST); gl.disable(gl.CULL_FACE);
  gl.useProgram(prog);
  gl.uniformMatrix4fv(U("u_mvp"), false, mvp());
  gl.uniform3fv(U("u_eye"), S.eye); gl.uniform3fv(U("u_light_pos"), S.light);
  gl.uniform3f(U("u_light_power"), S.intensity, S.intensity, S.intensity);
  gl.uniform1f(U("u_exposure"), S.exposure);
  const ch = channel();
  gl.uniform1i(U("u_mode"), S.mode === "false" ? 1 : 0);
  gl.uniform1i(U("u_channel"), ch.index); gl.uniform2f(U("u_range"), ch.range[0], ch.range[1]);
  const m = meshes[S.object] || meshes.plane;
  gl.bindVertexArray(m.vao); gl.drawElements(gl.TRIANGLES, m.count, gl.UNSIGNED_INT, 0); gl.bindVertexArray(null);
  const err = gl.getError();
  if (err !== gl.NO_ERROR) fail("WebGL error " + err);
  syncUI();
}
// --- controls -------------------------------------------------------------------------------------------------------
const el = id => document.getElementById(id);
const chSel = el("channel");
for (const c of D.channels) { const o = document.createElement("option"); o.value = o.textContent = c.name; chSel.appendChild(o); }
function syncUI() {
  el("object").value = S.object; el("mode").value = S.mode; chSel.value = channel().name;
  el("exposure").value = Math.log2(S.exposure); el("exposure_v").textContent = `${Math.log2(S.exposure).toFixed(1)} (×${S.exposure.toPrecision(3)})`;
  el("intensity").value = Math.log2(S.intensity); el("intensity_v").textContent = S.intensity.toPrecision(3);
  const ch = channel(); el("range").textContent = ch.range[0].toPrecision(3) + " … " + ch.range[1].toPrecision(3);
  el("info").textContent = `${D.kind} ${D.source}\nmodel ${D.model} ${JSON.stringify(D.model_config)}` +
    (D.quantizer ? ` · quantizer ${D.quantizer}` : "") + ` · ${D.texels[0]}×${D.texels[1]} texels` +
    (D.stride > 1 ? ` (every ${D.stride}th shown)` : "") +
    `\neye ${S.eye.map(x => x.toFixed(2))} · light ${S.light.map(x => x.toFixed(2))}` +
    (D.samples ? `\nsamples embedded: ${D.samples.grid[0]}×${D.samples.grid[1]} texels, ${D.samples.total} samples (≤ ${D.samples.max_per_texel} per texel)` :
      "\n" + (D.samples_note || "no samples embedded"));
}
(function legend() {
  const c = el("legend").getContext("2d");
  const stops = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
  const g = c.createLinearGradient(0, 0, 256, 0);
  stops.forEach((s, i) => g.addColorStop(i / 4, `rgb(${s})`)); c.fillStyle = g; c.fillRect(0, 0, 256, 10);
})();
el("object").onchange = e => { S.object = e.target.value; draw(); };
el("mode").onchange = e => { S.mode = e.target.value; draw(); };
chSel.onchange = e => { S.channel = e.target.value; S.mode = "false"; draw(); };
el("exposure").oninput = e => { S.exposure = Math.pow(2, Number(e.target.value)); draw(); };
el("intensity").oninput = e => { S.intensity = Math.pow(2, Number(e.target.value)); draw(); };
function orbit(p, dx, dy) {
  const r = Math.hypot(p[0], p[1], p[2]);
  let az = Math.atan2(p[1], p[0]) - dx * 0.01, el_ = Math.asin(p[2] / r) + dy * 0.01;
  el_ = Math.max(-1.5, Math.min(1.5, el_));
  return [r * Math.cos(el_) * Math.cos(az), r * Math.cos(el_) * Math.sin(az), r * Math.sin(el_)];
}
let drag = null;
canvas.addEventListener("contextmenu", e => e.preventDefault());
canvas.addEventListener("mousedown", e => { drag = { x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, light: e.shiftKey || e.button === 2 }; });
window.addEventListener("mouseup", e => {
  if (drag && Math.abs(e.clientX - drag.x0) + Math.abs(e.clientY - drag.y0) < 3) clickAt(e);
  drag = null;
});
window.addEventListener("mousemove", e => {
  if (!drag) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y; drag.x = e.clientX; drag.y = e.clientY;
  if (drag.light) S.light = orbit(S.light, dx, -dy); else S.eye = orbit(S.eye, dx, dy);
  draw();
});
canvas.addEventListener("wheel", e => { e.preventDefault(); const k = Math.exp(e.deltaY * 0.001); S.eye = S.eye.map(x => x * k); draw(); }, { passive: false });
// --- picking: the ray through the pixel, intersected with the object, gives uv ---------------------------------------
function clickAt(e) {
  const rc = canvas.getBoundingClientRect();
  const px = (e.clientX - rc.left) / rc.width, py = (e.clientY - rc.top) / rc.height;
  const [r, u, f] = basis(), half = Math.tan(S.fov * Math.PI / 360);
  const x = (px * 2 - 1) * half * S.width / S.height, y = (1 - py * 2) * half;
  const d = norm([0, 1, 2].map(i => f[i] + x * r[i] + y * u[i])), o = S.eye;
  let uv = null;
  if (S.object === "plane") {
    if (Math.abs(d[2]) > 1e-9) {
      const t = -o[2] / d[2], p = o.map((v, i) => v + t * d[i]);
      const s = p[0] / 2 + 0.5, tt = p[1] / (2 * aspect) + 0.5;
      if (t > 0 && s >= 0 && s <= 1 && tt >= 0 && tt <= 1) uv = [s, tt];
    }
  } else {
    const b = dot(o, d), c = dot(o, o) - 1, disc = b * b - c;
    if (disc >= 0) {
      const t = -b - Math.sqrt(disc), p = o.map((v, i) => v + t * d[i]);
      let phi = Math.atan2(p[1], p[0]); if (phi < 0) phi += 2 * Math.PI;
      if (t > 0) uv = [phi / (2 * Math.PI), 1 - Math.acos(Math.max(-1, Math.min(1, p[2]))) / Math.PI];
    }
  }
  if (!uv) return;
  V.pick(Math.min(D.texels[0] - 1, Math.floor(uv[0] * D.texels[0])), Math.min(D.texels[1] - 1, Math.floor(uv[1] * D.texels[1])));
}
const SM = D.samples ? { th: f32(D.samples.theta_h), me: f32(D.samples.measured), fi: f32(D.samples.fitted) } : null;
function nearest(list, x) { let b = 0; list.forEach((v, i) => { if (Math.abs(v - x) < Math.abs(list[b] - x)) b = i; }); return b; }
V.pick = function (tu, tv) {
  const ctx = el("plot").getContext("2d"), W = 400, H = 260;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, W, H);
  const at = k => extra[((tv / D.stride | 0) * TU + (tu / D.stride | 0)) * 4 + k];
  let info = `texel (${tu}, ${tv}): rms ${at(0).toPrecision(3)} · held-out rms ${at(1).toPrecision(3)} sr⁻¹ · ${at(2)} samples`;
  if (!SM) { el("pickinfo").textContent = info + "\n" + (D.samples_note || "no samples embedded"); return; }
  const gi = nearest(D.samples.us, tu), gj = nearest(D.samples.vs, tv), t = gj * D.samples.grid[0] + gi;
  const a = D.samples.offsets[t], b = D.samples.offsets[t + 1];
  info += `\nplotted: embedded texel (${D.samples.us[gi]}, ${D.samples.vs[gj]}), ${b - a} samples` +
    "\nx: half-vector angle θh (deg) · y: luminance of f_r (sr⁻¹, log) · grey: measured · orange: fitted model";
  el("pickinfo").textContent = info;
  let lo = Infinity, hi = -Infinity;
  for (let i = a; i < b; i++) for (const v of [SM.me[i], SM.fi[i]]) if (v > 0) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!(hi > 0)) return;
  lo = Math.max(lo, hi * 1e-4);
  const X = th => 40 + th / 90 * (W - 50), Y = v => H - 25 - (Math.log(Math.max(v, lo)) - Math.log(lo)) / (Math.log(hi) - Math.log(lo) + 1e-9) * (H - 40);
  ctx.strokeStyle = "#888"; ctx.strokeRect(40, 15, W - 50, H - 40);
  ctx.fillStyle = "#333"; ctx.font = "11px sans-serif";
  ctx.fillText("0°", 36, H - 10); ctx.fillText("90° θh", W - 40, H - 10);
  ctx.fillText(hi.toPrecision(2), 2, 22); ctx.fillText(lo.toPrecision(2), 2, H - 25);
  for (let i = a; i < b; i++) {
    ctx.fillStyle = "rgba(90,90,90,0.7)"; ctx.fillRect(X(SM.th[i]) - 1.5, Y(SM.me[i]) - 1.5, 3, 3);
    ctx.fillStyle = "rgba(230,120,0,0.9)"; ctx.fillRect(X(SM.th[i]) - 1, Y(SM.fi[i]) - 1, 2, 2);
  }
  V.state.picked = [D.samples.us[gi], D.samples.vs[gj], b - a];
};
V.set = function (opts) {
  for (const [k, v] of Object.entries(opts || {})) S[k] = Array.isArray(v) ? v.slice() : v;
  draw();
};
draw();
if (q.get("texel")) { const [tu, tv] = q.get("texel").split(",").map(Number); V.pick(tu, tv); }
V.ready = true;
})();
</script>
</body>
</html>
"""
