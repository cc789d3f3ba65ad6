"""Colours of building pixels: a building's look (:mod:`geoloc.sim.textures`) sampled at facade coordinates.

A building pixel has facade coordinates ``u`` (metres along the wall from the facade start) and ``v``
(metres above ground); its colour comes from the look's upper-floor or ground-floor tiles (variants
picked by a deterministic hash of seed, building, facade, bay and floor), the sign band, the cornice,
and the stain and street-level detail fields, each sampled bilinearly at the mip level of the pixel's
footprint (metres per pixel on the wall).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from geoloc.sim.scene import Scene
from geoloc.sim.textures import (
    DETAIL_HEIGHT_M,
    DETAIL_TEXELS_PER_M,
    NOISE_TEXELS_PER_M,
    SIGN_BAND_M,
    TEXELS_PER_M,
)


def _bilinear(tex: np.ndarray, var: np.ndarray, fx: np.ndarray, fy: np.ndarray, wrap_y: bool) -> np.ndarray:
    """Bilinear lookup in (K, h, w, 3) uint8 ``tex`` at texel coords (fx, fy) (centres at i + 0.5); x wraps."""
    _, th, tw, _ = tex.shape
    x = fx - 0.5
    y = fy - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    ax = (x - x0)[:, None].astype(np.float32)
    ay = (y - y0)[:, None].astype(np.float32)
    x0 = x0.astype(np.int64) % tw
    x1 = (x0 + 1) % tw
    y0 = y0.astype(np.int64)
    y1 = y0 + 1
    if wrap_y:
        y0 %= th
        y1 %= th
    else:
        y0 = np.clip(y0, 0, th - 1)
        y1 = np.clip(y1, 0, th - 1)
    flat = tex.reshape(-1, 3)
    base = var.astype(np.int64) * (th * tw)
    c00 = flat[base + y0 * tw + x0].astype(np.float32)
    c01 = flat[base + y0 * tw + x1].astype(np.float32)
    c10 = flat[base + y1 * tw + x0].astype(np.float32)
    c11 = flat[base + y1 * tw + x1].astype(np.float32)
    top = c00 + (c01 - c00) * ax
    bot = c10 + (c11 - c10) * ax
    colour: np.ndarray = (top + (bot - top) * ay) * np.float32(1.0 / 255.0)
    return colour


def _sample_mip(
    levels: list[np.ndarray],
    level: np.ndarray,
    var: np.ndarray,
    fx0: np.ndarray,
    fy0: np.ndarray,
    wrap_y: bool,
    fractional: bool,
) -> np.ndarray:
    """Sample a mip list per pixel at its ``level``.

    fractional: (fx0, fy0) are fractions of the tile in [0, 1); else texel coords at level 0.
    """
    out = np.empty((len(level), 3), np.float32)
    for lv in np.unique(level):
        sel = level == lv
        tex = levels[int(lv)]
        th, tw = tex.shape[-3:-1]
        if fractional:
            fx, fy = fx0[sel] * tw, fy0[sel] * th
        else:
            scale = tw / levels[0].shape[-2]
            fx, fy = fx0[sel] * scale, fy0[sel] * (th / levels[0].shape[-3])
        tex4 = tex if tex.ndim == 4 else tex[None]
        out[sel] = _bilinear(tex4, var[sel], fx, fy, wrap_y)
    return out


def hash_ints(*keys: npt.ArrayLike) -> np.ndarray:
    """Deterministic integer hash of integer arrays -> uint64."""
    h = np.full(np.broadcast(*keys).shape, 1469598103934665603, dtype=np.uint64)
    for k in keys:
        h ^= np.asarray(k).astype(np.uint64)
        h *= np.uint64(1099511628211)
        h ^= h >> np.uint64(29)
    return h


def shade_buildings(
    scene: Scene,
    bid: np.ndarray,
    fid: np.ndarray,
    u_m: np.ndarray,
    v_m: np.ndarray,
    footprint_m: np.ndarray,
) -> np.ndarray:
    """(N, 3) float32 RGB of building pixels from their facade coordinates (u along, v up, metres)."""
    fac = scene.map.facades
    out = np.empty((len(bid), 3), np.float32)
    d = TEXELS_PER_M
    level_all = np.clip(np.floor(np.log2(np.maximum(footprint_m * d, 1e-6)) + 0.5), 0, 3).astype(np.int64)
    order = np.argsort(bid, kind="stable")
    bounds = np.flatnonzero(np.diff(bid[order])) + 1
    for idx in np.split(order, bounds):
        if len(idx) == 0:
            continue
        b = int(bid[idx[0]])
        look = scene.look(b)
        f, u, v, level = fid[idx], u_m[idx], v_m[idx], level_all[idx]
        length = fac.length_m[f]
        n_bays = np.maximum(np.round(length / look.bay_m), 1)
        plain = length < 0.8 * look.bay_m
        bay = length / n_bays
        fu = (u / bay) % 1.0
        bay_i = np.floor(u / bay).astype(np.int64)
        rgb = np.broadcast_to(look.wall_rgb.astype(np.float32), (len(idx), 3)).copy()
        top_of_floors = look.ground_m + look.n_floors * look.floor_m
        ground = (v < look.ground_m) & ~plain
        upper = (v >= look.ground_m) & (v < top_of_floors) & ~plain
        if ground.any():
            g = hash_ints(np.int64(scene.seed), np.int64(b), f[ground], bay_i[ground]) % np.uint64(10)
            var = np.where(g < 7, 0, np.where(g < 9, 1, 2)) if look.shops else np.where(g < 3, 1, 2)
            rgb[ground] = _sample_mip(
                look.ground, level[ground], var, fu[ground], 1.0 - v[ground] / look.ground_m, False, True
            )
        if upper.any():
            fl = (v[upper] - look.ground_m) / look.floor_m
            fl_i = np.floor(fl).astype(np.int64)
            g = hash_ints(np.int64(scene.seed), np.int64(b), f[upper], bay_i[upper], fl_i) % np.uint64(10)
            var = np.where(g < 5, 0, np.where(g < 7, 1, np.where(g < 9, 2, 3)))
            rgb[upper] = _sample_mip(look.tiles, level[upper], var, fu[upper], 1.0 - (fl - fl_i), True, True)
        # Cornice at the top of the wall.
        cornice = v > scene.map.building_height_m[b] - 0.35
        rgb[cornice] = look.trim_rgb
        under = (v > scene.map.building_height_m[b] - 0.5) & ~cornice
        rgb[under] *= 0.6
        # Shop signs on the ground floor's sign band.
        u_ring = scene.facade_offset_m[f] + u
        band = (v >= SIGN_BAND_M[0]) & (v < SIGN_BAND_M[1]) & ~plain
        if band.any() and look.sign_mask.any():
            sx = np.clip((u_ring[band] * d).astype(np.int64), 0, len(look.sign_mask) - 1)
            on = look.sign_mask[sx]
            if on.any():
                sel = np.flatnonzero(band)[on]
                rgb[sel] = _sample_mip(
                    look.sign,
                    level[sel],
                    np.zeros(len(sel), np.int64),
                    u_ring[sel] * d,
                    (SIGN_BAND_M[1] - v[sel]) * d,
                    False,
                    False,
                )
        # Stains and large-scale variation, continuous around the building.
        nh, nw = look.stain.shape
        sy = np.clip((v * NOISE_TEXELS_PER_M).astype(np.int64), 0, nh - 1)
        sx = np.clip((u_ring * NOISE_TEXELS_PER_M).astype(np.int64), 0, nw - 1)
        rgb *= look.stain[sy, sx][:, None]
        low = np.flatnonzero((v < DETAIL_HEIGHT_M) & (level < 3))
        if len(low):
            dh, dw = look.detail.shape
            dy = np.clip((v[low] * DETAIL_TEXELS_PER_M).astype(np.int64), 0, dh - 1)
            dx = np.clip((u_ring[low] * DETAIL_TEXELS_PER_M).astype(np.int64), 0, dw - 1)
            rgb[low] *= (look.detail[dy, dx] * np.float32(1.0 / 128.0))[:, None]
        out[idx] = rgb
    return out
