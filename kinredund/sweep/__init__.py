"""Placement sweeps: where can the cyclic task run? One closed path, given in a part frame, tracked
(Chapter 4) at many part poses, serially or on a Dask cluster.

- :func:`sweep` runs it and returns one :class:`PlacementRecord` per placement, in placement order;
- :func:`grid` lays placements out over position and yaw; :class:`PartPath` carries a path with the part;
- :func:`best` ranks the feasible placements by a criterion (:data:`CRITERIA`);
- ``sweep(..., scene=, clearance=)`` checks each placement's motion against a cell (:mod:`kinredund.sweep.cell`);
- :func:`read_sweep_file` reads a sweep file back (header and records).
"""

from kinredund.sweep.cell import SweepScene, sweep_scene
from kinredund.sweep.evaluate import SweepOptions, evaluate_placement, run_tracker
from kinredund.sweep.placement import PartPath, PlacementError, check_placements, grid, placement_pose
from kinredund.sweep.record import CAUSES, CRITERIA, PlacementRecord, best
from kinredund.sweep.run import SweepJob, run_batch, sweep
from kinredund.sweep.store import read_sweep_file, write_sweep_file

__all__ = [
    "CAUSES", "CRITERIA", "PartPath", "PlacementError", "PlacementRecord", "SweepJob", "SweepOptions", "SweepScene",
    "best", "check_placements", "evaluate_placement", "grid", "placement_pose", "read_sweep_file", "run_batch",
    "run_tracker", "sweep", "sweep_scene", "write_sweep_file",
]
