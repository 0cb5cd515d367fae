"""The dispersions of a Monte Carlo campaign: a table of cases, or rules that draw them.

A campaign (:mod:`render.montecarlo`) renders one scenario many times, each case with some
of its values changed. The values a case may change (its *keys*):

=====================================  ======================================================
key                                    what it sets in the case's scenario
=====================================  ======================================================
``seed``                               ``seed``: the sensor's noise and every other draw
``position.x``, ``.y``, ``.z``         ``[dispersion] position`` (m, world): initial position
``velocity.x``, ``.y``, ``.z``         ``[dispersion] velocity`` (m/s, world): velocity error
``attitude.x``, ``.y``, ``.z``         ``[dispersion] attitude`` (degrees, camera frame)
``sun.azimuth``, ``sun.elevation``     ``[sun]`` (degrees; the scenario's sun must be given
                                       by angles, not by ``direction``)
``sensor.NAME``                        ``[sensor] NAME`` for each number of the sensor
                                       model (:data:`SENSOR_KEYS`: ``exposure``, ``gain``,
                                       ``read_noise``, ``exposure_time``, ``bits``, ...)
=====================================  ======================================================

A key a case leaves out keeps the scenario's value. An unknown key is refused by name, with
the nearest valid one.

The cases come from one of three files:

* a CSV table, one row per case and one column per key (an empty cell: the scenario's value);
* a TOML table of cases, ``[[case]]`` tables of keys (``position = [x, y, z]`` and
  ``sun = {elevation = 4.0}`` are read as their dotted keys);
* TOML sampling rules, ``cases = N``, ``seed = S`` and a ``[sample]`` table giving each key
  a rule: ``{normal = [mean, sd]}``, ``{uniform = [low, high]}`` or ``{choice = [a, ...]}``,
  and ``seed = "per-case"`` for a sensor seed of each case's own. Every draw is keyed by
  (``S``, the key, the case), so case ``k`` is the same whatever ``N`` is and whichever
  worker draws it.

Examples
--------
>>> d = Dispersions.from_mapping({"cases": 3, "seed": 1,
...                               "sample": {"sun.elevation": {"uniform": [4.0, 6.0]}}})
>>> d.keys, len(d.cases)
(('sun.elevation',), 3)
>>> all(4.0 <= c["sun.elevation"] <= 6.0 for c in d.cases)
True
"""

from __future__ import annotations

import copy
import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from render.sensor import Sensor
from terrain.core.checks import check_keys, integer, number, reject_unknown, text
from terrain.core.errors import InvalidParameterError, MissingInputError
from terrain.core.rng import (
    MAX_SEED,
    check_seed,
    hash64,
    normal_scalar,
    stream_id,
    uniform_scalar,
)
from terrain.core.tomlfile import read_toml

__all__ = ["KEYS", "MAX_CASES", "SENSOR_KEYS", "Dispersions", "case_table", "read_dispersions"]

#: The sensor model's numbers a case may set (``sensor.NAME``).
SENSOR_KEYS = tuple(sorted(
    name for name, f in Sensor.__dataclass_fields__.items()
    if str(f.type) in ("float", "float | None") or name == "bits"))
#: The vectors of ``[dispersion]`` and their components.
_VECTORS = ("position", "velocity", "attitude")
_AXES = ("x", "y", "z")
#: Every key a case may set.
KEYS = frozenset({"seed", "sun.azimuth", "sun.elevation"}
                 | {f"{v}.{a}" for v in _VECTORS for a in _AXES}
                 | {f"sensor.{k}" for k in SENSOR_KEYS})
#: Keys whose values are integers.
_INTEGER_KEYS = frozenset({"seed", "sensor.bits"})
#: The most cases one campaign may hold.
MAX_CASES = 1_000_000
#: Rules of a ``[sample]`` key and the number of parameters each takes (None: one or more).
RULES = {"normal": 2, "uniform": 2, "choice": None}
#: The value of ``[sample] seed`` that draws every case a sensor seed of its own.
PER_CASE = "per-case"
_TABLE_KEYS = frozenset({"case"})
_RULE_KEYS = frozenset({"cases", "seed", "sample"})


def _flatten(table: Mapping, where: str, *, rules: bool = False) -> dict[str, Any]:
    """Return nested tables as dotted keys (``sun = {elevation = 4}``: ``sun.elevation``)."""
    out: dict[str, Any] = {}
    todo = [("", table)]
    while todo:
        prefix, t = todo.pop()
        for k, v in t.items():
            name = f"{prefix}{k}"
            if isinstance(v, Mapping) and not (rules and name in KEYS):
                todo.append((f"{name}.", v))
            elif name in _VECTORS and isinstance(v, list) and not rules:
                if len(v) != 3:
                    raise InvalidParameterError(f"{where} {name} must be [x, y, z]; got {v!r}")
                out.update({f"{name}.{a}": x for a, x in zip(_AXES, v, strict=True)})
            else:
                out[name] = v
    reject_unknown(out, KEYS, where)
    return out


def _value(key: str, value: Any, where: str) -> float | int:
    """Check one case's value of ``key`` (integers for ``seed`` and ``sensor.bits``)."""
    if key == "seed":
        try:
            return check_seed(value)
        except ValueError as exc:
            raise InvalidParameterError(f"{where} seed: {exc}") from None
    if key in _INTEGER_KEYS:
        return integer(value, key, low=1, where=where)
    return number(value, key, where=where)


@dataclass(frozen=True)
class Dispersions:
    """The cases of a campaign: for each, the keys it sets and their values.

    Parameters
    ----------
    keys : tuple of str
        Every key some case sets, sorted (:data:`KEYS`).
    cases : tuple of dict
        One mapping of key to value per case, in case order (case 0 first).
    source : str
        ``"table"`` or ``"rules"`` (and the rules' seed), for the campaign's record.
    """

    keys: tuple[str, ...]
    cases: tuple[dict, ...]
    source: str = "table"

    def __post_init__(self) -> None:
        if not self.cases:
            raise InvalidParameterError("dispersions give no cases")
        if len(self.cases) > MAX_CASES:
            raise InvalidParameterError(
                f"dispersions give {len(self.cases)} cases; at most {MAX_CASES} per campaign")

    @classmethod
    def from_mapping(cls, table: Mapping) -> Dispersions:
        """Build the cases of a TOML file's tables: ``[[case]]`` tables, or sampling rules.

        Parameters
        ----------
        table : mapping
            ``{"case": [...]}`` or ``{"cases": N, "seed": S, "sample": {...}}``.

        Returns
        -------
        Dispersions
        """
        if not isinstance(table, Mapping):
            raise InvalidParameterError(f"dispersions must be a table; got {table!r}")
        if "case" in table:
            check_keys(table, _TABLE_KEYS, "dispersions")
            rows = table["case"]
            if not isinstance(rows, list) or not all(isinstance(r, Mapping) for r in rows):
                raise InvalidParameterError("dispersions case must be [[case]] tables")
            cases = []
            for n, row in enumerate(rows):
                where = f"dispersions [[case]] #{n}"
                flat = _flatten(row, where)
                cases.append({k: _value(k, v, where) for k, v in sorted(flat.items())})
            return cls(tuple(sorted({k for c in cases for k in c})), tuple(cases), "table")
        return cls._from_rules(check_keys(table, _RULE_KEYS, "dispersions"))

    @classmethod
    def _from_rules(cls, table: dict) -> Dispersions:
        where = "dispersions"
        if "cases" not in table or "sample" not in table:
            raise InvalidParameterError(
                "dispersions need [[case]] tables, or sampling rules: cases = N, seed = S "
                "and a [sample] table")
        n = integer(table["cases"], "cases", low=1, high=MAX_CASES, where=where)
        try:
            seed = check_seed(table.get("seed", 0))
        except ValueError as exc:
            raise InvalidParameterError(f"dispersions seed: {exc}") from None
        if not isinstance(table["sample"], Mapping):
            raise InvalidParameterError(f"dispersions [sample] must be a table; got "
                                        f"{table['sample']!r}")
        rules = _flatten(table["sample"], "dispersions [sample]", rules=True)
        draws = {key: _rule(key, rule) for key, rule in sorted(rules.items())}
        cases = tuple({key: draw(seed, k) for key, draw in draws.items()} for k in range(n))
        return cls(tuple(sorted(draws)), cases, f"rules (seed {seed})")

    def as_dict(self) -> dict:
        """Return the cases as plain data (the campaign's record of what it renders)."""
        return {"keys": list(self.keys), "source": self.source,
                "cases": [dict(c) for c in self.cases]}


def _rule(key: str, rule: Any):
    """Return the draw of one ``[sample]`` rule: a function of (seed, case)."""
    where = f"dispersions [sample] {key}"
    stream = stream_id(f"dispersion:{key}")
    if key == "seed":
        if rule != PER_CASE:
            raise InvalidParameterError(f"{where} must be {PER_CASE!r}; got {rule!r}")
        return lambda seed, k: int(hash64(seed, stream, 0, k, 0, 0)) & MAX_SEED
    if not isinstance(rule, Mapping) or len(rule) != 1:
        raise InvalidParameterError(
            f"{where} must be one of {{normal = [mean, sd]}}, {{uniform = [low, high]}} or "
            f"{{choice = [a, b, ...]}}; got {rule!r}")
    kind, params = next(iter(rule.items()))
    reject_unknown([kind], RULES, f"{where} rule", "kind")
    if not isinstance(params, list) or not params or (
            RULES[kind] is not None and len(params) != RULES[kind]):
        shape = "[a, b, ...]" if kind == "choice" else \
            "[mean, sd]" if kind == "normal" else "[low, high]"
        raise InvalidParameterError(f"{where} {kind} must be {shape}; got {params!r}")
    values = [_value(key, p, f"{where} {kind}") for p in params]
    if kind == "choice":
        return lambda seed, k: values[min(int(uniform_scalar(seed, stream, 0, k, 0, 0)
                                              * len(values)), len(values) - 1)]
    if key in _INTEGER_KEYS:
        raise InvalidParameterError(f"{where}: an integer key takes choice = [a, b, ...]")
    a, b = values
    if kind == "normal":
        if not b >= 0:
            raise InvalidParameterError(f"{where} normal sd must be >= 0; got {b}")
        return lambda seed, k: a + b * float(normal_scalar(seed, stream, 0, k, 0, 0))
    if not b >= a:
        raise InvalidParameterError(f"{where} uniform needs low <= high; got [{a}, {b}]")
    return lambda seed, k: a + (b - a) * float(uniform_scalar(seed, stream, 0, k, 0, 0))


def _read_csv(path: Path) -> Dispersions:
    """Read a CSV table of cases (one column per key; an empty cell keeps the scenario's)."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InvalidParameterError(f"cannot read dispersions '{path}': {exc}") from None
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if not rows:
        raise InvalidParameterError(f"dispersions '{path}' is empty; expected a header of keys")
    header = [h.strip() for h in rows[0]]
    reject_unknown(header, KEYS, f"dispersions '{path}'", "column")
    if len(set(header)) != len(header):
        raise InvalidParameterError(f"dispersions '{path}' names a column twice: {header}")
    cases = []
    for n, row in enumerate(rows[1:], start=2):
        where = f"dispersions '{path}' line {n}"
        if len(row) != len(header):
            raise InvalidParameterError(f"{where} has {len(row)} cells; the header has "
                                        f"{len(header)}")
        case = {}
        for key, cell in zip(header, row, strict=True):
            cell = cell.strip()
            if not cell:
                continue
            try:
                value: float | int = int(cell) if key in _INTEGER_KEYS else float(cell)
            except ValueError:
                raise InvalidParameterError(f"{where} {key} must be a number; got "
                                            f"{cell!r}") from None
            case[key] = _value(key, value, where)
        cases.append(dict(sorted(case.items())))
    if not cases:
        raise InvalidParameterError(f"dispersions '{path}' has a header but no cases")
    return Dispersions(tuple(sorted(set(header))), tuple(cases), "table")


def read_dispersions(path: str | Path) -> Dispersions:
    """Read a campaign's dispersions: a CSV table, a TOML table of cases or sampling rules.

    Parameters
    ----------
    path : str or pathlib.Path
        ``.csv`` or ``.toml`` (see the module docstring).

    Returns
    -------
    Dispersions
    """
    path = Path(path)
    if not path.is_file():
        raise MissingInputError(f"dispersions file '{path}' does not exist")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return _read_csv(path)
    if suffix == ".toml":
        return Dispersions.from_mapping(read_toml(path, "dispersions"))
    raise InvalidParameterError(f"dispersions must be a .csv or .toml file; got '{path}'")


def case_table(scenario: dict, values: Mapping[str, Any], name: str) -> dict:
    """Return a scenario's tables with one case's values set (see the module docstring).

    Parameters
    ----------
    scenario : dict
        The scenario's parsed TOML tables (left unchanged).
    values : mapping of str to number
        The case's keys and values.
    name : str
        The case's scenario name.

    Returns
    -------
    dict
        The case's scenario tables, for :func:`render.scenario.parse_scenario`.

    Examples
    --------
    >>> t = case_table({"sun": {"elevation": 5.0}}, {"sun.elevation": 7.0,
    ...                                              "position.x": 10.0}, "c1")
    >>> t["sun"]["elevation"], t["dispersion"]["position"], t["name"]
    (7.0, [10.0, 0.0, 0.0], 'c1')
    """
    table = copy.deepcopy(scenario)
    table["name"] = text(name, "name", where="dispersions case")
    for key, value in values.items():
        section, _, field = key.partition(".")
        if key == "seed":
            table["seed"] = value
        elif section in _VECTORS:
            disp = table.setdefault("dispersion", {})
            vec = list(disp.get(section, [0.0, 0.0, 0.0]))
            vec[_AXES.index(field)] = value
            disp[section] = vec
        elif section == "sun":
            sun = table.setdefault("sun", {})
            if "direction" in sun:
                raise InvalidParameterError(
                    f"dispersions set {key}, but the scenario's [sun] gives a direction; give "
                    "the sun by azimuth and elevation there")
            sun[field] = value
        else:
            table.setdefault("sensor", {})[field] = value
    for v in values.values():
        if isinstance(v, float) and not math.isfinite(v):
            raise InvalidParameterError(f"dispersions case {name}: values must be finite")
    return table
