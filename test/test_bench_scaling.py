"""``rheo bench scaling``'s parts: the stretched record and the memory of a process tree."""

from __future__ import annotations

import sys

import pytest

from rheo_ros.bench.scaling import peak_memory, record_params
from rheo_ros.config.setup import Setup


@pytest.mark.parametrize(("length", "rate"), [(170.0, 50.0), (600.0, 500.0), (3000.0, 50.0)])
def test_the_record_is_stretched_to_the_length_asked_at_the_rate_asked(length, rate):
    setup = Setup(record_params(length, rate))
    assert setup.profile.t_end == pytest.approx(length, rel=0.01)
    assert setup.params["rates.tactile"] == rate and setup.params["rates.stage"] >= rate


def test_the_peak_counts_the_children_a_process_starts():
    """A parent holding 150 MB and a child holding 300 MB at once, for 0.5 s (over the 0.2 s
    sampling): the peak is their sum (within the interpreters' own ~30 MB each)."""
    code = ("import subprocess, sys, time; a = bytearray(150_000_000); a[::4096] = b'x' * len(a[::4096]); "
            "subprocess.run([sys.executable, '-c', \"import time; b = bytearray(300_000_000); "
            "b[::4096] = b'x' * len(b[::4096]); time.sleep(0.5)\"])")
    assert 450e6 < _peak_of(code) < 600e6


def test_pages_a_forked_child_only_reads_are_counted_once():
    """A parent holding 300 MB forks a child that reads them and holds nothing of its own:
    their resident sizes would count the 300 MB twice (~600 MB); the peak is ~300 MB."""
    code = ("import os, time; a = bytearray(300_000_000); a[::4096] = b'x' * len(a[::4096]); pid = os.fork()\n"
            "if pid == 0:\n    s = sum(a[::4096]); time.sleep(0.6); os._exit(0)\n"
            "os.waitpid(pid, 0)")
    assert 290e6 < _peak_of(code) < 400e6


def _peak_of(code: str) -> float:
    """``peak_memory`` of a Python child running ``code`` (which holds its memory 0.5 s or more)."""
    wall, peak, rc = peak_memory([sys.executable, "-c", code])
    assert rc == 0 and wall > 0.5
    return peak
