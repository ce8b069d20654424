"""softreach.filters (work in progress)."""
