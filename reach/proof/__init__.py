"""What the safety filter's proof is built from: the one-period look-ahead's parameters, one held period's bounds
(its boxes, ``C1``, the budget, landing inside it), interval arithmetic, the compiled kernels (certificate, box
maxima, cover test, a model's kernels by address, blocks of a batch), the cells' game and certificate (with the
packaged cells), and the early check of a model's enclosures."""
