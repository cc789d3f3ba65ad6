// The page's shared parts: its state, the map view and the track layer, the status line, and the small helpers
// every panel uses (numbers, building labels and lists, the address hash). The panels: map_panel.js,
// reference_panel.js, query_panel.js, track_panel.js; app.js wires them to the forms.

import { ApiError } from "./api.js";
import { buildingColor } from "./geo.js";
import { MapView } from "./mapview.js";
import { TrackLayer } from "./track.js";

export const $ = (id) => document.getElementById(id);

export const state = {
  authRequired: false,
  maps: [],
  map: null,
  references: [],
  counts: { queued: 0, processing: 0, done: 0, failed: 0 },
  query: null,
  track: null,
  place: null,
  queryJob: null,
  selectedReference: null,
  selectedRank: 1,
  picking: false,
};

export const view = new MapView($("map"), {
  buildings: $("layer-buildings"),
  heat: $("layer-heatmap"),
  overlay: $("layer-overlay"),
  tooltip: $("tooltip"),
  scaleLine: $("scale-bar-line"),
  scaleLabel: $("scale-bar-label"),
});
export const trackLayer = new TrackLayer(view, $("layer-overlay"));

const objectUrls = { reference: null, labels: null, query: null };

export function setStatus(text, kind = "info") {
  const el = $("status");
  el.textContent = text;
  el.dataset.kind = kind;
}

export function reportError(err, what) {
  const message = err instanceof ApiError ? err.message : String(err);
  setStatus(`${what}: ${message}`, "error");
  if (err instanceof ApiError && err.status === 401 && state.authRequired) $("api-key").focus();
}

export function replaceObjectUrl(slot, url) {
  if (objectUrls[slot]) URL.revokeObjectURL(objectUrls[slot]);
  objectUrls[slot] = url;
  return url;
}

export function sleep(ms) {
  return new Promise((resolve) => setTimeout(resolve, ms));
}

export function percent(p) {
  return p > 0 && p < 0.0005 ? "<0.1%" : `${(100 * p).toFixed(1)}%`;
}

export function fixed(v, digits) {
  return Number.isFinite(v) ? v.toFixed(digits) : "–";
}

export function buildingLabel(b) {
  return b.name || (b.osm_id ? `${b.osm_id}` : `building ${b.building_id}`);
}

export function updateHash() {
  const parts = [];
  if (state.map) parts.push(`map=${state.map.id}`);
  if (state.query) parts.push(`query=${state.query.id}`);
  if (state.track) parts.push(`track=${state.track.id}`);
  const hash = parts.length ? `#${parts.join("&")}` : "";
  if (location.hash !== hash) history.replaceState(null, "", hash || location.pathname);
}

export function hashParams() {
  return new URLSearchParams(location.hash.replace(/^#/, ""));
}

export function fact(list, term, value) {
  const dt = document.createElement("dt");
  dt.textContent = term;
  const dd = document.createElement("dd");
  dd.textContent = value;
  list.append(dt, dd);
}

export function buildingItems(list, buildings, extra) {
  list.replaceChildren();
  for (const b of buildings) {
    const li = document.createElement("li");
    li.dataset.buildingId = b.building_id;
    const swatch = document.createElement("i");
    swatch.className = "swatch";
    swatch.style.background = buildingColor(b.building_id);
    const name = document.createElement("span");
    name.className = "name";
    name.textContent = buildingLabel(b);
    const detail = document.createElement("span");
    detail.className = "hint";
    detail.textContent = extra(b);
    li.append(swatch, name, detail);
    li.addEventListener("mouseenter", () => hoverBuilding(b.building_id, true));
    li.addEventListener("mouseleave", () => hoverBuilding(b.building_id, false));
    list.appendChild(li);
  }
}

export function hoverBuilding(id, on) {
  view.buildingPaths.get(Number(id))?.classList.toggle("hovered", on);
  for (const band of document.querySelectorAll(`.band[data-building-id="${id}"]`)) band.classList.toggle("hovered", on);
}
