"""The filter's compiled one-period test is compiled once for every action it judges: numba compiles a function
once per argument type, and an array's type says whether it is writable. The decision judges the policy's action
from a work array (writable) and the candidates as rows of the filter's candidate array: were those read-only, the
test and the landing check it calls would be compiled twice, seconds each on the filter's first use."""

from __future__ import annotations

import numba
import numpy as np

from softreach.filters import ValueFilter
from softreach.filters.compiled import decision_space


def test_a_candidate_row_has_the_type_of_the_action_being_judged(pointmass_held_table):
    vf = ValueFilter(pointmass_held_table, pointmass_held_table.control_period)
    cd = vf.compiled
    assert cd is not None
    J, m = cd.cands.shape
    space = decision_space(vf.lookahead.n, m, J)[0]
    assert numba.typeof(cd.cands[0]) == numba.typeof(space.act)
    # the candidates themselves are the filter's: the compiled code reads them, it never writes them
    np.testing.assert_array_equal(cd.cands, np.asarray(vf.lookahead.candidates, dtype=np.float64))
