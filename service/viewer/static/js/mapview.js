// The map: streets and building footprints (SVG in metres under one transform; street names in pixels), the
// probability heatmap (heatmap.js) and an overlay in screen pixels (references, the prior, the answer's ranked
// locations and uncertainty circle: answer_markers.js) redrawn on every pan or zoom. Input (pan, zoom, clicks,
// tooltips): map_input.js; more layers: streets.js, track.js; the SVG helpers they share: svg.js.

import { addLocationMarkers, renderLocations } from "./answer_markers.js";
import { LocalPlane, formatDistance, horizontalFovDeg, niceLength } from "./geo.js";
import { drawHeat, heatImage } from "./heatmap.js";
import { installMapInput } from "./map_input.js";
import { StreetLayer } from "./streets.js";
import { svg, wedgePath } from "./svg.js";

const MAX_SCALE_PX_PER_M = 40;
const REFERENCE_CONE_PX = 18;
const SELECTED_REFERENCE_CONE_PX = 30;

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

    installMapInput(this);
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
      this.heatImage = heatImage(this.answer.result.heatmap, this.plane);
      addLocationMarkers(this.answerGroup, this.answer.result, (rank) => this.handlers.locationSelect(rank));
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

  // --- drawing --------------------------------------------------------------------------------

  render() {
    if (!this.plane) return;
    const s = this.scale;
    const tx = this.width / 2 - this.center[0] * s;
    const ty = this.height / 2 + this.center[1] * s;
    const transform = `matrix(${s} 0 0 ${-s} ${tx} ${ty})`;
    this.buildingGroup.setAttribute("transform", transform);
    this.streets.render(transform, (x, y) => this.toScreen(x, y), s);
    drawHeat(this.parts.heat, this.heatImage, this);
    this.renderPrior();
    this.renderReferences();
    renderLocations(this);
    for (const layer of this.layers) layer.render();
    this.renderScaleBar();
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

  renderScaleBar() {
    const metres = niceLength(110 / this.scale);
    this.parts.scaleLine.style.width = `${metres * this.scale}px`;
    this.parts.scaleLabel.textContent = formatDistance(metres);
  }
}
