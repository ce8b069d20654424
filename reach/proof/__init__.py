"""The safety filter's proof: the one-period look-ahead, one held period's bounds, interval arithmetic, the
compiled kernels, the cells' game and certificate, and the early check of a model's enclosures."""
