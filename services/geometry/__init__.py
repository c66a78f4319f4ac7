"""Geometry shared by every service: one pinhole camera (``camera``), one set of rotations and
rigid transforms (``transforms``, on scipy's ``Rotation``) and one family of closed-form shapes
(``shapes``: ray casting for synthetic pointmaps, exact signed distance for analytic fields).

Import the sub-modules directly; this package imports none of them. All three load without
scipy (``transforms`` imports it only in the functions that call ``Rotation``).
"""
