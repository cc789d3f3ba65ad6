"""Procedural looks for the simulator: facade tiles per building, signs, sky clouds, tree sprites.

Facade textures live in facade coordinates: ``u`` along the wall (metres) and ``v`` height above the
ground (metres). A building's look is drawn once from a generator seeded with (world seed,
building id), so the same building looks the same from every viewpoint.

A look holds small periodic *tiles* (one window bay by one storey, at ``TEXELS_PER_M``) in a few
variants (curtains, blinds, tints), ground-floor tiles (shop front, door, small window), a sign
strip along the building's perimeter and a low-resolution stain field. Each is kept as a short mip
pyramid (level l has ``TEXELS_PER_M / 2**l`` texels per metre) so that far facades do not alias.
All colours are linear-ish RGB floats in [0, 1] stored as uint8.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

TEXELS_PER_M = 24.0
MIP_LEVELS = 4
NOISE_TEXELS_PER_M = 2.0
DETAIL_TEXELS_PER_M = 8.0
DETAIL_HEIGHT_M = 8.0  # unique street-level detail (posters, graffiti, plaques) up to this height
SIGN_BAND_M = (3.15, 3.85)  # bottom and top of the sign band on the ground floor (m above ground)

_WALL_PALETTE = np.array(
    [
        [0.86, 0.78, 0.58],  # ochre
        [0.90, 0.86, 0.76],  # cream
        [0.84, 0.66, 0.60],  # old pink
        [0.70, 0.70, 0.68],  # concrete grey
        [0.62, 0.34, 0.26],  # brick red
        [0.66, 0.72, 0.76],  # blue grey
        [0.93, 0.92, 0.89],  # white
        [0.78, 0.62, 0.40],  # sand brown
        [0.55, 0.60, 0.52],  # sage
        [0.45, 0.42, 0.40],  # dark granite
    ]
)
_SIGN_COLOURS = np.array(
    [
        [0.75, 0.10, 0.10],
        [0.10, 0.25, 0.60],
        [0.05, 0.45, 0.25],
        [0.95, 0.75, 0.10],
        [0.10, 0.10, 0.10],
        [0.95, 0.95, 0.95],
        [0.55, 0.15, 0.50],
        [0.95, 0.45, 0.05],
    ]
)
_SYLLABLES = ("KA", "MA", "RI", "TO", "LA", "NE", "SU", "PO", "VI", "HE", "JO", "KU", "SA", "TI", "RO", "BE")
_SHOP_WORDS = (
    "CAFE",
    "BAR",
    "APTEEKKI",
    "KIRJA",
    "PANKKI",
    "HOTEL",
    "MARKET",
    "SHOP",
    "KUKKA",
    "OPTIKKO",
    "RAVINTOLA",
    "BAKERY",
    "SALON",
    "R-KIOSKI",
    "BOUTIQUE",
    "PIZZA",
    "SUSHI",
    "KEBAB",
    "GALLERY",
)


def _u8(img: np.ndarray) -> np.ndarray:
    return np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)


def mip_pyramid(img_u8: np.ndarray, levels: int = MIP_LEVELS) -> list[np.ndarray]:
    """Mip levels of an (..., h, w, 3) uint8 texture (area-averaged halvings, at least 1 texel)."""
    out = [img_u8]
    for _ in range(levels - 1):
        prev = out[-1]
        h, w = prev.shape[-3:-1]
        nh, nw = max(1, h // 2), max(1, w // 2)
        flat = prev.reshape(-1, h, w, 3)
        out.append(
            np.stack([cv2.resize(t, (nw, nh), interpolation=cv2.INTER_AREA) for t in flat]).reshape(
                (*prev.shape[:-3], nh, nw, 3)
            )
        )
    return out


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], scale_px: float, octaves: int = 3) -> np.ndarray:
    """Fractal value noise in [-1, 1] roughly, of ``shape`` (h, w); feature size ``scale_px``."""
    h, w = shape
    out = np.zeros(shape, np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        s = max(scale_px / 2**o, 1.0)
        gh, gw = max(2, int(np.ceil(h / s)) + 2), max(2, int(np.ceil(w / s)) + 2)
        grid = rng.standard_normal((gh, gw)).astype(np.float32)
        big = cv2.resize(grid, (int(gw * s), int(gh * s)), interpolation=cv2.INTER_CUBIC)
        out += amp * big[:h, :w]
        total += amp
        amp *= 0.5
    return out / total


@dataclass
class BuildingLook:
    """Per-building appearance (see module docstring). Sizes in metres; textures as mip lists.

    tiles[l]: (K, th, tw, 3) upper-floor bay tiles; ground[l]: (G, gh, tw, 3) ground-floor bay tiles
    (variant 0 shop front, 1 door, 2 small window); sign[l]: (sh, sw, 3) strip along the perimeter
    (u in metres from the ring start) covering ``SIGN_BAND_M``; sign_mask: (sw,) bool at level 0,
    True where a sign is; stain: (nh, nw) float32 multiplicative brightness at ``NOISE_TEXELS_PER_M``.
    """

    wall_rgb: np.ndarray
    trim_rgb: np.ndarray
    bay_m: float
    floor_m: float
    ground_m: float
    n_floors: int
    style: str
    shops: bool
    tiles: list[np.ndarray]
    ground: list[np.ndarray]
    sign: list[np.ndarray]
    sign_mask: np.ndarray
    stain: np.ndarray
    detail: np.ndarray


def make_look(
    seed: int,
    building_id: int,
    height_m: float,
    perimeter_m: float,
    facade_offsets_m: np.ndarray,
    facade_lengths_m: np.ndarray,
    name: str | None = None,
) -> BuildingLook:
    """Draw one building's look from a generator seeded with (``seed``, ``building_id``).

    facade_offsets_m, facade_lengths_m: (F_b,) the building's facades along its perimeter, used to
    centre signs on walls.
    """
    rng = np.random.default_rng([seed, building_id, 7])
    style = str(rng.choice(["plaster", "plaster", "brick", "stone", "modern"]))
    wall = _WALL_PALETTE[rng.integers(len(_WALL_PALETTE))].copy()
    if style == "brick":
        wall = np.array([0.58, 0.30, 0.22]) + rng.normal(0, 0.04, 3)
    if style == "modern":
        wall = np.array([0.55, 0.57, 0.58]) + rng.normal(0, 0.08, 3)
    wall = np.clip(wall * rng.uniform(0.85, 1.05) + rng.normal(0, 0.03, 3), 0.08, 0.97)
    trim = np.clip(wall * rng.uniform(0.6, 0.8) if rng.random() < 0.5 else wall * 0.4 + 0.55, 0.05, 0.98)
    ground_m = float(rng.uniform(3.9, 4.6)) if height_m > 7 else min(3.0, height_m)
    shops = bool(height_m > 7 and rng.random() < 0.75)
    n_floors = max(1, int(round((height_m - ground_m - 0.8) / rng.uniform(3.0, 3.5))))
    floor_m = max(2.6, (height_m - ground_m - 0.8) / n_floors) if height_m > ground_m + 2.6 else 3.0
    bay_m = float(rng.uniform(2.6, 4.2)) if style != "modern" else float(rng.uniform(1.5, 2.5))

    tiles = _window_tiles(rng, style, wall, trim, bay_m, floor_m)
    ground = _ground_tiles(rng, style, wall, trim, bay_m, ground_m, shops)
    sign, sign_mask = _sign_strip(rng, wall, perimeter_m, facade_offsets_m, facade_lengths_m, shops, name)
    nh = max(2, int(np.ceil(height_m * NOISE_TEXELS_PER_M)) + 2)
    nw = max(2, int(np.ceil(perimeter_m * NOISE_TEXELS_PER_M)) + 2)
    stain = 1.0 + 0.07 * smooth_noise(rng, (nh, nw), 6.0) + 0.035 * smooth_noise(rng, (nh, nw), 1.5, 1)
    streaks = smooth_noise(rng, (1, nw), 1.2, 1)[0]
    stain -= 0.05 * np.clip(streaks, 0, None)[None, :] * np.linspace(1.0, 0.2, nh)[:, None]
    detail = _detail_field(rng, perimeter_m, facade_offsets_m, facade_lengths_m)
    return BuildingLook(
        wall,
        trim,
        bay_m,
        floor_m,
        ground_m,
        n_floors,
        style,
        shops,
        mip_pyramid(tiles),
        mip_pyramid(ground),
        mip_pyramid(sign),
        sign_mask,
        stain.astype(np.float32),
        detail,
    )


def _detail_field(
    rng: np.random.Generator, perimeter_m: float, offsets_m: np.ndarray, lengths_m: np.ndarray
) -> np.ndarray:
    """(dh, dw) uint8 street-level detail (128 = no change), row 0 at the ground (see BuildingLook)."""
    d = DETAIL_TEXELS_PER_M
    dh, dw = int(DETAIL_HEIGHT_M * d), max(2, int(np.ceil(perimeter_m * d)) + 2)
    img = np.full((dh, dw), 128, np.uint8)
    n_marks = max(1, int(perimeter_m / 4.0))
    for _ in range(n_marks):
        kind = rng.random()
        x = int(rng.uniform(0, perimeter_m) * d)
        if kind < 0.35:  # graffiti scribble low on the wall
            pts = np.column_stack([x + np.cumsum(rng.normal(2.5, 2.0, 8)), rng.uniform(0.4, 1.8, 8) * d])
            tone = int(rng.choice([40, 60, 200, 230]))
            cv2.polylines(
                img, [pts.astype(np.int32).reshape(-1, 1, 2)], False, tone, int(rng.integers(1, 3)), cv2.LINE_AA
            )
        elif kind < 0.65:  # poster with a pattern
            w, h = int(rng.uniform(0.5, 1.0) * d), int(rng.uniform(0.7, 1.3) * d)
            y = int(rng.uniform(1.0, 1.6) * d)
            cv2.rectangle(img, (x, y), (x + w, y + h), int(rng.integers(150, 240)), -1)
            for _ in range(int(rng.integers(2, 6))):
                px, py = x + int(rng.integers(0, max(1, w - 2))), y + int(rng.integers(0, max(1, h - 2)))
                cv2.rectangle(
                    img,
                    (px, py),
                    (px + int(rng.integers(1, 4)), py + int(rng.integers(1, 4))),
                    int(rng.integers(20, 120)),
                    -1,
                )
        elif kind < 0.8:  # plaque or house number
            y = int(rng.uniform(2.3, 2.9) * d)
            cv2.rectangle(img, (x, y), (x + 3, y + 2), int(rng.integers(30, 90)), -1)
        elif kind < 0.9:  # patched plaster
            w, h = int(rng.uniform(0.5, 2.5) * d), int(rng.uniform(0.4, 2.0) * d)
            y = int(rng.uniform(0.2, DETAIL_HEIGHT_M - 2.0) * d)
            cv2.rectangle(img, (x, y), (x + w, y + h), int(rng.choice([105, 112, 145, 150])), -1)
        else:  # air-conditioning box or lamp
            y = int(rng.uniform(2.6, DETAIL_HEIGHT_M - 1.0) * d)
            cv2.rectangle(img, (x, y), (x + 5, y + 4), int(rng.choice([70, 210])), -1)
            cv2.rectangle(img, (x, y), (x + 5, y + 4), 60, 1)
    for off, length in zip(offsets_m, lengths_m, strict=True):  # drainpipes at some corners
        if length > 4.0 and rng.random() < 0.4:
            x = int((off + 0.3) * d)
            img[:, x : x + 1] = 80
    return img


def _wall_base(rng: np.random.Generator, style: str, wall: np.ndarray, h: int, w: int) -> np.ndarray:
    """(h, w, 3) plain wall texture for one tile, periodic enough to repeat."""
    grain = 0.025 * rng.standard_normal((h, w, 1)).astype(np.float32)
    img = np.broadcast_to(wall, (h, w, 3)).astype(np.float32) * (1.0 + grain)
    if style == "brick":
        course = int(round(0.075 * TEXELS_PER_M * 2))  # two texels per 7.5 cm course, drawn at 15 cm
        img[:: max(course, 3)] *= 0.8
        img *= 1.0 + 0.06 * rng.standard_normal((1, w, 3)).astype(np.float32)
    elif style == "stone":
        img[:: int(0.6 * TEXELS_PER_M)] *= 0.78
    elif style == "modern":
        img[:, :: max(1, w // 2)] *= 0.75  # panel joints
    return img


def _window_tiles(
    rng: np.random.Generator, style: str, wall: np.ndarray, trim: np.ndarray, bay_m: float, floor_m: float
) -> np.ndarray:
    """(K, th, tw, 3) uint8 upper-floor bay tiles: a window in a wall, floor band at the bottom."""
    th, tw = int(round(floor_m * TEXELS_PER_M)), int(round(bay_m * TEXELS_PER_M))
    d = TEXELS_PER_M
    modern = style == "modern"
    win_w = bay_m * (rng.uniform(0.75, 0.9) if modern else rng.uniform(0.35, 0.55))
    sill = rng.uniform(0.3, 0.5) if modern else rng.uniform(0.8, 1.0)
    win_h = min(floor_m - sill - 0.35, rng.uniform(1.4, 1.9) if not modern else floor_m - sill - 0.3)
    frame_rgb = np.array([0.95, 0.95, 0.93]) if rng.random() < 0.6 else trim * 0.6
    glass = np.array([0.16, 0.20, 0.26]) + rng.normal(0, 0.03, 3)
    mullion = rng.random() < 0.7
    band = (not modern) and rng.random() < 0.7
    lintel = (not modern) and rng.random() < 0.5
    x0 = int(round((bay_m - win_w) / 2 * d))
    x1 = tw - x0
    # Tile rows go from the top of the storey (row 0) down to its floor (row th - 1).
    y1 = th - int(round(sill * d))
    y0 = y1 - int(round(win_h * d))
    fr = max(2, int(round(0.07 * d)))
    variants = []
    for k in range(4):
        img = _wall_base(rng, style, wall, th, tw)
        if band:
            img[th - int(0.22 * d) :] = trim
            img[th - int(0.22 * d)] *= 0.7
        if lintel:
            img[y0 - int(0.25 * d) : y0, x0 - fr : x1 + fr] = trim
        # Sill ledge and its shadow.
        img[y1 : y1 + max(2, int(0.08 * d)), x0 - fr : x1 + fr] = np.clip(frame_rgb * 1.05, 0, 1)
        img[y1 + max(2, int(0.08 * d)) : y1 + max(3, int(0.14 * d)), x0 - fr : x1 + fr] *= 0.6
        img[y0 - fr : y1, x0 - fr : x1 + fr] = frame_rgb
        gy = np.linspace(1.5, 0.8, y1 - y0)[:, None, None]  # sky reflection brighter at the top
        tint = glass * (1.0 + 0.25 * (k == 1)) + (0.05 * k) * np.array([0.0, 0.02, 0.04])
        pane = np.broadcast_to(tint * gy, (y1 - y0, x1 - x0, 3)).copy()
        if k == 2:  # curtains on both sides
            cw = max(1, (x1 - x0) // 4)
            curtain = np.array([0.85, 0.80, 0.70]) * rng.uniform(0.7, 1.0)
            pane[:, :cw] = curtain
            pane[:, -cw:] = curtain
        elif k == 3:  # blinds half down
            bh = (y1 - y0) // 2
            pane[:bh] = np.array([0.80, 0.80, 0.78])
            pane[:bh:3] *= 0.8
        img[y0:y1, x0:x1] = pane
        img[y0 : y0 + fr, x0:x1] *= 0.55  # reveal shadow under the lintel
        if mullion:
            mx = (x0 + x1) // 2
            img[y0:y1, mx - fr // 2 : mx + fr - fr // 2] = frame_rgb
            ty = y0 + (y1 - y0) // 3
            img[ty - fr // 2 : ty + fr - fr // 2, x0:x1] = frame_rgb
        variants.append(img)
    return _u8(np.stack(variants))


def _ground_tiles(
    rng: np.random.Generator,
    style: str,
    wall: np.ndarray,
    trim: np.ndarray,
    bay_m: float,
    ground_m: float,
    shops: bool,
) -> np.ndarray:
    """(3, gh, tw, 3) uint8 ground-floor tiles: 0 shop front, 1 door, 2 small window; plinth at the bottom."""
    d = TEXELS_PER_M
    gh, tw = int(round(ground_m * d)), int(round(bay_m * d))
    base_wall = wall * (0.8 if shops else 0.95)
    plinth = int(round(0.45 * d))
    frame_rgb = np.array([0.2, 0.2, 0.22]) if rng.random() < 0.5 else trim * 0.7
    glass = np.array([0.12, 0.15, 0.19])
    top_glass = int(round((ground_m - min(ground_m, 3.05)) * d))
    fr = max(2, int(0.08 * d))
    out = []
    for k in range(3):
        img = _wall_base(rng, style, base_wall, gh, tw)
        img[gh - plinth :] = np.array([0.32, 0.31, 0.30]) + 0.02 * k
        if k == 0 and shops:  # shop window: glass over most of the bay, reflections, a lit display
            x0, x1 = fr * 2, tw - fr * 2
            y0, y1 = top_glass, gh - plinth + fr
            img[y0:y1, x0:x1] = frame_rgb
            ih, iw = y1 - y0 - 2 * fr, x1 - x0 - 2 * fr
            inner = np.empty((ih, iw, 3), np.float32)
            interior = rng.uniform(0.35, 0.7) * np.array([1.0, 0.95, 0.85])
            inner[:] = interior
            for _ in range(int(rng.integers(3, 8))):  # goods and shelves on display
                bw, bh = int(rng.integers(3, max(4, iw // 3))), int(rng.integers(3, max(4, ih // 3)))
                bx, by = int(rng.integers(0, max(1, iw - bw))), int(rng.integers(ih // 3, max(ih // 3 + 1, ih - bh)))
                inner[by : by + bh, bx : bx + bw] = rng.uniform(0.15, 0.95, 3)
            refl = np.linspace(0.55, 0.15, ih)[:, None, None] * np.array([0.75, 0.82, 0.9])
            diag = ((np.arange(iw)[None, :] + np.arange(ih)[:, None]) // max(4, iw // 3)) % 2
            inner = inner * 0.55 + refl * (0.8 + 0.2 * diag[..., None])
            img[y0 + fr : y1 - fr, x0 + fr : x1 - fr] = inner
            for mx in np.linspace(x0, x1, int(rng.integers(2, 4)) + 1)[1:-1].astype(int):
                img[y0:y1, mx - fr // 2 : mx + fr // 2 + 1] = frame_rgb
            tr = y0 + int(0.22 * (y1 - y0))
            img[tr : tr + fr, x0:x1] = frame_rgb
        elif k == 1 or (k == 0 and not shops):  # door
            dw = int(round(min(1.4, bay_m * 0.45) * d))
            x0 = (tw - dw) // 2
            y0 = gh - int(round(2.4 * d))
            door = np.array([0.30, 0.20, 0.12]) if rng.random() < 0.5 else rng.uniform(0.1, 0.5, 3)
            img[y0 - fr : gh, x0 - fr : x0 + dw + fr] = frame_rgb
            img[y0:gh, x0 : x0 + dw] = door
            img[y0 + fr * 2 : y0 + int(0.9 * d), x0 + fr * 2 : x0 + dw - fr * 2] = glass * 1.4
            img[y0 : y0 + fr, x0 : x0 + dw] *= 0.5
        else:  # small barred window
            x0, x1 = int(tw * 0.3), int(tw * 0.7)
            y0, y1 = int(gh * 0.3), int(gh * 0.62)
            img[y0 - fr : y1 + fr, x0 - fr : x1 + fr] = frame_rgb
            img[y0:y1, x0:x1] = glass * 1.2
            img[y0:y1, x0 : x1 : max(3, fr * 2)] = np.array([0.15, 0.15, 0.15])
        out.append(img)
    return _u8(np.stack(out))


def _random_sign_text(rng: np.random.Generator) -> str:
    if rng.random() < 0.5:
        return str(rng.choice(_SHOP_WORDS))
    n = int(rng.integers(2, 5))
    return "".join(rng.choice(_SYLLABLES, n))


def _ascii(text: str) -> str:
    table = str.maketrans("äöåÄÖÅéèüÜ", "aoaAOAeeuU")
    return "".join(c for c in text.translate(table) if 32 <= ord(c) < 127).upper()


def _sign_strip(
    rng: np.random.Generator,
    wall: np.ndarray,
    perimeter_m: float,
    offsets_m: np.ndarray,
    lengths_m: np.ndarray,
    shops: bool,
    name: str | None,
) -> tuple[np.ndarray, np.ndarray]:
    """(sh, sw, 3) uint8 sign band along the perimeter and (sw,) bool mask of where signs are."""
    d = TEXELS_PER_M
    sh = int(round((SIGN_BAND_M[1] - SIGN_BAND_M[0]) * d))
    sw = max(2, int(np.ceil(perimeter_m * d)) + 2)
    strip = np.zeros((sh, sw, 3), np.float32)
    mask = np.zeros(sw, bool)
    if not shops:
        return _u8(strip), mask
    texts = [_ascii(name)] if name and _ascii(name).strip() else []
    for off, length in zip(offsets_m, lengths_m, strict=True):
        if length < 5.0 or rng.random() < 0.3:
            continue
        width_m = min(length - 1.5, rng.uniform(3.0, 9.0))
        start_m = off + rng.uniform(0.75, length - 0.75 - width_m)
        text = texts.pop(0) if texts else _random_sign_text(rng)
        bg = _SIGN_COLOURS[rng.integers(len(_SIGN_COLOURS))]
        fg = np.array([0.97, 0.97, 0.95]) if bg.mean() < 0.5 else np.array([0.08, 0.08, 0.1])
        a, b = int(start_m * d), int((start_m + width_m) * d)
        panel = np.ascontiguousarray(np.broadcast_to(_u8(bg), (sh, b - a, 3)))
        ink = tuple(int(x) for x in _u8(fg))
        font = cv2.FONT_HERSHEY_DUPLEX if rng.random() < 0.5 else cv2.FONT_HERSHEY_TRIPLEX
        (tw, th), _ = cv2.getTextSize(text, font, 1.0, 2)
        scale = min((sh * 0.7) / th, (b - a) * 0.92 / tw)
        thick = max(1, int(scale * 2))
        (tw, th), _ = cv2.getTextSize(text, font, scale, thick)
        org = ((b - a - tw) // 2, (sh + th) // 2)
        cv2.putText(panel, text, org, font, scale, ink, thick, cv2.LINE_AA)
        if rng.random() < 0.5 and org[0] > sh:  # logo disc left of the text
            cv2.circle(panel, (org[0] - sh // 2 - 2, sh // 2), max(2, sh // 3), ink, -1, cv2.LINE_AA)
        panel = panel.astype(np.float32) / 255.0
        panel[:2] *= 0.6
        panel[-2:] *= 0.6
        strip[:, a:b] = panel
        mask[a:b] = True
    return _u8(strip), mask


# ----------------------------------------------------------------------------------------------
# Sky and trees


def cloud_panorama(rng: np.random.Generator, cover: float, res_deg: float = 0.25) -> np.ndarray:
    """(rows, cols) float32 cloud opacity in [0, 1] over elevation 0..90 deg (row 0 = horizon) x bearing 0..360.

    Periodic in bearing (FFT noise). ``cover`` in [0, 1] is the fraction of sky with clouds.
    """
    rows, cols = int(90 / res_deg), int(360 / res_deg)
    fy = np.fft.fftfreq(rows * 2)[:, None]
    fx = np.fft.fftfreq(cols)[None, :]
    f = np.sqrt((fx * 2.5) ** 2 + fy**2) + 1e-3
    spectrum = (rng.standard_normal(f.shape) + 1j * rng.standard_normal(f.shape)) / f**1.7
    spectrum[f < 2e-3] = 0
    field = np.real(np.fft.ifft2(spectrum))[:rows]
    field = (field - field.mean()) / (field.std() + 1e-9)
    thresh = np.quantile(field, 1.0 - cover)
    opacity: np.ndarray = np.clip((field - thresh) / 1.2, 0.0, 1.0) ** 0.8
    return opacity.astype(np.float32)


def tree_sprites(rng: np.random.Generator, n: int = 6, width_px: int = 96, height_px: int = 160) -> np.ndarray:
    """(n, height_px, width_px, 4) float32 RGBA tree billboards (crown of leaf blobs on a trunk).

    The sprite spans the crown width horizontally and the whole tree height vertically; the trunk
    is centred at the bottom and takes ``TRUNK_FRAC`` of the width.
    """
    out = np.zeros((n, height_px, width_px, 4), np.float32)
    yy, xx = np.mgrid[0:height_px, 0:width_px].astype(np.float32)
    for i in range(n):
        img = out[i]
        crown_bottom = height_px * rng.uniform(0.68, 0.78)
        cy_c = crown_bottom * 0.5
        ry = crown_bottom * 0.5
        trunk_w = width_px * TRUNK_FRAC
        trunk = (np.abs(xx - width_px / 2) < trunk_w / 2) & (yy > cy_c)
        bark = np.array([0.28, 0.22, 0.16]) * (0.85 + 0.15 * rng.random())
        img[trunk, :3] = bark * (0.8 + 0.4 * ((xx[trunk] - width_px / 2) / trunk_w + 0.5))[:, None] * 0.8
        img[trunk, 3] = 1.0
        base = np.array([0.20, 0.36, 0.14]) * rng.uniform(0.7, 1.2) + rng.normal(0, 0.02, 3)
        for _ in range(110):
            ang = rng.uniform(0, 2 * np.pi)
            rad = np.sqrt(rng.random())
            bx = width_px / 2 + np.cos(ang) * rad * (width_px / 2 - 9)
            by = cy_c + np.sin(ang) * rad * (ry - 9)
            br = rng.uniform(5, 12)
            blob = (xx - bx) ** 2 + (yy - by) ** 2 < br**2
            light = 1.3 - 0.7 * (by / (2 * ry)) - 0.25 * (1 - rad) + rng.normal(0, 0.08)
            img[blob, :3] = base * light
            img[blob, 3] = 1.0
        leaf = rng.random((height_px, width_px)) < 0.18  # holes and speckle in the foliage
        crown = (img[..., 3] > 0) & ~trunk
        img[crown & leaf, 3] = 0.0
        img[crown, :3] *= (0.8 + 0.4 * rng.random((height_px, width_px)))[crown][:, None]
        img[..., 3] = cv2.GaussianBlur(img[..., 3], (3, 3), 0.6)
    return out


TRUNK_FRAC = 0.07
