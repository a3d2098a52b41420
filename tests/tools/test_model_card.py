"""tools/model_card.py: how the shipped weights' recipe is written out."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "model_card.py"
spec = importlib.util.spec_from_file_location("model_card", SCRIPT)
model_card = importlib.util.module_from_spec(spec)
spec.loader.exec_module(model_card)


def test_an_average_of_averages_is_written_with_brackets_and_kept_steps():
    assert model_card.average_text({"stages": [2, 4], "weights": [0.5, 0.5]}) == "0.5 x stage 2 + 0.5 x stage 4"
    inner = {"stages": [{"stages": [2, 4], "weights": [0.5, 0.5]}, 21], "weights": [0.5, 0.5], "steps": {"21": 4000}}
    nested = {"stages": [inner, 25], "weights": [0.5, 0.5], "steps": {"25": 3500}}
    assert model_card.average_text(nested) == ("0.5 x (0.5 x (0.5 x stage 2 + 0.5 x stage 4) + 0.5 x stage 21 "
                                               "(its step 4,000)) + 0.5 x stage 25 (its step 3,500)")
