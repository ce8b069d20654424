"""The tables anyone loads: the file (written snapshot by snapshot, checksummed, memory-mapped), ``Table`` and
``load_table``, the interpolant every look-up uses, the start states drawn from the sets."""
