// The review page: flights, uploads with progress, live job progress (the
// flight's event stream), a grid of chips grouped by GCP name or marker id,
// and accept/reject by mouse or keyboard. Plain JavaScript over the
// documented API; every request carries the API key as its bearer when one
// is set.
"use strict";

const KEY_ITEM = "gcp-tagger-api-key";
const state = { flight: null, observations: [], selected: 0, stream: null, images: new Map() };
const $ = (sel) => document.querySelector(sel);

function el(tag, className, text) {
  const e = document.createElement(tag);
  if (className) e.className = className;
  e.textContent = text;
  return e;
}

function setStatus(text, error) {
  const s = $("#status");
  s.textContent = text;
  s.className = error ? "error" : "";
}

function authHeaders() {
  const key = localStorage.getItem(KEY_ITEM);
  return key ? { Authorization: "Bearer " + key } : {};
}

function askKey() {
  const key = prompt("API key for this service (sent as the bearer):", localStorage.getItem(KEY_ITEM) || "");
  if (key === null) return false;
  if (key) localStorage.setItem(KEY_ITEM, key); else localStorage.removeItem(KEY_ITEM);
  return true;
}

// fetch with the key; a 401 asks for the key once and retries.
async function api(path, options = {}, retried = false) {
  const headers = Object.assign({}, options.headers || {}, authHeaders());
  const response = await fetch(path, Object.assign({}, options, { headers }));
  if (response.status === 401 && !retried && askKey()) return api(path, options, true);
  if (!response.ok) {
    let detail = response.status + " " + response.statusText;
    try { detail = (await response.json()).detail || detail; } catch (_) { /* not problem+json */ }
    throw new Error(detail);
  }
  return response;
}

async function loadFlights() {
  try {
    const page = await (await api("/v1/flights?limit=100")).json();
    const list = $("#flights");
    list.replaceChildren();
    for (const f of page.items) {
      const li = document.createElement("li");
      li.dataset.id = f.id;
      li.className = state.flight === f.id ? "current" : "";
      const ended = f.jobs.succeeded + f.jobs.failed + f.jobs.canceled;
      const all = Object.values(f.jobs).reduce((a, b) => a + b, 0);
      li.append(
        el("div", "", `${f.id.slice(0, 8)} \u00b7 ${f.state}`),
        el("div", "meta", `${ended}/${all} frames, ${f.targets} targets \u00b7 ${f.created_at.replace("T", " ").slice(0, 16)}`));
      li.addEventListener("click", () => openFlight(f.id));
      list.append(li);
    }
  } catch (e) {
    setStatus("Cannot list flights: " + e.message, true);
  }
}

function upload(files) {
  if (!files.length) return;
  const form = new FormData();
  for (const f of files) form.append("frame", f, f.name);
  const query = new URLSearchParams({ crs: $("#crs").value.trim(), marker_types: $("#marker-types").value.trim() });
  const bar = $("#upload-progress");
  bar.hidden = false;
  bar.value = 0;
  const send = (retried) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", "/v1/flights?" + query);
    for (const [k, v] of Object.entries(authHeaders())) xhr.setRequestHeader(k, v);
    xhr.upload.onprogress = (e) => { if (e.lengthComputable) bar.value = e.loaded / e.total; };
    xhr.onload = () => {
      if (xhr.status === 401 && !retried && askKey()) return send(true);
      bar.hidden = true;
      let body = {};
      try { body = JSON.parse(xhr.responseText); } catch (_) { /* empty */ }
      if (xhr.status >= 300) {
        setStatus("Upload refused: " + (body.detail || xhr.status), true);
        return;
      }
      setStatus(`Uploaded ${files.length} frame(s)`);
      loadFlights();
      openFlight(body.flight.id);
    };
    xhr.onerror = () => { bar.hidden = true; setStatus("Upload failed: network error", true); };
    setStatus(`Uploading ${files.length} frame(s)...`);
    xhr.send(form);
  };
  send(false);
}

// The flight's server-sent events, read through fetch so the bearer is sent.
async function follow(id) {
  if (state.stream) state.stream.abort();
  const controller = new AbortController();
  state.stream = controller;
  let seen = -1;
  try {
    const response = await api(`/v1/flights/${id}/events`, { signal: controller.signal });
    const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
    let buffer = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buffer += value;
      let end;
      while ((end = buffer.indexOf("\n\n")) >= 0) {
        const block = buffer.slice(0, end);
        buffer = buffer.slice(end + 2);
        const data = block.split("\n").filter((l) => l.startsWith("data:")).map((l) => l.slice(5)).join("\n");
        if (!data) continue;
        const flight = JSON.parse(data);
        showFlight(flight);
        const ended = flight.jobs.succeeded + flight.jobs.failed + flight.jobs.canceled;
        if (ended !== seen) {
          seen = ended;
          await loadObservations();
          loadFlights();
        }
      }
    }
  } catch (e) {
    if (e.name !== "AbortError") setStatus("Progress stream: " + e.message, true);
  }
}

function showFlight(f) {
  $("#flight-title").textContent = "Flight " + f.id;
  $("#job-progress").value = f.progress;
  const j = f.jobs;
  $("#flight-state").textContent = `${f.state}: ${j.succeeded} succeeded, ${j.failed} failed, ${
    j.queued + j.running + j.fetching} to go; ${f.targets} targets`;
  $("#flight").dataset.state = f.state;
}

async function openFlight(id) {
  state.flight = id;
  state.observations = [];
  state.selected = 0;
  $("#flight").hidden = false;
  $("#groups").replaceChildren();
  document.querySelectorAll("#flights li").forEach((li) => li.classList.toggle("current", li.dataset.id === id));
  surveyState();
  follow(id);
}

async function surveyState() {
  const id = state.flight;
  try {
    const s = await (await api(`/v1/flights/${id}/survey`)).json();
    $("#survey-state").textContent = `${s.points} surveyed points (${s.with_marker_id} with a marker id)`;
  } catch (_) {
    $("#survey-state").textContent = "no survey (needed for the GCP files)";
  }
}

async function loadObservations() {
  const id = state.flight;
  try {
    const list = await (await api(`/v1/flights/${id}/observations`)).json();
    if (state.flight !== id) return;
    state.observations = list.observations;
    renderChips();
  } catch (e) {
    setStatus("Cannot list detections: " + e.message, true);
  }
}

function groupName(o) {
  if (o.gcp_name) return "GCP " + o.gcp_name;
  if (o.marker_id !== null && o.marker_id !== undefined) return `${o.marker_type} ${o.marker_id}`;
  return o.marker_type;
}

function renderChips() {
  const groups = new Map();
  state.observations.forEach((o, i) => {
    const name = groupName(o);
    if (!groups.has(name)) groups.set(name, []);
    groups.get(name).push(i);
  });
  // Display order is group order; keyboard moves follow it.
  state.order = [];
  const root = $("#groups");
  root.replaceChildren();
  for (const [name, members] of [...groups.entries()].sort((a, b) => a[0].localeCompare(b[0], undefined, { numeric: true }))) {
    const section = document.createElement("section");
    section.className = "group";
    const h = document.createElement("h3");
    h.textContent = `${name} (${members.length})`;
    const grid = document.createElement("div");
    grid.className = "grid";
    for (const i of members) {
      state.order.push(i);
      grid.append(chip(state.observations[i], i));
    }
    section.append(h, grid);
    root.append(section);
  }
  select(Math.min(state.selected, state.order.length - 1), false);
}

function chip(o, i) {
  const fig = document.createElement("figure");
  fig.className = "chip";
  fig.tabIndex = -1;
  fig.dataset.index = i;
  fig.dataset.review = o.review;
  const img = document.createElement("img");
  img.alt = `${o.image}, detection ${o.index}`;
  loadImage(img, o.chip_url);
  const cap = document.createElement("figcaption");
  // Names come from uploads: text only, never markup.
  const name = el("span", "name", `${o.image} #${o.index} \u00b7 ${o.marker_id ?? o.marker_type} \u00b7 ${o.confidence.toFixed(2)}`);
  name.title = o.image;
  const buttons = el("span", "", "");
  for (const [verdict, mark, title] of [["accepted", "\u2713", "Accept (a)"], ["rejected", "\u2717", "Reject (r)"]]) {
    const b = el("button", "", mark);
    b.type = "button";
    b.title = title;
    b.addEventListener("click", (e) => { e.stopPropagation(); review(i, verdict); });
    buttons.append(b);
  }
  cap.append(name, el("span", "verdict", o.review), buttons);
  fig.addEventListener("click", () => select(state.order.indexOf(i), true));
  fig.append(img, cap);
  return fig;
}

// Images need the bearer too: fetched, then shown from a blob URL.
async function loadImage(img, url) {
  try {
    if (!state.images.has(url)) {
      const blob = await (await api(url)).blob();
      state.images.set(url, URL.createObjectURL(blob));
    }
    img.src = state.images.get(url);
    img.dataset.loaded = "1";
  } catch (e) {
    img.alt += " (" + e.message + ")";
  }
}

function select(pos, focus) {
  if (!state.order || !state.order.length || pos < 0) return;
  state.selected = pos;
  document.querySelectorAll(".chip.selected").forEach((c) => c.classList.remove("selected"));
  const el = document.querySelector(`.chip[data-index="${state.order[pos]}"]`);
  if (!el) return;
  el.classList.add("selected");
  if (focus) { el.focus({ preventScroll: true }); el.scrollIntoView({ block: "nearest" }); }
}

async function review(i, verdict) {
  const o = state.observations[i];
  try {
    const answer = await (await api(o.review_url, {
      method: "PUT",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ verdict }),
    })).json();
    o.review = answer.review;
    const el = document.querySelector(`.chip[data-index="${i}"]`);
    el.dataset.review = o.review;
    el.querySelector(".verdict").textContent = o.review;
    setStatus(`${o.image} #${o.index}: ${o.review}`);
  } catch (e) {
    setStatus("Review not stored: " + e.message, true);
  }
}

// What a download button fetches, as text (used by the buttons, and by
// scripts driving the page).
async function fetchExport(file) {
  const only = $("#accepted-only").checked ? (file.includes("?") ? "&" : "?") + "accepted_only=true" : "";
  return api(`/v1/flights/${state.flight}/${file}${only}`);
}

async function download(file) {
  try {
    const blob = await (await fetchExport(file)).blob();
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = file.split("/").pop();
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  } catch (e) {
    setStatus(`Cannot download ${file}: ${e.message}`, true);
  }
}

async function putSurvey(file) {
  try {
    await api(`/v1/flights/${state.flight}/survey`, { method: "PUT", headers: { "Content-Type": "text/csv" }, body: await file.text() });
    setStatus("Survey stored");
    await surveyState();
    await loadObservations();
  } catch (e) {
    setStatus("Survey refused: " + e.message, true);
  }
}

function keys(e) {
  if (e.target.matches("input, textarea") || $("#flight").hidden || !state.order) return;
  const pos = state.selected;
  const here = state.order[pos];
  switch (e.key) {
    case "ArrowRight": case "ArrowDown": select(Math.min(pos + 1, state.order.length - 1), true); break;
    case "ArrowLeft": case "ArrowUp": select(Math.max(pos - 1, 0), true); break;
    case "a": if (here !== undefined) review(here, "accepted"); break;
    case "r": if (here !== undefined) review(here, "rejected"); break;
    case "u": if (here !== undefined) review(here, "unreviewed"); break;
    default: return;
  }
  e.preventDefault();
}

window.gcpTagger = { fetchExport, openFlight, state };

document.addEventListener("DOMContentLoaded", () => {
  const drop = $("#drop");
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => { e.preventDefault(); drop.classList.remove("over"); upload([...e.dataTransfer.files]); });
  $("#frames-input").addEventListener("change", (e) => { upload([...e.target.files]); e.target.value = ""; });
  $("#survey-input").addEventListener("change", (e) => { if (e.target.files[0]) putSurvey(e.target.files[0]); e.target.value = ""; });
  $("#refresh").addEventListener("click", loadFlights);
  $("#key-button").addEventListener("click", () => { if (askKey()) loadFlights(); });
  document.querySelectorAll("[data-download]").forEach((b) => b.addEventListener("click", () => download(b.dataset.download)));
  document.addEventListener("keydown", keys);
  loadFlights();
});
