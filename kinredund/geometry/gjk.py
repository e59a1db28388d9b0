"""GJK's settings for every exact distance of the geometry layer (:mod:`kinredund.geometry.engine`): its stopping
tolerance, and one start for every query, so that a distance is a function of the configuration alone."""

from __future__ import annotations

import coal
import numpy as np

#: GJK's stopping tolerance (coal's default is 1e-6): separated distances to ~1e-9 m, at no measurable cost on
#: the Panda's hulls, so that the rates can be checked by central differences
GJK_TOLERANCE = 1e-9


def no_warm_start(requests) -> None:
    """GJK from its default guess at every call, never from the previous call's result (for each of ``requests``,
    under one filter of the warning: a Scene's workspace sets a request per pair).

    With coal 3.0.3's warm start (the default), the distance between a hull and a box came out alternately
    0.0819774 and 0.0820143 m on consecutive calls at configurations 5e-5 rad apart (GJK stopping early from
    the cached support vertices), which ruins the rates' central differences; from the default guess it is
    the same, smallest value every time, at no measurable cost. coal marks ``enable_cached_gjk_guess`` as
    deprecated, but ``gjk_initial_guess = DefaultGuess`` alone does not stop the support-function cache.

    One cache stays: each pair's GJK solver (pinocchio's distance functor) starts its support-vertex search from
    where its last call ended (coal 3.0.3, ``narrowphase.h``) unless the request asks for a cached guess: a distance
    then differed with the queries the same workspace made before, within GJK's stopping tolerance (so that a change
    which only added queries could move a tracking run's numbers; ``tests/test_geometry_core.py``). So the
    requests ask for a cached guess, and :func:`fresh_starts` gives them the same one, GJK's default direction and
    support hint 0, before each query (coal writes the query's own back): a distance is a function of q alone. The
    compiled query does the same (``fresh_distance``, src/core/distances.cpp).
    """
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        for request in requests:
            request.gjk_initial_guess = coal.GJKInitialGuess.CachedGuess
            request.enable_cached_gjk_guess = False
    fresh_starts(requests, range(len(requests)))


#: GJK's default first direction and the support hint of a fresh start (:func:`fresh_starts`)
_FIRST_DIRECTION, _FIRST_HINT = np.array([1.0, 0.0, 0.0]), np.zeros(2, dtype=np.int32)


def fresh_starts(requests, ks) -> None:
    """Pairs ``ks``' requests given the same start before a query (:func:`no_warm_start`): GJK's default direction and
    support hint 0 as their cached guess."""
    for k in ks:
        request = requests[k]
        request.cached_gjk_guess = _FIRST_DIRECTION
        request.cached_support_func_guess = _FIRST_HINT
