"""The benchmark seeds: which ones development may look at, and which were reported.

A constant is chosen (``fit_light_constants.py``) and a change is judged on the
development seeds only; a version is reported on a fresh seed, generated for it, never
looked at before the version is final, and run once. A reported seed is never reported
again: it joins ``REPORTED`` (and may then serve development, as 1618 and 7777 do).

    zcomp make-benchmark OUT --n 32 --seed S --resolution 256 256 --samples 64
"""

DEVELOPMENT = (1618, 7777)
# Seeds reported by earlier versions (docs/physical.md's calibration record): never again.
REPORTED = (123, 1618, 2468, 4242, 4711, 5077, 5150, 5555, 6091, 6502, 7321, 7777, 8128, 8675, 9001, 27182,
            2026, 3141, 31337, 31415, 60221, 90210, 1729, 4096, 6174, 7391, 8191, 2719, 3301, 4441, 6067,
            5881, 9973, 7057, 6263, 8363, 9431, 7411, 5309)
# The seed this version reports on (fresh: in neither list above).
REPORT = 6871

BENCHMARK_ARGS = ("--n", "32", "--resolution", "256", "256", "--samples", "64")

assert REPORT not in DEVELOPMENT + REPORTED
