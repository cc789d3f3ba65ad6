// The viewer page: wires the forms and panels to the /v1 API and the map view.
// State lives in this module; `window.viewer` exposes it (and the projection) for tests and debugging.

import { ApiError, apiUrl, getJson, hasApiKey, objectUrl, postForm, setApiKey } from "./api.js";
import { LocalPlane, angleDiffDeg, buildingColor, formatDistance } from "./geo.js";
import { MapView } from "./mapview.js";
import { installPlaceSearch } from "./places.js";
import { TrackLayer } from "./track.js";

const REFERENCE_POLL_MS = 1500;
const JOB_POLL_MS = 700;
const PAGE_LIMIT = 500;

const $ = (id) => document.getElementById(id);

const state = {
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

const view = new MapView($("map"), {
  buildings: $("layer-buildings"),
  heat: $("layer-heatmap"),
  overlay: $("layer-overlay"),
  tooltip: $("tooltip"),
  scaleLine: $("scale-bar-line"),
  scaleLabel: $("scale-bar-label"),
});
const trackLayer = new TrackLayer(view, $("layer-overlay"));

let referencePollTimer = 0;
let referenceLoadToken = 0;
let queryWatchToken = 0;
let referenceToken = 0;
const objectUrls = { reference: null, labels: null, query: null };

// --- small helpers ------------------------------------------------------------------------------

function setStatus(text, kind = "info") {
  const el = $("status");
  el.textContent = text;
  el.dataset.kind = kind;
}

function reportError(err, what) {
  const message = err instanceof ApiError ? err.message : String(err);
  setStatus(`${what}: ${message}`, "error");
  if (err instanceof ApiError && err.status === 401 && state.authRequired) $("api-key").focus();
}

function replaceObjectUrl(slot, url) {
  if (objectUrls[slot]) URL.revokeObjectURL(objectUrls[slot]);
  objectUrls[slot] = url;
  return url;
}

function sleep(ms) {
  return new Promise((resolve) => setTimeout(resolve, ms));
}

function percent(p) {
  return p > 0 && p < 0.0005 ? "<0.1%" : `${(100 * p).toFixed(1)}%`;
}

function fixed(v, digits) {
  return Number.isFinite(v) ? v.toFixed(digits) : "–";
}

function buildingLabel(b) {
  return b.name || (b.osm_id ? `${b.osm_id}` : `building ${b.building_id}`);
}

function updateHash() {
  const parts = [];
  if (state.map) parts.push(`map=${state.map.id}`);
  if (state.query) parts.push(`query=${state.query.id}`);
  if (state.track) parts.push(`track=${state.track.id}`);
  const hash = parts.length ? `#${parts.join("&")}` : "";
  if (location.hash !== hash) history.replaceState(null, "", hash || location.pathname);
}

function hashParams() {
  return new URLSearchParams(location.hash.replace(/^#/, ""));
}

function fact(list, term, value) {
  const dt = document.createElement("dt");
  dt.textContent = term;
  const dd = document.createElement("dd");
  dd.textContent = value;
  list.append(dt, dd);
}

function buildingItems(list, buildings, extra) {
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

function hoverBuilding(id, on) {
  view.buildingPaths.get(Number(id))?.classList.toggle("hovered", on);
  for (const band of document.querySelectorAll(`.band[data-building-id="${id}"]`)) band.classList.toggle("hovered", on);
}

// --- API key ------------------------------------------------------------------------------------

async function start() {
  view.on("referenceSelect", (id) => openReference(id));
  view.on("locationSelect", (rank) => selectLocation(rank));
  view.on("mapClick", (lat, lon) => pickPrior(lat, lon));
  installForms();
  try {
    const config = await getJson("viewer/config.json");
    state.authRequired = Boolean(config.auth_required);
  } catch (err) {
    reportError(err, "Viewer configuration");
    return;
  }
  if (state.authRequired) {
    $("key-form").hidden = false;
    setStatus("This service needs an API key: enter it above.");
    $("api-key").focus();
    return;
  }
  await loadMaps();
}

async function useKey(event) {
  event.preventDefault();
  setApiKey($("api-key").value);
  if (!hasApiKey()) {
    setStatus("Enter an API key first.", "error");
    return;
  }
  await loadMaps();
}

// --- maps ---------------------------------------------------------------------------------------

async function loadMaps(selectId = null) {
  let body;
  try {
    body = await getJson("v1/maps");
  } catch (err) {
    reportError(err, "Loading maps");
    return;
  }
  state.maps = body.maps;
  const select = $("map-select");
  select.replaceChildren();
  for (const m of state.maps) {
    const option = document.createElement("option");
    option.value = m.id;
    option.textContent =
      m.status === "done" ? `${m.id}: ${m.name} (${m.building_count} buildings)` : `${m.id}: ${m.name} (${m.status})`;
    select.appendChild(option);
  }
  select.disabled = state.maps.length === 0;
  if (state.maps.length === 0) {
    const option = document.createElement("option");
    option.textContent = "(no maps yet)";
    select.appendChild(option);
    $("section-map").open = true;
    setStatus("No map yet: upload one (Upload a map, on the right).");
    return;
  }
  const wanted = selectId ?? Number(hashParams().get("map"));
  const chosen = state.maps.find((m) => m.id === wanted) || state.maps[state.maps.length - 1];
  select.value = chosen.id;
  await selectMap(chosen.id);
}

async function selectMap(mapId) {
  setStatus(`Loading map ${mapId}…`);
  state.place = null; // a place belongs to its map
  $("prior-place").value = "";
  let map;
  let buildings;
  let streets;
  try {
    map = await waitForMap(await getJson(`v1/maps/${mapId}`)); // usable once its parse is done
    if (map.status === "failed") {
      setStatus(`Map ${map.id} could not be loaded: ${map.error}`, "error");
      return;
    }
    [buildings, streets] = await Promise.all([
      getJson(`v1/maps/${mapId}/buildings`),
      getJson(`v1/maps/${mapId}/streets`),
    ]);
  } catch (err) {
    reportError(err, `Loading map ${mapId}`);
    return;
  }
  const queryId = Number(hashParams().get("query")); // an answer to reopen (read before the hash changes)
  const trackId = Number(hashParams().get("track"));
  state.map = map;
  state.query = null;
  closeReference();
  clearAnswer();
  view.setMap(map, buildings, streets);
  $("map-attribution").textContent = map.attribution; // the map data's licence requires it shown (ODbL)
  $("map-attribution").hidden = !map.attribution;
  $("map-info").textContent =
    `${map.name}: ${map.building_count} buildings, ${map.facade_count} facades (from ${map.source_filename}).`;
  document.body.dataset.mapId = map.id;
  document.body.dataset.buildingsDrawn = view.buildingPaths.size;
  document.body.dataset.streetsDrawn = view.streets.count;
  setStatus(`Map ${map.id} “${map.name}”: ${map.building_count} buildings.`);
  updateHash();
  await loadReferences();
  if (queryId) await loadQuery(queryId);
  showTrack(null);
  if (trackId) await loadTrack(trackId);
}

// --- tracks -------------------------------------------------------------------------------------

async function loadTrack(trackId) {
  let track;
  try {
    track = await getJson(`v1/tracks/${trackId}`);
  } catch (err) {
    reportError(err, `Loading track ${trackId}`);
    return;
  }
  if (state.map && track.map_id !== state.map.id) {
    setStatus(`Track ${trackId} is on map ${track.map_id}: pick that map to see it.`);
    return;
  }
  showTrack(track);
}

/** Draw a track (TrackOut) and open its stepper; null clears it. */
function showTrack(track) {
  state.track = track;
  trackLayer.setTrack(track);
  $("section-track").hidden = !track;
  if (!track) return;
  setStatus(`Track ${track.id}: ${track.status}, ${track.frames.length} frames, ${trackLayer.frames.length} located.`);
  if (trackLayer.frames.length) view.fitBox(trackLayer.box(), 60);
  stepTrack(0);
  updateHash();
}

function stepTrack(delta) {
  const frame = trackLayer.select(trackLayer.selected + delta);
  const facts = $("track-facts");
  facts.replaceChildren();
  const n = trackLayer.frames.length;
  $("track-prev").disabled = !n || trackLayer.selected === 0;
  $("track-next").disabled = !n || trackLayer.selected === n - 1;
  if (!frame) {
    $("track-frame-label").textContent = "No frame located yet.";
    return;
  }
  $("track-frame-label").textContent = `Frame ${trackLayer.selected + 1} of ${n}`;
  document.body.dataset.trackFrame = frame.index;
  fact(facts, "Photo", frame.original_filename || `query ${frame.query_id}`);
  fact(facts, "Position", `${fixed(frame.lat, 6)}, ${fixed(frame.lon, 6)}`);
  fact(facts, "Heading", `${fixed(frame.heading_deg, 1)}°`);
  fact(facts, "Uncertainty (90 %)", formatDistance(Number(frame.uncertainty_radius_m)));
  fact(facts, "Source", frame.outlier ? `${frame.source} (outlier)` : frame.source);
  fact(facts, "Buildings", frame.buildings.map(buildingLabel).join(", ") || "–");
}

async function uploadMap(event) {
  event.preventDefault();
  const file = $("map-file").files[0];
  const name = $("map-name").value.trim();
  if (!file || !name) {
    setStatus("Give the map a name and choose its file.", "error");
    return;
  }
  const form = new FormData();
  form.append("name", name);
  form.append("file", file);
  const attribution = $("map-attribution-input").value.trim();
  if (attribution) form.append("attribution", attribution);
  setStatus(`Uploading ${file.name} (${(file.size / 1e6).toFixed(1)} MB)…`);
  form.append("wait_s", "2"); // a file the workers cannot read is a 422 within these seconds
  try {
    const { status, body } = await postForm("v1/maps", form);
    const map = status === 200 ? body : await waitForMap(body);
    if (map.status === "failed") {
      setStatus(`Map ${map.id} could not be loaded: ${map.error}`, "error");
      return;
    }
    setStatus(
      status === 200
        ? `This file is already map ${map.id} “${map.name}”.`
        : `Map ${map.id} stored: ${map.building_count} buildings, ${map.facade_count} facades.`,
    );
    $("section-map").open = false;
    history.replaceState(null, "", location.pathname);
    await loadMaps(map.id);
  } catch (err) {
    reportError(err, "Map upload");
  }
}

/** Poll a map until its parse is done or failed, showing its progress; returns the map as it ended. */
async function waitForMap(map) {
  let pauseMs = 250;
  while (map.status === "queued" || map.status === "processing") {
    const { elements = 0, buildings = 0 } = map.progress || {};
    setStatus(
      map.status === "queued"
        ? `Map ${map.id} “${map.name}” is queued for parsing…`
        : `Parsing map ${map.id} “${map.name}”: ${elements.toLocaleString()} elements read, ` +
            `${buildings.toLocaleString()} buildings so far…`,
    );
    document.body.dataset.mapStatus = map.status;
    await sleep(pauseMs);
    pauseMs = Math.min(pauseMs * 2, 2000);
    map = await getJson(`v1/maps/${map.id}`);
  }
  document.body.dataset.mapStatus = map.status;
  return map;
}

// --- references ---------------------------------------------------------------------------------

async function loadReferences() {
  if (!state.map) return;
  const mapId = state.map.id;
  const token = ++referenceLoadToken; // a newer load supersedes this one (one polling chain at a time)
  clearTimeout(referencePollTimer);
  const references = [];
  let after = 0;
  let counts = null;
  let walksPlacing = 0;
  try {
    for (;;) {
      const page = await getJson(`v1/maps/${mapId}/references?after_id=${after}&limit=${PAGE_LIMIT}`);
      references.push(...page.references);
      counts = page.counts;
      walksPlacing = page.walks_placing;
      if (page.next_after_id == null) break;
      after = page.next_after_id;
    }
  } catch (err) {
    reportError(err, "Loading references");
    return;
  }
  if (token !== referenceLoadToken || !state.map || state.map.id !== mapId) return;
  state.references = references;
  state.counts = counts;
  view.setReferences(references);
  showIngest(counts, walksPlacing);
  if (state.selectedReference) {
    const fresh = references.find((r) => r.id === state.selectedReference.id);
    if (fresh && fresh.status !== state.selectedReference.status) openReference(fresh.id, { keepFocus: true });
  }
  // keep polling while walks are being placed too: their references move when it finishes
  if (counts.queued + counts.processing + walksPlacing > 0) {
    referencePollTimer = setTimeout(loadReferences, REFERENCE_POLL_MS);
  }
}

function showIngest(counts, walksPlacing) {
  const total = counts.queued + counts.processing + counts.done + counts.failed;
  const finished = counts.done + counts.failed;
  const box = $("ingest");
  box.dataset.total = total;
  box.dataset.done = counts.done;
  box.dataset.failed = counts.failed;
  box.dataset.pending = counts.queued + counts.processing;
  box.dataset.walksPlacing = walksPlacing;
  const bar = $("ingest-progress");
  bar.max = Math.max(total, 1);
  bar.value = finished;
  const text = $("ingest-text");
  if (total === 0) {
    text.textContent = "No references yet: upload geo-tagged photos of this map.";
  } else {
    const parts = [`${counts.done} of ${total} labelled`];
    if (counts.processing) parts.push(`${counts.processing} processing`);
    if (counts.queued) parts.push(`${counts.queued} queued`);
    if (counts.failed) parts.push(`${counts.failed} failed`);
    if (walksPlacing) parts.push("placing walks");
    text.textContent = `${parts.join(", ")}.`;
  }
}

async function uploadReferences(event) {
  event.preventDefault();
  if (!state.map) {
    setStatus("Choose or upload a map first.", "error");
    return;
  }
  const files = [...$("ref-files").files];
  if (files.length === 0) {
    setStatus("Choose geo-tagged photos first.", "error");
    return;
  }
  const mapId = state.map.id;
  const rejected = [];
  let accepted = 0;
  let duplicates = 0;
  for (const [i, file] of files.entries()) {
    setStatus(`Uploading reference ${i + 1} of ${files.length}: ${file.name}…`);
    const form = new FormData();
    form.append("image", file);
    try {
      const { status } = await postForm(`v1/maps/${mapId}/references`, form);
      if (status === 200) duplicates += 1;
      else accepted += 1;
    } catch (err) {
      if (err instanceof ApiError && (err.status === 401 || err.status === 403 || err.status === 0)) {
        reportError(err, "Reference upload");
        return;
      }
      rejected.push(`${file.name}: ${err.message}`);
    }
    if (i % 4 === 3) loadReferences();
  }
  const summary = [`${accepted} accepted`];
  if (duplicates) summary.push(`${duplicates} already present`);
  if (rejected.length) summary.push(`${rejected.length} rejected (${rejected.join("; ")})`);
  setStatus(`References: ${summary.join(", ")}. Labelling runs in the workers.`, rejected.length ? "error" : "info");
  $("ref-files").value = "";
  await loadReferences();
}

async function openReference(id, { keepFocus = false } = {}) {
  const token = ++referenceToken;
  let ref;
  try {
    ref = await getJson(`v1/references/${id}`);
  } catch (err) {
    reportError(err, `Reference ${id}`);
    return;
  }
  if (token !== referenceToken) return;
  state.selectedReference = ref;
  view.selectReference(ref.id);
  const card = $("reference-card");
  card.hidden = false;
  card.dataset.referenceId = ref.id;
  $("reference-title").textContent = `Reference ${ref.id}${ref.original_filename ? ` · ${ref.original_filename}` : ""}`;
  const facts = $("reference-facts");
  facts.replaceChildren();
  fact(facts, "Status", ref.status === "done" ? "labelled" : ref.status + (ref.error ? ` (${ref.error})` : ""));
  fact(facts, "GPS tag", `${fixed(ref.position.lat, 6)}, ${fixed(ref.position.lon, 6)} (${ref.position.source})`);
  const est = ref.estimated;
  if (est && Number.isFinite(est.lat)) {
    const plane = new LocalPlane(ref.position.lat, ref.position.lon);
    const [dx, dy] = plane.toLocal(est.lat, est.lon);
    fact(facts, "Estimated", `${fixed(est.lat, 6)}, ${fixed(est.lon, 6)}: ${formatDistance(Math.hypot(dx, dy))} from the GPS tag`);
  }
  if (est && Number.isFinite(est.heading_deg)) {
    const prior = ref.prior_heading_deg;
    const vsPrior = Number.isFinite(prior) ? `; prior ${prior.toFixed(0)}°, ${angleDiffDeg(est.heading_deg, prior).toFixed(0)}° apart` : "";
    fact(facts, "Heading", `${est.heading_deg.toFixed(1)}°${vsPrior}`);
  }
  fact(facts, "Photo", `${ref.width} × ${ref.height} px${ref.focal_length_35mm ? `, ${ref.focal_length_35mm} mm (35 mm equiv.)` : ""}`);
  const seen = ref.buildings_seen || [];
  buildingItems($("reference-buildings"), seen, (b) => (b.pixel_share != null ? percent(b.pixel_share) : ""));
  view.setHighlights(new Map(seen.map((b) => [b.building_id, buildingColor(b.building_id)])));
  const labelsButton = $("ref-show-labels");
  labelsButton.disabled = ref.status !== "done";
  await showReferencePhoto(ref, ref.status === "done" && $("ref-show-labels").getAttribute("aria-pressed") === "true");
  if (!keepFocus) $("reference-close").focus();
}

async function showReferencePhoto(ref, labels) {
  $("ref-show-photo").setAttribute("aria-pressed", String(!labels));
  $("ref-show-labels").setAttribute("aria-pressed", String(labels));
  const img = $("reference-photo");
  const path = labels ? `v1/references/${ref.id}/labels.png` : `v1/references/${ref.id}/image`;
  img.dataset.loaded = "false";
  try {
    const url = await objectUrl(path);
    if (state.selectedReference?.id !== ref.id) return;
    img.onload = () => {
      img.dataset.loaded = "true";
    };
    img.src = replaceObjectUrl(labels ? "labels" : "reference", url);
    img.dataset.kind = labels ? "labels" : "photo";
    img.alt = labels
      ? `Reference ${ref.id} with its building pixels coloured by identity`
      : `Reference photo ${ref.id}`;
    $("reference-caption").textContent = labels
      ? "Building pixels coloured by identity (paler: less certain); colours match the map."
      : "The photo as uploaded.";
  } catch (err) {
    reportError(err, `Photo of reference ${ref.id}`);
  }
}

function closeReference() {
  const card = $("reference-card");
  const wasOpen = !card.hidden;
  const id = state.selectedReference?.id;
  card.hidden = true;
  state.selectedReference = null;
  referenceToken += 1;
  view.selectReference(null);
  showAnswerHighlights();
  if (wasOpen && id != null) view.referenceEls.get(id)?.focus();
}

// --- queries ------------------------------------------------------------------------------------

function priorFromForm() {
  if (state.place && !$("prior-lat").value) {
    const radius = parseFloat($("prior-radius").value);
    return { lat: state.place.lat, lon: state.place.lon, radius_m: Number.isFinite(radius) ? radius : state.place.radius_m };
  }
  const lat = parseFloat($("prior-lat").value);
  const lon = parseFloat($("prior-lon").value);
  const radius = parseFloat($("prior-radius").value);
  if (!Number.isFinite(lat) || !Number.isFinite(lon)) return null;
  return { lat, lon, radius_m: Number.isFinite(radius) ? radius : 50 };
}

function pickPrior(lat, lon) {
  if (!state.picking) return;
  $("prior-lat").value = lat.toFixed(7);
  $("prior-lon").value = lon.toFixed(7);
  setPicking(false);
  view.setPrior(priorFromForm());
  setStatus(`Prior set at ${lat.toFixed(6)}, ${lon.toFixed(6)}.`);
  $("prior-radius").focus();
}

function setPicking(on) {
  state.picking = on;
  $("prior-pick").setAttribute("aria-pressed", String(on));
  $("map").classList.toggle("picking", on);
  if (on) setStatus("Click the map where the photo was roughly taken (Escape cancels).");
}

async function submitQuery(event) {
  event.preventDefault();
  if (!state.map) {
    setStatus("Choose or upload a map first.", "error");
    return;
  }
  const file = $("query-file").files[0];
  if (!file) {
    setStatus("Choose or drop a photo to locate.", "error");
    return;
  }
  const form = new FormData();
  form.append("image", file);
  const prior = priorFromForm();
  const place = $("prior-place").value.trim();
  if ($("prior-lat").value || !place) {
    if (prior) {
      form.append("lat", prior.lat);
      form.append("lon", prior.lon);
    }
  } else {
    form.append("place", place); // the service resolves it (422 when ambiguous or unknown)
  }
  if ($("prior-radius").value) form.append("radius_m", $("prior-radius").value);
  form.append("use_exif_gps", $("use-exif").checked ? "true" : "false");
  form.append("top_n", $("top-n").value || "10");
  form.append("wait_s", "0");
  clearAnswer();
  $("answer").hidden = false;
  $("query-photo").src = replaceObjectUrl("query", URL.createObjectURL(file));
  $("query-submit").disabled = true;
  jobLine(`Uploading ${file.name}…`);
  try {
    const { body } = await postForm(`v1/maps/${state.map.id}/queries`, form);
    await watchQuery(body);
  } catch (err) {
    jobLine(`Failed: ${err.message}`, "error");
    reportError(err, "Query");
  } finally {
    $("query-submit").disabled = false;
  }
}

function jobLine(text, kind = "info") {
  const el = $("query-job");
  el.textContent = text;
  el.dataset.kind = kind;
}

/** Follow a query's job until it finishes, then show the answer. */
async function watchQuery(query) {
  const token = ++queryWatchToken;
  const started = performance.now();
  let current = query;
  $("answer").dataset.queryId = query.id;
  $("answer").dataset.status = query.status;
  while (current.status !== "done" && current.status !== "failed") {
    let line = `Query ${current.id}: ${current.status}`;
    if (current.job_id != null) {
      const job = await getJson(`v1/jobs/${current.job_id}`);
      state.queryJob = job;
      line = `Query ${current.id}, job ${job.id}: ${job.status === "running" ? "processing" : job.status}`;
      if (job.attempts > 1 || (job.status === "queued" && job.attempts > 0)) {
        const lastError = job.error ? `; last error: ${job.error.split("\n")[0]}` : "";
        line += ` (attempt ${job.attempts} of ${job.max_attempts}${lastError})`;
      }
    }
    jobLine(`${line}… ${((performance.now() - started) / 1000).toFixed(1)} s`);
    await sleep(JOB_POLL_MS);
    if (token !== queryWatchToken) return;
    current = await getJson(`v1/queries/${current.id}`);
  }
  if (token !== queryWatchToken) return;
  const seconds = ((performance.now() - started) / 1000).toFixed(1);
  if (current.status === "failed") {
    jobLine(`Query ${current.id} failed: ${current.error || "unknown error"}`, "error");
    $("answer").dataset.status = "failed";
    return;
  }
  jobLine(`Query ${current.id} answered in ${seconds} s.`);
  showQuery(current);
  const best = current.result.locations[0];
  setStatus(
    best
      ? `Query ${current.id}: most probable at ${best.lat.toFixed(6)}, ${best.lon.toFixed(6)}, heading ${best.heading_deg.toFixed(0)}° (${percent(best.probability)}).`
      : `Query ${current.id}: no location found.`,
  );
}

async function loadQuery(queryId) {
  try {
    const query = await getJson(`v1/queries/${queryId}`);
    if (!state.map || query.map_id !== state.map.id) return;
    $("answer").hidden = false;
    try {
      $("query-photo").src = replaceObjectUrl("query", await objectUrl(`v1/queries/${queryId}/image`));
    } catch (err) {
      reportError(err, `Photo of query ${queryId}`);
    }
    await watchQuery(query);
  } catch (err) {
    reportError(err, `Query ${queryId}`);
  }
}

function clearAnswer() {
  queryWatchToken += 1;
  state.query = null;
  view.setAnswer(null);
  view.setPrior(priorFromForm());
  showAnswerHighlights();
  $("answer").hidden = true;
  $("answer").dataset.status = "";
  $("query-bands").replaceChildren();
  $("answer-buildings").replaceChildren();
  $("answer-locations").tBodies[0].replaceChildren();
  $("legend-answer").hidden = true;
  $("legend-heat").hidden = true;
  jobLine("");
}

/** Draw a finished query: heatmap, ranked poses, prior, buildings on the map and in the photo. */
function showQuery(query, { fit = true } = {}) {
  state.query = query;
  updateHash();
  const result = query.result;
  const answer = $("answer");
  answer.hidden = false;
  answer.dataset.queryId = query.id;
  answer.dataset.status = query.status;
  view.setAnswer(query);
  view.setPrior(query.params?.prior || null);
  $("legend-answer").hidden = false;
  $("legend-heat").hidden = false;

  // buildings: list, photo bands, map fill
  buildingItems($("answer-buildings"), result.buildings, (b) => `${percent(b.pixel_share)} of building pixels, p ${b.probability.toFixed(2)}`);
  drawBands(result);
  showAnswerHighlights();

  // ranked locations
  const body = $("answer-locations").tBodies[0];
  body.replaceChildren();
  for (const loc of result.locations) {
    const row = document.createElement("tr");
    row.tabIndex = 0;
    row.dataset.rank = loc.rank;
    row.setAttribute("aria-selected", String(loc.rank === 1));
    const radius = Number.isFinite(loc.uncertainty_radius_m) ? ` ± ${formatDistance(loc.uncertainty_radius_m)}` : "";
    for (const text of [
      `${loc.rank}`,
      percent(loc.probability),
      `${loc.heading_deg.toFixed(0)}°`,
      `${loc.lat.toFixed(6)}, ${loc.lon.toFixed(6)}${radius}`,
    ]) {
      const cell = document.createElement("td");
      cell.textContent = text;
      row.appendChild(cell);
    }
    row.addEventListener("click", () => selectLocation(loc.rank, { center: true }));
    row.addEventListener("keydown", (event) => {
      if (event.key === "Enter" || event.key === " ") {
        event.preventDefault();
        selectLocation(loc.rank, { center: true });
      }
    });
    body.appendChild(row);
  }
  selectLocation(1);

  const s = result.search || {};
  const searchBits = [
    s.region ? `searched ${String(s.region).replaceAll("_", " ")}` : null,
    s.positions ? `${s.positions} positions × ${s.yaws} headings` : null,
    s.identity === false ? "geometry only (no building identities)" : "with building identities",
    query.params?.prior ? `prior from ${query.params.prior.source}, ${query.params.prior.radius_m} m` : "no position prior",
  ].filter(Boolean);
  $("answer-search").textContent = `${searchBits.join("; ")}.`;

  setLink("link-json", `v1/queries/${query.id}`);
  setLink("link-geojson", `v1/queries/${query.id}/answer.geojson`);
  setLink("link-heatmap", `v1/queries/${query.id}/heatmap.png`);

  $("section-map").open = false;
  if (fit) {
    fitAnswer(result, query.params?.prior);
    $("query-job").scrollIntoView({ block: "start" });
  }
}

/** Frame the answer: its heatmap grid, ranked locations, prior circle and identified buildings. */
function fitAnswer(result, prior) {
  const b = result.heatmap.bounds;
  const points = [
    [b.min_lat, b.min_lon],
    [b.max_lat, b.max_lon],
    ...result.locations.map((loc) => [loc.lat, loc.lon]),
  ];
  view.fitFeatures(
    {
      points,
      circles: prior ? [[prior.lat, prior.lon, prior.radius_m || 50]] : [],
      buildingIds: result.buildings.map((building) => building.building_id),
    },
    60,
  );
}

function drawBands(result) {
  const bands = $("query-bands");
  bands.replaceChildren();
  const width = result.camera?.width || $("query-photo").naturalWidth || 1;
  for (const b of result.buildings) {
    const band = document.createElement("div");
    band.className = "band";
    band.dataset.buildingId = b.building_id;
    band.style.left = `${(100 * b.x_start) / width}%`;
    band.style.width = `${(100 * (b.x_end - b.x_start + 1)) / width}%`;
    band.style.setProperty("--band-color", buildingColor(b.building_id));
    const label = document.createElement("span");
    label.textContent = buildingLabel(b);
    band.appendChild(label);
    band.addEventListener("mouseenter", () => hoverBuilding(b.building_id, true));
    band.addEventListener("mouseleave", () => hoverBuilding(b.building_id, false));
    bands.appendChild(band);
  }
}

function showAnswerHighlights() {
  if (state.selectedReference) return; // the open reference's buildings are shown
  const buildings = state.query?.result?.buildings || [];
  view.setHighlights(new Map(buildings.map((b) => [b.building_id, buildingColor(b.building_id)])));
}

/** Emphasise one ranked location on the map and in the table (and centre the map on it if asked). */
function selectLocation(rank, { center = false } = {}) {
  state.selectedRank = rank;
  view.selectLocation(rank);
  for (const row of $("answer-locations").tBodies[0].rows) {
    row.setAttribute("aria-selected", String(Number(row.dataset.rank) === rank));
  }
  const loc = state.query?.result?.locations.find((l) => l.rank === rank);
  if (loc && center) view.centerOn(loc.lat, loc.lon);
}

function setLink(id, path) {
  const link = $(id);
  link.href = apiUrl(path);
  link.dataset.path = path;
}

/** With a key the browser cannot open API links itself (no header): fetch and open the body. */
async function openApiLink(event) {
  const link = event.currentTarget;
  if (!hasApiKey()) return;
  event.preventDefault();
  try {
    const url = await objectUrl(link.dataset.path);
    window.open(url, "_blank", "noopener");
    setTimeout(() => URL.revokeObjectURL(url), 60_000); // the new tab has read it by then
  } catch (err) {
    reportError(err, link.textContent);
  }
}

// --- forms and controls -------------------------------------------------------------------------

function installDrop(zone) {
  const input = $(zone.dataset.dropFor);
  zone.addEventListener("dragover", (event) => {
    event.preventDefault();
    zone.classList.add("over");
  });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (event) => {
    event.preventDefault();
    zone.classList.remove("over");
    if (event.dataTransfer?.files?.length) {
      input.files = event.dataTransfer.files;
      input.dispatchEvent(new Event("change", { bubbles: true }));
    }
  });
}

function installForms() {
  $("key-form").addEventListener("submit", useKey);
  $("map-select").addEventListener("change", (event) => {
    history.replaceState(null, "", location.pathname);
    selectMap(Number(event.target.value));
  });
  $("map-form").addEventListener("submit", uploadMap);
  $("ref-form").addEventListener("submit", uploadReferences);
  $("query-form").addEventListener("submit", submitQuery);
  $("zoom-in").addEventListener("click", () => view.zoomBy(1.4));
  $("zoom-out").addEventListener("click", () => view.zoomBy(1 / 1.4));
  $("zoom-fit").addEventListener("click", () => view.fitMap());
  $("reference-close").addEventListener("click", closeReference);
  $("ref-show-photo").addEventListener("click", () => state.selectedReference && showReferencePhoto(state.selectedReference, false));
  $("ref-show-labels").addEventListener("click", () => state.selectedReference && showReferencePhoto(state.selectedReference, true));
  $("prior-pick").addEventListener("click", () => setPicking(!state.picking));
  installPlaceSearch($("prior-place"), $("place-options"), () => state.map?.id ?? null, (place) => {
    state.place = place;
    if (place) {
      $("prior-lat").value = "";
      $("prior-lon").value = "";
      setStatus(`Prior: ${place.name} (${place.kind}, ${Math.round(place.radius_m)} m).`);
    }
    if (!state.query) view.setPrior(priorFromForm());
  });
  for (const id of ["prior-lat", "prior-lon", "prior-radius"]) {
    $(id).addEventListener("input", () => {
      if (!state.query) view.setPrior(priorFromForm());
    });
  }
  for (const id of ["link-json", "link-geojson", "link-heatmap"]) $(id).addEventListener("click", openApiLink);
  $("track-prev").addEventListener("click", () => stepTrack(-1));
  $("track-next").addEventListener("click", () => stepTrack(1));
  for (const zone of document.querySelectorAll(".drop[data-drop-for]")) installDrop(zone);
  document.addEventListener("keydown", (event) => {
    if (event.key !== "Escape") return;
    if (state.picking) setPicking(false);
    else if (!$("reference-card").hidden) closeReference();
  });
}

window.viewer = {
  state,
  view,
  /** WGS84 -> viewport pixels, as the page draws it. */
  project: (lat, lon) => view.project(lat, lon),
  /** Pixels per metre on screen. */
  scale: () => view.scale,
  /** Draw a query (QueryOut) as if it had just been answered. */
  showQuery: (query, options) => showQuery(query, options),
  /** Open a track by id (GET /v1/tracks/{id}) and its frame stepper. */
  loadTrack: (trackId) => loadTrack(trackId),
  trackLayer: () => trackLayer,
};

start();
