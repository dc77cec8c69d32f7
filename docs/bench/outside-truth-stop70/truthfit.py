"""Each wrong-named out-of-catalogue bag: the named catalogue model against the truth's
effect (the tests' plugins), both fitted over the whole record; BIC and force RMS / noise."""
import json, sys
sys.path.insert(0, "/work/main/test"); sys.path.insert(0, "/work/main")
from conftest import readme_block
import test_unexplained as tu
from rheo_ros.models.effects import register_effect, catalogue
from rheo_ros.app.analyze import analyze
ns = {}
exec(readme_block("python", "class SensorLag"), ns)
ns2 = {}
exec(tu.DAMAGE, ns2)
if "damage" not in catalogue():
    register_effect(ns2["Damage"])
print(sorted(catalogue()))
spec, named, truth = sys.argv[1], sys.argv[2].split("+"), sys.argv[3]
seed, i = spec.split(":")
bag = f"/tmp/outside-truth/out{seed}_{i}"
pf = bag + ".params.yaml"
out = {}
for label, effects in (("named", named), ("truth", [truth])):
    a = analyze(bag, effects=effects, params_file=pf, discover_effects=False, workers=1)
    j = a.to_json()
    m = j["models"][-1]
    out[label] = {"model": m.get("name") or m.get("model"), "bic": m["bic"], "params": {k: float(f"{v:.4g}") for k, v in m["params"].items()}}
print(spec, json.dumps(out))
print(spec, "BIC truth - named:", round(out["truth"]["bic"] - out["named"]["bic"], 1))
