"""Test-wide settings: no network for model hubs, caches in a temporary folder."""

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("HF_HUB_DISABLE_TELEMETRY", "1")


@pytest.fixture(autouse=True, scope="session")
def _zcomp_cache(tmp_path_factory):
    """Object renders and estimates are cached under a per-session folder, so tests
    never read a cache left by an earlier run or by the user."""
    path = tmp_path_factory.mktemp("zcomp-cache")
    old = os.environ.get("ZCOMP_CACHE_DIR")
    os.environ["ZCOMP_CACHE_DIR"] = str(path)
    yield path
    if old is None:
        os.environ.pop("ZCOMP_CACHE_DIR", None)
    else:
        os.environ["ZCOMP_CACHE_DIR"] = old
