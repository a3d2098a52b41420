"""Speed and memory of d4rt: the same as ``d4rt bench`` (the logic lives in ``d4rt.speed``).

    PYTHONPATH=src python benchmarks/bench.py --preset tiny --frames 48 --json bench.json
    PYTHONPATH=src python benchmarks/bench.py --preset giant --device cuda --dtype bf16 --frames 48 --size 256

Every option of ``d4rt bench --help`` applies; docs/performance.md says what each figure means.
"""

import sys

from d4rt.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
