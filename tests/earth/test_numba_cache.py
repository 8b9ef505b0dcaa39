"""The numba cache files of a module go when it, or a module it imports (directly or through others), changes;
the others stay (``earth.numba_cache``)."""
import json
from pathlib import Path

import earth
from earth.numba_cache import RECORD, affected_modules, invalidate_stale_caches, module_hashes

SOURCES = {
    "p/__init__.py": "from .k import f\n",
    "p/k.py": "import numba\n\ndef f():\n    return 1\n",
    "p/kk.py": "def f():\n    return 2\n",  # its name starts like k's: its cache is not k's
    "p/u.py": "from .k import f\n\ndef g():\n    return f()\n",
    "p/v.py": "x = 1\n",
    "q/w.py": "from p.u import g\n",  # through u, w may hold k's code
    "q/z.py": "def h():\n    import p.v as v\n    return v.x\n",  # an import inside a function counts
}
CACHES = ["p/__pycache__/k.f-3.py311.nbi", "p/__pycache__/k.f-3.py311.1.nbc", "p/__pycache__/kk.f-1.py311.nbi",
          "p/__pycache__/u.g-3.py311.nbi", "p/__pycache__/v.x-1.py311.nbi", "p/__pycache__/__init__.f-1.py311.nbi",
          "q/__pycache__/w.g-1.py311.nbi", "q/__pycache__/z.h-1.py311.nbi"]


def _tree(root: Path):
    for rel, text in SOURCES.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    _caches(root)


def _caches(root: Path):
    for rel in CACHES:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(b"x")


def _left(root: Path):
    return sorted(rel for rel in CACHES if (root / rel).exists())


def test_changed_modules_and_their_importers_lose_their_caches(tmp_path):
    _tree(tmp_path)
    (tmp_path / "earth").mkdir()
    pk = ("p", "q")
    assert invalidate_stale_caches(tmp_path, pk) == len(CACHES)  # no record yet: every cache file goes
    assert _left(tmp_path) == []
    assert json.loads((tmp_path / RECORD).read_text()) == module_hashes(tmp_path, pk)
    _caches(tmp_path)
    assert invalidate_stale_caches(tmp_path, pk) == 0  # nothing changed: nothing goes
    assert _left(tmp_path) == sorted(CACHES)

    (tmp_path / "p/k.py").write_text(SOURCES["p/k.py"] + "# edited\n")
    assert invalidate_stale_caches(tmp_path, pk) == 5
    assert _left(tmp_path) == ["p/__pycache__/kk.f-1.py311.nbi", "p/__pycache__/v.x-1.py311.nbi",
                               "q/__pycache__/z.h-1.py311.nbi"]
    _caches(tmp_path)
    (tmp_path / "p/v.py").write_text("x = 2\n")
    assert invalidate_stale_caches(tmp_path, pk) == 2
    assert set(CACHES) - set(_left(tmp_path)) == {"p/__pycache__/v.x-1.py311.nbi", "q/__pycache__/z.h-1.py311.nbi"}
    _caches(tmp_path)
    (tmp_path / "q/w.py").unlink()  # a removed module: its caches go too
    assert invalidate_stale_caches(tmp_path, pk) == 1
    assert set(CACHES) - set(_left(tmp_path)) == {"q/__pycache__/w.g-1.py311.nbi"}
    _caches(tmp_path)
    (tmp_path / RECORD).write_text("{damaged")  # an unreadable record counts as none
    assert invalidate_stale_caches(tmp_path, pk) == len(CACHES)


def test_the_import_graph_follows_relative_absolute_and_package_imports(tmp_path):
    _tree(tmp_path)
    files = set(module_hashes(tmp_path, ("p", "q")))
    assert affected_modules(tmp_path, {"p/k.py"}, files) == {"p/k.py", "p/__init__.py", "p/u.py", "q/w.py"}
    assert affected_modules(tmp_path, {"p/v.py"}, files) == {"p/v.py", "q/z.py"}
    assert affected_modules(tmp_path, {"p/kk.py"}, files) == {"p/kk.py"}


def test_importing_earth_recorded_the_sources_of_this_tree():
    root = Path(earth.__file__).resolve().parents[1]
    assert json.loads((root / RECORD).read_text()) == module_hashes(root)


def test_compile_notice_once_when_a_kernel_of_the_packages_compiles():
    """The first run of a checkout compiles navgym's kernels for minutes: one line says so, once; kernels of other
    packages and a second compilation say nothing."""
    import io

    import numba
    from numba.core import event

    from earth.numba_cache import COMPILE_NOTICE, CompileNotice

    def f(x):
        return x + 1

    def g(x):
        return 2 * x
    out = io.StringIO()
    mine = f.__module__.split(".")[0]
    with event.install_listener("numba:compile", CompileNotice(out, packages=("not-this-one",))):
        numba.njit(f)(1)
    assert out.getvalue() == ""  # another package's kernel
    with event.install_listener("numba:compile", CompileNotice(out, packages=(mine,))):
        assert numba.njit(f)(1) == 2 and numba.njit(g)(2) == 4 and numba.njit(f)(1.5) == 2.5
    assert out.getvalue() == COMPILE_NOTICE + "\n"
    assert "compiling" in COMPILE_NOTICE and "once" in COMPILE_NOTICE


def test_the_announcer_is_one_listener_per_process():
    from numba.core import event

    from earth.numba_cache import announce_compilation
    a = announce_compilation()
    assert announce_compilation() is a and event._registered["numba:compile"].count(a) == 1
