"""Scene parameters: each field's allowed values stated beside it, checked before a scene runs.

A field of a scene's ``Parameters`` is declared with ``param``::

    periods: int = param(200, "periods of T = 2 pi / 1.01 simulated", ge=1)

``ge``/``gt``/``le``/``lt`` bound a number (inclusive/exclusive; for a tuple, each element), ``choices`` lists
the allowed values (or is a callable giving them, e.g. from the integrator registry), ``multiple_of`` is an
integer's step and ``length`` a tuple's (min, max) length. Numbers must be finite: ``finite=False`` lets
+-inf through, ``nan=True`` NaN. The type is the annotation's: ``int``, ``float``, ``str``, ``bool``,
``tuple[int, ...]``, ``tuple[float, ...]``, each optionally ``| None``. Rules across fields are ``Rule``s in
the class attribute ``RULES`` (not a field). ``check`` applies both and raises a one-line ``ValueError``
naming the parameter, the value given and what is allowed.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable

import numpy as np

#: the longest chain a scene accepts: the longest measured (finite-size's 12801 sites, on the sliced path); every count
#: has such a ceiling, so that no value the ranges allow runs out of memory or for ever
MAX_SITES = 12801
#: the longest chain of a branch walk, a dispersion table or a scan of them: their dense Newton Jacobians (4N x 2N),
#: linear modes (N x N) and Floquet blocks are held in memory (a K branch at 3201 sites: 6 GB resident, a log
#: line every 45 s or sooner; at 51201 one Jacobian alone would take 156 GB)
DENSE_MAX_SITES = 3201

#: how a value reached the parameters (for the messages): typed after --set, or given through the API
SET, API = "set", "api"


@dataclasses.dataclass(frozen=True)
class Allowed:
    """What one field accepts (``param`` builds it; the field's annotation gives the type)."""

    help: str = ""
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: Any = None
    multiple_of: int | None = None
    length: tuple | None = None
    finite: bool = True
    nan: bool = False

    def options(self) -> tuple | None:
        values = self.choices() if callable(self.choices) else self.choices
        return None if values is None else tuple(values)

    def accepts(self, value, kind: "Kind") -> bool:
        if value is None:
            return kind.optional
        if kind.base is tuple:
            if not isinstance(value, (tuple, list)):
                return False
            lo, hi = self.length or (0, None)
            if len(value) < lo or (hi is not None and len(value) > hi):
                return False
            return all(self._scalar(v, kind.item) for v in value)
        return self._scalar(value, kind.base)

    def _scalar(self, v, base: type) -> bool:
        if base is bool:
            return isinstance(v, (bool, np.bool_))
        if isinstance(v, (bool, np.bool_)):
            return False
        if base is str:
            ok = isinstance(v, str)
        elif base is int:
            ok = isinstance(v, (int, np.integer))
            if ok and self.multiple_of and int(v) % self.multiple_of:
                return False
        else:
            ok = isinstance(v, (int, float, np.integer, np.floating))
            if ok and math.isnan(v):
                return self.nan
            if ok and math.isinf(v) and self.finite:
                return False
        if not ok:
            return False
        options = self.options()
        if options is not None and v not in options:
            return False
        if base in (int, float):
            if self.ge is not None and not v >= self.ge:
                return False
            if self.gt is not None and not v > self.gt:
                return False
            if self.le is not None and not v <= self.le:
                return False
            if self.lt is not None and not v < self.lt:
                return False
        return True

    def bounds(self) -> str:
        """The bounds in words: '>= 1', 'in (0, 1]', '' when there are none."""
        lo = ("[", self.ge) if self.ge is not None else ("(", self.gt) if self.gt is not None else None
        hi = ("]", self.le) if self.le is not None else (")", self.lt) if self.lt is not None else None
        if lo and hi:
            return f"in {lo[0]}{number(lo[1])}, {number(hi[1])}{hi[0]}"
        if lo:
            return f"{'>=' if lo[0] == '[' else '>'} {number(lo[1])}"
        if hi:
            return f"{'<=' if hi[0] == ']' else '<'} {number(hi[1])}"
        return ""

    def describe(self, kind: "Kind") -> str:
        """What is allowed, as the end of 'must be ...': 'an integer >= 1', 'one of verlet, kahan8', ..."""
        if kind.base is tuple:
            lo, hi = self.length or (0, None)
            count = (
                f"exactly {lo}"
                if hi == lo
                else f"{lo} to {hi}"
                if hi is not None
                else "any number of"
                if lo == 0
                else "one or more"
                if lo == 1
                else f"{lo} or more"
            )
            noun = "integers" if kind.item is int else "finite numbers" if self.finite and not self.nan else "numbers"
            each = self._element(kind.item, plural=True)
            text = f"{count} comma-separated {noun}" + (f", each {each}" if each else "")
        else:
            text = self._element(kind.base, plural=False)
        return text + (", or none" if kind.optional else "")

    def _element(self, base: type, plural: bool) -> str:
        options = self.options()
        if base is bool:
            return "true or false"
        if options is not None:
            return "one of " + ", ".join(str(o) for o in options)
        if base is str:
            return "" if plural else "any text"
        bounds = self.bounds()
        if plural:
            parts = (
                ["even" if self.multiple_of == 2 else f"a multiple of {self.multiple_of}"] if self.multiple_of else []
            )
            return " and ".join(parts + ([bounds] if bounds else []))
        if base is int:
            noun = (
                "an even integer"
                if self.multiple_of == 2
                else f"an integer multiple of {self.multiple_of}"
                if self.multiple_of
                else "an integer"
            )
        else:
            noun = "a finite number" if self.finite and not self.nan else "a number"
        return f"{noun} {bounds}".strip()


def param(default, help: str = "", **allowed) -> Any:
    """A dataclass field with its allowed values (``Allowed``'s keywords) and its description."""
    return dataclasses.field(default=default, metadata={"allowed": Allowed(help=help, **allowed)})


@dataclasses.dataclass(frozen=True)
class Rule:
    """A rule across fields: ``test(P)`` is True when it holds. ``text`` (a string, or ``text(P)``) says what
    is needed; the message names the first of ``names`` that was given (else the first), and the values of
    the others."""

    names: tuple
    text: Any
    test: Callable

    def wording(self, P) -> str:
        return self.text(P) if callable(self.text) else self.text


@dataclasses.dataclass(frozen=True)
class Kind:
    base: type
    item: type | None = None
    optional: bool = False


@functools.lru_cache(maxsize=None)
def kind_of(annotation) -> Kind:
    """The type of a field from its annotation (a string under ``from __future__ import annotations``)."""
    if isinstance(annotation, type):
        return Kind(annotation, float if annotation is tuple else None)
    parts = [p.strip() for p in str(annotation).replace("typing.", "").split("|")]
    optional = "None" in parts
    main = [p for p in parts if p != "None"]
    if len(main) != 1:
        raise TypeError(f"unsupported parameter annotation {annotation!r}")
    main = main[0]
    if main.startswith("tuple"):
        return Kind(tuple, int if main.replace(" ", "").startswith("tuple[int") else float, optional)
    names = {"int": int, "float": float, "str": str, "bool": bool}
    if main not in names:
        raise TypeError(f"unsupported parameter annotation {annotation!r}")
    return Kind(names[main], None, optional)


def allowed_of(field: dataclasses.Field) -> Allowed | None:
    return field.metadata.get("allowed")


def number(x) -> str:
    """A number as short as it reads back exactly (6 significant digits when they do)."""
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        return str(int(x))
    short = f"{x:.6g}"
    return short if float(short) == x else f"{x:.9g}"


def show(value) -> str:
    """A value as typed after --set."""
    if isinstance(value, (tuple, list)):
        return ",".join(show(v) for v in value)
    if isinstance(value, bool):
        return str(value).lower()
    if value is None:
        return "none"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return number(value)
    return str(value)


#: what ``convert`` returns for text that does not read as the field's type
UNREADABLE = object()
#: a bool as typed after --set
BOOL_WORDS = {"1": True, "true": True, "yes": True, "on": True, "0": False, "false": False, "no": False, "off": False}


def convert(text: str, kind: Kind):
    """A --set value as the field's type (``UNREADABLE`` when it does not read as one)."""
    text = text.strip()
    if kind.optional and text.lower() in ("none", "null"):
        return None
    if kind.base is tuple:
        items = [t.strip() for t in text.strip("()[] ").split(",") if t.strip()]
        out = tuple(_scalar(t, kind.item) for t in items)
        return UNREADABLE if any(v is None for v in out) else out
    value = _scalar(text, kind.base)
    return UNREADABLE if value is None else value


def _scalar(text: str, base: type):
    if base is str:
        return text
    if base is bool:
        return BOOL_WORDS.get(text.lower())
    try:
        if base is int:
            try:
                return int(text)
            except ValueError:
                f = float(text)  # 2e6, 1e3: integers written as floats
                return int(f) if math.isfinite(f) and f.is_integer() else None
        return float(text)
    except ValueError:
        return None


def _source(name: str, value, given: dict, raw: dict, quick: bool) -> str:
    how = given.get(name)
    if how == SET:
        return f"--set {name}={raw.get(name, show(value))!s}".replace("\n", "\\n")  # one line, whatever was typed
    if how == API:
        return f"parameter {name}={show(value)}"
    return f"{name}={show(value)} (the scene's {'--quick ' if quick else ''}default)"


def refused(source: str, allowed: Allowed | None, kind: Kind) -> ValueError:
    """'SOURCE: must be WHAT (HELP)': the one line for a value a field does not accept."""
    allowed = allowed or Allowed()
    return ValueError(f"{source}: must be {allowed.describe(kind)}" + (f" ({allowed.help})" if allowed.help else ""))


def check(P, given: dict, quick: bool = False, raw: dict | None = None) -> None:
    """Every field of ``P`` against its ``Allowed`` (those in ``given`` first), then the class's ``RULES``;
    a ``ValueError`` with one line on the first that fails. ``given``: name -> SET or API; ``raw``: the text
    typed after --set, quoted as typed."""
    raw = raw or {}
    fields = dataclasses.fields(P)
    ordered = [f for f in fields if f.name in given] + [f for f in fields if f.name not in given]
    for f in ordered:
        allowed = allowed_of(f)
        if allowed is None:
            continue
        kind = kind_of(f.type)
        value = getattr(P, f.name)
        if not allowed.accepts(value, kind):
            raise refused(_source(f.name, value, given, raw, quick), allowed, kind)
    for rule in getattr(type(P), "RULES", ()):
        name = next((n for n in rule.names if n in given), rule.names[0])
        try:
            if rule.test(P):
                continue
        except ValueError as exc:  # the rule cannot be weighed at these values (a chain too stiff to step)
            raise ValueError(f"{_source(name, getattr(P, name), given, raw, quick)}: {exc}") from None
        others = ", ".join(f"{n} = {show(getattr(P, n))}" for n in rule.names if n != name)
        raise ValueError(
            f"{_source(name, getattr(P, name), given, raw, quick)}: needs {rule.wording(P)}"
            + (f" ({others})" if others else "")
        )


def listing(cls, quick: dict | None = None) -> list[str]:
    """The parameters of a ``Parameters`` class, with types, defaults (and --quick's), what is allowed and
    their descriptions; then the rules across fields."""
    quick = quick or {}
    defaults = cls()
    lines = []
    for f in dataclasses.fields(cls):
        allowed = allowed_of(f) or Allowed()
        kind = kind_of(f.type)
        type_name = (f"tuple[{kind.item.__name__}]" if kind.base is tuple else kind.base.__name__) + (
            " | None" if kind.optional else ""
        )
        head = f"  {f.name} ({type_name}) = {show(getattr(defaults, f.name)) or '(empty)'}"
        if f.name in quick:
            head += f"  [--quick: {show(quick[f.name]) or '(empty)'}]"
        lines.append(head)
        lines.append(f"      allowed: {allowed.describe(kind)}")
        if allowed.help:
            lines.append(f"      {allowed.help}")
    rules = getattr(cls, "RULES", ())
    if rules:
        lines.append("  across parameters (at the defaults):")
        for rule in rules:
            lines.append(f"    {', '.join(rule.names)}: {rule.wording(defaults)}")
    return lines


# ----------------------------------------------------------------------------- limits the code sets


def splitting_methods() -> tuple:
    """The integrators of the registry that are palindromic splitting compositions (time-reversible,
    symplectic): what ``observe`` runs and what the reduced Floquet analysis of a reversible orbit needs."""
    from warpchain.integrators import METHODS, SplittingMethod

    return tuple(name for name, m in METHODS.items() if isinstance(m, SplittingMethod))


#: a chain this stiff (the optical top ~ sqrt(4K / M)) is refused: more steps than any run here takes
MAX_STEPS_PER_PERIOD = 1e8


def min_steps_per_period(method: str, M: float, K: float, omega: float, multiple_of: int = 1) -> int:
    """The fewest steps per period 2 pi / omega (a multiple of ``multiple_of``) whose step is below the
    method's linear stability limit on the (M, K) chain (``warpchain.stability_limit``)."""
    limit = stability_dt(method, M, K)
    period = 2 * math.pi / omega
    if not (limit > 0 and math.isfinite(period / limit) and period / limit < MAX_STEPS_PER_PERIOD):
        bound = f"dt < {limit:.3g}" if limit > 0 and math.isfinite(limit) else "no stable dt (the stiffness overflows)"
        raise ValueError(
            f"M = {M:g}, K = {K:g}: {method}'s linear stability limit, {bound}, needs more than "
            f"{MAX_STEPS_PER_PERIOD:.0e} steps per period 2 pi / {omega:g}; choose a smaller K or a larger M"
        )
    n = math.floor(period / limit) + 1
    return -(-n // multiple_of) * multiple_of


@functools.lru_cache(maxsize=256)
def stability_dt(method: str, M: float, K: float) -> float:
    from warpchain import ChainParams, stability_limit

    return stability_limit(method, ChainParams(M, K, 1))


@functools.lru_cache(maxsize=256)
def anticontinuum_reached(omega: float, M: float) -> bool:
    """Whether ``continuation.anticontinuum_orbit`` finds the single-site orbit of this frequency (below
    w0 = sqrt((M + 1) / M), and not below the lowest frequency its root finder reaches)."""
    from continuation import anticontinuum_orbit

    try:
        anticontinuum_orbit(omega, M)
    except (ValueError, RuntimeError):
        return False
    return True


def anticontinuum_rule(omega: str = "omega") -> Rule:
    """omega, M: the single-site anti-continuum orbit of that frequency exists (a seed, or the scene's orbit)."""

    def wording(P) -> str:
        w0 = number(math.sqrt((P.M + 1) / P.M))
        if getattr(P, omega) >= math.sqrt((P.M + 1) / P.M):
            return (
                f"{omega} < w0 = sqrt((M + 1) / M) = {w0}: the single-site oscillator softens, its orbits lie below w0"
            )
        return (
            f"{omega} a frequency of the single-site anti-continuum orbit: below w0 = {w0}, and not so low that "
            "continuation.anticontinuum_orbit finds none"
        )

    return Rule((omega, "M"), wording, lambda P: anticontinuum_reached(float(getattr(P, omega)), float(P.M)))
