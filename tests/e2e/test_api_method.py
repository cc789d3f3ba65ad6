"""The whole service with the real method.

A real server on loopback, real worker processes, a real SQLite file, the Helsinki map, and a simulated
world's photos ingested and queried through the API.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import shapely

from benchmarks.bench_places import nearest_address
from contracts.settings import shared_path
from geoloc.localize.query import PRESETS
from geoloc.maps.places import VIEW_MARGIN_M, find_place, place_index
from geoloc.sim.world import WorldOptions, generate_world, load_world
from geoloc.vision.model_files import SEG_DEFAULT_SIZE
from geoloc.vision.onnx_session import CUDA_PROVIDER, available_providers
from tests.conftest import Profile
from tests.geojson_checks import check_query_collection
from tests.service_fixtures import read_rows, running_service, wait_for

N_REFERENCES = 16

pytestmark = pytest.mark.slow  # the real method end to end: minutes


@pytest.fixture(scope="module")
def world_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("api-world")
    generate_world(
        shared_path("data", "osm", "helsinki.osm.pbf"),
        out,
        WorldOptions(n_references=N_REFERENCES, n_queries=4, seed=3, radius_m=110.0, query_gps_noise_m=10.0),
    )
    return out


def _upload_map(client: httpx.Client) -> int:
    path = shared_path("data", "osm", "helsinki.osm.pbf")
    with path.open("rb") as f:
        response = client.post("/v1/maps", files={"file": (path.name, f)}, data={"wait_s": "120", "name": "helsinki"})
    assert response.status_code in (200, 201), response.text
    return response.json()["id"]


def _upload_reference(client: httpx.Client, map_id: int, path: Path) -> dict[str, Any]:
    response = client.post(f"/v1/maps/{map_id}/references", files={"image": (path.name, path.read_bytes())})
    assert response.status_code in (200, 202), response.text
    return response.json()


def _wait_done(client: httpx.Client, reference_ids: list[int], timeout: float = 600.0) -> dict[int, dict[str, Any]]:
    def all_finished() -> dict[int, dict] | None:
        rows = {rid: client.get(f"/v1/references/{rid}").json() for rid in reference_ids}
        return rows if all(r["status"] in ("done", "failed") for r in rows.values()) else None

    return wait_for(all_finished, timeout=timeout, interval=1.0, what="references to be labelled")


def _angle(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_ingest_label_and_query_through_the_api(
    tmp_path: Path, built_models: Path, world_dir: Path, profile: Profile
) -> None:
    world = load_world(world_dir)
    env = profile.new_env()
    with (
        running_service(tmp_path, workers=2, models=built_models, **env) as service,
        service.client(timeout=300.0) as client,
    ):
        map_id = _upload_map(client)
        accepted = {im.name: _upload_reference(client, map_id, im.path)["id"] for im in world.references}
        done = _wait_done(client, list(accepted.values()))
        assert all(r["status"] == "done" for r in done.values()), [r["error"] for r in done.values()]

        # References: the estimated heading and the buildings seen, against the renderer's truth.
        heading_errors = [
            _angle(done[accepted[im.name]]["estimated"]["heading_deg"], im.record["pose"]["heading_deg"])
            for im in world.references
        ]
        assert np.mean(np.array(heading_errors) <= 10.0) >= 0.6, np.round(heading_errors, 1)
        png = client.get(f"/v1/references/{accepted[world.references[0].name]}/labels.png")
        assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"

        # Queries (EXIF GPS 10 m off, used as a prior): right buildings named, true position among the answers.
        seen_by_references = {
            b["osm_id"] for im in world.references for b in im.record["buildings"] if b["pixel_share"] >= 0.02
        }
        named_right, found = [], []
        for image in world.queries:
            response = client.post(
                f"/v1/maps/{map_id}/queries", files={"image": (image.path.name, image.path.read_bytes())}
            )
            assert response.status_code == 200, response.text
            answer = response.json()
            assert answer["status"] == "done", answer
            result = answer["result"]
            assert result["search"]["position_prior"] and len(result["locations"]) == 10
            # Continuous poses with an honest-looking 90 % radius, and the stage's configuration recorded.
            assert all(loc["source"] in ("anchors", "likelihood") for loc in result["locations"])
            assert all(0.0 < loc["uncertainty_radius_m"] < 1000.0 for loc in result["locations"])
            assert result["search"]["config"] == PRESETS["balanced"].as_dict() and "anchors" in result["search"]
            assert result["search"]["preset"] == answer["params"]["preset"] == "balanced"
            # GEOLOC_DEVICE=auto: the GPU only where onnxruntime has the CUDA provider.
            assert result["search"]["device"] == ("cuda" if CUDA_PROVIDER in available_providers() else "cpu")
            assert result["search"]["segmentation"] == f"espnetv2_s2_city_{SEG_DEFAULT_SIZE[0]}x{SEG_DEFAULT_SIZE[1]}"
            heat = np.array(result["heatmap"]["values"])
            assert list(heat.shape) == result["heatmap"]["shape"] and heat.sum() == pytest.approx(1.0, abs=1e-3)
            # Identities come from references: judge the buildings (over 5 % of the photo) that one shows.
            truth = {b["osm_id"] for b in image.record["buildings"] if b["pixel_share"] > 0.05} & seen_by_references
            named = {b["osm_id"] for b in result["buildings"]}
            named_right.append(bool(truth & named) if truth else None)
            frame = world.load_map().frame
            true_xy = np.array([image.pose.x_m, image.pose.y_m])
            top5 = np.array([frame.to_local(loc["lat"], loc["lon"]) for loc in result["locations"][:5]], dtype=float)
            found.append(float(np.min(np.hypot(*(top5 - true_xy).T))))
            geojson = client.get(f"/v1/queries/{answer['id']}/answer.geojson").json()
            assert len(geojson["features"]) == 10
            # The same real answer for GIS tools: poses, view cones, the identified buildings' footprints.
            gis = client.get(f"/v1/queries/{answer['id']}", headers={"Accept": "application/geo+json"}).json()
            by_type = check_query_collection(gis, answer)
            assert len(by_type["building"]) == len(result["buildings"]) and gis["attribution"] == answer["attribution"]
            assert client.get(f"/v1/queries/{answer['id']}/heatmap.png").content[:4] == b"\x89PNG"
        judged = [n for n in named_right if n is not None]
        assert judged and np.mean(judged) >= 0.6, named_right

        # A fast query is answered with the fast preset's configuration, recorded with its answer.
        image = world.queries[0]
        response = client.post(
            f"/v1/maps/{map_id}/queries",
            files={"image": (image.path.name, image.path.read_bytes())},
            data={"preset": "fast"},
        )
        assert response.status_code == 200, response.text
        fast = response.json()
        assert fast["status"] == "done" and fast["params"]["preset"] == "fast", fast
        assert fast["result"]["search"]["config"] == PRESETS["fast"].as_dict()
        assert fast["result"]["search"]["preset"] == "fast" and len(fast["result"]["locations"]) == 10
        assert np.mean(np.array(found) <= 15.0) >= 0.5, np.round(found, 1)
        _check_a_place_query(client, map_id, world)


def _check_a_place_query(client: httpx.Client, map_id: int, world: Any) -> None:
    """A query given its camera's nearest address is answered near that building's walls (the shaped prior)."""
    city, image = world.load_map(), world.queries[0]
    address, _ = nearest_address(city, image.pose.x_m, image.pose.y_m) or pytest.fail("no addressed building")
    response = client.post(
        f"/v1/maps/{map_id}/queries",
        files={"image": (image.path.name, image.path.read_bytes())},
        data={"place": address, "use_exif_gps": "false"},
    )
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["status"] == "done" and answer["params"]["prior"]["source"] == "place", answer
    assert answer["result"]["search"]["position_prior_shaped"]
    kind = answer["params"]["prior"]["place_kind"]
    place = find_place(place_index(city), address, kind, image.pose.x_m, image.pose.y_m)
    assert place is not None and place.geometry is not None
    for loc in answer["result"]["locations"][:3]:  # within the band's 3 sigma of the walls, not the disc's
        x, y = (float(v) for v in city.frame.to_local(loc["lat"], loc["lon"]))
        assert shapely.distance(place.geometry, shapely.Point(x, y)) <= 1.5 * VIEW_MARGIN_M, (loc, address)


def test_killed_worker_and_restarted_service_lose_no_reference(
    tmp_path: Path,
    built_models: Path,
    world_dir: Path,
    profile: Profile,
) -> None:
    world = load_world(world_dir)
    photos = [im.path for im in world.references[:6]]
    env = profile.new_env()  # the restarted service finds the same database (and broker)
    with (
        running_service(tmp_path, workers=1, models=built_models, **env) as service,
        service.client(timeout=120.0) as client,
    ):
        map_id = _upload_map(client)
        first = [_upload_reference(client, map_id, p)["id"] for p in photos[:3]]

        def running_job() -> dict | None:
            rows = read_rows(
                service.database, "SELECT * FROM jobs WHERE status = 'running' AND lease_owner IS NOT NULL"
            )
            return rows[0] if rows else None

        job = wait_for(running_job, timeout=120, what="a labelling job to start")
        os.kill(int(job["lease_owner"].split(":")[1]), signal.SIGKILL)  # a new worker takes it after the lease
    # The whole service stops mid-ingest (SIGTERM to the supervisor), then starts again on the same data.
    with (
        running_service(tmp_path, workers=1, models=built_models, **env) as service,
        service.client(timeout=120.0) as client,
    ):
        again = [_upload_reference(client, map_id, p) for p in photos]
        assert [a["id"] for a in again[:3]] == first and all(a.get("duplicate") for a in again[:3])
        ids = [a["id"] for a in again]
        done = _wait_done(client, ids)
        assert all(r["status"] == "done" for r in done.values()), [r["error"] for r in done.values()]
        rows = read_rows(service.database, "SELECT id FROM reference_images WHERE map_id = ?", (map_id,))
        assert sorted(r["id"] for r in rows) == sorted(ids)  # nothing lost, nothing duplicated
        jobs = read_rows(service.database, "SELECT reference_id, status FROM jobs WHERE kind = 'label_reference'")
        assert sorted(j["reference_id"] for j in jobs) == sorted(ids)
