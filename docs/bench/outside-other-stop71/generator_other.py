"""test/generator.py's bench protocol with the effects in no catalogue drawn from
BENCH_OUTSIDE_OTHER: laws of the rivals' kinds that are not the rivals' own (a second-order
sensor lag, an exponential damage) and a sensor's play, which no rival has.

rheo bench diagnosis --generator docs/bench/outside-other-stop71/generator_other.py --outside --quick
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "test"))
import generator  # noqa: E402

GENERATOR_ID = generator.GENERATOR_ID + " (effects in no catalogue by other laws)"


def bench_bag(rng, index, out_dir, noise_scale=1.0, quick=False, outside=False, limit=None):
    return generator.bench_bag(rng, index, out_dir, noise_scale, quick, outside, limit,
                               kinds=generator.BENCH_OUTSIDE_OTHER)
