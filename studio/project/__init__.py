"""An artist's saved work and background jobs (built by the studio issue; empty for now)."""
