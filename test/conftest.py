"""Shared fixtures: the paper's cases simulated once per session (deterministic)."""

import pytest

from rheo_ros.bench.cases import table_i_case, table_iv_case


@pytest.fixture(scope="session")
def long_case():
    return table_i_case("long", 200.0)


@pytest.fixture(scope="session")
def short_case():
    return table_i_case("short", 20.0)


@pytest.fixture(scope="session")
def plane_case():
    return table_iv_case()
