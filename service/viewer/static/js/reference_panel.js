// The reference panel: the map's references loaded page by page and polled while they are labelled (or their walks
// placed), their upload, and the card of one reference: its facts, buildings, photo and identity labels.

import { ApiError, getJson, objectUrl, postForm } from "./api.js";
import { LocalPlane, angleDiffDeg, buildingColor, formatDistance } from "./geo.js";
import { $, buildingItems, fact, fixed, percent, replaceObjectUrl, reportError, setStatus, state, view } from "./page.js";
import { showAnswerHighlights } from "./query_panel.js";

const REFERENCE_POLL_MS = 1500;
const PAGE_LIMIT = 500;

let referencePollTimer = 0;
let referenceLoadToken = 0;
let referenceToken = 0;

export async function loadReferences() {
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

export async function uploadReferences(event) {
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

export async function openReference(id, { keepFocus = false } = {}) {
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

export async function showReferencePhoto(ref, labels) {
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

export function closeReference() {
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
