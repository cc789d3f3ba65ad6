// The probability heatmap: the answer's grid as a canvas, one texel per grid cell, drawn into the map's heat
// layer without smoothing so every cell keeps its value.

/** Heatmap colour for t in (0, 1] (a magma-like ramp) and its opacity: faint where the probability is
 * small but never invisible, so every non-zero cell shows. */
function heatColor(t) {
  const stops = [
    [0.0, [72, 18, 140]],
    [0.35, [190, 40, 120]],
    [0.7, [250, 125, 40]],
    [1.0, [255, 232, 90]],
  ];
  let i = 1;
  while (i < stops.length - 1 && t > stops[i][0]) i += 1;
  const [t0, c0] = stops[i - 1];
  const [t1, c1] = stops[i];
  const f = Math.min(1, Math.max(0, (t - t0) / (t1 - t0)));
  const rgb = c0.map((v, k) => Math.round(v + f * (c1[k] - v)));
  return [...rgb, Math.round(255 * (0.3 + 0.55 * t))];
}

/** The answer's heatmap as a canvas, with its outer edges in local metres of `plane` (a LocalPlane). */
export function heatImage(heatmap, plane) {
  const [rows, cols] = heatmap.shape;
  const values = heatmap.values;
  let max = 0;
  for (const row of values) for (const v of row) max = Math.max(max, v);
  const canvas = document.createElement("canvas");
  canvas.width = cols;
  canvas.height = rows;
  const ctx = canvas.getContext("2d");
  const image = ctx.createImageData(cols, rows);
  for (let r = 0; r < rows; r += 1) {
    for (let c = 0; c < cols; c += 1) {
      const v = values[r][c];
      if (!(v > 0) || !(max > 0)) continue;
      const [red, green, blue, alpha] = heatColor(Math.sqrt(v / max));
      const i = 4 * ((rows - 1 - r) * cols + c); // row 0 of the grid is its southern edge
      image.data[i] = red;
      image.data[i + 1] = green;
      image.data[i + 2] = blue;
      image.data[i + 3] = alpha;
    }
  }
  ctx.putImageData(image, 0, 0);
  const [ox, oy] = plane.toLocal(heatmap.origin.lat, heatmap.origin.lon);
  const cell = heatmap.cell_m;
  // outer edges of the grid in local metres: cell (0, 0) is centred on the origin
  return { canvas, left: ox - cell / 2, top: oy + (rows - 0.5) * cell, width: cols * cell, height: rows * cell };
}

/** Draw a heat image (null: none) onto the heat layer's canvas at the view's centre and scale. */
export function drawHeat(canvas, hm, view) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.round(view.width * dpr);
  const h = Math.round(view.height * dpr);
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, w, h);
  if (!hm) return;
  const [x, y] = view.toScreen(hm.left, hm.top);
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(hm.canvas, x, y, hm.width * view.scale, hm.height * view.scale);
}
