"""Test oracles: the plain implementations (numpy renderings, OSQP) the compiled production paths are
checked against. Tests import them (``from oracles.esdf import ...``); shipped code never does."""
