// The map panel: the service's maps listed, one chosen and drawn (with the references, answer and track the address
// names), and a map file uploaded and followed while the workers parse it.

import { getJson, postForm } from "./api.js";
import { $, hashParams, reportError, setStatus, sleep, state, updateHash, view } from "./page.js";
import { clearAnswer, loadQuery } from "./query_panel.js";
import { closeReference, loadReferences } from "./reference_panel.js";
import { loadTrack, showTrack } from "./track_panel.js";

export async function loadMaps(selectId = null) {
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

export async function selectMap(mapId) {
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

export async function uploadMap(event) {
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
