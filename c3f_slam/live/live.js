/* C3Fusion live page (c3f_slam/live/page.html). Polls /state.json?since=V every POLL_MS ms, one request
   at a time (a failed one is retried after RETRY_MS), keeps what it received (LiveState.snapshot's
   schema: c3f_slam/live/state.py) and draws: the current frame (/frame.jpg; its capture->display
   delay is POSTed to /shown), the 3D map (three.js, the global THREE of /three.js: map points, the
   wall rows as a tube, the scope's path and frustum, orbit controls; the view follows the scope
   until the user moves it), the unrolled wall, the unseen share per segment, the alerts, the frame
   timeline, the rates and the run's status. Units: metres in the data, cm on the page.
   With "#selftest" in the address, once a frame was shown and wall rows and an alert were received
   (or after SELFTEST_TIMEOUT_MS), the page writes a JSON result into <pre id="live-selftest">
   (tests/test_live_page.py). */
(function () {
  "use strict";
  const errors = [];
  const origError = console.error;
  console.error = function (...args) { errors.push(args.map(String).join(" ")); origError.apply(console, args); };
  window.addEventListener("error", (e) => errors.push(String(e.message || e)));
  window.addEventListener("unhandledrejection", (e) => errors.push("unhandled rejection: " + String(e.reason)));

  const POLL_MS = 200, IDLE_POLL_MS = 1000, RETRY_MS = 1000, SELFTEST_TIMEOUT_MS = 20000;
  const MAP_BG = [0x1d, 0x21, 0x27], PLOT_BG = [0x14, 0x18, 0x1d];
  const UNSEEN = [255, 45, 111], NEUTRAL = [201, 154, 134], OBSERVED_GREY = [150, 158, 168], UNKNOWN = [44, 50, 58];
  const PATH_COLOUR = 0x4fd1c5, SCOPE_COLOUR = 0xffd84d;
  const SRGB_TO_LINEAR = new Float32Array(256).map((_, i) => {
    const c = i / 255;
    return c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4);
  });
  /* timeline kinds: [legend label, colour]; kinds sharing a label share the legend entry */
  const KIND_STYLE = {
    extended: ["tracked", "#3fb27f"], keyframe: ["tracked", "#3fb27f"], attached: ["tracked", "#3fb27f"],
    lone: ["new map part", "#4c8dff"], lost: ["lost", "#ff8c42"], rejoined: ["rejoined", "#2ee6d6"],
    black: ["black", "#8e7fc0"], saturated: ["saturated", "#f2f2f2"], featureless: ["featureless", "#b08a6e"],
    unreadable: ["unreadable", "#d35d6e"], blurred: ["blurred", "#e0c341"], dark: ["dark", "#7d6457"],
    washed_out: ["washed out", "#fff3b0"], duplicate: ["repeated", "#8f98a3"], covered: ["covered", "#c49bff"],
    dropped: ["dropped", "#3e4550"],
  };
  const BACKGROUND_KINDS = new Set(["extended", "keyframe", "attached", "dropped"]);
  const SELFTEST = location.hash === "#selftest";
  const $ = (id) => document.getElementById(id);

  const S = {
    version: 0, snap: null, rows: new Map(), rowsChanged: new Set(), rowsAll: false, path: [], timeline: [], segments: [], alerts: [],
    wantFrame: -1, loadedFrame: -1, frameLoaded: false, frameIndex: null, frameBusy: false, frameUrl: null,
    shownDelay: null, connected: true, keys: {},
  };

  function decodeB64(b64) {
    const bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return bytes;
  }
  const pct = (x) => (x === null || x === undefined ? "-" : String(Math.round(x * 100)));
  function fmtCm(m) {
    const v = m * 100;
    return Math.abs(v - Math.round(v)) < 0.05 ? String(Math.round(v)) : v.toFixed(1);
  }
  const fmtMs = (x) => (x === null || x === undefined ? "-" : String(Math.round(x)));
  const fmtFps = (x) => (x === null || x === undefined ? "-" : x.toFixed(1));
  const kindLabel = (k) => (KIND_STYLE[k] ? KIND_STYLE[k][0] : k);
  const kindColour = (k) => (KIND_STYLE[k] ? KIND_STYLE[k][1] : "#777777");
  const rgbCss = (c) => `rgb(${c[0]},${c[1]},${c[2]})`;
  function changed(key, value) { /* true when value differs from the last one seen under key */
    const s = JSON.stringify(value);
    if (S.keys[key] === s) return false;
    S.keys[key] = s;
    return true;
  }

  /* ---- wall rows ---------------------------------------------------------------------------- */
  function decodeRow(r) {
    const A = r.radius.length, pts = new Float32Array(A * 3), radius = new Float32Array(A);
    const [c, N, B] = [r.centre, r.N, r.B];
    for (let j = 0; j < A; j++) {
      const rad = r.radius[j] === null ? NaN : r.radius[j];
      const th = -Math.PI + ((j + 0.5) * 2 * Math.PI) / A, ct = Math.cos(th), st = Math.sin(th);
      radius[j] = rad;
      for (let k = 0; k < 3; k++) pts[3 * j + k] = c[k] + rad * (ct * N[k] + st * B[k]);
    }
    return { i: r.i, A, centre: c, radius, pts, observed: r.observed, measured: r.measured, colour: decodeB64(r.colour) };
  }
  function cellColour(row, j, forTube) { /* [r, g, b] 0..255 of cell j of a row */
    if (row.observed[j] !== "1") return UNSEEN;
    if (row.measured[j] === "1") return [row.colour[3 * j], row.colour[3 * j + 1], row.colour[3 * j + 2]];
    return forTube ? NEUTRAL : OBSERVED_GREY;
  }

  /* ---- 3D view ------------------------------------------------------------------------------ */
  function makeView(box) {
    let renderer;
    try {
      renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    } catch (e) {
      $("map-waiting").textContent = "The 3D view could not start: " + e.message;
      errors.push("3D view: " + e.message);
      return null;
    }
    renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    renderer.setClearColor(new THREE.Color(rgbCss(MAP_BG)), 1);
    renderer.localClippingEnabled = true;
    box.appendChild(renderer.domElement);
    const scene = new THREE.Scene();
    const camera = new THREE.PerspectiveCamera(50, 1, 1e-4, 20);
    camera.up.set(0, -1, 0); /* the first camera's image up */
    camera.position.set(0.05, -0.1, 0.05);
    scene.add(new THREE.AmbientLight(0xffffff, 1.1));
    const head = new THREE.DirectionalLight(0xffffff, 1.7);
    head.target.position.set(0, 0, -1);
    camera.add(head, head.target);
    scene.add(camera);
    const controls = new THREE.OrbitControls(camera, renderer.domElement);
    const plane = new THREE.Plane();
    const clipping = [plane];
    const V = { renderer, camera, controls, follow: true, cut: true, points: null, pointsCap: 0, pointsN: 0,
      tube: false, path: null, scope: null, target: null, hasContent: false };

    const tubeMaterial = new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide, clippingPlanes: clipping });
    const pointsMaterial = new THREE.PointsMaterial({ size: 3, sizeAttenuation: false, vertexColors: true, clippingPlanes: clipping });
    const pathMaterial = new THREE.LineBasicMaterial({ color: PATH_COLOUR, depthTest: false, transparent: true });
    const scopeMaterial = new THREE.LineBasicMaterial({ color: SCOPE_COLOUR, depthTest: false, transparent: true });
    const apexMaterial = new THREE.PointsMaterial({ color: SCOPE_COLOUR, size: 7, sizeAttenuation: false, depthTest: false, transparent: true });

    let pending = false;
    V.requestRender = () => {
      if (pending) return;
      pending = true;
      requestAnimationFrame(() => { pending = false; V.render(); });
    };
    V.render = () => {
      const dir = new THREE.Vector3().subVectors(controls.target, camera.position).normalize();
      plane.setFromNormalAndCoplanarPoint(dir, controls.target);
      tubeMaterial.clippingPlanes = V.cut ? clipping : null;
      pointsMaterial.clippingPlanes = V.cut ? clipping : null;
      renderer.render(scene, camera);
    };
    V.setFollow = (on) => {
      V.follow = on;
      $("follow").classList.toggle("on", on);
      if (on) V.updateFollow();
    };
    controls.addEventListener("change", V.requestRender);
    controls.addEventListener("start", () => V.setFollow(false));
    V.resize = () => {
      const w = box.clientWidth, h = box.clientHeight;
      if (!w || !h) return;
      renderer.setSize(w, h, false);
      camera.aspect = w / h;
      camera.updateProjectionMatrix();
      V.render();
    };
    new ResizeObserver(V.resize).observe(box);
    V.resize();

    function replace(old, obj) {
      if (old) { scene.remove(old); old.geometry.dispose(); }
      if (obj) { obj.frustumCulled = false; scene.add(obj); }
      return obj;
    }
    function contentChanged() {
      V.hasContent = V.pointsN > 0 || Boolean(V.tube) || Boolean(V.path);
      $("map-waiting").hidden = V.hasContent;
    }

    V.clear = () => {
      V.points = replace(V.points, null); V.pointsCap = V.pointsN = 0;
      for (const mesh of V.tubes.values()) replace(mesh, null);
      V.tubes.clear(); V.tube = false;
      V.path = replace(V.path, null); V.scope = replace(V.scope, null);
      V.apex = replace(V.apex, null); V.pose = null;
      contentChanged();
      V.requestRender();
    };

    /* map points from offset start: xyz Float32Array (n * 3), rgb Uint8Array (n * 3) */
    V.setPoints = (start, xyz, rgb) => {
      const n = start + xyz.length / 3;
      if (n > V.pointsCap || !V.points) {
        const cap = Math.max(4096, 2 ** Math.ceil(Math.log2(Math.max(n, 1))));
        const pos = new Float32Array(cap * 3), col = new Float32Array(cap * 3);
        if (V.points) {
          pos.set(V.points.geometry.attributes.position.array.subarray(0, start * 3));
          col.set(V.points.geometry.attributes.color.array.subarray(0, start * 3));
        }
        const g = new THREE.BufferGeometry();
        g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
        g.setAttribute("color", new THREE.BufferAttribute(col, 3));
        V.points = replace(V.points, new THREE.Points(g, pointsMaterial));
        V.pointsCap = cap;
      }
      const g = V.points.geometry, pos = g.attributes.position, col = g.attributes.color;
      pos.array.set(xyz, start * 3);
      for (let k = 0; k < rgb.length; k++) col.array[start * 3 + k] = SRGB_TO_LINEAR[rgb[k]];
      for (const a of [pos, col]) { /* upload the new points only */
        a.clearUpdateRanges();
        a.addUpdateRange(start * 3, Math.max(xyz.length, 3));
        a.needsUpdate = true;
      }
      g.setDrawRange(0, n);
      V.pointsN = n;
      contentChanged();
      V.requestRender();
    };

    /* the wall rows (Map i -> decoded row) as a tube: one quad between the cell centres of rows i and
       i + 1 and bins j and j + 1, coloured as cell (i, j); not drawn where a radius is unknown. The
       tube is cut into meshes of TUBE_CHUNK rows; ``changed`` (row indices, or null: all) says which
       are rebuilt, so a long colon costs its changed rows only */
    const TUBE_CHUNK = 32;
    V.tubes = new Map();
    function tubeChunk(rows, k) {
      let v = 0, pos = null, col = null;
      const put = (row, j, c) => {
        pos[v] = row.pts[3 * j]; pos[v + 1] = row.pts[3 * j + 1]; pos[v + 2] = row.pts[3 * j + 2];
        col[v] = c[0]; col[v + 1] = c[1]; col[v + 2] = c[2];
        v += 3;
      };
      for (let i = k * TUBE_CHUNK; i < (k + 1) * TUBE_CHUNK; i++) {
        const a = rows.get(i), b = rows.get(i + 1);
        if (!a || !b || a.A !== b.A) continue;
        if (!pos) { pos = new Float32Array(TUBE_CHUNK * a.A * 18); col = new Float32Array(TUBE_CHUNK * a.A * 18); }
        if (v + a.A * 18 > pos.length) break;
        for (let j = 0; j < a.A; j++) {
          const jn = (j + 1) % a.A;
          if (isNaN(a.radius[j]) || isNaN(a.radius[jn]) || isNaN(b.radius[j]) || isNaN(b.radius[jn])) continue;
          const c8 = cellColour(a, j, true), c = [SRGB_TO_LINEAR[c8[0]], SRGB_TO_LINEAR[c8[1]], SRGB_TO_LINEAR[c8[2]]];
          put(a, j, c); put(b, j, c); put(b, jn, c);
          put(a, j, c); put(b, jn, c); put(a, jn, c);
        }
      }
      if (!v) return null;
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(pos.slice(0, v), 3));
      g.setAttribute("color", new THREE.BufferAttribute(col.slice(0, v), 3));
      g.computeVertexNormals();
      return new THREE.Mesh(g, tubeMaterial);
    }
    V.setWall = (rows, changed) => {
      const chunks = new Set();
      if (changed === null) {
        for (const k of V.tubes.keys()) chunks.add(k);
        for (const i of rows.keys()) chunks.add(Math.floor(i / TUBE_CHUNK));
      } else {
        for (const i of changed) { chunks.add(Math.floor(i / TUBE_CHUNK)); chunks.add(Math.floor((i - 1) / TUBE_CHUNK)); }
      }
      for (const k of chunks) {
        if (k < 0) continue;
        const mesh = replace(V.tubes.get(k), tubeChunk(rows, k));
        if (mesh) V.tubes.set(k, mesh); else V.tubes.delete(k);
      }
      V.tube = V.tubes.size > 0;
      contentChanged();
      V.requestRender();
    };

    V.setPath = (path) => {
      if (path.length < 2) { V.path = replace(V.path, null); contentChanged(); V.requestRender(); return; }
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(Float32Array.from(path.flat()), 3));
      const line = new THREE.Line(g, pathMaterial);
      line.renderOrder = 10;
      V.path = replace(V.path, line);
      contentChanged();
      V.requestRender();
    };

    /* the scope: its frustum 8 mm deep, an image-up tick and its centre, from the camera-to-world pose */
    V.setPose = (pose, cam) => {
      if (!pose) { V.scope = replace(V.scope, null); V.apex = replace(V.apex, null); V.pose = null; V.requestRender(); return; }
      if (V.pose && V.pose.every((x, k) => x === pose[k])) return;
      V.pose = pose;
      const K = cam && cam.K ? cam.K : [[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]];
      const W = cam && cam.width ? cam.width : 1, H = cam && cam.height ? cam.height : 1, d = 0.008;
      const local = (u, v) => [((u - K[0][2]) / K[0][0]) * d, ((v - K[1][2]) / K[1][1]) * d, d];
      const corners = [local(0, 0), local(W, 0), local(W, H), local(0, H)];
      const top = local(W / 2, 0), tick = [top[0], top[1] * 1.45, top[2]];
      const world = (p) => [
        pose[0] * p[0] + pose[1] * p[1] + pose[2] * p[2] + pose[3],
        pose[4] * p[0] + pose[5] * p[1] + pose[6] * p[2] + pose[7],
        pose[8] * p[0] + pose[9] * p[1] + pose[10] * p[2] + pose[11]];
      const o = world([0, 0, 0]), w = corners.map(world);
      const seg = [];
      for (let k = 0; k < 4; k++) seg.push(o, w[k], w[k], w[(k + 1) % 4]);
      seg.push(world(top), world(tick));
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(Float32Array.from(seg.flat()), 3));
      const lines = new THREE.LineSegments(g, scopeMaterial);
      lines.renderOrder = 11;
      V.scope = replace(V.scope, lines);
      const ga = new THREE.BufferGeometry();
      ga.setAttribute("position", new THREE.BufferAttribute(Float32Array.from(o), 3));
      const apex = new THREE.Points(ga, apexMaterial);
      apex.renderOrder = 12;
      V.apex = replace(V.apex, apex);
      V.requestRender();
    };

    /* while following: look at the scope from beside its path (above it in the first camera's image
       and a little ahead of its motion), at a distance of 6 wall radii */
    V.updateFollow = () => {
      if (!V.follow) return;
      const pose = V.pose, path = S.path;
      let target = pose ? [pose[3], pose[7], pose[11]] : path.length ? path[path.length - 1] : null;
      if (!target) return;
      let dir = null;
      for (let k = path.length - 2; k >= 0 && path.length; k--) {
        const last = path[path.length - 1], p = path[k];
        const d = [last[0] - p[0], last[1] - p[1], last[2] - p[2]], n = Math.hypot(...d);
        if (n >= 0.02 || k === 0) { if (n > 1e-4) dir = d.map((x) => x / n); break; }
      }
      if (!dir && pose) dir = [pose[2], pose[6], pose[10]];
      if (!dir) dir = [0, 0, 1];
      const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
      const perp = (u) => { const t = dot(u, dir); const p = u.map((x, k) => x - t * dir[k]); const n = Math.hypot(...p); return n > 0.3 ? p.map((x) => x / n) : null; };
      const up = perp([0, -1, 0]) || perp([1, 0, 0]);
      const side = [dir[1] * up[2] - dir[2] * up[1], dir[2] * up[0] - dir[0] * up[2], dir[0] * up[1] - dir[1] * up[0]];
      const radii = [], near = scopeRow(); /* the wall's radius around the scope */
      for (const row of S.rows.values()) {
        if (near && Math.abs(row.i - near.i) > 20) continue;
        for (const r of row.radius) if (!isNaN(r)) radii.push(r);
      }
      radii.sort((a, b) => a - b);
      const dist = Math.min(0.4, Math.max(0.05, radii.length ? 6 * radii[radii.length >> 1] : 0.12));
      const off = up.map((x, k) => 0.75 * x + 0.35 * side[k] + 0.4 * dir[k]);
      const n = Math.hypot(...off);
      if (V.target) target = target.map((x, k) => V.target[k] + 0.6 * (x - V.target[k]));
      V.target = target;
      controls.target.set(...target);
      camera.position.set(...target.map((x, k) => x + (off[k] / n) * dist));
      controls.update();
      V.requestRender();
    };

    /* pixels of the canvas that differ from the background (the self-test) */
    V.drawnPixels = () => {
      V.render();
      const gl = renderer.getContext(), w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
      const px = new Uint8Array(w * h * 4);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
      let n = 0;
      for (let i = 0; i < px.length; i += 4) {
        if (Math.abs(px[i] - MAP_BG[0]) + Math.abs(px[i + 1] - MAP_BG[1]) + Math.abs(px[i + 2] - MAP_BG[2]) > 6) n++;
      }
      return n;
    };
    return V;
  }

  /* ---- 2D drawings -------------------------------------------------------------------------- */
  function fitCanvas(cv) {
    const dpr = window.devicePixelRatio || 1, W = cv.clientWidth, H = cv.clientHeight;
    const w = Math.max(1, Math.round(W * dpr)), h = Math.max(1, Math.round(H * dpr));
    if (cv.width !== w || cv.height !== h) { cv.width = w; cv.height = h; }
    const ctx = cv.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    return { ctx, W, H, dpr };
  }

  /* the camera's row: the row whose centre is nearest the scope */
  function scopeRow() {
    const pose = S.snap && S.snap.pose;
    if (!pose || !S.rows.size) return null;
    let best = null, bestD = Infinity;
    for (const row of S.rows.values()) {
      const d = Math.hypot(row.centre[0] - pose[3], row.centre[1] - pose[7], row.centre[2] - pose[11]);
      if (d < bestD) { bestD = d; best = row; }
    }
    return best;
  }

  let unrolledPlot = null, offscreen = null;
  function drawUnrolled() {
    const cv = $("unrolled"), { ctx, W, H, dpr } = fitCanvas(cv);
    ctx.fillStyle = "#181c22";
    ctx.fillRect(0, 0, W, H);
    const snap = S.snap;
    const ws = (snap && snap.wall_settings) || {}, cl = ws.cell_length_m || 0.005, segM = ws.segment_m || 0.05;
    const threshold = ws.threshold === undefined ? 1 : ws.threshold;
    const L = { x0: 52, x1: W - 10, y0: 20, y1: H - 20 };
    unrolledPlot = { x: L.x0 * dpr, y: L.y0 * dpr, w: (L.x1 - L.x0) * dpr, h: (L.y1 - L.y0) * dpr };
    ctx.fillStyle = rgbCss(PLOT_BG);
    ctx.fillRect(L.x0, L.y0, L.x1 - L.x0, L.y1 - L.y0);
    let maxI = -1, A = ws.angle_bins || 0;
    for (const row of S.rows.values()) { maxI = Math.max(maxI, row.i); A = row.A; }
    let sMax = Math.max((maxI + 1) * cl, 4 * segM);
    for (const seg of S.segments) sMax = Math.max(sMax, seg.end_m);
    const x = (s) => L.x0 + (s / sMax) * (L.x1 - L.x0);
    if (maxI >= 0 && A > 0) {
      offscreen = offscreen || document.createElement("canvas");
      offscreen.width = maxI + 1; offscreen.height = A;
      const octx = offscreen.getContext("2d"), img = octx.createImageData(maxI + 1, A);
      for (const row of S.rows.values()) {
        for (let j = 0; j < A; j++) {
          const c = isNaN(row.radius[j]) ? UNKNOWN : cellColour(row, j, false), o = 4 * (j * (maxI + 1) + row.i);
          img.data[o] = c[0]; img.data[o + 1] = c[1]; img.data[o + 2] = c[2]; img.data[o + 3] = 255;
        }
      }
      octx.putImageData(img, 0, 0);
      ctx.imageSmoothingEnabled = false;
      ctx.drawImage(offscreen, 0, 0, maxI + 1, A, x(0), L.y0, x((maxI + 1) * cl) - x(0), L.y1 - L.y0);
    } else {
      ctx.fillStyle = "#98a2ae"; ctx.font = "14px system-ui, sans-serif"; ctx.textAlign = "center";
      ctx.fillText("no wall yet", (L.x0 + L.x1) / 2, (L.y0 + L.y1) / 2);
    }
    ctx.font = "12px system-ui, sans-serif";
    /* segments: boundaries, labels, the current one framed */
    ctx.strokeStyle = "rgba(220,228,236,0.55)"; ctx.lineWidth = 1; ctx.setLineDash([4, 3]);
    ctx.fillStyle = "#98a2ae"; ctx.textAlign = "center"; ctx.textBaseline = "top";
    const segPx = x(segM) - x(0), every = Math.max(1, Math.ceil(34 / Math.max(segPx, 1))); /* labels >= 34 px apart */
    for (let k = 0; k * segM <= sMax + 1e-9; k++) {
      const xs = Math.round(x(k * segM)) + 0.5;
      ctx.beginPath(); ctx.moveTo(xs, L.y0); ctx.lineTo(xs, L.y1); ctx.stroke();
      if (k % every === 0) ctx.fillText(fmtCm(k * segM), Math.min(xs, W - 12), L.y1 + 4);
    }
    ctx.setLineDash([]);
    ctx.textBaseline = "bottom"; ctx.textAlign = "center"; ctx.font = "bold 12px system-ui, sans-serif";
    for (const seg of S.segments) {
      const xm = (x(seg.start_m) + x(seg.end_m)) / 2, over = seg.unseen_share > threshold;
      const width = x(seg.end_m) - x(seg.start_m);
      ctx.fillStyle = over ? "#ff6f98" : "#c9d1da";
      if (width >= 78) ctx.fillText(`${pct(seg.unseen_share)} % unseen`, xm, L.y0 - 3);
      else if (width >= 26 || over) ctx.fillText(`${pct(seg.unseen_share)}%`, xm, L.y0 - 3);
      if (seg.state === "current") {
        ctx.strokeStyle = "#4fd1c5"; ctx.lineWidth = 2;
        ctx.strokeRect(x(seg.start_m) + 1, L.y0 + 1, x(seg.end_m) - x(seg.start_m) - 2, L.y1 - L.y0 - 2);
      }
    }
    /* angle axis */
    ctx.font = "11px system-ui, sans-serif"; ctx.fillStyle = "#98a2ae"; ctx.textAlign = "right"; ctx.textBaseline = "middle";
    for (const deg of [-180, -90, 0, 90, 180]) ctx.fillText(`${deg}\u00b0`, L.x0 - 6, L.y0 + ((deg + 180) / 360) * (L.y1 - L.y0));
    /* the scope's position along the wall */
    const row = scopeRow();
    if (row) {
      const xs = x((row.i + 0.5) * cl);
      ctx.strokeStyle = "#ffd84d"; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.moveTo(xs, L.y0); ctx.lineTo(xs, L.y1); ctx.stroke();
      ctx.fillStyle = "#ffd84d";
      ctx.beginPath(); ctx.moveTo(xs - 6, L.y1 + 1); ctx.lineTo(xs + 6, L.y1 + 1); ctx.lineTo(xs, L.y1 - 9); ctx.fill();
    }
    $("unrolled-note").textContent = maxI >= 0
      ? `s along the centreline (cm) \u2192, angle around it \u2193 \u00b7 scope at ${row ? fmtCm((row.i + 0.5) * cl) + " cm" : "-"}`
      : "";
  }

  function unrolledDrawnPixels() {
    if (!unrolledPlot) return 0;
    const ctx = $("unrolled").getContext("2d"), p = unrolledPlot;
    const px = ctx.getImageData(Math.round(p.x), Math.round(p.y), Math.max(1, Math.round(p.w)), Math.max(1, Math.round(p.h))).data;
    let n = 0;
    for (let i = 0; i < px.length; i += 4) {
      if (Math.abs(px[i] - PLOT_BG[0]) + Math.abs(px[i + 1] - PLOT_BG[1]) + Math.abs(px[i + 2] - PLOT_BG[2]) > 6) n++;
    }
    return n;
  }

  function drawTimeline() {
    const { ctx, W, H } = fitCanvas($("timeline"));
    ctx.fillStyle = rgbCss(PLOT_BG);
    ctx.fillRect(0, 0, W, H);
    const last = S.snap && S.snap.latest_index !== null && S.snap.latest_index !== undefined ? S.snap.latest_index : -1;
    const n = Math.max(100, last + 1), x = (i) => (i / n) * W;
    for (const pass of [true, false]) { /* the rare kinds on top of the common ones */
      for (const [first, lastIndex, kind] of S.timeline) {
        if (BACKGROUND_KINDS.has(kind) !== pass) continue;
        ctx.fillStyle = kindColour(kind);
        ctx.fillRect(x(first), 0, Math.max(pass ? 0.5 : 1.5, x(lastIndex + 1) - x(first)), H);
      }
    }
    const counts = new Map();
    for (const [first, lastIndex, kind] of S.timeline) {
      const label = kindLabel(kind);
      counts.set(label, (counts.get(label) || 0) + lastIndex - first + 1);
    }
    const legend = [];
    const labels = [...new Set(Object.values(KIND_STYLE).map((s) => s[0]))];
    for (const k of S.timeline) if (!labels.includes(kindLabel(k[2]))) labels.push(kindLabel(k[2]));
    for (const label of labels) {
      const kind = Object.keys(KIND_STYLE).find((k) => KIND_STYLE[k][0] === label) || label;
      legend.push([kindColour(kind), label, counts.get(label) || 0]);
    }
    if (changed("legend", legend)) {
      const box = $("timeline-legend");
      box.textContent = "";
      for (const [colour, label, count] of legend) {
        const span = document.createElement("span"), sw = document.createElement("i"), b = document.createElement("b");
        sw.style.background = colour;
        b.textContent = count.toLocaleString("en-US");
        span.append(sw, document.createTextNode(label + " "), b);
        box.appendChild(span);
      }
    }
  }

  /* ---- panels ------------------------------------------------------------------------------- */
  function alertText(a) {
    let t = `Segment ${a.segment + 1} (${fmtCm(a.start_m)}-${fmtCm(a.end_m)} cm): ${pct(a.unseen_share)} % of the wall unseen`;
    const g = a.gap;
    if (g) {
      if (g.clock !== null && g.clock !== undefined) t += `, gap at ${g.clock} o'clock`;
      if (g.s_from_m !== null && g.s_from_m !== undefined && g.s_to_m !== null && g.s_to_m !== undefined) {
        t += `, ${Math.round(g.s_from_m * 100)}-${Math.round(g.s_to_m * 100)} cm`; /* whole cm, as the console's alert */
      }
    }
    return t;
  }
  function alertWhen(a) {
    const parts = [];
    if (a.frame !== null && a.frame !== undefined) parts.push(`frame ${a.frame}`);
    if (typeof a.time === "number") {
      parts.push(a.time > 1e8 ? new Date(a.time * 1000).toLocaleTimeString("en-GB") : `t ${a.time.toFixed(1)} s`);
    }
    if (a.gap && typeof a.gap.area_cm2 === "number") parts.push(`gap ${a.gap.area_cm2.toFixed(1)} cm\u00b2`);
    return parts.join(" \u00b7 ");
  }

  function drawAlerts() {
    if (!changed("alerts", S.alerts.map((a) => a.version))) return;
    const list = $("alerts");
    list.textContent = "";
    $("alert-count").textContent = S.alerts.length ? `(${S.alerts.length})` : "";
    if (!S.alerts.length) {
      $("banner").hidden = true;
      const li = document.createElement("li");
      li.className = "empty"; li.style.cssText = "border:0;background:none"; li.textContent = "none";
      list.appendChild(li);
      return;
    }
    for (const a of [...S.alerts].reverse()) {
      const li = document.createElement("li"), small = document.createElement("small");
      li.textContent = alertText(a);
      small.textContent = alertWhen(a);
      li.appendChild(small);
      list.appendChild(li);
    }
    const newest = S.alerts[S.alerts.length - 1];
    $("banner-text").textContent = alertText(newest);
    $("banner-when").textContent = alertWhen(newest);
    $("banner").hidden = false;
  }

  function drawSegments() {
    const ws = (S.snap && S.snap.wall_settings) || {};
    const threshold = ws.threshold === undefined ? 1 : ws.threshold;
    if (!changed("segments", [S.segments, threshold])) return;
    const box = $("segments");
    box.textContent = "";
    if (!S.segments.length) {
      const d = document.createElement("div");
      d.className = "empty"; d.textContent = "no segment yet";
      box.appendChild(d);
      return;
    }
    let current = null;
    for (const seg of S.segments) {
      const row = document.createElement("div"), label = document.createElement("span"), bar = document.createElement("div");
      const fill = document.createElement("div"), thr = document.createElement("div"), val = document.createElement("span");
      row.className = "seg" + (seg.state === "current" ? " current" : "") + (seg.unseen_share > threshold ? " over" : "");
      label.textContent = `${seg.index + 1} \u00b7 ${fmtCm(seg.start_m)}-${fmtCm(seg.end_m)} cm`;
      bar.className = "bar"; fill.className = "fill"; thr.className = "thr"; val.className = "val";
      fill.style.width = `${Math.max(0, Math.min(1, seg.unseen_share || 0)) * 100}%`;
      thr.style.left = `calc(${Math.max(0, Math.min(1, threshold)) * 100}% - 1px)`;
      thr.title = `alert threshold ${pct(threshold)} %`;
      val.textContent = `${pct(seg.unseen_share)} %`;
      bar.append(fill, thr);
      row.append(label, bar, val);
      box.appendChild(row);
      if (seg.state === "current") current = row;
    }
    if (current) current.scrollIntoView({ block: "nearest" });
  }

  function summaryText(summary) {
    if (!summary) return "";
    const parts = [];
    for (const [k, v] of Object.entries(summary)) {
      const key = k === "out" ? "run folder" : k.replace(/_/g, " ");
      if (typeof v === "number") parts.push(`${key} ${k.endsWith("share") ? pct(v) + " %" : Number(v.toPrecision(4))}`);
      else if (v !== null && typeof v !== "object") parts.push(`${key} ${v}`);
    }
    return parts.join(" \u00b7 ");
  }

  function drawHeader() {
    const snap = S.snap, src = snap.source || {}, cam = snap.camera || {};
    const srcText = [src.name, src.kind, src.rate_fps ? `${fmtFps(src.rate_fps)} fps` : null,
      cam.width ? `${cam.width}\u00d7${cam.height}` : null].filter(Boolean).join(" \u00b7 ");
    $("source").textContent = srcText;
    $("source").title = srcText;
    const status = $("status");
    status.className = "badge " + snap.status;
    status.textContent = snap.status;
    const notice = $("notice");
    if (snap.status === "running") notice.hidden = true;
    else {
      notice.hidden = false;
      notice.className = "notice " + (snap.status === "finished" ? "finished" : "error");
      const s = summaryText(snap.summary);
      notice.textContent = snap.status === "finished" ? `Finished${s ? " \u00b7 " + s : ""}`
        : snap.status === "error" ? `Error: ${snap.error || "the run failed"}${s ? " \u00b7 " + s : ""}`
          : `Interrupted${snap.error ? ": " + snap.error : ""}${s ? " \u00b7 " + s : ""}`;
    }
    const reset = $("reset-notice");
    reset.hidden = !(snap.wall && snap.wall.epoch > 0);
    if (!reset.hidden) {
      reset.textContent = `Map restarted${snap.wall.epoch > 1 ? ` (${snap.wall.epoch} times)` : ""}: ${snap.wall.reason || "tracking lost"}. ` +
        "The page shows this map part's wall and map (an earlier part's come back if the scope rejoins it).";
    }
    const r = snap.rates, d = r.delays, pub = d.capture_to_publish_ms, disp = d.capture_to_display_ms;
    const el = $("rates");
    el.textContent = "";
    const add = (label, value) => {
      const b = document.createElement("b");
      b.textContent = value;
      el.append(document.createTextNode(label), b);
    };
    add("source ", `${fmtFps(r.source_fps)} fps`);
    add(" \u00b7 processed ", `${fmtFps(r.processed_fps)} fps`);
    add(" \u00b7 taken ", r.taken.toLocaleString("en-US"));
    add(" \u00b7 dropped ", `${r.dropped.toLocaleString("en-US")} (${pct(r.dropped_share)} %)`);
    add(" \u00b7 capture\u2192publish ", `${fmtMs(pub.median)} / ${fmtMs(pub.p95)} ms`);
    add(" \u00b7 capture\u2192display ", `${fmtMs(disp.median)} / ${fmtMs(disp.p95)} ms`);
    el.append(document.createTextNode(" (median / p95)"));
  }

  function drawCaption() {
    const f = S.snap && S.snap.frame, cap = $("frame-caption");
    cap.textContent = "";
    if (!f || S.frameIndex === null) return;
    const add = (label, value) => {
      const span = document.createElement("span"), b = document.createElement("b");
      b.textContent = value;
      span.append(document.createTextNode(label), b);
      cap.appendChild(span);
    };
    add("frame ", String(S.frameIndex));
    const kind = S.frameDecision || f.decision;
    add("", kindLabel(kind) === kind ? kind : `${kindLabel(kind)} (${kind})`);
    // a negative delay means this page's clock is not the server's (another machine, or a test browser's virtual time)
    if (S.shownDelay !== null && S.shownDelay >= 0) add("shown ", `${Math.round(S.shownDelay)} ms after capture`);
    if (S.snap.pose_index !== null && S.snap.latest_index !== null && S.snap.pose_index !== S.snap.latest_index) {
      add("scope placed at frame ", String(S.snap.pose_index));
    }
  }

  /* ---- the frame ---------------------------------------------------------------------------- */
  function showImage(img, url) {
    return new Promise((resolve, reject) => {
      img.onload = () => resolve();
      img.onerror = () => reject(new Error("the frame did not decode"));
      img.src = url;
    });
  }

  async function loadFrame() {
    if (S.frameBusy) return;
    S.frameBusy = true;
    try {
      while (S.wantFrame > S.loadedFrame) {
        const want = S.wantFrame;
        const r = await fetch(`/frame.jpg?v=${want}`, { cache: "no-store" });
        if (!r.ok) break; /* no frame yet (404): the next snapshot asks again */
        const version = Number(r.headers.get("X-Frame-Version")), index = Number(r.headers.get("X-Frame-Index"));
        const captured = Number(r.headers.get("X-Captured-At")), decision = r.headers.get("X-Frame-Decision");
        const url = URL.createObjectURL(await r.blob());
        const img = $("frame");
        await showImage(img, url);
        if (S.frameUrl) URL.revokeObjectURL(S.frameUrl);
        S.frameUrl = url;
        img.hidden = false;
        $("frame-waiting").hidden = true;
        S.loadedFrame = Math.max(version, want);
        S.frameLoaded = true;
        S.frameIndex = index;
        S.frameDecision = decision;
        S.shownDelay = Date.now() - captured * 1000;
        fetch("/shown", { method: "POST", headers: { "Content-Type": "application/json" },
          body: JSON.stringify({ index, delay_ms: S.shownDelay }) }).catch(() => {});
        drawCaption();
        maybeSelftest();
      }
    } catch (e) {
      setTimeout(loadFrame, 500); /* a failed load is retried */
    } finally {
      S.frameBusy = false;
    }
  }

  /* ---- polling ------------------------------------------------------------------------------ */
  function clearAll() {
    S.rows.clear(); S.rowsAll = true; S.path = []; S.timeline = []; S.segments = []; S.alerts = [];
    S.loadedFrame = -1; S.keys = {};
    if (view) view.clear();
  }

  function apply(snap) {
    if (snap.full) clearAll();
    const have = { path: S.path.length, map: view ? view.pointsN : 0, timeline: S.timeline.length };
    if (snap.path.start > have.path || (view && snap.map.start > have.map) || snap.timeline.start > have.timeline) {
      S.version = 0; /* out of step (should not happen): the next poll asks for everything */
      return;
    }
    S.version = snap.version;
    S.snap = snap;
    if (snap.wall.reset) { S.rows.clear(); S.rowsAll = true; }
    for (const r of snap.wall.rows) { S.rows.set(r.i, decodeRow(r)); S.rowsChanged.add(r.i); }
    const pathChanged = snap.path.points.length > 0 || snap.path.start < S.path.length;
    S.path.length = snap.path.start;
    for (const p of snap.path.points) S.path.push(p);
    S.timeline.length = snap.timeline.start;
    for (const e of snap.timeline.entries) S.timeline.push(e);
    S.segments = snap.segments;
    S.alerts = snap.alerts;
    if (view) {
      if (snap.map.start < view.pointsN || snap.map.xyz) {
        view.setPoints(snap.map.start, new Float32Array(decodeB64(snap.map.xyz).buffer), decodeB64(snap.map.rgb));
      }
      if (pathChanged) view.setPath(S.path);
      if (S.rowsAll || S.rowsChanged.size) view.setWall(S.rows, S.rowsAll ? null : S.rowsChanged);
      view.setPose(snap.pose, snap.camera);
      view.updateFollow();
    }
    S.rowsAll = false;
    S.rowsChanged = new Set();
    if (snap.frame && snap.frame.version > S.loadedFrame) {
      S.wantFrame = snap.frame.version;
      loadFrame();
    }
    drawHeader();
    drawAlerts();
    drawSegments();
    drawUnrolled();
    drawTimeline();
    drawCaption();
  }

  function setConnected(ok) {
    if (ok === S.connected) return;
    S.connected = ok;
    $("connection").hidden = ok;
  }

  async function poll() {
    let wait = POLL_MS;
    let snap = null;
    try {
      const r = await fetch(`/state.json?since=${S.version}`, { cache: "no-store" });
      if (!r.ok) throw new Error(`HTTP ${r.status}`);
      snap = await r.json();
      setConnected(true);
    } catch (e) {
      setConnected(false);
      wait = RETRY_MS;
    }
    if (snap) {
      try {
        apply(snap);
      } catch (e) {
        errors.push("apply: " + (e && e.stack ? e.stack : e));
      }
      if (snap.status !== "running") wait = IDLE_POLL_MS;
      maybeSelftest();
    }
    setTimeout(poll, wait);
  }

  /* ---- self-test ---------------------------------------------------------------------------- */
  const started = performance.now();
  let selftestDone = false;
  function maybeSelftest() {
    if (!SELFTEST || selftestDone) return;
    const ready = S.frameLoaded && S.rows.size > 0 && S.alerts.length > 0;
    if (!ready && performance.now() - started < SELFTEST_TIMEOUT_MS) return;
    selftestDone = true;
    setTimeout(writeSelftest, 300);
  }
  function writeSelftest() {
    let out;
    try {
      drawUnrolled();
      out = {
        frame_loaded: S.frameLoaded, frame_index: S.frameIndex, map_points: view ? view.pointsN : 0,
        wall_rows: S.rows.size, canvas_nonbackground_pixels: view ? view.drawnPixels() : 0,
        unrolled_nonbackground_pixels: unrolledDrawnPixels(), alerts: S.alerts.length,
        alert_text: $("banner").hidden ? "" : $("banner-text").textContent, timeline_entries: S.timeline.length,
        errors,
      };
    } catch (e) {
      out = { failed: String(e), errors };
    }
    const pre = document.createElement("pre");
    pre.id = "live-selftest";
    pre.textContent = JSON.stringify(out);
    document.body.appendChild(pre);
  }

  /* ---- start -------------------------------------------------------------------------------- */
  let view = null;
  function start() {
    try { view = makeView($("map")); } catch (e) { errors.push("3D view: " + e); }
    $("follow").addEventListener("click", () => { if (view) view.setFollow(!view.follow); });
    $("cut").addEventListener("change", (e) => { if (view) { view.cut = e.target.checked; view.render(); } });
    new ResizeObserver(() => { if (S.snap) { drawUnrolled(); drawTimeline(); } }).observe($("unrolled-panel"));
    if (SELFTEST) setTimeout(maybeSelftest, SELFTEST_TIMEOUT_MS + 10);
    poll();
  }
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start); else start();
})();
