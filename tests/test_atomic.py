"""The one atomic writer: a failed or killed write leaves the old file intact and readable."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from studio.atomic import write_bytes, write_json, write_text, write_with


def _leftovers(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_forms_round_trip(tmp_path):
    assert write_text(tmp_path / "a" / "t.txt", "héllo\nwörld\n").read_text(encoding="utf-8") == "héllo\nwörld\n"
    assert write_bytes(tmp_path / "b.bin", b"\x00\x01\xff").read_bytes() == b"\x00\x01\xff"
    assert json.loads(write_json(tmp_path / "c.json", {"x": [1, 2.5]}).read_text()) == {"x": [1, 2.5]}
    write_with(tmp_path / "d.npz", lambda f: np.savez_compressed(f, a=np.arange(5)))
    with np.load(tmp_path / "d.npz") as z:
        assert z["a"].tolist() == [0, 1, 2, 3, 4]
    assert not _leftovers(tmp_path) and not _leftovers(tmp_path / "a")


def test_torch_save_through_the_callback(tmp_path):
    torch = pytest.importorskip("torch")
    write_with(tmp_path / "m.pt", lambda f: torch.save({"w": torch.ones(3)}, f))
    assert torch.load(tmp_path / "m.pt", weights_only=True)["w"].tolist() == [1.0, 1.0, 1.0]


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_a_write_that_raises_midway_keeps_the_old_file(tmp_path, exc):
    path = write_text(tmp_path / "show.json", "old content")

    def half(f):
        f.write(b"new cont")
        f.flush()
        raise exc("disk on fire")

    with pytest.raises(exc, match="disk on fire"):
        write_with(path, half)
    assert path.read_text() == "old content"
    assert _leftovers(tmp_path) == []


def test_unserialisable_json_never_touches_the_file(tmp_path):
    path = write_json(tmp_path / "p.json", {"ok": 1})
    with pytest.raises(ValueError):
        write_json(path, {"bad": float("nan")}, allow_nan=False)
    assert json.loads(path.read_text()) == {"ok": 1} and _leftovers(tmp_path) == []


def test_a_write_killed_in_a_subprocess_leaves_the_previous_content(tmp_path):
    path = write_bytes(tmp_path / "data.bin", b"previous" * 1000)
    script = textwrap.dedent(f"""
        import os
        from studio.atomic import write_with

        def killed(f):
            f.write(b"partial" * 5000)
            f.flush()
            os.fsync(f.fileno())
            os._exit(3)  # no cleanup, no exception handlers: as if the process were killed

        write_with({str(path)!r}, killed)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=60)
    assert proc.returncode == 3, proc.stderr.decode()
    assert path.read_bytes() == b"previous" * 1000
    # only the dead writer's hidden temporary file remains beside it, never under the target's name
    assert all(n.startswith(".data.bin.") for n in _leftovers(tmp_path)) and len(_leftovers(tmp_path)) == 1


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
def test_permissions_follow_the_umask_and_the_replaced_file(tmp_path):
    old = os.umask(0o022)
    try:
        fresh = write_text(tmp_path / "fresh.txt", "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(fresh.stat().st_mode) == 0o644
    kept = write_text(tmp_path / "kept.txt", "x")
    os.chmod(kept, 0o600)
    write_text(kept, "y")
    assert stat.S_IMODE(kept.stat().st_mode) == 0o600 and kept.read_text() == "y"
