"""The nearest-sample search (``geometry.nearest``) against a brute-force search of every point."""

import numpy as np
import pytest
import torch
from threadpoolctl import threadpool_info

from ctp_core.geometry import nearest


def _brute(data: np.ndarray, at: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Every distance, sorted: the k nearest (distance, index), padded with (inf, len(data)) past the points."""
    dist = np.sqrt(((at[:, None, :] - data[None]) ** 2).sum(-1))
    order = np.argsort(dist, axis=1, kind="stable")[:, :k]
    near = np.take_along_axis(dist, order, axis=1)
    pad = k - order.shape[1]
    return (np.pad(near, ((0, 0), (0, pad)), constant_values=np.inf),
            np.pad(order, ((0, 0), (0, pad)), constant_values=len(data)))


@pytest.fixture(scope="module")
def points() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    sphere = rng.normal(size=(3000, 3))
    data = sphere / np.linalg.norm(sphere, axis=1, keepdims=True)  # a surface's samples
    at = np.concatenate([rng.uniform(-1.2, 1.2, (400, 3)), rng.uniform(-30, 30, (100, 3))])  # near and far
    return data, at


@pytest.mark.parametrize("k", [1, 2, 8, 32, 64])  # 64: past ``MANY``, scipy's tree
def test_neighbours_and_distances_are_the_brute_force_searchs(points, k):
    data, at = points
    dist, idx = nearest.Tree(data).query(at, k=k)
    want_dist, want_idx = _brute(data, at, k)
    if k == 1:
        assert dist.shape == idx.shape == (len(at),)
        dist, idx = dist[:, None], idx[:, None]
    assert idx.dtype == np.int64
    assert np.array_equal(idx, want_idx)
    np.testing.assert_allclose(dist, want_dist, rtol=1e-12, atol=1e-12)


def test_a_bound_leaves_farther_neighbours_unfound(points):
    data, at = points
    bound = 0.15
    dist, idx = nearest.Tree(data).query(at, k=2, upper=bound)
    want_dist, want_idx = _brute(data, at, 2)
    near = want_dist < bound
    assert np.array_equal(idx[near], want_idx[near])
    assert np.isinf(dist[~near]).all() and (idx[~near] == len(data)).all()
    assert near.any() and (~near).any()  # both kinds were asked


def test_more_neighbours_than_points_are_padded_as_scipy_pads_them():
    data = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    at = np.array([[0.1, 0.0, 0.0], [0.0, 1.5, 0.0]])
    dist, idx = nearest.Tree(data).query(at, k=5)
    want_dist, want_idx = _brute(data, at, 5)
    assert np.array_equal(idx, want_idx)
    np.testing.assert_allclose(dist, want_dist)


def test_no_query_points_give_empty_answers(points):
    data, _ = points
    dist, idx = nearest.Tree(data).query(np.zeros((0, 3)), k=2)
    assert dist.shape == idx.shape == (0, 2)


def test_a_large_search_runs_on_the_runs_threads_a_small_one_on_one_and_both_answer_alike(points):
    """From ``PARALLEL_QUERY`` points a search runs on torch's count of threads (the run's), below it on one: the
    count pykdtree's own OpenMP runtime is set to before each search. Each query is answered alone, so the answers
    are the same on any number."""
    data, _ = points
    tree = nearest.Tree(data)
    at = np.random.default_rng(4).uniform(-2, 2, (nearest.PARALLEL_QUERY, 3))
    threads = torch.get_num_threads()

    def pykdtree_threads() -> int:
        own = [i for i in threadpool_info() if i["user_api"] == "openmp" and "pykdtree" in i["filepath"]]
        assert own, "pykdtree's wheel bundles its OpenMP runtime"
        return own[0]["num_threads"]

    try:
        torch.set_num_threads(2)
        large = tree.query(at, k=8)
        assert pykdtree_threads() == 2
        small = tree.query(at[:100], k=8)
        assert pykdtree_threads() == 1
        torch.set_num_threads(1)
        one = tree.query(at, k=8)
        assert pykdtree_threads() == 1
    finally:
        torch.set_num_threads(threads)
    assert np.array_equal(large[0], one[0]) and np.array_equal(large[1], one[1])
    assert np.array_equal(small[1], one[1][:100])
