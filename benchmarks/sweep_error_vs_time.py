"""Error against run time: rerun a benchmark over each renderer's cost knobs.

    python benchmarks/sweep_error_vs_time.py BENCH_DIR --out OUT [--quick] [--knobs K1,K2]
        [--values march_steps=8,16,32] [--max-jobs N] [--resume]

The logic lives in ``zcomp_cli.benchsuite.sweep`` (its docstring says what is measured).
"""

import sys

from zcomp_cli.benchsuite.sweep import main

if __name__ == "__main__":
    sys.exit(main())
