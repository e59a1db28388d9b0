"""A switch of the active set inside a step the step control rejects for the watch (issue 27).

The watch predicts a fold or a singularity for the current active set; where a row is reached inside that step,
the active set changes there and the prediction may be the old set's only. Named case: test_tracking_clearance's
``panda_elbow_sphere`` (its elbow reaches the sphere once on a loop), with a watch that predicts a fold for the set
without the row in the step that holds the reach (what the corner run of test_tracking_corners meets: the right
finger's vertex row crosses zero inside steps the fold prediction rejects). Before the switch was searched inside
rejected steps the run stopped there (``fold``); now the reach is located and the run is the one without the
fake prediction: its switching time to the switch search's 1e-9 s, its record to the corrector's ~1e-10 rad.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_tracking_clearance import CASES, case, sphere

from kinredund.tracking import step_control, track
from kinredund.tracking.watch import Watch


def _reaches(tr) -> list[float]:
    return [w["t"] for w in tr.meta["switches"] if w.get("constraint") and w["kind"] == "reach"]


@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
def test_a_row_reached_inside_a_step_rejected_for_a_fold_is_located_first(monkeypatch, scheme):
    monkeypatch.setenv("KINREDUND_BACKEND", "python")  # the prediction below is the Python watch's
    r, path, index, q0 = case(CASES["panda_elbow_sphere"][0])
    c = sphere("panda_elbow_sphere")
    steps = 100
    ref = track(r, path, index, q0, loops=1, steps_per_loop=steps, scheme=scheme, constraints=[c])
    t_s = _reaches(ref)[0]
    dt = path.period / steps

    class FoldWithoutTheRow(Watch):
        """Predicts a fold by any time in (t_s, t_s + dt] while no row is held (the set the row's reach ends)."""

        def ahead(self, t_next):
            if t_s < t_next <= t_s + dt and not self.stepper.rows:
                return "fold"
            return super().ahead(t_next)

    init = step_control.StepControl.__init__

    def with_stepper(self, stepper):
        init(self, stepper)
        watch = FoldWithoutTheRow()
        watch.__dict__.update(self.watch.__dict__)
        watch.stepper, self.watch = stepper, watch

    monkeypatch.setattr(step_control.StepControl, "__init__", with_stepper)
    tr = track(r, path, index, q0, loops=1, steps_per_loop=steps, scheme=scheme, constraints=[c])
    assert abs(_reaches(tr)[0] - t_s) <= 1e-9
    assert len(tr.meta["switches"]) == len(ref.meta["switches"])
    assert np.abs(np.asarray(tr.q) - np.asarray(ref.q)).max() <= 1e-9
    assert min(c.values(q)[0] for q in tr.q) >= -1e-9
