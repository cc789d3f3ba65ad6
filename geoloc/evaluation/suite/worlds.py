"""The accuracy suite's worlds: the declared list (``worlds.toml``), their content keys and their rendering cache.

A :class:`SuiteWorld` is one simulated world of the list: a map (a file under the shared data folder), a centre
(WGS84), a seed, a capture kind (``walk``, ``scattered`` or ``tracks``: a walk world whose queries are query
tracks), its urban form and its split (``dev`` or ``test``). :func:`load_suite` reads and checks the list;
:func:`world_key` is the content key a rendered world is cached under (the map file's bytes, the simulator's
source, the world's options); :func:`rendered_world` renders a world once into ``CACHE/suite/worlds/KEY`` and
returns its folder, written atomically (a world is rendered into a temporary folder and renamed, so an
interrupted render leaves nothing that reads as done).
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from geoloc.sim.options import WorldOptions
from geoloc.vision.model_files import sha256_file

__all__ = [
    "CAPTURES",
    "FORMS",
    "SPLITS",
    "WORLDS_TOML",
    "Suite",
    "SuiteWorld",
    "load_suite",
    "rendered_world",
    "world_key",
]

WORLDS_TOML = Path(__file__).with_name("worlds.toml")
"""The declared list of worlds (versioned with the code)."""

SPLITS = ("dev", "test")
CAPTURES = ("walk", "scattered", "tracks")
FORMS = ("closed_blocks", "squares_parks", "wide_roads", "waterfront", "sparse_detached")
"""The urban forms a world is labelled with: closed blocks (facades close on both sides of narrow streets),
squares and parks (open ground inside the built area), wide roads (facades far from the carriageway), waterfronts
(buildings on one side only), sparse or detached buildings (few, small, far apart)."""

SIM_SOURCES = Path(__file__).resolve().parents[2] / "sim"
"""The simulator's package: its sources are part of every world's key (a changed renderer renders anew)."""

Capture = Literal["walk", "scattered", "tracks"]


@dataclass(frozen=True)
class SuiteWorld:
    """One world of the suite: where, how it was captured, its form and split, and its simulator options."""

    name: str
    split: str
    capture: Capture
    form: str
    map_file: str  # under the shared data folder, e.g. "osm/helsinki.osm.pbf"
    centre_wgs84: tuple[float, float]  # latitude, longitude (deg)
    seed: int
    references: int
    queries: int
    radius_m: float
    query_tracks: int
    track_length: int

    def options(self) -> WorldOptions:
        """The simulator's options of this world (a tracks world: a walk world with query tracks, no singles)."""
        tracks = self.capture == "tracks"
        return WorldOptions(
            n_references=self.references,
            n_queries=0 if tracks else self.queries,
            seed=self.seed,
            radius_m=self.radius_m,
            capture="scattered" if self.capture == "scattered" else "walk",
            query_tracks=self.query_tracks if tracks else 0,
            track_length=self.track_length,
            centre_wgs84=self.centre_wgs84,
        )

    def as_dict(self) -> dict[str, Any]:
        """What ``geoloc eval suite --list --json`` prints of the world."""
        return {
            "name": self.name,
            "split": self.split,
            "map": self.map_file,
            "centre_wgs84": list(self.centre_wgs84),
            "seed": self.seed,
            "capture": self.capture,
            "form": self.form,
            "references": self.references,
            "queries": 0 if self.capture == "tracks" else self.queries,
            "query_tracks": self.query_tracks if self.capture == "tracks" else 0,
            "track_length": self.track_length,
            "radius_m": self.radius_m,
        }


@dataclass(frozen=True)
class Suite:
    """The declared list: its version and worlds (both splits, in file order)."""

    version: int
    worlds: tuple[SuiteWorld, ...]

    def split(self, name: str) -> list[SuiteWorld]:
        """The worlds of split ``name`` (``dev`` or ``test``); ValueError for another name."""
        if name not in SPLITS:
            raise ValueError(f"unknown split {name!r}: expected one of {', '.join(SPLITS)}")
        return [w for w in self.worlds if w.split == name]


def load_suite(path: Path = WORLDS_TOML) -> Suite:
    """Read and check the list of worlds; ValueError naming the world and field that is wrong."""
    data = tomllib.loads(path.read_text())
    defaults: dict[str, Any] = data.get("defaults", {})
    maps: dict[str, str] = data.get("maps", {})
    worlds = []
    for entry in data.get("worlds", []):
        merged = {**defaults, **entry}
        name = str(merged.get("name", "?"))
        for key, allowed in (("split", SPLITS), ("capture", CAPTURES), ("form", FORMS)):
            if merged.get(key) not in allowed:
                raise ValueError(f"{path.name}: world {name}: {key} must be one of {allowed}, got {merged.get(key)!r}")
        if merged.get("map") not in maps:
            raise ValueError(f"{path.name}: world {name}: map {merged.get('map')!r} is not under [maps]")
        lat, lon = (float(v) for v in merged["centre"])
        worlds.append(
            SuiteWorld(
                name=name,
                split=merged["split"],
                capture=merged["capture"],
                form=merged["form"],
                map_file=maps[merged["map"]],
                centre_wgs84=(lat, lon),
                seed=int(merged["seed"]),
                references=int(merged["references"]),
                queries=int(merged["queries"]),
                radius_m=float(merged["radius_m"]),
                query_tracks=int(merged["query_tracks"]),
                track_length=int(merged["track_length"]),
            )
        )
    names = [w.name for w in worlds]
    if len(set(names)) != len(names):
        raise ValueError(f"{path.name}: world names repeat: {sorted({n for n in names if names.count(n) > 1})}")
    return Suite(int(data.get("version", 0)), tuple(worlds))


def simulator_digest() -> str:
    """sha256 over the simulator's Python sources (path and bytes, sorted): the generator's version."""
    digest = hashlib.sha256()
    for source in sorted(SIM_SOURCES.rglob("*.py")):
        digest.update(source.relative_to(SIM_SOURCES).as_posix().encode())
        digest.update(source.read_bytes())
    return digest.hexdigest()


def world_key(world: SuiteWorld, map_path: Path, generator: str | None = None) -> str:
    """The content key of a rendered world (20 hex digits).

    From the map file's bytes, the generator (:func:`simulator_digest`) and the world's options. The world's name,
    split and form are labels, not content: not in the key.
    """
    options = world.options()
    content = {
        "map_sha256": sha256_file(map_path),
        "generator": generator or simulator_digest(),
        "options": {k: getattr(options, k) for k in options.__dataclass_fields__},
    }
    return hashlib.sha256(json.dumps(content, sort_keys=True, default=list).encode()).hexdigest()[:20]


def rendered_world(
    world: SuiteWorld, map_path: Path, folder: Path, progress: Callable[[str], None] | None = None
) -> Path:
    """``folder`` (``CACHE/worlds/KEY``, :func:`world_key`) with ``world`` rendered from ``map_path`` in it.

    Rendered now unless already there.
    """
    # lazy: rendering loads the simulator's renderer (OpenCV, the compiled ray caster) only when a world is missing
    from geoloc.sim.world import generate_world

    if (folder / "manifest.json").is_file():
        return folder
    partial = folder.with_name(folder.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    generate_world(map_path, partial, world.options(), progress=progress)
    shutil.rmtree(folder, ignore_errors=True)
    partial.rename(folder)
    return folder
