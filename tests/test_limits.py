"""Limits on every input (issue 24): bounded flags and file fields, typed one-line errors where an "internal error"
was, JSON types not coerced, outputs never onto inputs, temporary files never followed through a planted symlink."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
from limits_support import edited, one_line

from studio.motion.bounds import MAX_KEYFRAMES
from studio.motion.errors import PlanError
from studio.motion.plan import parse_keyframes

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
