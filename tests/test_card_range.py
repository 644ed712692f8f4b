"""Issue 39, 9: a warning when a material's measured error is far outside its model card's range for its family."""

from __future__ import annotations

import pytest

from brdfcodec.models.card_range import FAR_FACTOR, card_range_warning, family_of
from brdfcodec.models.registry import default_model_folder
from brdfcodec.models.store import load_manifest


@pytest.fixture(scope="module")
def info() -> dict:
    return load_manifest(default_model_folder()).info


def test_families_follow_the_source_kind() -> None:
    assert family_of({}) == "merl" and family_of({"source_kind": "nbrdf-proxy"}) == "merl"
    assert family_of({"source_kind": "rgl-measured"}) == "rgl" and family_of({"source_kind": "analytic"}) is None


def test_a_merl_material_within_the_card_is_quiet_and_one_far_outside_is_named(info: dict) -> None:
    largest = max(split["mapped_max"] for split in info["summary"].values())
    typical = {"relae": {"mapped": largest, "linear": 0.1}}
    assert card_range_warning("m", typical, info, "default") is None
    far = {"relae": {"mapped": FAR_FACTOR * largest * 1.01, "linear": 0.1}}
    message = card_range_warning("m", far, info, "default")
    assert message is not None and message.startswith("m: RelAE far outside model default's card for merl")
    assert f"{largest:.4f}" in message and "--compare" in message


def test_measured_rgl_data_is_warned_about(info: dict) -> None:
    """The real paper_white: mapped 0.058 (inside the card's NBRDF-proxy-of-RGL figure), yet a visible tint."""
    meta = {"source_kind": "rgl-measured", "relae": {"mapped": 0.058, "linear": 0.67}}
    message = card_range_warning("paper_white", meta, info, "default")
    assert message is not None and "no measurement of such data" in message and "NBRDF proxy of RGL" in message


def test_no_warning_without_a_measurement_or_a_family(info: dict) -> None:
    assert card_range_warning("a", {"source_kind": "analytic", "relae": {"mapped": 9.0}}, info, "d") is None
    assert card_range_warning("a", {"source_kind": "rgl-measured"}, info, "d") is None
    assert card_range_warning("a", {"relae": {"mapped": 9.0}}, {}, "d") is None  # a card without measurements
