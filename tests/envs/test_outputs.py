"""Output files are written to a temporary file and renamed into place (envs.outputs): a write interrupted by
an exception (or a kill) leaves the previous file whole, never a truncated one, and no temporary file."""
import os
import stat

import pytest

from envs.outputs import atomic_path, write_atomic


class Boom(Exception):
    pass


def test_write_atomic_replaces_the_whole_file(tmp_path):
    p = tmp_path / "results.json"
    write_atomic(p, '{"old": 1}\n')
    write_atomic(p, '{"new": 2}\n')
    assert p.read_text() == '{"new": 2}\n' and os.listdir(tmp_path) == ["results.json"]
    write_atomic(p, b"\x00\xffbytes")
    assert p.read_bytes() == b"\x00\xffbytes"


def test_an_interrupted_write_leaves_the_previous_file_intact(tmp_path):
    p = tmp_path / "results.json"
    write_atomic(p, '{"earlier": "run"}\n')
    with pytest.raises(Boom):
        with atomic_path(p) as tmp:
            with open(tmp, "w") as fh:
                fh.write('{"half": ')  # the new file half written ...
                fh.flush()
                raise Boom()          # ... when the run dies
    assert p.read_text() == '{"earlier": "run"}\n'
    assert os.listdir(tmp_path) == ["results.json"]  # no temporary file left behind
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(tmp_path / "new.md"):
            raise KeyboardInterrupt
    assert os.listdir(tmp_path) == ["results.json"]  # no empty or partial new file either


def test_a_killed_writer_leaves_the_previous_file(tmp_path):
    """The temporary file is a different file: whatever state it is in when the process dies, the named
    file is the previous one until the rename."""
    p = tmp_path / "timing.json"
    write_atomic(p, "previous\n")
    ctx = atomic_path(p)
    tmp = ctx.__enter__()
    tmp.write_text("trunc")               # a kill now: no rename has happened
    assert p.read_text() == "previous\n" and tmp.name.startswith(".timing.json.") and tmp.suffix == ".json"
    ctx.__exit__(None, None, None)
    assert p.read_text() == "trunc"


def test_the_temporary_name_keeps_the_suffix_and_the_permissions_follow_the_umask(tmp_path):
    with atomic_path(tmp_path / "model.zip") as tmp:
        assert tmp.suffix == ".zip" and tmp.parent == tmp_path
        tmp.write_bytes(b"PK")
    old = os.umask(0o022)
    try:
        write_atomic(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o644
