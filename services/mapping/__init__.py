"""The mapping service: pointmaps → confidence-weighted semantic TSDF → semantic occupancy →
semantically inflated signed ESDF (the paper's "Semantic Map and ESDF Construction",
Algorithm 1), in the manner of nvblox: a rolling volume, layers, one integrator per
transformation, each with its own parameter struct, and a ``Mapper`` composing them with the
stages that follow a changing world (the keyframe protocol's ``keyframes.py``, the present layer's
``present.py``, the decay of people and animals' ``decay.py``, the floor seen free's
``free_floor.py``) and the output of the published grids (``esdf_output.py``). The core never
imports zenoh; ``node.py`` is the thin Zenoh wrapper.
"""
