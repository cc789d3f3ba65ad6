// Streets under the footprints: centrelines (SVG in local metres, under the footprints' transform) and their
// names (screen pixels, along the street, redrawn on every pan or zoom): one label per name, on the longest
// piece of that street, shown only where the piece is long enough on screen to hold it.

import { svg } from "./svg.js";

const CHAR_PX = 6.5; // about the width of one character of a street name
const LABEL_PAD_PX = 16;

/** Length, the point halfway along and the direction there (deg, counter-clockwise from east) of a polyline. */
function halfway(points) {
  const lengths = points.slice(1).map(([x, y], i) => Math.hypot(x - points[i][0], y - points[i][1]));
  const total = lengths.reduce((a, b) => a + b, 0);
  let left = total / 2;
  for (let i = 0; i < lengths.length; i += 1) {
    if (left <= lengths[i] || i === lengths.length - 1) {
      const [x0, y0] = points[i];
      const [x1, y1] = points[i + 1];
      const f = lengths[i] > 0 ? Math.min(1, left / lengths[i]) : 0;
      return { length: total, x: x0 + f * (x1 - x0), y: y0 + f * (y1 - y0), angle: (Math.atan2(y1 - y0, x1 - x0) * 180) / Math.PI };
    }
    left -= lengths[i];
  }
  return { length: 0, x: points[0][0], y: points[0][1], angle: 0 };
}

export class StreetLayer {
  /** @param {SVGSVGElement} root the footprints' SVG: the streets go first, so they lie under the footprints */
  constructor(root) {
    this.lines = svg("g", { class: "streets" }, root);
    this.names = svg("g", { class: "street-names" }, root);
    this.labels = [];
    this.count = 0;
  }

  /** Streets (GeoJSON LineStrings with a `name` property) in the map's local plane. */
  set(streets, plane) {
    this.lines.replaceChildren();
    this.names.replaceChildren();
    this.labels = [];
    const longest = new Map();
    for (const feature of streets.features) {
      if (!feature.geometry || feature.geometry.type !== "LineString") continue;
      const points = feature.geometry.coordinates.map(([lon, lat]) => plane.toLocal(lat, lon));
      if (points.length < 2) continue;
      const name = (feature.properties || {}).name;
      svg(
        "path",
        { class: "street", d: "M" + points.map(([x, y]) => `${x.toFixed(2)},${y.toFixed(2)}`).join("L"), "data-name": name || "" },
        this.lines,
      );
      if (name) {
        const where = halfway(points);
        if (!longest.has(name) || longest.get(name).length < where.length) longest.set(name, where);
      }
    }
    this.count = this.lines.childElementCount;
    for (const [name, where] of longest) {
      const el = svg("text", { class: "street-name" }, this.names);
      el.textContent = name;
      this.labels.push({ el, name, ...where });
    }
  }

  /** Place the lines under `transform` (the footprints' matrix) and each name where `toScreen` puts it. */
  render(transform, toScreen, scale) {
    this.lines.setAttribute("transform", transform);
    for (const label of this.labels) {
      const fits = label.length * scale >= label.name.length * CHAR_PX + LABEL_PAD_PX;
      label.el.setAttribute("visibility", fits ? "visible" : "hidden");
      if (!fits) continue;
      const [sx, sy] = toScreen(label.x, label.y);
      let angle = -label.angle; // screen y points down
      if (angle > 90) angle -= 180;
      if (angle < -90) angle += 180; // never upside down
      label.el.setAttribute("transform", `translate(${sx.toFixed(1)} ${sy.toFixed(1)}) rotate(${angle.toFixed(1)})`);
    }
  }
}
