"""Design objectives a tissue engineer asks for, computed from normalised fields.

Every quantity is a function of the normalised fields F (condor.data.fields.normalise; channels
condor.data.fields.FIELD_NAMES = P, T, Sx2, Sy2, Sz2, SxSy, SxSz, SySz) summed over the pixels p
of a region R (the whole grid by default: sums over the grid are sums over the cells, so "the
tissue" needs no threshold). Each field pixel is a kernel-weighted sum over cells, so a sum of
a field over a region is a (kernel-weighted) sum over the cells in it.

  alignment:THETA   in-plane nematic order along the direction THETA (radians from x):
                    sum_R[(Sx2 - Sy2) cos 2THETA + 2 SxSy sin 2THETA] / sum_R(Sx2 + Sy2),
                    i.e. the mean of cos 2(phi_i - THETA) over the cells, phi_i the in-plane
                    angle of cell i, each cell weighted by its in-plane |s_xy|^2 (a cell
                    standing along z carries no in-plane direction). In [-1, 1]: 1 when every
                    cell lies along THETA, 0 when isotropic, -1 when all lie across it.
  density_cv        coefficient of variation of the density P as the cells see it (each cell
                    samples the density where it sits, so empty pixels weigh nothing):
                    m = sum P^2 / sum P,  cv = sqrt(sum P (P - m)^2 / sum P) / m. P < 0 (a
                    surrogate's ringing outside the tissue) is clipped to 0. In [0, inf).
  uniformity        1 - density_cv (1 for a perfectly uniform tissue; larger is better).
  max_tension       the largest T over the region's pixels: a tearing risk (hot spot).
  mean_tension      sum_R T / sum_R P, the mean cell tension (the paper's T-bar over R).

All but max_tension are ratios of sums, so they do not depend on the normalisation; max_tension
is in normalised units (T * N_pixels / N_cells), comparable between moulds of one scene.

A spec string names what to maximise and, after semicolons, constraints:

    alignment:x                      alignment along x over the tissue
    alignment:45deg@centre           along 45 degrees inside the named region "centre"
    -max_tension                     minimise the hottest tension spot
    alignment:x+0.5*uniformity       a weighted sum (each term is maximised)
    alignment:x; max_tension<0.02    maximise alignment subject to a constraint

Directions: x (0), y (90 deg), a number in degrees ("45", "45deg") or radians ("0.7rad").
Regions (fractions of the box side, origin lower left, y up, as the fields' rows):
`REGIONS` by name, `rect(x0,x1,y0,y1)` or `disc(cx,cy,r)`. `parse_objective` raises an
`ObjectiveError` subclass naming the bad part for an unknown objective or region, a region
that holds no pixel or lies where no mould can reach, or constraints no mould can meet.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from condor.data.fields import FIELD_NAMES

_P, _T, _SX2, _SY2, _SXSY = (FIELD_NAMES.index(n) for n in ("P", "T", "Sx2", "Sy2", "SxSy"))

# Quantity -> (needs a direction, lowest possible value, highest possible value).
QUANTITIES: dict[str, tuple[bool, float, float]] = {
    "alignment": (True, -1.0, 1.0),
    "uniformity": (False, -math.inf, 1.0),
    "density_cv": (False, 0.0, math.inf),
    "max_tension": (False, -math.inf, math.inf),
    "mean_tension": (False, -math.inf, math.inf),
}

# Named regions, fractions of the box side: ("rect", x0, x1, y0, y1) or ("disc", cx, cy, r).
REGIONS: dict[str, tuple] = {
    "all": ("rect", 0.0, 1.0, 0.0, 1.0),
    "tissue": ("rect", 0.0, 1.0, 0.0, 1.0),
    "centre": ("disc", 0.5, 0.5, 0.15),
    "center": ("disc", 0.5, 0.5, 0.15),
    "left": ("rect", 0.0, 0.5, 0.0, 1.0),
    "right": ("rect", 0.5, 1.0, 0.0, 1.0),
    "bottom": ("rect", 0.0, 1.0, 0.0, 0.5),
    "top": ("rect", 0.0, 1.0, 0.5, 1.0),
}
_DIRECTIONS = {"x": 0.0, "y": 90.0}


class ObjectiveError(ValueError):
    """A design objective that cannot be used; the message names the bad part."""


class UnknownObjectiveError(ObjectiveError):
    """An objective, direction or region name that does not exist, or a malformed spec."""


class EmptyRegionError(ObjectiveError):
    """A region that holds no pixel of the grid, or none that any mould can reach."""


class InfeasibleConstraintError(ObjectiveError):
    """Constraints that no mould can meet (out of a quantity's range, or contradictory)."""


@dataclass(frozen=True)
class ObjectiveRegion:
    """A part of the box: ("rect", x0, x1, y0, y1) or ("disc", cx, cy, r), box fractions."""

    shape: tuple
    name: str = ""

    @property
    def label(self) -> str:
        if self.name:
            return self.name
        kind, *values = self.shape
        return f"{kind}({','.join(f'{v:g}' for v in values)})"

    @property
    def is_everything(self) -> bool:
        return self.shape == REGIONS["all"]

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Mask of points (box fractions) inside the region (half-open rectangles)."""
        kind, *v = self.shape
        if kind == "rect":
            x0, x1, y0, y1 = v
            return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
        cx, cy, r = v
        return (x - cx) ** 2 + (y - cy) ** 2 < r * r

    def mask(self, pixels: int) -> np.ndarray:
        """bool (pixels, pixels) [y, x]: pixel centres (i + 0.5) / pixels inside the region."""
        centres = (np.arange(pixels) + 0.5) / pixels
        x, y = np.meshgrid(centres, centres)
        return self.contains(x, y)


EVERYWHERE = ObjectiveRegion(REGIONS["all"], "all")


@dataclass(frozen=True)
class Quantity:
    """One measurable of the fields: `name` (a QUANTITIES key), direction `angle` in radians
    (alignment only) and the region it is measured over."""

    name: str
    angle: float | None = None
    region: ObjectiveRegion = EVERYWHERE

    @property
    def label(self) -> str:
        """Canonical name, e.g. "alignment:0deg", "alignment:45deg@centre", "max_tension"."""
        text = self.name
        if self.angle is not None:
            text += f":{math.degrees(self.angle):g}deg"
        if not self.region.is_everything:
            text += f"@{self.region.label}"
        return text

    @property
    def bounds(self) -> tuple[float, float]:
        return QUANTITIES[self.name][1:]

    def __call__(self, fields: np.ndarray) -> np.ndarray:
        """Values (S,) for normalised fields (S, 8, H, W) (or one (8, H, W) -> shape ())."""
        fields = np.asarray(fields, dtype=np.float64)
        single = fields.ndim == 3
        batch = fields[None] if single else fields
        if batch.ndim != 4 or batch.shape[1] != len(FIELD_NAMES):
            raise ValueError(f"fields must have shape (S, 8, H, W) or (8, H, W), got {fields.shape}")
        mask = None if self.region.is_everything else self.region.mask(batch.shape[-1])
        values = _QUANTITY_FUNCTIONS[self.name](batch, mask, self.angle)
        return values[0] if single else values


def _region_sum(a: np.ndarray, mask) -> np.ndarray:
    """Sum over (H, W) of a (S, H, W), restricted to mask (H, W) when given."""
    return a.sum(axis=(-2, -1)) if mask is None else a[:, mask].sum(axis=-1)


def _alignment(f, mask, angle):
    c, s = math.cos(2 * angle), math.sin(2 * angle)
    along = _region_sum(c * (f[:, _SX2] - f[:, _SY2]) + 2 * s * f[:, _SXSY], mask)
    in_plane = _region_sum(f[:, _SX2] + f[:, _SY2], mask)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(in_plane > 0, along / in_plane, np.nan)


def _density_cv(f, mask, angle):
    p = np.clip(f[:, _P], 0.0, None)
    s1, s2, s3 = (_region_sum(p ** k, mask) for k in (1, 2, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        # sum P (P - m)^2 / sum P with m = s2 / s1 is s3 / s1 - m^2; divided by m^2.
        ratio = np.where(s2 > 0, s3 * s1 / (s2 * s2), np.nan)
    return np.sqrt(np.clip(ratio - 1.0, 0.0, None))


def _uniformity(f, mask, angle):
    return 1.0 - _density_cv(f, mask, angle)


def _max_tension(f, mask, angle):
    t = f[:, _T]
    return t.max(axis=(-2, -1)) if mask is None else t[:, mask].max(axis=-1)


def _mean_tension(f, mask, angle):
    total = _region_sum(f[:, _P], mask)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, _region_sum(f[:, _T], mask) / total, np.nan)


_QUANTITY_FUNCTIONS = {"alignment": _alignment, "density_cv": _density_cv,
                       "uniformity": _uniformity, "max_tension": _max_tension,
                       "mean_tension": _mean_tension}

_OPERATORS = ("<=", ">=", "<", ">")


@dataclass(frozen=True)
class Constraint:
    """quantity `op` bound, op one of <, <=, >, >= (strict and non-strict are treated alike:
    the fields are continuous)."""

    quantity: Quantity
    op: str
    bound: float

    @property
    def label(self) -> str:
        return f"{self.quantity.label}{self.op}{self.bound:g}"

    @property
    def upper(self) -> bool:
        return self.op in ("<", "<=")

    def violation(self, values: np.ndarray) -> np.ndarray:
        """How far values miss the bound (0 where met; NaN values count as infinitely far)."""
        gap = values - self.bound if self.upper else self.bound - values
        return np.where(np.isnan(values), np.inf, np.clip(gap, 0.0, None))


@dataclass(frozen=True)
class Objective:
    """sum_k weight_k * quantity_k, to be maximised, subject to `constraints`."""

    spec: str
    terms: tuple[tuple[float, Quantity], ...]
    constraints: tuple[Constraint, ...] = field(default=())

    @property
    def quantities(self) -> tuple[Quantity, ...]:
        """Every distinct quantity used by terms and constraints, in order of appearance."""
        seen: dict[str, Quantity] = {}
        for q in [q for _, q in self.terms] + [c.quantity for c in self.constraints]:
            seen.setdefault(q.label, q)
        return tuple(seen.values())

    @property
    def label(self) -> str:
        """Canonical text of the objective (what to maximise), e.g. "alignment:0deg"."""
        parts = []
        for weight, q in self.terms:
            sign = "-" if weight < 0 else "+"
            magnitude = abs(weight)
            parts.append(f"{sign}{'' if magnitude == 1 else f'{magnitude:g}*'}{q.label}")
        text = "".join(parts)
        return text[1:] if text.startswith("+") else text

    def evaluate(self, fields: np.ndarray) -> pd.DataFrame:
        """One row per sample of normalised fields (S, 8, H, W): a column per quantity (its
        label), "objective" (the weighted sum), "violation" (summed constraint misses) and
        "feasible". A quantity that is undefined (a region without cells) is NaN, and so is
        the objective."""
        fields = np.asarray(fields)
        if fields.ndim == 3:
            fields = fields[None]
        values = {q.label: q(fields) for q in self.quantities}
        objective = sum(w * values[q.label] for w, q in self.terms)
        violation = np.zeros(len(fields))
        for c in self.constraints:
            violation = violation + c.violation(values[c.quantity.label])
        table = pd.DataFrame(values)
        table.insert(0, "objective", objective)
        table["violation"] = violation
        table["feasible"] = violation == 0
        return table

    def evaluate_raw(self, raw: np.ndarray, n_cells) -> pd.DataFrame:
        """`evaluate` of un-normalised fields (S, 8, H, W) with their cell counts (S,)."""
        from condor.data.fields import normalise

        return self.evaluate(normalise(np.asarray(raw), n_cells))

    def check(self, pixels: int, max_extent: float = 1.0) -> None:
        """Raise EmptyRegionError for a region with no pixel centre of a `pixels` grid, or
        none inside the central square of side `max_extent` (box fractions) where every
        mould lies (moulds are centred and no wider than max_extent)."""
        if isinstance(pixels, bool) or not isinstance(pixels, (int, np.integer)) or pixels < 1:
            raise ValueError(f"pixels = {pixels!r} must be a positive integer")
        centres = (np.arange(pixels) + 0.5) / pixels
        x, y = np.meshgrid(centres, centres)
        low, high = 0.5 - max_extent / 2, 0.5 + max_extent / 2
        reachable = (x >= low) & (x <= high) & (y >= low) & (y <= high)
        for q in self.quantities:
            inside = q.region.contains(x, y)
            if not inside.any():
                raise EmptyRegionError(f"region {q.region.label!r} of {q.label!r} holds no pixel "
                                       f"of the {pixels}x{pixels} grid")
            if not (inside & reachable).any():
                raise EmptyRegionError(
                    f"region {q.region.label!r} of {q.label!r} lies outside the central "
                    f"{max_extent:g} x {max_extent:g} of the box, where every mould lies: no "
                    "mould puts cells there")


# --------------------------------------------------------------------------- parsing

_TOKEN = re.compile(r"\s*(?:(?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)"
                    r"|(?P<name>[A-Za-z_][A-Za-z0-9_]*)|(?P<op><=|>=|[-+*:@(),<>;]))")


def _tokenise(text: str) -> list[tuple[str, str, int]]:
    tokens, pos = [], 0
    while pos < len(text):
        if text[pos:].strip() == "":
            break
        match = _TOKEN.match(text, pos)
        if match is None or match.end() == pos:
            where = len(text) - len(text[pos:].lstrip())
            raise UnknownObjectiveError(f"objective {text!r}: unexpected character "
                                        f"{text[where]!r} at position {where}")
        kind = match.lastgroup
        start = match.start(kind)
        tokens.append((kind, match.group(kind), start))
        pos = match.end()
    return tokens


class _Parser:
    def __init__(self, text: str, part: str):
        self.text, self.part = text, part
        self.tokens = _tokenise(part)
        self.i = 0

    def error(self, message: str, cls=UnknownObjectiveError):
        return cls(f"objective {self.text!r}: {message}")

    def peek(self, value=None):
        if self.i >= len(self.tokens):
            return None
        token = self.tokens[self.i]
        return token if value is None or token[1] == value else None

    def take(self, value=None, kind=None, what=""):
        token = self.peek()
        if token is None or (value is not None and token[1] != value) or \
                (kind is not None and token[0] != kind):
            found = "the end" if token is None else repr(token[1])
            raise self.error(f"expected {what or repr(value)} in {self.part.strip()!r}, "
                             f"found {found}")
        self.i += 1
        return token

    def number(self, what: str) -> float:
        sign = -1.0 if self.peek("-") and self.take("-") else 1.0
        return sign * float(self.take(kind="number", what=what)[1])

    def quantity(self) -> Quantity:
        name = self.take(kind="name", what="an objective name")[1].lower()
        if name not in QUANTITIES:
            raise self.error(f"unknown objective {name!r}; choose one of {sorted(QUANTITIES)}")
        angle = None
        if self.peek(":"):
            self.take(":")
            if not QUANTITIES[name][0]:
                raise self.error(f"{name!r} takes no direction")
            angle = self.direction()
        elif QUANTITIES[name][0]:
            raise self.error(f"{name!r} needs a direction, e.g. {name}:x, {name}:y or "
                             f"{name}:45deg")
        region = EVERYWHERE
        if self.peek("@"):
            self.take("@")
            region = self.region()
        return Quantity(name, angle, region)

    def direction(self) -> float:
        token = self.peek()
        if token is not None and token[0] == "name":
            self.take()
            if token[1].lower() not in _DIRECTIONS:
                raise self.error(f"unknown direction {token[1]!r}; use x, y or an angle such as "
                                 "45deg or 0.5rad")
            return math.radians(_DIRECTIONS[token[1].lower()])
        value = self.number("a direction (x, y or an angle)")
        unit = self.peek()
        if unit is not None and unit[0] == "name" and unit[1].lower() in ("deg", "rad"):
            self.take()
            return value if unit[1].lower() == "rad" else math.radians(value)
        return math.radians(value)

    def region(self) -> ObjectiveRegion:
        name = self.take(kind="name", what="a region")[1].lower()
        if name in ("rect", "disc"):
            count = 4 if name == "rect" else 3
            self.take("(")
            values = [self.number("a box fraction")]
            for _ in range(count - 1):
                self.take(",")
                values.append(self.number("a box fraction"))
            self.take(")")
            return _checked_region((name, *values), self)
        if name not in REGIONS:
            raise self.error(f"unknown region {name!r}; choose one of {sorted(REGIONS)}, "
                             "rect(x0,x1,y0,y1) or disc(cx,cy,r) in box fractions")
        return ObjectiveRegion(REGIONS[name], name)

    def expression(self) -> list[tuple[float, Quantity]]:
        terms = []
        sign = 1.0
        if self.peek("-") or self.peek("+"):
            sign = -1.0 if self.take()[1] == "-" else 1.0
        while True:
            weight = 1.0
            token = self.peek()
            if token is not None and token[0] == "number":
                weight = float(self.take()[1])
                self.take("*", what="'*' after a weight")
            terms.append((sign * weight, self.quantity()))
            token = self.peek()
            if token is None:
                return terms
            if token[1] not in "+-":
                raise self.error(f"unexpected {token[1]!r} in {self.part.strip()!r} (terms are "
                                 "joined by + or -; constraints follow a ';')")
            sign = -1.0 if self.take()[1] == "-" else 1.0

    def constraint(self) -> Constraint:
        q = self.quantity()
        token = self.peek()
        if token is None or token[1] not in _OPERATORS:
            raise self.error(f"constraint {self.part.strip()!r} needs a comparison "
                             f"({', '.join(_OPERATORS)}) and a bound")
        op = self.take()[1]
        bound = self.number("a bound")
        if self.peek() is not None:
            raise self.error(f"unexpected {self.peek()[1]!r} after the bound in "
                             f"{self.part.strip()!r}")
        return Constraint(q, op, bound)


def _checked_region(shape: tuple, parser: _Parser) -> ObjectiveRegion:
    kind, *v = shape
    region = ObjectiveRegion(tuple([kind, *map(float, v)]))
    if kind == "rect" and not (v[0] < v[1] and v[2] < v[3]):
        raise parser.error(f"region {region.label} is empty: it needs x0 < x1 and y0 < y1",
                           EmptyRegionError)
    if kind == "disc" and not v[2] > 0:
        raise parser.error(f"region {region.label} is empty: its radius must be positive",
                           EmptyRegionError)
    return region


def parse_objective(spec: str, pixels: int | None = None,
                    max_extent: float = 1.0) -> Objective:
    """Parse a spec string (module docstring) into an Objective.

    With `pixels` (the grid the fields live on; the predictor's native size) every region is
    checked to hold a pixel inside the central `max_extent` square where the moulds lie
    (`Objective.check`). Raises UnknownObjectiveError, EmptyRegionError or
    InfeasibleConstraintError (all ObjectiveError, a ValueError) naming the bad part.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise UnknownObjectiveError(f"objective {spec!r} is empty; e.g. 'alignment:x', "
                                    f"'-max_tension', 'alignment:x+0.5*uniformity'")
    parts = spec.split(";")
    if not parts[0].strip():
        raise UnknownObjectiveError(f"objective {spec!r} has constraints but nothing to "
                                    "maximise before the first ';'")
    terms = _Parser(spec, parts[0]).expression()
    constraints = []
    for part in parts[1:]:
        if part.strip():
            constraints.append(_Parser(spec, part).constraint())
    objective = Objective(spec, tuple(terms), tuple(constraints))
    check_constraints(objective)
    if pixels is not None:
        objective.check(pixels, max_extent)
    return objective


def check_constraints(objective: Objective) -> None:
    """Raise InfeasibleConstraintError when no mould can meet the constraints: a bound beyond
    a quantity's range, contradictory bounds on one quantity, or alignment bounds (in one
    region) that no in-plane order tensor meets. The in-plane order of a region is a point
    (a, b) = (sum(Sx2 - Sy2), sum 2 SxSy) / sum(Sx2 + Sy2) of the unit disc, and
    alignment:THETA = a cos 2THETA + b sin 2THETA, so alignment bounds are half-planes."""
    if not objective.constraints:
        return
    by_quantity: dict[str, list[Constraint]] = {}
    for c in objective.constraints:
        by_quantity.setdefault(c.quantity.label, []).append(c)
        low, high = c.quantity.bounds
        if (c.upper and c.bound < low) or (not c.upper and c.bound > high):
            raise InfeasibleConstraintError(
                f"objective {objective.spec!r}: no mould can meet {c.label}: "
                f"{c.quantity.name} lies in [{low:g}, {high:g}]")
    for label, group in by_quantity.items():
        low = max([c.bound for c in group if not c.upper], default=-math.inf)
        high = min([c.bound for c in group if c.upper], default=math.inf)
        if low > high:
            raise InfeasibleConstraintError(
                f"objective {objective.spec!r}: the constraints on {label} contradict each "
                f"other (at least {low:g} and at most {high:g})")
    _check_alignment_disc(objective)


def _check_alignment_disc(objective: Objective, resolution: int = 401) -> None:
    by_region: dict[str, list[Constraint]] = {}
    for c in objective.constraints:
        if c.quantity.name == "alignment":
            by_region.setdefault(c.quantity.region.label, []).append(c)
    grid = np.linspace(-1.0, 1.0, resolution)
    a, b = np.meshgrid(grid, grid)
    disc = a * a + b * b <= 1.0 + 1e-12
    slack = 2.0 / (resolution - 1)  # one grid step: a boundary solution is not missed
    for region, group in by_region.items():
        if len({c.quantity.angle for c in group}) < 2:
            continue  # one direction: the range check above is exact
        ok = disc.copy()
        for c in group:
            value = a * math.cos(2 * c.quantity.angle) + b * math.sin(2 * c.quantity.angle)
            ok &= value <= c.bound + slack if c.upper else value >= c.bound - slack
        if not ok.any():
            labels = ", ".join(c.label for c in group)
            raise InfeasibleConstraintError(
                f"objective {objective.spec!r}: no in-plane orientation meets {labels} "
                f"together (alignment along THETA and THETA + 90 deg sum to zero)")
