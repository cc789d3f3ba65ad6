"""``geoloc analyze IMAGE --out DIR``: the image side of the method on one photo, as overlays.

Writes overlays a person can check (paper Fig. 4 and 6) plus a JSON summary.

Files written to DIR (``<stem>`` = the image's file stem):

- ``<stem>_segmentation.png``: class colours over the photo.
- ``<stem>_lines.png``: line segments coloured by vanishing point (vertical white, outliers grey),
  with the horizon (dashed) and a legend of the horizontal VPs' orientations theta.
- ``<stem>_facades.png``: building pixels tinted by the VP of their facade piece, dashed cutting
  lines, theta per piece, and a strip along the bottom with the per-column confidence.
- ``<stem>_birdseye.png``: top view of the facade pieces relative to the camera: each piece drawn
  at unit depth along its central ray with its orientation (the depth is unknown), the field of
  view and the principal plane (dashed).
- ``<stem>_overview.png``: the four side by side; ``<stem>_summary.json``: numbers.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

if TYPE_CHECKING:
    import numpy as np

    from geoloc.photos.photo import Photo
    from geoloc.vision.facades import ImageAnalysis

# RGB colours for horizontal VPs 1, 2, ... (vertical: white; outliers: grey).
VP_COLORS: tuple[tuple[int, int, int], ...] = (
    (255, 60, 60),
    (60, 220, 60),
    (70, 130, 255),
    (255, 170, 0),
    (220, 60, 220),
    (0, 220, 220),
    (170, 120, 60),
    (255, 255, 90),
)
VERTICAL_COLOR = (255, 255, 255)
OUTLIER_COLOR = (150, 150, 150)


def vp_color(index: int) -> tuple[int, int, int]:
    """RGB colour of VP row ``index`` (0 = vertical, -1 = outlier)."""
    if index < 0:
        return OUTLIER_COLOR
    if index == 0:
        return VERTICAL_COLOR
    return VP_COLORS[(index - 1) % len(VP_COLORS)]


# ----------------------------------------------------------------------------------------------
# Loading


def read_photo(path: Path, hfov_deg: float | None = None) -> Photo:
    """The photo as the service reads it (:func:`geoloc.photos.photo.load_photo`), its field of view overridden.

    Focal length: ``hfov_deg`` if given (explicit override, ``source="given"``), else EXIF
    FocalLengthIn35mmFilm, else the default horizontal field of view (:data:`geoloc.core.camera.DEFAULT_HFOV_DEG`).
    """
    # The method's modules load numpy: imported when a command reads a photo, for CLI start-up time.
    from geoloc.core.camera import Intrinsics
    from geoloc.photos.photo import load_photo

    photo = load_photo(path)
    if hfov_deg is not None:
        width, height = photo.intrinsics.width, photo.intrinsics.height
        photo.intrinsics = Intrinsics.from_hfov(width, height, hfov_deg, source="given")
    return photo


def load_labels(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """Read a label image (class codes as pixel values, e.g. a simulator's ground truth PNG)."""
    import cv2
    import numpy as np
    from PIL import Image

    with Image.open(path) as im:
        lab = np.asarray(im)
    if lab.ndim == 3:
        lab = lab[:, :, 0]
    if lab.shape != shape:
        lab = cv2.resize(lab.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return lab.astype(np.uint8)


# ----------------------------------------------------------------------------------------------
# Drawing


def _dashed_line(
    img: np.ndarray,
    p0: tuple[float, float],
    p1: tuple[float, float],
    color: Any,
    thickness: int = 1,
    dash_px: float = 10.0,
) -> None:
    import cv2
    import numpy as np

    a, b = np.asarray(p0, float), np.asarray(p1, float)
    length = float(np.linalg.norm(b - a))
    if not math.isfinite(length) or length < 1e-6:
        return
    n = max(1, int(length // dash_px))
    for i in range(0, n, 2):
        s = a + (b - a) * (i / n)
        e = a + (b - a) * (min(i + 1, n) / n)
        cv2.line(img, (round(s[0]), round(s[1])), (round(e[0]), round(e[1])), color, thickness, cv2.LINE_AA)


def _text(img: np.ndarray, text: str, org: tuple[int, int], color: Any, scale: float = 0.5) -> None:
    import cv2

    thick = max(1, round(scale * 2))
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, color, thick, cv2.LINE_AA)


def draw_segmentation(image: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Class colours blended over the photo, with a legend."""
    import numpy as np

    # The method's modules load numpy and OpenCV: imported when a command draws, for CLI start-up time.
    from geoloc.core.labels import CLASS_COLORS, CLASS_NAMES, colorize

    out = (0.45 * image + 0.55 * colorize(labels)).astype(np.uint8)
    scale = max(0.4, image.shape[1] / 1600)
    for i, name in enumerate(CLASS_NAMES):
        _text(out, name, (10, round(25 * scale * 1.6 * (i + 1))), tuple(int(c) for c in CLASS_COLORS[i]), scale)
    return out


def draw_lines(image: np.ndarray, analysis: ImageAnalysis) -> np.ndarray:
    """Segments coloured by VP, horizon, legend."""
    import cv2
    import numpy as np

    gray = cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), cv2.COLOR_GRAY2RGB)
    out = (0.55 * gray).astype(np.uint8)
    h, w = out.shape[:2]
    thick = max(1, round(w / 700))
    vps = analysis.vanishing_points
    order = np.argsort(vps.assignment >= 0, kind="stable")  # outliers first (underneath)
    for i in order:
        x1, y1, x2, y2 = analysis.segments[i]
        k = int(vps.assignment[i])
        cv2.line(out, (round(x1), round(y1)), (round(x2), round(y2)), vp_color(k), thick if k >= 0 else 1, cv2.LINE_AA)
    a, b, c = vps.horizon_line(analysis.intrinsics)
    if abs(b) > 1e-6:
        _dashed_line(out, (0, -c / b), (w - 1, -(c + a * (w - 1)) / b), (255, 255, 0), 1, dash_px=14)
    scale = max(0.45, w / 1500)
    step = round(28 * scale * 1.5)
    _text(
        out,
        f"pitch {vps.pitch_deg:+.1f} deg  roll {vps.roll_deg:+.1f} deg  "
        f"hfov {analysis.intrinsics.hfov_deg:.1f} deg ({analysis.intrinsics.source})",
        (10, step),
        (255, 255, 0),
        scale,
    )
    _text(out, f"vertical: {int(np.sum(vps.assignment == 0))} segs", (10, 2 * step), VERTICAL_COLOR, scale)
    for k in range(1, vps.n_horizontal + 1):
        n_k = int(np.sum(vps.assignment == k))
        _text(out, f"VP{k}: theta {vps.theta_deg[k]:+.1f} deg, {n_k} segs", (10, (k + 2) * step), vp_color(k), scale)
    return out


def _piece_table(analysis: ImageAnalysis) -> np.ndarray:
    """(C + 1, W) VP index of the piece covering each (component, column), -1 where none."""
    import numpy as np

    deco = analysis.decomposition
    n_c = int(deco.components.max()) if deco.components.size else 0
    table = np.full((n_c + 1, analysis.intrinsics.width), -1)
    for p in deco.pieces:
        table[p.component, p.x_start : p.x_end] = p.vp_index
    return table


def draw_facades(image: np.ndarray, analysis: ImageAnalysis) -> np.ndarray:
    """Building pixels tinted by facade piece, dashed cutting lines, theta labels, confidence strip."""
    import numpy as np

    deco = analysis.decomposition
    h, w = image.shape[:2]
    out = (0.6 * image).astype(np.uint8)
    table = _piece_table(analysis)
    comp = deco.components
    vp_of_pixel = table[comp, np.arange(w)[None, :]]
    vp_of_pixel[comp == 0] = -2
    palette = np.array([vp_color(k) for k in range(0, 1 + max(1, analysis.vanishing_points.n_horizontal))])
    tinted = vp_of_pixel >= 1
    out[tinted] = (0.5 * image[tinted] + 0.5 * palette[vp_of_pixel[tinted]]).astype(np.uint8)
    unexplained = vp_of_pixel == -1  # building without a hypothesis
    out[unexplained] = (0.5 * image[unexplained] + 0.5 * np.array(OUTLIER_COLOR)).astype(np.uint8)
    thick = max(1, round(w / 600))
    for x in deco.cut_columns:
        _dashed_line(out, (float(x), 0.0), (float(x), float(h - 1)), (255, 255, 255), thick, dash_px=max(8.0, h / 50))
    scale = max(0.45, w / 1600)
    rows_any = np.flatnonzero(comp.any(axis=1))
    top_default = int(rows_any[0]) if len(rows_any) else h // 3
    for p in deco.pieces:
        cols = comp[:, p.x_start : p.x_end] == p.component
        rows = np.flatnonzero(cols.any(axis=1))
        y = int(rows[0]) if len(rows) else top_default
        y = min(max(y + round(30 * scale), round(30 * scale)), h - 40)
        xc = (p.x_start + p.x_end) // 2 - round(30 * scale)
        if p.x_end - p.x_start > 25:
            _text(out, f"{p.theta_deg:+.0f}", (max(0, xc), y), vp_color(p.vp_index), scale * 1.2)
    # Confidence strip: height ~ column_present, colour = dominant VP.
    strip = max(12, h // 25)
    out[h - strip :] = 0
    present = deco.column_present
    heights = np.round(present * (strip - 2)).astype(int)
    yy = np.arange(strip)[:, None]
    bar = (strip - 1 - yy) < heights[None, :]
    colours = palette[np.clip(deco.column_vp, 0, len(palette) - 1)]
    region = out[h - strip :]
    region[bar] = np.broadcast_to(colours[None, :, :], (strip, w, 3))[bar]
    return out


def draw_birdseye(analysis: ImageAnalysis, size_px: int = 640) -> np.ndarray:
    """Top view: camera, field of view, principal plane, facade pieces at unit depth with their theta."""
    import numpy as np

    intr = analysis.intrinsics
    w_px, h_px = size_px, round(size_px * 0.8)
    out = np.full((h_px, w_px, 3), 255, np.uint8)
    cam = np.array([w_px / 2.0, h_px - 40.0])
    scale = 0.55 * h_px  # px per unit depth

    def to_px(x: float, z: float) -> tuple[float, float]:
        return cam[0] + scale * x, cam[1] - scale * z

    half = math.radians(intr.hfov_deg / 2.0)
    for s in (-1, 1):
        _dashed_line(out, tuple(cam), to_px(s * 1.6 * math.sin(half), 1.6 * math.cos(half)), (160, 160, 160), 1)
    _dashed_line(out, to_px(-0.9, 0.0), to_px(0.9, 0.0), (0, 0, 0), 1, dash_px=8)  # principal plane
    import cv2

    cv2.circle(out, (round(cam[0]), round(cam[1])), 5, (0, 0, 0), -1, cv2.LINE_AA)
    cv2.arrowedLine(
        out,
        (round(cam[0]), round(cam[1])),
        (round(cam[0]), round(cam[1] - 40)),
        (0, 0, 0),
        1,
        cv2.LINE_AA,
        tipLength=0.25,
    )
    for p in analysis.decomposition.pieces:
        a0, a1 = np.radians(intr.column_angle_deg(np.array([p.x_start, p.x_end - 1]) + 0.5))
        ac = 0.5 * (a0 + a1)
        t = math.radians(p.theta_deg)
        u = np.array([math.cos(t), -math.sin(t)])  # along-wall direction (x, z)
        centre = np.array([math.tan(ac), 1.0])  # unit depth along the central ray
        ends = []
        for a in (a0, a1):
            ray = np.array([math.sin(a), math.cos(a)])
            m = np.column_stack([ray, -u])
            if abs(np.linalg.det(m)) < 1e-6:
                ends.append(centre)
                continue
            tt, _ = np.linalg.solve(m, centre)
            ends.append(tt * ray if tt > 0 else centre)
        # On the wall line through the centre, at most 0.35 units to either side (walls seen at a
        # grazing angle would run off to infinity).
        offsets = [float(np.clip(np.dot(e - centre, u), -0.35, 0.35)) for e in ends]
        proj = [centre + o * u for o in offsets]
        color = vp_color(p.vp_index)
        p0, p1 = to_px(*proj[0]), to_px(*proj[1])
        cv2.line(out, (round(p0[0]), round(p0[1])), (round(p1[0]), round(p1[1])), color, 3, cv2.LINE_AA)
        c_px = to_px(*centre)
        normal = np.array([math.sin(t), math.cos(t)])
        normal = -normal if normal[1] > 0 else normal  # draw the normal facing the camera
        n_px = to_px(*(centre + 0.08 * normal))
        cv2.line(out, (round(c_px[0]), round(c_px[1])), (round(n_px[0]), round(n_px[1])), color, 1, cv2.LINE_AA)
        _text(out, f"{p.theta_deg:+.0f}", (round(c_px[0]) + 4, round(c_px[1]) - 6), color, 0.45)
    _text(
        out, "bird's-eye: facades at unit depth (depth unknown); dashed = principal plane", (8, 18), (60, 60, 60), 0.42
    )
    return out


def draw_overview(panels: list[np.ndarray], height_px: int = 480) -> np.ndarray:
    """Panels resized to a common height, two per row."""
    import cv2
    import numpy as np

    resized = [
        cv2.resize(p, (round(p.shape[1] * height_px / p.shape[0]), height_px), interpolation=cv2.INTER_AREA)
        for p in panels
    ]
    rows = []
    for i in range(0, len(resized), 2):
        pair = resized[i : i + 2]
        rows.append(np.hstack(pair) if len(pair) == 2 else pair[0])
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.vstack(rows)


def write_outputs(
    image: np.ndarray, labels: np.ndarray, analysis: ImageAnalysis, out_dir: Path, stem: str, extra: dict | None = None
) -> dict[str, Path]:
    """Write the overlays and the JSON summary; returns the written paths by kind."""
    from PIL import Image

    out_dir.mkdir(parents=True, exist_ok=True)
    panels = {
        "segmentation": draw_segmentation(image, labels),
        "lines": draw_lines(image, analysis),
        "facades": draw_facades(image, analysis),
        "birdseye": draw_birdseye(analysis),
    }
    panels["overview"] = draw_overview(list(panels.values()))
    paths: dict[str, Path] = {}
    for name, arr in panels.items():
        path = out_dir / f"{stem}_{name}.png"
        Image.fromarray(arr).save(path)
        paths[name] = path
    summary = analysis.to_dict()
    summary.update(extra or {})
    path = out_dir / f"{stem}_summary.json"
    path.write_text(json.dumps(summary, indent=2))
    paths["summary"] = path
    return paths


# ----------------------------------------------------------------------------------------------
# Command


def analyze(
    image: Path = typer.Argument(..., exists=True, dir_okay=False, readable=True, help="Photo (JPEG/PNG)."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the overlays and summary JSON."),
    hfov: float | None = typer.Option(
        None, "--hfov", help="Horizontal field of view (deg); overrides EXIF. Default: EXIF focal length, else 60."
    ),
    labels: Path | None = typer.Option(
        None, "--labels", exists=True, dir_okay=False, help="Label image (class codes) to use instead of segmentation."
    ),
) -> None:
    """Segmentation, lines, vanishing points and facade orientations of one photo, as overlays + JSON.

    The photo is read as the service reads it (:func:`geoloc.photos.photo.load_photo`: EXIF orientation, at
    most 1024 pixels on the long side), so the overlays show the pixels the method sees.
    """
    import time

    # The method's modules load numpy and OpenCV: imported when the command runs, for CLI start-up time.
    from geoloc.vision.facades import analyze_image

    try:
        photo = read_photo(image, hfov)
    except (OSError, ValueError) as exc:  # a missing file, or data Pillow cannot decode
        typer.echo(f"error: cannot read {image} as an image ({exc})", err=True)
        raise typer.Exit(2) from exc
    rgb, intr = photo.image_rgb, photo.intrinsics
    t0 = time.perf_counter()
    if labels is not None:
        lab = load_labels(labels, rgb.shape[:2])
        seg_source = str(labels)
    else:
        # Loads onnxruntime's session factory and the workers' settings: for CLI start-up time.
        from geoloc.vision.segmentation import load_session, segment
        from workers.context import method_context

        try:
            lab = segment(rgb, session=load_session(method_context()))
        except FileNotFoundError as exc:  # ONNX model not built
            typer.echo(f"error: {exc}\n(or pass --labels LABELS.png)", err=True)
            raise typer.Exit(2) from exc
        seg_source = "geoloc.vision.segmentation"
    t_seg = time.perf_counter() - t0
    analysis = analyze_image(rgb, lab, intr)
    analysis.timings_s["segmentation"] = t_seg
    paths = write_outputs(rgb, lab, analysis, out, image.stem, {"source": str(image), "labels": seg_source})
    vps = analysis.vanishing_points
    thetas = ", ".join(f"{t:+.1f}" for t in vps.theta_deg[1:])
    typer.echo(
        f"{image.name}: {len(analysis.segments)} segments, pitch {vps.pitch_deg:+.1f} roll {vps.roll_deg:+.1f} deg, "
        f"horizontal VPs theta [{thetas}], {len(analysis.decomposition.pieces)} facade pieces "
        f"(hfov {intr.hfov_deg:.1f} deg from {intr.source})"
    )
    for kind, path in paths.items():
        typer.echo(f"  {kind}: {path}")
