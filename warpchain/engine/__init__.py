"""The engine behind ``simulate``, ``propagate_tangent`` and the ``Flow``: devices, host memory, launch plans,
the runner, the kernels, and the one object that holds every policy number (``tuning.Tuning``).

Modules:

- ``tuning``: ``Tuning`` (frozen) and ``override`` for tests and benchmarks.
- ``devices``: Warp's import and initialisation, device names and locks, CPU threads.
- ``hostmem``: pinned staging buffers, threaded host copies, recorded frames on their way to the host.
- ``plans``: what one (layout, method type) launches, and the rules choosing a kernel variant.
- ``runner``: device buffers of one batch, launches replayed as CUDA graphs or kept commands, the guard.
- ``thread_kernels`` (a thread per lattice: the CPU path), ``block_kernels`` (a thread block per lattice, a
  thread per site) and ``site_group_kernels`` (a thread per run of sites: the GPU path for large batches)
  hold the kernels; ``warpchain.reference`` is their numpy oracle.
"""
