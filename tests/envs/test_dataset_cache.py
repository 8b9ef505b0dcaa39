"""The parse cache of RINEX files (issue 12): a cached world equals the parsed one, keys follow the content."""
import dataclasses

import numpy as np
import pytest

from envs.datasets.errors import shared_data_dir

REACH = shared_data_dir() / "instinct_tckf_static"
needs_reach = pytest.mark.skipif(not (REACH / "reach-m2-01_raw_202306291111.nav").is_file(),
                                 reason=f"Reach M2 RINEX files not found in {REACH} (../shared/data is absent)")


def _equal(a, b):
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if dataclasses.is_dataclass(x):
            _equal(x, y)
        elif isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=f.name)
            assert x.dtype.kind == y.dtype.kind, f.name
        elif f.name != "path":
            assert x == y, f.name


@needs_reach
def test_cached_world_equals_the_parsed_one(tmp_path, monkeypatch, capsys):
    pytest.importorskip("georinex")
    from envs.datasets import cache, dataset_world
    from envs.worlds import make_world
    monkeypatch.setenv("NAVGYM_CACHE_DIR", str(tmp_path / "cache"))
    dataset_world._prepare_rinex_cached.cache_clear()
    first = make_world("instinct-reach-static", [5, 6])
    entries = sorted(p.name for p in (tmp_path / "cache").iterdir())
    assert len(entries) == 2 and entries[0].startswith("nav-") and entries[1].startswith("obs-")
    printed = capsys.readouterr().err
    assert "(G22)" in printed
    dataset_world._prepare_rinex_cached.cache_clear()                    # a new process: from disk
    calls = []
    monkeypatch.setattr(cache, "load_obs", lambda *a, **k: calls.append(a))
    monkeypatch.setattr(cache, "load_nav", lambda *a, **k: calls.append(a))
    second = make_world("instinct-reach-static", [5, 6])
    assert calls == []                                                    # nothing parsed again
    assert capsys.readouterr().err == printed                            # the summary lines come back
    for part in ("truth", "imu", "gnss", "init"):
        _equal(getattr(first, part), getattr(second, part))
    np.testing.assert_array_equal(first.epoch_idx, second.epoch_idx)
    # the same obs with other loader arguments is another entry; the cache can be turned off
    monkeypatch.undo()
    monkeypatch.setenv("NAVGYM_CACHE_DIR", str(tmp_path / "cache"))
    o1 = cache.cached_obs(REACH / "reach-m2-01_raw_202306291111.23O", systems=("G",), interval_s=1.0)
    assert len(list((tmp_path / "cache").iterdir())) == 3 and o1.pr.shape[0] == 61
    _equal(o1, cache.cached_obs(REACH / "reach-m2-01_raw_202306291111.23O", systems=("G",), interval_s=1.0))
    monkeypatch.setenv("NAVGYM_CACHE_DIR", "none")
    assert cache.cache_dir() is None
    _equal(o1, cache.cached_obs(REACH / "reach-m2-01_raw_202306291111.23O", systems=("G",), interval_s=1.0))
    dataset_world._prepare_rinex_cached.cache_clear()


def test_cache_key_follows_the_bytes(tmp_path, monkeypatch):
    from envs.datasets import cache
    monkeypatch.setenv("NAVGYM_CACHE_DIR", str(tmp_path / "c"))
    f = tmp_path / "x.obs"
    f.write_bytes(b"abc")
    k1 = cache._entry("obs", f, {"a": 1})
    assert k1 == cache._entry("obs", f, {"a": 1}) and k1 != cache._entry("obs", f, {"a": 2})
    f.write_bytes(b"abd")
    assert cache._entry("obs", f, {"a": 1}) != k1
    (tmp_path / "c").mkdir()
    k1.write_bytes(b"not an npz")
    assert cache._load(k1) is None                                        # unreadable: parsed again
