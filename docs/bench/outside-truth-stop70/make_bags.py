import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, "/work/main/test")
from generator import bench_bag
for spec in sys.argv[1:]:
    seed, i = map(int, spec.split(":"))
    out = Path(f"/tmp/outside-truth/out{seed}_{i}")
    if out.exists(): continue
    row = bench_bag(np.random.default_rng((seed, i)), i, out, 1.0, True, outside=True)
    print(spec, row["outside"], row["info"].get("sensor"))
