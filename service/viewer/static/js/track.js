// A track (GET /v1/tracks/{id}) on the map: its trajectory, each frame's view cone and uncertainty circle, and
// a stepper through the frames (the selected frame emphasised, its facts in the panel).

import { svg, wedgePath } from "./svg.js";

const FRAME_CONE_PX = 34;
const SELECTED_CONE_PX = 56;

export class TrackLayer {
  /** @param {import("./mapview.js").MapView} view the map view to draw into (its overlay layer) */
  constructor(view, overlay) {
    this.view = view;
    this.group = svg("g", { class: "track-layer", role: "group", "aria-label": "Track" }, overlay);
    this.track = null;
    this.frames = [];
    this.selected = 0;
    view.layers.push(this);
  }

  /** A track (TrackOut), or null to clear it. Frames without a pose are listed but not drawn. */
  setTrack(track) {
    this.track = track;
    this.frames = track ? track.frames.filter((f) => f.lat !== null && f.lon !== null && f.heading_deg !== null) : [];
    this.selected = 0;
    this.group.replaceChildren();
    if (this.frames.length) {
      svg("path", { class: "track-line" }, this.group);
      for (const f of this.frames) {
        const el = svg("g", { class: "track-frame", "data-index": f.index, "data-lat": f.lat, "data-lon": f.lon });
        el.dataset.heading = f.heading_deg;
        el.dataset.hfov = f.hfov_deg || 60;
        el.dataset.radiusM = f.uncertainty_radius_m ?? "";
        el.classList.toggle("outlier", Boolean(f.outlier));
        svg("circle", { class: "track-uncertainty" }, el);
        svg("path", { class: "cone" }, el);
        svg("circle", { class: "dot", r: "4.5" }, el);
        this.group.appendChild(el);
      }
    }
    this.select(0);
  }

  /** Emphasise frame number ``i`` (of the drawn frames); returns that frame (or null). */
  select(i) {
    if (!this.frames.length) return null;
    this.selected = Math.max(0, Math.min(this.frames.length - 1, i));
    const wanted = this.frames[this.selected].index;
    for (const el of this.group.querySelectorAll(".track-frame")) {
      el.classList.toggle("selected", Number(el.dataset.index) === wanted);
    }
    this.view.requestRender();
    return this.frames[this.selected];
  }

  /** Local metres of the frames' bounding box with their uncertainty, to fit the view. */
  box() {
    const plane = this.view.plane;
    const xs = [];
    const ys = [];
    for (const f of this.frames) {
      const [x, y] = plane.toLocal(f.lat, f.lon);
      const r = Number(f.uncertainty_radius_m) || 0;
      xs.push(x - r, x + r);
      ys.push(y - r, y + r);
    }
    return [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
  }

  render() {
    if (!this.frames.length || !this.view.plane) return;
    const view = this.view;
    const points = [];
    for (const el of this.group.querySelectorAll(".track-frame")) {
      const [x, y] = view.toScreen(...view.plane.toLocal(Number(el.dataset.lat), Number(el.dataset.lon)));
      points.push([x, y]);
      const selected = el.classList.contains("selected");
      const length = selected ? SELECTED_CONE_PX : FRAME_CONE_PX;
      el.querySelector(".cone").setAttribute("d", wedgePath(x, y, Number(el.dataset.heading), Number(el.dataset.hfov), length));
      const dot = el.querySelector(".dot");
      dot.setAttribute("cx", x);
      dot.setAttribute("cy", y);
      const circle = el.querySelector(".track-uncertainty");
      const radius = Number(el.dataset.radiusM);
      circle.setAttribute("cx", x);
      circle.setAttribute("cy", y);
      circle.setAttribute("r", Number.isFinite(radius) && radius > 0 ? radius * view.scale : 0);
    }
    const d = points.map(([x, y], i) => `${i ? "L" : "M"}${x.toFixed(1)},${y.toFixed(1)}`).join(" ");
    this.group.querySelector(".track-line").setAttribute("d", points.length > 1 ? d : "");
  }
}
