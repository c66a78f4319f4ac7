"""The paper's experiments and the demo, in one place.

Everything here composes the services' pure cores (mapping, safety filter, navigator, simulator,
perception) or runs the whole stack as processes; no service imports from here.

* ``safety_benchmark``, ``sampling``, ``metrics``, ``tables``, ``scannetpp``: the simulation
  protocol of the paper's Section V-A (Tables II and III; the point-cloud baseline field is
  ``riskfield.services.fields.pointcloud``);
* ``scenarios``, ``teleop``, ``navigation``: the paper's hardware experiments (their worlds, the
  operator's approach to a ball and a dog, the navigation loop with an unseen obstacle, and their
  metrics), shared by the demo and the benches;
* ``stack``: the whole stack as processes (the runtime's process runner), for those experiments;
* ``demo``: ``riskfield demo`` — both hardware experiments in simulation, with a report;
* ``benches``: every ``riskfield bench NAME`` entry point, one module per NAME exposing ``app``.
"""
