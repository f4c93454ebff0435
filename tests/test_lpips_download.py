"""LPIPS weights fetched on first use into zcomp's cache (issue 50): checked against the
published SHA-256, cached, not fetched again; a wrong file refused and not kept; an
offline path (files given); a clear reason when neither works. The only network is an
HTTP server the test starts on 127.0.0.1, standing in for the published addresses
(``$ZCOMP_LPIPS_MIRROR``); the published hashes are those of the test's own files."""

from __future__ import annotations

import dataclasses
import functools
import http.server
import json
import threading
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from zcomp_cli.cli import cli
from zcomp_cli.imageio import write_png
from zcomp_cli.metrics import lpips as L
from zcomp_cli.metrics import lpips_weights as W


class _Counting(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *a):  # (quiet)
        pass

    def do_GET(self):
        self.server.requests.append(self.path)
        super().do_GET()


@pytest.fixture
def server(tmp_path):
    """(base URL, served folder, the paths asked for) of a loopback HTTP server."""
    root = tmp_path / "served"
    root.mkdir()
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Counting, directory=str(root)))
    httpd.requests = []
    t = threading.Thread(target=httpd.serve_forever, daemon=True)
    t.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}", root, httpd.requests
    finally:
        httpd.shutdown()
        httpd.server_close()


@pytest.fixture
def weights(tmp_path, monkeypatch):
    """Random LPIPS weights in the published layout, made the "published" files: their
    hashes replace the real ones. Nothing on the machine (torch hub, lpips) is found."""
    import torch

    model = L.make_lpips_model()
    src = tmp_path / "src"
    src.mkdir()
    torch.save({k: v for k, v in model.net.state_dict().items()}, src / W.BACKBONE.name)
    torch.save({k: v for k, v in model.state_dict().items() if k.startswith("lin")}, src / W.LINEAR.name)
    for pf, attr in ((W.BACKBONE, "BACKBONE"), (W.LINEAR, "LINEAR")):
        monkeypatch.setattr(W, attr, dataclasses.replace(pf, sha256=W.sha256_of(src / pf.name)))
    monkeypatch.setattr(L, "BACKBONE", W.BACKBONE)
    monkeypatch.setattr(L, "LINEAR", W.LINEAR)
    monkeypatch.setattr(L, "installed_lpips_weights", lambda: None)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setenv("ZCOMP_CACHE_DIR", str(tmp_path / "cache"))
    for env in (W.BACKBONE.env, W.LINEAR.env, W.OFFLINE_ENV, W.MIRROR_ENV):
        monkeypatch.delenv(env, raising=False)
    return src


def _folders(tmp_path) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    write_png(tmp_path / "p" / "x.png", rng.random((32, 40, 3)).astype(np.float32))
    write_png(tmp_path / "r" / "x.png", rng.random((32, 40, 3)).astype(np.float32))
    return tmp_path / "p", tmp_path / "r"


def _eval(tmp_path, *extra) -> dict:
    p, r = _folders(tmp_path)
    res = CliRunner().invoke(cli, ["-q", "eval", "--metrics", "psnr,lpips", *map(str, extra), str(p), str(r)])
    assert res.exit_code == 0, res.output
    return json.loads((p / "eval.json").read_text())


def _serve(root: Path, src: Path, junk: str | None = None) -> None:
    for pf in (W.BACKBONE, W.LINEAR):
        data = b"not the weights" if pf.name == junk else (src / pf.name).read_bytes()
        (root / pf.name).write_bytes(data)


def test_fetched_on_first_use_checked_cached_and_not_fetched_again(tmp_path, weights, server, monkeypatch):
    url, root, asked = server
    _serve(root, weights)
    monkeypatch.setenv(W.MIRROR_ENV, url)
    doc = _eval(tmp_path)
    assert doc["unavailable"] == {} and doc["mean"]["lpips"] is not None
    assert sorted(asked) == sorted(f"/{pf.name}" for pf in (W.BACKBONE, W.LINEAR))
    cache = tmp_path / "cache" / "lpips"
    for pf in (W.BACKBONE, W.LINEAR):
        assert W.sha256_of(cache / pf.name) == pf.sha256
    assert sorted(p.name for p in cache.iterdir()) == sorted(pf.name for pf in (W.BACKBONE, W.LINEAR))
    first = doc["mean"]["lpips"]
    doc = _eval(tmp_path)
    assert len(asked) == 2 and doc["mean"]["lpips"] == first  # from the cache, not fetched again


@pytest.mark.parametrize("junk", [W.BACKBONE.name, W.LINEAR.name])
def test_a_wrong_file_is_refused_and_not_kept(tmp_path, weights, server, monkeypatch, junk):
    url, root, asked = server
    _serve(root, weights, junk=junk)
    monkeypatch.setenv(W.MIRROR_ENV, url)
    doc = _eval(tmp_path)
    why = doc["unavailable"]["lpips"]
    assert "not the published one" in why and f"{url}/{junk}" in why, why
    assert doc["mean"]["psnr"] is not None  # the other metrics run
    assert not (tmp_path / "cache" / "lpips" / junk).exists()
    assert not [p for p in (tmp_path / "cache" / "lpips").iterdir() if p.name.startswith(".")]


def test_offline_path_given_files_and_the_reason_when_neither_works(tmp_path, weights, server, monkeypatch):
    url, root, asked = server
    monkeypatch.setenv(W.OFFLINE_ENV, "1")
    doc = _eval(tmp_path)  # nothing on the machine, no download allowed
    why = doc["unavailable"]["lpips"]
    assert "ZCOMP_OFFLINE" in why and "--lpips-backbone" in why and W.BACKBONE.url in why, why
    doc = _eval(tmp_path, "--lpips-backbone", weights / W.BACKBONE.name, "--lpips-weights",
                weights / W.LINEAR.name)
    assert doc["unavailable"] == {} and doc["mean"]["lpips"] is not None
    assert asked == []


def test_an_unreachable_address_is_named(tmp_path, weights, server, monkeypatch):
    url, root, asked = server  # serves nothing: every file is a 404
    monkeypatch.setenv(W.MIRROR_ENV, url)
    why = _eval(tmp_path)["unavailable"]["lpips"]
    assert f"{url}/{W.BACKBONE.name}" in why and "HTTP 404" in why, why
