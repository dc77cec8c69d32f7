"""Out-of-catalogue bags of the other laws (seed S, indices): generate, analyse on the
snapshot's code, print what is named."""
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "test"))
from generator import BENCH_OUTSIDE_OTHER, bench_bag

from rheo_ros.app.analyze import analyze
from rheo_ros.io.bag import BagError
from rheo_ros.record import RecordError

seed = int(sys.argv[1]); idx = [int(x) for x in sys.argv[2].split(",")]
for i in idx:
    with tempfile.TemporaryDirectory() as tmp:
        truth = bench_bag(np.random.default_rng((seed, i)), i, Path(tmp) / "bag", 1.0, True, outside=True,
                          kinds=BENCH_OUTSIDE_OTHER)
        o = truth["outside"][0]
        t = time.perf_counter()
        try:
            d = analyze(Path(tmp) / "bag", params_file=truth["params_file"], workers=1).to_json()["diagnosis"]
        except (BagError, RecordError) as exc:   # the bench counts these as refused
            print(f"bag {i}: {o['effect']} size {o['size']:.3g} refused: {str(exc)[-160:]}", flush=True)
            continue
        named = sorted(d["missing_effects"]) if d else []
        outcome = "wrong" if named else ("unexplained" if not d["explained"] else "nothing seen")
        rivals = [(r["effect"], round(r["delta_bic"], 1)) for r in (d.get("remaining") or {}).get("rivals", []) if r["beats"]]
        print(f"bag {i}: {o['effect']} size {o['size']:.3g} params {o['params']} named {named} -> {outcome}, "
              f"{time.perf_counter() - t:.1f} s, rivals beating {rivals}", flush=True)
