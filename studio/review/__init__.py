"""Everything a person looks at; the only package that imports rerun and meshcat (DESIGN §3, §5.6).

- :mod:`.recording`: :class:`~studio.review.recording.ProjectRecording`, THE review (one entity tree, one blueprint)
  of every project, so of every still, video and show the studio imitates (a one-source project) and of every
  playback, streamed live (a running viewer, the notebook viewer) and/or saved as ``.rrd``. Its pieces:
  :mod:`.blueprint` (entity paths, the layout), :mod:`.frames` (frames and keyframes on ``frame``),
  :mod:`.job_progress` (job progress on ``opt_step``), :mod:`.rig3d` (the hand from the URDF, light and backdrop in
  3D, the show on ``show_time``), :mod:`.playback` (commanded vs measured servo angles).
- :mod:`.notebook_viewer`: the Rerun viewer widget for notebooks (offline, full width, on a recording's live stream).
- :mod:`.scene`: the rig in meshcat (light, hand, backdrop textured with the shadow), offline snapshots.
- :mod:`.sheets`, :mod:`.video_review`: contact sheets and side-by-side videos (numpy + OpenCV).
- :mod:`.readback`: reading a recording back (``read_recording``, ``scalar_series``) for tests and tools.
"""

import os

# Rerun's notebook viewer fetches its JavaScript from the internet unless told otherwise (DESIGN §6); every module
# here that imports rerun is imported after this line. A value the user set first is kept ("serve-local", say).
os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "inline")
