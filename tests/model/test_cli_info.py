"""``d4rt info``: parameter counts of every preset, built on the meta device."""

import argparse
import json
import re

import pytest
import torch

import d4rt.cli
from d4rt.cli import info
from d4rt.config import D4RTConfig
from d4rt.model import D4RT


def run_info(argv, capsys):
    parser = argparse.ArgumentParser(prog="d4rt")
    info.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["info", *argv])
    assert args.func(args) == 0
    return capsys.readouterr().out


def printed_count(output: str, label: str) -> int:
    match = re.search(rf"^  {label}\s+([\d,]+)", output, flags=re.M)
    assert match, f"no '{label}' line in:\n{output}"
    return int(match.group(1).replace(",", ""))


def test_info_is_a_registered_subcommand():
    assert "info" in d4rt.cli.COMMANDS


@pytest.mark.parametrize("name", D4RTConfig.preset_names())
def test_info_prints_the_parameter_counts_of_every_preset(name, capsys):
    output = run_info(["--preset", name], capsys)
    assert f"D4RT model '{name}'" in output
    with torch.device("meta"):
        model = D4RT(D4RTConfig.preset(name))
    encoder = sum(p.numel() for p in model.encoder.parameters())
    total = sum(p.numel() for p in model.parameters())
    assert printed_count(output, "encoder") == encoder
    assert printed_count(output, "decoder") == total - encoder
    assert printed_count(output, "total") == total


def test_giant_matches_the_paper_sizes(capsys):
    output = run_info(["--preset", "giant"], capsys)
    # Paper: ViT-g encoder of about 1B parameters, decoder of about 144M; within 10%.
    assert printed_count(output, "encoder") == pytest.approx(1e9, rel=0.10)
    assert printed_count(output, "decoder") == pytest.approx(144e6, rel=0.10)


def test_tiny_and_small_are_cpu_sized(capsys):
    for name in ("tiny", "small"):
        assert printed_count(run_info(["--preset", name], capsys), "total") < 15e6


def test_info_json_and_config_file(tmp_path, capsys):
    config = D4RTConfig.preset("tiny", decoder_depth=2)
    config.save(tmp_path / "config.json")
    data = json.loads(run_info(["--config", str(tmp_path / "config.json"), "--json"], capsys))
    assert data["config"] == config.to_dict()
    assert data["parameters"]["total"] == data["parameters"]["encoder"] + data["parameters"]["decoder"]


def test_main_entry_point_runs_info(capsys):
    # The full CLI also imports the other subcommands; skip until they are present in this checkout.
    for name in d4rt.cli.COMMANDS:
        pytest.importorskip(f"d4rt.cli.{name}")
    assert d4rt.cli.main(["info", "--preset", "base"]) == 0
    assert "D4RT model 'base'" in capsys.readouterr().out
