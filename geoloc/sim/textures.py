"""Procedural facade textures for the simulator: window and ground-floor bay tiles, street-level detail.

Facade textures live in facade coordinates: ``u`` along the wall (metres) and ``v`` height above the
ground (metres). A look (:mod:`geoloc.sim.looks`) holds small periodic *tiles* (one window bay by one
storey, at ``TEXELS_PER_M``) in a few variants (curtains, blinds, tints), ground-floor tiles (shop front,
door, small window), a sign strip (:mod:`geoloc.sim.signs`) and low-resolution stain and detail fields.
Each texture is kept as a short mip pyramid (level l has ``TEXELS_PER_M / 2**l`` texels per metre) so that
far facades do not alias. All colours are linear-ish RGB floats in [0, 1] stored as uint8.
"""

from __future__ import annotations

import cv2
import numpy as np

TEXELS_PER_M = 24.0
MIP_LEVELS = 4
NOISE_TEXELS_PER_M = 2.0
DETAIL_TEXELS_PER_M = 8.0
DETAIL_HEIGHT_M = 8.0  # unique street-level detail (posters, graffiti, plaques) up to this height
SIGN_BAND_M = (3.15, 3.85)  # bottom and top of the sign band on the ground floor (m above ground)


def to_u8(img: np.ndarray) -> np.ndarray:
    """Float RGB in [0, 1] -> uint8 (rounded, clipped)."""
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


def detail_field(
    rng: np.random.Generator, perimeter_m: float, offsets_m: np.ndarray, lengths_m: np.ndarray
) -> np.ndarray:
    """(dh, dw) uint8 street-level detail (128 = no change), row 0 at the ground (see ``BuildingLook``).

    perimeter_m: the building's perimeter; offsets_m, lengths_m: (F_b,) its facades along it (metres).
    """
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


def window_tiles(
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
    return to_u8(np.stack(variants))


def ground_tiles(
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
    return to_u8(np.stack(out))
