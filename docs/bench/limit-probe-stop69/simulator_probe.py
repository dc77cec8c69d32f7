"""Probe (not the bench): single-effect simulator bags of strain_stiffening (a form drawn as
the bench draws it) scaled to a readable size (size_live) log-uniform in [lo, hi];
usage: limit_probe_sim.py LO HI N NOISE_SCALE SEED OUT.json"""
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rheo_ros.app.analyze import analyze
from rheo_ros.bench.diagnosis import draw_effect, draw_params, effect_size, simulator_forms
from rheo_ros.config.setup import Setup, check_params
from rheo_ros.io.bag import write_run
from rheo_ros.rig.simulator import simulate_run

lo, hi, n, noise_scale, seed, out = float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5]), sys.argv[6]
family = "strain_stiffening"
rows = []
for i in range(n):
    rng = np.random.default_rng((seed, i))
    params = draw_params(rng, noise_scale, True)
    form = str(rng.choice(simulator_forms(family)))
    values = draw_effect(rng, family, form, params["material.E"], params["stage.keep_time"])
    nseed = int(rng.integers(0, 2**31 - 1))
    target = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    c = 1.0
    for _ in range(6):
        p = params | {f"effects.{family}.form": form, f"effects.{family}.coefficient": values["coefficient"] * c,
                      "simulator.effects": [family]}
        setup = Setup(check_params(p, f"bag {i}"))
        run = simulate_run(setup, nseed)
        size = effect_size(setup, run.tactile_t, run.marker_t)["size_live"]
        if abs(size / target - 1) < 0.03:
            break
        c *= target / size if size > 0 else 10.0
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "bag"
        write_run(run, {**setup.params, "simulator.seed": nseed}, d)
        t0 = time.perf_counter()
        try:
            a = analyze(d, workers=1)
            named = list(a.missing_effects)
            outcome = "exact" if named == [family] else ("missed" if not named else "extra/wrong")
        except Exception as exc:
            named, outcome = [], f"refused: {type(exc).__name__}: {exc}"
        dt = time.perf_counter() - t0
    row = {"i": i, "form": form, "size_live": size, "target": target, "coefficient": values["coefficient"] * c, "named": named, "outcome": outcome, "seconds": dt}
    rows.append(row)
    print(json.dumps(row), flush=True)
json.dump(rows, open(out, "w"), indent=1)
