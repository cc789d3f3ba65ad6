// The place search box of the query form: autocompletes from GET /v1/maps/{id}/places and keeps the
// chosen place, whose name is sent as the query's `place` field (the service resolves it again).

import { getJson } from "./api.js";

const DEBOUNCE_MS = 150;
const LIMIT = 8;

/**
 * Wire the search input and its suggestion list.
 * mapId(): the current map's id (null: none); onChoose(place | null): a place was chosen or the box cleared.
 */
export function installPlaceSearch(input, list, mapId, onChoose) {
  let timer = 0;
  let token = 0;
  let places = [];
  let active = -1;

  const close = () => {
    list.replaceChildren();
    list.hidden = true;
    input.setAttribute("aria-expanded", "false");
    active = -1;
  };

  const choose = (place) => {
    input.value = place.name;
    input.dataset.placeKind = place.kind;
    close();
    onChoose(place);
  };

  const highlight = (index) => {
    active = index;
    list.querySelectorAll("li").forEach((li, i) => li.setAttribute("aria-selected", String(i === index)));
  };

  const show = (found) => {
    places = found;
    list.replaceChildren(
      ...found.map((place, i) => {
        const li = document.createElement("li");
        li.setAttribute("role", "option");
        li.id = `place-option-${i}`;
        li.dataset.kind = place.kind;
        li.textContent = `${place.name} · ${place.kind}`;
        li.addEventListener("mousedown", (event) => {
          event.preventDefault(); // keep the focus in the input
          choose(place);
        });
        return li;
      }),
    );
    list.hidden = found.length === 0;
    input.setAttribute("aria-expanded", String(found.length > 0));
    active = -1;
  };

  const search = async () => {
    const q = input.value.trim();
    const id = mapId();
    const mine = ++token;
    if (!q || id == null) return close();
    try {
      const body = await getJson(`v1/maps/${id}/places?q=${encodeURIComponent(q)}&limit=${LIMIT}`);
      if (mine === token) show(body.places);
    } catch {
      if (mine === token) close();
    }
  };

  input.addEventListener("input", () => {
    delete input.dataset.placeKind;
    onChoose(null);
    clearTimeout(timer);
    timer = setTimeout(search, DEBOUNCE_MS);
  });
  input.addEventListener("keydown", (event) => {
    if (list.hidden) return;
    if (event.key === "ArrowDown" || event.key === "ArrowUp") {
      event.preventDefault();
      const step = event.key === "ArrowDown" ? 1 : -1;
      highlight((active + step + places.length) % places.length);
    } else if (event.key === "Enter" && active >= 0) {
      event.preventDefault();
      choose(places[active]);
    } else if (event.key === "Escape") {
      event.stopPropagation();
      close();
    }
  });
  input.addEventListener("blur", () => setTimeout(close, 100));
  return { close };
}
