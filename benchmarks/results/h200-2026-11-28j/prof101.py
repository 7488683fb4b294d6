import cProfile
import io
import json
import pstats
import sys
import time
import continuation as ct
from warpchain.lattice import LatticeParams, square, triangular

n = int(sys.argv[1])
build = {"square": square, "triangular": triangular}[sys.argv[2]]
p = LatticeParams(30.0, 1.0, build(n, n, "fixed"))
omega = 1.014
t = time.perf_counter()
b = ct.require(ct.find_breather(p, omega, ct.anticontinuum_seed(p, omega), device="cuda"))
print("newton", round(time.perf_counter() - t, 2), flush=True)
t = time.perf_counter()
fl = ct.floquet(b, solver="probed")
print(
    "first floquet",
    round(time.perf_counter() - t, 2),
    fl.complete,
    fl.stable,
    fl.max_modulus,
    json.dumps(fl.stats["seconds"]),
    flush=True,
)
if len(sys.argv) > 3:
    pr = cProfile.Profile()
    pr.enable()
    t = time.perf_counter()
    fl = ct.floquet(b, solver="probed")
    pr.disable()
    print("second floquet", round(time.perf_counter() - t, 2), json.dumps(fl.stats["seconds"]), flush=True)
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats("cumulative").print_stats(40)
    print(s.getvalue()[:9000])
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(25)
    print(s.getvalue()[:6000])
