"""What the Targets panel does (mixed into :class:`widgets.targets.TargetsPanel`): add a source (a bundled sample, a
file path or an upload, written inside the project), apply the threshold, and segment raw colour footage from its
first frame's box or painted mask as a job on the project's queue, followed in the panel's line."""

from __future__ import annotations

import logging
from pathlib import Path

from studio.atomic import write_bytes
from studio.jobs import Job
from studio.progress import Progress
from studio.project.containment import check_subfolders
from studio.project.state import ProjectError
from studio.targets.source import source_kind
from studio.targets.video import SegmentationNeeded

log = logging.getLogger(__name__)

UPLOADS = "uploads"  # folder inside the project where uploaded files are written


class TargetsActions:
    """Actions of ``TargetsPanel`` (it provides ``state``, ``messages``, ``pending``, ``segment_job``, ``first``,
    ``segment_info``, ``cancel_segment``, ``_waiting``, ``redraw``, ``_is_still`` and ``_source_index``)."""

    def _add(self, path: Path) -> None:
        if not path.exists():
            raise ProjectError(f"no such file or folder: {path} (give a still, a video or a folder of frames)")
        try:
            index = self.state.edit("add_source", path)
        except SegmentationNeeded as e:
            self._waiting(path, e.footage.frames[0])  # the box's first guess: the middle of the frame
            self.redraw()
            self.messages.say(
                f"{path.name} is colour footage: give the object's box on its first frame, or paint it, then Segment"
            )
            return
        self._waiting(None)
        first = next(i for i, f in enumerate(self.state.project.frames) if f.source == index)
        self.state.select(frame=first)

    def _uploaded(self, value) -> None:
        if not value:
            return
        item = value[0]
        name = Path(str(item["name"])).name
        if source_kind(name) not in ("still", "video"):
            raise ProjectError(f"{name} is neither a still nor a video (upload a .jpeg, .png, .gif or .mp4)")
        data = bytes(item["content"])
        check_subfolders(self.state.project.path)  # uploads/ is a real folder inside the project, never a link
        folder = self.state.project.path / UPLOADS
        folder.mkdir(exist_ok=True)
        out, n = folder / name, 1
        while out.is_symlink() or (out.exists() and out.read_bytes() != data):  # never over another file
            n += 1
            out = folder / f"{Path(name).stem}-{n}{Path(name).suffix}"
        write_bytes(out, data)  # atomic: a link planted at that name is replaced, never followed
        log.info("uploaded %s (%d bytes)", out, len(data))
        self._add(out)

    def _apply_threshold(self) -> None:
        """The threshold (or Otsu) to the selected frame's kind of source; for a still also whether its crease
        pockets are filled: one edit of what changed (the sources are read again once)."""
        level = None if self.otsu.value else float(self.threshold.value)
        if not self._is_still(self._source_index()):
            self.state.edit("set_threshold", video=level)
            return
        still = self.state.project.state.still
        changes = {} if level == still.threshold else {"still": level}
        if bool(self.pockets.value) != (still.pocket_reach > 0):
            changes["pockets"] = bool(self.pockets.value)
        if changes:
            self.state.edit("set_threshold", **changes)

    def _segment(self) -> Job:
        project, pending = self.state.project, self.pending
        if pending is None and self._is_still(self._source_index()):
            raise ProjectError("the selected frame is a still: segmentation is for colour footage")
        prompt = self.first.prompt()  # {"box": ...} or {"first_mask": ...}
        source = self._source_index()

        def run(report, cancel) -> int:
            def progress(p: Progress) -> None:
                report(p)
                report.check()  # a cancelled job stops within a frame

            if pending is not None:
                return project.add_source(pending, progress=progress, **prompt)
            project.set_segmentation(source, progress=progress, **prompt)
            return source

        def apply(index: int) -> None:
            if pending is not None and self.pending == pending:
                self._waiting(None)
            self.state.changed("project")
            frames = self.state.project.frames
            self.state.select(frame=next((i for i, f in enumerate(frames) if f.source == index), 0))  # its first

        what = pending.name if pending is not None else f"source {source}"
        job = Job("segment", run, apply=apply, title=f"segment {what}")
        self.segment_job = job
        self.cancel_segment.disabled = False
        self.state.queue.submit(job)
        self.segment_info.value = f"segmenting {what} (job {job.id})"
        self.state.changed("jobs")
        return job

    def _job_event(self, event) -> None:
        job = self.segment_job
        if job is None or event.job_id != job.id:
            return
        if not event.final:
            counted = f" {event.step}/{event.total}" if event.total else ""
            self.segment_info.value = f"{job.title}: {event.stage}{counted}"
            return
        self.cancel_segment.disabled = True
        self.segment_info.value = f"{job.title}: {event.state.value}"
        if event.error is not None:
            self.messages.say(f"segmentation failed: {event.error}", error=True)
