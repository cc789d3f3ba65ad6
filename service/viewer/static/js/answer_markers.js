// The answer on the map: a marker per ranked location (view cone, dot and, for the first three, a rank label placed
// where it covers nothing better ranked) and the selected location's uncertainty circle, in screen pixels.

import { svg, wedgePath } from "./svg.js";

const TOP_CONE_PX = 48;
const OTHER_CONE_PX = 30;
const LABELLED_RANKS = 3;

/** Fill `group` with the markers of an answer's ranked locations (rank 1 last, on top); onSelect(rank) on a click. */
export function addLocationMarkers(group, result, onSelect) {
  const hfov = result.camera?.hfov_deg || 60;
  for (const loc of result.locations) {
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
    const select = () => onSelect(loc.rank);
    el.addEventListener("click", select);
    el.addEventListener("keydown", (event) => {
      if (event.key === "Enter" || event.key === " ") {
        event.preventDefault();
        select();
      }
    });
    group.insertBefore(el, group.firstChild); // rank 1 drawn last, on top
  }
}

/** Place the markers at the view's pan and zoom, and the selected rank's uncertainty circle (MapView.render). */
export function renderLocations(view) {
  const group = view.answerGroup;
  for (const el of group.querySelectorAll(".uncertainty")) el.remove();
  if (!view.answer) return;
  const labels = [];
  for (const el of group.querySelectorAll(".location")) {
    const rank = Number(el.dataset.rank);
    const [x, y] = view.toScreen(...view.plane.toLocal(Number(el.dataset.lat), Number(el.dataset.lon)));
    const heading = Number(el.dataset.heading);
    const length = rank === 1 ? TOP_CONE_PX : OTHER_CONE_PX;
    el.querySelector(".cone").setAttribute("d", wedgePath(x, y, heading, Number(el.dataset.hfov), length));
    const dot = el.querySelector(".loc-dot");
    dot.setAttribute("cx", x);
    dot.setAttribute("cy", y);
    const label = el.querySelector(".loc-label");
    if (label) labels.push({ label, x, y, heading, rank });
  }
  placeLabels(group, labels);
  const loc = view.answer.result.locations.find((l) => l.rank === view.selectedRank);
  const radius = loc ? Number(loc.uncertainty_radius_m) : NaN;
  if (loc && Number.isFinite(radius) && radius > 0) {
    const [x, y] = view.toScreen(...view.plane.toLocal(loc.lat, loc.lon));
    const circle = svg("circle", { class: "uncertainty", cx: x, cy: y, r: radius * view.scale });
    circle.dataset.radiusM = radius;
    circle.dataset.rank = loc.rank;
    group.insertBefore(circle, group.firstChild);
  }
}

/** Put each rank label beside its marker where it overlaps no better-ranked label, no location dot and
 * not the best location's cone (behind the camera first, so it never covers its own cone); a label with
 * no free place is hidden (the table and the marker's tooltip still give it). */
function placeLabels(group, labels) {
  // keep clear of the best location's view cone and of every location's dot
  const placed = [...group.querySelectorAll(".location.top .cone, .loc-dot")].map((el) => el.getBBox());
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
