"""Everything a person looks at; the only package that imports rerun and meshcat (DESIGN §3, §5.6).

- :mod:`.rerun`: single imitations and videos as ``.rrd`` files, reading recordings back (``read_recording``).
- :mod:`.recording`: :class:`~studio.review.recording.ProjectRecording`, a project's review streamed live (a running
  viewer, the notebook viewer) and/or saved as ``.rrd``; its pieces: :mod:`.blueprint` (entity paths, the layout),
  :mod:`.frames` (frames and keyframes on ``frame``, job progress on ``opt_step``), :mod:`.rig3d` (hand, light and
  backdrop in 3D, the show on ``show_time``), :mod:`.playback` (commanded vs measured servo angles).
- :mod:`.scene`: the rig in meshcat (light, hand, backdrop textured with the shadow), offline snapshots.
- :mod:`.sheets`, :mod:`.video_review`: contact sheets and side-by-side videos (numpy + OpenCV).
"""

import os

# Rerun's notebook viewer fetches its JavaScript from the internet unless told otherwise (DESIGN §6); every module
# here that imports rerun is imported after this line. A value the user set first is kept ("serve-local", say).
os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "inline")
