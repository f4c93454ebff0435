"""Importers for the official evaluation sets of ZeroComp (WACV 2025) and SpotLight.

``zcomp import zerocomp DIR`` and ``zcomp import spotlight DIR`` turn an archive into a
manifest that ``zcomp composite`` runs as it is, with each case's ground-truth composite
as its ``reference``:

* ``lvsn.py``: the archives' conventions (layer channel layouts, normal frames, alpha,
  the PNG maps, the SpotLight light frame), each converted once into zcomp's
  (DESIGN.md section 3) by a small pure function;
* ``bundle_exr.py``: one multi-layer ``*_bundle0001.exr`` -> the background photo, the
  ground truth and a zcomp object bundle (no Blender);
* ``layouts.py``: where each archive keeps its cases, background maps and lights;
* ``importer.py``: the import itself (per-case folders, the manifest, the report).

Every rule is read from the official loaders (github.com/lvsn/ZeroComp
``data/dataset_labo.py``, ``controlnet_input_handle.py``, ``sdi_utils.py``,
``configs/sg_labo.yaml``; github.com/lvsn/SpotLight ``src/zerocomp/data/dataset_render.py``,
``src/spotlight/shadow_map_generation.py``, ``configs/default.yaml``); see
docs/reproduce.md.
"""
