"""conftest.py for running scikit-image's own test module of marching_cubes against adaptiso's
(test_adaptiso.py copies both into a temporary folder and runs pytest there).

skimage.measure.marching_cubes is replaced before the test module imports it. Calls with
method="_lorensen" (scikit-image 0.19's private old implementation, removed upstream) still go to
scikit-image's own function: the tests that compare it with the public methods then compare it
with ours. Every other call goes to adaptiso.marching_cubes and is counted, so a run where the
replacement did not take effect fails.
"""
import os

import skimage.measure

import adaptiso

theirs = skimage.measure.marching_cubes
calls = {"adaptiso": 0}


def marching_cubes(volume, level=None, **kwargs):
    if kwargs.get("method") == "_lorensen":
        return theirs(volume, level, **kwargs)
    calls["adaptiso"] += 1
    return adaptiso.marching_cubes(volume, level, **kwargs)


skimage.measure.marching_cubes = marching_cubes


def pytest_sessionfinish(session, exitstatus):
    with open(os.environ["ADAPTISO_SHIM_CALLS"], "w") as f:
        f.write(str(calls["adaptiso"]))
