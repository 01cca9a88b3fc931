"""BLAS thread limits around the fitter's small linear algebra (morphable.threads)."""
import threading

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from morphable.threads import single_blas_thread


def _blas_threads():
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_single_blas_thread_nests_and_restores():
    before = _blas_threads()
    with single_blas_thread():
        assert set(_blas_threads()) == {1}
        with single_blas_thread():
            assert set(_blas_threads()) == {1}
        assert set(_blas_threads()) == {1}      # the outer block still holds the limit
    assert _blas_threads() == before


def test_single_blas_thread_across_threads_restores_once():
    """Python threads share the process' BLAS setting: the limit holds until the last block
    leaves, then the original comes back. (OpenBLAS reports its thread count unreliably from
    non-main threads, so only the main thread's view is checked.)"""
    before = _blas_threads()
    inside = threading.Barrier(4)
    done = []

    @single_blas_thread()
    def work():
        inside.wait(timeout=10)            # all four inside the block at once
        done.append(np.linalg.solve(np.eye(4), np.ones(4)).sum())

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert done == [4.0] * 4
    assert _blas_threads() == before


def test_fit_landmarks_runs_single_threaded(sfm, monkeypatch):
    from morphable.camera import Camera
    from morphable.fitting import landmark_fit

    seen = []
    solve = np.linalg.solve

    def spy(*args):
        seen.append(set(_blas_threads()))
        return solve(*args)

    cam = Camera.looking_at_face(image_size=(256, 256), yaw=10)
    lms = cam.project(sfm.landmark_positions())
    monkeypatch.setattr(landmark_fit.np.linalg, "solve", spy)
    landmark_fit.fit_landmarks(sfm, lms, (256, 256), n_iterations=1)
    assert seen and all(s == {1} for s in seen)


def test_single_torch_thread_nests_and_restores():
    torch = pytest.importorskip("torch")
    from morphable.threads import single_torch_thread

    before = torch.get_num_threads()
    with single_torch_thread():
        assert torch.get_num_threads() == 1
        with single_torch_thread():
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
