"""Everything a person looks at: Rerun recordings (the only place that imports rerun)."""
