"""The camera figure judge_guarded_stage.sh compares, by its PAIRING setting (stage 73).

``camera_ate(row)``: a camera_probe model row's held-out mean trajectory ATE: adjacent's (PAIRING=adjacent, the
default of stages 29-72), or the lowest over the pairings the probe reports (PAIRING=best). As a script,
``judge_pairing.py PROBE.json MODEL CONFIG.json`` writes MODEL's best pairing into CONFIG.json's ``pose_pairs``.
"""

from __future__ import annotations

import json
import os
import sys

from d4rt.config import POSE_PAIRS


def pairing_figures(row: dict) -> dict[str, float]:
    """Mean held-out ATE per pairing (the probe's reference cameras, static and constant-velocity, left out)."""
    return {pairs: ate["mean"] for pairs, ate in row["trajectory_ate"].items() if pairs in POSE_PAIRS}


def best_pairing(row: dict) -> str:
    figures = pairing_figures(row)
    return min(figures, key=figures.get)


def camera_ate(row: dict) -> float:
    if os.environ.get("PAIRING", "adjacent") == "best":
        return pairing_figures(row)[best_pairing(row)]
    return row["trajectory_ate"]["adjacent"]["mean"]


def main() -> None:
    probe, model, config_path = sys.argv[1:]
    row = json.load(open(probe))["models"][model]
    config = json.load(open(config_path))
    config["pose_pairs"] = best_pairing(row)
    json.dump(config, open(config_path, "w"), indent=2)
    print(f"candidate pairing: {config['pose_pairs']} (held-out mean ATE {pairing_figures(row)})")


if __name__ == "__main__":
    main()
