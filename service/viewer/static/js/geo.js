// Geometry for the page: a local east-north metric plane around the map's origin, colours shared with
// the service's overlays, and small helpers (field of view, distances, scale-bar lengths).

const WGS84_A = 6378137.0;
const WGS84_E2 = 0.00669437999014;
const DEG = Math.PI / 180;

/**
 * Local tangent plane at (lat0, lon0): x east, y north, metres, from the WGS84 ellipsoid's radii of
 * curvature at the origin. Over a city map (a few km) it differs from the service's azimuthal
 * equidistant frame by well under a metre; north is up everywhere on screen.
 */
export class LocalPlane {
  constructor(lat0, lon0) {
    this.lat0 = lat0;
    this.lon0 = lon0;
    const s = 1 - WGS84_E2 * Math.sin(lat0 * DEG) ** 2;
    this.metresPerDegLat = DEG * (WGS84_A * (1 - WGS84_E2)) / s ** 1.5;
    this.metresPerDegLon = DEG * (WGS84_A * Math.cos(lat0 * DEG)) / Math.sqrt(s);
  }

  /** WGS84 degrees -> [east_m, north_m]. */
  toLocal(lat, lon) {
    return [(lon - this.lon0) * this.metresPerDegLon, (lat - this.lat0) * this.metresPerDegLat];
  }

  /** [east_m, north_m] -> [lat, lon] degrees. */
  toLatLon(x, y) {
    return [this.lat0 + y / this.metresPerDegLat, this.lon0 + x / this.metresPerDegLon];
  }
}

/**
 * The colour of a building id, as the service's labels.png draws it (service/rendering.py: golden-ratio
 * hue, OpenCV HSV saturation 200/255, value 255), so a building has one colour in photos and on the map.
 */
export function buildingColor(buildingId) {
  const hue = (buildingId * 0.618033988749895) % 1.0;
  const h = Math.floor(hue * 179) * 2; // OpenCV stores hue / 2 in a byte
  const s = 200 / 255;
  const c = s;
  const x = c * (1 - Math.abs(((h / 60) % 2) - 1));
  const m = 1 - c;
  const [r, g, b] =
    h < 60 ? [c, x, 0] : h < 120 ? [x, c, 0] : h < 180 ? [0, c, x] : h < 240 ? [0, x, c] : h < 300 ? [x, 0, c] : [c, 0, x];
  const hex = (v) => Math.round((v + m) * 255).toString(16).padStart(2, "0");
  return `#${hex(r)}${hex(g)}${hex(b)}`;
}

/** Horizontal field of view (deg) of a photo from its 35 mm-equivalent focal length (applied to the
 * longer side, as the service does), else the service's default of 60 degrees. */
export function horizontalFovDeg(focal35mm, width, height) {
  if (!focal35mm || !width || !height) return 60;
  const halfWidthMm = (36 / 2) * (width / Math.max(width, height));
  return (2 * Math.atan(halfWidthMm / focal35mm)) / DEG;
}

/** The largest 1-2-5 x 10^k value not above `value`. */
export function niceLength(value) {
  const power = 10 ** Math.floor(Math.log10(value));
  const unit = value / power;
  return (unit >= 5 ? 5 : unit >= 2 ? 2 : 1) * power;
}

/** "850 m" / "1.2 km". */
export function formatDistance(metres) {
  return metres >= 1000 ? `${+(metres / 1000).toFixed(1)} km` : `${Math.round(metres)} m`;
}

/** Bearing difference in degrees, in [0, 180]. */
export function angleDiffDeg(a, b) {
  return Math.abs(((a - b + 540) % 360) - 180);
}
