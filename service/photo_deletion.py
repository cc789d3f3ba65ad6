"""Deleting queries and tracks with their photos: a photo goes once no query uses it any more."""

from __future__ import annotations

from collections.abc import Callable

from fastapi import Response, status

from db import Database, transaction
from db import queries as query_store
from db.files import FileStore
from service.errors import ApiError


def delete_with_photos(
    db: Database, store: FileStore, what: str, delete: Callable[[Database], list[str | None] | None]
) -> Response:
    """Delete rows, then their photos that no query uses any more (the same photo asked again shares the file).

    ``delete`` runs in a transaction and returns the rows' photo paths (None: nothing to delete: 404); 204.
    """
    with transaction(db):
        paths = delete(db)
    if paths is None:
        raise ApiError(404, "not_found", f"{what} not found")
    with transaction(db):
        store.delete(*query_store.unreferenced_images(db, paths))
    return Response(status_code=status.HTTP_204_NO_CONTENT)
