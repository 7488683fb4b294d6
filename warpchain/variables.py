"""Long names and units of every array the stores hold: what ``store``, the branch store and the sweep store
write beside each array (CF ``long_name`` and ``units``; ``flag_values`` and ``flag_meanings`` for integer
codes), so that any zarr or xarray reader sees what a number is.

The model is dimensionless (``model``: displacements in units of the static contact overlap, time in units of
sqrt(m2/k2), frequencies in units of sqrt(k2/m2), energies in the model's units): its quantities, counts and
indices have units "1" (CF's dimensionless); wall-clock times "s"; the dispersion scene's ``physical_curves``
SI ("m-1", "rad s-1"). Sites are numbered from 0 everywhere (the centre of N sites is N // 2).

A name means one thing (``VARIABLES``) unless a group gives it another (``BY_GROUP``, keyed by the group's last
path component). The branch store's fixed arrays must be here (``describe`` raises); tables, fields and sweeps
written through the public writers (``store.write_table``, ``store.FieldWriter``, ``sweep``) may hold a user's own
names, which get no entry; every array of every scene's store has one (``tests/test_cli.py`` reads the paper's
stores and checks every variable).
"""

from __future__ import annotations

VARIABLES = {
    # ------------------------------------------------------------------ coordinates and chain parameters
    "t": ("time, in units of sqrt(m2/k2)", "1"),
    "site": ("site index j (0-based; the centre is N // 2)", "1"),
    "point": ("point index along the continuation branch", "1"),
    "K": ("coupling ratio k1/k2", "1"),
    "N": ("number of sites (unit cells) of the chain", "1"),
    "A": (
        "amplitude of the initial Gaussian impulse (substrate velocity by default; see group attrs parameters.impulse)",
        "1",
    ),
    "W": ("width of the initial Gaussian impulse in sites", "1"),
    "damping": ("damping case index (rates (gamma_c, gamma_s) in group attribute damping_rates)", "1"),
    "realisation": ("noise realisation index r (seed rule in group attribute seed_rule)", "1"),
    "frame": ("frame index, one frame per breather period 2 pi / w_b (frame 0: initial state)", "1"),
    "peak": ("slot index of an envelope peak at the end of the run (peaks in site order)", "1"),
    "kind": ("instability kind index into continuation.floquet.KINDS (labels also in group attribute kinds)", "1"),
    "q": ("Bloch wavenumber q (phase per unit cell) in [0, pi]", "1"),
    "period": ("number of breather periods elapsed", "1"),
    # ------------------------------------------------------------------ fields and profiles
    "u": ("chain (substrate) mass displacement u_j", "1"),
    "v": ("resonator displacement v_j", "1"),
    "z": ("relative displacement z = u - v (contact overlap minus 1)", "1"),
    "state": ("breather orbit start at t = 0, components (u, v, u', v') per site", "1"),
    "u_general": ("breather u_j at t = 0 from the general shooting formulation (x(T) - x0 plus phase condition)", "1"),
    "v_general": ("breather v_j at t = 0 from the general shooting formulation (x(T) - x0 plus phase condition)", "1"),
    "u_numerical": ("numerical (Newton) breather u_j at t = 0", "1"),
    "v_numerical": ("numerical (Newton) breather v_j at t = 0", "1"),
    "u_nls": ("second-order NLS approximation of the breather u_j at t = 0", "1"),
    "v_nls": ("second-order NLS approximation of the breather v_j at t = 0", "1"),
    "u_nls_first_order": ("first-order NLS approximation of the breather u_j at t = 0", "1"),
    "v_nls_first_order": ("first-order NLS approximation of the breather v_j at t = 0", "1"),
    # ------------------------------------------------------------------ breather scalars (branch / sweep / tables)
    "omega": ("breather frequency w_b", "1"),
    "energy": ("breather energy (Hamiltonian H)", "1"),
    "min_contact": ("minimum over the orbit and sites of the contact overlap 1 + u - v (<= 0: contact lost)", "1"),
    "s": ("continuation coordinate (log10 K or weighted arclength: group attribute coordinate)", "1"),
    "iterations": ("Newton iterations of the corrector", "1"),
    "newton_residuals": ("Newton residual norm at each iteration of the corrector (NaN padded)", "1"),
    "residual": ("Newton residual norm at each iterate, seed first (2-norm of the velocities at T/2)", "1"),
    "checksum": (
        "CRC-32 of each array's row (order: group attribute checksum_arrays, or array attribute variables)",
        "1",
    ),
    # ------------------------------------------------------------------ Floquet analysis
    "max_modulus": ("largest nontrivial Floquet multiplier modulus |l|", "1"),
    "max_modulus_minus_1": ("largest nontrivial Floquet multiplier modulus |l| minus 1", "1"),
    "tolerance": ("stability tolerance in mu: stable iff every nontrivial mu lies within it of [-1, 1]", "1"),
    "stable": ("linear stability verdict of the breather (1 stable, 0 unstable)", "1"),
    "floquet_complete": ("every Floquet multiplier accounted for (1) or not (0)", "1"),
    "verdict_complete": ("Floquet verdict complete: every multiplier accounted for (1) or not (0)", "1"),
    "mu_real": ("real part of the reduced Floquet eigenvalue mu = (l + 1/l)/2", "1"),
    "mu_imag": ("imaginary part of the reduced Floquet eigenvalue mu = (l + 1/l)/2", "1"),
    "signature": ("Krein signature of each mu (+1/-1 for elliptic mu, 0 otherwise and for the trivial mu)", "1"),
    "parity": ("mirror parity of the Floquet vector (+1 even, -1 odd, 0 unknown or mixed)", "1"),
    "participation": ("participation ratio in sites of the Floquet vector (site weight M|a_u|^2 + |a_v|^2)", "1"),
    "central_weight": (
        "fraction of the Floquet vector's site weight on the 5 sites nearest the orbit's energy centre",
        "1",
    ),
    "instability_kind": ("kind of each unstable multiplier group (index into KINDS), largest first", "1"),
    "instability_mu_real": ("real part of mu = (l + 1/l)/2 of each unstable multiplier group", "1"),
    "instability_mu_imag": ("imaginary part of mu = (l + 1/l)/2 of each unstable multiplier group", "1"),
    "instability_participation": ("participation ratio in sites of each unstable group's Floquet vector", "1"),
    "instability_central_weight": (
        "fraction of each unstable group's Floquet vector weight on the 5 central sites",
        "1",
    ),
    "instability_localized": ("unstable group's Floquet vector localized (participation < 0.1 N) or extended", "1"),
    "instability_parity": ("mirror parity of each unstable group's Floquet vector", "1"),
    "instability_count": ("number of unstable multiplier groups of the point (rows beyond 16 are cut)", "1"),
    "modulus": ("modulus |l| >= 1 of the outer Floquet multiplier of the instability", "1"),
    "localized": ("instability's Floquet vector localized (participation < 0.1 N) or extended", "1"),
    "weight": ("normalised site weight (M|a_u|^2 + |a_v|^2) of the instability's Floquet vector per site", "1"),
    "real": ("real part of the Floquet multiplier l", "1"),
    "imag": ("imaginary part of the Floquet multiplier l", "1"),
    "trivial": ("Floquet multiplier belongs to the trivial pair at l = 1", "1"),
    # ------------------------------------------------------------------ stability atlas (sweep over K)
    "arclength": ("continuation coordinate: weighted arclength (theta = 1 / gap width)", "1"),
    "foam_fraction": (
        "predicted unstable fraction of the foam (unresolved bubbles) in the step to the next point; NaN: none",
        "1",
    ),
    "instabilities": ("number of unstable multiplier groups of each kind", "1"),
    "leading_kind": ("kind of the leading instability (index into KINDS; -1 no instability or no point)", "1"),
    "leading_localized": ("leading instability's Floquet vector localized (1) or extended (0); -1 none", "1"),
    "end_reason": ("why the branch stopped (index into array attribute reasons)", "1"),
    "points": ("number of points of the branch", "1"),
    "contact_points": ("number of points before the first without contact (the physical branch)", "1"),
    "contact_loss_omega": ("breather frequency w_b where contact is lost (interpolated)", "1"),
    "stability_changes": ("number of located stability changes on the branch", "1"),
    "foam_stretches": ("number of stretches of unresolved instability bubbles (foam) on the branch", "1"),
    "eigenmode_amplitude": (
        "amplitude max |u - v| of the branch's first point (started from the lowest optical eigenmode)",
        "1",
    ),
    "solves": ("number of Newton solves of the branch walk", "1"),
    "seconds": ("wall-clock time", "s"),
    "completed": ("task's region of every variable written (1) or not (0)", "1"),
    # ------------------------------------------------------------------ breakup statistics (observables)
    "peaks": ("number of localized peaks of the frame interval's |z| envelope above threshold", "1"),
    "spot_energy": ("energy of the sites within W of the centre, |j - N//2| <= W", "1"),
    "max_envelope": ("maximum over sites of the frame interval's |z| envelope", "1"),
    "dissipated": ("energy lost to damping since t = 0", "1"),
    "peak_position": ("position of a final envelope peak, in sites (0-based, parabola-refined)", "1"),
    "peak_amplitude": ("|z| envelope value at a final envelope peak", "1"),
    "peak_velocity": ("drift velocity of a final envelope peak, sites per unit time (NaN: unmatched)", "1"),
    "contact_loss_time": (
        "time of the first frame whose interval lost contact (NaN: never), in units of sqrt(m2/k2)",
        "1",
    ),
    # ------------------------------------------------------------------ anticontinuum
    "z_max": ("upper turning point z_max of the single-site (K = 0) oscillator orbit", "1"),
    "lindstedt": ("Lindstedt approximation of the single-site frequency, w0 (1 - z_max^2 / 24)", "1"),
    # ------------------------------------------------------------------ breather scene checks
    "relative_deviation": ("max |x(nT) - x(0)| over u, v and sites, relative to max |x(0)| (direct simulation)", "1"),
    "case": ("case index (labels in group attribute case_names)", "1"),
    "finite_difference": ("row is a finite-difference Jacobian (1) or the tangent Jacobian (0)", "1"),
    "h": ("finite-difference step h (NaN for the tangent row)", "1"),
    "relative_difference": ("max |J_fd - J_tangent| / max |J_tangent| of the half-period Jacobian", "1"),
    # ------------------------------------------------------------------ dispersion
    "acoustic": ("acoustic branch frequency w(q) of the infinite chain", "1"),
    "optical": ("optical branch frequency w(q) of the infinite chain", "1"),
    "acoustic_long_wave": ("long-wave (continuum) limit of the acoustic branch, 2K(1 - cos q) -> K q^2", "1"),
    "optical_long_wave": ("long-wave (continuum) limit of the optical branch, 2K(1 - cos q) -> K q^2", "1"),
    "frequency": ("linear mode frequency of the finite fixed-end chain (2N modes, ascending)", "1"),
    "k": ("wavenumber", "m-1"),
    "continuous_lower": (
        "angular frequency, lower branch of the continuous surface-wave model (Rayleigh waves, sphere resonators)",
        "rad s-1",
    ),
    "continuous_upper": (
        "angular frequency of the upper branch of the continuous surface-wave model (NaN above the c_T line)",
        "rad s-1",
    ),
    "discrete_acoustic": (
        "angular frequency of the chain's acoustic branch with the fitted M, K (q = k d, scaled by the fitted omega0)",
        "rad s-1",
    ),
    "discrete_optical": (
        "angular frequency of the chain's optical branch with the fitted M, K (q = k d, scaled by the fitted omega0)",
        "rad s-1",
    ),
    "paper_acoustic": (
        "angular frequency of the chain's acoustic branch at the paper's M = 30, K = 160 (times the fitted omega0)",
        "rad s-1",
    ),
    "paper_optical": (
        "angular frequency of the chain's optical branch at the paper's M = 30, K = 160 (times the fitted omega0)",
        "rad s-1",
    ),
    # ------------------------------------------------------------------ finite size
    "tail_amplitude": ("max |u - v| at t = 0 further than tail_distance sites from the centre", "1"),
    "outer_amplitude": ("max |u - v| at t = 0 over the outer quarter of the chain on each side", "1"),
    "extended_max_modulus": ("largest |l| among the extended (finite-size) instabilities (1 if none)", "1"),
    "localized_max_modulus": ("largest |l| among the localized instabilities (1 if none)", "1"),
    "extended_instabilities": ("number of extended (finite-size) unstable multiplier groups", "1"),
    "localized_instabilities": ("number of localized unstable multiplier groups", "1"),
    "newton_seconds": ("wall-clock time of the Newton solve", "s"),
    # ------------------------------------------------------------------ NLS
    "delta": ("distance below the optical band bottom, w0 - w_b", "1"),
    "relative_profile_difference": (
        "max |x_NLS - x_numerical| over u, v relative to the numerical breather's max |v|",
        "1",
    ),
    "nls_energy": ("energy (Hamiltonian H) of the NLS approximation", "1"),
    "numerical_energy": ("energy (Hamiltonian H) of the numerical breather", "1"),
    # ------------------------------------------------------------------ site-bond
    "site_energy": ("energy of the site-centred breather at K", "1"),
    "bond_energy": ("energy of the bond-centred in-phase breather at K", "1"),
    "barrier": ("Peierls-Nabarro barrier, E(bond in phase) - E(site)", "1"),
    "null_vector": ("Floquet vector at mu = 1 of the branch point, positions (u then v; NaN padded)", "1"),
    "sites": ("number of sites of the family's chain (N or N + 1)", "1"),
    "amplitude": ("step along the unit null vector onto the asymmetric family", "1"),
    "K_offset": ("K - K*, offset of the asymmetric point's coupling from the pitchfork", "1"),
    "distance": (
        "2-norm distance of the asymmetric orbit's positions from the symmetric (site) orbit at the same K",
        "1",
    ),
    # ------------------------------------------------------------------ work-precision
    "implementation": ("implementation index (labels in group attribute implementation_names)", "1"),
    "method": ("integration method index (labels in group attribute method_names)", "1"),
    "dt": ("time step, in units of sqrt(m2/k2) (NaN for adaptive DOP853)", "1"),
    "rtol": ("relative tolerance of the adaptive integrator (NaN for fixed-step methods)", "1"),
    "error": ("final-state error max |x - x_ref| / max |x_ref| against DOP853 at rtol 1e-13", "1"),
    # ------------------------------------------------------------------ monolayer
    "breather_participation": ("participation ratio of the breather's z = u - v at t = 0, in sites", "1"),
    "centre_amplitude": ("max |u - v| at t = 0 (the centre site's)", "1"),
    "x": ("site position along the first lattice vector's direction, in lattice spacings", "1"),
    "y": ("site position perpendicular to it, in lattice spacings", "1"),
    # ------------------------------------------------------------------ benchmarks/throughput.py
    "batch": ("lattices integrated together in one launch", "1"),
    "site_steps_per_second": ("lattice sites times time steps per second of kernel time", "s-1"),
    "force_evals_per_second": ("force evaluations (sites times stages) per second of kernel time", "s-1"),
    "kernel_rate": ("site-steps per second of the kernel alone (time_steps)", "s-1"),
    "default_rate": ("site-steps per second of simulate() from a host x0, end to end", "s-1"),
    "on_device_rate": ("site-steps per second of simulate() continued on the device", "s-1"),
    "recording_rate": ("site-steps per second of simulate() recording frames", "s-1"),
    "recording_reused_rate": ("site-steps per second of simulate() recording into reused frame buffers", "s-1"),
    "recording_pinned_rate": ("site-steps per second of simulate() recording into page-locked buffers", "s-1"),
    "relative_energy_error": ("relative energy error |E(t) - E(0)| / |E(0)| (128 steps per period)", "1"),
}

#: where a group gives a name another meaning: (group, name) -> (long_name, units)
BY_GROUP = {
    # anticontinuum
    ("orbit", "t"): ("time along one period of the single-site (K = 0) orbit, in units of sqrt(m2/k2)", "1"),
    ("orbit", "z"): ("relative displacement z = u - v of the single-site (K = 0) orbit", "1"),
    ("frequency_amplitude", "omega"): ("frequency of the single-site (K = 0) oscillator at amplitude z_max", "1"),
    ("seed", "u"): ("anti-continuum seed u_j at t = 0 (single-site orbit on the centre site)", "1"),
    ("seed", "v"): ("anti-continuum seed v_j at t = 0 (single-site orbit on the centre site)", "1"),
    # breather
    ("breather", "u"): ("breather u_j at t = 0 (time-reversible shooting)", "1"),
    ("breather", "v"): ("breather v_j at t = 0 (time-reversible shooting)", "1"),
    ("direct", "t"): ("time, sampled once per breather period, in units of sqrt(m2/k2)", "1"),
    ("jacobian_comparison", "case"): (
        "orbit index (labels in group attribute case_names: smooth breather, contact loss)",
        "1",
    ),
    ("jacobian_comparison", "seconds"): ("wall-clock time to compute the half-period Jacobian", "s"),
    ("paper_profile", "z"): ("relative displacement z = u - v at t = 0 of the largest chain", "1"),
    ("site_profile", "z"): ("relative displacement z = u - v at t = 0 of the largest chain", "1"),
    # finite-size foam (fixed grid of K)
    ("foam_N101", "stable"): ("linear stability verdict at each K of the fixed grid (1 stable, 0 unstable)", "1"),
    ("foam_N201", "stable"): ("linear stability verdict at each K of the fixed grid (1 stable, 0 unstable)", "1"),
    # site-bond
    ("bifurcations", "K"): ("coupling ratio k1/k2 at the located branch point", "1"),
    ("bifurcations", "energy"): ("breather energy (Hamiltonian H) at the branch point", "1"),
    ("bifurcations", "participation"): (
        "participation ratio in sites of the null vector (Floquet vector at mu = 1)",
        "1",
    ),
    ("bifurcations", "central_weight"): ("fraction of the null vector's site weight on the 5 central sites", "1"),
    ("bifurcations", "state"): ("orbit start at the branch point (u, v, u', v') per site, NaN padded", "1"),
    ("sqrt_law", "K"): ("coupling ratio k1/k2 of the asymmetric point reached with the step amplitude", "1"),
    ("finite_size_K10_N61", "parity"): ("mirror parity of the instability's Floquet vector", "1"),
    ("finite_size_K10_N121", "parity"): ("mirror parity of the instability's Floquet vector", "1"),
    ("finite_size_K10_N61", "participation"): ("participation ratio in sites of the instability's Floquet vector", "1"),
    ("finite_size_K10_N121", "participation"): (
        "participation ratio in sites of the instability's Floquet vector",
        "1",
    ),
    ("finite_size_K10_N61", "central_weight"): (
        "fraction of the instability's Floquet vector weight on the 5 central sites",
        "1",
    ),
    ("finite_size_K10_N121", "central_weight"): (
        "fraction of the instability's Floquet vector weight on the 5 central sites",
        "1",
    ),
    # stability atlas
    ("atlas", "kind"): (
        "instability kind label (coordinate of instabilities: real_pair, period_doubling, complex_quadruplet)",
        "1",
    ),
    ("atlas", "stable"): ("linear stability verdict (1 stable, 0 unstable, -1 no point or no verdict)", "1"),
    ("atlas", "verdict_complete"): ("every multiplier accounted for (1), not (0); -1 no point", "1"),
    ("atlas", "seconds"): ("wall-clock time of the task (timing, not science)", "s"),
    ("atlas", "checksum"): ("CRC-32 of each variable's region of the task (order in array attribute variables)", "1"),
    # breakup statistics
    ("observables", "energy"): ("lattice energy sum_j e_j at the frame", "1"),
    ("observables", "participation"): ("participation ratio of the site energies, (sum e_j)^2 / sum e_j^2", "1"),
    ("observables", "min_contact"): (
        "minimum over the frame interval's steps and the sites of 1 + z_j (<= 0: contact lost)",
        "1",
    ),
    ("observables", "checksum"): (
        "CRC-32 of each variable's region of the task (order in array attribute variables)",
        "1",
    ),
    ("fields_damped", "t"): ("time, sampled 4 times per breather period, in units of sqrt(m2/k2)", "1"),
    ("fields_lossless", "t"): ("time, sampled 4 times per breather period, in units of sqrt(m2/k2)", "1"),
    # work-precision
    ("points", "case"): ("case index (labels in group attribute case_names: smooth, contact-loss)", "1"),
    ("points", "seconds"): ("wall-clock time of the run", "s"),
}

FLAGS = {  # integer codes with meanings (CF flag_values / flag_meanings), name -> (values list, meanings list)
    "instability_kind": ([0, 1, 2], ["real_pair", "period_doubling", "complex_quadruplet"]),
    # int8 "kind" of the site-bond finite_size_K*_N* tables; NOT the atlas' string coordinate "kind"
    "kind": ([0, 1, 2], ["real_pair", "period_doubling", "complex_quadruplet"]),
    "leading_kind": ([0, 1, 2], ["real_pair", "period_doubling", "complex_quadruplet"]),  # -1: none / fill
    "instability_localized": ([0, 1], ["extended", "localized"]),
    "localized": ([0, 1], ["extended", "localized"]),
    "leading_localized": ([0, 1], ["extended", "localized"]),  # -1: none / fill
    "instability_parity": ([-1, 0, 1], ["odd", "unknown_or_mixed", "even"]),
    "parity": ([-1, 0, 1], ["odd", "unknown_or_mixed", "even"]),
    "signature": ([-1, 0, 1], ["negative_krein_signature", "not_elliptic_or_trivial", "positive_krein_signature"]),
    "stable": ([0, 1], ["unstable", "stable"]),  # atlas -1 / branch -128: no point or no verdict (fill)
    "floquet_complete": ([0, 1], ["incomplete", "complete"]),
    "verdict_complete": ([0, 1], ["incomplete", "complete"]),  # atlas -1: no point (fill)
    "completed": ([0, 1], ["not_written", "written"]),
    "end_reason": (
        [0, 1, 2, 3, 4, 5],
        ["end_reached", "contact_lost", "newton_failed", "step_underflow", "max_points", "time_budget"],
    ),
    "finite_difference": ([0, 1], ["tangent", "finite_difference"]),  # bool array
    "trivial": ([0, 1], ["nontrivial", "trivial"]),  # bool array
}


def describe(name: str, group: str | None = None, *, integer: bool = False, required: bool = True) -> dict:
    """The attributes to store beside array ``name`` of ``group`` (a path; its last component is looked up):
    ``long_name``, ``units`` and, for an integer array with fixed codes, ``flag_values`` / ``flag_meanings``.

    Raises:
        ValueError: the name has no entry (add one to ``VARIABLES`` or ``BY_GROUP``); with ``required=False``
            (a user's own sweep variables, ``sweep.store``: their ``Variable.attrs`` describe them) ``{}`` instead.
    """
    leaf = str(group).rstrip("/").rsplit("/", 1)[-1] if group else None
    entry = BY_GROUP.get((leaf, name)) or VARIABLES.get(name)
    if entry is None and not required:
        return {}
    if entry is None:
        where = f" (group {group!r})" if group else ""
        raise ValueError(f"array {name!r}{where} has no long_name and units: add it to warpchain.variables")
    long_name, units = entry
    out = {"long_name": long_name, "units": units}
    if integer and name in FLAGS:
        values, meanings = FLAGS[name]
        out.update(flag_values=list(values), flag_meanings=" ".join(meanings))
    return out
