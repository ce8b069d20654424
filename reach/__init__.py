"""softreach.reach: the soft-constrained HJ solver and W_eps tables."""
