"""Places in the map itself: names, addresses, streets and landmarks to a position prior, offline.

:func:`place_index` gathers what the loaded :class:`~geoloc.maps.model.CityMap` names: building names
(``name``, ``name:*``, ``alt_name``...), addresses (``addr:street`` + ``addr:housenumber``, else
``addr:place`` / ``addr:housename``), named streets (``highway=*`` ways) and landmarks (named points).
Entries of one kind with the same name that lie close together (the ways of one street, the parts of one
address) are one place. :meth:`PlaceIndex.search` ranks the places for a text; :func:`resolve_place` says
whether a text names one place, several (ambiguous) or none.

Matching is accent- and case-insensitive (Unicode NFKD without combining marks, casefold: ä -> a,
ß -> ss; ``str.`` -> ``strasse``), by tokens, fuzzy (difflib's ratio, stdlib): every query token is matched
to its best token of the place's name (numbers only exactly; the last token also as a prefix, for
autocompletion); the score is the mean of those matches, lowered a little for name tokens the query
left out (so "Aleksanterinkatu" is the street rather than one of its addresses); a house number the map
does not hold falls back to the street, scored :data:`STREET_FALLBACK`.

Each place carries a disc that covers it (centre, ``radius_m``, about 2 sigma as everywhere): a building or
an address is the footprint's centroid with a radius reaching its farthest corner plus :data:`VIEW_MARGIN_M`
(photos of a building are taken from its street); a street is the centroid of its centreline with a radius
covering all of it; a landmark point gets :data:`POINT_RADIUS_M`. The prior the query stage uses follows the
place's shape (``geometry``, :meth:`Place.prior_shape`): within :data:`VIEW_MARGIN_M` of a building's walls,
within :data:`STREET_MARGIN_M` of a street's centreline; only a landmark point keeps its disc.
Areas (squares, parks as polygons) are not read yet: a square is found through its buildings and streets.
"""

from __future__ import annotations

import bisect
import dataclasses
import difflib
import math
import re
import unicodedata
from collections import defaultdict
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np
import shapely
from shapely.geometry import LineString

from geoloc.maps.model import CityMap

PlaceKind = Literal["address", "building", "landmark", "street"]
VIEW_MARGIN_M = 30.0
"""Added to a building's radius: a photo of it is taken from within about this far of its walls."""
STREET_MARGIN_M = 20.0
"""A photo taken on a street is within about this far (2 sigma) of its centreline (carriageway and pavements)."""
POINT_RADIUS_M = 60.0
"""The prior radius of a landmark known only as a point."""
MIN_SCORE = 0.75
"""Below this a place does not match a text at all."""
STREET_FALLBACK = 0.9
"""A street's score for a text naming one of its addresses that the map lacks ("Mannerheimintie 9999")."""
AMBIGUITY_MARGIN = 0.05
"""Places scoring within this of the best one are as good a match (then ambiguous if elsewhere)."""
SAME_PLACE_M = 50.0
"""Equally good matches closer than this plus the larger of their radii are the same place (a building and
its landmark point, a street and the station named after it)."""
_GROUP_GAP_M = {"street": 150.0, "address": 30.0, "building": 30.0, "landmark": 30.0}
"""Same-named entries of one kind within this gap (m) are one place."""
_KIND_ORDER = {"address": 0, "building": 1, "street": 2, "landmark": 3}
"""Equal scores: the smaller, better-defined place first (a landmark point named after its street loses)."""
_TOKEN = re.compile(r"\w+")
_NAME_KEYS = ("name", "alt_name", "official_name", "short_name", "old_name")
_MIN_TOKEN_RATIO = 0.75


def normalize(text: str) -> str:
    """Lower-case, accent-free, space-separated words of ``text`` (NFKD, combining marks dropped, casefold)."""
    decomposed = unicodedata.normalize("NFKD", text)
    plain = "".join(c for c in decomposed if not unicodedata.combining(c)).casefold()
    words = _TOKEN.findall(plain.replace("_", " "))
    return " ".join(w[:-3] + "strasse" if w.endswith("str") else w for w in words)


@dataclass(frozen=True)
class Place:
    """A place of the map: its name, kind, the prior it gives (lat/lon WGS84 degrees, radius_m about 2 sigma).

    x_m, y_m: the centre in the map's local frame; building_id: the building (address, building), else None;
    score: how well it matched the text (0-1; 1 for an exact name); geometry: its footprint, centreline or
    point (local metres).
    """

    name: str
    kind: PlaceKind
    lat: float
    lon: float
    radius_m: float
    x_m: float
    y_m: float
    building_id: int | None = None
    score: float = 0.0
    geometry: shapely.Geometry | None = field(default=None, compare=False, repr=False)

    def prior_shape(self) -> tuple[shapely.Geometry, float] | None:
        """The shape a photo of this place is taken near and how near (m, about 2 sigma); None: use the disc."""
        if self.geometry is None or self.kind == "landmark":
            return None
        return self.geometry, STREET_MARGIN_M if self.kind == "street" else VIEW_MARGIN_M


@dataclass(frozen=True)
class PlaceMatch:
    """What a text names: ``status`` "found" (``place``), "ambiguous" (``candidates``) or "unknown"."""

    status: Literal["found", "ambiguous", "unknown"]
    place: Place | None = None
    candidates: list[Place] = field(default_factory=list)


@dataclass
class _Entry:
    name: str
    kind: PlaceKind
    geometry: shapely.Geometry
    building_id: int | None


@dataclass
class PlaceIndex:
    """The places of one map and a token index over their names (build with :func:`place_index`)."""

    city_map: CityMap
    places: list[Place]
    tokens: list[tuple[str, ...]]
    by_token: dict[str, list[int]]

    @cached_property
    def vocabulary(self) -> list[str]:
        """The sorted distinct name tokens (for prefix and fuzzy look-ups)."""
        return sorted(self.by_token)

    def search(self, text: str, limit: int = 10, prefix: bool = True) -> list[Place]:
        """The best places for ``text`` (score >= :data:`MIN_SCORE`), best first, at most ``limit``.

        prefix: let the last word match as a prefix (autocompletion while typing).
        """
        query = normalize(text).split()
        if not query:
            return []
        scored = [(score, i) for i in self._candidates(query, prefix) if (score := self._score(query, i, prefix))]
        scored = [(s, i) for s, i in scored if s >= MIN_SCORE]
        scored.sort(key=lambda si: (-si[0], _KIND_ORDER[self.places[si[1]].kind], self.places[si[1]].name))
        out = []
        for score, i in scored[:limit]:
            p = self.places[i]
            out.append(dataclasses.replace(p, score=round(score, 3)))
        return out

    def _close_tokens(self, token: str, prefix: bool) -> set[str]:
        if _is_number(token):
            return {token} if token in self.by_token else set()
        found = set(difflib.get_close_matches(token, self.vocabulary, n=20, cutoff=_MIN_TOKEN_RATIO))
        if prefix and len(token) >= 2:
            start = bisect.bisect_left(self.vocabulary, token)
            for word in self.vocabulary[start : start + 200]:
                if not word.startswith(token):
                    break
                found.add(word)
        return found

    def _candidates(self, query: list[str], prefix: bool) -> set[int]:
        """Places sharing a (close) word with the query: its words' if any are not numbers, else its numbers'."""
        words = [t for t in query if not _is_number(t)] or query
        out: set[int] = set()
        for n, token in enumerate(words):
            for word in self._close_tokens(token, prefix and n == len(words) - 1 and token == query[-1]):
                out.update(self.by_token[word])
        return out

    def _score(self, query: list[str], index: int, prefix: bool) -> float:
        names = self.tokens[index]
        factor = 1.0
        if self.places[index].kind == "street" and any(not _is_number(t) for t in query):
            # A street has no house numbers: an address the map lacks falls back to its street, below any
            # address that matches.
            if any(_is_number(t) for t in query):
                factor = STREET_FALLBACK
            query = [t for t in query if not _is_number(t)]
        matched: set[int] = set()
        total = 0.0
        for n, token in enumerate(query):
            best, best_j = 0.0, -1
            for j, word in enumerate(names):
                sim = _similarity(token, word, prefix and n == len(query) - 1)
                if sim > best:
                    best, best_j = sim, j
            if best_j >= 0:
                matched.add(best_j)
            total += best
        coverage = len(matched) / len(names)
        return factor * (total / len(query)) * (0.8 + 0.2 * coverage)


def _is_number(token: str) -> bool:
    return any(c.isdigit() for c in token)


def _similarity(token: str, word: str, prefix: bool) -> float:
    """How well a query token matches a name token (0-1): numbers exactly, words fuzzily (and as prefix)."""
    if token == word:
        return 1.0
    if _is_number(token) or _is_number(word):
        return 0.0
    if prefix and len(token) >= 2 and word.startswith(token):
        return 0.9 + 0.1 * len(token) / len(word)
    ratio = difflib.SequenceMatcher(None, token, word).ratio()
    return ratio if ratio >= _MIN_TOKEN_RATIO else 0.0


def _building_entries(city_map: CityMap) -> list[_Entry]:
    entries = []
    for b in city_map.buildings:
        names = {b.tags[k] for k in b.tags if k in _NAME_KEYS or k.startswith("name:")} | (
            {b.name} if b.name else set()
        )
        entries += [_Entry(name, "building", b.polygon, b.building_id) for name in sorted(names) if name.strip()]
        street, number = b.tags.get("addr:street") or b.tags.get("addr:place"), b.tags.get("addr:housenumber")
        if street and number:
            entries.append(_Entry(f"{street} {number}", "address", b.polygon, b.building_id))
        elif b.tags.get("addr:housename"):
            entries.append(_Entry(b.tags["addr:housename"], "address", b.polygon, b.building_id))
    return entries


def _street_entries(city_map: CityMap) -> list[_Entry]:
    return [
        _Entry(name, "street", LineString(line), None)
        for name, line in zip(city_map.street_names, city_map.streets, strict=True)
        if name.strip() and len(line) >= 2
    ]


def _landmark_entries(city_map: CityMap) -> list[_Entry]:
    if not len(city_map.landmark_names):
        return []
    lonlat = np.asarray(city_map.landmark_lonlat, dtype=float)
    x, y = city_map.frame.to_local(lonlat[:, 1], lonlat[:, 0])
    return [
        _Entry(name, "landmark", shapely.points(px, py), None)
        for name, px, py in zip(
            city_map.landmark_names, np.atleast_1d(x).tolist(), np.atleast_1d(y).tolist(), strict=True
        )
        if name.strip()
    ]


def _groups(entries: list[_Entry], gap_m: float) -> list[list[_Entry]]:
    """Same-named entries split into groups whose members lie within ``gap_m`` of another member."""
    parent = list(range(len(entries)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    geometries = np.array([e.geometry for e in entries], dtype=object)
    tree = shapely.STRtree(geometries)
    left, right = tree.query(geometries, predicate="dwithin", distance=gap_m)
    for a, b in zip(left.tolist(), right.tolist(), strict=True):
        parent[root(a)] = root(b)
    groups: dict[int, list[_Entry]] = defaultdict(list)
    for i, entry in enumerate(entries):
        groups[root(i)].append(entry)
    return list(groups.values())


def _place(city_map: CityMap, group: list[_Entry]) -> Place:
    """One place from a group of entries: its centre and the radius of its prior (see the module)."""
    first = group[0]
    geometry = shapely.union_all([e.geometry for e in group]) if len(group) > 1 else first.geometry
    centre = shapely.centroid(geometry)
    cx, cy = float(shapely.get_x(centre)), float(shapely.get_y(centre))
    coords = shapely.get_coordinates(geometry)
    reach = float(np.max(np.hypot(coords[:, 0] - cx, coords[:, 1] - cy))) if len(coords) else 0.0
    if first.kind == "street":
        radius = max(reach, POINT_RADIUS_M / 2)
    elif first.kind == "landmark" and reach < 1.0:
        radius = POINT_RADIUS_M
    else:
        radius = reach + VIEW_MARGIN_M
    lat, lon = city_map.frame.to_wgs84(cx, cy)
    radius = math.ceil(radius * 10) / 10  # rounded up: the disc still covers the place
    building_id = first.building_id if len({e.building_id for e in group}) == 1 else None
    return Place(
        first.name, first.kind, round(float(lat), 7), round(float(lon), 7), radius, cx, cy, building_id, 0.0, geometry
    )


def place_index(city_map: CityMap) -> PlaceIndex:
    """The places of ``city_map`` (buildings, addresses, streets, landmarks) with their token index."""
    by_name: dict[tuple[str, str], list[_Entry]] = defaultdict(list)
    for entry in _building_entries(city_map) + _street_entries(city_map) + _landmark_entries(city_map):
        key = normalize(entry.name)
        if key:
            by_name[(entry.kind, key)].append(entry)
    places: list[Place] = []
    tokens: list[tuple[str, ...]] = []
    by_token: dict[str, list[int]] = defaultdict(list)
    for (kind, key), entries in sorted(by_name.items()):
        for group in _groups(entries, _GROUP_GAP_M[kind]):
            words = tuple(key.split())
            for word in set(words):
                by_token[word].append(len(places))
            places.append(_place(city_map, group))
            tokens.append(words)
    return PlaceIndex(city_map, places, tokens, dict(by_token))


def find_place(index: PlaceIndex, name: str, kind: str, x_m: float, y_m: float) -> Place | None:
    """The place named exactly ``name`` of ``kind`` nearest to (x_m, y_m) (local metres); None if none.

    How a worker gets back the place a query was given by (its stored name, kind and centre).
    """
    words = normalize(name).split()
    found = set.intersection(*(set(index.by_token.get(w, ())) for w in words)) if words else set()
    same = [index.places[i] for i in found if index.places[i].name == name and index.places[i].kind == kind]
    return min(same, key=lambda p: math.hypot(p.x_m - x_m, p.y_m - y_m), default=None)


def resolve_place(index: PlaceIndex, text: str) -> PlaceMatch:
    """Whether ``text`` names one place of the map, several equally well (ambiguous), or none.

    The best match wins unless another place scoring within :data:`AMBIGUITY_MARGIN` lies elsewhere (farther
    than the larger of the two radii plus :data:`SAME_PLACE_M`): then the text is ambiguous and the candidates are
    those places (nearby equals folded into the best one). No prefix matching: the text is taken as written.
    """
    ranked = index.search(text, limit=50, prefix=False)
    if not ranked:
        return PlaceMatch("unknown")
    best = ranked[0]
    equals = [p for p in ranked if p.score >= best.score - AMBIGUITY_MARGIN]
    elsewhere: list[Place] = []
    for p in equals[1:]:  # a candidate elsewhere lies outside the disc of every one listed
        far_from_all = all(
            np.hypot(p.x_m - q.x_m, p.y_m - q.y_m) > max(p.radius_m, q.radius_m) + SAME_PLACE_M
            for q in [best, *elsewhere]
        )
        if far_from_all:
            elsewhere.append(p)
    if elsewhere:
        return PlaceMatch("ambiguous", candidates=[best, *elsewhere][:10])
    return PlaceMatch("found", place=best)
