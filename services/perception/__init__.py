"""The perception service: camera images → ``PerceptionFrame`` (pointmap, pose, confidence,
ADE20K labels) on ``perception/frame``.

Backends behind one interface (``backend``): ``sim`` (simulator ground truth degraded like a
foundation model, with the paper's keyframe fusion run for real), ``mast3r`` (MASt3R-SLAM
adapter, GPU) for geometry, ``efficientvit`` (EfficientViT, local checkpoint) for labels. The
GPU adapters import their frameworks lazily and raise ``MissingBackend`` naming what is missing.
"""
