"""Shop signs for the simulator: a strip along a building's perimeter at the ground floor's sign band.

The strip is in facade coordinates (``u`` metres from the building's ring start, at
:data:`geoloc.sim.textures.TEXELS_PER_M`) and covers :data:`geoloc.sim.textures.SIGN_BAND_M`; a building
with shops gets a panel on most facades of at least 5 m, with its OSM name or a made-up shop word.
"""

from __future__ import annotations

import cv2
import numpy as np

from geoloc.sim.textures import SIGN_BAND_M, TEXELS_PER_M, to_u8

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


def _random_sign_text(rng: np.random.Generator) -> str:
    if rng.random() < 0.5:
        return str(rng.choice(_SHOP_WORDS))
    n = int(rng.integers(2, 5))
    return "".join(rng.choice(_SYLLABLES, n))


def _ascii(text: str) -> str:
    table = str.maketrans("äöåÄÖÅéèüÜ", "aoaAOAeeuU")
    return "".join(c for c in text.translate(table) if 32 <= ord(c) < 127).upper()


def sign_strip(
    rng: np.random.Generator,
    wall: np.ndarray,
    perimeter_m: float,
    offsets_m: np.ndarray,
    lengths_m: np.ndarray,
    shops: bool,
    name: str | None,
) -> tuple[np.ndarray, np.ndarray]:
    """(sh, sw, 3) uint8 sign band along the perimeter and (sw,) bool mask of where signs are.

    wall: (3,) the wall's RGB; perimeter_m: the building's perimeter; offsets_m, lengths_m: (F_b,) its
    facades along it (metres); shops: whether the building has any; name: its OSM name, the first sign.
    """
    d = TEXELS_PER_M
    sh = int(round((SIGN_BAND_M[1] - SIGN_BAND_M[0]) * d))
    sw = max(2, int(np.ceil(perimeter_m * d)) + 2)
    strip = np.zeros((sh, sw, 3), np.float32)
    mask = np.zeros(sw, bool)
    if not shops:
        return to_u8(strip), mask
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
        panel = np.ascontiguousarray(np.broadcast_to(to_u8(bg), (sh, b - a, 3)))
        ink = tuple(int(x) for x in to_u8(fg))
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
    return to_u8(strip), mask
