"""Source trees the suite evaluates: a commit exported with ``git archive``, and a tree's content fingerprint.

:func:`export_commit` is the one export of a baseline commit (the speed benchmarks' ``benchmarks/baseline.py`` use
it too). :func:`tree_fingerprint` names what a tree's evaluation results depend on: the sources the evaluation
runs (``contracts`` and ``geoloc`` less the suite's own reporting code) and the built models; the suite caches
a world's outcomes under it, so a tree whose method is unchanged is not evaluated again.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import tarfile
from pathlib import Path

from contracts.settings import REPO_ROOT

FINGERPRINTED = ("contracts", "geoloc")
"""The packages whose sources the method's results depend on (the evaluation imports nothing above them)."""
NOT_FINGERPRINTED = ("geoloc/evaluation/suite",)
"""The suite's reporting code changes no outcome (its runner, ``outcomes.py``, is keyed on its own)."""


def export_commit(ref: str, target: Path, repo: Path = REPO_ROOT) -> str:
    """``git archive REF`` of ``repo`` into ``target`` (emptied first); returns the commit's short id."""
    commit = subprocess.run(
        ["git", "rev-parse", "--short", ref], cwd=repo, capture_output=True, text=True, check=True
    ).stdout.strip()
    shutil.rmtree(target, ignore_errors=True)
    target.mkdir(parents=True)
    archive = target.parent / f"{target.name}.tar"
    subprocess.run(["git", "archive", "-o", str(archive), commit], cwd=repo, check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(target, filter="data")
    archive.unlink()
    return commit


def resolve_commit(ref: str, repo: Path = REPO_ROOT) -> str:
    """The full commit id ``ref`` names in ``repo``; ValueError when it names none."""
    command = ["git", "rev-parse", "--verify", f"{ref}^{{commit}}"]
    done = subprocess.run(command, cwd=repo, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ValueError(f"{ref!r} names no commit of {repo}")
    return done.stdout.strip()


def tree_fingerprint(tree: Path, models: Path | None = None) -> str:
    """sha256 (24 hex digits) of the tree's runtime sources (:data:`FINGERPRINTED`) and the built models' files."""
    digest = hashlib.sha256()
    for package in FINGERPRINTED:
        for source in sorted((tree / package).rglob("*.py")):
            relative = source.relative_to(tree).as_posix()
            if relative.startswith(NOT_FINGERPRINTED):
                continue
            digest.update(relative.encode())
            digest.update(source.read_bytes())
    if models is not None and models.is_dir():
        for path in sorted(p for p in models.rglob("*") if p.is_file()):
            digest.update(f"{path.relative_to(models).as_posix()}:{path.stat().st_size}".encode())
            if path.suffix == ".json":
                digest.update(path.read_bytes())
    return digest.hexdigest()[:24]
