"""Durability against real processes.

A corrupted stored photo, a map deleted under a running job, SIGKILL of the API in the middle of uploads,
and a full disk (a 20 MB tmpfs): jobs fail at once with a reason while the others go on, the database
stays consistent, writes on a full disk are ``507`` with nothing stored, and the service recovers once
there is space again.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sqlite3
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from contracts.settings import shared_path
from tests.conftest import Profile
from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    ONE_BUILDING,
    WRITE_KEY,
    RunningProcess,
    get_job_row,
    jpeg_bytes,
    read_rows,
    running_service,
    running_workers,
    stored_files,
    table_counts,
    upload_hall_map,
    wait_for,
)

pytestmark = pytest.mark.slow

FINAL = ("done", "failed", "cancelled")


def _upload_reference(client: httpx.Client, map_id: int, photo: bytes) -> httpx.Response:
    return client.post(f"/v1/maps/{map_id}/references", files={"image": ("r.jpg", photo)}, data=INSIDE_ONE_BUILDING)


def _final_job(db_path: Path, job_id: int, timeout: float = 180.0) -> dict[str, Any]:
    return dict(
        wait_for(
            lambda: (row := get_job_row(db_path, job_id))["status"] in FINAL and row,
            timeout=timeout,
            what=f"job {job_id} to end",
        )
    )


def _integrity(db_path: Path) -> str:
    conn = sqlite3.connect(str(db_path), timeout=30)
    try:
        return str(conn.execute("PRAGMA integrity_check").fetchone()[0])
    finally:
        conn.close()


def test_a_corrupted_stored_photo_fails_its_job_the_others_go_on(tmp_path: Path, built_models: Path) -> None:
    data_dir = tmp_path / "data"
    with running_service(data_dir, workers=0) as service, service.client(WRITE_KEY) as client:
        map_id = upload_hall_map(client)
        corrupted, good, gone = (_upload_reference(client, map_id, jpeg_bytes(seed=s)).json() for s in (1, 2, 3))
        for reference, damage in ((corrupted, "corrupt"), (gone, "delete")):
            path = data_dir / read_rows(service.database, "SELECT image_path FROM reference_images WHERE id = ?",
                                        (reference["id"],))[0]["image_path"]  # fmt: skip
            if damage == "corrupt":
                path.write_bytes(path.read_bytes()[:300] + os.urandom(2000))  # the header survives, the data not
            else:
                path.unlink()
        with running_workers(data_dir, models=built_models):
            jobs = {name: _final_job(service.database, ref["job_id"]) for name, ref in
                    (("corrupted", corrupted), ("good", good), ("gone", gone))}  # fmt: skip
        assert jobs["good"]["status"] == "done", jobs["good"]["error"]
        for name in ("corrupted", "gone"):
            assert jobs[name]["status"] == "failed" and jobs[name]["attempts"] == 1, (name, jobs[name])
            assert "cannot read the stored photo" in jobs[name]["error"], jobs[name]["error"]
        shown = client.get(f"/v1/references/{corrupted['id']}").json()
        assert shown["status"] == "failed" and "cannot read the stored photo" in shown["error"]


def test_a_map_deleted_under_a_running_job_fails_it_at_once(tmp_path: Path, built_models: Path) -> None:
    with (
        running_service(tmp_path / "data", workers=1, models=built_models) as service,
        service.client(WRITE_KEY, timeout=120) as client,
    ):
        with shared_path("data", "osm", "helsinki.osm.pbf").open("rb") as f:
            map_id = client.post(
                "/v1/maps", files={"file": ("h.osm.pbf", f)}, data={"wait_s": "120", "name": "h"}
            ).json()["id"]
        accepted = client.post(
            f"/v1/maps/{map_id}/references",
            files={"image": ("r.jpg", jpeg_bytes(1280, 960, seed=4))},
            data={"lat": "60.1716", "lon": "24.9443"},
        ).json()
        wait_for(
            lambda: get_job_row(service.database, accepted["job_id"])["status"] == "running",
            timeout=120,
            interval=0.02,
            what="the labelling job to start",
        )
        assert client.delete(f"/v1/maps/{map_id}").status_code == 204
        job = _final_job(service.database, accepted["job_id"])
        assert job["status"] == "failed" and job["attempts"] == 1, job
        assert job["error"].startswith(("reference 1 was deleted", "map 1 was deleted")), job["error"]


def _api_pid(supervisor: RunningProcess) -> int:
    """The API child (``python -m service``) of a ``geoloc serve`` supervisor."""
    pid = supervisor.process.pid
    children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    for child in children:
        if "service" in Path(f"/proc/{child}/cmdline").read_bytes().decode(errors="replace").split("\0"):
            return int(child)
    raise AssertionError(f"no API process among {children}")


def _slow_multipart(photo: bytes, chunk: int = 8192, pause_s: float = 0.05) -> tuple[Iterator[bytes], str]:
    """A reference upload body sent in small pieces (a slow client), and its content type."""
    boundary = "geoloc-slow-upload"
    head = "".join(
        f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"\r\n\r\n{value}\r\n'
        for name, value in INSIDE_ONE_BUILDING.items()
    )
    head += f'--{boundary}\r\nContent-Disposition: form-data; name="image"; filename="slow.jpg"\r\n'
    head += "Content-Type: image/jpeg\r\n\r\n"

    def body() -> Iterator[bytes]:
        yield head.encode()
        for start in range(0, len(photo), chunk):
            time.sleep(pause_s)
            yield photo[start : start + chunk]
        yield f"\r\n--{boundary}--\r\n".encode()

    return body(), f"multipart/form-data; boundary={boundary}"


def test_sigkill_of_the_api_mid_upload_loses_nothing(tmp_path: Path) -> None:
    photos = [jpeg_bytes(1600, 1200, seed=seed, quality=95) for seed in range(24)]
    with running_service(tmp_path / "data", workers=0) as service:
        with service.client(WRITE_KEY) as client:
            map_id = upload_hall_map(client)
        outcomes: dict[int, int | str] = {}

        def upload(index: int) -> None:
            with service.client(WRITE_KEY) as own:
                try:
                    if index % 3 == 0:  # a slow client: certainly mid-body when the API dies
                        body, content_type = _slow_multipart(photos[index])
                        response = own.post(f"/v1/maps/{map_id}/references", content=body,
                                            headers={"content-type": content_type})  # fmt: skip
                    else:
                        response = _upload_reference(own, map_id, photos[index])
                    outcomes[index] = response.status_code
                except httpx.HTTPError as exc:
                    outcomes[index] = type(exc).__name__

        threads = [threading.Thread(target=upload, args=(i,)) for i in range(len(photos))]
        for thread in threads:
            thread.start()
            time.sleep(0.02)
        time.sleep(0.4)
        os.kill(_api_pid(service), signal.SIGKILL)
        for thread in threads:
            thread.join(timeout=60)
        assert any(not isinstance(code, int) for code in outcomes.values()), f"some uploads were cut: {outcomes}"

        wait_for(lambda: _healthy(service), timeout=60, what="the supervisor to restart the API")
        assert _integrity(service.database) == "ok"
        _assert_every_row_complete(service)
        with service.client(WRITE_KEY) as client:  # every photo again: nothing lost, nothing twice
            again = [_upload_reference(client, map_id, photo) for photo in photos]
        assert {r.status_code for r in again} <= {200, 202}
        for index, response in enumerate(again):
            if outcomes[index] == 202:
                assert response.status_code == 200 and response.json()["duplicate"], "an accepted photo was kept"
        assert len(read_rows(service.database, "SELECT id FROM reference_images")) == len(photos)
        _assert_every_row_complete(service)


def _healthy(service: RunningProcess) -> bool:
    try:
        return httpx.get(f"{service.base_url}/healthz", timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


def _assert_every_row_complete(service: RunningProcess) -> None:
    """Every reference has its photo on disk and its job; every job of a reference points at one."""
    references = read_rows(service.database, "SELECT id, image_path, job_id FROM reference_images")
    reference_jobs = "SELECT id, reference_id FROM jobs WHERE kind != 'load_map'"  # the maps' own jobs aside
    jobs = {row["id"]: row for row in read_rows(service.database, reference_jobs)}
    for reference in references:
        assert (service.data_dir / reference["image_path"]).is_file(), reference
        assert jobs[reference["job_id"]]["reference_id"] == reference["id"], reference
    assert len(jobs) == len(references)


@contextlib.contextmanager
def _small_disk(mount_point: Path, size_mb: int = 20) -> Iterator[Path]:
    mount_point.mkdir(parents=True)
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(mount_point)],
        capture_output=True,
        text=True,
        check=False,
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a {size_mb} MB tmpfs to fill (needs root): {mounted.stderr.strip()}")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=False)


def _fill(path: Path, leave_bytes: int = 0) -> None:
    """Write ``path`` until the disk is full, then free ``leave_bytes`` again."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        for block in (b"\0" * 65536, b"\0" * 512):
            with contextlib.suppress(OSError):
                while os.write(fd, block):
                    pass
    finally:
        os.close(fd)
    if leave_bytes:
        os.truncate(path, max(path.stat().st_size - leave_bytes, 0))


def test_a_full_disk_answers_507_stores_nothing_and_recovers(tmp_path: Path, profile: Profile) -> None:
    """Both profiles: the data folder (with the file store) fills up; in the embedded one the SQLite file too."""
    env = profile.new_env()
    with _small_disk(tmp_path / "disk") as disk, running_service(disk, workers=0, **env) as service:
        filler = disk / "filler"
        with service.client(WRITE_KEY) as client:
            map_id = upload_hall_map(client)
            assert _upload_reference(client, map_id, jpeg_bytes(seed=1)).status_code == 202

            _fill(filler)
            counts, files = table_counts(service.database), stored_files(disk)
            for response in (
                _upload_reference(client, map_id, jpeg_bytes(seed=2)),
                client.post(f"/v1/maps/{map_id}/queries", files={"image": ("q.jpg", jpeg_bytes(seed=3))}),
                client.post(
                    "/v1/maps",
                    files={"file": ("m.geojson", json.dumps(ONE_BUILDING).replace("Hall", "Other hall").encode())},
                    data={"wait_s": "120", "name": "other"},
                ),
            ):
                assert response.status_code == 507, response.text
                error = response.json()["error"]
                assert error["code"] == "insufficient_storage" and "nothing was stored" in error["message"]
            assert table_counts(service.database) == counts and stored_files(disk) == files
            assert client.get(f"/v1/maps/{map_id}").status_code == 200, "reads work on a full disk"

            # Room for the photo itself but hardly more: the database write may fail instead (SQLite on this disk).
            # Either the upload is whole (202, the photo and its job stored) or absent (507); never half-stored,
            # never a 500.
            statuses: list[int] = []
            for step, spare in enumerate((0, 4096, 16384, 65536)):
                photo = jpeg_bytes(seed=10 + step)
                filler.unlink()
                _fill(filler, leave_bytes=len(photo) + spare)
                before = table_counts(service.database)
                response = _upload_reference(client, map_id, photo)
                assert response.status_code in (202, 507), response.text
                statuses.append(response.status_code)
                after = table_counts(service.database)
                if response.status_code == 507:
                    assert after == before
                else:
                    assert after["reference_images"] == before["reference_images"] + 1
                    assert after["jobs"] == before["jobs"] + 1
                _assert_every_row_complete(service)
                assert not list((disk / "tmp").glob("upload-*")), "no temporary upload left behind"
            assert statuses[0] == 507 or profile.distributed, statuses  # PostgreSQL's disk is not this one

            filler.unlink()
            recovered = _upload_reference(client, map_id, jpeg_bytes(seed=30))
            assert recovered.status_code == 202, recovered.text
            assert client.get(f"/v1/references/{recovered.json()['id']}").status_code == 200
            other = json.dumps(ONE_BUILDING).replace("Hall", "Other hall").encode()
            assert (
                client.post(
                    "/v1/maps", files={"file": ("m.geojson", other)}, data={"wait_s": "120", "name": "o"}
                ).status_code
                == 201
            )
        if not profile.distributed:
            assert _integrity(service.database) == "ok"
        _assert_every_row_complete(service)
