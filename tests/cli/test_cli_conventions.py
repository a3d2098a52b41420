"""What every `d4rt` command shares: --version, --no-progress, -o/--out, one size syntax, help on every
option, and argument errors reported before torch is imported."""

import subprocess
import sys

import pytest

from d4rt.cli import COMMANDS, build_parser, main, parse_size
from d4rt.errors import UserError
from subprocess_budget import budget


def _in_a_fresh_interpreter(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=budget(120))


def test_a_bad_input_path_is_reported_before_torch_loads(tmp_path):
    r = _in_a_fresh_interpreter(
        "import sys\nfrom d4rt.cli import main\n"
        f"status = main(['reconstruct', {str(tmp_path / 'missing.mp4')!r}, '-o', {str(tmp_path / 'out')!r}])\n"
        "print(status, 'torch' in sys.modules)")
    assert r.stdout.split() == ["2", "False"], r.stderr
    assert r.stderr.strip().endswith("missing.mp4 does not exist") and len(r.stderr.strip().splitlines()) == 1


def test_version_and_no_progress(capsys, tmp_path):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.startswith("d4rt ")
    # The same generation with and without bars: --no-progress (before or after the command) silences them,
    # and the switch does not outlive the call.
    for flags, bars in (((), True), (("--no-progress",), False), ((), True)):
        assert main([*flags, "generate", "-o", str(tmp_path / "clips"), "--num-clips", "1", "--frames", "2",
                     "--size", "16x12"]) == 0
        assert ("generate:" in capsys.readouterr().err) == bars, flags
    assert main(["generate", "--no-progress", "-o", str(tmp_path / "clips"), "--num-clips", "1", "--frames", "2",
                 "--size", "16"]) == 0
    assert "generate:" not in capsys.readouterr().err


def test_one_size_syntax():
    assert parse_size("640x480", "--size") == (480, 640) and parse_size("256", "--size") == (256, 256)
    for bad in ("640x", "x480", "0x10", "big", "1x2x3"):
        with pytest.raises(UserError, match="--size must be WIDTHxHEIGHT"):
            parse_size(bad, "--size")


def test_every_option_of_every_command_has_help_and_out_has_its_short_form():
    parser = build_parser()
    for name, sub in parser._subparsers._group_actions[0].choices.items():
        assert name in COMMANDS
        for action in sub._actions:
            assert action.help, (name, action.option_strings)
            if "--out" in action.option_strings:
                assert "-o" in action.option_strings, name
