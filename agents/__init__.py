"""softreach.agents (work in progress)."""
