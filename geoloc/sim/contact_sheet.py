"""The contact sheet of a simulated world: thumbnails of its photos beside a plan of their poses."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from geoloc.sim.scene import Scene


def contact_sheet(out: Path, manifest: dict[str, Any], scene: Scene, thumb_w: int = 192, cols: int = 10) -> Path:
    """Write ``contact_sheet.jpg``: thumbnails with names (blue: references, red: queries) and a pose map."""
    images = manifest["images"]
    th = int(round(thumb_w * 3 / 4))
    rows = max(1, math.ceil(len(images) / cols))
    label_h = 18
    grid = np.full((rows * (th + label_h), cols * thumb_w, 3), 30, np.uint8)
    for i, rec in enumerate(images):
        img = cv2.imread(str(out / rec["file"]))
        if img is None:
            continue
        thumb = cv2.resize(img, (thumb_w, th), interpolation=cv2.INTER_AREA)
        y, x = (i // cols) * (th + label_h), (i % cols) * thumb_w
        grid[y : y + th, x : x + thumb_w] = thumb
        colour = (230, 140, 40) if rec["role"] == "reference" else (40, 40, 230)
        grid[y + th : y + th + label_h, x : x + thumb_w] = colour
        text = rec["name"] + ("" if rec["role"] == "reference" else f" {rec['kind']}")
        cv2.putText(grid, text, (x + 4, y + th + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
    side = grid.shape[0]
    plan = _pose_map(manifest, scene, side)
    sheet = np.hstack([grid, plan])
    path = out / "contact_sheet.jpg"
    cv2.imwrite(str(path), sheet, [cv2.IMWRITE_JPEG_QUALITY, 88])
    return path


def _pose_map(manifest: dict[str, Any], scene: Scene, side: int) -> np.ndarray:
    """(side, side, 3) BGR plan view: footprints, streets, and each pose as a dot with its view wedge."""
    img = np.full((side, side, 3), 245, np.uint8)
    xy = np.array([[r["pose"]["x_m"], r["pose"]["y_m"]] for r in manifest["images"]]).reshape(-1, 2)
    if len(xy) == 0:
        return img
    lo, hi = xy.min(axis=0) - 40.0, xy.max(axis=0) + 40.0
    span = float(max(hi - lo))
    scale = (side - 20) / span

    def to_px(p: np.ndarray) -> np.ndarray:
        q = (np.asarray(p) - lo) * scale + 10
        return np.column_stack([q[:, 0], side - q[:, 1]]).round().astype(np.int32)

    for line in scene.map.streets:
        if len(line) >= 2:
            cv2.polylines(img, [to_px(line)], False, (215, 215, 215), max(1, int(6 * scale)), cv2.LINE_AA)
    for b in scene.map.buildings:
        for poly in getattr(b.polygon, "geoms", [b.polygon]):
            ring = np.asarray(poly.exterior.coords)
            if np.all(ring.max(axis=0) >= lo) and np.all(ring.min(axis=0) <= hi):
                cv2.fillPoly(img, [to_px(ring)], (170, 170, 170), cv2.LINE_AA)
    for rec in manifest["images"]:
        p = np.array([[rec["pose"]["x_m"], rec["pose"]["y_m"]]])
        yaw = math.radians(rec["pose"]["yaw_deg"])
        half = math.radians(rec["intrinsics"]["hfov_deg"] / 2)
        colour = (200, 110, 20) if rec["role"] == "reference" else (30, 30, 220)
        c = to_px(p)[0]
        for a in (yaw - half, yaw + half):
            tip = to_px(p + 15.0 * np.array([[math.sin(a), math.cos(a)]]))[0]
            cv2.line(img, tuple(int(v) for v in c), tuple(int(v) for v in tip), colour, 1, cv2.LINE_AA)
        cv2.circle(img, tuple(int(v) for v in c), 4, colour, -1, cv2.LINE_AA)
        cv2.putText(
            img,
            rec["name"].split("_")[-1],
            (int(c[0]) + 5, int(c[1]) - 4),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.35,
            colour,
            1,
            cv2.LINE_AA,
        )
    cv2.putText(
        img,
        f"references (blue) and queries (red); 15 m view wedges; {span:.0f} m across",
        (10, 20),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.5,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    return img
