"""The simulation the environments step: one control period with the action and the wind held (RK4 sub-steps, the budget
integral exact at the kinks of ``h_eps``), a model's scalar form for it, and the closed-loop rollouts of the plots and
tests."""
