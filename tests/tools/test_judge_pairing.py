"""benchmarks/judge_pairing.py: the judge's camera figure by PAIRING, and the candidate's pairing written once."""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from judge_pairing import best_pairing, camera_ate, main  # noqa: E402

ROW = {"trajectory_ate": {"first": {"mean": 0.12, "median": 0.1}, "adjacent": {"mean": 0.09, "median": 0.06},
                          "graph": {"mean": 0.07, "median": 0.05}, "static": {"mean": 0.01, "median": 0.01},
                          "constant_velocity": {"mean": 0.005, "median": 0.004}}}


def test_the_camera_figure_is_adjacents_unless_the_best_pairing_is_asked_for(monkeypatch):
    monkeypatch.delenv("PAIRING", raising=False)
    assert camera_ate(ROW) == 0.09
    monkeypatch.setenv("PAIRING", "best")
    assert camera_ate(ROW) == 0.07 and best_pairing(ROW) == "graph"  # the reference cameras never count


def test_the_candidate_carries_its_best_pairing(tmp_path, monkeypatch, capsys):
    probe, config = tmp_path / "probe.json", tmp_path / "config.json"
    probe.write_text(json.dumps({"models": {"/j/avg-1": ROW}}))
    config.write_text(json.dumps({"preset": "tiny", "pose_pairs": "adjacent"}))
    monkeypatch.setattr(sys, "argv", ["judge_pairing.py", str(probe), "/j/avg-1", str(config)])
    main()
    assert json.loads(config.read_text()) == {"preset": "tiny", "pose_pairs": "graph"}
    assert "candidate pairing: graph" in capsys.readouterr().out
