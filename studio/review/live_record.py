"""What a live session leaves behind: ``live --record DIR`` (and the Live panel's record box).

:class:`LiveRecorder` streams every :class:`~studio.project.live.LiveUpdate` into ``DIR/live.rrd`` as it comes
(a session cut short keeps what was logged), on ``play_time`` (s since the session started, the timeline of the
servo angles too)::

    images/source        the camera frame (longer side ≤ 320 px, RGB)
    images/target        the silhouette the hand follows (dark on light), cleared while there is none
    images/rendered      the commanded pose's shadow as the mount casts it
    world/pose/<joint>   the commanded pose, rad (scalars)
    loss/live            the commanded shadow's loss against its target
    log/live             why the hand holds, when it does
    servo/<joint>/commanded|measured   from the playback result, when the session ends

and, when the session ends, ``DIR/keyframes.json``: the commanded poses thinned to at most ``keyframe_hz`` a
second (the newest pose of each interval), timed from the first, in the POSES.json form that
``shadow-studio plan`` reads (each keyframe's loss kept, and the mount roll the poses were chosen for).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import rerun as rr

from studio.atomic import write_text
from studio.review.blueprint import LOG, LOSS, PLAY_TIME, POSE, RENDERED, SOURCE, TARGET, part, set_time
from studio.review.playback import log_playback
from studio.review.recording import APPLICATION
from studio.review.sheets import display
from studio.sim.hand import Hand
from studio.sim.roll import file_deg

LIVE_LOSS = f"{LOSS}/live"
LIVE_LOG = f"{LOG}/live"
PREVIEW_SIDE = 320  # the camera frame's longer side in the recording, px


def keyframes_doc(
    times: np.ndarray, poses: np.ndarray, losses: np.ndarray, hand: Hand, keyframe_hz: float, roll: float = 0.0
) -> dict:
    """Commanded poses ``(U, 21)`` rad at ``times (U,)`` s → a POSES.json document: the newest pose of each
    ``1 / keyframe_hz`` interval, times from the first kept one, holding at both ends; ``roll`` rad, the mount roll
    the poses were chosen for (a show planned from the file is then for that mount)."""
    if not len(times):
        raise ValueError("the session commanded no pose: nothing to keep as keyframes")
    slot = np.floor((np.asarray(times) - times[0]) * keyframe_hz).astype(int)
    last = np.flatnonzero(np.r_[slot[1:] != slot[:-1], True])  # the newest update of each interval
    t = np.asarray(times)[last] - times[last[0]]
    frames = [
        {"t": round(float(ti), 4), "pose": hand.pose_to_dict(poses[i]), "loss": round(float(losses[i]), 5)}
        for ti, i in zip(t, last, strict=True)
    ]
    frames[0]["hold"] = frames[-1]["hold"] = True
    return {"title": "live session", "roll_deg": file_deg(roll), "keyframes": frames}


class LiveRecorder:
    """``live --record DIR`` (module doc). Refuses a ``folder`` that is a file, before the session starts."""

    def __init__(self, folder: Path, hand: Hand, keyframe_hz: float = 4.0):
        self.folder, self.hand, self.keyframe_hz = Path(folder), hand, float(keyframe_hz)
        if self.folder.exists() and not self.folder.is_dir():
            raise ValueError(f"--record {self.folder}: a file is there; give a folder")
        self.folder.mkdir(parents=True, exist_ok=True)
        self.rrd = self.folder / "live.rrd"
        self.rec = rr.RecordingStream(APPLICATION)
        self.rec.save(str(self.rrd))
        self._held = ""

    def update(self, u: Any) -> None:
        """Log one update (a :class:`~studio.project.live.LiveUpdate`)."""
        rec = self.rec
        set_time(rec, **{PLAY_TIME: max(0.0, float(u.t))})
        if u.image.shape[0] > 1:
            rgb = cv2.cvtColor(np.asarray(u.image), cv2.COLOR_BGR2RGB)
            scale = PREVIEW_SIDE / max(rgb.shape[:2])
            if scale < 1:
                rgb = cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            rec.log(SOURCE, rr.Image(rgb))
        rec.log(TARGET, rr.Clear(recursive=False) if u.target is None else rr.Image(display(u.target)))
        if u.theta is not None:
            rec.log(RENDERED, rr.Image(display(u.shadow)))
            for name, value in zip(self.hand.joint_names, u.theta, strict=True):
                rec.log(f"{POSE}/{part(name)}", rr.Scalars(float(value)))
            rec.log(LIVE_LOSS, rr.Scalars(float(u.loss)))
        if u.status != self._held:
            rec.log(LIVE_LOG, rr.TextLog(u.status or "following the camera again"))
            self._held = u.status

    def finish(self, result: Any) -> list[Path]:
        """Log the servo angles, close the recording and write the keyframes → the files written."""
        out = [self.rrd]
        try:
            if result is not None and len(np.asarray(result.playback.t)):
                log_playback(self.rec, result.playback)
            self.rec.flush()
        finally:
            self.rec.disconnect()
        if result is not None and result.updates:
            doc = keyframes_doc(result.times, result.poses, result.losses, self.hand, self.keyframe_hz, result.roll)
            path = self.folder / "keyframes.json"
            write_text(path, json.dumps(doc, indent=1) + "\n")
            out.append(path)
        return out
