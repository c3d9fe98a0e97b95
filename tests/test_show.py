"""Show file: lossless round trip, atomic writes, CSV export, and one clear error per kind of broken file."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from studio.errors import StudioError
from studio.motion.bounds import MAX_OFFSET_S
from studio.motion.show import KeyframeMarker, MediaRef, Show, ShowError, export_csv, load_show, save_show, show_schema
from studio.sim.hand import load_hand

HAND = load_hand()


def make_show(n: int = 41, seed: int = 0, **fields) -> Show:
    """A slow, smooth, in-limit show of ``n`` samples at 40 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 40.0
    mid = (HAND.lower + HAND.upper) / 2
    amp = (HAND.upper - HAND.lower) / 4 * rng.uniform(0, 1, HAND.dof)
    q = mid + amp * np.sin(2 * np.pi * 0.5 * t[:, None] + rng.uniform(0, 6, HAND.dof))
    fields.setdefault("keyframes", [KeyframeMarker(0.0, 0, "frame_000.png", True), KeyframeMarker(t[-1], 7)])
    return Show.from_samples(HAND, t, q, title="test show", **fields)


def write_doc(tmp_path, doc, name="show.json"):
    p = tmp_path / name
    p.write_text(json.dumps(doc, indent=1))
    return p


def doc_of(show: Show) -> dict:
    return json.loads(json.dumps(show.to_dict()))


finite = st.floats(-MAX_OFFSET_S, MAX_OFFSET_S, allow_nan=False, allow_infinity=False)  # a media offset's bounds


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    n=st.integers(1, 30),
    seed=st.integers(0, 2**16),
    title=st.text(max_size=20),
    offset=finite,
    losses=st.lists(st.floats(0, 10, allow_nan=False), max_size=4),
)
@pytest.mark.slow
def test_round_trip_is_lossless(tmp_path, n, seed, title, offset, losses):
    rng = np.random.default_rng(seed)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.02, 0.05, n - 1))])
    # small random steps keep the speed under the velocity limit
    q = np.clip(
        rng.uniform(HAND.lower, HAND.upper)[None] + np.cumsum(rng.normal(0, 0.004, (n, 21)), 0), HAND.lower, HAND.upper
    )
    show = Show.from_samples(
        HAND, t, q, title=title, calibration="cal/servos.yaml",
        media=MediaRef("song.ogg", "audio", offset),
        keyframes=[KeyframeMarker(float(t[-1]), None, None, False)],
        provenance={"loss_weights": {"mae": 0.06, "iou": 0.4}, "keyframe_losses": [{"total": x} for x in losses]},
    )  # fmt: skip
    path = save_show(show, tmp_path / "rt.json", HAND)
    back = load_show(path, HAND)
    assert back.equals(show)
    assert np.array_equal(back.times, show.times) and np.array_equal(back.positions, show.positions)
    assert back.title == title and back.media == show.media and back.keyframes == show.keyframes
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_api_fields_and_defaults():
    show = make_show()
    assert show.rate_hz == 40.0 and show.joint_names == HAND.joint_names and show.hand_hash == HAND.hash
    assert show.times[0] == 0 and show.positions.shape == (41, 21) and show.format_version == 1
    assert show.created.endswith("+00:00") and show.limits.velocity.shape == (21,)
    assert np.allclose(show.sample(show.times[3]), show.positions[3])
    assert issubclass(ShowError, StudioError)


def test_saved_file_matches_the_shipped_schema(tmp_path):
    import jsonschema

    path = save_show(make_show(), tmp_path / "a.json")
    jsonschema.validate(json.loads(path.read_text()), show_schema())


def test_csv_export(tmp_path):
    show = make_show(n=5)
    path = export_csv(show, tmp_path / "a.csv")
    rows = list(csv.reader(path.open()))
    assert rows[0] == ["t_s"] + [f"{n}_rad" for n in HAND.joint_names]
    got = np.array(rows[1:], dtype=float)
    assert np.array_equal(got[:, 0], show.times) and np.array_equal(got[:, 1:], show.positions)
    deg = np.array(list(csv.reader(export_csv(show, tmp_path / "d.csv", degrees=True).open()))[1:], dtype=float)
    assert np.allclose(deg[:, 1:], np.degrees(show.positions))


def test_atomic_write_keeps_the_old_file_when_validation_fails(tmp_path):
    good = save_show(make_show(), tmp_path / "a.json")
    before = good.read_text()
    bad = make_show()
    bad.positions[3, 0] = np.nan
    with pytest.raises(ShowError, match="wrist is NaN"):
        save_show(bad, good)
    assert good.read_text() == before


def expect_error(tmp_path, doc, *patterns, raw: str | None = None):
    path = tmp_path / "broken.json"
    path.write_text(raw if raw is not None else json.dumps(doc))
    with pytest.raises(ShowError) as e:
        load_show(path, HAND)
    msg = str(e.value)
    for p in patterns:
        assert p in msg, msg
    return e.value


def test_bad_version(tmp_path):
    doc = doc_of(make_show())
    doc["version"] = 7
    err = expect_error(tmp_path, doc, "unsupported show format version 7", "newer Shadow Studio")
    assert len(err.problems) == 1


def test_wrong_joint_names(tmp_path):
    doc = doc_of(make_show())
    doc["hand"]["joint_names"][2] = "elbow"
    expect_error(tmp_path, doc, "joint names do not match the hand", "unknown ['elbow']", "missing ['thumb_mcp_flex']")
    doc = doc_of(make_show())
    names = doc["hand"]["joint_names"]
    names[1], names[2] = names[2], names[1]
    expect_error(tmp_path, doc, "different order")


def test_nan_value(tmp_path):
    show = make_show()
    text = json.dumps(doc_of(show)).replace(repr(float(show.positions[4, 6])), "NaN", 1)
    expect_error(tmp_path, None, "index_mcp_flex is NaN/inf", raw=text)


def test_time_going_backwards(tmp_path):
    doc = doc_of(make_show())
    doc["samples"][10][0] = doc["samples"][8][0]
    err = expect_error(tmp_path, doc, "time goes backwards or repeats at sample 10")
    assert len(err.problems) == 1
    doc = doc_of(make_show())
    doc["samples"][0][0] = 0.01
    expect_error(tmp_path, doc, "a show starts at t = 0")


def test_out_of_limit_angle(tmp_path):
    doc = doc_of(make_show())
    doc["samples"][5][HAND.joint_names.index("ring_mcp_abd") + 1] = 2.0
    expect_error(tmp_path, doc, "ring_mcp_abd leaves its limits", "t = 0.125 s")


def test_truncated_json(tmp_path):
    path = save_show(make_show(), tmp_path / "a.json")
    text = path.read_text()
    expect_error(tmp_path, None, "not valid JSON (truncated or corrupt?)", raw=text[: len(text) // 2])


def test_schema_violation_and_too_fast(tmp_path):
    doc = doc_of(make_show())
    del doc["limits"]
    expect_error(tmp_path, doc, "schema: at top level: 'limits' is a required property")
    doc = doc_of(make_show())
    doc["samples"][3][1 + 7] = doc["samples"][2][1 + 7] + 1.0  # 1 rad in 25 ms
    expect_error(tmp_path, doc, "index_pip moves at", "above its velocity limit")


def test_checking_a_show_in_a_fresh_process_leaves_jsonschemas_iri_grammar_unloaded(tmp_path):
    """A process that checks a show (every verb that saves or loads one) imports jsonschema without building the
    "iri" format's grammar (rfc3987_syntax, 1.7 s on import when installed): the schema still finds a violation,
    and the package stays importable afterwards."""
    doc = doc_of(make_show())
    del doc["limits"]
    path = write_doc(tmp_path, doc)
    code = (
        "import sys\n"
        "from studio.motion.show import ShowError, load_show\n"
        f"try:\n    load_show({str(path)!r})\nexcept ShowError as e:\n    print(e)\n"
        "print('rfc3987_syntax' in sys.modules, 'jsonschema' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    said, loaded = out.stdout.strip().splitlines()[-2:]
    assert "'limits' is a required property" in said
    assert loaded == "False True"  # jsonschema checked it; the grammar was never built, its name is not left blocked


def test_several_problems_are_each_reported(tmp_path):
    doc = doc_of(make_show())
    doc["samples"][10][0] = 0.0
    doc["samples"][5][HAND.joint_names.index("wrist") + 1] = 3.0
    err = expect_error(tmp_path, doc, "problems", "time goes backwards", "wrist leaves its limits")
    assert len(err.problems) >= 2


def test_from_samples_rejects_bad_shapes():
    with pytest.raises(ShowError, match=r"positions \(N, 21\)"):
        Show.from_samples(HAND, np.arange(3) / 40, np.zeros((3, 20)))


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_show(tmp_path / "nope.json")
