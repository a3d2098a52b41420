"""Progress bars (tqdm) that one switch turns off everywhere: ``d4rt --no-progress`` for logs, where
bars write carriage returns and escape codes. Each caller still decides whether its own bar is wanted."""

from __future__ import annotations

import os

from tqdm import tqdm

# Set by the command line (``--no-progress``); D4RT_NO_PROGRESS=1 does the same from the environment.
_enabled = os.environ.get("D4RT_NO_PROGRESS", "") in ("", "0")


def set_progress(enabled: bool) -> bool:
    """Turn every d4rt progress bar on or off (they are on by default); returns the previous setting."""
    global _enabled
    previous, _enabled = _enabled, enabled
    return previous


def progress_bar(*args, disable: bool = False, **kwargs) -> tqdm:
    """``tqdm(...)``, disabled when the caller asks or when progress is switched off."""
    return tqdm(*args, disable=disable or not _enabled, **kwargs)


def write_line(text: str) -> None:
    """Print a line without breaking a progress bar drawn below it."""
    tqdm.write(text)
