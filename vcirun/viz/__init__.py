"""Seeing a run: the geometry a scene is drawn from (drawing.py) and its animation (animate.py:
`Trajectory.animate`, `vcirun animate`). matplotlib only, imported on use."""
