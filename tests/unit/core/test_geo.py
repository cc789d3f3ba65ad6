import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from geoloc.core.geo import LocalFrame, bearing_deg, bearing_vector

FRAME = LocalFrame(60.1716, 24.9443)


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
