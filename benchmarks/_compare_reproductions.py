"""Compare the thesis reproductions of two checkouts: joint values, solver labels, counts, verdicts.

Run ``kinredund reproduce X --json DIR/X.json`` for X in 3.2, 4.1, 4.2, 4.3, 6.2, 6.3 in each checkout,
then ``python benchmarks/_compare_reproductions.py BEFORE_DIR AFTER_DIR``. (Not a benchmark:
``make bench`` skips scripts whose name starts with an underscore.)
"""
import json
import sys
from pathlib import Path

import numpy as np

before, after = Path(sys.argv[1]), Path(sys.argv[2])
def arr(d, k):
    v = d.get(k)
    return None if v is None else np.array(v, dtype=float)
for ex in ["3.2", "4.1", "4.2", "4.3", "6.2", "6.3"]:
    a = json.loads((before / f"{ex}.json").read_text()) if (before / f"{ex}.json").exists() else None
    b = json.loads((after / f"{ex}.json").read_text()) if (after / f"{ex}.json").exists() else None
    if a is None or b is None:
        print(ex, "missing", a is None, b is None)
        continue
    out = [ex]
    for k in ("q", "q_spline", "beta"):
        qa, qb = arr(a, k), arr(b, k)
        if qa is not None and qb is not None and qa.shape == qb.shape and qa.size:
            out.append(f"{k} max diff {np.nanmax(np.abs(qa - qb)):.2e}")
        elif qa is not None or qb is not None:
            out.append(f"{k} shapes {None if qa is None else qa.shape} vs {None if qb is None else qb.shape}")
    for k in ("solver", "ok", "lu_steps", "steps", "reason", "clearance_min", "m_indefinite_interval"):
        if k in a or k in b:
            same = a.get(k) == b.get(k)
            if not same and k == "clearance_min":
                same = np.allclose(a.get(k), b.get(k), atol=1e-9)
            diff = f"DIFF: {str(a.get(k))[:80]!r} vs {str(b.get(k))[:80]!r}"
            out.append(f"{k} {'same' if same else diff}")
    print(" | ".join(out))
