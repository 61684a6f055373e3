"""Transfer across buildings of another width (docs/journal/places.md, session 17): random
world 806 is a 1.9 m corridor, the world of its protocol (c) (seed 1806) a 3.9 m one. Taught
in the first, the default calls the second's whole corridor "hall" (its walls are as far
apart as the taught hall's); with each log stretched across the path to one usual free width
(`Config.canonical_width`) the corridor is found."""

from __future__ import annotations

import pytest

from toolkit.features.evaluate import protocol_scores, worlds
from toolkit.features.model import Config

pytestmark = pytest.mark.slow


def test_a_wider_buildings_corridor_is_found_at_a_canonical_width() -> None:
    runs = worlds(806)
    default = protocol_scores(Config(), runs)["c"]
    canonical = protocol_scores(Config(canonical_width=2.0), runs)["c"]
    assert default["recall"]["corridor"] < 0.05  # 0.000: every corridor scan called hall
    assert default["ece"] > 0.5  # 0.728
    assert canonical["recall"]["corridor"] > 0.9  # 0.975
    assert canonical["ba"] > default["ba"] + 0.2  # 0.698 against 0.440
    assert canonical["ece"] < 0.1  # 0.057
