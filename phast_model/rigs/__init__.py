"""The rigs layer both tools share: recordings (one container, one loader), simulators (env id, ``module:Class``,
``path/rig.py:Class``, MJCF / URDF through MuJoCo), signal preparation and the held-out split.

The world model and the mismatch tool both build on it; it imports neither.
"""
