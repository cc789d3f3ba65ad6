// The map's input: drag or arrow keys to pan, the wheel or +/-/0 to zoom, a click (no drag) on the map to pick a
// point, and the tooltip of whatever carries a `data-tip` under the pointer.

const DRAG_THRESHOLD_PX = 4;

/** Wire a MapView's element: pan, zoom, map clicks (its mapClick handler) and tooltips. */
export function installMapInput(view) {
  const root = view.root;
  let drag = null;
  root.addEventListener("pointerdown", (event) => {
    if (event.button !== 0) return;
    drag = { id: event.pointerId, x: event.clientX, y: event.clientY, moved: false };
  });
  root.addEventListener("pointermove", (event) => {
    updateTooltip(view, event);
    if (!drag || event.pointerId !== drag.id) return;
    const dx = event.clientX - drag.x;
    const dy = event.clientY - drag.y;
    if (!drag.moved && Math.hypot(dx, dy) < DRAG_THRESHOLD_PX) return;
    if (!drag.moved) {
      drag.moved = true;
      root.setPointerCapture(event.pointerId);
      root.classList.add("dragging");
    }
    view.panBy(dx, dy);
    drag.x = event.clientX;
    drag.y = event.clientY;
  });
  const endDrag = (event) => {
    if (!drag || event.pointerId !== drag.id) return;
    const wasClick = !drag.moved;
    if (drag.moved) root.releasePointerCapture(event.pointerId);
    root.classList.remove("dragging");
    drag = null;
    if (wasClick && event.type === "pointerup" && view.plane && !event.target.closest(".reference, .location")) {
      view.handlers.mapClick(...view.unproject(event.clientX, event.clientY));
    }
  };
  root.addEventListener("pointerup", endDrag);
  root.addEventListener("pointercancel", endDrag);
  root.addEventListener("pointerleave", () => hideTooltip(view));
  root.addEventListener(
    "wheel",
    (event) => {
      event.preventDefault();
      const rect = root.getBoundingClientRect();
      const delta = event.deltaMode === 1 ? event.deltaY * 16 : event.deltaY;
      view.zoomBy(Math.exp(-delta * 0.0015), [event.clientX - rect.left, event.clientY - rect.top]);
    },
    { passive: false },
  );
  root.addEventListener("keydown", (event) => {
    if (event.target !== root) return; // markers handle their own keys
    const step = event.shiftKey ? 240 : 80;
    const actions = {
      ArrowLeft: () => view.panBy(step, 0),
      ArrowRight: () => view.panBy(-step, 0),
      ArrowUp: () => view.panBy(0, step),
      ArrowDown: () => view.panBy(0, -step),
      "+": () => view.zoomBy(1.4),
      "=": () => view.zoomBy(1.4),
      "-": () => view.zoomBy(1 / 1.4),
      0: () => view.fitMap(),
    };
    const action = actions[event.key];
    if (action) {
      event.preventDefault();
      action();
    }
  });
}

/** Show the tooltip of the element under the pointer that carries a `data-tip` (none while dragging). */
function updateTooltip(view, event) {
  const tip = view.parts.tooltip;
  const target = event.target.closest ? event.target.closest("[data-tip]") : null;
  if (!target || (event.buttons & 1) === 1) {
    hideTooltip(view);
    return;
  }
  const rect = view.root.parentElement.getBoundingClientRect();
  tip.textContent = target.dataset.tip;
  tip.hidden = false;
  const x = Math.min(event.clientX - rect.left + 14, rect.width - tip.offsetWidth - 8);
  tip.style.left = `${x}px`;
  tip.style.top = `${event.clientY - rect.top + 16}px`;
}

/** Hide the map's tooltip. */
function hideTooltip(view) {
  view.parts.tooltip.hidden = true;
}
