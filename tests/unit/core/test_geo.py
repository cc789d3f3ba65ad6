import math
import threading
from collections.abc import Callable
from functools import partial
from typing import TypeVar
from unittest import mock

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Transformer
from pyproj._transformer import _Transformer

from geoloc.core.geo import LocalFrame, bearing_deg, bearing_vector

FRAME = LocalFrame(60.1716, 24.9443)
T = TypeVar("T")


@settings(max_examples=200, deadline=None)
@given(
    st.floats(min_value=-5000, max_value=5000, allow_nan=False),
    st.floats(min_value=-5000, max_value=5000, allow_nan=False),
)
def test_local_wgs84_round_trip(east_m: float, north_m: float) -> None:
    lat, lon = FRAME.to_wgs84(east_m, north_m)
    e2, n2 = FRAME.to_local(lat, lon)
    # PROJ's aeqd snaps points within ~1e-10 rad of the origin onto it: millimetres are what matter.
    assert abs(e2 - east_m) < 1e-3 and abs(n2 - north_m) < 1e-3


@settings(max_examples=100, deadline=None)
@given(
    st.floats(min_value=-89.0, max_value=89.0),
    st.floats(min_value=-179.0, max_value=179.0),
    st.floats(min_value=-0.02, max_value=0.02),
    st.floats(min_value=-0.02, max_value=0.02),
)
def test_wgs84_local_round_trip_any_origin(lat0: float, lon0: float, dlat: float, dlon: float) -> None:
    frame = LocalFrame(lat0, lon0)
    e, n = frame.to_local(lat0 + dlat, lon0 + dlon)
    lat, lon = frame.to_wgs84(e, n)
    # In metres, as above: PROJ snaps a point within ~1e-10 rad of the origin onto it, which near the poles is
    # several 1e-8 degrees of longitude but under a millimetre on the ground.
    north_error_m = abs(lat - (lat0 + dlat)) * 111_320.0
    east_error_m = abs(lon - (lon0 + dlon)) * 111_320.0 * math.cos(math.radians(lat0))
    assert north_error_m < 1e-3 and east_error_m < 1e-3


def test_metres_are_metres() -> None:
    # On the WGS84 ellipsoid one arc-minute of latitude at 60.17 N is 1856.9 m (meridional radius
    # 6.3835e6 m); 0.001 deg of longitude there is 55.5 m.
    _, north = FRAME.to_local(60.1716 + 1 / 60, 24.9443)
    east, _ = FRAME.to_local(60.1716, 24.9443 + 0.001)
    assert abs(float(north) - 1856.9) < 0.5
    assert abs(float(east) - 55.5) < 0.3


@settings(max_examples=100, deadline=None)
@given(
    st.floats(min_value=0, max_value=359.99),
    st.floats(min_value=-3000, max_value=3000),
    st.floats(min_value=-3000, max_value=3000),
)
def test_heading_bearing_round_trip(heading: float, east_m: float, north_m: float) -> None:
    bearing = FRAME.heading_to_bearing(heading, east_m, north_m)
    back = FRAME.bearing_to_heading(bearing, east_m, north_m)
    assert abs((back - heading + 180) % 360 - 180) < 1e-9


def test_heading_is_bearing_at_origin_and_converges_east() -> None:
    assert abs(float(FRAME.heading_to_bearing(90.0)) - 90.0) < 1e-6
    # East of the origin, true north leans west of grid north... in this projection meridians converge
    # towards the pole, so at +3 km east true north points slightly west of grid north (negative).
    conv = float(FRAME.meridian_convergence_deg(3000.0, 0.0))
    assert -3.0 < conv < 0.0


def test_bearing_helpers() -> None:
    assert np.allclose(bearing_deg(np.array([0, 1, 0, -1]), np.array([1, 0, -1, 0])), [0, 90, 180, 270])
    assert np.allclose(bearing_vector(90.0), [1.0, 0.0])


def _on_new_thread(work: Callable[[], T]) -> T:
    """``work()`` run on a fresh thread (as each worker job is), its result returned."""
    results: list[T] = []
    thread = threading.Thread(target=lambda: results.append(work()))
    thread.start()
    thread.join()
    return results[0]


def test_transformers_match_pyprojs_own_choice_bit_for_bit_on_a_new_thread() -> None:
    """The pipeline transformers give PROJ's ``from_crs`` results exactly, near and far, on a job's thread."""
    rng = np.random.default_rng(7)
    origins = [(60.169912345678912, 24.938412345678901), (52.52, 13.405), (-33.8688, 151.2093), (0.5, -179.9)]
    origins += [(float(rng.uniform(-85, 85)), float(rng.uniform(-180, 180))) for _ in range(8)]
    for lat0, lon0 in origins:
        frame = LocalFrame(lat0, lon0)
        definition = f"+proj=aeqd +lat_0={lat0!r} +lon_0={lon0!r} +ellps=WGS84 +units=m"
        forward = Transformer.from_crs("EPSG:4326", definition, always_xy=True)
        inverse = Transformer.from_crs(definition, "EPSG:4326", always_xy=True)
        lat = np.concatenate([lat0 + rng.normal(0, 0.05, 2000), rng.uniform(-89.9, 89.9, 2000)])
        lon = np.concatenate([lon0 + rng.normal(0, 0.05, 2000), rng.uniform(-180, 180, 2000)])
        east = np.concatenate([rng.normal(0, 5000, 2000), rng.uniform(-1.9e7, 1.9e7, 2000), [0.0, 1e-9]])
        north = np.concatenate([rng.normal(0, 5000, 2000), rng.uniform(-1.9e7, 1.9e7, 2000), [0.0, -1e-9]])
        got_local = _on_new_thread(partial(frame.to_local, lat, lon))
        got_wgs84 = _on_new_thread(partial(frame.to_wgs84, east, north))
        want_east, want_north = forward.transform(lon, lat)
        want_lon, want_lat = inverse.transform(east, north)
        for got, want in zip(got_local + got_wgs84, (want_east, want_north, want_lat, want_lon), strict=True):
            assert np.array_equal(got, want, equal_nan=True)


def test_a_new_thread_does_not_search_the_proj_database_again() -> None:
    """A job's thread makes its PROJ objects from the pipeline string, not with ``proj_create_crs_to_crs``."""
    frame = LocalFrame(60.1716, 24.9443)
    frame.to_local(60.17, 24.94)  # this thread's objects
    # pyproj makes each thread's PROJ object with its extension type _Transformer: watch which maker runs.
    with mock.patch("pyproj.transformer._Transformer", wraps=_Transformer) as proj:
        proj.from_crs.side_effect = AssertionError("the PROJ database was searched again")
        lat, lon = _on_new_thread(lambda: frame.to_wgs84(120.0, -40.0))
        east, north = _on_new_thread(lambda: frame.to_local(lat, lon))
    assert proj.from_pipeline.call_count == 2
    assert abs(float(east) - 120.0) < 1e-6 and abs(float(north) + 40.0) < 1e-6
