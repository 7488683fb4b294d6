"""Wall time of ``simulate()`` calls as users make them, in whichever tree Python imports: min and median of 40 calls
after 3 untimed ones, for a 2000-step and a 20-step run of 805 lattices and a 20-step run of 64 (Verlet, N = 201,
dt = 0.1), from a plain x0 and continued on the device (a ``DeviceState`` x0 kept there). The short runs show the
fixed cost of a call: its host work and the state's trips. Flat keywords, so it runs on trees back to e5baf0b.

Command (GPU): ``PYTHONPATH=TREE python benchmarks/simulate_calls.py LABEL [--device cuda]``. Prints one line:
``LABEL BATCHxSTEPS dev|plain MIN/MEDIAN ms; ...``.
"""

from __future__ import annotations

import time

import numpy as np

from simulate_ab import arguments, paper_state  # this folder: python puts it first on the path


def main(argv=None) -> None:
    args = arguments(argv, __doc__)
    wc, params, one = paper_state()
    out = []
    for batch, steps in ((805, 2000), (805, 20), (64, 20)):
        x0 = np.repeat(one[None], batch, axis=0)
        kept = wc.DeviceState.of(x0, device=args.device)
        for label, start, kwargs in (("dev", kept, {"keep_on_device": True}), ("plain", x0, {})):
            for _ in range(3):
                wc.simulate(params, start, steps * 0.1, 0.1, device=args.device, **kwargs)
            walls = []
            for _ in range(40):
                t0 = time.perf_counter()
                run = wc.simulate(params, start, steps * 0.1, 0.1, device=args.device, **kwargs)
                walls.append(time.perf_counter() - t0)
                del run
            out.append(f"{batch}x{steps} {label} {1e3 * min(walls):.3f}/{1e3 * np.median(walls):.3f}")
    print(args.label, "; ".join(out), flush=True)


if __name__ == "__main__":
    main()
