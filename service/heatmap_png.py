"""A query's heat map as a picture that stands alone (``GET /v1/queries/{id}/heatmap.png``).

North up, in the local East-North metres of the map the query was answered on. Drawn bottom to top: the
map's streets (:attr:`geoloc.maps.CityMap.streets`), the probability of each grid cell (never smoothed: one
block per cell, only non-zero cells tinted, see-through, on the ``inferno`` ramp by the square root of the
cell's share of the largest value, as the viewer does), the building footprints (opaque: a camera stands
outside them), the top :data:`MAX_CONES` poses as view cones (apex at the pose, opening the answer's
horizontal field of view, :data:`CONE_LENGTH_M` long; rank 1 in dark blue, on top) and a north arrow. Below
the map a footer holds the colour bar (probability per cell), a scale bar and the map data's attribution
(bottom right).

The extent is the heat map's grid (``result.heatmap``: ``origin_local_m`` is the centre of cell (0, 0),
``cell_m`` its size, rows south to north) and the view cones, with :data:`MARGIN_M` around, made square. Only
Pillow and numpy draw it (no plotting library in the service's runtime).
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
import shapely
from PIL import Image, ImageDraw, ImageFont
from shapely.geometry import MultiPolygon, Polygon

from contracts.answers import QueryResult
from geoloc.maps import CityMap

SIZE_PX = 800
"""Width and height of the map panel (pixels); the PNG is this wide and :data:`FOOTER_PX` taller."""
FOOTER_PX = 72
CONE_LENGTH_M = 40.0
"""How far a view cone reaches from its pose (m)."""
MARGIN_M = 20.0
"""Room around the grid and the poses (m)."""
MAX_CONES = 5

BACKGROUND = (250, 250, 246)
STREET = (208, 210, 222)
STREET_WIDTH_M = 4.0
FOOTPRINT_FILL = (150, 146, 138)
FOOTPRINT_EDGE = (96, 92, 86)
CONE_COLORS = ((16, 52, 150), (70, 130, 215), (70, 130, 215), (70, 130, 215), (70, 130, 215))
"""Rank 1 dark blue, the others a lighter blue."""
TEXT = (30, 30, 30)
INFERNO = np.array([(0, 0, 4), (87, 16, 110), (188, 55, 84), (249, 142, 9), (252, 255, 164)], dtype=float)
"""Anchors of the ``inferno`` colour ramp at 0, 1/4, 1/2, 3/4 and 1."""


def ramp(t: np.ndarray) -> np.ndarray:
    """``inferno`` colours (..., 3) uint8 of values ``t`` in [0, 1]."""
    pos = np.clip(np.asarray(t, dtype=float), 0.0, 1.0) * (len(INFERNO) - 1)
    lo = np.minimum(pos.astype(int), len(INFERNO) - 2)
    frac = (pos - lo)[..., None]
    colors: np.ndarray = (INFERNO[lo] * (1 - frac) + INFERNO[lo + 1] * frac).round().astype(np.uint8)
    return colors


@dataclass(frozen=True)
class View:
    """Local metres -> map-panel pixels: a square extent from (``min_x``, ``min_y``), ``m_per_px`` metres a pixel."""

    min_x: float
    min_y: float
    m_per_px: float
    size_px: int = SIZE_PX

    @classmethod
    def around(cls, result: QueryResult, cones_m: list[np.ndarray], size_px: int = SIZE_PX) -> View:
        """The square view of the heat map's grid and the view cones (local m), :data:`MARGIN_M` around."""
        heat = result.heatmap
        half = heat.cell_m / 2.0
        x0, y0 = heat.origin_local_m[0] - half, heat.origin_local_m[1] - half
        points = np.concatenate([np.zeros((0, 2)), *cones_m])
        xs = [x0, x0 + heat.shape[1] * heat.cell_m, *points[:, 0]]
        ys = [y0, y0 + heat.shape[0] * heat.cell_m, *points[:, 1]]
        side = max(max(xs) - min(xs), max(ys) - min(ys), 1.0) + 2 * MARGIN_M
        cx, cy = (max(xs) + min(xs)) / 2.0, (max(ys) + min(ys)) / 2.0
        return cls(cx - side / 2.0, cy - side / 2.0, side / size_px, size_px)

    def to_px(self, x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Pixel column and row (float) of local points; north is up."""
        col = (np.asarray(x, dtype=float) - self.min_x) / self.m_per_px
        row = self.size_px - (np.asarray(y, dtype=float) - self.min_y) / self.m_per_px
        return col, row

    def box(self) -> Polygon:
        """The view's extent as a local-metre polygon."""
        side = self.size_px * self.m_per_px
        return shapely.box(self.min_x, self.min_y, self.min_x + side, self.min_y + side)

    def points(self, xy: np.ndarray) -> list[tuple[float, float]]:
        """(N, 2) local points as pixel tuples for ``ImageDraw``."""
        col, row = self.to_px(xy[:, 0], xy[:, 1])
        return list(zip(col.tolist(), row.tolist(), strict=True))


def view_cones(city_map: CityMap, result: QueryResult) -> list[np.ndarray]:
    """The top :data:`MAX_CONES` poses' view cones in local metres (:func:`cone_polygon`; the apex first)."""
    top = result.locations[:MAX_CONES]
    if not top:
        return []
    x, y = city_map.frame.to_local(np.array([p.lat for p in top]), np.array([p.lon for p in top]))
    bearings = city_map.frame.heading_to_bearing(np.array([p.heading_deg for p in top]), x, y)
    fov = result.camera.hfov_deg
    return [cone_polygon(np.array([x[i], y[i]]), float(bearings[i]), fov) for i in range(len(top))]


def cone_polygon(apex: np.ndarray, bearing_deg: float, fov_deg: float, length_m: float = CONE_LENGTH_M) -> np.ndarray:
    """The view cone (local m, (N, 2)): the apex then an arc of ``fov_deg`` around ``bearing_deg`` at ``length_m``."""
    angles = np.radians(bearing_deg + np.linspace(-fov_deg / 2.0, fov_deg / 2.0, 13))
    arc = apex + length_m * np.column_stack([np.sin(angles), np.cos(angles)])
    return np.vstack([apex, arc])


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size=size)


def _draw_heat(image: Image.Image, view: View, result: QueryResult) -> None:
    heat = result.heatmap
    values = np.asarray(heat.values, dtype=float).reshape(heat.shape)
    peak = float(values.max()) if values.size else 0.0
    if peak <= 0:
        return
    t = np.sqrt(np.clip(values / peak, 0.0, 1.0))
    rgba = np.zeros((*values.shape, 4), dtype=np.uint8)
    rgba[..., :3] = ramp(t)
    rgba[..., 3] = np.where(values > 0, (50 + 170 * t).round(), 0).astype(np.uint8)
    half = heat.cell_m / 2.0
    left, top = view.to_px(heat.origin_local_m[0] - half, heat.origin_local_m[1] - half + heat.shape[0] * heat.cell_m)
    width = max(1, round(heat.shape[1] * heat.cell_m / view.m_per_px))
    height = max(1, round(heat.shape[0] * heat.cell_m / view.m_per_px))
    cells = Image.fromarray(np.flipud(rgba), "RGBA").resize((width, height), Image.Resampling.NEAREST)
    layer = Image.new("RGBA", image.size, (0, 0, 0, 0))
    layer.paste(cells, (round(float(left)), round(float(top))))
    image.alpha_composite(layer)


def _draw_streets(draw: ImageDraw.ImageDraw, view: View, city_map: CityMap) -> None:
    min_x, min_y, max_x, max_y = view.box().bounds
    width_px = max(2, round(STREET_WIDTH_M / view.m_per_px))
    for line in city_map.streets:
        if len(line) < 2:
            continue
        lo, hi = line.min(axis=0), line.max(axis=0)
        if hi[0] < min_x or lo[0] > max_x or hi[1] < min_y or lo[1] > max_y:
            continue
        draw.line(view.points(line), fill=STREET, width=width_px, joint="curve")


def _draw_footprints(image: Image.Image, view: View, city_map: CityMap) -> None:
    layer = Image.new("RGBA", image.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    for building_id in city_map.footprint_tree.query(view.box()):
        shape = city_map.footprints[int(building_id)]
        for polygon in shape.geoms if isinstance(shape, MultiPolygon) else [shape]:
            draw.polygon(view.points(np.asarray(polygon.exterior.coords)), fill=FOOTPRINT_FILL, outline=FOOTPRINT_EDGE)
            for ring in polygon.interiors:  # courtyards stay see-through
                draw.polygon(view.points(np.asarray(ring.coords)), fill=(0, 0, 0, 0), outline=FOOTPRINT_EDGE)
    image.alpha_composite(layer)


def _draw_cones(image: Image.Image, view: View, cones_m: list[np.ndarray]) -> None:
    layer = Image.new("RGBA", image.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    font = _font(14)
    for rank in range(len(cones_m) - 1, -1, -1):  # rank 1 last, on top
        color = CONE_COLORS[min(rank, len(CONE_COLORS) - 1)]
        cone = view.points(cones_m[rank])
        draw.polygon(cone, fill=(*color, 80), outline=(*color, 255), width=2)
        col, row = cone[0]
        draw.ellipse((col - 6, row - 6, col + 6, row + 6), fill=(*color, 255), outline=(255, 255, 255, 255))
        if rank < 3:
            draw.text(
                (col + 9, row - 9),
                str(rank + 1),
                fill=(*color, 255),
                font=font,
                stroke_width=2,
                stroke_fill=(255, 255, 255, 255),
            )
    image.alpha_composite(layer)


def _draw_north_arrow(draw: ImageDraw.ImageDraw, size_px: int) -> None:
    x, y = size_px - 34, 18
    draw.polygon([(x, y), (x - 11, y + 30), (x, y + 22), (x + 11, y + 30)], fill=TEXT)
    draw.text((x, y + 34), "N", fill=TEXT, font=_font(16), anchor="mt")


def scale_length_m(m_per_px: float, max_px: float) -> float:
    """The longest round length (1, 2 or 5 x 10^k m) that fits in ``max_px`` pixels at ``m_per_px``."""
    limit = max_px * m_per_px
    exponent = np.floor(np.log10(limit))
    best = 10.0**exponent
    for step in (2.0, 5.0, 10.0):
        if step * 10.0**exponent <= limit:
            best = step * 10.0**exponent
    return float(best)


def _draw_footer(draw: ImageDraw.ImageDraw, view: View, peak: float, attribution: str) -> None:
    top = view.size_px
    font = _font(13)
    draw.rectangle((0, top, view.size_px, top + FOOTER_PX), fill=(255, 255, 255))
    draw.line((0, top, view.size_px, top), fill=(200, 200, 200))
    bar_x, bar_y, bar_w, bar_h = 16, top + 12, 220, 14  # the colour bar
    gradient = ramp(np.linspace(0.0, 1.0, bar_w))
    for i, color in enumerate(gradient):
        draw.line((bar_x + i, bar_y, bar_x + i, bar_y + bar_h), fill=tuple(int(c) for c in color))
    draw.rectangle((bar_x, bar_y, bar_x + bar_w, bar_y + bar_h), outline=TEXT)
    for t in (0.0, 0.5, 1.0):  # the ramp is on sqrt(p / peak): position t is p = t^2 * peak
        x = bar_x + t * bar_w
        draw.line((x, bar_y + bar_h, x, bar_y + bar_h + 4), fill=TEXT)
        draw.text((x, bar_y + bar_h + 6), f"{t * t * peak:.2g}", fill=TEXT, font=font, anchor="mt")
    draw.text((bar_x + bar_w + 10, bar_y), "probability per cell", fill=TEXT, font=font)
    length = scale_length_m(view.m_per_px, 160)  # the scale bar
    px = length / view.m_per_px
    sx, sy = 420, top + 20
    draw.rectangle((sx, sy, sx + px, sy + 6), fill=TEXT)
    draw.text((sx + px / 2, sy + 10), f"{length:g} m", fill=TEXT, font=font, anchor="mt")
    draw.text((view.size_px - 10, top + FOOTER_PX - 8), attribution, fill=TEXT, font=font, anchor="rd")


def heatmap_png(city_map: CityMap, result: QueryResult, attribution: str, size_px: int = SIZE_PX) -> bytes:
    """The PNG (``size_px`` wide, ``size_px + FOOTER_PX`` high) of ``result`` drawn over ``city_map``."""
    cones_m = view_cones(city_map, result)
    view = View.around(result, cones_m, size_px)
    image = Image.new("RGBA", (size_px, size_px + FOOTER_PX), (*BACKGROUND, 255))
    draw = ImageDraw.Draw(image)
    _draw_streets(draw, view, city_map)
    _draw_heat(image, view, result)
    _draw_footprints(image, view, city_map)
    _draw_cones(image, view, cones_m)
    draw = ImageDraw.Draw(image)
    _draw_north_arrow(draw, size_px)
    values = result.heatmap.values
    peak = max((max(row) for row in values if row), default=0.0)
    _draw_footer(draw, view, float(peak), attribution)
    out = io.BytesIO()
    image.convert("RGB").save(out, format="PNG", optimize=False)
    return out.getvalue()
