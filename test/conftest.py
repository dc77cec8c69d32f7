"""Shared fixtures: the reference bags and their truth, the paper's cases simulated once
per session (deterministic), and a ROS environment per graph on a DDS domain no other
test process holds."""

from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO

import pytest

from rheo_ros.bench.cases import table_i_case, table_iv_case

BAGS = Path(__file__).resolve().parents[1] / "bags"
# The simulated clay of the reference bags (the paper's Table IV).
TRUTH = {"E": 3.33e4, "c1": 1.69e5, "c2": 3.11e7, "gamma": 0.332}

# Fast DDS maps a domain to ports: 0-232 are valid. Tests take theirs below 100, clear of
# the demo's 100-199 and the online bench's 180-219.
DOMAINS = range(1, 100)
_held: list[IO[str]] = []


def reserve_domain() -> int:
    """A DDS domain for one ROS graph, held (an exclusive lock on a file per domain) until
    this process ends: concurrent test processes, and graphs within one, never share one."""
    folder = Path(tempfile.gettempdir()) / "rheo_ros-dds-domains"
    folder.mkdir(exist_ok=True)
    for domain in DOMAINS:
        handle = (folder / str(domain)).open("w")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            continue
        _held.append(handle)
        return domain
    raise RuntimeError(f"every DDS domain in {DOMAINS} is held by a running test process")


@pytest.fixture(scope="session")
def ros_env() -> Callable[[], dict[str, str]]:
    """Gives the environment of a new ROS graph: its own domain, localhost only."""
    def make() -> dict[str, str]:
        return dict(os.environ, ROS_DOMAIN_ID=str(reserve_domain()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return make


@pytest.fixture(scope="session")
def long_case():
    return table_i_case("long", 200.0)


@pytest.fixture(scope="session")
def short_case():
    return table_i_case("short", 20.0)


@pytest.fixture(scope="session")
def plane_case():
    return table_iv_case()
