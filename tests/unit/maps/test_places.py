"""The place search on the real Helsinki and Berlin extracts: names, addresses, streets, ambiguity, the priors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from contracts.settings import shared_path
from geoloc.maps import load_map, read_city_map, save_city_map
from geoloc.maps.model import CityMap
from geoloc.maps.places import VIEW_MARGIN_M, PlaceIndex, normalize, place_index, resolve_place


@pytest.fixture(scope="module")
def helsinki() -> CityMap:
    return load_map(shared_path("data", "osm", "helsinki.osm.pbf"))


@pytest.fixture(scope="module")
def berlin() -> CityMap:
    return load_map(shared_path("data", "berlin", "berlin_mitte.osm.gz"))


@pytest.fixture(scope="module")
def helsinki_places(helsinki: CityMap) -> PlaceIndex:
    return place_index(helsinki)


@pytest.fixture(scope="module")
def berlin_places(berlin: CityMap) -> PlaceIndex:
    return place_index(berlin)


def test_normalize_drops_accents_and_case() -> None:
    assert normalize("Karl-Liebknecht-Straße") == "karl liebknecht strasse"
    assert normalize("Töölönkatu ÄÄ") == "toolonkatu aa"
    assert normalize("Friedrichstr. 5") == "friedrichstrasse 5"


def test_an_address_is_its_building(helsinki: CityMap, helsinki_places: PlaceIndex) -> None:
    match = resolve_place(helsinki_places, "mannerheimintie 5")
    assert match.status == "found" and match.place is not None
    place = match.place
    assert (place.kind, place.name) == ("address", "Mannerheimintie 5")
    building = helsinki.buildings[place.building_id or 0]
    assert building.tags["addr:street"] == "Mannerheimintie" and building.tags["addr:housenumber"] == "5"
    centre = shapely.centroid(building.polygon)
    assert np.hypot(place.x_m - centre.x, place.y_m - centre.y) < 1.0
    corners = shapely.get_coordinates(building.polygon)
    reach = np.hypot(corners[:, 0] - centre.x, corners[:, 1] - centre.y).max()
    assert place.radius_m == pytest.approx(reach + VIEW_MARGIN_M, abs=0.2)


def test_a_street_covers_its_centreline(helsinki: CityMap, helsinki_places: PlaceIndex) -> None:
    match = resolve_place(helsinki_places, "Aleksanterinkatu")
    assert match.status == "found" and match.place is not None
    place = match.place
    assert (place.kind, place.name) == ("street", "Aleksanterinkatu")
    points = np.concatenate(
        [s for s, n in zip(helsinki.streets, helsinki.street_names, strict=True) if n == place.name]
    )
    assert np.hypot(points[:, 0] - place.x_m, points[:, 1] - place.y_m).max() <= place.radius_m + 1e-6
    assert place.radius_m > 200  # a long street: a wide, honest disc


def test_typos_accents_and_prefixes(helsinki_places: PlaceIndex, berlin_places: PlaceIndex) -> None:
    assert resolve_place(berlin_places, "berliner dom").place.name == "Berliner Dom"  # type: ignore[union-attr]
    assert resolve_place(helsinki_places, "Aleksanterinktu").place.name == "Aleksanterinkatu"  # type: ignore[union-attr]
    assert resolve_place(berlin_places, "karl liebknecht strasse").place.name == "Karl-Liebknecht-Straße"  # type: ignore[union-attr]
    first = helsinki_places.search("mannerheimint", limit=3)[0]
    assert first.name == "Mannerheimintie" and first.kind == "street"


def test_a_named_building_wins_over_its_landmark_point(berlin: CityMap, berlin_places: PlaceIndex) -> None:
    match = resolve_place(berlin_places, "Berliner Dom")
    assert match.status == "found" and match.place is not None
    assert match.place.kind == "building"
    assert berlin.buildings[match.place.building_id or 0].name == "Berliner Dom"
    kinds = {p.kind for p in berlin_places.search("Berliner Dom") if p.name == "Berliner Dom"}
    assert kinds == {"building", "landmark"}  # both known; one place


def test_the_same_name_in_two_places_is_ambiguous(berlin_places: PlaceIndex) -> None:
    match = resolve_place(berlin_places, "Motel One")
    assert match.status == "ambiguous" and match.place is None
    assert len(match.candidates) >= 2 and {c.name for c in match.candidates} == {"Motel One"}
    a, b = match.candidates[:2]
    assert np.hypot(a.x_m - b.x_m, a.y_m - b.y_m) > a.radius_m


def test_unknown_names_match_nothing(helsinki_places: PlaceIndex) -> None:
    assert resolve_place(helsinki_places, "Xyzzy Plugh").status == "unknown"
    assert resolve_place(helsinki_places, "Mannerheimintie 9999").place.kind == "street"  # type: ignore[union-attr]
    assert helsinki_places.search("   ") == []


def test_the_stored_map_keeps_what_places_need(berlin: CityMap, tmp_path: Path) -> None:
    path = tmp_path / "berlin.citymap.npz"
    save_city_map(berlin, path)
    back = read_city_map(path)
    assert back.street_names == berlin.street_names and len(back.street_names) == len(back.streets)
    assert back.landmark_names == berlin.landmark_names
    np.testing.assert_array_equal(back.landmark_lonlat, berlin.landmark_lonlat)
    assert [p.name for p in place_index(back).places] == [p.name for p in place_index(berlin).places]


def test_the_prior_of_a_place_follows_its_shape(helsinki: CityMap, helsinki_places: PlaceIndex) -> None:
    """A building's prior is a band along its walls, a street's a corridor along it, not the disc around them."""
    from geoloc.localize.grid import PositionPrior  # the query stage's prior, built from the maps layer's place

    address = resolve_place(helsinki_places, "mannerheimintie 5").place
    assert address is not None and address.geometry is not None
    prior = PositionPrior.of_place(address)
    assert prior.shape is not None and prior.radius_m == pytest.approx(VIEW_MARGIN_M)
    walls = shapely.get_coordinates(shapely.get_exterior_ring(address.geometry))
    outward = walls[0] + 10.0 * (walls[0] - np.array([address.x_m, address.y_m])) / np.hypot(
        *(walls[0] - np.array([address.x_m, address.y_m]))
    )
    # on the wall: weight 1; 10 m out: the band's Gaussian; the disc would have weighed the centre highest
    assert prior.weights(walls[:1])[0] == pytest.approx(1.0)
    assert prior.distances_m(outward[None, :])[0] == pytest.approx(10.0, abs=3.0)
    far = np.array([[address.x_m + 2 * address.radius_m, address.y_m]])
    assert prior.weights(far)[0] < 1e-3
    assert shapely.contains(prior.region(3.0), address.geometry)

    street = resolve_place(helsinki_places, "Aleksanterinkatu").place
    assert street is not None and street.prior_shape() is not None
    corridor = PositionPrior.of_place(street)
    line = shapely.get_coordinates(street.geometry)
    assert np.allclose(corridor.weights(line), 1.0)  # anywhere along the street, not only near its middle
    assert corridor.radius_m < street.radius_m / 5
    assert PositionPrior.of_place(street, radius_m=50.0).radius_m == 50.0  # the request's radius: from the line


def test_a_stored_place_is_found_again(helsinki: CityMap, helsinki_places: PlaceIndex) -> None:
    """What a query stores (name, kind, centre) gives the worker back the same place, with its shape."""
    from geoloc.maps.places import find_place

    for text in ("mannerheimintie 5", "Aleksanterinkatu"):
        place = resolve_place(helsinki_places, text).place
        assert place is not None
        again = find_place(helsinki_places, place.name, place.kind, place.x_m + 5.0, place.y_m)
        assert again is not None and (again.name, again.kind, again.x_m, again.y_m) == (
            place.name,
            place.kind,
            place.x_m,
            place.y_m,
        )
        assert again.geometry is not None
        assert shapely.equals(again.geometry, place.geometry)
    assert find_place(helsinki_places, "Mannerheimintie 5", "street", 0.0, 0.0) is None
    assert find_place(helsinki_places, "Nowhere 99", "address", 0.0, 0.0) is None
