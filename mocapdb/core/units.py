"""Length units and up axes of source motion files (what ``--unit`` and ``--up-axis`` accept)."""

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "cmu": 0.0254 / 0.45}  # metres per unit
UP_AXES = ("x", "-x", "y", "-y", "z", "-z")
