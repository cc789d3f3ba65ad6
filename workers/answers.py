"""Check what a job computed against the API's answer models before it is stored.

The query and label handlers call these on the dicts they are about to store. A malformed answer
(a missing or unknown field, a wrong type, a NaN) raises :class:`PermanentJobError`: the job fails
at once, without retries, and its error (shown by ``GET /v1/jobs/{id}`` and on the query or
reference) names the field. What is stored is the model's JSON form, exactly what the API serves.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ValidationError

from service.answers import QueryResult, ReferenceLabels
from workers.handlers import PermanentJobError


def checked_query_answer(result: dict[str, Any]) -> dict[str, Any]:
    """The query answer ``result`` as :class:`service.answers.QueryResult` serves it.

    Parameters
    ----------
    result
        The answer as built by the query handler (JSON-like).

    Returns
    -------
    dict[str, Any]
        The validated answer in its JSON form, ready to store.

    Raises
    ------
    PermanentJobError
        The answer does not match the model; the message lists each bad field and why.
    """
    return _checked(QueryResult, result, "query answer")


def checked_reference_labels(labels: dict[str, Any]) -> dict[str, Any]:
    """A reference's labelling result (``estimated``, ``buildings_seen``, ``timings``), validated.

    Parameters
    ----------
    labels
        ``{"estimated": {"lat", "lon", "heading_deg"}, "buildings_seen": [...], "timings": {...}}``.

    Returns
    -------
    dict[str, Any]
        The same in the JSON form :class:`service.answers.ReferenceLabels` serves.

    Raises
    ------
    PermanentJobError
        The result does not match the model; the message lists each bad field and why.
    """
    return _checked(ReferenceLabels, labels, "reference labels")


def _checked(model: type[BaseModel], data: dict[str, Any], what: str) -> dict[str, Any]:
    try:
        return model.model_validate(data).model_dump(mode="json")
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(part) for part in error['loc']) or '(root)'}: {error['msg']}"
            for error in exc.errors(include_url=False)
        )
        raise PermanentJobError(
            f"malformed {what}, not stored ({exc.error_count()} problem(s) against {model.__name__}): {problems}"
        ) from None
