"""``riskfield demo``: the whole stack on one machine, the paper's teleop and navigation
experiments in simulation, and a report."""
