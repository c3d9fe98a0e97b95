"""From poses to a timed show: limits, spline path with recovery, detours, Ruckig timing, planning, the show file."""
