"""How far a query trusts its transferred identities: by how near the references that transfer them stand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from geoloc.localize.anchors import MapAnchors
from geoloc.localize.grid import PositionPrior
from geoloc.localize.matching import ReferenceMatch
from geoloc.localize.query.retrieve import identity_trust
from geoloc.localize.store import StoredReference
from geoloc.vision.features import Features


def _reference(name: str, xy: tuple[float, float]) -> StoredReference:
    anchors = MapAnchors(np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, int), np.zeros(0))
    return StoredReference(
        name, Features.empty((480, 640)), np.zeros((0, 0)), np.zeros(0, int), anchors, np.eye(2), np.array(xy)
    )


def _match(name: str, inliers: int) -> ReferenceMatch:
    return ReferenceMatch(name, 0.5, inliers, inliers, "F", np.zeros((0, 2), int))


def test_identities_from_a_reference_near_the_prior_are_trusted_and_from_far_ones_not() -> None:
    stored = {"near": _reference("near", (3.0, 4.0)), "far": _reference("far", (150.0, 0.0))}
    prior = PositionPrior(0.0, 0.0, 25.0)
    scale = 25.0**2 + 30.0**2
    # The nearest of the top k counts: one reference 5 m away vouches for the transfer.
    both = identity_trust(stored, [_match("far", 43), _match("near", 16)], 4, prior, 30.0)
    assert both == pytest.approx(math.exp(-0.5 * 25.0 / scale))
    far = identity_trust(stored, [_match("far", 43)], 4, prior, 30.0)
    assert far == pytest.approx(math.exp(-0.5 * 150.0**2 / scale)) and far < 0.01
    # Only the top k transfer: a near reference below them does not vouch.
    assert identity_trust(stored, [_match("far", 43), _match("near", 16)], 1, prior, 30.0) == pytest.approx(far)


def test_identities_are_trusted_without_a_prior_a_view_distance_or_a_known_position() -> None:
    stored = {"far": _reference("far", (150.0, 0.0)), "unknown": _reference("unknown", (math.nan, math.nan))}
    prior = PositionPrior(0.0, 0.0, 25.0)
    assert identity_trust(stored, [_match("far", 43)], 4, None, 30.0) == 1.0
    assert identity_trust(stored, [_match("far", 43)], 4, prior, 0.0) == 1.0
    assert identity_trust(stored, [_match("far", 43), _match("unknown", 20)], 4, prior, 30.0) == 1.0
    assert identity_trust(stored, [], 4, prior, 30.0) == 1.0
