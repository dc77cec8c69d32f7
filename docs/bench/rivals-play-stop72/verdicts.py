"""Re-analyse bench bags (generator, seed S, indices) on the snapshot's code; print named set
and outcome beside a stored bench JSON's."""
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "test"))
from generator import bench_bag

from rheo_ros.app.analyze import analyze

stored = {b["index"]: b for b in json.load(open(sys.argv[1]))["bags"]}
seed = int(sys.argv[2]); idx = [int(x) for x in sys.argv[3].split(",")] if len(sys.argv) > 3 else sorted(stored)
same = 0
for i in idx:
    with tempfile.TemporaryDirectory() as tmp:
        truth = bench_bag(np.random.default_rng((seed, i)), i, Path(tmp) / "bag", 1.0, True)
        t = time.perf_counter()
        d = analyze(Path(tmp) / "bag", params_file=truth["params_file"], workers=1).to_json()["diagnosis"]
        named = sorted(d["missing_effects"]) if d else []
        old = sorted(stored[i]["named"])
        ok = named == old and d["explained"] == stored[i]["explained"]
        same += ok
        rivals = [(r["effect"], round(r["delta_bic"], 1)) for r in (d.get("remaining") or {}).get("rivals", [])] if d.get("remaining") else []
        print(f"bag {i}: named {named} explained {d['explained']} | stored {old} {stored[i]['explained']} "
              f"{'same' if ok else 'CHANGED'} {time.perf_counter() - t:.1f} s {rivals}", flush=True)
print(f"{same}/{len(idx)} the same")
