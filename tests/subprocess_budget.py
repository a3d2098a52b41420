"""How long a test lets a subprocess (a `d4rt` command, a browser) run before it counts as hung: one
place, so a slow or loaded machine is accounted for here rather than test by test.

budget(s) is s times D4RT_TEST_TIMEOUT_SCALE (default 2 under CI=true, where 2 shared cores run the
suite in parallel, else 1). The figures passed in are a few times what an idle 2-core machine needs.
"""

import os

SCALE = float(os.environ.get("D4RT_TEST_TIMEOUT_SCALE", "2" if os.environ.get("CI") == "true" else "1"))


def budget(seconds: float) -> float:
    return seconds * SCALE
