"""The engine behind ``simulate``, ``propagate_tangent`` and the ``Flow``: devices, host memory, launch plans,
the runner, the kernels, and the one object that holds every policy number (``tuning.Tuning``).

Modules:

- ``tuning``: ``Tuning`` (frozen) and ``override`` for tests and benchmarks.
- ``devices``: Warp's import and initialisation, device names and locks, CPU threads.
- ``hostmem``: pinned staging buffers, threaded host copies, the state moved in lattice slices
  (``_SlicedTransfers``), recorded frames on their way to the host.
- ``plans``: what one layout launches, and the rules choosing a kernel variant.
- ``runner``: device buffers of one batch, launches replayed as CUDA graphs or kept commands, the guard.
- ``site``: what every layout computes at one site, written once (the contact law, the neighbour rules of the
  chain and of a neighbour table, the force and its tangent, the damped kick, the energy, the observables'
  per-site tests) and the structs the kernels read.
- the step loops, one per layout, each serving base runs and tangent columns (compile-time flags: tangent,
  record, save, damped, observed): ``thread_kernels`` (a thread per lattice: the CPU path), ``block_kernels`` (a
  thread block per lattice, a thread per site) and ``site_kernels`` (the ``"sites"`` layout: a thread per site and a
  launch per force evaluation, for lattices longer than a block, and for neighbour tables); beside them
  ``site_group_kernels`` (a thread per run of sites), the chain's fast path for many short lattices on a GPU
  (``plans.site_group_launch`` says where it pays).
  ``warpchain.reference`` is their numpy oracle. Kernels take their arguments as a few
  structs passed whole: the lattices (``site.Lattice``: M, 1/M, K, losses, boundary), the method
  (``block_kernels.Scheme``: a splitting method's coefficients times dt), what a run records
  (``site.Recording``) and, compiled ``observed``, the observables of ``warpchain.observe``
  (``site.Observer``; hooks in the same step loop of the thread and block layouts, launched by
  ``simulate(..., observe=...)``).

How the state moves (measured on an H100, ``benchmarks/results/h100-2026-11-25/engine-split.json``): through pinned
staging buffers (``hostmem``), in lattice slices overlapped with the first and last chunk for large batches,
or not at all when the caller keeps it on the device (``DeviceState``, ``Placement(keep_on_device=True)``).

The engine steps the splitting methods only (``devices.engine_method``); the classical RK4 runs on the numpy
reference (``warpchain.reference``, ``ReferenceFlow``): a splitting method is as cheap or cheaper at every accuracy (the
work-precision scene) and RK4 alone needed step loops of its own in two layouts.

Adding a splitting method (a new family of coefficients), in 2 files:

1. ``warpchain/integrators.py``: a ``SplittingMethod`` with its drift and kick coefficients (data, at most
   ``block_kernels.MAX_STAGES`` stages) and its order, in ``METHODS``. Every kernel (thread, block, site
   group, tangent, observe) and the numpy reference take the coefficients as they are; stage counts compile
   on first use.
2. ``tests/test_integrators.py``: its order against DOP853 and its bits against the reference (the
   parametrised tests over ``METHODS`` pick it up; add the expected order where they list orders).

Adding a boundary that changes the wall values (like fixed or free ends), in 3 edit sites of 2 files:

1. ``warpchain/model.py``: its name in ``BOUNDARIES`` (its code follows from the order) and its walls in
   ``walls``; the Laplacian and the energy's wall bonds (``wall_bonds``: ``energy``, ``site_energies``) follow
   from them on the host (the numpy reference, observe's oracle).
2. ``warpchain/engine/site.py``: its walls in ``wall_values`` (its code: ``BOUNDARY_CODES[name]``,
   or a ``BOUNDARY_...`` constant made from it as the others are), which every layout reads (thread and sites
   layouts through ``neighbours_at``, the block kernels through ``block_kernels.neighbour_or_wall``, the
   site-group kernels in ``neighbour_values``) and from which the kernels' energies take their wall bonds
   (``site_energy``: the guard, the observables).

A boundary that wraps like the ring also needs the neighbour indices of ``block_kernels.site_neighbours``, the
ends the site-group kernels publish (``ends``) and its bond counted once (``wall_bonds``, ``site_energy``).
The tests over ``BOUNDARIES`` (``tests/test_gpu_engine.py``, ``tests/test_integrators.py``,
``tests/test_site_kernels.py``, ``tests/test_model.py``) check every layout against the reference bit for bit.

A 2-D lattice (the monolayer) is a new neighbour rule, not a new engine: a ``warpchain.lattice.LatticeParams``
carries its neighbour table and bond weights in the ``Lattice`` struct every kernel already takes
(``Lattice.degree`` > 0), and ``site_kernels.evaluate`` reads a site's neighbours from it
(``site.table_laplacian``) where the chain's read ``neighbours_at``; the launch sequence, the kicks and
drifts, the tangent lanes and the guard (``table_bonds``) stay. Only the sites layout takes a table
(``devices.resolve_layout(table=True)``); the thread, block and site-group kernels keep the chain's neighbours.
"""
