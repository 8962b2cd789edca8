// tilerender's web viewer: scenes, a live session (MJPEG in an <img>), orbit and zoom with
// the mouse, stats, and stills rendered as jobs. No build step, no dependencies.
"use strict";

const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.hash.slice(1)).get("token");
const state = { session: null, orbit: null, sending: false, pending: null, statsTimer: null };

function withToken(url) {
  if (!token) return url;
  return url + (url.includes("?") ? "&" : "?") + "access_token=" + encodeURIComponent(token);
}

async function api(method, path, body) {
  const options = { method, headers: {} };
  if (token) options.headers.Authorization = "Bearer " + token;
  if (body instanceof FormData) options.body = body;
  else if (body !== undefined) {
    options.headers["Content-Type"] = "application/json";
    options.body = JSON.stringify(body);
  }
  const response = await fetch(path, options);
  if (response.status === 204) return null;
  const data = await response.json().catch(() => ({}));
  if (!response.ok) throw new Error((data.error && data.error.message) || response.statusText);
  return data;
}

function status(text, error = false) {
  $("status").textContent = text;
  $("status").className = error ? "error" : "muted";
}

async function loadScenes(select) {
  const list = await api("GET", "/v1/scenes");
  const scenes = $("scenes");
  scenes.innerHTML = "";
  for (const scene of list.data) {
    const option = document.createElement("option");
    option.value = scene.id;
    option.textContent = `${scene.name} (${scene.triangles} triangles, v${scene.version})`;
    scenes.appendChild(option);
  }
  if (select) scenes.value = select;
  showScene();
}

async function showScene() {
  const id = $("scenes").value;
  if (!id) { $("scene-info").textContent = "no scenes yet: upload one"; return; }
  const scene = await api("GET", `/v1/scenes/${id}`);
  const b = scene.bounds;
  $("scene-info").textContent = `${scene.triangles} triangles, ${scene.nodes} nodes, version ${scene.version}` +
    (b ? `, bounds ${b.min.map((v) => v.toFixed(2))} .. ${b.max.map((v) => v.toFixed(2))}` : "");
}

async function upload(files) {
  const form = new FormData();
  const lower = (f) => f.name.toLowerCase();
  const json = files.find((f) => lower(f).endsWith(".json"));
  if (json) {
    form.append("scene", json);
    for (const f of files) if (f !== json) form.append("files", f);
  } else if (files.length === 1 && lower(files[0]).endsWith(".zip")) {
    form.append("bundle", files[0]);
  } else if (files.length === 1) {
    form.append("mesh", files[0]);
  } else {
    throw new Error("several files need their scene .json (or upload a .zip)");
  }
  status("uploading...");
  const scene = await api("POST", "/v1/scenes", form);
  status(`uploaded ${scene.name}`);
  await loadScenes(scene.id);
}

// --- Orbit camera -------------------------------------------------------------------------

function orbitFrom(camera) {
  const [px, py, pz] = camera.position, [lx, ly, lz] = camera.look_at;
  const dx = px - lx, dy = py - ly, dz = pz - lz;
  const r = Math.hypot(dx, dy, dz);
  return { target: camera.look_at, r, theta: Math.atan2(dx, dz), phi: Math.asin(dy / r),
           vfov: camera.vfov_deg };
}

function orbitCamera(o) {
  const [lx, ly, lz] = o.target;
  const c = Math.cos(o.phi);
  return {
    position: [lx + o.r * c * Math.sin(o.theta), ly + o.r * Math.sin(o.phi), lz + o.r * c * Math.cos(o.theta)],
    look_at: o.target,
    up: [0, 1, 0],
  };
}

async function sendCamera() {
  if (!state.session || state.sending || !state.pending) return;
  const camera = state.pending;
  state.pending = null;
  state.sending = true;
  try {
    await api("PUT", `/v1/sessions/${state.session.id}/camera`, camera);
  } catch (error) {
    status(error.message, true);
  } finally {
    state.sending = false;
    if (state.pending) sendCamera();
  }
}

function moved() {
  state.pending = orbitCamera(state.orbit);
  sendCamera();
}

function setupMouse() {
  const img = $("stream");
  let last = null;
  img.addEventListener("pointerdown", (e) => {
    if (!state.orbit) return;
    last = [e.clientX, e.clientY];
    img.setPointerCapture(e.pointerId);
    img.classList.add("dragging");
  });
  img.addEventListener("pointermove", (e) => {
    if (!last) return;
    const dx = e.clientX - last[0], dy = e.clientY - last[1];
    last = [e.clientX, e.clientY];
    state.orbit.theta -= dx * 0.01;
    state.orbit.phi = Math.max(-1.5, Math.min(1.5, state.orbit.phi + dy * 0.01));
    moved();
  });
  const end = () => { last = null; img.classList.remove("dragging"); };
  img.addEventListener("pointerup", end);
  img.addEventListener("pointercancel", end);
  img.addEventListener("wheel", (e) => {
    if (!state.orbit) return;
    e.preventDefault();
    state.orbit.r *= Math.exp(Math.max(-0.5, Math.min(0.5, e.deltaY * 0.001)));
    moved();
  }, { passive: false });
}

// --- Sessions -------------------------------------------------------------------------------

async function startSession() {
  await stopSession();
  const [width, height] = $("size").value.split("x").map(Number);
  const denoise = $("denoise").value;
  const session = await api("POST", "/v1/sessions", { scene_id: $("scenes").value, width, height, denoise });
  state.session = session;
  state.orbit = orbitFrom(session.camera);
  const img = $("stream");
  img.src = withToken(session.stream_url);
  img.style.display = "block";
  $("placeholder").style.display = "none";
  $("stop").disabled = false;
  $("render").disabled = false;
  status(`session ${session.id}`);
  state.statsTimer = setInterval(showStats, 1000);
}

async function stopSession() {
  clearInterval(state.statsTimer);
  const session = state.session;
  state.session = null;
  state.orbit = null;
  $("stream").removeAttribute("src");
  $("stop").disabled = true;
  if (session) await api("DELETE", `/v1/sessions/${session.id}`).catch(() => {});
}

async function setDenoise() {
  if (!state.session) return;
  try {
    const session = await api("PATCH", `/v1/sessions/${state.session.id}`, { denoise: $("denoise").value });
    state.session.denoise = session.denoise;
    status(`session ${session.id}: denoise ${session.denoise}`);
  } catch (error) {
    $("denoise").value = state.session.denoise || "off";  // the session kept its setting
    throw error;
  }
}

function fmt(value, digits = 2) {
  if (value === null || value === undefined) return "-";
  return typeof value === "number" ? value.toFixed(digits) : String(value);
}

async function showStats() {
  if (!state.session) return;
  try {
    const s = (await api("GET", `/v1/sessions/${state.session.id}`)).stats;
    const rows = [["fps", fmt(s.fps, 1)], ["stream fps", fmt(s.fps_stream, 1)], ["spp", s.spp],
      ["blend", fmt(s.blend, 3)], ["scale", fmt(s.scale)], ["samples", s.samples_accumulated],
      ["frames", s.frames], ["camera latency ms", fmt(s.camera_latency_last_ms, 0)],
      ["encode ms", fmt(s.encode_ms, 1)], ["denoise", s.denoise],
      ["denoise ms", fmt(s.denoise_ms, 1)]];
    $("stats").innerHTML = rows.map(([k, v]) => `<dt>${k}</dt><dd>${v}</dd>`).join("");
  } catch (error) {
    status(error.message, true);
    stopSession();
  }
}

// --- Stills ---------------------------------------------------------------------------------

async function renderStill() {
  const [width, height] = $("still-size").value.split("x").map(Number);
  const body = { scene_id: $("scenes").value, spp: Number($("spp").value), width, height };
  if ($("denoise").value !== "off") body.denoise = $("denoise").value;
  if (state.orbit) body.camera = orbitCamera(state.orbit);
  const job = await api("POST", "/v1/jobs", body);
  $("job").textContent = `job ${job.id}: queued`;
  const events = new EventSource(withToken(`/v1/jobs/${job.id}/events`));
  events.addEventListener("progress", (e) => {
    const p = JSON.parse(e.data);
    const eta = p.eta_seconds === null ? "" : `, ${p.eta_seconds.toFixed(1)} s left`;
    $("job").textContent = `job ${job.id}: ${p.lines_done}/${p.lines_total} lines${eta}`;
  });
  const links = () => ["png", "exr", "npy"].map((f) =>
    `<a id="download-${f}" href="${withToken(`/v1/jobs/${job.id}/result?format=${f}`)}" download>${f.toUpperCase()}</a>`).join(" ");
  events.addEventListener("done", () => {
    $("job").innerHTML = `job ${job.id}: done. Download ${links()}`;
    events.close();
  });
  for (const kind of ["error", "cancelled"]) {
    events.addEventListener(kind, (e) => {
      const data = e.data ? JSON.parse(e.data) : {};
      $("job").textContent = `job ${job.id}: ${kind} ${data.message || ""}`;
      events.close();
    });
  }
}

// --- Start ----------------------------------------------------------------------------------

function guard(fn) {
  return (...args) => fn(...args).catch((error) => status(error.message, true));
}

window.addEventListener("DOMContentLoaded", guard(async () => {
  setupMouse();
  $("scenes").addEventListener("change", guard(showScene));
  $("refresh").addEventListener("click", guard(() => loadScenes()));
  $("upload").addEventListener("change", guard((e) => upload([...e.target.files])));
  $("start").addEventListener("click", guard(startSession));
  $("stop").addEventListener("click", guard(stopSession));
  $("render").addEventListener("click", guard(renderStill));
  $("denoise").addEventListener("change", guard(setDenoise));
  window.addEventListener("beforeunload", () => {
    if (state.session) {
      fetch(withToken(`/v1/sessions/${state.session.id}`), { method: "DELETE", keepalive: true });
    }
  });
  const ready = await fetch("/readyz").then((r) => r.json());
  status(ready.status === "ready" ? `ready: ${ready.tracers} tracer(s)` : ready.message, ready.status !== "ready");
  await loadScenes();
}));
