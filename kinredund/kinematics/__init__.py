"""Kinematics (Chapters 2, 4 and 5): Hartenberg-Denavit tables, the one Pinocchio layer (:mod:`.state`),
the closure equations and rotation invariants (:mod:`.closure`), the recursive K of Chapter 5
(:mod:`.recursive`, :mod:`.opcount`), joint-angle utilities (:mod:`.angles`) and the shared
finite-difference helper. Nothing here knows of robots, tasks or solvers."""
