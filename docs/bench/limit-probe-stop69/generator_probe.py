"""Probe (not the bench): single-effect generator bags of one family scaled to a readable
size (size_live) log-uniform in [lo, hi] x the total-force noise, analysed by rheo analyze;
prints size, outcome. usage: limit_probe.py FAMILY LO HI N NOISE_SCALE SEED OUT.json"""
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "test"))   # test/generator.py
import generator as g

from rheo_ros.app.analyze import analyze

family, lo, hi, n, noise_scale, seed, out = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]), int(sys.argv[6]), sys.argv[7]
AMP = {"strain_stiffening": ("stiffening", None), "adhesion": ("adhesion", 0), "sensor_drift": ("drift", 0),
       "relaxation_branch": ("maxwell", None)}

def scaled(fields, c):
    key, idx = AMP[family]
    v = fields[key]
    if family == "strain_stiffening":
        return {key: v * c}
    if family == "relaxation_branch":
        return {key: tuple((E * c, tau) for E, tau in v)}
    if key == "drift":
        return {key: (v[0] * c, *v[1:])}
    return {key: (v[0] * c, *v[1:])}

rows = []
for i in range(n):
    rng = np.random.default_rng((seed, i))
    material, profile, base, sensor, layout, nseed = g._bench_draw(rng, noise_scale, True)
    form, fields, values = g.bench_effect(rng, family, material, profile, layout.height)
    if family == "sensor_drift" and form == "per_segment":
        continue
    target = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    c, size = 1.0, 0.0
    for _ in range(6):
        size = g.bench_sizes(material, g.Effects(**scaled(fields, c)), sensor, nseed, profile, layout)["size_live"]
        if size <= 0:
            c *= 10.0
            continue
        if abs(size / target - 1) < 0.03:
            break
        c *= target / size
    fields = scaled(fields, c)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "bag"
        g.generate(d, material=material, effects=g.Effects(**fields), sensor=sensor, seed=nseed, profile=profile, layout=layout)
        t0 = time.perf_counter()
        try:
            a = analyze(d, params_file=d.with_name("bag.params.yaml"), workers=1)
            named = list(a.missing_effects)
            outcome = "exact" if named == [family] else ("missed" if not named else "extra/wrong")
        except Exception as exc:
            named, outcome = [], f"refused: {type(exc).__name__}"
        dt = time.perf_counter() - t0
    row = {"i": i, "form": form, "sensor": base.name, "size_live": size, "target": target, "scale": c, "named": named, "outcome": outcome, "seconds": dt}
    rows.append(row)
    print(json.dumps(row), flush=True)
json.dump(rows, open(out, "w"), indent=1)
