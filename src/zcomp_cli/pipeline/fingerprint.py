"""A job's input fingerprint: what ``--resume`` compares to decide a job is unchanged.

The fingerprint hashes everything that can change a job's pixels, generically, so that
a setting or a file added to the manifest later is covered without a hand-kept list:

* the scene's, the object's and the job's parsed specs (``SceneSpec``, ``ObjectSpec``,
  ``JobSpec``), every field but those named in ``NOT_PIXELS`` (names, manifest lines,
  the evaluation reference). Nested values (the scene's ``light:`` mapping, estimator
  settings, a pose) are hashed as canonical JSON, whatever their keys;
* the *content* (sha256) of every file they name: a ``Path`` field, and every string
  that the manifest resolved as a file for the scene's settings (``SceneSpec.setting_files``:
  a light probe's ``hdr`` today), named relative to the manifest, so ``touch`` or
  moving the project changes nothing;
* a mesh's side files (an OBJ's MTL and textures, a ``.gltf``'s buffers and images);
* the content of every file in an estimator's ``model`` folder (its weights);
* the working resolution, the Cycles samples and the renderer's settings (not those
  that only change speed, ``RendererEntry.speed_settings``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

import numpy as np

# Bump when the payload changes shape: reports of older versions then no longer match.
FINGERPRINT_VERSION = 2

# Spec fields that never change a job's pixels (renaming a scene or moving a job in the
# manifest does not make its finished output stale).
NOT_PIXELS = {
    "SceneSpec": {"name", "width", "height", "setting_files"},  # size: read from the image, hashed
    "ObjectSpec": {"name"},
    "JobSpec": {"index", "name", "line", "reference", "scene", "object"},
    # the renderer is passed apart (the CLI may override it); seed and radius reach
    # the job's own fields; samples is passed apart (it is what the run used)
    "Defaults": {"renderer", "seed", "shading_radius", "samples"},
}


class _Canon:
    """Canonical JSON-able form of parsed specs; files become ``{path, sha256}``."""

    def __init__(self, root: Path, digests, files: set[str], folders: set[str] = frozenset()):
        self.root = root
        self.digests = digests
        self.files = files  # strings known to name files (absolute, as the manifest resolved them)
        self.folders = folders  # strings known to name model folders (``estimators``' ``model``)

    def folder(self, p: Path) -> dict:
        """A model folder: every file's name and content hash (remembered by path, size
        and mtime: a folder's gigabytes are hashed once per change, not per run)."""
        return {"path": os.path.relpath(p, self.root), "sha256": self.digests.digest(p) if p.is_dir() else None}

    def file(self, p: Path) -> dict:
        from zcomp_cli.blender.meshes import MESH_FORMATS, side_files

        rec: dict = {"path": os.path.relpath(p, self.root)}
        if not p.exists():
            rec["sha256"] = None
            return rec
        rec["sha256"] = self.digests.digest(p)
        if p.suffix.lower() in MESH_FORMATS and p.is_file():
            # named relative to the mesh, as the mesh refers to them
            rec["side_files"] = [[os.path.relpath(f, p.parent), self.digests.digest(f)] for f in side_files(p)]
        return rec

    def __call__(self, v):
        if isinstance(v, Path):
            return self.file(v)
        if isinstance(v, str):
            if v in self.folders:
                return self.folder(Path(v))
            return self.file(Path(v)) if v in self.files else v
        if isinstance(v, bool) or v is None or isinstance(v, int):
            return v
        if isinstance(v, (float, np.floating)):
            return float(v)
        if isinstance(v, np.integer):
            return int(v)
        if isinstance(v, np.ndarray):
            return self(v.tolist())
        if isinstance(v, dict):
            return {str(k): self(x) for k, x in sorted(v.items(), key=lambda kv: str(kv[0]))}
        if isinstance(v, (list, tuple, set, frozenset)):
            items = [self(x) for x in v]
            return sorted(items, key=json.dumps) if isinstance(v, (set, frozenset)) else items
        if hasattr(v, "to_dict"):  # Pose: its canonical dict, not the rotation's float noise
            return self(v.to_dict())
        if dataclasses.is_dataclass(v):
            # every attribute, declared or not: a setting added to a spec is covered
            skip = NOT_PIXELS.get(type(v).__name__, set())
            names = vars(v) if hasattr(v, "__dict__") else {f.name: None for f in dataclasses.fields(v)}
            return {k: self(getattr(v, k)) for k in sorted(names) if k not in skip and not k.startswith("_")}
        return repr(v)


def job_fingerprint(manifest, job, renderer, samples: int, digests=None) -> str:
    """Identifies a job's inputs (see the module docstring). ``renderer`` is the
    ``RendererSpec`` the run uses, ``samples`` its Cycles samples, ``digests`` an
    ``outguard.DigestCache`` (content hashes remembered by path, size and mtime)."""
    from zcomp_cli.pipeline.outguard import DigestCache
    from zcomp_cli.renderers.registry import RENDERERS

    digests = digests if digests is not None else DigestCache(None)
    scene = manifest.scenes[job.scene]
    obj = manifest.objects[job.object]
    files = {str(p) for p in getattr(scene, "setting_files", ()) or ()}
    # the estimators' model folders: their weights are the job's inputs too (new weights
    # in the same folder change the job, as they change the estimate cache's key)
    folders = {str(e["model"]) for e in (getattr(scene, "estimators", None) or {}).values()
               if isinstance(e, dict) and isinstance(e.get("model"), str)}
    canon = _Canon(manifest.root, digests, files, folders)
    entry = RENDERERS.get(renderer.name)
    speed_only = set(entry.speed_settings) if entry is not None else set()
    payload = {
        "version": FINGERPRINT_VERSION,
        "scene": canon(scene),
        "object": canon(obj),
        "job": canon(job),
        "defaults": canon(manifest.defaults),
        "samples": samples,
        "renderer": {"name": renderer.name,
                     "settings": canon({k: v for k, v in renderer.settings.items() if k not in speed_only})},
    }
    blob = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]
