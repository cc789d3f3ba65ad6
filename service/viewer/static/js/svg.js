// SVG helpers shared by the map's layers (mapview.js, streets.js, track.js, answer_markers.js): an element
// maker and the view-cone wedge.

const SVG_NS = "http://www.w3.org/2000/svg";

/** A new SVG element with these attributes, appended to `parent` when one is given. */
export function svg(tag, attrs = {}, parent = null) {
  const el = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  if (parent) parent.appendChild(el);
  return el;
}

/** A view cone's SVG path: apex at (x, y) in screen pixels, centred on a compass heading, fovDeg wide. */
export function wedgePath(x, y, headingDeg, fovDeg, length) {
  const a0 = ((headingDeg - fovDeg / 2) * Math.PI) / 180;
  const a1 = ((headingDeg + fovDeg / 2) * Math.PI) / 180;
  const p0 = [x + length * Math.sin(a0), y - length * Math.cos(a0)];
  const p1 = [x + length * Math.sin(a1), y - length * Math.cos(a1)];
  const f = (v) => v.toFixed(1);
  return `M${f(x)},${f(y)} L${f(p0[0])},${f(p0[1])} A${length},${length} 0 0 1 ${f(p1[0])},${f(p1[1])} Z`;
}
