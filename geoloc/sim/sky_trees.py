"""Sky clouds and tree sprites for the simulator, drawn once per world from its seed."""

from __future__ import annotations

import cv2
import numpy as np

TRUNK_FRAC = 0.07


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
