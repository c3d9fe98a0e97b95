"""Projects under concurrency and hostile files (studio.project.lock, studio.project.containment,
studio.project.project_read): one writer at a time, nothing lost, nothing outside the project touched."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from studio.cli.main import main
from studio.project.lock import ProjectChanged, ProjectLocked
from studio.project.project import Project, ProjectError
from studio.targets.video import VideoConfig

S = 32
VIDEO = VideoConfig(size=S, fps=8.0, hz=8.0)
ROOT = Path(__file__).resolve().parents[1]


def make(tmp_path: Path, sources: list[Path], name: str = "p.shadow") -> Project:
    return Project.create(tmp_path / name, sources=[str(s) for s in sources], video=VIDEO)


def cli(capsys, *argv) -> tuple[int, str]:
    rc = main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out + out.err


def files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` → its bytes (the lock file's note aside)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
            and p.name != ".lock"}  # fmt: skip


def edit_doc(project: Path, change) -> None:
    doc = json.loads((project / "project.json").read_text())
    change(doc)
    (project / "project.json").write_text(json.dumps(doc))


def spawn(script: str) -> subprocess.Popen:
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(script)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)  # fmt: skip


# ---------------------------------------------------------------- one writer at a time
def test_a_second_writer_is_refused_with_who_holds_it_and_a_killed_holder_frees_it(tmp_path, sources, capsys):
    p = make(tmp_path, sources)
    holder = spawn(f"""
        import sys, time
        from studio.project.project import Project
        p = Project.open({str(p.path)!r})
        with p.writing("project run"):
            print("holding", flush=True)
            time.sleep(120)
    """)
    try:
        assert holder.stdout.readline().strip() == "holding"
        before = files(p.path)
        rc, text = cli(capsys, "project", "run", p.path, "--no-refine")
        assert rc == 2 and f"being written by project run (pid {holder.pid}" in text and "--wait" in text
        assert "Traceback" not in text and files(p.path) == before
        with pytest.raises(ProjectLocked, match="project run"):  # an edit from the notebook: refused at once
            p.set_hold(p.keyframes[0].id, True)
        assert files(p.path) == before and not p.can_undo
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=30)
    p.set_hold(p.keyframes[0].id, True)  # the kernel freed the killed holder's lock: taken over
    assert Project.open(p.path).keyframes[0].hold


def test_a_save_over_another_process_s_newer_save_is_refused(tmp_path, sources):
    p = make(tmp_path, sources)
    q = Project.open(p.path)  # another face (a terminal) saves results meanwhile
    q.set_result(q.keyframes[0].id, np.zeros(21), {"total": 0.1}, np.ones((S, S), np.uint8))
    theirs = files(p.path)
    with pytest.raises(ProjectChanged, match="reopen it"):
        p.set_hold(p.keyframes[0].id, True)
    assert files(p.path) == theirs and not p.can_undo
    assert Project.open(p.path).results[q.keyframes[0].id].loss["total"] == 0.1


def test_two_processes_editing_at_once_lose_nothing(tmp_path, sources):
    """Two writers toggling holds and painting as fast as they can: each save either lands whole or is refused;
    the project stays readable and names only files that exist."""
    p = make(tmp_path, sources)
    script = f"""
        import numpy as np
        from studio.project.lock import ProjectChanged, ProjectLocked
        from studio.project.project import Project
        p, done, refused = Project.open({str(p.path)!r}), 0, 0
        rng = np.random.default_rng(%d)
        for i in range(25):
            try:
                m = (rng.random(({S}, {S})) > 0.7).astype(np.uint8)
                p.paint(int(rng.integers(0, len(p.frames))), additions=m)
                done += 1
            except (ProjectLocked, ProjectChanged):
                refused += 1
                p = Project.open({str(p.path)!r})
        print(done, refused)
    """
    writers = [spawn(script % seed) for seed in (1, 2)]
    outs = [w.communicate(timeout=300) for w in writers]
    assert all(w.returncode == 0 for w in writers), [o[1][-2000:] for o in outs]
    done = [int(o[0].split()[0]) for o in outs]
    assert sum(done) >= 25  # both wrote, turn by turn
    q = Project.open(p.path)  # every file project.json names exists and matches its hash
    assert q.state.additions and len(q.frames) == 9


# ---------------------------------------------------------------- containment
@pytest.mark.parametrize("sub", ["results", "masks"])
def test_a_symlinked_subfolder_is_refused_and_its_target_untouched(tmp_path, sources, sub):
    p = make(tmp_path, sources)
    p.set_result(p.keyframes[0].id, np.zeros(21), {"total": 0.1}, np.ones((S, S), np.uint8))
    elsewhere = tmp_path / "my_pictures"
    elsewhere.mkdir()
    Image.fromarray(np.full((4, 4), 200, np.uint8)).save(elsewhere / "holiday.png")
    for f in (p.path / sub).iterdir():
        os.replace(f, elsewhere / f.name)
    (p.path / sub).rmdir()
    (p.path / sub).symlink_to(elsewhere)
    before = files(elsewhere)
    with pytest.raises(ProjectError, match=f"{sub}/ must be a real folder"):
        Project.open(p.path)
    with pytest.raises(ProjectError, match="symbolic link"):
        p.set_hold(p.keyframes[0].id, True)  # an object opened before the link was planted
    assert files(elsewhere) == before


@pytest.mark.parametrize("name", ["../../etc/passwd", "/etc/hostname", "masks/../../x.png", "results/a.png"])
def test_file_names_outside_the_project_are_refused(tmp_path, sources, name, capsys):
    p = make(tmp_path, sources)
    edit_doc(p.path, lambda d: d["frames"][0].update(target=name))
    rc, text = cli(capsys, "project", "info", p.path)
    assert rc == 2 and "outside the project's own files" in text and "Traceback" not in text


def test_a_planted_symlink_at_a_project_file_name_is_never_read(tmp_path, sources):
    p = make(tmp_path, sources)
    name = json.loads((p.path / "project.json").read_text())["frames"][0]["target"]
    secret = tmp_path / "secret.png"
    os.replace(p.path / name, secret)
    (p.path / name).symlink_to(secret)
    with pytest.raises(ProjectError, match="symbolic link"):
        Project.open(p.path)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs POSIX FIFOs")
def test_devices_and_fifos_are_never_sources(tmp_path, sources, capsys):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for bad in ("/dev/zero", fifo):
        rc, text = cli(capsys, "project", "new", tmp_path / "x.shadow", "--source", bad)
        assert rc == 2 and "not a file or a folder" in text
    p = make(tmp_path, sources)
    edit_doc(p.path, lambda d: d["sources"][0].update(path="/dev/zero", absolute=str(fifo)))
    t0 = time.monotonic()
    rc, text = cli(capsys, "project", "info", p.path)  # would hang reading the FIFO or /dev/zero
    assert rc == 0 and "MISSING" in text and time.monotonic() - t0 < 30


def test_project_new_refuses_a_folder_with_someone_s_files(tmp_path, sources, capsys):
    folder = tmp_path / "old.shadow"
    (folder / "masks").mkdir(parents=True)
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(folder / "masks" / "keep.png")
    (folder / "show-1.json").write_text("{}")
    before = files(folder)
    rc, text = cli(capsys, "project", "new", folder, "--source", sources[1])
    assert rc == 2 and "not a project" in text and files(folder) == before
    (tmp_path / "empty.shadow").mkdir()
    assert Project.create(tmp_path / "empty.shadow", sources=[str(sources[1])], video=VIDEO).frames


def test_a_save_keeps_files_of_other_shapes_in_the_folder(tmp_path, sources):
    p = make(tmp_path, sources)
    (p.path / "results").mkdir()
    mine = {p.path / "masks" / "my-notes.png": b"x", p.path / "results" / "print.png": b"y",
            p.path / "show-final.json": b"{}"}  # fmt: skip
    for path, data in mine.items():
        path.write_bytes(data)
    p.set_hold(p.keyframes[0].id, True)
    p.undo()
    assert all(path.read_bytes() == data for path, data in mine.items())


# ---------------------------------------------------------------- damaged entries: one clear line each
DAMAGE = {
    "zero keyframes": (lambda d: d.update(keyframes=[]), "no keyframe"),
    "member out of range": (lambda d: d["keyframes"][0]["members"].append(999), "member frame 999"),
    "frame in no keyframe": (
        lambda d: (
            d["keyframes"][0].update(members=[d["keyframes"][0]["representative"]])
            if len(d["keyframes"][0]["members"]) > 1
            else d["keyframes"].pop()
        ),
        "belong to no keyframe",
    ),
    "duplicate ids": (lambda d: d["keyframes"][1].update(id=d["keyframes"][0]["id"]), "keyframe id"),
    "weights abc": (lambda d: d["weights"].update(w_iou="abc"), "weights.w_iou must be a finite"),
    "weights NaN": (lambda d: d["weights"].update(w_mae=float("nan")), "weights.w_mae must be a finite"),
    "hold as text": (lambda d: d["keyframes"][0].update(hold="false"), "must be true or false"),
    "frame of no source": (lambda d: d["frames"][0].update(source=7), "a frame's source 7"),
    "nested": (None, "JSON nested deeper than 64 levels"),  # written as text below
    "time 1e7": (lambda d: d["keyframes"][0].update(time_s=1e7), "time must be a number of seconds in [0, 3600]"),
    "size as text": (lambda d: d["settings"]["video"].update(size="20000"), "settings.video.size"),
}


@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_a_damaged_entry_is_one_clear_line(tmp_path, sources, capsys, case):
    p = make(tmp_path, sources)
    change, said = DAMAGE[case]
    if case == "nested":
        text = (p.path / "project.json").read_text().replace('"title": "p"', '"title": ' + "[" * 5000 + "]" * 5000)
        (p.path / "project.json").write_text(text)
    else:
        edit_doc(p.path, change)
    for verb in ("info", "run"):
        rc, text = cli(capsys, "project", verb, p.path, *(["--no-refine"] if verb == "run" else []))
        assert rc == 2 and said in text and "internal error" not in text and "Traceback" not in text, text


def test_a_result_owed_something_unknown_is_one_clear_line(tmp_path, sources, capsys):
    p = make(tmp_path, sources)
    k = p.keyframes[0].id
    p.set_result(k, np.zeros(21), {"total": 0.1}, np.ones((S, S), np.uint8), awaits="together")
    assert Project.open(p.path).results[k].awaits == "together"
    edit_doc(p.path, lambda d: d["results"][0].update(awaits="soon"))
    rc, text = cli(capsys, "project", "info", p.path)
    assert rc == 2 and f"keyframe {k}'s result awaits \"soon\", not one of ['again', 'together']" in text, text


# ---------------------------------------------------------------- relink and colliding results from the CLI
def test_relink_from_the_command_line_and_info_flags_colliding_results(tmp_path, sources, capsys):
    p = make(tmp_path, sources)
    k = p.keyframes[0].id
    p.set_result(k, np.zeros(21), {"total": 0.1}, np.ones((S, S), np.uint8), collision_free=False)
    moved = tmp_path / "moved"
    os.replace(sources[0], moved)
    rc, text = cli(capsys, "project", "info", p.path)
    assert rc == 0 and "MISSING" in text and f"COLLIDES with itself (project run {p.path} --keyframe {k})" in text
    assert json.loads(text.strip().splitlines()[-1])["colliding"] == [k]
    rc, text = cli(capsys, "project", "relink", p.path, "0", moved)
    assert rc == 0 and f"source 0 is now {moved}" in text
    q = Project.open(p.path)
    assert not q.missing_sources and k in q.results  # the same content keeps every result
    rc, text = cli(capsys, "project", "relink", p.path, "5", moved)
    assert rc == 2 and "no source 5" in text
