// bvae studio front-end: slider editor and UMAP manifold explorer.
//
// All edit state lives in this tab (window.studio.editor.state); every request
// carries the full state, so tabs never share or corrupt each other's edits.
// Each preview keeps at most one decode request in flight and, when it
// returns, sends only the newest state: dragging never queues stale frames.
// Instrumentation for tests and the latency benchmark: every painted frame
// increments preview.paintCount (also canvas.dataset.paints) and dispatches a
// "studio-paint" event; preview.latencies holds input-to-paint times in ms.
"use strict";

const $ = (id) => document.getElementById(id);

function setStatus(text, isError = false) {
  const status = $("status");
  status.textContent = text;
  status.classList.toggle("error", isError);
}

async function api(path, body) {
  const options = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  };
  const response = await fetch(path, options);
  if (!response.ok) {
    let message = `${response.status} ${response.statusText}`;
    try { message = (await response.json()).error || message; } catch (_) { /* not JSON */ }
    const error = new Error(message);
    error.status = response.status;
    throw error;
  }
  return response;
}

function median(values) {
  if (!values.length) return NaN;
  const sorted = [...values].sort((a, b) => a - b);
  const mid = sorted.length >> 1;
  return sorted.length % 2 ? sorted[mid] : (sorted[mid - 1] + sorted[mid]) / 2;
}

// ---------------------------------------------------------------- a live preview

class Preview {
  constructor(name, canvas, stats, mask) {
    this.name = name;
    this.canvas = canvas;
    this.stats = stats;
    this.mask = mask;
    this.context = canvas.getContext("2d");
    this.imageData = this.context.createImageData(canvas.width, canvas.height);
    this.light = [-1, 1, 1];
    this.geometry = BvaeRender.sphereGeometry(canvas.width, this.light, mask);
    this.lighting = "directional";
    this.exposure = null;          // set from the first image (auto), then kept
    this.exposureScale = 1;        // the exposure slider, 2^EV
    this.slices = null;            // decoded kept slices of the shown state
    this.linear = null;            // last linear image
    this.shownState = null;
    this.inflight = false;
    this.pending = null;
    this.pendingSince = null;
    this.paintCount = 0;
    this.requestCount = 0;
    this.latencies = [];
    this.decodeMs = [];
    this.lightFrame = null;
    this.installLightDrag();
  }

  // Ask for a new state; t0 is the input event's time stamp (performance.now() clock).
  request(state, t0 = performance.now()) {
    // base: a layered material's edits keep its layers (the server adds them to the edited base).
    this.pending = { base: state.base, z: [...state.z], graft: state.graft ? [...state.graft] : null };
    if (this.pendingSince === null) this.pendingSince = t0;  // the oldest input not shown yet
    if (!this.inflight) this.flush();
  }

  async flush() {
    const state = this.pending, t0 = this.pendingSince;
    this.pending = null; this.pendingSince = null;
    this.inflight = true;
    this.requestCount++;
    try {
      const response = await api("/api/decode", state);
      this.decodeMs.push(Number(response.headers.get("X-Decode-Ms")));
      this.slices = new Uint16Array(await response.arrayBuffer());
      this.shownState = state;
      if (this.lighting === "directional") this.paintDirectional(t0);
      else await this.paintEnvironment(state, t0);
    } catch (error) {
      setStatus(`${this.name}: ${error.message}`, true);
    } finally {
      this.inflight = false;
      if (this.pending) this.flush();
    }
  }

  paintDirectional(t0) {
    if (!this.slices) return;
    this.linear = BvaeRender.renderSphere(this.geometry, this.slices, this.linear);
    if (this.exposure === null) this.exposure = BvaeRender.autoExposure(this.linear);
    BvaeRender.encode(this.linear, this.exposure * this.exposureScale, this.imageData, this.geometry.inside);
    this.context.putImageData(this.imageData, 0, 0);
    this.markPainted(t0);
  }

  async paintEnvironment(state, t0) {
    if (this.exposure === null) {  // the exposure of the directional view, so both look alike
      this.linear = BvaeRender.renderSphere(this.geometry, this.slices, this.linear);
      this.exposure = BvaeRender.autoExposure(this.linear);
    }
    const response = await api("/api/render-environment",
      { ...state, env: this.lighting, exposure: this.exposure * this.exposureScale });
    const bitmap = await createImageBitmap(await response.blob());
    this.context.imageSmoothingEnabled = true;
    this.context.clearRect(0, 0, this.canvas.width, this.canvas.height);
    this.context.drawImage(bitmap, 0, 0, this.canvas.width, this.canvas.height);
    this.markPainted(t0);
  }

  repaint() {
    if (this.lighting === "directional") this.paintDirectional(null);
    else if (this.shownState) this.request(this.shownState);
  }

  markPainted(t0) {
    // After the frame holding the new pixels is produced: rAF, then a task.
    requestAnimationFrame(() => setTimeout(() => {
      if (t0 !== null && t0 !== undefined) this.latencies.push(performance.now() - t0);
      this.paintCount++;
      this.canvas.dataset.paints = String(this.paintCount);
      if (this.stats && this.latencies.length) {
        const last = this.latencies[this.latencies.length - 1];
        this.stats.textContent = `input → painted: last ${last.toFixed(0)} ms, median ${median(this.latencies).toFixed(0)} ms` +
          ` (${this.latencies.length} frames, ${this.requestCount} decodes, server decode median ${median(this.decodeMs).toFixed(1)} ms)`;
      }
      window.dispatchEvent(new CustomEvent("studio-paint", { detail: { preview: this.name, count: this.paintCount } }));
    }, 0));
  }

  setLight(light) {
    this.light = light;
    if (this.lightFrame !== null) return;  // one geometry update per animation frame
    this.lightFrame = requestAnimationFrame(() => {
      this.lightFrame = null;
      this.geometry = BvaeRender.sphereGeometry(this.canvas.width, this.light, this.mask);
      if (this.lighting === "directional") this.paintDirectional(performance.now());
    });
  }

  installLightDrag() {
    const move = (event) => {
      if (this.lighting !== "directional") return;
      const rect = this.canvas.getBoundingClientRect();
      const x = ((event.clientX - rect.left) / rect.width) * 2 - 1;
      const y = -(((event.clientY - rect.top) / rect.height) * 2 - 1);
      const r2 = x * x + y * y;
      const light = r2 < 1 ? [x, y, Math.sqrt(1 - r2)] : [x / Math.sqrt(r2), y / Math.sqrt(r2), 0.05];
      this.setLight(light);
    };
    this.canvas.addEventListener("pointerdown", (event) => {
      this.canvas.setPointerCapture(event.pointerId);
      move(event);
    });
    this.canvas.addEventListener("pointermove", (event) => { if (event.buttons & 1) move(event); });
  }
}

// ---------------------------------------------------------------- the editor

class Editor {
  constructor(info, preview) {
    this.info = info;
    this.preview = preview;
    this.materials = new Map(info.materials.map((m) => [m.id, m]));
    this.range = info.slider_range;
    this.undoStack = [];
    this.state = null;
    this.committed = null;
    this.buildControls();
    this.select(info.materials[0].id, false);
  }

  snapshot() {
    const s = this.state;
    return { base: s.base, z: [...s.z], graft: s.graft ? [...s.graft] : null, edit: JSON.parse(JSON.stringify(s.edit)) };
  }

  pushUndo() {
    this.undoStack.push(this.committed || this.snapshot());
    if (this.undoStack.length > 200) this.undoStack.shift();
    $("undo").disabled = false;
  }

  commit() { this.committed = this.snapshot(); }

  buildControls() {
    const info = this.info;
    for (const select of [$("material"), $("material-b")]) {
      for (const m of info.materials) {
        const option = document.createElement("option");
        option.value = m.id;
        option.textContent = m.id;
        select.appendChild(option);
      }
    }
    $("material").addEventListener("change", (e) => this.select(e.target.value, true));
    $("sample").addEventListener("click", (e) => this.sample(e.timeStamp));
    $("reset").addEventListener("click", (e) => this.reset(e.timeStamp));
    $("undo").addEventListener("click", (e) => this.undo(e.timeStamp));

    const box = $("sliders");
    this.sliders = [];
    info.labels.forEach((label, d) => {
      const wrap = document.createElement("div");
      wrap.className = "slider";
      const isColour = info.colour_dims.includes(d) ? " (colour)" : "";
      wrap.innerHTML = `<label for="z${d}"><span>z${d + 1}: ${label}${isColour}</span><output id="z${d}-value"></output></label>` +
        `<div class="track"><input type="range" id="z${d}" min="${-this.range}" max="${this.range}" step="0.01">` +
        `<span class="mu" id="z${d}-mu">▲</span></div>`;
      box.appendChild(wrap);
      const input = wrap.querySelector("input");
      input.addEventListener("input", (e) => this.onSlider(d, Number(input.value), e.timeStamp));
      input.addEventListener("change", () => { this.pushUndo(); this.commit(); });
      this.sliders.push(input);
    });

    this.graftSliders = [];
    info.colour_dims.forEach((dim, k) => {
      const wrap = document.createElement("div");
      wrap.className = "slider";
      wrap.innerHTML = `<label for="g${k}"><span>graft ${k + 1}: z${dim + 1} of the code whose red becomes green</span>` +
        `<output id="g${k}-value"></output></label><div class="track"><input type="range" id="g${k}" ` +
        `min="${-this.range}" max="${this.range}" step="0.01" disabled></div>`;
      $("graft-sliders").appendChild(wrap);
      const input = wrap.querySelector("input");
      input.addEventListener("input", (e) => this.onGraftSlider(k, Number(input.value), e.timeStamp));
      input.addEventListener("change", () => { this.pushUndo(); this.commit(); });
      this.graftSliders.push(input);
    });
    $("graft").addEventListener("change", (e) => {
      this.pushUndo();
      this.state.graft = e.target.checked ? info.colour_dims.map((d) => this.state.z[d]) : null;
      this.state.edit.graft = e.target.checked;
      this.commit();
      this.sync();
      this.preview.request(this.state, e.timeStamp);
    });

    const toggles = $("factor-toggles");
    this.toggles = info.labels.map((_, d) => {
      const label = document.createElement("label");
      label.innerHTML = `<input type="checkbox" id="from-a-${d}"> z${d + 1} from A`;
      toggles.appendChild(label);
      const box = label.querySelector("input");
      box.addEventListener("change", (e) => this.onInterpolation(e.timeStamp, true));
      return box;
    });
    $("material-b").addEventListener("change", (e) => this.onInterpolation(e.timeStamp, true));
    $("interp-t").addEventListener("input", (e) => this.onInterpolation(e.timeStamp, false));
    $("interp-t").addEventListener("change", () => { this.pushUndo(); this.commit(); });

    for (const button of document.querySelectorAll("#save-box button")) {
      button.addEventListener("click", () => this.save(button.dataset.suffix, false));
    }
  }

  select(id, undoable) {
    if (undoable) this.pushUndo();
    const m = this.materials.get(id);
    this.state = { base: id, z: [...m.mu], graft: m.graft ? [...m.graft] : null, edit: { source: id } };
    this.preview.exposure = null;  // auto exposure for a new material
    $("material").value = id;
    $("save-name").value = `${m.name}-edit`;
    $("save-file").value = `${m.name.replace(/[^A-Za-z0-9._-]/g, "_")}-edit.bvae`;
    this.commit();
    this.sync();
    this.preview.request(this.state);
  }

  markChanged(d) {
    const changed = new Set(this.state.edit.changed || []);
    changed.add(d);
    this.state.edit.changed = [...changed].sort((a, b) => a - b);
  }

  onSlider(d, value, t0) {
    this.state.z[d] = value;
    this.markChanged(d);
    $(`z${d}-value`).textContent = value.toFixed(2);
    this.preview.request(this.state, t0);
  }

  onGraftSlider(k, value, t0) {
    this.state.graft[k] = value;
    $(`g${k}-value`).textContent = value.toFixed(2);
    this.preview.request(this.state, t0);
  }

  onInterpolation(t0, undoable) {
    const b = $("material-b").value;
    $("interp-t-value").textContent = Number($("interp-t").value).toFixed(2);
    if (!b) return;
    if (undoable) this.pushUndo();
    const a = this.materials.get(this.state.base), other = this.materials.get(b);
    const t = Number($("interp-t").value);
    const fromA = this.toggles.map((box, d) => (box.checked ? d : -1)).filter((d) => d >= 0);
    this.state.z = a.mu.map((va, d) => (fromA.includes(d) ? va : (1 - t) * va + t * other.mu[d]));
    this.state.edit = { ...this.state.edit, b, t, dims_from_a: fromA };
    if (undoable) this.commit();
    this.sync();
    this.preview.request(this.state, t0);
  }

  sample(t0) {
    this.pushUndo();
    const m = this.materials.get(this.state.base);
    const gauss = () => {  // Box-Muller
      const u = 1 - Math.random(), v = Math.random();
      return Math.sqrt(-2 * Math.log(u)) * Math.cos(2 * Math.PI * v);
    };
    this.state.z = m.mu.map((mu, d) => mu + m.sigma[d] * gauss());
    this.state.edit.sampled = true;
    this.commit();
    this.sync();
    this.preview.request(this.state, t0);
  }

  reset(t0) {
    this.pushUndo();
    const m = this.materials.get(this.state.base);
    this.state = { base: m.id, z: [...m.mu], graft: m.graft ? [...m.graft] : null, edit: { source: m.id } };
    $("material-b").value = "";
    $("interp-t").value = "0";
    this.toggles.forEach((box) => { box.checked = false; });
    this.commit();
    this.sync();
    this.preview.request(this.state, t0);
  }

  undo(t0) {
    const previous = this.undoStack.pop();
    $("undo").disabled = this.undoStack.length === 0;
    if (!previous) return;
    this.state = previous;
    this.commit();
    $("material").value = previous.base;
    this.sync();
    this.preview.request(this.state, t0);
  }

  setCode(z, t0, manifoldPoint) {
    this.pushUndo();
    this.state.z = [...z];
    this.state.edit = { source: this.state.base, manifold: manifoldPoint };
    this.commit();
    this.sync();
    this.preview.request(this.state, t0);
  }

  sync() {
    const m = this.materials.get(this.state.base);
    this.sliders.forEach((input, d) => {
      input.value = String(this.state.z[d]);
      $(`z${d}-value`).textContent = this.state.z[d].toFixed(2);
      const mu = Math.min(Math.max(m.mu[d], -this.range), this.range);
      $(`z${d}-mu`).style.left = `${((mu + this.range) / (2 * this.range)) * 100}%`;
    });
    $("graft").checked = this.state.graft !== null;
    this.graftSliders.forEach((input, k) => {
      input.disabled = this.state.graft === null;
      const value = this.state.graft ? this.state.graft[k] : this.state.z[this.info.colour_dims[k]];
      input.value = String(value);
      $(`g${k}-value`).textContent = value.toFixed(2);
    });
  }

  async save(suffix, overwrite) {
    const stem = $("save-file").value.replace(/\.(bvae|binary|png|exr)$/i, "");
    const file = stem + suffix;
    const body = {
      file, name: $("save-name").value, overwrite, base: this.state.base, z: this.state.z, graft: this.state.graft,
      edit: this.state.edit, light: this.preview.light,
      exposure: (this.preview.exposure || 1) * this.preview.exposureScale,
      env: this.preview.lighting === "directional" ? null : this.preview.lighting,
    };
    const status = $("save-status");
    try {
      const result = await (await api("/api/save", body)).json();
      status.textContent = `wrote ${result.saved} (${result.bytes} bytes) in ${result.folder}`;
      status.classList.remove("error");
    } catch (error) {
      if (error.status === 409 && !overwrite) {
        if (window.confirm(`${file} already exists in the save folder. Replace it?`)) return this.save(suffix, true);
        status.textContent = `not saved: ${file} exists`;
      } else {
        status.textContent = `not saved: ${error.message}`;
      }
      status.classList.add("error");
    }
    return null;
  }
}

// ---------------------------------------------------------------- the manifold explorer

class Explorer {
  constructor(info, preview, editor) {
    this.info = info;
    this.preview = preview;
    this.editor = editor;
    this.canvas = $("map");
    this.context = this.canvas.getContext("2d");
    this.map = null;
    this.cursor = null;
    this.code = null;
    this.samples = 7;
    this.canvas.addEventListener("pointerdown", (e) => {
      if (!this.map) return;
      this.canvas.setPointerCapture(e.pointerId);
      this.moveCursor(e);
    });
    this.canvas.addEventListener("pointermove", (e) => {
      if (!this.map) return;
      if (e.buttons & 1) this.moveCursor(e);
      else this.hover(e);
    });
    this.canvas.addEventListener("pointerleave", () => { $("map-tip").hidden = true; });
    $("to-editor").addEventListener("click", (e) => {
      if (this.code) this.editor.setCode(this.code, e.timeStamp, this.cursor);
    });
    this.load();
  }

  async load() {
    const started = performance.now();
    const progress = $("map-progress");
    for (;;) {
      let response;
      try {
        response = await api("/api/manifold");
      } catch (error) {
        progress.hidden = true;
        $("map-status").textContent = error.message;
        $("map-status").classList.add("error");
        return;
      }
      const body = await response.json();
      if (response.status === 200) { this.map = body; break; }
      // The first map of a library takes a while on a busy machine: say what runs and for how long so far.
      const seconds = Math.round((performance.now() - started) / 1000);
      progress.hidden = false;
      $("map-status").textContent = `computing the UMAP map of ${this.info.materials.length} materials ` +
        `(once per library, cached afterwards): ${seconds} s so far`;
      await new Promise((resolve) => setTimeout(resolve, 1000));  // poll until the background fit is done
    }
    progress.hidden = true;
    $("map-status").textContent = `${this.map.points.length} materials; the grey grid: ${this.samples}×${this.samples} ` +
      "samples of the paper's figure; hover a point for its thumbnail";
    const [x0, x1, y0, y1] = this.map.bounds;
    this.setCursor((x0 + x1) / 2, (y0 + y1) / 2, performance.now());
    window.dispatchEvent(new CustomEvent("studio-map-ready"));
  }

  toCanvas(x, y) {
    const [x0, x1, y0, y1] = this.map.bounds;
    return [((x - x0) / (x1 - x0)) * this.canvas.width, (1 - (y - y0) / (y1 - y0)) * this.canvas.height];
  }

  fromEvent(event) {
    const rect = this.canvas.getBoundingClientRect();
    const [x0, x1, y0, y1] = this.map.bounds;
    const u = Math.min(Math.max((event.clientX - rect.left) / rect.width, 0), 1);
    const v = Math.min(Math.max((event.clientY - rect.top) / rect.height, 0), 1);
    return [x0 + u * (x1 - x0), y0 + (1 - v) * (y1 - y0)];
  }

  // Bilinear interpolation of the tabulated inverse transform (manifold.latent_at).
  latentAt(x, y) {
    const [x0, x1, y0, y1] = this.map.bounds;
    const g = this.map.grid_size, dim = this.info.latent_dim, grid = this.map.grid;
    const u = Math.min(Math.max((x - x0) / (x1 - x0), 0), 1) * (g - 1);
    const v = Math.min(Math.max((y - y0) / (y1 - y0), 0), 1) * (g - 1);
    const i = Math.min(Math.floor(u), g - 2), j = Math.min(Math.floor(v), g - 2);
    const fu = u - i, fv = v - j;
    const at = (jj, ii, d) => grid[(jj * g + ii) * dim + d];
    const z = [];
    for (let d = 0; d < dim; d++) {
      const top = at(j, i, d) * (1 - fu) + at(j, i + 1, d) * fu;
      const bottom = at(j + 1, i, d) * (1 - fu) + at(j + 1, i + 1, d) * fu;
      z.push(top * (1 - fv) + bottom * fv);
    }
    return z;
  }

  moveCursor(event) {
    const [x, y] = this.fromEvent(event);
    this.setCursor(x, y, event.timeStamp);
  }

  setCursor(x, y, t0) {
    this.cursor = [x, y];
    this.code = this.latentAt(x, y);
    $("to-editor").disabled = false;
    this.draw();
    this.preview.request({ z: this.code, graft: null }, t0);
  }

  nearest(event) {
    const rect = this.canvas.getBoundingClientRect();
    const px = ((event.clientX - rect.left) / rect.width) * this.canvas.width;
    const py = ((event.clientY - rect.top) / rect.height) * this.canvas.height;
    let best = null, bestD = 8 * 8;
    for (const p of this.map.points) {
      const [cx, cy] = this.toCanvas(p.x, p.y);
      const d = (cx - px) ** 2 + (cy - py) ** 2;
      if (d < bestD) { best = p; bestD = d; }
    }
    return best;
  }

  hover(event) {
    const point = this.nearest(event);
    const tip = $("map-tip");
    if (!point) { tip.hidden = true; return; }
    const [cx, cy] = this.toCanvas(point.x, point.y);
    const img = $("map-tip-img");
    const src = `/api/thumbnail?id=${encodeURIComponent(point.id)}`;
    if (img.getAttribute("src") !== src) img.setAttribute("src", src);
    $("map-tip-name").textContent = point.id;
    tip.style.left = `${Math.min(cx + 10, this.canvas.width - 150)}px`;
    tip.style.top = `${Math.min(cy + 10, this.canvas.height - 70)}px`;
    tip.hidden = false;
  }

  // Labels that neither overlap one another nor leave the canvas: each point tries four places around it (right or
  // left, above or below) and keeps the first that is free; a point with no free place goes unlabelled (hover
  // still names it). Returns [{id, text, x, y, w, h}] (the label's box, canvas pixels).
  placeLabels(ctx, w, h) {
    const placed = [], height = 10, gap = 4;
    const overlaps = (a, b) => a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h;
    for (const p of this.map.points) {
      const [cx, cy] = this.toCanvas(p.x, p.y);
      const text = p.id.split("/").pop();
      const width = Math.ceil(ctx.measureText(text).width);
      const places = [[cx + gap, cy - height - 1], [cx - gap - width, cy - height - 1], [cx + gap, cy + 1],
                      [cx - gap - width, cy + 1]];
      for (const [x, y] of places) {
        const box = { id: p.id, text, x, y, w: width, h: height };
        if (x < 0 || y < 0 || x + width > w || y + height > h) continue;
        if (placed.some((other) => overlaps(box, other))) continue;
        placed.push(box);
        break;
      }
    }
    return placed;
  }

  draw() {
    const ctx = this.context, w = this.canvas.width, h = this.canvas.height;
    ctx.clearRect(0, 0, w, h);
    const [x0, x1, y0, y1] = this.map.bounds;
    ctx.fillStyle = "#777";
    for (let j = 0; j < this.samples; j++) {  // the N×N samples of the paper's figure (bvae render --umap-grid)
      for (let i = 0; i < this.samples; i++) {
        const [cx, cy] = this.toCanvas(x0 + (i / (this.samples - 1)) * (x1 - x0), y0 + (j / (this.samples - 1)) * (y1 - y0));
        ctx.fillRect(cx - 2, cy - 2, 4, 4);
      }
    }
    ctx.fillStyle = "#7fb2ff";
    for (const p of this.map.points) {
      const [cx, cy] = this.toCanvas(p.x, p.y);
      ctx.beginPath(); ctx.arc(cx, cy, 3.2, 0, 2 * Math.PI); ctx.fill();
    }
    ctx.font = "9px system-ui, sans-serif";
    ctx.fillStyle = "#bbb";
    ctx.textBaseline = "alphabetic";
    this.labels = this.placeLabels(ctx, w, h);
    for (const label of this.labels) ctx.fillText(label.text, label.x, label.y + label.h - 2);
    if (this.cursor) {
      const [cx, cy] = this.toCanvas(this.cursor[0], this.cursor[1]);
      ctx.strokeStyle = "#ffcc66"; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.arc(cx, cy, 7, 0, 2 * Math.PI); ctx.stroke();
      ctx.beginPath(); ctx.moveTo(cx - 11, cy); ctx.lineTo(cx + 11, cy); ctx.moveTo(cx, cy - 11); ctx.lineTo(cx, cy + 11); ctx.stroke();
    }
  }
}

// ---------------------------------------------------------------- start

async function start() {
  try {
    const [info, maskBuffer] = await Promise.all([
      api("/api/library").then((r) => r.json()),
      api("/api/mask").then((r) => r.arrayBuffer()),
    ]);
    const mask = new Uint8Array(maskBuffer);
    $("model-info").textContent = `${info.materials.length} materials (${info.libraries.join(", ")}), ` +
      `model ${info.model.name} ${info.model.decoder_sha256.slice(0, 12)}…, ` +
      (info.save_dir ? `saving to ${info.save_dir}` : "saving off (the studio was started without --save-dir)");
    const lighting = $("lighting");
    for (const env of info.environments) {
      const option = document.createElement("option");
      option.value = env;
      option.textContent = env === "sky" ? "built-in sky (rendered on the server, not real time)"
        : `environment map ${info.environment_name} (server, not real time)`;
      lighting.appendChild(option);
    }
    const editorPreview = new Preview("editor", $("editor-canvas"), $("editor-stats"), mask);
    const explorerPreview = new Preview("explorer", $("explorer-canvas"), $("explorer-stats"), mask);
    const editor = new Editor(info, editorPreview);
    lighting.addEventListener("change", () => { editorPreview.lighting = lighting.value; editorPreview.request(editor.state); });
    $("exposure").addEventListener("input", (e) => {
      editorPreview.exposureScale = 2 ** Number(e.target.value);
      editorPreview.repaint();
    });
    $("auto-exposure").addEventListener("click", () => {
      if (editorPreview.linear) editorPreview.exposure = BvaeRender.autoExposure(editorPreview.linear);
      $("exposure").value = "0";
      editorPreview.exposureScale = 1;
      editorPreview.repaint();
    });
    const explorer = new Explorer(info, explorerPreview, editor);
    window.studio = { info, editor, explorer, previews: { editor: editorPreview, explorer: explorerPreview }, ready: true };
    const skipped = info.without_latent || [];  // basis-only records (format 2.1): no latent code to edit
    const total = info.materials.length + skipped.length;
    setStatus(skipped.length ? `ready; ${skipped.length} of ${total} materials left out: no latent code to edit ` +
      `(basis-only records; re-encode with bvae compress --latent always): ` +
      `${skipped.slice(0, 5).join(", ")}${skipped.length > 5 ? ", …" : ""}` : "ready");
    window.dispatchEvent(new CustomEvent("studio-ready"));
  } catch (error) {
    setStatus(`could not start: ${error.message}`, true);
  }
}

start();
