"""Everything that drives Blender. bpy itself is only ever imported by the scripts in
``scripts/``, which run in a subprocess (see ``runner``)."""

# Cycles samples of the anti-aliased object pass (mask, albedo). One default for
# ``render-intrinsics`` and ``composite``, so both share cache entries.
DEFAULT_SAMPLES = 16
