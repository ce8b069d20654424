"""What the safety filter's proof is built from: the one-period look-ahead from the model's held enclosures, landing
inside a period, the horizon, interval arithmetic, the compiled kernels (certificate, box maxima, cover test, a model's
kernels by address, blocks of a batch), the cells' game and certificate (with the packaged cells), and the early check
of a model's enclosures."""
