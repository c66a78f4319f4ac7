"""The mapping service: pointmaps → confidence-weighted semantic TSDF → semantic occupancy →
semantically inflated signed ESDF (the paper's "Semantic Map and ESDF Construction",
Algorithm 1), in the manner of nvblox: a rolling volume, layers, one integrator per
transformation and a ``Mapper`` composing them. The core never imports zenoh; ``node.py``
is the thin Zenoh wrapper.
"""
