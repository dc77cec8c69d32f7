"""Shared fixtures: the reference bags and their truth, the paper's cases simulated once
per session (deterministic), and a ROS environment per graph on a DDS domain no other
test process holds."""

from __future__ import annotations

import fcntl
import os
import re
import tempfile
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import IO

import numpy as np
import pytest

from rheo_ros.bench.cases import table_i_case, table_iv_case
from rheo_ros.config.setup import Setup
from rheo_ros.experiment import StageProfile, sample_times
from rheo_ros.models.elements import three_element
from rheo_ros.models.response import respond, stage_program
from rheo_ros.record import Record

REPO = Path(__file__).resolve().parents[1]
BAGS = REPO / "bags"
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



def readme_block(language: str, marker: str) -> str:
    """The README's one ``language`` block that holds ``marker`` (its examples are tests)."""
    text = (REPO / "README.md").read_text()
    blocks = re.findall(rf"^( *)```{language}\n(.*?)^\1```", text, flags=re.S | re.M)
    [code] = [textwrap.dedent(body) for _, body in blocks if marker in body]
    return code

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


def analytic_block_record(setup: Setup, truth: dict[str, float], profile: StageProfile) -> Record:
    """The frictionless block in uniform uniaxial stress from the three-element model's
    exact response alone (no FE): the stress is ``Q[s] / H`` with ``s`` the top's sinking,
    each tactile segment reads it times its area; every marker moves by the uniform
    strain field ``u_y = -s y / H``, ``u_x = gamma s (x - W/2) / H`` (lateral strain
    -gamma times the axial, the centre of the bottom held)."""
    mesh, p = setup.mesh, setup.params
    stage_t, force_t, marker_t = (sample_times(profile.t_end, p[f"rates.{k}"]) for k in ("stage", "tactile", "markers"))
    element = three_element(truth["E"], truth["c1"], truth["c2"])
    stress = respond(element, stage_program(profile), force_t).stress / mesh.height        # Pa
    segment_area = np.diff(setup.tactile.segment_edges) * mesh.thickness              # m^2
    axial = respond(element, stage_program(profile), marker_t).strain / mesh.height       # compressive strain
    x, y = mesh.nodes[:, 0] - mesh.width / 2, mesh.nodes[:, 1]
    displacement = np.stack([truth["gamma"] * axial[:, None] * x, -axial[:, None] * y], axis=2)
    return Record(mesh=mesh, stage_t=stage_t, stage_depth=profile.depth_at(stage_t), force_t=force_t,
                  force=np.outer(stress, segment_area), marker_t=marker_t, markers=mesh.nodes[None] + displacement,
                  source="analytic uniaxial block")
