"""The light stage: a scene's light fitted once and shared (DESIGN.md section 5).

``SceneLight`` is the one entry point of ``zcomp_cli.light``: it takes a scene's maps
(``LightInputs``) and its light tree (``LightParams``; None: estimated), finds world up
(``scene.frame.scene_up``: the tree's tilt, else the support plane), fits the tree
(``fit.fit_light``) and returns a ``FittedLight`` -- the model the renderers draw, the
filled tree (what ``written`` writes as the manifest's ``light:``), the searched light's
posterior and the evidence the fit read.

A fit is kept under an explicit key: the scene's content (its key, made from the
image, the maps, the camera and the working size), the tree, the stage's config, the
seed and the code (``code_digest``: an upgraded or edited zcomp fits again, whatever its
config says). In memory for the process, and on disk under zcomp's cache (``lights/``,
``--cache-dir``): every job of a scene, every shard and Ray worker sharing the cache,
``preview-light`` and ``composite`` fit a scene's light once. A fit that fails (a given
light that lights nothing the camera sees) is remembered with its reason, so every job
of that scene fails with it.

Inputs without a scene key (an API caller's request) are fitted on the request's own
known pixels and kept in memory only.
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli.errors import ZcompError
from zcomp_cli.light.config import LightConfig
from zcomp_cli.light.evidence_maps import LightEvidence
from zcomp_cli.light.posterior import DirectionPosterior
from zcomp_cli.scene.lightmodel import LightModel
from zcomp_cli.scene.lightparams import LightParams

# The disk cache's format: an entry written by another format is refitted. (2: a light
# given whole is fitted without the depth mesh, its rays marched: issue 49. 3: a probe's
# sky visibility weighed by its map, not its order-2 SH: issue 48. 4: the scene's specular
# layer by its roughness, the offset growing toward grazing views, not one albedo offset:
# issue 48. 5: a searched light drawn as its posterior's modes at its own size, never
# widened to its doubt: issue 47. 6: each cue at the weight its own blocks bear out, and
# gated: issue 47. 7: the posterior mixed with the prior by the chance that its cues
# mislead, at the temperature fitted with it: issue 47. 8: the split read with the shadow
# the drawn light casts at its size and moved by a lamp's fall-off to where it is stated;
# a sun's size kept at the Sun's unless its shadows beat it by the fitted odds, a lamp's
# the likeliest: issue 47. 9: the lit level fitted coarse to fine, the dark region split
# into its basins before each is tied to a caster: issue 47.) The key holds the code's
# digest too (``code_digest``), so a change to the fit needs no new FORMAT; FORMAT now
# names the entry's layout.
FORMAT = 9
# Fits kept in memory (per process): a batch visits its scenes in order, so a few are
# enough; each holds the posterior and the evidence's small maps.
KEEP_IN_MEMORY = 8


def clean(a, lo: float, hi: float) -> np.ndarray:
    """``a`` as float64, clipped to [lo, hi] (+-inf to the bounds), NaN to the bound
    nearest 0: the maps as the fit may read them."""
    out = np.array(a, np.float64)
    np.clip(out, lo, hi, out=out)
    nan = np.isnan(out)
    if nan.any():
        out[nan] = min(max(0.0, lo), hi)
    return out


@dataclass(frozen=True)
class LightInputs:
    """A scene's maps as the light fit reads them: ``depth`` (H, W) metres (0 none),
    ``normals`` (H, W, 3), ``albedo`` (H, W, 3) in [0, 1], ``shading`` (H, W, 3) the
    photograph over the albedo, ``known`` (H, W) the pixels whose shading counts, the
    ``camera``; ``scene_key`` the scene's content key (None: not kept beyond the
    process's memory, where ``memo`` keys it)."""

    depth: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    shading: np.ndarray
    known: np.ndarray
    camera: object
    scene_key: str | None = None

    @classmethod
    def of(cls, maps, shading, known, camera, scene_key: str | None = None) -> "LightInputs":
        """From a scene's (or a render request's) maps, shading and known pixels, each
        checked against the camera's size and cleaned (non-finite values out). With a
        ``scene_key`` the fit must depend on the scene alone: it reads every pixel of
        valid depth and finite shading, not the first job's shading mask -- else a
        job's result would depend on which job of its scene a process ran first, and
        shards or Ray workers would give other composites than one local run."""
        from zcomp_cli.errors import InputError

        H, W = camera.height, camera.width
        shapes = {"depth": (maps.depth, (H, W)), "normals": (maps.normals, (H, W, 3)),
                  "albedo": (maps.albedo, (H, W, 3)), "shading": (shading, (H, W, 3))}
        if scene_key is None:  # (with one, the known pixels are the scene's own)
            shapes["known"] = (known, (H, W))
        for name, (a, want) in shapes.items():
            if np.shape(a) != want:
                raise InputError(f"light: {name} has shape {np.shape(a)}, expected {want}")
        d = clean(maps.depth, 0.0, 1e6)
        sh = clean(shading, 0.0, 1e6)
        k = ((d > 0) & np.all(np.isfinite(shading), axis=-1)) if scene_key is not None else np.asarray(known, bool)
        return cls(depth=d, normals=clean(maps.normals, -1.0, 1.0), albedo=clean(maps.albedo, 0.0, 1.0), shading=sh,
                   known=k, camera=camera, scene_key=scene_key)

    def memo(self) -> str:
        """A key of the arrays themselves (inputs without a scene key)."""
        h = hashlib.sha256()
        for a in (self.depth, self.normals, self.albedo, self.shading, self.known, np.asarray(self.camera.K)):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()


@dataclass(frozen=True)
class FittedLight:
    """A scene's light, fitted: the ``model`` (``LightModel``) the renderers draw, the
    filled tree (``params``), the searched light's ``posterior`` (None: no direction
    was searched), the ``evidence`` its fit read (``evidence_maps.LightEvidence``, for
    ``--debug``; None where no shadow was read), the entry's ``key``, the fit's
    ``seconds`` and how this copy was had (``how``: ``fitted``, ``memory`` or
    ``cache``)."""

    model: LightModel
    params: LightParams
    posterior: DirectionPosterior | None
    evidence: LightEvidence | None
    key: str
    seconds: float
    how: str = "fitted"
    steps: dict = field(default_factory=dict)  # each step's seconds (``ledger``)

    def ledger(self) -> dict:
        """The light stage's line in a job's report."""
        return {"stage": "light", "status": "run" if self.how == "fitted" else "skipped",
                "why": None if self.how == "fitted" else f"{'process memory' if self.how == 'memory' else 'cache'} hit",
                "key": self.key, "fit_s": round(self.seconds, 4)}


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """A digest of zcomp's own Python sources (every ``.py`` under the package, by its
    path and bytes), once per process: a light fitted by other code is another entry.
    ``FORMAT`` alone relied on each change that moves a fit but not its config being
    marked by hand (a change to the sky's solve kept every config value, and a run of
    it read the lights the code before had fitted)."""
    from zcomp_cli.filedigest import sources_sha256

    root = Path(__file__).resolve().parents[1]
    return sources_sha256(root, root)[:16]


class SceneLight:
    """The light stage (module docstring): ``get`` fits a scene's light tree, once per
    key, kept in memory and under ``cache_dir`` (None: memory only). ``fits`` counts the
    fits this object ran."""

    def __init__(self, cfg: LightConfig, cache_dir: str | Path | None = None):
        self.cfg = cfg
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        self._memory: dict[str, FittedLight] = {}
        self._errors: dict[str, ZcompError] = {}
        self.fits = 0

    def key(self, inputs: LightInputs, params: LightParams, seed: int) -> str:
        """The entry's key: the scene's content, the tree, the config, the seed, the code."""
        from zcomp_cli.knobs import as_dict

        scene = inputs.scene_key if inputs.scene_key is not None else f"arrays:{inputs.memo()}"
        text = json.dumps([FORMAT, scene, params.key(), as_dict(self.cfg), int(seed), code_digest()], sort_keys=True,
                          default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:32]

    def get(self, inputs: LightInputs, params: LightParams | None, seed: int) -> FittedLight:
        """The scene's fitted light (module docstring). Raises the fit's ``ZcompError``
        (the same one again for every later ask of the same key)."""
        params = LightParams.estimate() if params is None else params
        key = self.key(inputs, params, seed)
        if key in self._errors:
            raise self._errors[key]
        hit = self._memory.get(key)
        if hit is not None:
            return _as(hit, "memory")
        disk = self._read(key) if inputs.scene_key is not None else None
        if disk is not None:
            self._remember(key, disk)
            return disk
        try:
            fitted = self._fit(inputs, params, seed, key)
        except ZcompError as exc:
            self._errors[key] = exc
            raise
        self.fits += 1
        self._remember(key, fitted)
        if inputs.scene_key is not None:
            self._write(fitted)
        return fitted

    def _fit(self, inputs: LightInputs, params: LightParams, seed: int, key: str) -> FittedLight:
        from zcomp_cli.light.fit import fit_light
        from zcomp_cli.scene.depthmesh import has_geometry
        from zcomp_cli.scene.frame import scene_up
        from zcomp_cli.threads import own_threads

        t0 = time.perf_counter()
        d, n = inputs.depth, inputs.normals
        up, up_from = scene_up(params.tilt, n, inputs.known & has_geometry(d, n), self.cfg.frame)
        with own_threads():  # (the fit's own threads; numpy's BLAS on one: threads.own_threads)
            res = fit_light(params, d, n, inputs.shading, inputs.known, inputs.albedo, inputs.camera, up=up,
                            up_from=up_from, cfg=self.cfg, seed=seed)
        evidence = LightEvidence.from_fit(res.diagnostics.get("evidence"), res.diagnostics.get("mesh"))
        return FittedLight(model=res.model, params=res.params, posterior=res.posterior, evidence=evidence, key=key,
                           seconds=time.perf_counter() - t0, steps=dict(res.diagnostics.get("steps") or {}))

    def _remember(self, key: str, fitted: FittedLight) -> None:
        while len(self._memory) >= KEEP_IN_MEMORY:
            self._memory.pop(next(iter(self._memory)))
        self._memory[key] = fitted

    # -- the disk cache --------------------------------------------------------------
    def _path(self, key: str) -> Path | None:
        return None if self.cache_dir is None else self.cache_dir / f"{key}.npz"

    def _write(self, fitted: FittedLight) -> None:
        """The entry as one ``.npz`` (written atomically): its JSON (the model, the
        tree, the time) and the posterior's and evidence's arrays. A cache that cannot
        be written costs the next process a fit, nothing more."""
        path = self._path(fitted.key)
        if path is None:
            return
        from zcomp_cli.imageio import atomic_path

        doc = {"format": FORMAT, "model": fitted.model.to_dict(), "params": fitted.params.to_dict(),
               "seconds": fitted.seconds, "steps": fitted.steps}
        arrays = {"doc": np.array(json.dumps(doc))}
        p = fitted.posterior
        if p is not None:
            arrays.update(post_dirs=p.dirs, post_log=p.log_post, post_omega=p.solid_angle,
                          post_temperature=np.float64(p.temperature), post_misled=np.float64(p.misled))
            if p.loglik is not None and p.log_prior is not None:
                arrays.update(post_loglik=p.loglik, post_prior=p.log_prior)
        ev = fitted.evidence
        if ev is not None:
            arrays.update(ev_soft=ev.soft_mask, ev_conf=ev.confidence, ev_ratio=ev.ratio, ev_casters=ev.casters)
        try:
            with atomic_path(path) as tmp:
                buf = io.BytesIO()
                np.savez(buf, **arrays)
                tmp.write_bytes(buf.getvalue())
        except (OSError, ZcompError):
            pass

    def _read(self, key: str) -> FittedLight | None:
        """The entry under ``key``, or None (none, another format, or damaged: refitted)."""
        path = self._path(key)
        if path is None or not path.is_file():
            return None
        try:
            # (read whole, then parsed from memory: an interrupt inside np.load left a zip
            # reader over a closed file, whose clean-up printed a traceback at exit)
            with np.load(io.BytesIO(path.read_bytes()), allow_pickle=False) as z:
                doc = json.loads(str(z["doc"]))
                if doc.get("format") != FORMAT:
                    return None
                post = None
                if "post_dirs" in z:
                    post = DirectionPosterior(dirs=z["post_dirs"], log_post=z["post_log"], solid_angle=z["post_omega"],
                                              loglik=z["post_loglik"] if "post_loglik" in z else None,
                                              log_prior=z["post_prior"] if "post_prior" in z else None,
                                              temperature=float(z["post_temperature"]),
                                              misled=float(z["post_misled"]))
                ev = None
                if "ev_soft" in z:
                    ev = LightEvidence(soft_mask=z["ev_soft"], confidence=z["ev_conf"], ratio=z["ev_ratio"],
                                       casters=z["ev_casters"])
                return FittedLight(model=LightModel.from_dict(doc["model"]), params=LightParams.from_dict(doc["params"]),
                                   posterior=post, evidence=ev, key=key, seconds=float(doc["seconds"]), how="cache",
                                   steps={k: float(v) for k, v in (doc.get("steps") or {}).items()})
        except Exception:  # noqa: BLE001 - a damaged entry is refitted, never fatal
            return None


def _as(fitted: FittedLight, how: str) -> FittedLight:
    import dataclasses

    return dataclasses.replace(fitted, how=how)


__all__ = ["SceneLight", "FittedLight", "LightInputs", "clean", "FORMAT"]
