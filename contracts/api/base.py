"""The base of the API's envelope models and what several resources share."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class ApiModel(BaseModel):
    """Base of the API's request and response envelopes: read-only once built; unknown fields are ignored.

    Ignored, not refused: a client parsing a newer service's answer (a field added) still parses it. The
    parts that workers compute (:mod:`contracts.answers`) are stricter: they refuse unknown fields.
    """

    model_config = ConfigDict(extra="ignore", frozen=True)


Attribution = Annotated[
    str,
    Field(
        description="The map data's attribution, to show with anything derived from the map: the map upload's "
        '`attribution` field, else "© OpenStreetMap contributors" (every format; docs/licenses.md)',
        examples=["© OpenStreetMap contributors"],
    ),
]
"""An answer's or a map's ``attribution`` (:func:`contracts.licenses.map_attribution`)."""
