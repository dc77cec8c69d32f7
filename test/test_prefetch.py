"""A bag decoded in a process beside the estimator (``io.prefetch``): the same samples in
the same order, the reader's errors after the samples before them, no process left behind."""

from __future__ import annotations

import multiprocessing
import pickle
from pathlib import Path

import numpy as np
import pytest

from rheo_ros.app.analyze import bag_params, release_jobs
from rheo_ros.config.setup import Setup
from rheo_ros.io.errors import BagError
from rheo_ros.io.prefetch import BATCH, Prefetched

BAG = Path(__file__).resolve().parents[1] / "bags" / "table_I_short"


def counted(n: int, fail_after: bool = False):
    for i in range(n):
        yield i, np.full(3, i, np.float32)
    if fail_after:
        raise BagError(f"bag: /tactile/pressure: message {n} is not a sensor_msgs/msg/Image")


@pytest.mark.parametrize("process", [True, False])
def test_the_items_come_in_order_and_to_the_bit(process):
    n = 2 * BATCH + 17   # batches and a remainder
    with Prefetched(lambda: counted(n), process=process) as items:
        got = list(items)
    assert [i for i, _ in got] == list(range(n))
    assert all(a.dtype == np.float32 and np.array_equal(a, np.full(3, i, np.float32)) for i, a in got)


@pytest.mark.parametrize("process", [True, False])
def test_the_readers_error_comes_after_the_items_before_it(process):
    seen = []
    with pytest.raises(BagError, match=r"^bag: /tactile/pressure: message 1500 is not a sensor_msgs/msg/Image$"):
        with Prefetched(lambda: counted(1500, fail_after=True), process=process) as items:
            for i, _ in items:
                seen.append(i)
    assert seen == list(range(1500))


def test_a_consumer_that_stops_early_ends_the_reader():
    def endless():
        while True:
            yield np.zeros(10_000)   # fills the pipe: the child blocks on it

    with Prefetched(endless) as items:
        for k, _ in enumerate(items):
            if k == 10:
                child = items._child
                assert child is not None and child.is_alive()
                break
    assert not child.is_alive()
    assert child not in multiprocessing.active_children()


def test_release_jobs_decoded_beside_the_estimator_are_the_same_to_the_bit():
    """What the node-equivalent replay makes of a bag (every job's record, profile and
    sensor model) does not depend on where the bag was decoded."""
    setup = Setup(bag_params(BAG))
    here, beside = [], []
    jobs_here = release_jobs(BAG, setup, here, workers=1)
    jobs_beside = release_jobs(BAG, setup, beside, workers=2)
    assert len(jobs_here) == 1
    assert pickle.dumps(jobs_here) == pickle.dumps(jobs_beside)
    assert here == beside
