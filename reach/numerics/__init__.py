"""The grid solver of the Hamilton-Jacobi-Isaacs variational inequality: the grid, upwind derivatives and the numerical
Hamiltonian, time marching and its compiled engines (CPU loops, GPU), the held game, the budget surface, and
``solve_table``, which writes a table; with the point mass's exact sets that grade the solver."""
