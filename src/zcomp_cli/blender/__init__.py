"""Everything that drives Blender. bpy itself is only ever imported by the scripts in
``scripts/``, which run in a subprocess (see ``runner``)."""

# Cycles samples of the anti-aliased object pass (mask, albedo). One default for
# ``render-intrinsics`` and ``composite``, so both share cache entries. The coverage is
# the share of the pixel's filter samples that hit the object: against 1024 samples a
# sphere's edge is 0.047 rms off at 16, 0.016 at 64 (tests/test_blender_intrinsics.py),
# a ragged silhouette against a bright background. ``benchmarks/fit_object_samples.py``
# (docs/object_samples.json, two development seeds, the light given): object PSNR 34.30
# dB at 16, 34.66 at 32, 34.80 at 64, 34.83 at 128, 34.84 at 256; the object passes
# 0.33 / 0.31 / 0.37 / 0.49 / 0.61 s a job at 256x256. 64 is the last doubling that
# gains 0.1 dB.
DEFAULT_SAMPLES = 64
