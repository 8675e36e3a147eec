"""The identification layer both tools share: recordings (one container, one loader), simulators (env id,
``module:Class``,
``path/rig.py:Class``, MJCF / URDF through MuJoCo), signal preparation and the held-out split, and the measurements
of recordings that fit nothing: the weak-form momentum balance (:mod:`.weakform`) and the non-parametric friction
curve (:mod:`.frictioncurve`), which the mismatch tool's friction laws and the rig path's friction check share.

The world model and the mismatch tool both build on it; it imports neither.
"""
