// The track panel: a track (GET /v1/tracks/{id}) drawn on the map and a stepper through its frames.

import { getJson } from "./api.js";
import { formatDistance } from "./geo.js";
import { $, buildingLabel, fact, fixed, reportError, setStatus, state, trackLayer, updateHash, view } from "./page.js";

export async function loadTrack(trackId) {
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
export function showTrack(track) {
  state.track = track;
  trackLayer.setTrack(track);
  $("section-track").hidden = !track;
  if (!track) return;
  setStatus(`Track ${track.id}: ${track.status}, ${track.frames.length} frames, ${trackLayer.frames.length} located.`);
  if (trackLayer.frames.length) view.fitBox(trackLayer.box(), 60);
  stepTrack(0);
  updateHash();
}

export function stepTrack(delta) {
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
