"""Tests keep the RINEX parse cache (envs.datasets.cache) in a temporary folder, not in ~/.cache/navgym."""
import os

import pytest


@pytest.fixture(autouse=True, scope="session")
def _parse_cache_in_tmp(tmp_path_factory):
    old = os.environ.get("NAVGYM_CACHE_DIR")
    os.environ["NAVGYM_CACHE_DIR"] = str(tmp_path_factory.mktemp("navgym-cache"))
    yield
    if old is None:
        os.environ.pop("NAVGYM_CACHE_DIR", None)
    else:
        os.environ["NAVGYM_CACHE_DIR"] = old
