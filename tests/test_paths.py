"""The paths a person gives and the files a verb writes: errors that became one line (nested JSON, an image given
to render, long names, a full disk, names that are not text, sources that are not there), outputs never written onto
or into their inputs, and temporary files never followed through a symlink."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest
from limits_support import one_line

from studio.atomic import write_text

# ---------------------------------------------------------------- internal errors that became one line


@pytest.mark.parametrize("depth", [70, 100_000])
def test_nested_json_is_one_line_everywhere(in_process, tmp_path, show_file, depth):
    from studio.atomic import MAX_DEPTH, JsonFileError, parse_json

    nested = "[" * depth + "]" * depth
    deep = tmp_path / "deep.json"
    deep.write_text(nested)
    for argv in (("validate", deep), ("show-info", deep), ("plan", deep, "--out", tmp_path / "o.json"),
                 ("render", deep, "--out", tmp_path / "o.png")):  # fmt: skip
        one_line(in_process(*argv), f"{deep}: JSON nested deeper than {MAX_DEPTH} levels")
    doc = show_file.read_text().replace('"provenance": {}', f'"provenance": {{"x": {nested}}}')
    inside = tmp_path / "inside.json"
    inside.write_text(doc)
    one_line(in_process("validate", inside), "nested deeper")
    assert parse_json("[" * MAX_DEPTH + "]" * MAX_DEPTH, "f") == parse_json("[" * MAX_DEPTH + "]" * MAX_DEPTH, "f")
    with pytest.raises(JsonFileError):
        parse_json("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1), "f")


def test_render_given_an_image_says_so(in_process, tmp_path):
    png = tmp_path / "good.png"
    assert in_process("render", "--out", png).returncode == 0
    one_line(in_process("render", png, "--out", tmp_path / "x.png"), "good.png: it is a PNG image, not a pose file")


@pytest.mark.parametrize("length", [241, 250, 255])
def test_long_names_are_written_atomically(tmp_path, length):
    name = "n" * (length - 5) + ".json"
    write_text(tmp_path / name, "{}")
    assert os.listdir(tmp_path) == [name] and (tmp_path / name).read_text() == "{}"
    uni = "é" * ((length - 5) // 2) + ".json"  # two bytes a character: the temporary name is cut by whole characters
    write_text(tmp_path / uni, "x")
    assert sorted(os.listdir(tmp_path)) == sorted([name, uni])


def test_a_name_too_long_names_the_target_not_the_temporary_file(in_process, tmp_path, show_file):
    name = "n" * 300 + ".csv"
    with pytest.raises(OSError) as e:
        write_text(tmp_path / name, "x")
    assert e.value.errno == errno.ENAMETOOLONG and e.value.filename == str(tmp_path / name)
    one_line(in_process("export-csv", show_file, "--out", tmp_path / name), "is 304 bytes; this file system allows")
    assert sorted(os.listdir(tmp_path)) == ["show.json"]


def test_a_full_disk_is_one_line_naming_the_file(in_process, tmp_path, show_file, monkeypatch):
    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    out = tmp_path / "s.csv"
    err = one_line(in_process("export-csv", show_file, "--out", out), f"{out}: No space left on device")
    assert "free some space" in err and ".tmp" not in err
    assert sorted(os.listdir(tmp_path)) == ["show.json"]  # no temporary file left behind


def test_an_os_error_of_another_kind_stays_an_internal_error(in_process, monkeypatch, show_file, tmp_path):
    from studio.cli.os_errors import os_error_line

    assert os_error_line(OSError(errno.EPROTO, "Protocol error")) is None
    assert os_error_line(OSError(errno.EROFS, "Read-only file system", "x.json")) == (
        "x.json: Read-only file system (write elsewhere)"
    )

    def odd(fd):
        raise OSError(errno.EPROTO, "Protocol error")

    monkeypatch.setattr(os, "fsync", odd)
    proc = in_process("export-csv", show_file, "--out", tmp_path / "s.csv")
    assert proc.returncode == 1 and "internal error: OSError" in proc.stderr and "Traceback" not in proc.stderr


def test_a_name_that_is_not_utf8_is_refused_at_once(in_process, tmp_path):
    out = tmp_path / os.fsdecode(b"caf\xe9.png")
    err = one_line(in_process("render", "--out", out), "caf\\xe9.png: the name is not UTF-8 text")
    assert "\udce9" not in err
    assert list(tmp_path.iterdir()) == []


def test_gathered_targets_with_names_that_are_not_utf8_are_refused(tmp_path):
    from studio.targets.image_sets import gather_targets
    from studio.targets.path_checks import NameNotText

    (tmp_path / os.fsdecode(b"caf\xe9.png")).write_bytes(b"")
    with pytest.raises(NameNotText, match=r"caf\\xe9.png"):
        gather_targets([tmp_path])


def test_sources_that_are_not_there_are_named_in_one_message_form(tmp_path):
    from studio.errors import TargetError
    from studio.evaluate.sequences import gather_sequences
    from studio.targets.image_sets import gather_targets
    from studio.targets.path_checks import existing_paths

    (tmp_path / "here.png").write_bytes(b"")
    assert existing_paths([str(tmp_path / "here.png"), tmp_path], "x") == [tmp_path / "here.png", tmp_path]
    gone = tmp_path / "gone"
    with pytest.raises(TargetError, match=f"^target file or folder not found: {gone}$"):
        gather_targets([tmp_path, gone])
    with pytest.raises(TargetError, match=r"^sequence \(video file or frame folder\) not found: "):
        gather_sequences([gone])


# ---------------------------------------------------------------- outputs never onto inputs


def test_outputs_never_overwrite_inputs(in_process, tmp_path, poses, show_file):
    before = poses.read_bytes(), show_file.read_bytes()
    one_line(in_process("plan", poses, "--out", poses), f"{poses} is both an input and an output")
    one_line(in_process("plan", poses, "--out", tmp_path / "a.json", "--csv", poses), "both an input and an output")
    one_line(in_process("plan", poses, "--out", tmp_path / "a.json", "--csv", tmp_path / "a.json"), "named twice")
    one_line(in_process("export-csv", show_file, "--out", show_file), "both an input and an output")
    link = tmp_path / "link.json"
    link.symlink_to(show_file)
    one_line(in_process("export-csv", show_file, "--out", link), f"the same file as the input {show_file}")
    one_line(in_process("render", poses, "--out", poses), "both an input and an output")
    assert (poses.read_bytes(), show_file.read_bytes()) == before


def test_project_export_never_writes_inside_the_project(in_process, tmp_path):
    project = tmp_path / "P.shadow"
    project.mkdir()
    (project / "project.json").write_text("{}")
    one_line(in_process("project", "export", project, "--out", project / "project.json"), "lies inside", "P.shadow")
    one_line(in_process("project", "export", project, "--out", project / "sub" / "show.json"), "lies inside")
    err = one_line(in_process("project", "export", project, "--out", tmp_path / "s.json", "--files", project))
    assert "lies inside" in err
    assert (project / "project.json").read_text() == "{}"


def test_verbs_with_an_output_folder_never_write_onto_or_into_their_input(in_process, tmp_path):
    import cv2

    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "a.png"), np.zeros((16, 16), np.uint8))
    still = tmp_path / "o" / "contact.png"
    still.parent.mkdir()
    still.write_bytes(b"\x89PNG\r\n\x1a\n")
    one_line(in_process("imitate", still, "--out", still.parent, "--threads", "1"), "both an input and an output")
    one_line(in_process("imitate-video", frames, "--out", frames), "lies inside", "frames")
    one_line(in_process("keyframes", frames, "--out", frames), "lies inside")
    one_line(in_process("evaluate", frames, "--out", frames / "tables"), "lies inside")
    one_line(in_process("evaluate-video", frames, "--out", frames), "lies inside")
    one_line(in_process("train", "--data", frames, "--out", frames), "both an input and an output")


def test_an_output_where_no_file_can_be_made_is_refused_first(in_process, tmp_path, poses):
    blocker = tmp_path / "file"
    blocker.write_text("")
    one_line(in_process("plan", poses, "--out", blocker / "s.json"), f"{blocker} is a file, not a folder")


# ---------------------------------------------------------------- temporary files


def test_the_video_never_follows_a_symlink_at_its_old_fixed_name(tmp_path):
    import cv2

    from studio.review.sheets import write_video

    victim = tmp_path / "elsewhere.txt"
    victim.write_text("keep me")
    out = tmp_path / "review"
    out.mkdir()
    planted = out / ".side_by_side.partial.mp4"  # the name the video was written under before
    planted.symlink_to(victim)
    path = write_video(out / "side_by_side.mp4", [np.full((33, 45, 3), 40 * i, np.uint8) for i in range(4)], 10)
    assert victim.read_text() == "keep me" and planted.is_symlink() and os.readlink(planted) == str(victim)
    assert sorted(os.listdir(out)) == [".side_by_side.partial.mp4", "side_by_side.mp4"]  # no temporary left
    assert int(cv2.VideoCapture(str(path)).get(cv2.CAP_PROP_FRAME_COUNT)) == 4


def test_temporary_files_are_made_exclusively_and_never_through_a_symlink(tmp_path, monkeypatch):
    import studio.atomic as atomic

    victim = tmp_path / "victim"
    victim.write_text("keep me")
    (tmp_path / ".t.json.00000000.tmp").symlink_to(victim)  # planted at the next temporary name
    tokens = iter(["00000000", "11111111"])
    monkeypatch.setattr(atomic.secrets, "token_hex", lambda n: next(tokens))
    write_text(tmp_path / "t.json", "new")
    assert victim.read_text() == "keep me" and (tmp_path / "t.json").read_text() == "new"
    assert not (tmp_path / ".t.json.11111111.tmp").exists()
