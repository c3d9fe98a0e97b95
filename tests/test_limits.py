"""Limits on every input (issue 24): bounded flags and file fields, typed one-line errors where an "internal error"
was, JSON types not coerced, outputs never onto inputs, temporary files never followed through a planted symlink."""

from __future__ import annotations

import argparse
import errno
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from studio.atomic import write_text
from studio.motion.bounds import MAX_KEYFRAMES
from studio.motion.errors import PlanError
from studio.motion.plan import parse_keyframes
from studio.motion.show import Show, save_show


def one_line(proc: subprocess.CompletedProcess, *words: str) -> str:
    """The one error line of a refused command (exit 2, no traceback, no internal error), checked for ``words``."""
    err = proc.stderr.strip()
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert err.count("\n") == 0 and "Traceback" not in err and "internal error" not in err, err
    for w in words:
        assert w in err, err
    return err


@pytest.fixture
def poses(tmp_path, hand) -> Path:
    """A keyframes file of two keyframes near rest (plans in about a second)."""
    q = hand.rest_pose()
    q2 = q.copy()
    q2[1] += 0.3
    path = tmp_path / "kf.json"
    keyframes = [{"t": 1.0, "pose": hand.pose_to_dict(q2)}, {"t": 2.0, "pose": hand.pose_to_dict(q)}]
    path.write_text(json.dumps({"keyframes": keyframes}))
    return path


@pytest.fixture
def show_file(tmp_path, hand) -> Path:
    q = hand.rest_pose()
    return save_show(Show.from_samples(hand, [0.0, 0.5, 1.0], np.stack([q, q, q])), tmp_path / "show.json")


def edited(path: Path, name: str, change) -> Path:
    doc = json.loads(path.read_text())
    change(doc)
    out = path.with_name(name)
    out.write_text(json.dumps(doc))
    return out


# ---------------------------------------------------------------- bounds


def _numeric_flags():
    """(verb, flag, its Range or None) of every int/float flag of every verb."""
    from studio.cli.main import build_parser

    def walk(parser, path):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    yield from walk(sub, [*path, name])
            elif a.type is not None and getattr(a.type, "__name__", "") in ("int", "float"):
                cells = [c.cell_contents for c in (getattr(a.type, "__closure__", None) or ())]
                rng = next((c for c in cells if type(c).__name__ == "Range"), None)
                yield " ".join(path), a.option_strings[0] if a.option_strings else a.dest, rng

    return list(walk(build_parser(), []))


OTHERS: set[tuple[str, str]] = set()  # the servo and project areas'


def test_every_numeric_flag_has_a_finite_range():
    """Every number a verb takes has an upper bound (and a lower one): nothing asks for 4 GB by a typo."""
    flags = _numeric_flags()
    assert len(flags) > 100
    open_ended = [
        (verb, flag, str(rng))
        for verb, flag, rng in flags
        if (verb, flag) not in OTHERS and (rng is None or not np.isfinite([rng.lo, rng.hi]).all())
    ]
    assert not open_ended, open_ended


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (("imitate", "t.png", "--out", "o", "--search-batch", "1000000000"), "--search-batch: must be in [1, 2048]"),
        (("render", "--resolution", "100000"), "--resolution: must be in [8, 8192], got 100000"),
        (("imitate", "t.png", "--out", "o", "--threads", "100000"), "--threads: must be in [1, 256]"),
        (("evaluate", "t.png", "--out", "o", "--threads", "100000"), "--threads: must be in [0, 256]"),
        (("imitate", "t.png", "--out", "o", "--device", "tpu"), "--device: expected cpu or cuda"),
        (("plan", "kf.json", "--out", "o.json", "--acceleration", "1e-9"), "--acceleration: must be in [0.01, 10000]"),
        (("train", "--batch-size", "100000"), "--batch-size: must be in [1, 1024]"),
        (("imitate", "t.png", "--out", "o", "--roll", "1e300"), "expected auto or an angle in degrees in [-360, 360]"),
        (("plan", "kf.json", "--out", "o.json", "--seed", str(2**40)), "--seed: must be in [0, 4294967295]"),
    ],
)
def test_out_of_bound_flags_are_refused_at_once(in_process, argv, words):
    one_line(in_process(*argv), words)


def test_cuda_without_a_gpu_is_one_line(in_process):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU: --device cuda is valid here")
    one_line(in_process("imitate", "t.png", "--out", "o", "--device", "cuda"), "no CUDA GPU", "use cpu")
    one_line(in_process("train", "--device", "cuda"), "no CUDA GPU")


def test_keyframe_fields_are_typed_and_bounded(hand, poses):
    good = json.loads(poses.read_text())
    cases = [
        ({"t": 1e7}, "t is 10000000; it must be a number of seconds in [0, 3600]"),
        ({"t": "2.5"}, "t is '2.5', a string"),
        ({"t": True}, "t is True, true/false"),
        ({"t": -1.0}, "t is -1; it must be"),
        ({"hold": "false"}, "\"hold\" is 'false'; it must be true or false"),
        ({"hold": 0}, '"hold" is 0; it must be true or false'),
        ({"source_frame": -3}, '"source_frame" is -3'),
        ({"source_frame": 1.5}, '"source_frame" is 1.5'),
        ({"target": 7}, '"target" is 7'),
    ]
    for change, words in cases:
        doc = json.loads(json.dumps(good))
        doc["keyframes"][1].update(change)
        with pytest.raises(PlanError) as e:
            parse_keyframes(doc, hand)
        assert words in str(e.value) and "np.float64" not in str(e.value), (change, str(e.value))
    doc = json.loads(json.dumps(good))
    doc["keyframes"][0]["pose"]["wrist"] = "0.1"
    with pytest.raises(PlanError, match="joint wrist is '0.1'; every angle must be a number"):
        parse_keyframes(doc, hand)
    kf = parse_keyframes({**good, "keyframes": [{**k, "hold": True} for k in good["keyframes"]]}, hand)
    assert kf.hold.tolist() == [True, True]


def test_duplicate_keyframe_ids_and_too_many_keyframes_are_refused(hand, poses):
    good = json.loads(poses.read_text())
    doc = json.loads(json.dumps(good))
    doc["keyframes"][0]["id"] = doc["keyframes"][1]["id"] = 3
    with pytest.raises(PlanError, match="keyframe id 3 appears more than once"):
        parse_keyframes(doc, hand)
    doc = {**good, "poses": [{"id": 1}, {"id": 1}]}
    with pytest.raises(PlanError, match="poses: keyframe id 1 appears more than once"):
        parse_keyframes(doc, hand)
    one = good["keyframes"][0]
    many = {"keyframes": [{**one, "t": i * 0.01} for i in range(MAX_KEYFRAMES + 1)]}
    with pytest.raises(PlanError, match=f"at most {MAX_KEYFRAMES}"):
        parse_keyframes(many, hand)


def test_plan_names_the_file_and_the_keyframe(in_process, poses, tmp_path):
    far = edited(poses, "far.json", lambda d: d["keyframes"][1].update(t=1e7))
    one_line(in_process("plan", far, "--out", tmp_path / "o.json"), f"{far}: keyframe 1: t is 10000000")
    hold = edited(poses, "hold.json", lambda d: d["keyframes"][0].update(hold="false"))
    one_line(in_process("plan", hold, "--out", tmp_path / "o.json"), "keyframe 0", "must be true or false")
    assert not (tmp_path / "o.json").exists()


def test_show_file_numbers_are_bounded(in_process, show_file):
    fast = edited(show_file, "fast.json", lambda d: d.update(rate_hz=1e9))
    one_line(in_process("validate", fast), "rate_hz", "maximum of 1000")
    from studio.motion.show_checks import show_problems

    doc = json.loads(fast.read_text())
    assert any("rate_hz is 1000000000; it must be a number of Hz in (0, 1000]" in p for p in show_problems(doc))
    late = edited(show_file, "late.json", lambda d: d["keyframes"].append({"t": 1e7}))
    one_line(in_process("validate", late), "keyframes/0/t", "maximum of 3600")


def test_the_schema_states_the_bounds_module():
    from studio.motion import bounds
    from studio.motion.show import show_schema

    p = show_schema()["properties"]
    assert p["rate_hz"]["maximum"] == bounds.MAX_RATE_HZ
    assert p["samples"]["maxItems"] == bounds.MAX_SAMPLES
    assert p["keyframes"]["maxItems"] == bounds.MAX_KEYFRAMES
    assert p["keyframes"]["items"]["properties"]["t"]["maximum"] == bounds.MAX_SHOW_S
    assert p["keyframes"]["items"]["properties"]["source_frame"]["maximum"] == bounds.MAX_SOURCE_FRAME
    assert p["media"]["properties"]["offset_s"]["maximum"] == bounds.MAX_OFFSET_S
    assert p["limits"]["properties"]["jerk"]["items"]["maximum"] == bounds.MAX_LIMIT


def test_plan_shows_progress_at_once(in_process, poses, tmp_path):
    proc = in_process("plan", poses, "--out", tmp_path / "s.json")
    assert proc.returncode == 0, proc.stderr
    assert "read keyframes" in proc.stderr and "keyframes" in proc.stderr, proc.stderr
    quiet = in_process("plan", poses, "--out", tmp_path / "s.json", "--quiet")
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr


def test_limits_too_small_for_ruckig_are_a_clear_plan_error(hand):
    from studio.motion.limits import JointLimits, LimitsConfig
    from studio.motion.segment_timer import RuckigSolver, SegmentTimer

    limits = JointLimits.from_hand(hand, LimitsConfig(acceleration=1e-9, jerk=1e-9))
    q0, q1 = hand.rest_pose(), hand.rest_pose()
    q1[1] += 0.3
    z = np.zeros_like(q0)
    assert RuckigSolver(limits).solve(q0, z, q1, z, None) is None  # Ruckig's -101, not "-101 is not a valid Result"
    timer = SegmentTimer(RuckigSolver(limits), limits)
    with pytest.raises(PlanError, match="limits are too small to reach it"):
        timer.time(0.0, 1.0, np.array([0.0, 1.0]), np.stack([q0, q1]), np.stack([z, z]), np.array([True, True]))


# ---------------------------------------------------------------- internal errors that became one line


@pytest.mark.parametrize("depth", [70, 100_000])
def test_nested_json_is_one_line_everywhere(in_process, tmp_path, show_file, depth):
    from studio.jsonfile import MAX_DEPTH, JsonFileError, parse_json

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
    from studio.path_checks import NameNotText
    from studio.targets.images import gather_targets

    (tmp_path / os.fsdecode(b"caf\xe9.png")).write_bytes(b"")
    with pytest.raises(NameNotText, match=r"caf\\xe9.png"):
        gather_targets([tmp_path])


def test_sources_that_are_not_there_are_named_in_one_message_form(tmp_path):
    from studio.errors import TargetError
    from studio.evaluate.sequences import gather_sequences
    from studio.path_checks import existing_paths
    from studio.targets.images import gather_targets

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
