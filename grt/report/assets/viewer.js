// GRT's mesh viewer: a few dozen lines of WebGL 1, embedded once per report page (no library, no network).
// Each <canvas class="grt-mesh" data-mesh="ID"> draws MESHES[ID]: positions (float32, m), the shared faces
// (uint32), per-vertex values (displacement, mm; colour scale 0..max) and marked vertices (handles red,
// anchors blue). Drag to turn, wheel to zoom; the views of one row turn together.
"use strict";
(function () {
  function b64(s, Type) {
    const bin = atob(s), buf = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) buf[i] = bin.charCodeAt(i);
    return new Type(buf.buffer);
  }
  // viridis at 5 stops, linearly interpolated
  const STOPS = [[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383],
                 [0.993, 0.906, 0.144]];
  function colormap(t) {
    t = Math.min(1, Math.max(0, t)) * (STOPS.length - 1);
    const i = Math.min(STOPS.length - 2, Math.floor(t)), f = t - i, a = STOPS[i], b = STOPS[i + 1];
    return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])];
  }
  window.GRT_COLORMAP = colormap;
  const VS = "attribute vec3 p; attribute vec3 n; attribute vec3 c; uniform mat4 mvp; uniform mat3 nm;" +
    "uniform float ps; varying vec3 vc; varying float l;" +
    "void main(){ gl_Position = mvp * vec4(p, 1.0); gl_PointSize = ps;" +
    " vec3 nn = normalize(nm * n); l = 0.35 + 0.65 * abs(nn.z); vc = c; }";
  const FS = "precision mediump float; varying vec3 vc; varying float l; uniform float lit;" +
    "void main(){ gl_FragColor = vec4(vc * mix(1.0, l, lit), 1.0); }";

  function shader(gl, type, src) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    return s;
  }
  function normals(pos, faces) {
    const n = new Float32Array(pos.length);
    for (let f = 0; f < faces.length; f += 3) {
      const a = 3 * faces[f], b = 3 * faces[f + 1], c = 3 * faces[f + 2];
      const ux = pos[b] - pos[a], uy = pos[b + 1] - pos[a + 1], uz = pos[b + 2] - pos[a + 2];
      const vx = pos[c] - pos[a], vy = pos[c + 1] - pos[a + 1], vz = pos[c + 2] - pos[a + 2];
      const x = uy * vz - uz * vy, y = uz * vx - ux * vz, z = ux * vy - uy * vx;
      for (const k of [a, b, c]) { n[k] += x; n[k + 1] += y; n[k + 2] += z; }
    }
    return n;
  }
  function buffer(gl, data, target) {
    const b = gl.createBuffer();
    gl.bindBuffer(target || gl.ARRAY_BUFFER, b);
    gl.bufferData(target || gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    return b;
  }
  function mul(a, b) {  // 4x4, column-major
    const o = new Float32Array(16);
    for (let i = 0; i < 4; i++) for (let j = 0; j < 4; j++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + j] * b[i * 4 + k];
      o[i * 4 + j] = s;
    }
    return o;
  }
  const groups = {};  // views that turn together: {yaw, pitch, zoom, draws: []}

  function view(canvas) {
    const m = window.GRT_MESHES[canvas.dataset.mesh], faces = b64(window.GRT_FACES[m.faces], Uint32Array);
    const pos = b64(m.positions, Float32Array), val = m.values ? b64(m.values, Float32Array) : null;
    const gl = canvas.getContext("webgl", {preserveDrawingBuffer: true, antialias: true});
    if (!gl || !gl.getExtension("OES_element_index_uint")) {
      canvas.insertAdjacentHTML("afterend", "<p class='warn'>WebGL is not available in this browser: no 3D view.</p>");
      return;
    }
    const prog = gl.createProgram();
    gl.attachShader(prog, shader(gl, gl.VERTEX_SHADER, VS));
    gl.attachShader(prog, shader(gl, gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(prog);
    gl.useProgram(prog);
    // center and scale: the nominal object's box (same for every view of the page)
    const c = m.center, s = 1.8 / m.size;
    const col = new Float32Array(pos.length);
    for (let v = 0; v < pos.length / 3; v++) {
      const rgb = val ? colormap(val[v] / (m.vmax || 1)) : [0.75, 0.75, 0.78];
      col.set(rgb, 3 * v);
    }
    const nrm = normals(pos, faces);
    const marks = [], mcol = [];
    for (const [key, rgb] of [["anchors", [0.15, 0.35, 1.0]], ["handles", [1.0, 0.1, 0.1]]]) {
      for (const v of (m[key] || [])) { marks.push(pos[3 * v], pos[3 * v + 1], pos[3 * v + 2]); mcol.push(...rgb); }
    }
    const bufs = {p: buffer(gl, pos), n: buffer(gl, nrm), c: buffer(gl, col), f: buffer(gl, faces, gl.ELEMENT_ARRAY_BUFFER),
                  mp: buffer(gl, new Float32Array(marks)), mn: buffer(gl, new Float32Array(marks.map((_, i) => (i % 3 === 2 ? 1 : 0)))),
                  mc: buffer(gl, new Float32Array(mcol))};
    const loc = {p: gl.getAttribLocation(prog, "p"), n: gl.getAttribLocation(prog, "n"), c: gl.getAttribLocation(prog, "c")};
    const u = {mvp: gl.getUniformLocation(prog, "mvp"), nm: gl.getUniformLocation(prog, "nm"),
               ps: gl.getUniformLocation(prog, "ps"), lit: gl.getUniformLocation(prog, "lit")};
    const g = groups[canvas.dataset.group] || (groups[canvas.dataset.group] = {yaw: 0.6, pitch: -1.1, zoom: 1, draws: []});
    function attrib(name, b) {
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.enableVertexAttribArray(loc[name]);
      gl.vertexAttribPointer(loc[name], 3, gl.FLOAT, false, 0, 0);
    }
    function draw() {
      const cy = Math.cos(g.yaw), sy = Math.sin(g.yaw), cp = Math.cos(g.pitch), sp = Math.sin(g.pitch);
      const rz = [cy, sy, 0, 0, -sy, cy, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];  // turn about z (up)
      const rx = [1, 0, 0, 0, 0, cp, sp, 0, 0, -sp, cp, 0, 0, 0, 0, 1];  // tilt
      const k = s * g.zoom;
      const sc = [k, 0, 0, 0, 0, k, 0, 0, 0, 0, k, 0, -k * c[0], -k * c[1], -k * c[2], 1];
      const depth = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -0.3, 0, 0, 0, 0, 1];  // orthographic, nearer = smaller
      const mvp = mul(depth, mul(rx, mul(rz, sc)));
      const r = mul(rx, rz);
      gl.uniformMatrix4fv(u.mvp, false, mvp);
      gl.uniformMatrix3fv(u.nm, false, new Float32Array([r[0], r[1], r[2], r[4], r[5], r[6], r[8], r[9], r[10]]));
      gl.viewport(0, 0, canvas.width, canvas.height);
      gl.clearColor(1, 1, 1, 1);
      gl.enable(gl.DEPTH_TEST);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      attrib("p", bufs.p); attrib("n", bufs.n); attrib("c", bufs.c);
      gl.uniform1f(u.lit, 1.0);
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, bufs.f);
      gl.drawElements(gl.TRIANGLES, faces.length, gl.UNSIGNED_INT, 0);
      if (marks.length) {
        gl.disable(gl.DEPTH_TEST);
        attrib("p", bufs.mp); attrib("n", bufs.mn); attrib("c", bufs.mc);
        gl.uniform1f(u.lit, 0.0);
        gl.uniform1f(u.ps, 6.0);
        gl.drawArrays(gl.POINTS, 0, marks.length / 3);
      }
      canvas.dataset.drawn = String(Number(canvas.dataset.drawn || 0) + 1);
    }
    g.draws.push(draw);
    let drag = null;
    canvas.addEventListener("pointerdown", e => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener("pointerup", () => { drag = null; });
    canvas.addEventListener("pointermove", e => {
      if (!drag) return;
      g.yaw += 0.01 * (e.clientX - drag[0]);
      g.pitch = Math.max(-3.1, Math.min(0, g.pitch + 0.01 * (e.clientY - drag[1])));
      drag = [e.clientX, e.clientY];
      g.draws.forEach(d => d());
    });
    canvas.addEventListener("wheel", e => {
      e.preventDefault();
      g.zoom = Math.max(0.3, Math.min(5, g.zoom * Math.exp(-0.001 * e.deltaY)));
      g.draws.forEach(d => d());
    }, {passive: false});
    draw();
  }
  window.addEventListener("load", () => document.querySelectorAll("canvas.grt-mesh").forEach(view));
})();
