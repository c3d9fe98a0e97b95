"""The footage stage (DESIGN §2, §3): from an image or a video to binary targets, with no torch and no self-model.

Still images (:mod:`.images`), reading and sampling footage (:mod:`.footage`), binarising a video into one square
frame (:mod:`.video`, :mod:`.cleanup`), segmenting raw colour footage (:mod:`.segment`, its settings in
:mod:`.segment_config`), expressive masks (:mod:`.expressive`), keyframe clustering (:mod:`.keyframes`), and
:func:`~studio.targets.source.open_source`, the one reader every face uses.
"""
