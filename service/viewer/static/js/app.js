// The viewer page: wires the forms and panels to the /v1 API and the map view, then starts.
// The state lives in page.js; `window.viewer` exposes it (and the projection) for tests and debugging.

import { getJson, hasApiKey, setApiKey } from "./api.js";
import { loadMaps, selectMap, uploadMap } from "./map_panel.js";
import { $, reportError, setStatus, state, trackLayer, view } from "./page.js";
import { installPlaceSearch } from "./places.js";
import { openApiLink, pickPrior, priorFromForm, selectLocation, setPicking, showQuery, submitQuery } from "./query_panel.js";
import { closeReference, openReference, showReferencePhoto, uploadReferences } from "./reference_panel.js";
import { loadTrack, stepTrack } from "./track_panel.js";

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
