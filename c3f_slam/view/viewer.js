/* C3Fusion 3D view (c3f_slam/view): draws a run's layers with three.js (the global THREE,
   vendor/three.view.min.js) in every element of class "c3f-view", reading the JSON in the
   <script type="application/json"> named by its data-source attribute. Orbit: left drag; pan:
   right drag (or shift + left drag); zoom: wheel. Units: metres in the data, cm on the page.
   With "#selftest" in the page's address it switches each layer off and on, reads the canvas
   pixels and writes the result as JSON into a <pre> element with id c3f-selftest (tests/test_view.py);
   "#show=surface,unseen,cut" shows those layers only (and cuts the near half away). */
(function () {
  "use strict";
  const errors = [];
  const origError = console.error;
  console.error = function (...args) { errors.push(args.map(String).join(" ")); origError.apply(console, args); };
  window.addEventListener("error", (e) => errors.push(String(e.message || e)));
  const BACKGROUND = [0x1d, 0x21, 0x27];
  const SRGB_TO_LINEAR = new Float32Array(256).map((_, i) => {
    const c = i / 255;
    return c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4);
  });

  function decode(b64, Type) {
    const bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Type(bytes.buffer);
  }

  function buildLayer(L, centre) {
    const p = decode(L.positions, Float32Array);
    for (let i = 0; i < p.length; i += 3) { p[i] -= centre[0]; p[i + 1] -= centre[1]; p[i + 2] -= centre[2]; }
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(p, 3));
    if (L.kind === "mesh") {
      g.setIndex(new THREE.BufferAttribute(decode(L.indices, Uint32Array), 1));
      const c8 = decode(L.colours, Uint8Array);
      g.setAttribute("color", new THREE.BufferAttribute(c8.length ? Float32Array.from(c8, (v) => SRGB_TO_LINEAR[v]) : new Float32Array(p.length).fill(0.5), 3));
      g.computeVertexNormals();
      const m = new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide,
        polygonOffset: L.id === "unseen", polygonOffsetFactor: -2, polygonOffsetUnits: -2 });
      return new THREE.Mesh(g, m);
    }
    const colour = new THREE.Color(L.colour);
    let obj;
    if (L.kind === "points") obj = new THREE.Points(g, new THREE.PointsMaterial({ color: colour, size: 6, sizeAttenuation: false, depthTest: false }));
    else if (L.kind === "segments") obj = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: colour, depthTest: false }));
    else obj = new THREE.Line(g, new THREE.LineBasicMaterial({ color: colour, depthTest: false }));
    obj.renderOrder = 10; // paths and cameras stay visible inside the tube
    return obj;
  }

  function bounds(data) {
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (const L of data.layers) {
      const p = decode(L.positions, Float32Array);
      for (let i = 0; i < p.length; i++) { const k = i % 3; if (p[i] < lo[k]) lo[k] = p[i]; if (p[i] > hi[k]) hi[k] = p[i]; }
    }
    if (!isFinite(lo[0])) return { centre: [0, 0, 0], radius: 0.1 };
    const centre = data.centre || lo.map((v, k) => (v + hi[k]) / 2);
    return { centre, radius: Math.max(1e-3, Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2) };
  }

  function panel(root, data, view) {
    const box = document.createElement("div");
    box.className = "c3f-panel";
    const title = document.createElement("b");
    title.textContent = "Layers";
    box.appendChild(title);
    for (const L of data.layers) {
      const row = document.createElement("label");
      row.title = L.note;
      const cb = document.createElement("input");
      cb.type = "checkbox"; cb.checked = L.visible; cb.dataset.layer = L.id;
      cb.addEventListener("change", () => { view.objects[L.id].visible = cb.checked; view.render(); });
      const swatch = document.createElement("span");
      swatch.className = "c3f-swatch";
      swatch.style.background = L.kind === "mesh" ? (L.id === "unseen" ? "#0d8cff" : L.id === "gt_surface" ? "#3c3" : "#c8665a") : L.colour;
      row.append(cb, swatch, document.createTextNode(" " + L.label));
      box.appendChild(row);
    }
    const cut = document.createElement("label");
    const cb = document.createElement("input");
    cb.type = "checkbox"; cb.dataset.control = "cut"; cb.checked = view.cut;
    cb.addEventListener("change", () => { view.cut = cb.checked; view.render(); });
    cut.append(cb, document.createTextNode(" cut away the near half"));
    const reset = document.createElement("button");
    reset.textContent = "reset view";
    reset.addEventListener("click", () => view.reset());
    const help = document.createElement("div");
    help.className = "c3f-help";
    help.textContent = "drag: orbit, right drag: pan, wheel: zoom. " + (data.caption || "");
    box.append(document.createElement("hr"), cut, reset, help);
    root.appendChild(box);
    return box;
  }

  function mount(root) {
    const data = JSON.parse(document.getElementById(root.dataset.source).textContent);
    const show = location.hash.startsWith("#show=") ? location.hash.slice(6).split(",") : null;
    if (show) for (const L of data.layers) L.visible = show.includes(L.id); // e.g. view.html#show=surface,unseen,cut
    const { centre, radius } = bounds(data);
    const canvasBox = document.createElement("div");
    canvasBox.className = "c3f-canvas";
    root.appendChild(canvasBox);
    const width = canvasBox.clientWidth || 800, height = canvasBox.clientHeight || 520;
    const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    renderer.setPixelRatio(1);
    renderer.setSize(width, height);
    renderer.setClearColor(new THREE.Color(`rgb(${BACKGROUND.join(",")})`), 1);
    canvasBox.appendChild(renderer.domElement);
    const scene = new THREE.Scene();
    const camera = new THREE.PerspectiveCamera(45, width / height, radius / 1000, radius * 100);
    scene.add(new THREE.AmbientLight(0xffffff, 1.2));
    const head = new THREE.DirectionalLight(0xffffff, 2.0);
    camera.add(head);
    scene.add(camera);
    const controls = new THREE.OrbitControls(camera, renderer.domElement);
    const plane = new THREE.Plane();
    const view = { objects: {}, cut: Boolean(show && show.includes("cut")), renderer, camera, controls };
    for (const L of data.layers) {
      const obj = buildLayer(L, centre);
      obj.visible = L.visible;
      view.objects[L.id] = obj;
      scene.add(obj);
    }
    view.render = () => {
      const dir = new THREE.Vector3().subVectors(controls.target, camera.position).normalize();
      plane.setFromNormalAndCoplanarPoint(dir, controls.target);
      renderer.clippingPlanes = view.cut ? [plane] : [];
      renderer.render(scene, camera);
    };
    view.reset = () => {
      const v = data.view_direction || [0.3, -0.5, -1];
      const n = Math.hypot(v[0], v[1], v[2]);
      const half = Math.tan((camera.fov * Math.PI) / 360);
      const e = data.view_extent || [radius, radius, radius];
      const d = Math.max(e[0] / (half * camera.aspect), e[1] / half) * 1.2 + e[2];
      camera.position.set(v[0] / n * d, v[1] / n * d, v[2] / n * d);
      camera.up.set(...(data.view_up || [0, -1, 0]));
      controls.target.set(0, 0, 0);
      controls.update();
      view.render();
    };
    controls.addEventListener("change", view.render);
    new ResizeObserver(() => {
      const w = canvasBox.clientWidth, h = canvasBox.clientHeight;
      if (w && h && (w !== renderer.domElement.width || h !== renderer.domElement.height)) {
        renderer.setSize(w, h); camera.aspect = w / h; camera.updateProjectionMatrix(); view.render();
      }
    }).observe(canvasBox);
    view.panel = panel(root, data, view);
    view.reset();
    return view;
  }

  function pixels(view) {
    view.render();
    const gl = view.renderer.getContext();
    const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    const px = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    return px;
  }

  function differ(a, b) {
    let n = 0;
    for (let i = 0; i < a.length; i += 4) if (a[i] !== b[i] || a[i + 1] !== b[i + 1] || a[i + 2] !== b[i + 2]) n++;
    return n;
  }

  function drawn(px) {
    let n = 0;
    for (let i = 0; i < px.length; i += 4) {
      if (Math.abs(px[i] - BACKGROUND[0]) + Math.abs(px[i + 1] - BACKGROUND[1]) + Math.abs(px[i + 2] - BACKGROUND[2]) > 6) n++;
    }
    return n;
  }

  function selftestView(view) {
    const before = pixels(view);
    const res = { pixels: before.length / 4, drawn: drawn(before), layers: {} };
    for (const cb of view.panel.querySelectorAll("input[data-layer], input[data-control]")) {
      cb.click();
      const toggled = pixels(view);
      cb.click();
      const back = pixels(view);
      res.layers[cb.dataset.layer || cb.dataset.control] = { changed: differ(before, toggled), restored: differ(before, back) === 0 };
    }
    return res;
  }

  function videoState(video) {
    return new Promise((resolve) => {
      const done = () => resolve({ src: video.dataset.name || "", width: video.videoWidth, height: video.videoHeight,
        duration: video.duration, error: video.error ? video.error.code : null });
      if (video.readyState >= 2 || video.error) return done();
      video.addEventListener("loadeddata", done, { once: true });
      video.addEventListener("error", done, { once: true });
      setTimeout(done, 4000);
    });
  }

  async function selftest(views) {
    const out = { views: views.map(selftestView), errors };
    out.videos = await Promise.all([...document.querySelectorAll("video")].map(videoState));
    const pre = document.createElement("pre");
    pre.id = "c3f-selftest";
    pre.textContent = JSON.stringify(out);
    document.body.appendChild(pre);
  }

  function start() {
    const views = [];
    for (const root of document.querySelectorAll(".c3f-view")) {
      try { views.push(mount(root)); } catch (e) { errors.push("mount: " + e); root.textContent = "The 3D view could not start: " + e; }
    }
    if (location.hash === "#selftest") {
      setTimeout(() => selftest(views).catch((e) => {
        const pre = document.createElement("pre");
        pre.id = "c3f-selftest";
        pre.textContent = JSON.stringify({ failed: String(e), errors });
        document.body.appendChild(pre);
      }), 50);
    }
  }
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start); else start();
})();
