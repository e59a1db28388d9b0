"""Robot models (Chapter 2): the thesis's robots, URDF in and out, :class:`~kinredund.model.robot.Robot`
and the loader."""
