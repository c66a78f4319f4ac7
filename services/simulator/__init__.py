"""The simulator service: procedural or loaded semantic indoor scenes, robot kinematics and a
raycast RGB camera with ground truth, so the whole stack runs on a CPU without hardware.

Pure parts (no I/O): ``shapes`` (watertight primitive meshes), ``scene`` (labelled objects →
open3d raycasting, ground-truth signed distance), ``procedural`` (seeded rooms),
``scenario`` (scenario files and built-in scenarios), ``mesh_io`` (labelled PLY),
``robots`` (kinematics), ``camera`` (pinhole model and renderer), ``world`` (everything
composed and advanced in time). ``node`` is the thin Zenoh wrapper.
"""
