"""The motion and sets of the cart of docs/models.md (a double integrator pushed by a bounded wind), shared by the
tests that declare their own variant of it (its boxes, grid and period) around them."""

from softreach.reach import sets


class CartMotion:
    """``p' = v``, ``v' = a + w``; target ``|p|, |v| <= 0.2``, ``C1 = {|p|, |v| <= 2}``, ``C2 = {|v| <= 1}``."""

    name = "cart"
    state_names = ("p", "v")
    state_units = ("m", "m/s")
    horizon = 3.0
    domain = ((-2.5, -2.5), (2.5, 2.5))
    hard_box = ((-2.0, -2.0), (2.0, 2.0))

    def drift(self, t, x):
        return [x[1], 0]

    def control_matrix(self, t, x):
        return [[0], [1.0]]

    def disturbance_matrix(self, t, x):
        return [[0], [1.0]]

    def target(self, t, x):
        return sets.box(x, (-0.2, -0.2), (0.2, 0.2))

    def hard_constraint(self, t, x):
        return sets.box(x, (-2.0, -2.0), (2.0, 2.0))

    def soft_constraint(self, t, x):
        return sets.box([x[1]], (-1.0,), (1.0,))
