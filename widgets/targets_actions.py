"""What the Targets panel does (mixed into :class:`widgets.targets.TargetsPanel`): add a source (a bundled sample, a
file path or an upload, written inside the project), apply the threshold or the sampling, relink a moved source, and
segment raw colour footage from its first frame's box or painted mask. Each of these reads the sources again (seconds
on a long video or a large photo), so each runs as a job on the project's queue, never in the click handler: the
notebook stays live, the panel's line follows the job, Cancel stops it with the project unchanged, and the panel's
edit buttons rest until it ends (an edit is decided on the project as the artist sees it, never on one that a queued
edit is about to change)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from studio.atomic import write_bytes
from studio.errors import Progress, ProgressFn, count
from studio.jobs import Job, JobState
from studio.project.containment import check_subfolders
from studio.project.state import ProjectError
from studio.targets.source import source_kind
from studio.targets.video import SegmentationNeeded

log = logging.getLogger(__name__)

UPLOADS = "uploads"  # folder inside the project where uploaded files are written
EDIT_BUTTONS = ("add_sample", "add_path", "upload", "apply_threshold", "apply_hz", "segment")  # rest while a job runs


class TargetsActions:
    """Actions of ``TargetsPanel`` (it provides ``state``, ``messages``, ``pending``, ``job``, ``first``,
    ``job_info``, ``cancel_job``, ``relink``, the buttons of ``EDIT_BUTTONS``, ``_waiting``, ``redraw``, ``_is_still``
    and ``_source_index``)."""

    def _add(self, path: Path) -> Job:
        if not path.exists():
            raise ProjectError(f"no such file or folder: {path} (give a still, a video or a folder of frames)")
        project = self.state.project

        def run(progress: ProgressFn) -> int | SegmentationNeeded:
            try:
                return project.add_source(path, progress=progress)
            except SegmentationNeeded as e:  # not a failure: the artist gives the object next
                return e

        def apply(added: int | SegmentationNeeded) -> None:
            if isinstance(added, SegmentationNeeded):
                self._waiting(path, added.footage.frames[0])  # the box's first guess: the middle of the frame
                self.messages.say(f"{path.name} is colour footage: give the object's box on its first frame, or "
                                  "paint it, then Segment")  # fmt: skip
                return
            self._waiting(None)
            self._select_source(added)

        return self._submit("add-source", f"add {path.name}", run, apply)

    def _select_source(self, index: int) -> None:
        """Bring source ``index``'s first frame into view."""
        frames = self.state.project.frames
        self.state.select(frame=next((i for i, f in enumerate(frames) if f.source == index), 0))

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

    def _apply_threshold(self) -> Job | None:
        """The threshold (or Otsu) to the selected frame's kind of source; for a still also whether its crease
        pockets are filled: one edit of what changed (the sources are read again once)."""
        level = None if self.otsu.value else float(self.threshold.value)
        if not self._is_still(self._source_index()):
            changes: dict[str, Any] = {"video": level}
        else:
            still = self.state.project.state.still
            changes = {} if level == still.threshold else {"still": level}
            if bool(self.pockets.value) != (still.pocket_reach > 0):
                changes["pockets"] = bool(self.pockets.value)
        if not changes:
            return None
        project = self.state.project
        return self._submit("threshold", "apply the threshold", lambda p: project.set_threshold(**changes, progress=p))

    def _apply_sampling(self) -> Job:
        hz, project = float(self.hz.value), self.state.project
        return self._submit(
            "sampling", f"sample the videos at {hz:g} Hz", lambda p: project.set_sampling(hz=hz, progress=p)
        )

    def _relink(self, source: int, where: Path) -> Job:
        project = self.state.project

        def apply(_) -> None:
            self.messages.say(f"source {source} relinked to {where}")
            self.relink.path.value = ""

        return self._submit("relink", f"relink source {source}", lambda p: project.relink_source(source, where, p),
                            apply)  # fmt: skip

    def _segment(self) -> Job:
        project, pending = self.state.project, self.pending
        if pending is None and self._is_still(self._source_index()):
            raise ProjectError("the selected frame is a still: segmentation is for colour footage")
        prompt = self.first.prompt()  # {"box": ...} or {"first_mask": ...}
        source = self._source_index()

        def run(progress: ProgressFn) -> int:
            if pending is not None:
                return project.add_source(pending, progress=progress, **prompt)
            project.set_segmentation(source, progress=progress, **prompt)
            return source

        def apply(index: int) -> None:
            if pending is not None and self.pending == pending:
                self._waiting(None)
            self._select_source(index)

        what = pending.name if pending is not None else f"source {source}"
        return self._submit("segment", f"segment {what}", run, apply)

    def _submit(self, kind: str, title: str, run: Callable[[ProgressFn], Any],
                apply: Callable[[Any], None] | None = None) -> Job:  # fmt: skip
        """``run(progress)``, a project edit, as a job of kind ``kind`` on the project's queue (module doc);
        ``apply(result)`` after it succeeded, on the queue's thread, then every panel redraws."""
        if self.job is not None and not self.job.finished:
            raise ProjectError(f"{self.job.title} has not ended yet: wait for it, or cancel it")

        def job_run(report, cancel) -> Any:
            def progress(p: Progress) -> None:
                report(p)
                report.check()  # a cancelled job stops at its next step: the project stays as it was

            return run(progress)

        def job_apply(result: Any) -> None:
            if apply is not None:
                apply(result)
            self.state.changed("project")

        job = Job(kind, job_run, apply=job_apply, title=title)
        self.job = job
        self._busy(True)
        self.job_info.value = f"{title}: queued"
        self.state.queue.submit(job)
        ahead = sum(not j.finished for j in self.state.queue.jobs() if j.id < job.id)  # e.g. the Optimise tab's run
        if ahead and job.state == JobState.QUEUED:
            self.job_info.value = f"{title}: queued behind {count(ahead, 'job')} (the Optimise tab's list)"
        self.state.changed("jobs")
        return job

    def _busy(self, busy: bool) -> None:
        """While the panel's job runs its edit buttons rest and Cancel is offered (and the other way round)."""
        for name in EDIT_BUTTONS:
            getattr(self, name).disabled = busy
        self.relink.button.disabled = busy
        self.cancel_job.disabled = not busy

    def _job_event(self, event) -> None:
        job = self.job
        if job is None or event.job_id != job.id:
            return
        if not event.final:
            counted = f" {event.step}/{event.total}" if event.total else ""
            self.job_info.value = f"{job.title}: {event.stage or event.state.value}{counted}"
            return
        self._busy(False)
        self.job_info.value = f"{job.title}: {event.state.value}"
        if event.error is not None:
            self.messages.say(f"{job.title} failed: {event.error.message}", error=True)
