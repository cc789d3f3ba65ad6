"""Which files of a folder ``geoloc ingest`` uploads: photos by content, one per sha256, in path order.

Also the per-file record (:class:`FileResult`) that the upload and the report fill in.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from client import ReferenceFields
from geoloc.photos.geotag import DESCRIPTION_FILE

OUTCOMES: dict[str, str] = {
    "accepted": "accepted (new reference)",
    "present": "already present (same sha256)",
    "duplicate": "duplicate within the folder",
    "rejected": "rejected by the service",
    "skipped": "skipped (not a photo, or not placed by --gpx)",
    "failed": "failed after retries",
}
"""Outcome of one file -> its label in the summary, in summary order."""


HEIF_BRANDS = {b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"mif1", b"msf1"}
"""ISO-BMFF major brands of HEIC/HEIF photos (the ``ftyp`` box at byte 4)."""


def sniff_photo(head: bytes) -> str | None:
    """MIME type of a photo from its first bytes (JPEG, PNG, WEBP, TIFF, HEIC/HEIF), else None."""
    if head.startswith(b"\xff\xd8\xff"):
        return "image/jpeg"
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "image/png"
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "image/webp"
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return "image/tiff"
    if head[4:8] == b"ftyp" and head[8:12] in HEIF_BRANDS:
        return "image/heic"
    return None


@dataclass
class FileResult:
    """What happened to one file (one row of ``--json``)."""

    path: str
    outcome: str
    reason: str | None = None
    sha256: str | None = None
    size_bytes: int | None = None
    mime_type: str | None = None
    http_status: int | None = None
    error_code: str | None = None
    details: dict[str, Any] | None = None
    reference_id: int | None = None
    job_id: int | None = None
    attempts: int = 0
    duplicate_of: str | None = None
    final_status: str | None = None
    final_error: str | None = None
    form_fields: dict[str, Any] | None = None
    """The form fields sent with the photo (``--gpx``, Mapillary's description file), None when none were."""
    field_sources: dict[str, str] | None = None
    """Where each sent field came from (``position``, ``heading``, ``sequence``: the track, the description)."""


@dataclass
class Candidate:
    """A photo to upload."""

    path: Path
    relative: str
    sha256: str
    size_bytes: int
    mime_type: str
    fields: ReferenceFields = field(default_factory=ReferenceFields)
    """The upload's form fields (:mod:`cli.ingest_geotag`: position, heading, sequence); empty: EXIF only."""
    field_sources: dict[str, str] = field(default_factory=dict)


def path_order(relative: str) -> tuple[tuple[str, ...], str, str]:
    """Sort key of a relative path: by folder, then name without suffix (``a.jpg`` before ``a-copy.jpg``)."""
    path = Path(relative)
    return path.parent.parts, path.stem, path.suffix


def scan_folder(folder: Path, *, recursive: bool) -> tuple[list[Candidate], list[FileResult]]:
    """Photos to upload (sorted by path, content-checked, hashed, one per sha256) and the files skipped.

    Mapillary's description files (``mapillary_image_description.json``) are metadata, read by
    :mod:`cli.ingest_geotag`: neither uploaded nor listed.
    """
    found = (
        p for p in (folder.rglob("*") if recursive else folder.iterdir()) if p.is_file() and p.name != DESCRIPTION_FILE
    )
    paths = sorted(found, key=lambda p: path_order(p.relative_to(folder).as_posix()))
    candidates: list[Candidate] = []
    others: list[FileResult] = []
    first_by_sha: dict[str, str] = {}
    for path in paths:
        relative = path.relative_to(folder).as_posix()
        try:
            data = path.read_bytes()
        except OSError as exc:
            others.append(FileResult(relative, "skipped", f"cannot read the file: {exc.strerror or exc}"))
            continue
        if not data:
            others.append(FileResult(relative, "skipped", "empty file", size_bytes=0))
            continue
        mime = sniff_photo(data[:16])
        if mime is None:
            others.append(
                FileResult(
                    relative,
                    "skipped",
                    "not a photo: content is not JPEG, PNG, WEBP, TIFF or HEIC",
                    size_bytes=len(data),
                )
            )
            continue
        sha = hashlib.sha256(data).hexdigest()
        if sha in first_by_sha:
            others.append(
                FileResult(
                    relative,
                    "duplicate",
                    f"same content as {first_by_sha[sha]}; uploaded once",
                    sha256=sha,
                    size_bytes=len(data),
                    mime_type=mime,
                    duplicate_of=first_by_sha[sha],
                )
            )
            continue
        first_by_sha[sha] = relative
        candidates.append(Candidate(path, relative, sha, len(data), mime))
    return candidates, others
