"""tools/deepen_checkpoint.py: the written checkpoint has the new depths, loads strictly and answers as the old one."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.model import D4RT

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "deepen_checkpoint.py"
spec = importlib.util.spec_from_file_location("deepen_checkpoint", SCRIPT)
deepen_checkpoint = importlib.util.module_from_spec(spec)
spec.loader.exec_module(deepen_checkpoint)


def test_the_deepened_checkpoint_loads_and_answers_as_before(tmp_path, capsys):
    torch.manual_seed(0)
    base = D4RT(D4RTConfig.preset("tiny", encoder_depth=2, decoder_depth=1))
    with torch.no_grad():
        for parameter in base.parameters():
            parameter.add_(0.05 * torch.randn_like(parameter))
    base.save_pretrained(tmp_path / "base")
    deepen_checkpoint.main([str(tmp_path / "base"), "--encoder-depth", "4", "--decoder-depth", "3",
                            "--out", str(tmp_path / "deep")])
    grown = D4RT.from_pretrained(tmp_path / "deep")  # strict load
    assert (grown.config.encoder_depth, grown.config.decoder_depth) == (4, 3)
    assert deepen_checkpoint.largest_difference(D4RT.from_pretrained(tmp_path / "base"), grown) < 1e-5
    assert "2/1 blocks" in capsys.readouterr().out


def test_a_shrinking_depth_is_one_line(tmp_path, capsys):
    torch.manual_seed(0)
    D4RT(D4RTConfig.preset("tiny", encoder_depth=4)).save_pretrained(tmp_path / "base")
    with pytest.raises(SystemExit) as stop:
        deepen_checkpoint.main([str(tmp_path / "base"), "--encoder-depth", "2", "--out", str(tmp_path / "deep")])
    assert stop.value.code == 2 and "grows a model" in capsys.readouterr().err
    assert not (tmp_path / "deep").exists()
