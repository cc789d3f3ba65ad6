// The query panel: the photo and its position prior (typed, picked on the map or a named place), the query's job
// followed to its answer, and the answer drawn: heatmap, ranked locations, buildings in the photo and on the map.

import { apiUrl, getJson, hasApiKey, objectUrl, postForm } from "./api.js";
import { buildingColor, formatDistance } from "./geo.js";
import {
  $,
  buildingItems,
  buildingLabel,
  hoverBuilding,
  percent,
  replaceObjectUrl,
  reportError,
  setStatus,
  sleep,
  state,
  updateHash,
  view,
} from "./page.js";

const JOB_POLL_MS = 700;

let queryWatchToken = 0;

export function priorFromForm() {
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

export function pickPrior(lat, lon) {
  if (!state.picking) return;
  $("prior-lat").value = lat.toFixed(7);
  $("prior-lon").value = lon.toFixed(7);
  setPicking(false);
  view.setPrior(priorFromForm());
  setStatus(`Prior set at ${lat.toFixed(6)}, ${lon.toFixed(6)}.`);
  $("prior-radius").focus();
}

export function setPicking(on) {
  state.picking = on;
  $("prior-pick").setAttribute("aria-pressed", String(on));
  $("map").classList.toggle("picking", on);
  if (on) setStatus("Click the map where the photo was roughly taken (Escape cancels).");
}

export async function submitQuery(event) {
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

export async function loadQuery(queryId) {
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

export function clearAnswer() {
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
export function showQuery(query, { fit = true } = {}) {
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

export function showAnswerHighlights() {
  if (state.selectedReference) return; // the open reference's buildings are shown
  const buildings = state.query?.result?.buildings || [];
  view.setHighlights(new Map(buildings.map((b) => [b.building_id, buildingColor(b.building_id)])));
}

/** Emphasise one ranked location on the map and in the table (and centre the map on it if asked). */
export function selectLocation(rank, { center = false } = {}) {
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
export async function openApiLink(event) {
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
