"""``softreach solve``, ``plot`` and ``study``: the command line's arguments and actions, the plots of a table (two and
three states) and the studies."""
