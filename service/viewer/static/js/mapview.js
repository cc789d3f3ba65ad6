// The map: streets and building footprints (SVG in metres under one transform; street names in pixels), the probability heatmap (a canvas,
// one texel per grid cell, drawn without smoothing so every cell keeps its value) and an overlay in
// screen pixels (references, answers, prior and uncertainty circles) redrawn on every pan or zoom.

import { LocalPlane, formatDistance, horizontalFovDeg, niceLength } from "./geo.js";
import { StreetLayer } from "./streets.js";

const SVG_NS = "http://www.w3.org/2000/svg";
const MAX_SCALE_PX_PER_M = 40;
const DRAG_THRESHOLD_PX = 4;
const REFERENCE_CONE_PX = 18;
const SELECTED_REFERENCE_CONE_PX = 30;
const TOP_CONE_PX = 48;
const OTHER_CONE_PX = 30;
const LABELLED_RANKS = 3;

export function svg(tag, attrs = {}, parent = null) {
  const el = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  if (parent) parent.appendChild(el);
  return el;
}

/** Heatmap colour for t in (0, 1] (a magma-like ramp) and its opacity: faint where the probability is
 * small but never invisible, so every non-zero cell shows. */
function heatColor(t) {
  const stops = [
    [0.0, [72, 18, 140]],
    [0.35, [190, 40, 120]],
    [0.7, [250, 125, 40]],
    [1.0, [255, 232, 90]],
  ];
  let i = 1;
  while (i < stops.length - 1 && t > stops[i][0]) i += 1;
  const [t0, c0] = stops[i - 1];
  const [t1, c1] = stops[i];
  const f = Math.min(1, Math.max(0, (t - t0) / (t1 - t0)));
  const rgb = c0.map((v, k) => Math.round(v + f * (c1[k] - v)));
  return [...rgb, Math.round(255 * (0.3 + 0.55 * t))];
}

export function wedgePath(x, y, headingDeg, fovDeg, length) {
  const a0 = ((headingDeg - fovDeg / 2) * Math.PI) / 180;
  const a1 = ((headingDeg + fovDeg / 2) * Math.PI) / 180;
  const p0 = [x + length * Math.sin(a0), y - length * Math.cos(a0)];
  const p1 = [x + length * Math.sin(a1), y - length * Math.cos(a1)];
  const f = (v) => v.toFixed(1);
  return `M${f(x)},${f(y)} L${f(p0[0])},${f(p0[1])} A${length},${length} 0 0 1 ${f(p1[0])},${f(p1[1])} Z`;
}

function ringsPath(rings, plane) {
  return rings
    .map(
      (ring) =>
        "M" +
        ring
          .map(([lon, lat]) => {
            const [x, y] = plane.toLocal(lat, lon);
            return `${x.toFixed(2)},${y.toFixed(2)}`;
          })
          .join("L") +
        "Z",
    )
    .join("");
}

export class MapView {
  /**
   * @param {HTMLElement} root the focusable map element holding the three layers
   * @param {object} parts {buildings, heat, overlay, tooltip, scaleLine, scaleLabel}
   */
  constructor(root, parts) {
    this.root = root;
    this.parts = parts;
    this.plane = null;
    this.center = [0, 0];
    this.scale = 1;
    this.fitScale = 1;
    this.bounds = null;
    this.buildingPaths = new Map();
    this.references = [];
    this.referenceEls = new Map();
    this.selectedReferenceId = null;
    this.answer = null;
    this.selectedRank = 1;
    this.prior = null;
    this.heatImage = null;
    this.highlights = new Map();
    this.handlers = { referenceSelect: () => {}, locationSelect: () => {}, mapClick: () => {} };
    this.pendingFrame = 0;
    this.layers = []; // more overlays ({render()}), drawn after the answer on every pan or zoom (track.js)

    this.streets = new StreetLayer(parts.buildings); // under the footprints
    this.buildingGroup = svg("g", { class: "buildings" }, parts.buildings);
    const overlay = parts.overlay;
    this.priorGroup = svg("g", { class: "prior-layer" }, overlay);
    this.referenceGroup = svg("g", { class: "references", role: "group", "aria-label": "References" }, overlay);
    this.poseGroup = svg("g", { class: "reference-pose" }, overlay);
    this.answerGroup = svg("g", { class: "answer-layer", role: "group", "aria-label": "Ranked locations" }, overlay);

    this.installInteraction();
    new ResizeObserver(() => this.requestRender()).observe(root);
  }

  /** Callbacks: referenceSelect(id), locationSelect(rank), mapClick(lat, lon). */
  on(name, callback) {
    this.handlers[name] = callback;
  }

  // --- view -----------------------------------------------------------------------------------

  get width() {
    return this.root.clientWidth;
  }

  get height() {
    return this.root.clientHeight;
  }

  /** Local metres -> pixels relative to the map element. */
  toScreen(x, y) {
    return [this.width / 2 + (x - this.center[0]) * this.scale, this.height / 2 - (y - this.center[1]) * this.scale];
  }

  /** WGS84 -> viewport (client) pixels: where the page draws that point. */
  project(lat, lon) {
    const [sx, sy] = this.toScreen(...this.plane.toLocal(lat, lon));
    const rect = this.root.getBoundingClientRect();
    return [rect.left + sx, rect.top + sy];
  }

  /** Viewport (client) pixels -> WGS84 [lat, lon]. */
  unproject(clientX, clientY) {
    const rect = this.root.getBoundingClientRect();
    const x = this.center[0] + (clientX - rect.left - this.width / 2) / this.scale;
    const y = this.center[1] - (clientY - rect.top - this.height / 2) / this.scale;
    return this.plane.toLatLon(x, y);
  }

  /** Show the local-metre box [minX, minY, maxX, maxY] with a margin. */
  fitBox(box, marginPx = 24) {
    const [x0, y0, x1, y1] = box;
    const w = Math.max(this.width - 2 * marginPx, 50);
    const h = Math.max(this.height - 2 * marginPx, 50);
    this.scale = Math.min(MAX_SCALE_PX_PER_M, w / Math.max(x1 - x0, 1), h / Math.max(y1 - y0, 1));
    this.center = [(x0 + x1) / 2, (y0 + y1) / 2];
    this.requestRender();
  }

  /** Show the whole map. */
  fitMap() {
    if (this.bounds) this.fitBox(this.bounds);
  }

  /** Show these points ([lat, lon]), circles ([lat, lon, radius_m]) and buildings (ids) together. */
  fitFeatures({ points = [], circles = [], buildingIds = [] }, marginPx = 40) {
    let box = [Infinity, Infinity, -Infinity, -Infinity];
    const add = (x0, y0, x1, y1) => {
      box = [Math.min(box[0], x0), Math.min(box[1], y0), Math.max(box[2], x1), Math.max(box[3], y1)];
    };
    for (const [lat, lon] of points) {
      const [x, y] = this.plane.toLocal(lat, lon);
      add(x, y, x, y);
    }
    for (const [lat, lon, r] of circles) {
      const [x, y] = this.plane.toLocal(lat, lon);
      add(x - r, y - r, x + r, y + r);
    }
    for (const id of buildingIds) {
      const path = this.buildingPaths.get(id);
      if (!path) continue;
      const b = path.getBBox(); // local metres: the group's transform is not applied
      add(b.x, b.y, b.x + b.width, b.y + b.height);
    }
    if (Number.isFinite(box[0])) this.fitBox(box, marginPx);
  }

  zoomBy(factor, anchor = null) {
    const minScale = this.fitScale / 4;
    const next = Math.min(MAX_SCALE_PX_PER_M, Math.max(minScale, this.scale * factor));
    const [ax, ay] = anchor || [this.width / 2, this.height / 2];
    // keep the point under the anchor where it is
    const mx = this.center[0] + (ax - this.width / 2) / this.scale;
    const my = this.center[1] - (ay - this.height / 2) / this.scale;
    this.scale = next;
    this.center = [mx - (ax - this.width / 2) / next, my + (ay - this.height / 2) / next];
    this.requestRender();
  }

  panBy(dxPx, dyPx) {
    this.center = [this.center[0] - dxPx / this.scale, this.center[1] + dyPx / this.scale];
    this.requestRender();
  }

  centerOn(lat, lon) {
    this.center = this.plane.toLocal(lat, lon);
    this.requestRender();
  }

  requestRender() {
    if (this.pendingFrame) return;
    this.pendingFrame = requestAnimationFrame(() => {
      this.pendingFrame = 0;
      this.render();
    });
  }

  // --- data -----------------------------------------------------------------------------------

  /** A map (MapOut), its buildings and streets (GeoJSON FeatureCollections): draw them, fit the view. */
  setMap(map, buildings, streets = { features: [] }) {
    this.plane = new LocalPlane(map.origin.lat, map.origin.lon);
    this.streets.set(streets, this.plane);
    this.buildingGroup.replaceChildren();
    this.buildingPaths.clear();
    let box = [Infinity, Infinity, -Infinity, -Infinity];
    for (const feature of buildings.features) {
      const g = feature.geometry;
      if (!g) continue;
      const polygons = g.type === "Polygon" ? [g.coordinates] : g.type === "MultiPolygon" ? g.coordinates : [];
      const p = feature.properties || {};
      const id = p.building_id ?? feature.id;
      const label = p.name ? p.name : `Building ${id}${p.osm_id ? ` (${p.osm_id})` : ""}`;
      const path = svg("path", {
        d: polygons.map((rings) => ringsPath(rings, this.plane)).join(""),
        class: "building",
        "data-building-id": id,
        "data-tip": p.height_m ? `${label} · ${Math.round(p.height_m)} m tall` : label,
      });
      this.buildingGroup.appendChild(path);
      this.buildingPaths.set(Number(id), path);
      for (const rings of polygons) {
        for (const [lon, lat] of rings[0]) {
          const [x, y] = this.plane.toLocal(lat, lon);
          box = [Math.min(box[0], x), Math.min(box[1], y), Math.max(box[2], x), Math.max(box[3], y)];
        }
      }
    }
    if (!Number.isFinite(box[0])) {
      const [x0, y0] = this.plane.toLocal(map.bbox.min_lat, map.bbox.min_lon);
      const [x1, y1] = this.plane.toLocal(map.bbox.max_lat, map.bbox.max_lon);
      box = [x0, y0, x1, y1];
    }
    this.bounds = box;
    this.references = [];
    this.referenceGroup.replaceChildren();
    this.referenceEls.clear();
    this.selectedReferenceId = null;
    this.setAnswer(null);
    this.fitMap();
    this.fitScale = this.scale;
  }

  /** References (ReferenceOut list): markers coloured by status, keyed by id so focus survives updates. */
  setReferences(references) {
    this.references = references;
    const seen = new Set();
    for (const ref of references) {
      seen.add(ref.id);
      let el = this.referenceEls.get(ref.id);
      if (!el) {
        el = svg("g", { class: "reference", tabindex: "0", role: "button", "data-reference-id": ref.id });
        svg("path", { class: "cone" }, el);
        svg("circle", { class: "dot", r: "4.5" }, el);
        el.addEventListener("click", () => this.handlers.referenceSelect(ref.id));
        el.addEventListener("keydown", (event) => {
          if (event.key === "Enter" || event.key === " ") {
            event.preventDefault();
            this.handlers.referenceSelect(ref.id);
          }
        });
        this.referenceGroup.appendChild(el);
        this.referenceEls.set(ref.id, el);
      }
      const label = ref.status === "done" ? "labelled" : ref.status;
      const name = ref.original_filename || `#${ref.id}`;
      el.setAttribute("class", `reference status-${ref.status}`);
      el.setAttribute("aria-label", `Reference ${ref.id} (${name}), ${label}: open its photo`);
      el.setAttribute("data-tip", `Reference ${ref.id} · ${name} · ${label}`);
      el.setAttribute("data-status", ref.status);
    }
    for (const [id, el] of this.referenceEls) {
      if (!seen.has(id)) {
        el.remove();
        this.referenceEls.delete(id);
      }
    }
    this.requestRender();
  }

  /** The reference whose pose and GPS tag are drawn (null: none). */
  selectReference(id) {
    this.selectedReferenceId = id;
    this.requestRender();
  }

  /** A finished query (QueryOut with its result), or null to clear the answer. */
  setAnswer(query) {
    this.answer = query && query.result ? query : null;
    this.selectedRank = 1;
    this.answerGroup.replaceChildren();
    this.heatImage = null;
    if (this.answer) {
      this.heatImage = this.buildHeatImage(this.answer.result.heatmap);
      const hfov = this.answer.result.camera?.hfov_deg || 60;
      for (const loc of this.answer.result.locations) {
        const pct = `${(100 * loc.probability).toFixed(1)}%`;
        const el = svg("g", {
          class: `location${loc.rank === 1 ? " top" : ""}`,
          tabindex: "0",
          role: "button",
          "data-rank": loc.rank,
          "data-lat": loc.lat,
          "data-lon": loc.lon,
          "data-heading": loc.heading_deg,
          "data-probability": loc.probability,
          "aria-label": `Location ${loc.rank}: probability ${pct}, heading ${Math.round(loc.heading_deg)} degrees`,
          "data-tip": `#${loc.rank} · ${pct} · heading ${Math.round(loc.heading_deg)}°`,
        });
        el.dataset.hfov = hfov;
        svg("path", { class: "cone" }, el);
        svg("circle", { class: "loc-dot", r: loc.rank === 1 ? "6" : "4.5" }, el);
        if (loc.rank <= LABELLED_RANKS) {
          const text = svg("text", { class: "loc-label" }, el);
          text.textContent = `${loc.rank} · ${pct}`;
        }
        const select = () => this.handlers.locationSelect(loc.rank);
        el.addEventListener("click", select);
        el.addEventListener("keydown", (event) => {
          if (event.key === "Enter" || event.key === " ") {
            event.preventDefault();
            select();
          }
        });
        this.answerGroup.insertBefore(el, this.answerGroup.firstChild); // rank 1 drawn last, on top
      }
    }
    this.requestRender();
  }

  /** Which ranked location is emphasised (and carries the uncertainty circle). */
  selectLocation(rank) {
    this.selectedRank = rank;
    for (const el of this.answerGroup.querySelectorAll(".location")) {
      el.classList.toggle("selected", Number(el.dataset.rank) === rank);
    }
    this.requestRender();
  }

  /** The position prior {lat, lon, radius_m} drawn as a dashed circle (null: none). */
  setPrior(prior) {
    this.prior = prior;
    this.requestRender();
  }

  /** Fill these buildings (Map of building id -> colour); others return to plain. */
  setHighlights(colours) {
    for (const id of this.highlights.keys()) {
      const path = this.buildingPaths.get(id);
      if (path) {
        path.classList.remove("identified");
        path.style.fill = "";
        path.style.stroke = "";
      }
    }
    this.highlights = new Map(colours);
    for (const [id, colour] of this.highlights) {
      const path = this.buildingPaths.get(id);
      if (path) {
        path.classList.add("identified");
        path.style.fill = colour;
        path.style.stroke = colour;
      }
    }
  }

  buildHeatImage(heatmap) {
    const [rows, cols] = heatmap.shape;
    const values = heatmap.values;
    let max = 0;
    for (const row of values) for (const v of row) max = Math.max(max, v);
    const canvas = document.createElement("canvas");
    canvas.width = cols;
    canvas.height = rows;
    const ctx = canvas.getContext("2d");
    const image = ctx.createImageData(cols, rows);
    for (let r = 0; r < rows; r += 1) {
      for (let c = 0; c < cols; c += 1) {
        const v = values[r][c];
        if (!(v > 0) || !(max > 0)) continue;
        const [red, green, blue, alpha] = heatColor(Math.sqrt(v / max));
        const i = 4 * ((rows - 1 - r) * cols + c); // row 0 of the grid is its southern edge
        image.data[i] = red;
        image.data[i + 1] = green;
        image.data[i + 2] = blue;
        image.data[i + 3] = alpha;
      }
    }
    ctx.putImageData(image, 0, 0);
    const [ox, oy] = this.plane.toLocal(heatmap.origin.lat, heatmap.origin.lon);
    const cell = heatmap.cell_m;
    // outer edges of the grid in local metres: cell (0, 0) is centred on the origin
    return { canvas, left: ox - cell / 2, top: oy + (rows - 0.5) * cell, width: cols * cell, height: rows * cell };
  }

  // --- drawing --------------------------------------------------------------------------------

  render() {
    if (!this.plane) return;
    const s = this.scale;
    const tx = this.width / 2 - this.center[0] * s;
    const ty = this.height / 2 + this.center[1] * s;
    const transform = `matrix(${s} 0 0 ${-s} ${tx} ${ty})`;
    this.buildingGroup.setAttribute("transform", transform);
    this.streets.render(transform, (x, y) => this.toScreen(x, y), s);
    this.renderHeat();
    this.renderPrior();
    this.renderReferences();
    this.renderAnswer();
    for (const layer of this.layers) layer.render();
    this.renderScaleBar();
  }

  renderHeat() {
    const canvas = this.parts.heat;
    const dpr = window.devicePixelRatio || 1;
    const w = Math.round(this.width * dpr);
    const h = Math.round(this.height * dpr);
    if (canvas.width !== w || canvas.height !== h) {
      canvas.width = w;
      canvas.height = h;
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, w, h);
    if (!this.heatImage) return;
    const hm = this.heatImage;
    const [x, y] = this.toScreen(hm.left, hm.top);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(hm.canvas, x, y, hm.width * this.scale, hm.height * this.scale);
  }

  renderPrior() {
    this.priorGroup.replaceChildren();
    if (!this.prior || !Number.isFinite(this.prior.lat) || !Number.isFinite(this.prior.lon)) return;
    const [x, y] = this.toScreen(...this.plane.toLocal(this.prior.lat, this.prior.lon));
    const radius = (this.prior.radius_m || 50) * this.scale;
    svg("circle", { class: "prior", cx: x, cy: y, r: radius }, this.priorGroup);
    svg("circle", { class: "prior-center", cx: x, cy: y, r: 3 }, this.priorGroup);
    const label = svg("text", { class: "prior-label", x: x, y: y - radius - 5, "text-anchor": "middle" }, this.priorGroup);
    label.textContent = "position prior";
  }

  referencePose(ref) {
    const est = ref.estimated;
    const hasEst = est && Number.isFinite(est.lat) && Number.isFinite(est.lon);
    const lat = hasEst ? est.lat : ref.position.lat;
    const lon = hasEst ? est.lon : ref.position.lon;
    const heading = est && Number.isFinite(est.heading_deg) ? est.heading_deg : ref.prior_heading_deg;
    return { lat, lon, heading, hasEst };
  }

  renderReferences() {
    this.poseGroup.replaceChildren();
    for (const ref of this.references) {
      const el = this.referenceEls.get(ref.id);
      if (!el) continue;
      const pose = this.referencePose(ref);
      const [x, y] = this.toScreen(...this.plane.toLocal(pose.lat, pose.lon));
      const selected = ref.id === this.selectedReferenceId;
      el.classList.toggle("selected", selected);
      const cone = el.querySelector(".cone");
      if (Number.isFinite(pose.heading)) {
        const fov = horizontalFovDeg(ref.focal_length_35mm, ref.width, ref.height);
        cone.setAttribute("d", wedgePath(x, y, pose.heading, fov, selected ? SELECTED_REFERENCE_CONE_PX : REFERENCE_CONE_PX));
      } else {
        cone.setAttribute("d", "");
      }
      const dot = el.querySelector(".dot");
      dot.setAttribute("cx", x);
      dot.setAttribute("cy", y);
      if (selected) {
        // the GPS tag against the estimated position
        const [gx, gy] = this.toScreen(...this.plane.toLocal(ref.position.lat, ref.position.lon));
        if (pose.hasEst) svg("line", { class: "gps-offset", x1: gx, y1: gy, x2: x, y2: y }, this.poseGroup);
        svg("circle", { class: "gps-tag", cx: gx, cy: gy, r: 7 }, this.poseGroup);
        const text = svg("text", { class: "gps-label", x: gx + 10, y: gy + 4 }, this.poseGroup);
        text.textContent = "GPS tag";
      }
    }
  }

  renderAnswer() {
    for (const el of this.answerGroup.querySelectorAll(".uncertainty")) el.remove();
    if (!this.answer) return;
    const labels = [];
    for (const el of this.answerGroup.querySelectorAll(".location")) {
      const rank = Number(el.dataset.rank);
      const [x, y] = this.toScreen(...this.plane.toLocal(Number(el.dataset.lat), Number(el.dataset.lon)));
      const heading = Number(el.dataset.heading);
      const length = rank === 1 ? TOP_CONE_PX : OTHER_CONE_PX;
      el.querySelector(".cone").setAttribute("d", wedgePath(x, y, heading, Number(el.dataset.hfov), length));
      const dot = el.querySelector(".loc-dot");
      dot.setAttribute("cx", x);
      dot.setAttribute("cy", y);
      const label = el.querySelector(".loc-label");
      if (label) labels.push({ label, x, y, heading, rank });
    }
    this.placeLabels(labels);
    const loc = this.answer.result.locations.find((l) => l.rank === this.selectedRank);
    const radius = loc ? Number(loc.uncertainty_radius_m) : NaN;
    if (loc && Number.isFinite(radius) && radius > 0) {
      const [x, y] = this.toScreen(...this.plane.toLocal(loc.lat, loc.lon));
      const circle = svg("circle", { class: "uncertainty", cx: x, cy: y, r: radius * this.scale });
      circle.dataset.radiusM = radius;
      circle.dataset.rank = loc.rank;
      this.answerGroup.insertBefore(circle, this.answerGroup.firstChild);
    }
  }

  /** Put each rank label beside its marker where it overlaps no better-ranked label, no location dot and
   * not the best location's cone (behind the camera first, so it never covers its own cone); a label with
   * no free place is hidden (the table and the marker's tooltip still give it). */
  placeLabels(labels) {
    // keep clear of the best location's view cone and of every location's dot
    const placed = [...this.answerGroup.querySelectorAll(".location.top .cone, .loc-dot")].map((el) => el.getBBox());
    labels.sort((a, b) => a.rank - b.rank);
    for (const { label, x, y, heading } of labels) {
      const back = ((heading + 180) * Math.PI) / 180;
      const candidates = [
        [16 * Math.sin(back), -16 * Math.cos(back)],
        [12, -12],
        [-12, -12],
        [12, 16],
        [-12, 16],
      ];
      label.removeAttribute("visibility");
      let free = false;
      for (const [dx, dy] of candidates) {
        label.setAttribute("x", x + dx);
        label.setAttribute("y", y + dy + 4);
        label.setAttribute("text-anchor", dx < -4 ? "end" : dx > 4 ? "start" : "middle");
        const box = label.getBBox();
        if (!placed.some((p) => box.x < p.x + p.width && p.x < box.x + box.width && box.y < p.y + p.height && p.y < box.y + box.height)) {
          placed.push(box);
          free = true;
          break;
        }
      }
      if (!free) label.setAttribute("visibility", "hidden");
    }
  }

  renderScaleBar() {
    const metres = niceLength(110 / this.scale);
    this.parts.scaleLine.style.width = `${metres * this.scale}px`;
    this.parts.scaleLabel.textContent = formatDistance(metres);
  }

  // --- interaction ----------------------------------------------------------------------------

  installInteraction() {
    const root = this.root;
    let drag = null;
    root.addEventListener("pointerdown", (event) => {
      if (event.button !== 0) return;
      drag = { id: event.pointerId, x: event.clientX, y: event.clientY, moved: false };
    });
    root.addEventListener("pointermove", (event) => {
      this.updateTooltip(event);
      if (!drag || event.pointerId !== drag.id) return;
      const dx = event.clientX - drag.x;
      const dy = event.clientY - drag.y;
      if (!drag.moved && Math.hypot(dx, dy) < DRAG_THRESHOLD_PX) return;
      if (!drag.moved) {
        drag.moved = true;
        root.setPointerCapture(event.pointerId);
        root.classList.add("dragging");
      }
      this.panBy(dx, dy);
      drag.x = event.clientX;
      drag.y = event.clientY;
    });
    const endDrag = (event) => {
      if (!drag || event.pointerId !== drag.id) return;
      const wasClick = !drag.moved;
      if (drag.moved) root.releasePointerCapture(event.pointerId);
      root.classList.remove("dragging");
      drag = null;
      if (wasClick && event.type === "pointerup" && this.plane && !event.target.closest(".reference, .location")) {
        this.handlers.mapClick(...this.unproject(event.clientX, event.clientY));
      }
    };
    root.addEventListener("pointerup", endDrag);
    root.addEventListener("pointercancel", endDrag);
    root.addEventListener("pointerleave", () => this.hideTooltip());
    root.addEventListener(
      "wheel",
      (event) => {
        event.preventDefault();
        const rect = root.getBoundingClientRect();
        const delta = event.deltaMode === 1 ? event.deltaY * 16 : event.deltaY;
        this.zoomBy(Math.exp(-delta * 0.0015), [event.clientX - rect.left, event.clientY - rect.top]);
      },
      { passive: false },
    );
    root.addEventListener("keydown", (event) => {
      if (event.target !== root) return; // markers handle their own keys
      const step = event.shiftKey ? 240 : 80;
      const actions = {
        ArrowLeft: () => this.panBy(step, 0),
        ArrowRight: () => this.panBy(-step, 0),
        ArrowUp: () => this.panBy(0, step),
        ArrowDown: () => this.panBy(0, -step),
        "+": () => this.zoomBy(1.4),
        "=": () => this.zoomBy(1.4),
        "-": () => this.zoomBy(1 / 1.4),
        0: () => this.fitMap(),
      };
      const action = actions[event.key];
      if (action) {
        event.preventDefault();
        action();
      }
    });
  }

  updateTooltip(event) {
    const tip = this.parts.tooltip;
    const target = event.target.closest ? event.target.closest("[data-tip]") : null;
    if (!target || (event.buttons & 1) === 1) {
      this.hideTooltip();
      return;
    }
    const rect = this.root.parentElement.getBoundingClientRect();
    tip.textContent = target.dataset.tip;
    tip.hidden = false;
    const x = Math.min(event.clientX - rect.left + 14, rect.width - tip.offsetWidth - 8);
    tip.style.left = `${x}px`;
    tip.style.top = `${event.clientY - rect.top + 16}px`;
  }

  hideTooltip() {
    this.parts.tooltip.hidden = true;
  }
}
