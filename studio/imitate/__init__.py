"""From a target to poses: targets, crops, losses, gradient search, refinement, one still end to end."""
