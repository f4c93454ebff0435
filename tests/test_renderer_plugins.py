"""Third-party renderers (issue 30): the registry is open to the ``zcomp.renderers``
entry point group, and the renderer contract checks what a plugin adds.

``tests/plugins`` holds an installed-looking distribution (a ``.dist-info`` with
``entry_points.txt``) with two renderers -- ``demo-flat`` keeps the contract,
``demo-noisy`` breaks it -- one whose module does not exist and one that takes a
built-in's name. The folder goes on ``PYTHONPATH`` of subprocesses only, so the rest
of the suite sees the built-in table.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from pathlib import Path

from hostile_project import make_project

TESTS = Path(__file__).resolve().parent
SRC = TESTS.parent / "src"
PLUGINS = TESTS / "plugins"


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), str(PLUGINS)]))


def test_plugins_join_the_table_and_broken_ones_are_left_out():
    code = ("from zcomp_cli.renderers.registry import RENDERERS\n"
            "print(sorted(RENDERERS)); print(RENDERERS['physical'].source)\n"
            "print(sorted(p.split(\"'\")[1] for p in RENDERERS.problems))\n")
    r = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    names, physical, left_out = r.stdout.splitlines()
    assert names == str(sorted(["physical", "zerocomp", "naive", "cycles", "demo-flat", "demo-noisy"]))
    assert physical == "zcomp"  # a plugin cannot take a built-in's name
    assert left_out == str(["demo-broken", "physical"])


def test_a_plugin_renderer_runs_through_the_cli_with_its_flags(tmp_path):
    make_project(tmp_path)
    cmd = [sys.executable, "-m", "zcomp_cli", "-q", "composite", str(tmp_path / "jobs.yaml"), "--out",
           str(tmp_path / "out"), "--renderer", "demo-flat", "--flat-gain", "1.5"]
    r = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert (tmp_path / "out/000_room_ball/composite.png").is_file()
    assert '"gain": 1.5' in (tmp_path / "out/000_room_ball/report.json").read_text()


def test_the_contract_checks_plugin_renderers():
    """The contract file, run with the plugin installed, collects the plugin's rows:
    ``demo-flat`` passes, ``demo-noisy`` fails on determinism."""
    r = subprocess.run([sys.executable, "-m", "pytest", str(TESTS / "test_renderer_contract.py"), "-q", "-rA",
                        "-p", "no:cacheprovider", "-k", "demo or covered", "--tb=no"],
                       env=_env(), capture_output=True, text=True, timeout=300, cwd=TESTS.parent)
    lines = r.stdout.splitlines()
    passed = {ln.split()[1] for ln in lines if ln.startswith("PASSED")}
    failed = {ln.split()[1] for ln in lines if ln.startswith("FAILED")}
    assert "tests/test_renderer_contract.py::test_every_renderer_is_covered" in passed, r.stdout
    assert any("test_deterministic_for_a_seed[demo-noisy]" in t for t in failed), r.stdout
    assert not [t for t in failed if "demo-flat" in t], r.stdout
    flat = [t for t in passed if "demo-flat" in t]
    assert len(flat) == 5, r.stdout  # every contract test ran on it


def test_a_plugin_whose_import_exits_is_left_out_and_zcomp_goes_on(tmp_path):
    """Issue 39, defect 11: a plugin module calling ``sys.exit(0)`` at import made
    composite, import, estimate and status exit 0 silently, writing nothing. Now it is
    left out with a warning and the command does its work (the physical renderer here)."""
    plug = tmp_path / "plug"
    info = plug / "zcomp_exit_plugin-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: zcomp-exit-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[zcomp.renderers]\nexiting = zcomp_exit_plugin:ENTRY\n")
    (plug / "zcomp_exit_plugin.py").write_text("import sys\nsys.exit(0)\n")
    make_project(tmp_path)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), str(plug)]))
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "zcomp_cli", "composite", str(tmp_path / "jobs.yaml"), "--out",
                        str(out)], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "exiting" in r.stderr and "SystemExit" in r.stderr and "left out" in r.stderr
    assert (out / "000_room_ball" / "composite.png").is_file()
    r = subprocess.run([sys.executable, "-m", "zcomp_cli", "status", str(out), "--manifest",
                        str(tmp_path / "jobs.yaml")], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "done" in r.stdout + r.stderr, r.stdout + r.stderr


@pytest.mark.parametrize("offset", [-5.0, 3e38])
def test_a_renderer_returning_impossible_radiance_fails_its_job(tmp_path, offset):
    """Issue 39 (low): a plugin's outputs of -5 or 3e38 were accepted and composited."""
    import numpy as np

    from zcomp_cli.bundle import ObjectBundle
    from zcomp_cli.errors import NumericalError
    from zcomp_cli.pipeline.job import run_job
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.pipeline.scene import load_scene
    from zcomp_cli.renderers.base import Renderer, RenderOutput

    class Broken(Renderer):
        name = "broken"

        def settings(self):
            return {"name": self.name}

        def render(self, requests, *, seed=469):
            ims = [np.asarray(r.maps.albedo, np.float32) * np.asarray(r.shading, np.float32) for r in requests]
            ims[1] = ims[1] + np.float32(offset)
            return RenderOutput(images=ims, info={})

    m = load_manifest(make_project(tmp_path))
    scene = load_scene(m.scenes["room"], m.defaults.resolution)
    bundle = ObjectBundle.load(tmp_path / "objects" / "ball")
    with pytest.raises(NumericalError, match="linear radiance"):
        run_job(scene, bundle, Broken())
